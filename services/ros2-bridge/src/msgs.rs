//! Every ROS 2 message the bridge reads or writes, written once, by hand.
//!
//! Each struct lists its fields in the order of its ROS 2 `.msg` definition
//! (Humble and newer; the layouts have not changed since), because plain CDR,
//! the encoding ROS 2 uses over DDS, is that order with no field names. Each
//! type carries its ROS 2 package and name, and the DDS type name ROS 2 gives
//! it (`geometry_msgs::msg::dds_::PoseArray_`): a reader and a writer match
//! only when the type names are the same.
//!
//! `uint8[]` fields (`Image.data`, `PointCloud2.data`) are (de)serialized as
//! byte strings: the same CDR bytes as a sequence of octets (a u32 count, the
//! bytes), read and written in one copy rather than one call per byte.

use ros2_client::MessageTypeName;
use serde::{Deserialize, Serialize};

/// A ROS 2 message type: its package, name and DDS type name.
pub trait RosMessage: Serialize + for<'de> Deserialize<'de> + 'static {
    /// `sensor_msgs`, `geometry_msgs`, ...
    const PACKAGE: &'static str;
    /// `Image`, `PoseArray`, ...
    const NAME: &'static str;
    /// The type name on DDS: `<package>::msg::dds_::<name>_`.
    const DDS_TYPE: &'static str;

    /// The type name as ros2-client takes it.
    fn type_name() -> MessageTypeName {
        MessageTypeName::new(Self::PACKAGE, Self::NAME)
    }
}

macro_rules! ros_message {
    ($ty:ty, $package:literal, $name:literal) => {
        impl RosMessage for $ty {
            const PACKAGE: &'static str = $package;
            const NAME: &'static str = $name;
            const DDS_TYPE: &'static str = concat!($package, "::msg::dds_::", $name, "_");
        }
    };
}

/// `builtin_interfaces/Time`: seconds and nanoseconds since the Unix epoch
/// (ROS time; the bridge reads and writes wall-clock stamps).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}
ros_message!(Time, "builtin_interfaces", "Time");

/// `std_msgs/Header`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    /// The coordinate frame of the data (`camera_optical_frame`).
    pub frame_id: String,
}
ros_message!(Header, "std_msgs", "Header");

/// `geometry_msgs/Point` (metres in this bridge).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Point {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}
ros_message!(Point, "geometry_msgs", "Point");

/// `geometry_msgs/Quaternion`: x, y, z, then w.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}
ros_message!(Quaternion, "geometry_msgs", "Quaternion");

impl Default for Quaternion {
    /// The identity rotation, as ROS 2 initialises it.
    fn default() -> Self {
        Self { x: 0.0, y: 0.0, z: 0.0, w: 1.0 }
    }
}

/// `geometry_msgs/Pose`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Pose {
    pub position: Point,
    pub orientation: Quaternion,
}
ros_message!(Pose, "geometry_msgs", "Pose");

/// `geometry_msgs/PoseArray`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PoseArray {
    pub header: Header,
    pub poses: Vec<Pose>,
}
ros_message!(PoseArray, "geometry_msgs", "PoseArray");

/// `geometry_msgs/PoseStamped`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PoseStamped {
    pub header: Header,
    pub pose: Pose,
}
ros_message!(PoseStamped, "geometry_msgs", "PoseStamped");

/// `geometry_msgs/Vector3` (metres in this bridge).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}
ros_message!(Vector3, "geometry_msgs", "Vector3");

/// `geometry_msgs/Transform`: the child frame in the parent frame.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Transform {
    pub translation: Vector3,
    pub rotation: Quaternion,
}
ros_message!(Transform, "geometry_msgs", "Transform");

/// `geometry_msgs/TransformStamped`: `header.frame_id` is the parent frame.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TransformStamped {
    pub header: Header,
    pub child_frame_id: String,
    pub transform: Transform,
}
ros_message!(TransformStamped, "geometry_msgs", "TransformStamped");

/// `tf2_msgs/TFMessage`, what `/tf` carries.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TFMessage {
    pub transforms: Vec<TransformStamped>,
}
ros_message!(TFMessage, "tf2_msgs", "TFMessage");

