//! A frame's result as ROS 2 perception nodes take one: the outlet (and each
//! hole) on `/tf`, as apriltag_ros broadcasts tags, and the holes as
//! `vision_msgs/Detection3DArray` with their position covariances. Pure
//! functions of the PoseArray and PoseStamped [`crate::convert::poses_of`] made
//! (and checked) from the same message, and of the message's covariances.

use crate::convert::Rejection;
use crate::msgs::{
    BoundingBox3D, Detection3D, Detection3DArray, ObjectHypothesis, ObjectHypothesisWithPose, Pose, PoseArray,
    PoseStamped, PoseWithCovariance, TFMessage, Transform, TransformStamped, Vector3,
};
use nalgebra::Matrix3;
use outlet_protocol::wire::{DetectionMsg, HolePosesMsg, MAX_HOLES};
use std::collections::VecDeque;

/// The variance (rad²) put on each rotation of a hole's PoseWithCovariance:
/// "not estimated" (a hole is a point; its orientation is the outlet's, whose
/// covariance is not on the wire). A large finite value, as robot_localization
/// and REP 145-style consumers read "unknown"; -1 would mark the whole
/// covariance unknown, which the position part is not.
pub const UNKNOWN_ROTATION_VARIANCE_RAD2: f64 = 1e6;

/// The tf child frame of hole `k`: `outlet/hole_0`, ...
pub fn hole_frame(outlet_frame: &str, k: usize) -> String {
    format!("{outlet_frame}/hole_{k}")
}

/// The `vision_msgs` class of a hole kind on the wire (1 power, 2 ground).
pub fn class_of(kind: u32) -> Option<&'static str> {
    match kind {
        1 => Some("power"),
        2 => Some("ground"),
        _ => None,
    }
}

/// One TFMessage for the frame: parent `stamped.header.frame_id` (the camera's
/// optical frame), child `outlet_frame` at the outlet's pose, and with
/// `hole_frames` one child per hole ([`hole_frame`]), also parented on the
/// camera: its position the hole's, its rotation the outlet's (the PoseArray's
/// poses). Stamped with the capture time.
pub fn tf_of(holes: &PoseArray, stamped: &PoseStamped, outlet_frame: &str, hole_frames: bool) -> TFMessage {
    let transform = |child_frame_id: String, pose: &Pose| TransformStamped {
        header: stamped.header.clone(),
        child_frame_id,
        transform: Transform {
            translation: Vector3 { x: pose.position.x, y: pose.position.y, z: pose.position.z },
            rotation: pose.orientation,
        },
    };
    let mut transforms = vec![transform(outlet_frame.to_string(), &stamped.pose)];
    if hole_frames {
        transforms.extend(holes.poses.iter().enumerate().map(|(k, p)| transform(hole_frame(outlet_frame, k), p)));
    }
    TFMessage { transforms }
}

/// The 6x6 row-major covariance of a hole's pose: its 3x3 position covariance
/// (m², camera frame) top left, symmetrised, [`UNKNOWN_ROTATION_VARIANCE_RAD2`]
/// on the rotations' diagonal, zero between position and rotation. None unless
/// the 3x3 block is finite and symmetric (to 1e-6 of its largest entry) with a
/// non-negative diagonal.
pub fn covariance_6x6(position_m2: &[f64; 9]) -> Option<[f64; 36]> {
    let c = Matrix3::from_row_slice(position_m2);
    let symmetric = (c - c.transpose()).amax() <= 1e-6 * c.amax();
    if !c.iter().all(|v| v.is_finite()) || !symmetric || (0..3).any(|i| c[(i, i)] < 0.0) {
        return None;
    }
    let c = (c + c.transpose()) / 2.0;
    let mut out = [0.0; 36];
    for i in 0..3 {
        for j in 0..3 {
            out[6 * i + j] = c[(i, j)];
        }
        out[6 * (i + 3) + i + 3] = UNKNOWN_ROTATION_VARIANCE_RAD2;
    }
    Some(out)
}

