//! The ROS 2 side of `outlet serve ros2-bridge`: camera images, their camera
//! info and point clouds come in from ROS 2, hole poses and the services'
//! diagnostics go out to it.
//!
//! - [`msgs`]: the ROS 2 messages, each with its DDS type name.
//! - [`cdr`]: the messages as CDR bytes with their `.msg` definitions, as
//!   rosbag2 stores them in MCAP files (`outlet record`, `outlet replay`).
//! - [`convert`]: ROS 2 messages to and from the sidecar's wire types, pure
//!   functions that check everything that comes from the network.
//! - [`perception`]: a result as tf transforms and a `vision_msgs`
//!   Detection3DArray with the holes' covariances.
//! - [`markers`]: a result as a `visualization_msgs` MarkerArray for rviz: the
//!   holes' uncertainty ellipsoids, the plate, the wall plane.
//! - [`debug_image`]: the frame with what was found drawn on it, as an Image
//!   and a JPEG CompressedImage, joined from the frame, its detection and its pose.
//! - [`bridge`]: the DDS participant (ros2-client on rustdds) on the configured
//!   network interfaces only, its subscriptions and publishers.
//!
//! The shared-memory side (iceoryx2) is the `outlet` command's
//! (`services/outlet/src/serve/ros2_bridge.rs`).

pub mod bridge;
pub mod cdr;
pub mod convert;
pub mod debug_image;
pub mod markers;
pub mod msgs;
pub mod perception;

pub use bridge::{Bridge, BridgeError, DebugPublisher, DebugSubscribers, Input, Inputs, Stop};
pub use convert::Rejection;
/// The ros2-client this crate is built on, for programs that talk to the bridge.
pub use ros2_client;

use serde::{Deserialize, Serialize};

/// The `[ros2]` table of the sidecar's configuration.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Ros2Config {
    /// The DDS domain id (ROS_DOMAIN_ID), 0..=232.
    pub domain_id: u16,
    /// Network interfaces (names such as `lo`, or IPv4 addresses) DDS may use;
    /// `["lo"]` confines it to loopback; empty: every interface (rustdds' default).
    pub interfaces: Vec<String>,
    /// The frame_id of the published headers: the camera's optical frame, the
    /// parent of the tf frames.
    pub frame_id: String,
    /// The tf child frame of the outlet (parent `frame_id`).
    pub outlet_frame: String,
    /// Whether each hole gets a tf frame as well: `<outlet_frame>/hole_<k>`.
    pub hole_frames: bool,
    pub topics: Ros2Topics,
}

/// ROS 2 topic names of the bridge.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Ros2Topics {
    /// In: sensor_msgs/Image (mono8, rgb8, bgr8), best-effort.
    pub image: String,
    /// In: sensor_msgs/CompressedImage (JPEG or PNG, the image_transport
    /// convention `<image>/compressed`), best-effort; decoded to rgb8.
    pub image_compressed: String,
    /// In: sensor_msgs/CameraInfo of the images (plumb_bob or no distortion).
    pub camera_info: String,
    /// In: sensor_msgs/PointCloud2 with float32 x, y, z, best-effort.
    pub points: String,
    /// Out: geometry_msgs/PoseArray, one pose per hole, reliable.
    pub holes: String,
    /// Out: geometry_msgs/PoseStamped of the outlet, reliable.
    pub pose: String,
    /// Out: vision_msgs/Detection3DArray, one detection per hole with its covariance, reliable.
    pub detections: String,
    /// Out: tf2_msgs/TFMessage, the outlet's (and the holes') frames, reliable.
    pub tf: String,
    /// Out: diagnostic_msgs/DiagnosticArray of the services' heartbeats, reliable.
    pub diagnostics: String,
    /// Out: sensor_msgs/Image (rgb8), the frame with what was found drawn on
    /// it; made only while the topic has a subscriber.
    pub debug_image: String,
    /// Out: sensor_msgs/CompressedImage (JPEG) of the same, image_transport's
    /// `<debug_image>/compressed`; made only while the topic has a subscriber.
    pub debug_image_compressed: String,
    /// Out: visualization_msgs/MarkerArray for rviz: the holes (ellipsoids of
    /// their 3-sigma position uncertainty), the plate, the wall plane.
    pub markers: String,
}

impl Default for Ros2Config {
    fn default() -> Self {
        Self {
            domain_id: 0,
            interfaces: Vec::new(),
            frame_id: "camera_optical_frame".into(),
            outlet_frame: "outlet".into(),
            hole_frames: true,
            topics: Ros2Topics::default(),
        }
    }
}

impl Default for Ros2Topics {
    fn default() -> Self {
        Self {
            image: "/camera/image_raw".into(),
            image_compressed: "/camera/image_raw/compressed".into(),
            camera_info: "/camera/camera_info".into(),
            points: "/camera/points".into(),
            holes: "/outlet/holes".into(),
            pose: "/outlet/pose".into(),
            detections: "/outlet/detections".into(),
            tf: "/tf".into(),
            diagnostics: "/diagnostics".into(),
            debug_image: "/outlet/debug_image".into(),
            debug_image_compressed: "/outlet/debug_image/compressed".into(),
            markers: "/outlet/markers".into(),
        }
    }
}