/// `geometry_msgs/PoseWithCovariance`: the covariance is 6x6 row-major over
/// (x, y, z, rotation about X, about Y, about Z).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PoseWithCovariance {
    pub pose: Pose,
    #[serde(with = "array36")]
    pub covariance: [f64; 36],
}
ros_message!(PoseWithCovariance, "geometry_msgs", "PoseWithCovariance");

impl Default for PoseWithCovariance {
    fn default() -> Self {
        Self { pose: Pose::default(), covariance: [0.0; 36] }
    }
}

/// `float64[36]` in CDR: 36 doubles, no count (serde's own arrays stop at 32).
mod array36 {
    use serde::de::{Error, SeqAccess, Visitor};
    use serde::ser::SerializeTuple;
    use serde::{Deserializer, Serializer};

    pub fn serialize<S: Serializer>(values: &[f64; 36], s: S) -> Result<S::Ok, S::Error> {
        let mut t = s.serialize_tuple(36)?;
        for v in values {
            t.serialize_element(v)?;
        }
        t.end()
    }

    struct Array36;

    impl<'de> Visitor<'de> for Array36 {
        type Value = [f64; 36];

        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("36 float64 values")
        }

        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<[f64; 36], A::Error> {
            let mut out = [0.0; 36];
            for (k, v) in out.iter_mut().enumerate() {
                *v = seq.next_element()?.ok_or_else(|| A::Error::invalid_length(k, &self))?;
            }
            Ok(out)
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 36], D::Error> {
        d.deserialize_tuple(36, Array36)
    }
}

/// `vision_msgs/ObjectHypothesis` (vision_msgs 4, Humble and newer).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ObjectHypothesis {
    pub class_id: String,
    pub score: f64,
}
ros_message!(ObjectHypothesis, "vision_msgs", "ObjectHypothesis");

/// `vision_msgs/ObjectHypothesisWithPose`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ObjectHypothesisWithPose {
    pub hypothesis: ObjectHypothesis,
    pub pose: PoseWithCovariance,
}
ros_message!(ObjectHypothesisWithPose, "vision_msgs", "ObjectHypothesisWithPose");

/// `vision_msgs/BoundingBox3D`: a box about `center`, `size` its edges (m).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct BoundingBox3D {
    pub center: Pose,
    pub size: Vector3,
}
ros_message!(BoundingBox3D, "vision_msgs", "BoundingBox3D");

/// `vision_msgs/Detection3D` as of vision_msgs 4 (Humble): header, results,
/// bbox, id (vision_msgs 3, Foxy, had `source_cloud` and tracking fields instead of `id`).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Detection3D {
    pub header: Header,
    pub results: Vec<ObjectHypothesisWithPose>,
    pub bbox: BoundingBox3D,
    pub id: String,
}
ros_message!(Detection3D, "vision_msgs", "Detection3D");

/// `vision_msgs/Detection3DArray`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Detection3DArray {
    pub header: Header,
    pub detections: Vec<Detection3D>,
}
ros_message!(Detection3DArray, "vision_msgs", "Detection3DArray");

/// `sensor_msgs/Image`: `height` rows of `step` bytes.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Image {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    /// `mono8`, `rgb8`, `bgr8`, ... (sensor_msgs/image_encodings.hpp).
    pub encoding: String,
    pub is_bigendian: u8,
    /// Bytes per row.
    pub step: u32,
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}
ros_message!(Image, "sensor_msgs", "Image");

/// `sensor_msgs/CompressedImage`: `format` says the codec (`jpeg`, `png`, or
/// image_transport's `rgb8; jpeg compressed bgr8`); the bytes tell it too.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct CompressedImage {
    pub header: Header,
    pub format: String,
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}
ros_message!(CompressedImage, "sensor_msgs", "CompressedImage");

/// `sensor_msgs/RegionOfInterest`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct RegionOfInterest {
    pub x_offset: u32,
    pub y_offset: u32,
    pub height: u32,
    pub width: u32,
    pub do_rectify: bool,
}
ros_message!(RegionOfInterest, "sensor_msgs", "RegionOfInterest");

