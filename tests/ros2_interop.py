#!/usr/bin/env python3
"""Interoperability test of `outlet serve ros2-bridge` against Eclipse Cyclone DDS.

An independent DDS implementation (Cyclone DDS through its Python package
`cyclonedds`) plays a ROS 2 camera driver and a ROS 2 consumer of the results:

- for each scene rendered by `outlet render` (`STEM.png`/`.jpg`, `STEM.json`,
  `STEM.camera.yaml`, `STEM.ply`) it publishes `sensor_msgs/Image`,
  `sensor_msgs/CameraInfo` and `sensor_msgs/PointCloud2` with one fresh
  header.stamp, again at about 5 Hz with a new stamp until the bridge answers;
- it subscribes to `geometry_msgs/PoseArray` on /outlet/holes (reliable) and
  `geometry_msgs/PoseStamped` on /outlet/pose, and checks the answer: the stamp
  of the image it came from, the frame_id, one pose per hole of the ground truth,
  each within 1 mm of the truth (template order), the orientation the outlet's
  (within 1 degree of the truth), and a PoseStamped with the same stamp;
- it subscribes to `tf2_msgs/TFMessage` on /tf and checks the frame's
  transforms: parent the camera's frame_id, children `outlet` and
  `outlet/hole_<k>`, the capture stamp, the outlet's within 1 mm and 1 degree of
  the truth, each hole's within 1 mm;
- it subscribes to `vision_msgs/Detection3DArray` on /outlet/detections and
  checks one detection per hole: the truth's class (`power`/`ground`), a score
  in 0..1, the PoseArray's pose, a 6x6 covariance whose position block is
  symmetric positive definite with a standard deviation under 5 mm, and whose
  rotation block is the "unknown" diagonal of 1e6;
- with `--debug-image-topic` it subscribes to the bridge's debug image
  (`sensor_msgs/Image`, rgb8: hundreds of DDS fragments each) and checks that
  one comes for the scene's images: the frame's size and frame_id, something
  drawn around every hole of the truth, and most of the frame the pixels it
  sent. With `--dump FILE` it writes
  each answered frame's scores and 3x3 covariances (JSON, by stamp) for the
  Rust test to compare with what the bridge read from shared memory.

The scenes exercise the message layouts: images go out as rgb8, mono8 and bgr8
(the bgr8 one with padded rows, step > width x 3); clouds have point_step 16
with a float32 `intensity` field beside x, y, z, placed after them in one scene
and before them in the next, so a reader that ignores offsets or point_step
gets a wrong wall plane.

LOOPBACK ONLY. The test machines may send traffic to loopback addresses only.
This script refuses to run unless CYCLONEDDS_URI names a Cyclone DDS
configuration whose only network interface is `lo` (or 127.0.0.1), such as
tests/dds/cyclonedds-loopback.xml (lo, no multicast, unicast discovery to
127.0.0.1):

    CYCLONEDDS_URI=file://$PWD/tests/dds/cyclonedds-loopback.xml \\
        python3 tests/ros2_interop.py --domain 42 SCENES_DIR

Exit status 0 only when every scene passed; 1 with a message saying what was
expected and what came otherwise; 2 for bad arguments or environment.

`--selftest` runs the same checks against a stand-in for the bridge written
here (`--play-bridge`, a second process on the same loopback set-up), which
checks what this script publishes and answers from the ground truth: it tests
the message definitions, QoS and discovery without the Rust bridge.
"""

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import time
import urllib.parse
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl import types as t
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

# ---------------------------------------------------------------------------
# ROS 2 messages (Humble layouts), with their DDS type names.


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: t.int32
    nanosec: t.uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class Image(IdlStruct, typename="sensor_msgs::msg::dds_::Image_"):
    header: Header
    height: t.uint32
    width: t.uint32
    encoding: str
    is_bigendian: t.uint8
    step: t.uint32
    data: t.sequence[t.uint8]  # written from bytes, read back as a list


@dataclass
class RegionOfInterest(IdlStruct, typename="sensor_msgs::msg::dds_::RegionOfInterest_"):
    x_offset: t.uint32
    y_offset: t.uint32
    height: t.uint32
    width: t.uint32
    do_rectify: bool


@dataclass
class CameraInfo(IdlStruct, typename="sensor_msgs::msg::dds_::CameraInfo_"):
    header: Header
    height: t.uint32
    width: t.uint32
    distortion_model: str
    d: t.sequence[t.float64]
    k: t.array[t.float64, 9]
    r: t.array[t.float64, 9]
    p: t.array[t.float64, 12]
    binning_x: t.uint32
    binning_y: t.uint32
    roi: RegionOfInterest


@dataclass
class PointField(IdlStruct, typename="sensor_msgs::msg::dds_::PointField_"):
    name: str
    offset: t.uint32
    datatype: t.uint8
    count: t.uint32


POINTFIELD_FLOAT32 = 7


@dataclass
class PointCloud2(IdlStruct, typename="sensor_msgs::msg::dds_::PointCloud2_"):
    header: Header
    height: t.uint32
    width: t.uint32
    fields: t.sequence[PointField]
    is_bigendian: bool
    point_step: t.uint32
    row_step: t.uint32
    data: t.sequence[t.uint8]
    is_dense: bool


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: t.float64
    y: t.float64
    z: t.float64


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: t.float64
    y: t.float64
    z: t.float64
    w: t.float64


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point
    orientation: Quaternion


@dataclass
class PoseArray(IdlStruct, typename="geometry_msgs::msg::dds_::PoseArray_"):
    header: Header
    poses: t.sequence[Pose]


@dataclass
class PoseStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseStamped_"):
    header: Header
    pose: Pose


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: t.float64
    y: t.float64
    z: t.float64


@dataclass
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3
    rotation: Quaternion


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header
    child_frame_id: str
    transform: Transform


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: t.sequence[TransformStamped]


@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose
    covariance: t.array[t.float64, 36]  # row-major 6x6: x, y, z, rotation about X, Y, Z


# vision_msgs 4 (Humble and newer).
@dataclass
class ObjectHypothesis(IdlStruct, typename="vision_msgs::msg::dds_::ObjectHypothesis_"):
    class_id: str
    score: t.float64


@dataclass
class ObjectHypothesisWithPose(IdlStruct, typename="vision_msgs::msg::dds_::ObjectHypothesisWithPose_"):
    hypothesis: ObjectHypothesis
    pose: PoseWithCovariance


@dataclass
class BoundingBox3D(IdlStruct, typename="vision_msgs::msg::dds_::BoundingBox3D_"):
    center: Pose
    size: Vector3