/// The largest DDS domain id whose RTPS ports (7400 + 250 x domain + ...) fit in 16 bits.
pub const MAX_DOMAIN_ID: u16 = 232;

impl Ros2Topics {
    /// Each topic with its key in the file.
    pub fn named(&self) -> [(&'static str, &str); 12] {
        [
            ("image", &self.image),
            ("image_compressed", &self.image_compressed),
            ("camera_info", &self.camera_info),
            ("points", &self.points),
            ("holes", &self.holes),
            ("pose", &self.pose),
            ("detections", &self.detections),
            ("tf", &self.tf),
            ("diagnostics", &self.diagnostics),
            ("debug_image", &self.debug_image),
            ("debug_image_compressed", &self.debug_image_compressed),
            ("markers", &self.markers),
        ]
    }
}

impl Ros2Config {
    /// Refuses values the bridge cannot run with, naming the key under `ros2`.
    pub fn check(&self) -> Result<(), String> {
        if self.domain_id > MAX_DOMAIN_ID {
            return Err(format!("key `ros2.domain_id`: {} is not in 0..={MAX_DOMAIN_ID}", self.domain_id));
        }
        if let Some(bad) = self.interfaces.iter().find(|i| i.trim().is_empty() || i.trim() != i.as_str()) {
            return Err(format!("key `ros2.interfaces`: {bad:?} is not an interface name"));
        }
        // tf2 refuses frame ids with a leading slash.
        for (key, frame) in [("frame_id", &self.frame_id), ("outlet_frame", &self.outlet_frame)] {
            if frame.is_empty() || frame.starts_with('/') || frame.trim() != frame.as_str() {
                return Err(format!("key `ros2.{key}`: {frame:?} is not a tf frame id (empty, spaces or a leading /)"));
            }
        }
        if self.outlet_frame == self.frame_id {
            return Err(format!("key `ros2.outlet_frame`: {:?} is the camera's frame_id too", self.outlet_frame));
        }
        for (key, topic) in self.topics.named() {
            bridge::topic_name(topic).map_err(|e| format!("key `ros2.topics.{key}`: {e}"))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_defaults_are_the_ros2_conventions_and_pass_the_checks() {
        let c = Ros2Config::default();
        assert_eq!(c.domain_id, 0);
        assert!(c.interfaces.is_empty());
        assert_eq!(c.topics.image, "/camera/image_raw");
        assert_eq!(c.topics.holes, "/outlet/holes");
        assert_eq!(c.topics.tf, "/tf");
        assert_eq!(c.topics.detections, "/outlet/detections");
        assert_eq!(c.topics.debug_image, "/outlet/debug_image");
        assert_eq!(c.topics.debug_image_compressed, "/outlet/debug_image/compressed");
        assert_eq!(c.topics.markers, "/outlet/markers");
        assert_eq!((c.outlet_frame.as_str(), c.hole_frames), ("outlet", true));
        assert_eq!(c.check(), Ok(()));
    }

    #[test]
    fn bad_values_are_named() {
        let c = Ros2Config { domain_id: 233, ..Ros2Config::default() };
        assert!(c.check().expect_err("domain").contains("ros2.domain_id"));
        let c = Ros2Config { interfaces: vec![String::new()], ..Ros2Config::default() };
        assert!(c.check().expect_err("interface").contains("ros2.interfaces"));
        let mut c = Ros2Config::default();
        c.topics.holes = "/outlet//holes".into();
        assert!(c.check().expect_err("topic").contains("ros2.topics.holes"));
        let mut c = Ros2Config::default();
        c.topics.image = "camera image".into();
        assert!(c.check().expect_err("topic").contains("ros2.topics.image"));
        let c = Ros2Config { frame_id: String::new(), ..Ros2Config::default() };
        assert!(c.check().expect_err("frame").contains("ros2.frame_id"));
        let c = Ros2Config { outlet_frame: "/outlet".into(), ..Ros2Config::default() };
        assert!(c.check().expect_err("frame").contains("ros2.outlet_frame"));
        let c = Ros2Config { outlet_frame: "camera_optical_frame".into(), ..Ros2Config::default() };
        assert!(c.check().expect_err("frame").contains("ros2.outlet_frame"));
        let mut c = Ros2Config::default();
        c.topics.tf = "tf topic".into();
        assert!(c.check().expect_err("topic").contains("ros2.topics.tf"));
        let mut c = Ros2Config::default();
        c.topics.markers = "/outlet/markers/".into();
        assert!(c.check().expect_err("topic").contains("ros2.topics.markers"));
        let mut c = Ros2Config::default();
        c.topics.debug_image_compressed = "/outlet/debug image".into();
        assert!(c.check().expect_err("topic").contains("ros2.topics.debug_image_compressed"));
    }
}