/// `sensor_msgs/CameraInfo`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct CameraInfo {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    /// `plumb_bob` (k1, k2, t1, t2, k3), `rational_polynomial`, `equidistant`, ...
    pub distortion_model: String,
    pub d: Vec<f64>,
    /// Intrinsics, row-major 3x3: fx 0 cx / 0 fy cy / 0 0 1.
    pub k: [f64; 9],
    /// Rectification rotation, row-major 3x3.
    pub r: [f64; 9],
    /// Projection, row-major 3x4.
    pub p: [f64; 12],
    pub binning_x: u32,
    pub binning_y: u32,
    pub roi: RegionOfInterest,
}
ros_message!(CameraInfo, "sensor_msgs", "CameraInfo");

/// `sensor_msgs/PointField`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct PointField {
    pub name: String,
    /// Byte offset of the field in a point.
    pub offset: u32,
    /// One of the `PointField::*` data type constants.
    pub datatype: u8,
    /// Elements of the field per point.
    pub count: u32,
}
ros_message!(PointField, "sensor_msgs", "PointField");

impl PointField {
    pub const INT8: u8 = 1;
    pub const UINT8: u8 = 2;
    pub const INT16: u8 = 3;
    pub const UINT16: u8 = 4;
    pub const INT32: u8 = 5;
    pub const UINT32: u8 = 6;
    pub const FLOAT32: u8 = 7;
    pub const FLOAT64: u8 = 8;

    /// The name of a data type constant, for messages.
    pub fn datatype_name(datatype: u8) -> &'static str {
        match datatype {
            Self::INT8 => "int8",
            Self::UINT8 => "uint8",
            Self::INT16 => "int16",
            Self::UINT16 => "uint16",
            Self::INT32 => "int32",
            Self::UINT32 => "uint32",
            Self::FLOAT32 => "float32",
            Self::FLOAT64 => "float64",
            _ => "unknown",
        }
    }
}

/// `sensor_msgs/PointCloud2`: `height` rows of `row_step` bytes, each row
/// `width` points of `point_step` bytes.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct PointCloud2 {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub fields: Vec<PointField>,
    pub is_bigendian: bool,
    pub point_step: u32,
    pub row_step: u32,
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
    pub is_dense: bool,
}
ros_message!(PointCloud2, "sensor_msgs", "PointCloud2");

/// `diagnostic_msgs/KeyValue`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct KeyValue {
    pub key: String,
    pub value: String,
}
ros_message!(KeyValue, "diagnostic_msgs", "KeyValue");

/// `diagnostic_msgs/DiagnosticStatus`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    /// `DiagnosticStatus::OK`, `WARN`, `ERROR` or `STALE` (ROS `byte`).
    pub level: u8,
    pub name: String,
    pub message: String,
    pub hardware_id: String,
    pub values: Vec<KeyValue>,
}
ros_message!(DiagnosticStatus, "diagnostic_msgs", "DiagnosticStatus");

impl DiagnosticStatus {
    pub const OK: u8 = 0;
    pub const WARN: u8 = 1;
    pub const ERROR: u8 = 2;
    pub const STALE: u8 = 3;
}

/// `diagnostic_msgs/DiagnosticArray`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct DiagnosticArray {
    pub header: Header,
    pub status: Vec<DiagnosticStatus>,
}
ros_message!(DiagnosticArray, "diagnostic_msgs", "DiagnosticArray");

/// `builtin_interfaces/Duration`: seconds and nanoseconds (0..1e9) of a span.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Duration {
    pub sec: i32,
    pub nanosec: u32,
}
ros_message!(Duration, "builtin_interfaces", "Duration");

/// `std_msgs/ColorRGBA`: each channel in 0..1, `a` the opacity.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct ColorRGBA {
    pub r: f32,
    pub g: f32,
    pub b: f32,
    pub a: f32,
}
ros_message!(ColorRGBA, "std_msgs", "ColorRGBA");

/// `visualization_msgs/UVCoordinate`: a vertex's place in a marker's texture (0..1).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct UVCoordinate {
    pub u: f64,
    pub v: f64,
}
ros_message!(UVCoordinate, "visualization_msgs", "UVCoordinate");

/// `visualization_msgs/MeshFile`: a mesh file sent in the message.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct MeshFile {
    pub filename: String,
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}
ros_message!(MeshFile, "visualization_msgs", "MeshFile");