/// The holes as a Detection3DArray: one Detection3D per hole in template order
/// (`id` `hole_<k>`), each with one hypothesis: class `power` or `ground`, the
/// detector's score of the hole (`scores`, 0 where the bridge did not see the
/// frame's detection), the hole's pose (the PoseArray's) with
/// [`covariance_6x6`]; the bounding box centred there with size zero (a point:
/// the hole's extent is the template's, not measured). Every header is the
/// PoseArray's (capture time, camera optical frame).
pub fn detections_of(
    holes: &PoseArray,
    msg: &HolePosesMsg,
    scores: Option<&[f64; MAX_HOLES]>,
) -> Result<Detection3DArray, Rejection> {
    let reject = |reason: String| Rejection::Poses { frame_id: msg.frame_id, reason };
    let detections = holes
        .poses
        .iter()
        .enumerate()
        .map(|(k, pose)| {
            let class = class_of(msg.kinds[k]).ok_or_else(|| reject(format!("hole {k}: kind {}", msg.kinds[k])))?;
            let covariance = covariance_6x6(&msg.covariances_m2[k])
                .ok_or_else(|| reject(format!("hole {k}: covariance {:?} is not one", msg.covariances_m2[k])))?;
            let score = scores.map_or(0.0, |s| s[k]);
            Ok(Detection3D {
                header: holes.header.clone(),
                results: vec![ObjectHypothesisWithPose {
                    hypothesis: ObjectHypothesis { class_id: class.to_string(), score },
                    pose: PoseWithCovariance { pose: *pose, covariance },
                }],
                bbox: BoundingBox3D { center: *pose, size: Vector3::default() },
                id: format!("hole_{k}"),
            })
        })
        .collect::<Result<Vec<_>, Rejection>>()?;
    Ok(Detection3DArray { header: holes.header.clone(), detections })
}

/// The holes' scores of the last detections, to be joined with the hole poses
/// solved from them (the pose service keeps the detection's frame id, capture
/// time and hole order). A detection is published before its pose, so the
/// bridge reads the detections it has received before each pose.
#[derive(Debug, Clone, Default)]
pub struct HoleScores {
    recent: VecDeque<(u64, u64, [f64; MAX_HOLES])>,
}

impl HoleScores {
    /// Detections kept: more than the poses in flight at once.
    pub const KEEP: usize = 32;

    /// Keeps the scores of a detection with holes (a score not in 0..=1 is 0).
    pub fn insert(&mut self, d: &DetectionMsg) {
        if d.hole_count == 0 {
            return;
        }
        let scores = std::array::from_fn(|k| {
            let s = d.holes[k].score;
            if (0.0..=1.0).contains(&s) { s } else { 0.0 }
        });
        if self.recent.len() == Self::KEEP {
            self.recent.pop_front();
        }
        self.recent.push_back((d.frame_id, d.capture_time_ns, scores));
    }

