"""MCAP interop peer of services/outlet/tests/record_mcap.rs, on the Python
`mcap` and `mcap-ros2-support` packages (Foxglove's, not ours).

    mcap_interop.py read RECORDING.mcap EXPECTED_DIR
        Decodes every message of an `outlet record` file with mcap_ros2's CDR
        decoder (and json for the JSON channels) and checks them against what
        the simulated camera rendered: EXPECTED_DIR/expected.json (camera,
        frame_id, views) and per view VIEW.rgb (packed rgb8) and VIEW.xyz
        (float32 x, y, z); frame id f (the message's sequence) is view
        (f - 1) mod views, as `outlet serve sim-camera --views N` sends
        them. Prints a JSON summary; exits non-zero on the first mismatch,
        saying what differs.

    mcap_interop.py write BAG.mcap RENDER_DIR FRAMES_PER_SCENE
        Writes a ROS 2 bag with mcap_ros2.writer, as a camera driver under
        `ros2 bag record` would: per frame a sensor_msgs/msg/CameraInfo, an
        Image and a PointCloud2 (float32 x, y, z after a float32 intensity,
        20-byte points), 200 ms apart, of every scene `outlet render` wrote in
        RENDER_DIR (sorted by name); scene k's images are rgb8, bgr8 or mono8
        by k mod 3. Prints a JSON list of the scene stems in frame order.
"""

import json
import sys
from pathlib import Path

import cv2
import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer

FLOAT32 = 7


def fail(message):
    print(f"mcap_interop.py: {message}", file=sys.stderr)
    sys.exit(1)


