//! ROS 2 messages as bytes outside DDS: the CDR encoding that ROS 2 puts on the
//! wire and rosbag2 stores in its MCAP files (message encoding `cdr`), and the
//! message definitions rosbag2 stores beside them (schema encoding `ros2msg`).
//!
//! The bytes are the same serialisation of the [`crate::msgs`] structs the DDS
//! side uses (`cdr_encoding`, as rustdds' and ros2-client's serializer), after
//! the 4-byte encapsulation header DDS puts in front of every sample: `00 01 00
//! 00` for little-endian plain CDR. Reading accepts big-endian CDR too.

use crate::msgs::{CameraInfo, Image, PointCloud2, RosMessage};
use byteorder::{BigEndian, LittleEndian};
use ros2_client::dds::rustdds::cdr_encoding;

/// The MCAP message encoding of CDR-encoded ROS 2 messages.
pub const MESSAGE_ENCODING: &str = "cdr";
/// The MCAP schema encoding of ROS 2 `.msg` definitions.
pub const SCHEMA_ENCODING: &str = "ros2msg";

const CDR_BE: [u8; 2] = [0x00, 0x00];
const CDR_LE: [u8; 2] = [0x00, 0x01];

/// Why bytes are not a message of the type asked for.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CdrError {
    #[error("{0} bytes: too short for the 4-byte CDR encapsulation header")]
    NoHeader(usize),
    #[error("encapsulation {0:02x?} is not plain CDR (00 00 big-endian or 00 01 little-endian)")]
    Representation([u8; 2]),
    #[error("{ty} does not decode: {reason}")]
    Decode { ty: &'static str, reason: String },
    #[error("{ty} does not serialise: {reason}")]
    Encode { ty: &'static str, reason: String },
}

/// The encapsulated little-endian CDR bytes of a message, as a ROS 2 publisher
/// sends them and rosbag2 stores them.
pub fn encode<M: RosMessage>(message: &M) -> Result<Vec<u8>, CdrError> {
    let mut out = CDR_LE.to_vec();
    out.extend_from_slice(&[0, 0]);
    cdr_encoding::to_writer::<M, LittleEndian, _>(&mut out, message)
        .map_err(|e| CdrError::Encode { ty: M::NAME, reason: e.to_string() })?;
    Ok(out)
}

/// A message from encapsulated CDR bytes (either byte order); trailing bytes
/// (padding) are allowed.
pub fn decode<M: RosMessage>(bytes: &[u8]) -> Result<M, CdrError> {
    let (head, body) = bytes.split_at_checked(4).ok_or(CdrError::NoHeader(bytes.len()))?;
    let representation = [head[0], head[1]];
    let decoded = match representation {
        CDR_LE => cdr_encoding::from_bytes::<M, LittleEndian>(body),
        CDR_BE => cdr_encoding::from_bytes::<M, BigEndian>(body),
        other => return Err(CdrError::Representation(other)),
    };
    decoded.map(|(m, _)| m).map_err(|e| CdrError::Decode { ty: M::NAME, reason: e.to_string() })
}

/// A message whose ROS 2 definition rosbag2 would store as its schema.
pub trait Definition: RosMessage {
    /// The `.msg` text, then each type it uses after a line of `=` and `MSG: <type>`.
    const DEFINITION: &'static str;

    /// The schema name: `sensor_msgs/msg/Image`.
    fn schema_name() -> String {
        format!("{}/msg/{}", Self::PACKAGE, Self::NAME)
    }
}

macro_rules! separator {
    () => {
        "================================================================================\n"
    };
}

macro_rules! header_definitions {
    () => {
        concat!(
            separator!(),
            "MSG: std_msgs/Header\n",
            "builtin_interfaces/Time stamp\n",
            "string frame_id\n",
            separator!(),
            "MSG: builtin_interfaces/Time\n",
            "int32 sec\n",
            "uint32 nanosec\n",
        )
    };
}

impl Definition for Image {
    const DEFINITION: &'static str = concat!(
        "std_msgs/Header header\n",
        "uint32 height\n",
        "uint32 width\n",
        "string encoding\n",
        "uint8 is_bigendian\n",
        "uint32 step\n",
        "uint8[] data\n",
        header_definitions!(),
    );
}