    /// The scores of the detection of `msg`'s frame, if it came.
    pub fn of(&self, msg: &HolePosesMsg) -> Option<&[f64; MAX_HOLES]> {
        self.recent
            .iter()
            .rev()
            .find(|(frame_id, capture_time_ns, _)| *frame_id == msg.frame_id && *capture_time_ns == msg.capture_time_ns)
            .map(|(_, _, scores)| scores)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::convert::poses_of;
    use outlet_protocol::wire::{HoleMsg, SCHEMA_VERSION, pose_status};

    fn hole_poses() -> HolePosesMsg {
        let mut msg = HolePosesMsg {
            schema_version: SCHEMA_VERSION,
            hole_count: 3,
            frame_id: 7,
            capture_time_ns: 1_700_000_000_250_000_000,
            published_ns: 0,
            mode: 3,
            status: pose_status::OK,
            outlier_mask: 0,
            reserved: 0,
            rotation: [0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            translation_m: [0.01, 0.02, 0.4],
            kinds: [0; MAX_HOLES],
            positions_m: [[0.0; 3]; MAX_HOLES],
            covariances_m2: [[0.0; 9]; MAX_HOLES],
        };
        for k in 0..3 {
            msg.kinds[k] = if k == 2 { 2 } else { 1 };
            msg.positions_m[k] = [0.01 * k as f64, 0.02, 0.4];
            let s = 1e-8 * (k + 1) as f64;
            msg.covariances_m2[k] = [s, 1e-9, 0.0, 1e-9, 2.0 * s, -1e-9, 0.0, -1e-9, 3.0 * s];
        }
        msg
    }

    fn detection(frame_id: u64, capture_time_ns: u64) -> DetectionMsg {
        let mut holes = [HoleMsg::default(); MAX_HOLES];
        for (k, h) in holes.iter_mut().take(3).enumerate() {
            h.score = 0.5 + 0.1 * k as f64;
        }
        holes[1].score = f64::NAN;
        DetectionMsg {
            schema_version: SCHEMA_VERSION,
            hole_count: 3,
            frame_id,
            capture_time_ns,
            score: 6,
            reserved: 0,
            detect_ms: 1.0,
            width: 640,
            height: 480,
            intrinsics: [500.0, 500.0, 320.0, 240.0],
            distortion: [0.0; 5],
            holes,
        }
    }

    #[test]
    fn the_outlet_and_each_hole_are_children_of_the_camera_frame_on_tf() {
        let msg = hole_poses();
        let (array, stamped) = poses_of(&msg, "cam_optical").expect("converted");
        let tf = tf_of(&array, &stamped, "outlet", true);
        let children: Vec<&str> = tf.transforms.iter().map(|t| t.child_frame_id.as_str()).collect();
        assert_eq!(children, ["outlet", "outlet/hole_0", "outlet/hole_1", "outlet/hole_2"]);
        for t in &tf.transforms {
            assert_eq!(t.header, stamped.header);
            assert_eq!(t.header.frame_id, "cam_optical");
            assert_eq!(t.transform.rotation, stamped.pose.orientation);
        }
        let outlet = tf.transforms[0].transform.translation;
        assert_eq!([outlet.x, outlet.y, outlet.z], msg.translation_m);
        let hole_2 = tf.transforms[3].transform.translation;
        assert_eq!([hole_2.x, hole_2.y, hole_2.z], msg.positions_m[2]);
        assert_eq!(tf_of(&array, &stamped, "plug", false).transforms.len(), 1);
    }

    #[test]
    fn each_hole_is_a_detection_with_its_class_score_and_position_covariance() {
        let msg = hole_poses();
        let (array, _) = poses_of(&msg, "cam").expect("converted");
        let mut scores = HoleScores::default();
        scores.insert(&detection(6, msg.capture_time_ns));
        assert!(scores.of(&msg).is_none(), "another frame");
        scores.insert(&detection(7, msg.capture_time_ns));
        let found = scores.of(&msg).expect("joined");
        assert_eq!(found[..3], [0.5, 0.0, 0.7], "a NaN score is 0");
        let d = detections_of(&array, &msg, Some(found)).expect("converted");
        assert_eq!(d.header, array.header);
        assert_eq!(d.detections.len(), 3);
        for (k, det) in d.detections.iter().enumerate() {
            assert_eq!(det.header, array.header);
            assert_eq!(det.id, format!("hole_{k}"));
            assert_eq!(det.results.len(), 1);
            let h = &det.results[0];
            assert_eq!(h.hypothesis.class_id, if k == 2 { "ground" } else { "power" });
            assert_eq!(h.hypothesis.score, found[k]);
            assert_eq!(h.pose.pose, array.poses[k]);
            assert_eq!(det.bbox.center, array.poses[k]);
            let c = &h.pose.covariance;
            for i in 0..6 {
                for j in 0..6 {
                    let expected = match (i < 3, j < 3) {
                        (true, true) => msg.covariances_m2[k][3 * i + j],
                        (false, false) if i == j => UNKNOWN_ROTATION_VARIANCE_RAD2,
                        _ => 0.0,
                    };
                    assert_eq!(c[6 * i + j], expected, "hole {k} ({i}, {j})");
                }
            }
        }
        assert!(
            detections_of(&array, &msg, None)
                .expect("no scores")
                .detections
                .iter()
                .all(|d| d.results[0].hypothesis.score == 0.0)
        );
    }

    #[test]
    fn holes_without_a_kind_or_a_covariance_are_rejected() {
        let msg = hole_poses();
        let (array, _) = poses_of(&msg, "cam").expect("converted");
        let mut unknown = msg;
        unknown.kinds[1] = 0;
        assert!(matches!(detections_of(&array, &unknown, None), Err(Rejection::Poses { frame_id: 7, .. })));
        for bad in [f64::NAN, f64::INFINITY] {
            let mut m = msg;
            m.covariances_m2[0][4] = bad;
            assert!(detections_of(&array, &m, None).is_err());
        }
        let mut asymmetric = msg;
        asymmetric.covariances_m2[2][1] = 5e-9;
        assert!(detections_of(&array, &asymmetric, None).is_err());
        let mut negative = msg;
        negative.covariances_m2[0][0] = -1e-8;
        assert!(detections_of(&array, &negative, None).is_err());
    }

    #[test]
    fn only_the_last_detections_are_kept() {
        let mut scores = HoleScores::default();
        for f in 0..(HoleScores::KEEP as u64 + 5) {
            scores.insert(&detection(f, 100 + f));
        }
        let asked = |frame_id: u64, capture_time_ns: u64| HolePosesMsg { frame_id, capture_time_ns, ..hole_poses() };
        assert!(scores.of(&asked(0, 100)).is_none());
        assert!(scores.of(&asked(10, 110)).is_some());
        assert!(scores.of(&asked(10, 111)).is_none(), "same frame id, another capture (a restarted bridge)");
        let mut empty = detection(99, 1);
        empty.hole_count = 0;
        scores.insert(&empty);
        assert!(scores.of(&asked(99, 1)).is_none());
    }
}