/// `visualization_msgs/Marker` as of visualization_msgs 3 (Galactic; Humble
/// and Jazzy have the same fields): after `colors` come the texture fields
/// (`texture_resource`, `texture`, `uv_coordinates`), `text`, and the mesh
/// fields (`mesh_resource`, `mesh_file`, `mesh_use_embedded_materials`).
/// The bridge leaves the texture and mesh fields empty.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Marker {
    pub header: Header,
    /// With `id`, the marker's name: a marker of the same `ns` and `id` replaces it.
    pub ns: String,
    pub id: i32,
    /// `Marker::SPHERE`, `CUBE`, ... (ROS `int32 type`).
    pub type_: i32,
    /// `Marker::ADD`, `DELETE` or `DELETEALL`.
    pub action: i32,
    /// The marker's centre and orientation in `header.frame_id`.
    pub pose: Pose,
    /// Full extent along the marker's own axes (m): a SPHERE's diameters, a CUBE's edges.
    pub scale: Vector3,
    pub color: ColorRGBA,
    /// Zero: until replaced or deleted.
    pub lifetime: Duration,
    pub frame_locked: bool,
    pub points: Vec<Point>,
    pub colors: Vec<ColorRGBA>,
    pub texture_resource: String,
    pub texture: CompressedImage,
    pub uv_coordinates: Vec<UVCoordinate>,
    pub text: String,
    pub mesh_resource: String,
    pub mesh_file: MeshFile,
    pub mesh_use_embedded_materials: bool,
}
ros_message!(Marker, "visualization_msgs", "Marker");

impl Marker {
    pub const ARROW: i32 = 0;
    pub const CUBE: i32 = 1;
    pub const SPHERE: i32 = 2;
    pub const CYLINDER: i32 = 3;
    pub const LINE_STRIP: i32 = 4;
    pub const LINE_LIST: i32 = 5;
    pub const CUBE_LIST: i32 = 6;
    pub const SPHERE_LIST: i32 = 7;
    pub const POINTS: i32 = 8;
    pub const TEXT_VIEW_FACING: i32 = 9;
    pub const MESH_RESOURCE: i32 = 10;
    pub const TRIANGLE_LIST: i32 = 11;
    pub const ADD: i32 = 0;
    pub const MODIFY: i32 = 0;
    pub const DELETE: i32 = 2;
    /// Deletes every marker (of `ns`, when it is not empty) shown so far.
    pub const DELETEALL: i32 = 3;
}

/// `visualization_msgs/MarkerArray`: markers applied in order.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct MarkerArray {
    pub markers: Vec<Marker>,
}
ros_message!(MarkerArray, "visualization_msgs", "MarkerArray");

#[cfg(test)]
mod tests {
    use super::*;
    use byteorder::LittleEndian;
    use ros2_client::dds::rustdds::cdr_encoding;

    fn dds_type<M: RosMessage>() -> (String, &'static str) {
        (M::type_name().dds_msg_type(), M::DDS_TYPE)
    }

