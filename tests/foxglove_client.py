"""A Foxglove WebSocket client nobody here wrote the protocol code of: the
`websockets` package speaks WebSocket, Google's `protobuf` decodes each channel
with the schema the server advertised (a FileDescriptorSet), JSON channels with
json. Subscribes to every channel of the live view, listens for a while and
prints what it decoded, one JSON object, for tests/tests/live_view.rs to check.

    python foxglove_client.py ws://127.0.0.1:PORT SECONDS [PICTURE.png]

With PICTURE, the last image that has annotations of its own time is drawn with
them (OpenCV) as a Foxglove Image panel would show it.
"""

import asyncio
import base64
import json
import struct
import sys
import time

import websockets
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory


def protobuf_class(schema_name, schema_b64):
    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(schema_b64))
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


def summary(topic, schema, msg):
    """The fields a test checks, per schema."""
    if schema == "foxglove.RawImage":
        return {"width": msg.width, "height": msg.height, "encoding": msg.encoding, "step": msg.step,
                "bytes": len(msg.data), "frame_id": msg.frame_id,
                "stamp_ns": msg.timestamp.seconds * 10**9 + msg.timestamp.nanos}
    if schema == "foxglove.ImageAnnotations":
        return {"stamp_ns": msg.timestamp.seconds * 10**9 + msg.timestamp.nanos,
                "circles": [[c.position.x, c.position.y, c.diameter,
                             c.outline_color.r, c.outline_color.g, c.outline_color.b] for c in msg.circles],
                "texts": [t.text for t in msg.texts]}
    if schema == "foxglove.SceneUpdate":
        return {"entities": [{"id": e.id, "frame_id": e.frame_id,
                              "stamp_ns": e.timestamp.seconds * 10**9 + e.timestamp.nanos,
                              "spheres": [[s.pose.position.x, s.pose.position.y, s.pose.position.z,
                                           s.size.x, s.size.y, s.size.z] for s in e.spheres],
                              "cubes": len(e.cubes)} for e in msg.entities],
                "deletions": [d.id for d in msg.deletions]}
    if schema == "foxglove.FrameTransforms":
        return [{"parent": t.parent_frame_id, "child": t.child_frame_id,
                 "translation": [t.translation.x, t.translation.y, t.translation.z]} for t in msg.transforms]
    if schema == "foxglove.CameraCalibration":
        return {"width": msg.width, "height": msg.height, "k": list(msg.K if hasattr(msg, "K") else msg.k)}
    if schema == "foxglove.PointCloud":
        return {"points": len(msg.data) // max(msg.point_stride, 1), "stride": msg.point_stride,
                "fields": [f.name for f in msg.fields]}
    return None


def draw(images, annotations, path):
    import cv2
    import numpy as np
    by_stamp = {a["stamp_ns"]: a for a in annotations}
    for stamp, msg in reversed(images):
        a = by_stamp.get(stamp)
        if a is None or not a["circles"]:
            continue
        rgb = np.frombuffer(msg.data, dtype=np.uint8).reshape(msg.height, msg.step)[:, :3 * msg.width]
        bgr = cv2.cvtColor(rgb.reshape(msg.height, msg.width, 3), cv2.COLOR_RGB2BGR)
        # The outlet's neighbourhood, enlarged 3x, as one would zoom in Foxglove.
        xs = [c[0] for c in a["circles"]]
        ys = [c[1] for c in a["circles"]]
        x0, y0 = max(0, int(min(xs)) - 70), max(0, int(min(ys)) - 50)
        x1, y1 = min(msg.width, int(max(xs)) + 70), min(msg.height, int(max(ys)) + 50)
        k = 3
        big = cv2.resize(bgr[y0:y1, x0:x1], None, fx=k, fy=k, interpolation=cv2.INTER_CUBIC)
        for c in a["circles"]:
            # Foxglove's origin is the first pixel's corner, OpenCV's its centre.
            x, y, d = (c[0] - 0.5 - x0) * k, (c[1] - 0.5 - y0) * k, c[2] * k
            colour = (int(255 * c[5]), int(255 * c[4]), int(255 * c[3]))
            cv2.circle(big, (round(x * 4), round(y * 4)), round(d * 2), colour, 2, cv2.LINE_AA, shift=2)
        for t in a["texts"]:
            cv2.putText(big, t, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 2, cv2.LINE_AA)
            cv2.putText(big, t, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
        cv2.imwrite(path, big)
        return True
    return False


async def listen(url, seconds, picture=None):
    deadline = time.monotonic() + 30.0
    while True:
        try:
            ws = await websockets.connect(url, subprotocols=["foxglove.sdk.v1"], max_size=None)
            break
        except OSError:
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.2)
    out = {"subprotocol": ws.subprotocol, "server": None, "channels": {}, "messages": {}}
    subs = {}
    decoders = {}
    images = []
    async with ws:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                raw = await asyncio.wait_for(ws.recv(), timeout=max(0.05, end - time.monotonic()))
            except asyncio.TimeoutError:
                break
            if isinstance(raw, str):
                op = json.loads(raw)
                if op.get("op") == "serverInfo":
                    out["server"] = op.get("name")
                elif op.get("op") == "advertise":
                    new = []
                    for ch in op["channels"]:
                        out["channels"][ch["topic"]] = {"schema": ch["schemaName"], "encoding": ch["encoding"],
                                                        "schemaEncoding": ch.get("schemaEncoding")}
                        sid = len(subs) + 1
                        subs[sid] = ch
                        if ch["encoding"] == "protobuf":
                            decoders[sid] = protobuf_class(ch["schemaName"], ch["schema"])
                        new.append({"id": sid, "channelId": ch["id"]})
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
                continue
            if raw[0] != 0x01:
                continue
            sid, log_time = struct.unpack_from("<IQ", raw, 1)
            payload = raw[13:]
            ch = subs.get(sid)
            if ch is None:
                continue
            topic = ch["topic"]
            if ch["encoding"] == "json":
                value = json.loads(payload)
            else:
                msg = decoders[sid].FromString(payload)
                value = summary(topic, ch["schemaName"], msg)
                if picture and ch["schemaName"] == "foxglove.RawImage":
                    images = (images + [(value["stamp_ns"], msg)])[-20:]
            out["messages"].setdefault(topic, []).append(value)
    if picture:
        out["picture"] = draw(images, out["messages"].get("/outlet/annotations", []), picture)
    # Keep the output small: the last 40 of each topic.
    for topic in out["messages"]:
        out["messages"][topic] = out["messages"][topic][-40:]
    return out


def main():
    url, seconds = sys.argv[1], float(sys.argv[2])
    picture = sys.argv[3] if len(sys.argv) > 3 else None
    print(json.dumps(asyncio.run(listen(url, seconds, picture))))


if __name__ == "__main__":
    main()