def stamp_ns(header):
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def read(recording, expected_dir):
    expected_dir = Path(expected_dir)
    expected = json.loads((expected_dir / "expected.json").read_text())
    views = {}

    def view(frame_id):
        if frame_id < 1:
            fail(f"sequence {frame_id}: not a frame id of the simulated camera")
        name = f"view{(frame_id - 1) % expected['views']}"
        if name not in views:
            rgb = np.fromfile(expected_dir / f"{name}.rgb", dtype=np.uint8)
            xyz = np.fromfile(expected_dir / f"{name}.xyz", dtype="<f4").reshape(-1, 3)
            views[name] = (rgb, xyz)
        return views[name]

    factory = DecoderFactory()
    summary = {"images": 0, "camera_infos": 0, "clouds": 0, "json": {}, "schemas": {}, "checked_pixels": 0}
    with open(recording, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if schema is None:
                fail(f"channel {channel.topic} has no schema")
            summary["schemas"][channel.topic] = [schema.name, schema.encoding, channel.message_encoding]
            if channel.message_encoding == "json":
                if schema.encoding != "jsonschema":
                    fail(f"{channel.topic}: schema encoding {schema.encoding}")
                json.loads(schema.data)
                value = json.loads(message.data)
                summary["json"].setdefault(channel.topic, []).append(value)
                continue
            decoder = factory.decoder_for(channel.message_encoding, schema)
            if decoder is None:
                fail(f"{channel.topic}: no ROS 2 decoder for {schema.name} ({schema.encoding}, {channel.message_encoding})")
            msg = decoder(message.data)
            if stamp_ns(msg.header) != message.log_time or message.publish_time != message.log_time:
                fail(f"{channel.topic}: header stamp {stamp_ns(msg.header)} ns, log time {message.log_time}, "
                     f"publish time {message.publish_time}")
            if msg.header.frame_id != expected["frame_id"]:
                fail(f"{channel.topic}: frame_id {msg.header.frame_id!r}")
            if schema.name == "sensor_msgs/msg/Image":
                rgb, _ = view(message.sequence)
                got = (msg.width, msg.height, msg.encoding, msg.step, msg.is_bigendian)
                want = (expected["width"], expected["height"], "rgb8", 3 * expected["width"], 0)
                if got != want:
                    fail(f"image {message.sequence}: width, height, encoding, step, is_bigendian {got}, expected {want}")
                data = np.frombuffer(bytes(msg.data), dtype=np.uint8)
                if data.shape != rgb.shape:
                    fail(f"image {message.sequence}: {data.size} bytes, expected {rgb.size}")
                differ = np.flatnonzero(data != rgb)
                if differ.size:
                    k = int(differ[0])
                    fail(f"image {message.sequence}: {differ.size} bytes differ, first at {k}: {data[k]} != {rgb[k]}")
                summary["images"] += 1
                summary["checked_pixels"] += int(data.size // 3)
            elif schema.name == "sensor_msgs/msg/CameraInfo":
                view(message.sequence)
                if (msg.width, msg.height, msg.distortion_model) != (expected["width"], expected["height"], "plumb_bob"):
                    fail(f"camera info {message.sequence}: {msg.width}x{msg.height} {msg.distortion_model}")
                if not np.allclose(msg.k, expected["k"], rtol=0, atol=1e-12):
                    fail(f"camera info {message.sequence}: K {list(msg.k)}, expected {expected['k']}")
                if not np.allclose(msg.d, expected["d"], rtol=0, atol=1e-12):
                    fail(f"camera info {message.sequence}: D {list(msg.d)}, expected {expected['d']}")
                summary["camera_infos"] += 1
            elif schema.name == "sensor_msgs/msg/PointCloud2":
                _, xyz = view(message.sequence)
                fields = {f.name: (f.offset, f.datatype, f.count) for f in msg.fields}
                for axis in "xyz":
                    if fields.get(axis, (0, 0, 0))[1:] != (FLOAT32, 1):
                        fail(f"cloud {message.sequence}: field {axis} is {fields.get(axis)}")
                n = msg.width * msg.height
                if n != len(xyz) or msg.is_bigendian:
                    fail(f"cloud {message.sequence}: {n} points, expected {len(xyz)}")
                raw = np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(msg.height, msg.row_step)
                points = np.stack(
                    [
                        raw[:, : msg.width * msg.point_step]
                        .reshape(n, msg.point_step)[:, fields[a][0] : fields[a][0] + 4]
                        .copy()
                        .view("<f4")[:, 0]
                        for a in "xyz"
                    ],
                    axis=1,
                )
                same = (points == xyz) | (np.isnan(points) & np.isnan(xyz))
                if not same.all():
                    k = int(np.flatnonzero(~same.all(axis=1))[0])
                    fail(f"cloud {message.sequence}: point {k} is {points[k]}, expected {xyz[k]}")
                summary["clouds"] += 1
                summary["finite_points"] = int(np.isfinite(points).all(axis=1).sum())
            else:
                fail(f"{channel.topic}: unexpected schema {schema.name}")
    print(json.dumps(summary))


def ply_xyz(path):
    """The x, y, z of a binary little-endian PLY of float32 vertices (as `outlet render` writes)."""
    data = Path(path).read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode().splitlines()
    count = next(int(line.split()[2]) for line in header if line.startswith("element vertex"))
    properties = [line.split()[2] for line in header if line.startswith("property")]
    if "binary_little_endian" not in header[1] or properties != ["x", "y", "z"]:
        fail(f"{path}: not the PLY outlet render writes ({header[1]}, {properties})")
    return np.frombuffer(data[end:], dtype="<f4", count=3 * count).reshape(count, 3)


def write(bag, render_dir, frames_per_scene):
    render_dir = Path(render_dir)
    stems = sorted(p.name[: -len(".json")] for p in render_dir.glob("*.json"))
    if not stems:
        fail(f"{render_dir}: no scenes")
    writer_file = open(bag, "wb")
    writer = Writer(writer_file)
    # The definitions as rosbag2 stores them: the message, then each type it uses.
    header_defs = (
        "================================================================================\n"
        "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
    )
    image_schema = writer.register_msgdef(
        "sensor_msgs/msg/Image",
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\n"
        "uint32 step\nuint8[] data\n" + header_defs,
    )
    info_schema = writer.register_msgdef(
        "sensor_msgs/msg/CameraInfo",
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] d\n"
        "float64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\nuint32 binning_y\nRegionOfInterest roi\n"
        + header_defs
        + "================================================================================\n"
        "MSG: sensor_msgs/RegionOfInterest\nuint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\n"
        "bool do_rectify\n",
    )
    cloud_schema = writer.register_msgdef(
        "sensor_msgs/msg/PointCloud2",
        "std_msgs/Header header\nuint32 height\nuint32 width\nPointField[] fields\nbool is_bigendian\n"
        "uint32 point_step\nuint32 row_step\nuint8[] data\nbool is_dense\n"
        + header_defs
        + "================================================================================\n"
        "MSG: sensor_msgs/PointField\nuint8 INT8=1\nuint8 UINT8=2\nuint8 INT16=3\nuint8 UINT16=4\n"
        "uint8 INT32=5\nuint8 UINT32=6\nuint8 FLOAT32=7\nuint8 FLOAT64=8\nstring name\nuint32 offset\n"
        "uint8 datatype\nuint32 count\n",
    )
    t0 = 1_750_000_000_000_000_000
    order = []
    frame = 0
    for k, stem in enumerate(stems):
        truth = json.loads((render_dir / f"{stem}.json").read_text())
        bgr = cv2.imread(str(render_dir / truth["image"]), cv2.IMREAD_COLOR)
        if bgr is None:
            fail(f"{truth['image']}: not an image")
        encoding = ["rgb8", "bgr8", "mono8"][k % 3]
        pixels = {
            "rgb8": lambda: cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB),
            "bgr8": lambda: bgr,
            "mono8": lambda: cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY),
        }[encoding]()
        height, width = pixels.shape[:2]
        camera = truth["camera"]
        fx, _, cx, _, fy, cy = camera["camera_matrix"][:6]
        xyz = ply_xyz(render_dir / f"{stem}.ply")
        points = np.zeros((len(xyz), 5), dtype="<f4")
        points[:, 0] = 0.5  # intensity
        points[:, 1:4] = xyz
        for _ in range(frames_per_scene):
            t = t0 + frame * 200_000_000
            header = {"stamp": {"sec": t // 1_000_000_000, "nanosec": t % 1_000_000_000}, "frame_id": "cam"}
            writer.write_message(
                "/camera/points",
                cloud_schema,
                {
                    "header": header,
                    "height": 1,
                    "width": len(points),
                    "fields": [
                        {"name": "intensity", "offset": 0, "datatype": FLOAT32, "count": 1},
                        {"name": "x", "offset": 4, "datatype": FLOAT32, "count": 1},
                        {"name": "y", "offset": 8, "datatype": FLOAT32, "count": 1},
                        {"name": "z", "offset": 12, "datatype": FLOAT32, "count": 1},
                    ],
                    "is_bigendian": False,
                    "point_step": 20,
                    "row_step": 20 * len(points),
                    "data": points.tobytes(),
                    "is_dense": bool(np.isfinite(xyz).all()),
                },
                log_time=t,
                publish_time=t,
            )
            writer.write_message(
                "/camera/camera_info",
                info_schema,
                {
                    "header": header,
                    "height": height,
                    "width": width,
                    "distortion_model": camera["distortion_model"],
                    "d": camera["distortion_coefficients"],
                    "k": camera["camera_matrix"],
                    "r": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                    "p": [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
                    "binning_x": 0,
                    "binning_y": 0,
                    "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False},
                },
                log_time=t + 1_000_000,
                publish_time=t,
            )
            channels = 1 if encoding == "mono8" else 3
            writer.write_message(
                "/camera/image_raw",
                image_schema,
                {
                    "header": header,
                    "height": height,
                    "width": width,
                    "encoding": encoding,
                    "is_bigendian": 0,
                    "step": width * channels,
                    "data": np.ascontiguousarray(pixels).tobytes(),
                },
                log_time=t + 2_000_000,
                publish_time=t,
            )
            order.append(stem)
            frame += 1
    writer.finish()
    writer_file.close()
    print(json.dumps(order))


def main():
    if len(sys.argv) == 4 and sys.argv[1] == "read":
        read(sys.argv[2], sys.argv[3])
    elif len(sys.argv) == 5 and sys.argv[1] == "write":
        write(sys.argv[2], sys.argv[3], int(sys.argv[4]))
    else:
        fail(__doc__)


if __name__ == "__main__":
    main()