    #[test]
    fn type_names_are_the_ones_ros2_gives_over_dds() {
        assert_eq!(PoseArray::DDS_TYPE, "geometry_msgs::msg::dds_::PoseArray_");
        assert_eq!(Image::DDS_TYPE, "sensor_msgs::msg::dds_::Image_");
        assert_eq!(DiagnosticArray::DDS_TYPE, "diagnostic_msgs::msg::dds_::DiagnosticArray_");
        assert_eq!(TFMessage::DDS_TYPE, "tf2_msgs::msg::dds_::TFMessage_");
        assert_eq!(Detection3DArray::DDS_TYPE, "vision_msgs::msg::dds_::Detection3DArray_");
        assert_eq!(MarkerArray::DDS_TYPE, "visualization_msgs::msg::dds_::MarkerArray_");
        assert_eq!(ColorRGBA::DDS_TYPE, "std_msgs::msg::dds_::ColorRGBA_");
        for (made, constant) in [
            dds_type::<Time>(),
            dds_type::<Header>(),
            dds_type::<Point>(),
            dds_type::<Quaternion>(),
            dds_type::<Pose>(),
            dds_type::<PoseArray>(),
            dds_type::<PoseStamped>(),
            dds_type::<Image>(),
            dds_type::<RegionOfInterest>(),
            dds_type::<CameraInfo>(),
            dds_type::<PointField>(),
            dds_type::<PointCloud2>(),
            dds_type::<KeyValue>(),
            dds_type::<DiagnosticStatus>(),
            dds_type::<DiagnosticArray>(),
            dds_type::<Vector3>(),
            dds_type::<Transform>(),
            dds_type::<TransformStamped>(),
            dds_type::<TFMessage>(),
            dds_type::<PoseWithCovariance>(),
            dds_type::<ObjectHypothesis>(),
            dds_type::<ObjectHypothesisWithPose>(),
            dds_type::<BoundingBox3D>(),
            dds_type::<Detection3D>(),
            dds_type::<Detection3DArray>(),
            dds_type::<Duration>(),
            dds_type::<ColorRGBA>(),
            dds_type::<UVCoordinate>(),
            dds_type::<MeshFile>(),
            dds_type::<Marker>(),
            dds_type::<MarkerArray>(),
        ] {
            assert_eq!(made, constant);
        }
    }

    fn cdr<T: Serialize>(value: &T) -> Vec<u8> {
        cdr_encoding::to_vec::<T, LittleEndian>(value).expect("serialises")
    }

    #[test]
    fn an_image_is_laid_out_as_ros2_lays_it_out() {
        let image = Image {
            header: Header { stamp: Time { sec: 1, nanosec: 2 }, frame_id: "cam".into() },
            height: 1,
            width: 2,
            encoding: "mono8".into(),
            is_bigendian: 0,
            step: 2,
            data: vec![7, 9],
        };
        #[rustfmt::skip]
        let expected: Vec<u8> = vec![
            1, 0, 0, 0, 2, 0, 0, 0,           // stamp: sec, nanosec
            4, 0, 0, 0, b'c', b'a', b'm', 0,  // frame_id, NUL-terminated
            1, 0, 0, 0, 2, 0, 0, 0,           // height, width
            6, 0, 0, 0, b'm', b'o', b'n', b'o', b'8', 0, // encoding
            0,                                // is_bigendian
            0,                                // padding to 4
            2, 0, 0, 0,                       // step
            2, 0, 0, 0, 7, 9,                 // data: count, bytes
        ];
        assert_eq!(cdr(&image), expected);
        let (back, _) = cdr_encoding::from_bytes::<Image, LittleEndian>(&expected).expect("decodes");
        assert_eq!(back, image);
    }

    #[test]
    fn pose_arrays_and_clouds_round_trip_through_cdr() {
        let poses = PoseArray {
            header: Header { stamp: Time { sec: 5, nanosec: 6 }, frame_id: "f".into() },
            poses: vec![Pose { position: Point { x: 1.0, y: 2.0, z: 3.0 }, orientation: Quaternion::default() }; 2],
        };
        let bytes = cdr(&poses);
        // Header (8 + 4 + 2 bytes, padded to 16), count 4 bytes, padding to 8, then 2 x 7 doubles.
        assert_eq!(bytes.len(), 16 + 4 + 4 + 2 * 56);
        assert_eq!(cdr_encoding::from_bytes::<PoseArray, LittleEndian>(&bytes).expect("decodes").0, poses);
        let cloud = PointCloud2 {
            header: Header::default(),
            height: 1,
            width: 1,
            fields: vec![PointField { name: "x".into(), offset: 0, datatype: PointField::FLOAT32, count: 1 }],
            is_bigendian: false,
            point_step: 4,
            row_step: 4,
            data: 1.5f32.to_le_bytes().to_vec(),
            is_dense: true,
        };
        assert_eq!(cdr_encoding::from_bytes::<PointCloud2, LittleEndian>(&cdr(&cloud)).expect("decodes").0, cloud);
    }