@dataclass
class Detection3D(IdlStruct, typename="vision_msgs::msg::dds_::Detection3D_"):
    header: Header
    results: t.sequence[ObjectHypothesisWithPose]
    bbox: BoundingBox3D
    id: str


@dataclass
class Detection3DArray(IdlStruct, typename="vision_msgs::msg::dds_::Detection3DArray_"):
    header: Header
    detections: t.sequence[Detection3D]


@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str
    value: str


@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: t.uint8  # ROS `byte`
    name: str
    message: str
    hardware_id: str
    values: t.sequence[KeyValue]


@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    header: Header
    status: t.sequence[DiagnosticStatus]


# ---------------------------------------------------------------------------
# QoS: plain CDR (XCDR1) as ROS 2 uses, on every endpoint.

CDR = Policy.DataRepresentation(use_cdrv0_representation=True)
# What camera drivers publish images with ("sensor data"); the bridge reads them best-effort.
SENSOR_QOS = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(5), Policy.Durability.Volatile, CDR)
# Reliable writers match reliable and best-effort readers alike.
RELIABLE_OUT_QOS = Qos(
    Policy.Reliability.Reliable(max_blocking_time=duration(seconds=1)),
    Policy.History.KeepLast(5),
    Policy.Durability.Volatile,
    CDR,
)
RESULT_QOS = Qos(
    Policy.Reliability.Reliable(max_blocking_time=duration(seconds=1)),
    Policy.History.KeepLast(100),
    Policy.Durability.Volatile,
    CDR,
)
# What tf2_ros' TransformListener reads /tf with: reliable, volatile, keep last 100.
TF_QOS = RESULT_QOS

HOLE_TOLERANCE_M = 1e-3
# The bridge's variance of a rotation it does not estimate (services/ros2-bridge/README.md).
UNKNOWN_ROTATION_VARIANCE = 1e6
# A hole's position standard deviation must be below this (m): a sane covariance, not a layout accident.
MAX_HOLE_SIGMA_M = 5e-3
ORIGIN_TOLERANCE_M = 1e-3
ROTATION_TOLERANCE_DEG = 1.0
PUBLISH_PERIOD_S = 0.2


def dds_topic(ros_name: str) -> str:
    """ROS 2 topic `/x/y` is DDS topic `rt/x/y`."""
    return ros_name if ros_name.startswith("rt/") else "rt/" + ros_name.lstrip("/")


class Refused(Exception):
    """The environment or the arguments do not allow a run (exit status 2)."""


# ---------------------------------------------------------------------------
# Loopback confinement.


def loopback_config() -> str:
    """The Cyclone DDS configuration in CYCLONEDDS_URI, checked to name `lo` only."""
    uri = os.environ.get("CYCLONEDDS_URI", "").strip()
    if not uri:
        raise Refused(
            "CYCLONEDDS_URI is not set: this test may only send traffic to loopback addresses; set "
            "CYCLONEDDS_URI=file://<repo>/tests/dds/cyclonedds-loopback.xml"
        )
    # Cyclone accepts a file:// URI, a path, or the XML itself (several, comma separated: refused here).
    if uri.lstrip().startswith("<"):
        text, where = uri, "CYCLONEDDS_URI"
    else:
        path = urllib.parse.unquote(urllib.parse.urlparse(uri).path) if uri.startswith("file://") else uri
        try:
            text, where = Path(path).read_text(), path
        except OSError as e:
            raise Refused(f"CYCLONEDDS_URI={uri}: cannot read the configuration: {e}") from e
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise Refused(f"{where}: not an XML configuration: {e}") from e
    local = lambda el: el.tag.rsplit("}", 1)[-1]  # noqa: E731 (tags may carry a namespace)
    interfaces = [el for el in root.iter() if local(el) == "NetworkInterface"]
    named = [el.get("name") or el.get("address") for el in interfaces]
    # Older Cyclone versions: <NetworkInterfaceAddress>lo</NetworkInterfaceAddress>.
    named += [(el.text or "").strip() for el in root.iter() if local(el) == "NetworkInterfaceAddress"]
    if not named or any(n not in ("lo", "127.0.0.1") for n in named):
        raise Refused(
            f"{where}: the Cyclone DDS configuration must confine DDS to the loopback interface "
            f"(<Interfaces><NetworkInterface name=\"lo\"/></Interfaces>), it names {named or 'no interface'}"
        )
    return where


# ---------------------------------------------------------------------------
# Scenes rendered by `outlet render`.


def parse_camera_yaml(text: str) -> dict:
    """A ROS camera_info YAML (the camera_calibration layout `outlet render` writes)."""
    try:
        import yaml  # type: ignore

        return yaml.safe_load(text)
    except ImportError:
        pass

    def value(v: str):
        v = v.strip()
        if v.startswith("[") and v.endswith("]"):
            return [value(x) for x in v[1:-1].split(",") if x.strip()]
        for cast in (int, float):
            try:
                return cast(v)
            except ValueError:
                pass
        return v.strip("'\"")

    root: dict = {}
    stack = [(-1, root)]
    for raw in text.splitlines():
        line = raw.rstrip()
        if not line.strip() or line.lstrip().startswith(("#", "%", "---")):
            continue
        indent = len(line) - len(line.lstrip())
        key, _, rest = line.strip().partition(":")
        while indent <= stack[-1][0]:
            stack.pop()
        if rest.strip():
            stack[-1][1][key] = value(rest)
        else:
            child: dict = {}
            stack[-1][1][key] = child
            stack.append((indent, child))
    return root