impl Definition for CameraInfo {
    const DEFINITION: &'static str = concat!(
        "std_msgs/Header header\n",
        "uint32 height\n",
        "uint32 width\n",
        "string distortion_model\n",
        "float64[] d\n",
        "float64[9] k\n",
        "float64[9] r\n",
        "float64[12] p\n",
        "uint32 binning_x\n",
        "uint32 binning_y\n",
        "sensor_msgs/RegionOfInterest roi\n",
        header_definitions!(),
        separator!(),
        "MSG: sensor_msgs/RegionOfInterest\n",
        "uint32 x_offset\n",
        "uint32 y_offset\n",
        "uint32 height\n",
        "uint32 width\n",
        "bool do_rectify\n",
    );
}

impl Definition for PointCloud2 {
    const DEFINITION: &'static str = concat!(
        "std_msgs/Header header\n",
        "uint32 height\n",
        "uint32 width\n",
        "sensor_msgs/PointField[] fields\n",
        "bool is_bigendian\n",
        "uint32 point_step\n",
        "uint32 row_step\n",
        "uint8[] data\n",
        "bool is_dense\n",
        header_definitions!(),
        separator!(),
        "MSG: sensor_msgs/PointField\n",
        "uint8 INT8=1\n",
        "uint8 UINT8=2\n",
        "uint8 INT16=3\n",
        "uint8 UINT16=4\n",
        "uint8 INT32=5\n",
        "uint8 UINT32=6\n",
        "uint8 FLOAT32=7\n",
        "uint8 FLOAT64=8\n",
        "string name\n",
        "uint32 offset\n",
        "uint8 datatype\n",
        "uint32 count\n",
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{Header, Time};

    fn image() -> Image {
        Image {
            header: Header { stamp: Time { sec: 1, nanosec: 2 }, frame_id: "cam".into() },
            height: 1,
            width: 2,
            encoding: "mono8".into(),
            is_bigendian: 0,
            step: 2,
            data: vec![7, 9],
        }
    }

    #[test]
    fn messages_are_encapsulated_little_endian_cdr_and_come_back() {
        let bytes = encode(&image()).expect("encodes");
        assert_eq!(&bytes[..4], &[0, 1, 0, 0]);
        // The body is the DDS sample's: stamp first.
        assert_eq!(&bytes[4..12], &[1, 0, 0, 0, 2, 0, 0, 0]);
        assert_eq!(decode::<Image>(&bytes), Ok(image()));
        let mut padded = bytes.clone();
        padded.extend_from_slice(&[0, 0, 0]);
        assert_eq!(decode::<Image>(&padded), Ok(image()));
    }

    #[test]
    fn big_endian_cdr_is_read() {
        let mut bytes = vec![0, 0, 0, 0];
        bytes.extend(cdr_encoding::to_vec::<Image, BigEndian>(&image()).expect("encodes"));
        assert_eq!(decode::<Image>(&bytes), Ok(image()));
    }

    #[test]
    fn bytes_that_are_not_the_message_say_why() {
        assert_eq!(decode::<Image>(&[0, 1]), Err(CdrError::NoHeader(2)));
        let mut xcdr2 = encode(&image()).expect("encodes");
        xcdr2[1] = 0x07;
        assert_eq!(decode::<Image>(&xcdr2), Err(CdrError::Representation([0, 7])));
        let bytes = encode(&image()).expect("encodes");
        for cut in 4..bytes.len() {
            let e = decode::<Image>(&bytes[..cut]).expect_err("truncated");
            assert!(e.to_string().starts_with("Image does not decode"), "{e}");
        }
    }

    #[test]
    fn definitions_name_every_type_they_use() {
        assert_eq!(Image::schema_name(), "sensor_msgs/msg/Image");
        assert_eq!(PointCloud2::schema_name(), "sensor_msgs/msg/PointCloud2");
        for (definition, used) in [
            (Image::DEFINITION, &["std_msgs/Header", "builtin_interfaces/Time"][..]),
            (CameraInfo::DEFINITION, &["std_msgs/Header", "builtin_interfaces/Time", "sensor_msgs/RegionOfInterest"]),
            (PointCloud2::DEFINITION, &["std_msgs/Header", "builtin_interfaces/Time", "sensor_msgs/PointField"]),
        ] {
            for ty in used {
                assert!(definition.contains(&format!("\nMSG: {ty}\n")), "{ty}");
            }
        }
    }
}