    #[test]
    fn a_detection_is_laid_out_as_vision_msgs_4_lays_it_out() {
        let mut covariance = [0.0; 36];
        covariance[0] = 1.5;
        covariance[35] = 2.5;
        let pose = Pose { position: Point { x: 1.0, y: 2.0, z: 3.0 }, orientation: Quaternion::default() };
        let d = Detection3DArray {
            header: Header { stamp: Time { sec: 1, nanosec: 2 }, frame_id: "c".into() },
            detections: vec![Detection3D {
                header: Header { stamp: Time { sec: 1, nanosec: 2 }, frame_id: "c".into() },
                results: vec![ObjectHypothesisWithPose {
                    hypothesis: ObjectHypothesis { class_id: "power".into(), score: 0.75 },
                    pose: PoseWithCovariance { pose, covariance },
                }],
                bbox: BoundingBox3D { center: pose, size: Vector3::default() },
                id: "hole_0".into(),
            }],
        };
        let bytes = cdr(&d);
        let f64_at = |at: usize| f64::from_le_bytes(bytes[at..at + 8].try_into().expect("8 bytes"));
        // Array header (8 + 4 + 2 = 14) | count at 16 | detection header 20..34 | results count at 36 |
        // class_id at 40 (4 + 6 = 10) | pad to 56 | score at 56 | pose 64..120 | covariance 120..408 |
        // bbox center 408..464, size 464..488 | id at 488 (4 + 7).
        assert_eq!(u32::from_le_bytes(bytes[16..20].try_into().expect("4")), 1);
        assert_eq!(&bytes[44..50], b"power\0");
        assert_eq!(f64_at(56), 0.75);
        assert_eq!([f64_at(64), f64_at(72), f64_at(80), f64_at(112)], [1.0, 2.0, 3.0, 1.0]);
        assert_eq!([f64_at(120), f64_at(120 + 35 * 8)], [1.5, 2.5]);
        assert_eq!(f64_at(408), 1.0);
        assert_eq!(&bytes[492..499], b"hole_0\0");
        assert_eq!(bytes.len(), 499);
        let (back, _) = cdr_encoding::from_bytes::<Detection3DArray, LittleEndian>(&bytes).expect("decodes");
        assert_eq!(back, d);
        for cut in 0..bytes.len() {
            assert!(cdr_encoding::from_bytes::<Detection3DArray, LittleEndian>(&bytes[..cut]).is_err(), "cut {cut}");
        }
    }

    #[test]
    fn tf_messages_round_trip_through_cdr() {
        let tf = TFMessage {
            transforms: vec![TransformStamped {
                header: Header { stamp: Time { sec: 3, nanosec: 4 }, frame_id: "cam".into() },
                child_frame_id: "outlet".into(),
                transform: Transform {
                    translation: Vector3 { x: 0.1, y: 0.2, z: 0.5 },
                    rotation: Quaternion::default(),
                },
            }],
        };
        let bytes = cdr(&tf);
        // count 4 | stamp 8 | "cam" 4 + 4 | "outlet" 4 + 7 | pad to 32 | 7 doubles.
        assert_eq!(bytes.len(), 32 + 56);
        assert_eq!(cdr_encoding::from_bytes::<TFMessage, LittleEndian>(&bytes).expect("decodes").0, tf);
    }