def read_ply(path: Path) -> np.ndarray:
    """The x, y, z of a PLY file's vertices (N x 3 float32); binary or ASCII, scalar properties."""
    raw = path.read_bytes()
    end = raw.find(b"end_header\n")
    if not raw.startswith(b"ply") or end < 0:
        raise ValueError(f"{path}: not a PLY file")
    header = raw[:end].decode("ascii").splitlines()
    body = raw[end + len(b"end_header\n") :]
    fmt, elements = None, []
    types = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2"}
    types |= {"ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4"}
    types |= {"float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}
    for line in header[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "element":
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property":
            if words[1] == "list":
                raise ValueError(f"{path}: list properties are not read here")
            elements[-1][2].append((words[2], types[words[1]]))
    if not elements or elements[0][0] != "vertex":
        raise ValueError(f"{path}: the first element is not `vertex`")
    _, count, props = elements[0]
    if fmt == "ascii":
        rows = np.array(body.decode("ascii").split()[: count * len(props)], dtype=np.float64)
        table = rows.reshape(count, len(props))
        columns = {name: table[:, k] for k, (name, _) in enumerate(props)}
    elif fmt in ("binary_little_endian", "binary_big_endian"):
        order = "<" if fmt == "binary_little_endian" else ">"
        dtype = np.dtype([(name, order + ty) for name, ty in props])
        table = np.frombuffer(body, dtype=dtype, count=count)
        columns = {name: table[name] for name, _ in props}
    else:
        raise ValueError(f"{path}: unknown PLY format {fmt}")
    return np.stack([columns["x"], columns["y"], columns["z"]], axis=1).astype(np.float32)


@dataclass
class Scene:
    stem: str
    bgr: np.ndarray
    camera: dict
    cloud: np.ndarray
    truth: dict
    encoding: str = "rgb8"
    padded_step: int = 0  # extra bytes at the end of each image row
    intensity_first: bool = False  # the cloud's padding field before x, y, z

    @property
    def holes_m(self) -> list[list[float]]:
        return [h["position_m"] for h in self.truth["holes"]]


ENCODINGS = ["rgb8", "mono8", "bgr8"]


def load_scenes(folder: Path) -> list[Scene]:
    scenes = []
    for truth_path in sorted(folder.glob("*.json")):
        stem = truth_path.name[: -len(".json")]
        camera_path, ply_path = folder / f"{stem}.camera.yaml", folder / f"{stem}.ply"
        if not camera_path.exists() or not ply_path.exists():
            continue  # not a rendered scene (a manifest, a report)
        truth = json.loads(truth_path.read_text())
        image_path = folder / truth.get("image", f"{stem}.png")
        bgr = cv2.imread(str(image_path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise Refused(f"{image_path}: cannot decode the image")
        if not truth.get("holes") or any(h.get("position_m") is None for h in truth["holes"]):
            raise Refused(f"{truth_path}: no outlet with hole positions in this scene; the bridge answers nothing")
        k = len(scenes)
        scene = Scene(stem, bgr, parse_camera_yaml(camera_path.read_text()), read_ply(ply_path), truth)
        scene.encoding = ENCODINGS[k % 3]
        scene.padded_step = 32 if scene.encoding == "bgr8" else 0
        scene.intensity_first = k % 2 == 1
        h, w = bgr.shape[:2]
        if (scene.camera["image_width"], scene.camera["image_height"]) != (w, h):
            raise Refused(f"{camera_path}: {scene.camera['image_width']}x{scene.camera['image_height']}, image {w}x{h}")
        scenes.append(scene)
    if not scenes:
        raise Refused(f"{folder}: no rendered scenes (STEM.json + STEM.camera.yaml + STEM.ply + image)")
    return scenes


# ---------------------------------------------------------------------------
# Messages out of a scene, and back.


def image_pixels(scene: Scene) -> np.ndarray:
    """The pixels in the scene's encoding (H x W x C)."""
    if scene.encoding == "mono8":
        return cv2.cvtColor(scene.bgr, cv2.COLOR_BGR2GRAY)[:, :, None]
    if scene.encoding == "rgb8":
        return cv2.cvtColor(scene.bgr, cv2.COLOR_BGR2RGB)
    return scene.bgr


def image_msg(scene: Scene, header: Header) -> Image:
    pixels = image_pixels(scene)
    h, w, c = pixels.shape
    step = w * c + scene.padded_step
    rows = np.zeros((h, step), dtype=np.uint8)
    rows[:, : w * c] = pixels.reshape(h, w * c)
    rows[:, w * c :] = 0xA5  # padding that is not a pixel
    return Image(header, h, w, scene.encoding, 0, step, rows.tobytes())


def camera_info_msg(scene: Scene, header: Header) -> CameraInfo:
    c = scene.camera
    k = [float(v) for v in c["camera_matrix"]["data"]]
    r = [float(v) for v in c.get("rectification_matrix", {}).get("data", [1, 0, 0, 0, 1, 0, 0, 0, 1])]
    default_p = k[0:3] + [0.0] + k[3:6] + [0.0] + k[6:9] + [0.0]
    p = [float(v) for v in c.get("projection_matrix", {}).get("data", default_p)]
    d = [float(v) for v in c.get("distortion_coefficients", {}).get("data", [])]
    model = c.get("distortion_model", "plumb_bob")
    roi = RegionOfInterest(0, 0, 0, 0, False)
    return CameraInfo(header, int(c["image_height"]), int(c["image_width"]), model, d, k, r, p, 0, 0, roi)


def cloud_msg(scene: Scene, header: Header) -> PointCloud2:
    """x, y, z float32 and a float32 `intensity` in 16-byte points (before or after x, y, z)."""
    n = len(scene.cloud)
    if scene.intensity_first:
        names, offsets = ["intensity", "x", "y", "z"], [0, 4, 8, 12]
    else:
        names, offsets = ["x", "y", "z", "intensity"], [0, 4, 8, 12]
    dtype = np.dtype({"names": names, "formats": ["<f4"] * 4, "offsets": offsets, "itemsize": 16})
    points = np.zeros(n, dtype=dtype)
    for j, axis in enumerate("xyz"):
        points[axis] = scene.cloud[:, j]
    points["intensity"] = 1e6  # far from any coordinate: read as one, it breaks the plane
    fields = [PointField(name, off, POINTFIELD_FLOAT32, 1) for name, off in zip(names, offsets)]
    dense = bool(np.isfinite(scene.cloud).all())
    return PointCloud2(header, 1, n, fields, False, 16, 16 * n, points.tobytes(), dense)


def decode_cloud(msg: PointCloud2) -> np.ndarray:
    """x, y, z of a PointCloud2 as any reader must: by field offsets and point_step."""
    by_name = {f.name: f for f in msg.fields}
    if msg.is_bigendian or any(by_name.get(a) is None or by_name[a].datatype != POINTFIELD_FLOAT32 for a in "xyz"):
        raise ValueError("no little-endian float32 x, y, z fields")
    n = msg.width * msg.height
    data = bytes(msg.data)
    dtype = np.dtype(
        {"names": list("xyz"), "formats": ["<f4"] * 3, "offsets": [by_name[a].offset for a in "xyz"],
         "itemsize": msg.point_step}
    )
    rows = [np.frombuffer(data, dtype=dtype, count=msg.width, offset=r * msg.row_step) for r in range(msg.height)]
    points = np.concatenate(rows) if rows else np.zeros(0, dtype=dtype)
    return np.stack([points[a] for a in "xyz"], axis=1)[:n]


def decode_image(msg: Image) -> np.ndarray:
    """The pixels of an Image as BGR (mono8 replicated), honouring step."""
    channels = {"mono8": 1, "rgb8": 3, "bgr8": 3}.get(msg.encoding)
    data = bytes(msg.data)
    if channels is None or len(data) < msg.height * msg.step or msg.step < msg.width * channels:
        raise ValueError(f"unusable image: {msg.encoding}, step {msg.step}, {len(data)} bytes")
    rows = np.frombuffer(data, dtype=np.uint8, count=msg.height * msg.step).reshape(msg.height, msg.step)
    pixels = rows[:, : msg.width * channels].reshape(msg.height, msg.width, channels)
    if msg.encoding == "mono8":
        return cv2.cvtColor(pixels, cv2.COLOR_GRAY2BGR)
    return cv2.cvtColor(pixels, cv2.COLOR_RGB2BGR) if msg.encoding == "rgb8" else pixels.copy()


def quaternion_matrix(q: Quaternion) -> np.ndarray:
    x, y, z, w = q.x, q.y, q.z, q.w
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not n > 0:
        return np.full((3, 3), np.nan)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_quaternion(r: np.ndarray) -> Quaternion:
    w = math.sqrt(max(0.0, 1 + r[0, 0] + r[1, 1] + r[2, 2])) / 2
    x = math.copysign(math.sqrt(max(0.0, 1 + r[0, 0] - r[1, 1] - r[2, 2])) / 2, r[2, 1] - r[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1 - r[0, 0] + r[1, 1] - r[2, 2])) / 2, r[0, 2] - r[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1 - r[0, 0] - r[1, 1] + r[2, 2])) / 2, r[1, 0] - r[0, 1])
    return Quaternion(x, y, z, w)


def rotation_error_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = (np.trace(a.T @ b) - 1) / 2
    return math.degrees(math.acos(max(-1.0, min(1.0, c)))) if np.isfinite(c) else math.inf


def stamp_of(ns: int) -> Time:
    return Time(ns // 1_000_000_000, ns % 1_000_000_000)


def stamp_key(s: Time) -> tuple[int, int]:
    return (s.sec, s.nanosec)


def show_stamp(k: tuple[int, int]) -> str:
    return f"{k[0]}.{k[1]:09d}"


# ---------------------------------------------------------------------------
# The test.


@dataclass
class Endpoints:
    participant: DomainParticipant
    image: DataWriter
    camera_info: DataWriter
    points: DataWriter
    holes: DataReader
    pose: DataReader
    diagnostics: DataReader
    tf: DataReader
    detections: DataReader
    debug_image: DataReader | None


def open_endpoints(args) -> Endpoints:
    dp = DomainParticipant(args.domain)
    topic = lambda name, ty: Topic(dp, dds_topic(name), ty)  # noqa: E731
    return Endpoints(
        dp,
        DataWriter(dp, topic(args.image_topic, Image), qos=SENSOR_QOS),
        DataWriter(dp, topic(args.camera_info_topic, CameraInfo), qos=RELIABLE_OUT_QOS),
        DataWriter(dp, topic(args.points_topic, PointCloud2), qos=RELIABLE_OUT_QOS),
        DataReader(dp, topic(args.holes_topic, PoseArray), qos=RESULT_QOS),
        DataReader(dp, topic(args.pose_topic, PoseStamped), qos=RESULT_QOS),
        DataReader(dp, topic(args.diagnostics_topic, DiagnosticArray), qos=RESULT_QOS),
        DataReader(dp, topic(args.tf_topic, TFMessage), qos=TF_QOS),
        DataReader(dp, topic(args.detections_topic, Detection3DArray), qos=RESULT_QOS),
        DataReader(dp, topic(args.debug_image_topic, Image), qos=RESULT_QOS) if args.debug_image_topic else None,
    )


def wait_for_discovery(ep: Endpoints, args, deadline: float) -> list[str]:
    """Waits until the bridge's endpoints match ours; what is unmatched at the deadline."""
    named = [
        ("reader of", args.image_topic, ep.image),
        ("reader of", args.camera_info_topic, ep.camera_info),
        ("reader of", args.points_topic, ep.points),
        ("writer of", args.holes_topic, ep.holes),
        ("writer of", args.pose_topic, ep.pose),
        ("writer of", args.tf_topic, ep.tf),
        ("writer of", args.detections_topic, ep.detections),
    ]

    def missing():
        out = []
        for what, name, e in named:
            if isinstance(e, DataWriter):
                matched = e.get_publication_matched_status().current_count
                incompatible = e.get_offered_incompatible_qos_status()
            else:
                matched = e.get_subscription_matched_status().current_count
                incompatible = e.get_requested_incompatible_qos_status()
            if matched == 0:
                note = ""
                if incompatible.total_count:
                    note = f" (an endpoint with incompatible QoS was seen, policy id {incompatible.last_policy_id})"
                out.append(f"no {what} {dds_topic(name)}{note}")
        return out

    while time.monotonic() < deadline:
        if not missing():
            return []
        time.sleep(0.05)
    return missing()


@dataclass
class Outcome:
    scene: Scene
    ok: bool = False
    problems: list[str] = field(default_factory=list)
    published: int = 0
    latency_ms: float = math.nan
    hole_error_mm: float = math.nan
    rotation_error_deg: float = math.nan
    tf_error_mm: float = math.nan  # worst of the outlet's and the holes' tf translations against the truth
    tf_rotation_error_deg: float = math.nan
    max_sigma_mm: float = math.nan  # the largest hole position standard deviation the detections gave
    debug_image_changed: float = math.nan  # share of the debug image's pixels drawn over
    dumped: dict | None = None  # what the detections carried, for --dump


class Inbox:
    """Everything the bridge sent, by stamp (first of each stamp kept)."""

    def __init__(self, ep: Endpoints):
        self.ep = ep
        self.holes: dict[tuple[int, int], tuple[PoseArray, float]] = {}
        self.pose: dict[tuple[int, int], tuple[PoseStamped, float]] = {}
        self.diagnostics: dict[str, DiagnosticStatus] = {}
        self.tf: dict[tuple[int, int], TFMessage] = {}  # by the first transform's stamp
        self.detections: dict[tuple[int, int], Detection3DArray] = {}
        self.debug_images: dict[tuple[int, int], Image] = {}

    def drain(self):
        now = time.monotonic()
        for m in self.ep.holes.take(N=256):
            if isinstance(m, PoseArray):
                self.holes.setdefault(stamp_key(m.header.stamp), (m, now))
        for m in self.ep.pose.take(N=256):
            if isinstance(m, PoseStamped):
                self.pose.setdefault(stamp_key(m.header.stamp), (m, now))
        for m in self.ep.diagnostics.take(N=256):
            if isinstance(m, DiagnosticArray):
                for s in m.status:
                    self.diagnostics[s.name] = s
        for m in self.ep.tf.take(N=256):
            if isinstance(m, TFMessage) and m.transforms:
                self.tf.setdefault(stamp_key(m.transforms[0].header.stamp), m)
        for m in self.ep.detections.take(N=256):
            if isinstance(m, Detection3DArray):
                self.detections.setdefault(stamp_key(m.header.stamp), m)
        if self.ep.debug_image is not None:
            for m in self.ep.debug_image.take(N=16):
                if isinstance(m, Image):
                    self.debug_images.setdefault(stamp_key(m.header.stamp), m)


def check_answer(outcome: Outcome, holes: PoseArray, pose: PoseStamped | None, key, frame_id: str):
    scene, problems = outcome.scene, outcome.problems
    truth_r = np.array(scene.truth["pose"]["rotation"], dtype=float)
    expected_q = matrix_quaternion(truth_r)
    show_q = lambda q: f"(x, y, z, w) = ({q.x:.4f}, {q.y:.4f}, {q.z:.4f}, {q.w:.4f})"  # noqa: E731

    got = stamp_key(holes.header.stamp)
    if got != key:
        problems.append(f"PoseArray header.stamp {show_stamp(got)}, expected {show_stamp(key)}")
    if holes.header.frame_id != frame_id:
        problems.append(f"PoseArray header.frame_id {holes.header.frame_id!r}, expected {frame_id!r}")
    truth = scene.holes_m
    if len(holes.poses) != len(truth):
        problems.append(f"PoseArray has {len(holes.poses)} poses, the truth {len(truth)} holes")
    errors = []
    for k, (p, t_m) in enumerate(zip(holes.poses, truth)):
        got_m = (p.position.x, p.position.y, p.position.z)
        e = math.dist(got_m, t_m)
        errors.append(e)
        if not e <= HOLE_TOLERANCE_M:
            problems.append(
                f"hole {k}: at ({got_m[0]:.5f}, {got_m[1]:.5f}, {got_m[2]:.5f}) m, truth "
                f"({t_m[0]:.5f}, {t_m[1]:.5f}, {t_m[2]:.5f}) m: {e * 1e3:.3f} mm off (tolerance 1 mm)"
            )
    outcome.hole_error_mm = max(errors) * 1e3 if errors else math.nan
    # Every hole's orientation is the outlet's.
    for k, p in enumerate(holes.poses):
        e = rotation_error_deg(quaternion_matrix(p.orientation), truth_r)
        if not e <= ROTATION_TOLERANCE_DEG:
            problems.append(
                f"PoseArray pose {k}: orientation {show_q(p.orientation)} is {e:.2f} deg from the outlet's, "
                f"expected {show_q(expected_q)} within {ROTATION_TOLERANCE_DEG} deg (the first such pose only)"
            )
            break

    if pose is None:
        problems.append(f"no PoseStamped on the pose topic with header.stamp {show_stamp(key)}")
        return
    if pose.header.frame_id != frame_id:
        problems.append(f"PoseStamped header.frame_id {pose.header.frame_id!r}, expected {frame_id!r}")
    outcome.rotation_error_deg = rotation_error_deg(quaternion_matrix(pose.pose.orientation), truth_r)
    if not outcome.rotation_error_deg <= ROTATION_TOLERANCE_DEG:
        problems.append(
            f"PoseStamped orientation {show_q(pose.pose.orientation)} is {outcome.rotation_error_deg:.2f} deg "
            f"from the truth's rotation, expected {show_q(expected_q)} within {ROTATION_TOLERANCE_DEG} deg"
        )
    origin = (pose.pose.position.x, pose.pose.position.y, pose.pose.position.z)
    t_m = scene.truth["pose"]["translation_m"]
    e = math.dist(origin, t_m)
    if not e <= ORIGIN_TOLERANCE_M:
        problems.append(
            f"PoseStamped position ({origin[0]:.5f}, {origin[1]:.5f}, {origin[2]:.5f}) m is {e * 1e3:.3f} mm "
            f"from the outlet's origin ({t_m[0]:.5f}, {t_m[1]:.5f}, {t_m[2]:.5f}) m (tolerance 1 mm)"
        )


def check_tf(outcome: Outcome, tf: TFMessage | None, key, args):
    """The frame's transforms: parent the camera frame, the outlet's and each hole's against the truth."""
    scene, problems = outcome.scene, outcome.problems
    if tf is None:
        problems.append(f"no TFMessage on {dds_topic(args.tf_topic)} with header.stamp {show_stamp(key)}")
        return
    children = [ts.child_frame_id for ts in tf.transforms]
    expected = [args.outlet_frame] + [f"{args.outlet_frame}/hole_{k}" for k in range(len(scene.holes_m))]
    if children != expected:
        problems.append(f"tf child frames {children}, expected {expected}")
    for ts in tf.transforms:
        if ts.header.frame_id != args.frame_id or stamp_key(ts.header.stamp) != key:
            problems.append(
                f"tf {ts.child_frame_id!r}: parent {ts.header.frame_id!r} at {show_stamp(stamp_key(ts.header.stamp))}, "
                f"expected {args.frame_id!r} at {show_stamp(key)}"
            )
    truth_r = np.array(scene.truth["pose"]["rotation"], dtype=float)
    truths = {args.outlet_frame: scene.truth["pose"]["translation_m"]}
    truths |= {f"{args.outlet_frame}/hole_{k}": t_m for k, t_m in enumerate(scene.holes_m)}
    errors, angles = [], []
    for ts in tf.transforms:
        t_m = truths.get(ts.child_frame_id)
        if t_m is None:
            continue
        v = ts.transform.translation
        e = math.dist((v.x, v.y, v.z), t_m)
        a = rotation_error_deg(quaternion_matrix(ts.transform.rotation), truth_r)
        errors.append(e)
        angles.append(a)
        if not (e <= HOLE_TOLERANCE_M and a <= ROTATION_TOLERANCE_DEG):
            problems.append(
                f"tf {ts.child_frame_id!r}: ({v.x:.5f}, {v.y:.5f}, {v.z:.5f}) m is {e * 1e3:.3f} mm and {a:.2f} deg "
                f"from the truth ({t_m[0]:.5f}, {t_m[1]:.5f}, {t_m[2]:.5f}) m (tolerances 1 mm, 1 deg)"
            )
    outcome.tf_error_mm = max(errors) * 1e3 if errors else math.nan
    outcome.tf_rotation_error_deg = max(angles) if angles else math.nan


def check_detections(outcome: Outcome, det: Detection3DArray | None, holes: PoseArray, key, args):
    """One detection per hole: the truth's class, a score, the PoseArray's pose and a sane covariance."""
    scene, problems = outcome.scene, outcome.problems
    topic = dds_topic(args.detections_topic)
    if det is None:
        problems.append(f"no Detection3DArray on {topic} with header.stamp {show_stamp(key)}")
        return
    if det.header.frame_id != args.frame_id:
        problems.append(f"Detection3DArray header.frame_id {det.header.frame_id!r}, expected {args.frame_id!r}")
    kinds = [h["kind"] for h in scene.truth["holes"]]
    if len(det.detections) != len(kinds):
        problems.append(f"Detection3DArray has {len(det.detections)} detections, the truth {len(kinds)} holes")
    dumped = {"scores": [], "covariances_m2": [], "classes": []}
    sigmas = []
    for k, (d, kind) in enumerate(zip(det.detections, kinds)):
        where = f"detection {k}"
        if stamp_key(d.header.stamp) != key or d.header.frame_id != args.frame_id or d.id != f"hole_{k}":
            problems.append(
                f"{where}: header {d.header.frame_id!r} at {show_stamp(stamp_key(d.header.stamp))}, id {d.id!r}; "
                f"expected {args.frame_id!r} at {show_stamp(key)}, id 'hole_{k}'"
            )
        if len(d.results) != 1:
            problems.append(f"{where}: {len(d.results)} hypotheses, expected 1")
            continue
        h = d.results[0]
        if h.hypothesis.class_id != kind:
            problems.append(f"{where}: class_id {h.hypothesis.class_id!r}, the truth's hole is {kind!r}")
        if not 0.0 <= h.hypothesis.score <= 1.0:
            problems.append(f"{where}: score {h.hypothesis.score} is not in 0..1")
        if k < len(holes.poses) and h.pose.pose != holes.poses[k]:
            problems.append(f"{where}: pose {h.pose.pose} is not the PoseArray's {holes.poses[k]}")
        if d.bbox.center != h.pose.pose:
            problems.append(f"{where}: bbox.center {d.bbox.center} is not the hypothesis' pose")
        c = np.array(h.pose.covariance, dtype=float).reshape(6, 6)
        position = c[:3, :3]
        expected_rest = np.zeros((6, 6))
        expected_rest[3:, 3:] = np.eye(3) * UNKNOWN_ROTATION_VARIANCE
        rest = c.copy()
        rest[:3, :3] = 0.0
        if not np.array_equal(rest, expected_rest):
            problems.append(
                f"{where}: covariance outside the position block is {rest.tolist()}, expected "
                f"{UNKNOWN_ROTATION_VARIANCE:g} on the rotations' diagonal and 0 elsewhere"
            )
        eig = np.linalg.eigvalsh(position) if np.all(np.isfinite(position)) else np.array([math.nan])
        if not (np.array_equal(position, position.T) and eig.min() > 0):
            problems.append(
                f"{where}: position covariance {position.tolist()} is not symmetric positive definite "
                f"(eigenvalues {eig.tolist()})"
            )
        elif not math.sqrt(eig.max()) < MAX_HOLE_SIGMA_M:
            problems.append(
                f"{where}: position standard deviation {math.sqrt(eig.max()) * 1e3:.3f} mm "
                f"({MAX_HOLE_SIGMA_M * 1e3:g} mm at most)"
            )
        else:
            sigmas.append(math.sqrt(eig.max()))
        dumped["scores"].append(h.hypothesis.score)
        dumped["covariances_m2"].append(position.reshape(9).tolist())
        dumped["classes"].append(h.hypothesis.class_id)
    outcome.max_sigma_mm = max(sigmas) * 1e3 if sigmas else math.nan
    outcome.dumped = {"stamp": list(key), "scene": scene.stem, **dumped}


def check_debug_image(outcome: Outcome, image: Image | None, mine: dict, args):
    """The debug image of one of this scene's frames: the frame itself with the
    holes drawn on it."""
    scene, problems = outcome.scene, outcome.problems
    topic = dds_topic(args.debug_image_topic)
    if image is None:
        problems.append(f"no Image on {topic} with the stamp of any of the {len(mine)} images of this scene")
        return
    h, w = scene.bgr.shape[:2]
    if (image.width, image.height, image.encoding) != (w, h, "rgb8") or image.header.frame_id != args.frame_id:
        problems.append(
            f"debug image {image.width}x{image.height} {image.encoding!r} in {image.header.frame_id!r}, "
            f"expected {w}x{h} 'rgb8' in {args.frame_id!r}"
        )
        return
    got = decode_image(image).astype(int)
    sent = image_pixels(scene)
    if scene.encoding == "mono8":
        sent = cv2.cvtColor(sent, cv2.COLOR_GRAY2BGR)
    elif scene.encoding == "rgb8":
        sent = cv2.cvtColor(sent, cv2.COLOR_RGB2BGR)
    changed = np.abs(got - sent.astype(int)).max(axis=2) > 0
    if changed.mean() > 0.25:
        problems.append(f"debug image: {changed.mean():.0%} of the pixels differ from the frame sent")
    for k, hole in enumerate(scene.truth["holes"]):
        u, v = (round(c) for c in hole["pixel"])
        box = changed[max(v - 12, 0) : v + 13, max(u - 12, 0) : u + 13]
        if box.sum() < 5:
            problems.append(f"debug image: nothing drawn within 12 px of hole {k} at ({u}, {v})")
    outcome.debug_image_changed = float(changed.mean())


def run_scene(ep: Endpoints, inbox: Inbox, scene: Scene, args, published_all: dict) -> Outcome:
    outcome = Outcome(scene)
    deadline = time.monotonic() + args.timeout
    mine: dict[tuple[int, int], float] = {}  # stamp -> when published
    next_publish = 0.0
    answer = None
    last_ns = 0
    while time.monotonic() < deadline:
        now = time.monotonic()
        if now >= next_publish:
            ns = max(time.time_ns(), last_ns + 1)
            last_ns = ns
            header = Header(stamp_of(ns), args.frame_id)
            # The cloud first: its wall plane is ready when the detection of the image is.
            ep.points.write(cloud_msg(scene, header))
            ep.camera_info.write(camera_info_msg(scene, header))
            ep.image.write(image_msg(scene, header))
            key = stamp_key(header.stamp)
            mine[key] = time.monotonic()
            published_all[key] = scene.stem
            outcome.published += 1
            next_publish = now + PUBLISH_PERIOD_S
        inbox.drain()
        answer = next((k for k in inbox.holes if k in mine), None)
        if answer is not None:
            break
        time.sleep(0.005)
    if answer is None:
        strangers = [k for k in inbox.holes if k not in published_all]
        hint = ""
        if strangers:
            hint = (
                f"; PoseArrays came with stamps never published ({', '.join(map(show_stamp, strangers[:3]))}), "
                f"the last published was {show_stamp(max(mine))}: is header.stamp carried through exactly?"
            )
        elif any(published_all.get(k) not in (None, scene.stem) for k in inbox.holes):
            hint = "; only answers to earlier scenes' images came"
        outcome.problems.append(
            f"no PoseArray with the stamp of any of the {outcome.published} images published in {args.timeout:.0f} s"
            + hint
        )
        return outcome
    holes, arrived = inbox.holes[answer]
    outcome.latency_ms = (arrived - mine[answer]) * 1e3
    # The PoseStamped of the same frame: a little later at most.
    pose_deadline = max(deadline, time.monotonic() + 2.0)
    while (
        answer not in inbox.pose or answer not in inbox.tf or answer not in inbox.detections
    ) and time.monotonic() < pose_deadline:
        time.sleep(0.005)
        inbox.drain()
    pose = inbox.pose.get(answer, (None, 0))[0]
    check_answer(outcome, holes, pose, answer, args.frame_id)
    check_tf(outcome, inbox.tf.get(answer), answer, args)
    check_detections(outcome, inbox.detections.get(answer), holes, answer, args)
    if ep.debug_image is not None:
        # Drawn and sent on a thread of its own, which skips an image when busy:
        # any of this scene's frames will do.
        debug_deadline = time.monotonic() + 5.0
        while not any(k in mine for k in inbox.debug_images) and time.monotonic() < debug_deadline:
            time.sleep(0.01)
            inbox.drain()
        stamp = next((k for k in sorted(inbox.debug_images) if k in mine), None)
        check_debug_image(outcome, inbox.debug_images.get(stamp), mine, args)
    strangers = [k for k in inbox.pose if k not in published_all]
    if pose is None and strangers:
        outcome.problems.append(
            f"PoseStamped messages came with stamps never published: {', '.join(map(show_stamp, strangers[:3]))}"
        )
    outcome.ok = not outcome.problems
    return outcome


def run_test(args) -> int:
    where = loopback_config()
    scenes = load_scenes(Path(args.scenes))
    print(
        f"ros2_interop: cyclonedds on loopback ({where}), DDS domain {args.domain}, {len(scenes)} scenes",
        flush=True,
    )
    player = None
    if args.selftest:
        player = subprocess.Popen(
            [sys.executable, __file__, "--play-bridge", *sys.argv[1:]],
            stdin=subprocess.DEVNULL,
        )
    try:
        ep = open_endpoints(args)
        start = time.monotonic()
        unmatched = wait_for_discovery(ep, args, start + args.timeout)
        if unmatched:
            print(
                f"FAIL: the bridge was not discovered on DDS domain {args.domain} within {args.timeout:.0f} s: "
                + "; ".join(unmatched),
                flush=True,
            )
            return 1
        print(f"discovered the bridge's endpoints in {time.monotonic() - start:.2f} s", flush=True)
        inbox = Inbox(ep)
        outcomes, published_all = [], {}
        for k, scene in enumerate(scenes):
            if k:
                # Stamps of two scenes further apart than the pose service joins a
                # detection with a wall plane (max_plane_age_ms, 200 ms by default).
                until = time.monotonic() + args.scene_gap
                while time.monotonic() < until:
                    inbox.drain()
                    time.sleep(0.01)
            o = run_scene(ep, inbox, scene, args, published_all)
            outcomes.append(o)
            layout = "intensity,x,y,z" if scene.intensity_first else "x,y,z,intensity"
            step = f", step +{scene.padded_step}" if scene.padded_step else ""
            print(
                f"{'PASS' if o.ok else 'FAIL'} {scene.stem}: {scene.encoding}{step}, cloud {layout}; "
                f"{len(scene.holes_m)} holes, worst {o.hole_error_mm:.3f} mm, rotation {o.rotation_error_deg:.3f} deg; "
                f"tf worst {o.tf_error_mm:.3f} mm, {o.tf_rotation_error_deg:.3f} deg; "
                f"largest hole sigma {o.max_sigma_mm:.3f} mm; debug image {o.debug_image_changed:.1%} drawn over; "
                f"{o.published} published, answered in {o.latency_ms:.0f} ms",
                flush=True,
            )
            for p in o.problems:
                print(f"    {p}", flush=True)
        # Diagnostics from the heartbeats: at least one heartbeat period after the last scene.
        missing = []
        if args.expect_diagnostics:
            until = time.monotonic() + args.timeout
            while time.monotonic() < until:
                inbox.drain()
                missing = [n for n in args.expect_diagnostics if n not in inbox.diagnostics]
                if not missing:
                    break
                time.sleep(0.05)
            print(f"diagnostics received ({len(inbox.diagnostics)} statuses):", flush=True)
            for name, status in sorted(inbox.diagnostics.items()):
                values = ", ".join(f"{kv.key}={kv.value}" for kv in status.values)
                print(f"    {name}: level {status.level} {status.message!r}; {values}", flush=True)
        if args.dump:
            Path(args.dump).write_text(json.dumps([o.dumped for o in outcomes if o.dumped], indent=1))
        passed = sum(o.ok for o in outcomes)
        print(f"ros2_interop: {passed} of {len(outcomes)} scenes passed", flush=True)
        if missing:
            print(
                f"FAIL: no DiagnosticStatus named {', '.join(missing)} on {dds_topic(args.diagnostics_topic)} "
                f"in {args.timeout:.0f} s",
                flush=True,
            )
        if passed != len(outcomes):
            failed = ", ".join(o.scene.stem for o in outcomes if not o.ok)
            print(f"FAIL: scenes {failed} did not pass (details above)", flush=True)
        return 0 if passed == len(outcomes) and not missing else 1
    finally:
        if player is not None:
            player.send_signal(signal.SIGTERM)
            try:
                player.wait(timeout=5)
            except subprocess.TimeoutExpired:
                player.kill()


# ---------------------------------------------------------------------------
# A stand-in for the bridge, for --selftest: it checks what the test publishes
# and answers from the ground truth.


def play_bridge(args) -> int:
    loopback_config()
    scenes = load_scenes(Path(args.scenes))
    dp = DomainParticipant(args.domain)
    best_effort = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(4), CDR)
    image_r = DataReader(dp, Topic(dp, dds_topic(args.image_topic), Image), qos=best_effort)
    info_r = DataReader(dp, Topic(dp, dds_topic(args.camera_info_topic), CameraInfo), qos=best_effort)
    cloud_r = DataReader(dp, Topic(dp, dds_topic(args.points_topic), PointCloud2), qos=best_effort)
    holes_w = DataWriter(dp, Topic(dp, dds_topic(args.holes_topic), PoseArray), qos=RESULT_QOS)
    pose_w = DataWriter(dp, Topic(dp, dds_topic(args.pose_topic), PoseStamped), qos=RESULT_QOS)
    diag_w = DataWriter(dp, Topic(dp, dds_topic(args.diagnostics_topic), DiagnosticArray), qos=RESULT_QOS)
    tf_w = DataWriter(dp, Topic(dp, dds_topic(args.tf_topic), TFMessage), qos=TF_QOS)
    det_w = DataWriter(dp, Topic(dp, dds_topic(args.detections_topic), Detection3DArray), qos=RESULT_QOS)
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    clouds: dict[tuple[int, int], str] = {}  # stamp -> scene whose cloud came with it
    info = None
    beat = 0.0

    def complain(what: str):
        print(f"play-bridge: rejected {what}", file=sys.stderr, flush=True)

    while not stop:
        for m in info_r.take(N=16):
            if isinstance(m, CameraInfo):
                info = m
        for m in cloud_r.take(N=16):
            if not isinstance(m, PointCloud2):
                continue
            try:
                xyz = decode_cloud(m)
            except ValueError as e:
                complain(f"cloud: {e}")
                continue
            same = [s for s in scenes if s.cloud.shape == xyz.shape and np.array_equal(s.cloud, xyz, equal_nan=True)]
            if same:
                clouds[stamp_key(m.header.stamp)] = same[0].stem
            else:
                complain("cloud: matches no scene's PLY")
        for m in image_r.take(N=4):
            if not isinstance(m, Image):
                continue
            key = stamp_key(m.header.stamp)
            if info is None or (info.width, info.height) != (m.width, m.height):
                complain(f"image {show_stamp(key)}: no CameraInfo of its size")
                continue
            try:
                bgr = decode_image(m)
            except ValueError as e:
                complain(f"image {show_stamp(key)}: {e}")
                continue
            scene = next((s for s in scenes if s.stem == clouds.get(key)), None)
            if scene is None:
                complain(f"image {show_stamp(key)}: no cloud with its stamp")
                continue
            expected = scene.bgr
            if m.encoding == "mono8":
                expected = cv2.cvtColor(cv2.cvtColor(scene.bgr, cv2.COLOR_BGR2GRAY), cv2.COLOR_GRAY2BGR)
            k = [float(v) for v in scene.camera["camera_matrix"]["data"]]
            d = [float(v) for v in scene.camera["distortion_coefficients"]["data"]]
            if not np.array_equal(bgr, expected):
                complain(f"image {show_stamp(key)} ({m.encoding}): pixels differ from {scene.stem}'s")
                continue
            if list(info.k) != k or list(info.d) != d or info.distortion_model != "plumb_bob":
                complain(f"camera info: K {list(info.k)} D {list(info.d)}, expected K {k} D {d}")
                continue
            header = Header(m.header.stamp, args.frame_id)
            r = np.array(scene.truth["pose"]["rotation"], dtype=float)
            q = matrix_quaternion(r)
            poses = [Pose(Point(*h), q) for h in scene.holes_m]
            holes_w.write(PoseArray(header, poses))
            pose_w.write(PoseStamped(header, Pose(Point(*scene.truth["pose"]["translation_m"]), q)))
            frames = [(args.outlet_frame, scene.truth["pose"]["translation_m"])]
            frames += [(f"{args.outlet_frame}/hole_{k}", h) for k, h in enumerate(scene.holes_m)]
            tf_w.write(TFMessage([TransformStamped(header, name, Transform(Vector3(*v), q)) for name, v in frames]))
            covariance = [0.0] * 36
            for i, v in enumerate([1e-8, 1e-8, 4e-8, UNKNOWN_ROTATION_VARIANCE, UNKNOWN_ROTATION_VARIANCE,
                                   UNKNOWN_ROTATION_VARIANCE]):
                covariance[7 * i] = v
            detections = [
                Detection3D(
                    header,
                    [ObjectHypothesisWithPose(ObjectHypothesis(h["kind"], 0.9), PoseWithCovariance(p, covariance))],
                    BoundingBox3D(p, Vector3(0.0, 0.0, 0.0)),
                    f"hole_{k}",
                )
                for k, (h, p) in enumerate(zip(scene.truth["holes"], poses))
            ]
            det_w.write(Detection3DArray(header, detections))
        if time.monotonic() > beat:
            beat = time.monotonic() + 0.5
            status = [DiagnosticStatus(0, f"outlet/{s}", "ok", "", [KeyValue("frames", "0")]) for s in
                      ("detector", "normal", "pose", "ros2-bridge")]
            diag_w.write(DiagnosticArray(Header(stamp_of(time.time_ns()), args.frame_id), status))
        time.sleep(0.005)
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenes", help="folder of scenes rendered by `outlet render`")
    parser.add_argument("--domain", type=int, required=True, help="DDS domain id (the bridge's [ros2] domain_id)")
    parser.add_argument("--timeout", type=float, default=30.0, help="seconds for discovery and for each scene")
    parser.add_argument(
        "--scene-gap", type=float, default=0.5, help="seconds between scenes, more than the pose's max_plane_age_ms"
    )
    parser.add_argument("--frame-id", default="camera_optical_frame")
    parser.add_argument("--image-topic", default="/camera/image_raw")
    parser.add_argument("--camera-info-topic", default="/camera/camera_info")
    parser.add_argument("--points-topic", default="/camera/points")
    parser.add_argument("--holes-topic", default="/outlet/holes")
    parser.add_argument("--pose-topic", default="/outlet/pose")
    parser.add_argument("--diagnostics-topic", default="/diagnostics")
    parser.add_argument("--tf-topic", default="/tf")
    parser.add_argument("--detections-topic", default="/outlet/detections")
    parser.add_argument("--outlet-frame", default="outlet", help="the bridge's [ros2] outlet_frame")
    parser.add_argument("--debug-image-topic", help="check the bridge's debug image (sensor_msgs/Image) on this topic")
    parser.add_argument("--dump", help="write each answer's detection scores and covariances here (JSON)")
    parser.add_argument(
        "--expect-diagnostics",
        type=lambda names: [n for n in names.split(",") if n],
        default=[],
        metavar="NAME,...",
        help="DiagnosticStatus names that must arrive on the diagnostics topic (e.g. outlet/detector,outlet/pose)",
    )
    parser.add_argument("--selftest", action="store_true", help="test against a stand-in for the bridge")
    parser.add_argument("--play-bridge", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if not 0 <= args.domain <= 232:
        print(f"ros2_interop: DDS domain id {args.domain} is outside 0..=232", file=sys.stderr)
        return 2
    try:
        return play_bridge(args) if args.play_bridge else run_test(args)
    except Refused as e:
        print(f"ros2_interop: refusing to run: {e}", file=sys.stderr, flush=True)
        return 2


if __name__ == "__main__":
    sys.exit(main())