    #[test]
    fn a_marker_is_laid_out_as_visualization_msgs_lays_it_out() {
        let marker = Marker {
            header: Header { stamp: Time { sec: 1, nanosec: 2 }, frame_id: "c".into() },
            ns: "holes".into(),
            id: 3,
            type_: Marker::SPHERE,
            action: Marker::ADD,
            pose: Pose { position: Point { x: 0.1, y: 0.2, z: 0.5 }, orientation: Quaternion::default() },
            scale: Vector3 { x: 0.001, y: 0.002, z: 0.006 },
            color: ColorRGBA { r: 1.0, g: 0.5, b: 0.25, a: 0.9 },
            lifetime: Duration { sec: 7, nanosec: 8 },
            frame_locked: true,
            ..Marker::default()
        };
        let bytes = cdr(&marker);
        let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
        let f64_at = |at: usize| f64::from_le_bytes(bytes[at..at + 8].try_into().expect("8 bytes"));
        let f32_at = |at: usize| f32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
        // header 0..14 | ns at 16 (4 + 6) | id 28, type 32, action 36 | pose 40..96 |
        // scale 96..120 | color 120..136 | lifetime 136..144 | frame_locked 144 |
        // points count 148, colors count 152 | texture_resource 156 (4 + 1) |
        // texture: stamp 164, frame_id 172 (4 + 1), format 180 (4 + 1), data count 188 |
        // uv_coordinates count 192 | text 196 (4 + 1) | mesh_resource 204 (4 + 1) |
        // mesh_file: filename 212 (4 + 1), data count 220 | mesh_use_embedded_materials 224.
        assert_eq!(&bytes[20..26], b"holes\0");
        assert_eq!([u32_at(28), u32_at(32), u32_at(36)], [3, 2, 0]);
        assert_eq!([f64_at(40), f64_at(48), f64_at(56), f64_at(88)], [0.1, 0.2, 0.5, 1.0]);
        assert_eq!([f64_at(96), f64_at(104), f64_at(112)], [0.001, 0.002, 0.006]);
        assert_eq!([f32_at(120), f32_at(124), f32_at(128), f32_at(132)], [1.0, 0.5, 0.25, 0.9]);
        assert_eq!([u32_at(136), u32_at(140)], [7, 8]);
        assert_eq!(bytes[144], 1);
        assert_eq!([u32_at(148), u32_at(152)], [0, 0]);
        // Every empty string is its terminating NUL alone.
        for at in [156, 172, 180, 196, 204, 212] {
            assert_eq!((u32_at(at), bytes[at + 4]), (1, 0), "string at {at}");
        }
        assert_eq!([u32_at(188), u32_at(192), u32_at(220)], [0, 0, 0]);
        assert_eq!(bytes[224], 0);
        assert_eq!(bytes.len(), 225);
        let (back, _) = cdr_encoding::from_bytes::<Marker, LittleEndian>(&bytes).expect("decodes");
        assert_eq!(back, marker);
    }

    #[test]
    fn marker_arrays_round_trip_through_cdr_with_every_field() {
        let full = Marker {
            header: Header { stamp: Time { sec: 5, nanosec: 6 }, frame_id: "cam".into() },
            ns: "n".into(),
            type_: Marker::TRIANGLE_LIST,
            points: vec![Point { x: 1.0, y: 2.0, z: 3.0 }; 3],
            colors: vec![ColorRGBA { r: 0.1, g: 0.2, b: 0.3, a: 0.4 }; 3],
            texture_resource: "embedded://t".into(),
            texture: CompressedImage { header: Header::default(), format: "png".into(), data: vec![1, 2, 3] },
            uv_coordinates: vec![UVCoordinate { u: 0.25, v: 0.75 }; 3],
            text: "hole_0".into(),
            mesh_resource: "embedded://m".into(),
            mesh_file: MeshFile { filename: "m.stl".into(), data: vec![9; 5] },
            mesh_use_embedded_materials: true,
            ..Marker::default()
        };
        let array = MarkerArray { markers: vec![Marker { action: Marker::DELETEALL, ..Marker::default() }, full] };
        let bytes = cdr(&array);
        assert_eq!(u32::from_le_bytes(bytes[..4].try_into().expect("4")), 2);
        let (back, _) = cdr_encoding::from_bytes::<MarkerArray, LittleEndian>(&bytes).expect("decodes");
        assert_eq!(back, array);
        for cut in 0..bytes.len() {
            assert!(cdr_encoding::from_bytes::<MarkerArray, LittleEndian>(&bytes[..cut]).is_err(), "cut {cut}");
        }
    }

    #[test]
    fn truncated_messages_fail_to_decode_without_panicking() {
        let image = Image { width: 4, height: 4, step: 4, data: vec![1; 16], ..Image::default() };
        let bytes = cdr(&image);
        for cut in 0..bytes.len() {
            assert!(cdr_encoding::from_bytes::<Image, LittleEndian>(&bytes[..cut]).is_err(), "cut at {cut}");
        }
        // Sequence counts far larger than the message: the fields', then the data's.
        let cloud = cdr(&PointCloud2::default());
        for at in [24, 40] {
            let mut huge = cloud.clone();
            huge[at..at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
            assert!(cdr_encoding::from_bytes::<PointCloud2, LittleEndian>(&huge).is_err(), "count at {at}");
        }
    }
}
