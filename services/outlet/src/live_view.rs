//! The live view (`outlet serve viewer`): what crosses the sidecar's shared
//! memory, as Foxglove messages on a Foxglove WebSocket server. Open Foxglove,
//! connect to `ws://localhost:8765`, and see:
//!
//! | topic | Foxglove schema | what |
//! |---|---|---|
//! | `/camera/image` | `foxglove.RawImage` | the camera's frames (mono8, rgb8, bgr8) |
//! | `/camera/calibration` | `foxglove.CameraCalibration` | their intrinsics (plumb_bob) |
//! | `/outlet/annotations` | `foxglove.ImageAnnotations` | each hole as a 3-sigma circle, class-coloured; a status line |
//! | `/outlet/scene` | `foxglove.SceneUpdate` | holes as 3-sigma ellipsoids, the plate, the wall plane |
//! | `/tf` | `foxglove.FrameTransforms` | camera frame to `outlet` |
//! | `/outlet/cloud` | `foxglove.PointCloud` | the stereo cloud (x, y, z float32) |
//! | `/outlet/detections`, `/outlet/hole_poses`, `/outlet/wall_plane`, `/outlet/heartbeat` | JSON (as in recordings) | the services' results and health |
//!
//! Every message is stamped with its frame's capture time, in the camera's
//! optical frame (`[ros2] frame_id`). Nothing is converted for a channel no
//! client subscribes to, so the view costs the pipeline nothing unwatched.

use crate::recording::{detection_json, heartbeat_json, hole_poses_json, schema, topic, wall_plane_json};
use foxglove::messages::{
    CameraCalibration, CircleAnnotation, Color, CubePrimitive, FrameTransform, FrameTransforms, ImageAnnotations,
    PackedElementField, Point2, PointCloud, Pose, Quaternion, RawImage, SceneEntity, SceneEntityDeletion, SceneUpdate,
    SpherePrimitive, TextAnnotation, Timestamp, Vector3 as FgVector3,
};
use foxglove::{Channel, Context, RawChannel, Schema};
use nalgebra::{Matrix3, Rotation3, SymmetricEigen, UnitQuaternion, Vector3};
use outlet_protocol::wire::{
    CloudHeader, DetectionMsg, FrameHeader, HeartbeatMsg, HolePosesMsg, PixelFormat, WallPlaneMsg, pose_status,
};
use serde_json::Value;
use std::sync::Arc;

/// Topics of the live view (see the module's table).
pub mod view_topic {
    pub const IMAGE: &str = "/camera/image";
    pub const CALIBRATION: &str = "/camera/calibration";
    pub const ANNOTATIONS: &str = "/outlet/annotations";
    pub const SCENE: &str = "/outlet/scene";
    pub const TF: &str = "/tf";
    pub const CLOUD: &str = "/outlet/cloud";
}

/// The child frame of the outlet's pose on `/tf`.
pub const OUTLET_FRAME: &str = "outlet";

/// The channels of one live view, in their own Foxglove context.
pub struct LiveView {
    frame_id: String,
    image: Channel<RawImage>,
    calibration: Channel<CameraCalibration>,
    annotations: Channel<ImageAnnotations>,
    scene: Channel<SceneUpdate>,
    transforms: Channel<FrameTransforms>,
    cloud: Channel<PointCloud>,
    detections: Arc<RawChannel>,
    hole_poses: Arc<RawChannel>,
    plane: Arc<RawChannel>,
    heartbeat: Arc<RawChannel>,
}

fn json_channel(ctx: &Arc<Context>, topic: &str, name: &str, schema: &Value) -> Result<Arc<RawChannel>, String> {
    ctx.channel_builder(topic)
        .message_encoding("json")
        .schema(Schema::new(name, "jsonschema", schema.to_string().into_bytes()))
        .build_raw()
        .map_err(|e| format!("channel {topic}: {e}"))
}

impl LiveView {
    /// The channels in `ctx`, stamped in the camera frame `frame_id`.
    pub fn new(ctx: &Arc<Context>, frame_id: &str) -> Result<Self, String> {
        Ok(Self {
            frame_id: frame_id.to_string(),
            image: ctx.channel_builder(view_topic::IMAGE).build(),
            calibration: ctx.channel_builder(view_topic::CALIBRATION).build(),
            annotations: ctx.channel_builder(view_topic::ANNOTATIONS).build(),
            scene: ctx.channel_builder(view_topic::SCENE).build(),
            transforms: ctx.channel_builder(view_topic::TF).build(),
            cloud: ctx.channel_builder(view_topic::CLOUD).build(),
            detections: json_channel(ctx, topic::DETECTIONS, "outlet.Detection", &schema::detection())?,
            hole_poses: json_channel(ctx, topic::HOLE_POSES, "outlet.HolePoses", &schema::hole_poses())?,
            plane: json_channel(ctx, topic::WALL_PLANE, "outlet.WallPlane", &schema::wall_plane())?,
            heartbeat: json_channel(ctx, topic::HEARTBEAT, "outlet.Heartbeat", &schema::heartbeat())?,
        })
    }

    /// A camera frame: its image and calibration. A frame whose header does not
    /// fit its pixels is refused with the reason.
    pub fn frame(&self, header: &FrameHeader, pixels: &[u8]) -> Result<(), String> {
        let (want_image, want_calibration) = (self.image.has_sinks(), self.calibration.has_sinks());
        if !want_image && !want_calibration {
            return Ok(());
        }
        let (format, _) = header.validate(pixels.len()).map_err(|e| e.to_string())?;
        if want_image {
            self.image.log(&raw_image(header, format, pixels, &self.frame_id));
        }
        if want_calibration {
            self.calibration.log(&calibration(header, &self.frame_id));
        }
        Ok(())
    }

    /// A stereo cloud (x, y, z per point, camera frame, metres).
    pub fn cloud(&self, header: &CloudHeader, xyz: &[f32]) {
        if self.cloud.has_sinks() {
            self.cloud.log(&point_cloud(header, xyz, &self.frame_id));
        }
    }

    /// A detection: its JSON and its holes drawn over the image.
    pub fn detection(&self, d: &DetectionMsg) {
        log_json(&self.detections, &detection_json(d));
        if self.annotations.has_sinks() {
            self.annotations.log(&annotations(d));
        }
    }

    /// Hole poses: their JSON, the holes and plate in 3D, the outlet on `/tf`.
    pub fn hole_poses(&self, p: &HolePosesMsg) {
        log_json(&self.hole_poses, &hole_poses_json(p));
        if self.scene.has_sinks() {
            self.scene.log(&holes_scene(p, &self.frame_id));
        }
        if self.transforms.has_sinks()
            && let Some(tf) = outlet_transform(p, &self.frame_id)
        {
            self.transforms.log(&FrameTransforms { transforms: vec![tf] });
        }
    }

    /// A wall plane: its JSON and a square of it in 3D.
    pub fn plane(&self, p: &WallPlaneMsg) {
        log_json(&self.plane, &wall_plane_json(p));
        if self.scene.has_sinks() {
            self.scene.log(&wall_scene(p, &self.frame_id));
        }
    }

    /// A service's heartbeat.
    pub fn heartbeat(&self, b: &HeartbeatMsg) {
        log_json(&self.heartbeat, &heartbeat_json(b));
    }
}

fn log_json(channel: &RawChannel, value: &Value) {
    if channel.has_sinks() {
        channel.log(value.to_string().as_bytes());
    }
}

fn stamp(capture_time_ns: u64) -> Timestamp {
    let sec = u32::try_from(capture_time_ns / 1_000_000_000).unwrap_or(u32::MAX);
    Timestamp::new(sec, (capture_time_ns % 1_000_000_000) as u32)
}

fn colour(r: f64, g: f64, b: f64, a: f64) -> Color {
    Color { r, g, b, a }
}

/// Power holes blue, ground holes green, an outlier's pixel orange (as `outlet
/// detect --annotate` draws them).
fn kind_colour(kind: u32, alpha: f64) -> Color {
    match kind {
        1 => colour(0.2, 0.45, 1.0, alpha),
        2 => colour(0.1, 0.85, 0.2, alpha),
        _ => colour(1.0, 1.0, 1.0, alpha),
    }
}

fn vector(v: &Vector3<f64>) -> FgVector3 {
    FgVector3 { x: v.x, y: v.y, z: v.z }
}

fn quaternion(q: &UnitQuaternion<f64>) -> Quaternion {
    Quaternion { x: q.i, y: q.j, z: q.k, w: q.w }
}

fn pose(position: &Vector3<f64>, orientation: &UnitQuaternion<f64>) -> Pose {
    Pose { position: Some(vector(position)), orientation: Some(quaternion(orientation)) }
}

/// The frame as a `foxglove.RawImage` (its rows as they are, stride kept).
pub fn raw_image(header: &FrameHeader, format: PixelFormat, pixels: &[u8], frame_id: &str) -> RawImage {
    let encoding = match format {
        PixelFormat::Mono8 => "mono8",
        PixelFormat::Rgb8 => "rgb8",
        PixelFormat::Bgr8 => "bgr8",
    };
    let len = (header.stride as usize * header.height as usize).min(pixels.len());
    RawImage {
        timestamp: Some(stamp(header.capture_time_ns)),
        frame_id: frame_id.to_string(),
        width: header.width,
        height: header.height,
        encoding: encoding.into(),
        step: header.stride,
        data: pixels[..len].to_vec().into(),
    }
}

/// The frame's camera as a `foxglove.CameraCalibration` (plumb_bob).
pub fn calibration(header: &FrameHeader, frame_id: &str) -> CameraCalibration {
    let [fx, fy, cx, cy] = header.intrinsics;
    CameraCalibration {
        timestamp: Some(stamp(header.capture_time_ns)),
        frame_id: frame_id.to_string(),
        width: header.width,
        height: header.height,
        distortion_model: "plumb_bob".into(),
        d: header.distortion.to_vec(),
        k: vec![fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
        r: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: vec![fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
    }
}

/// The cloud as a `foxglove.PointCloud`: float32 x, y, z, 12 bytes a point.
pub fn point_cloud(header: &CloudHeader, xyz: &[f32], frame_id: &str) -> PointCloud {
    let n = (xyz.len() / 3).min(usize::try_from(header.points).unwrap_or(usize::MAX));
    let data: Vec<u8> = xyz[..3 * n].iter().flat_map(|v| v.to_le_bytes()).collect();
    let field = |name: &str, offset: u32| PackedElementField {
        name: name.into(),
        offset,
        r#type: foxglove::messages::packed_element_field::NumericType::Float32 as i32,
    };
    PointCloud {
        timestamp: Some(stamp(header.capture_time_ns)),
        frame_id: frame_id.to_string(),
        pose: Some(pose(&Vector3::zeros(), &UnitQuaternion::identity())),
        point_stride: 12,
        fields: vec![field("x", 0), field("y", 4), field("z", 8)],
        data: data.into(),
    }
}

/// Image annotations of a detection: each hole a circle of 3 sigma (at least 8
/// px across) at its pixel as captured, and a status line. Pixel coordinates
/// here have their origin at the top-left pixel's centre (CONTRACT.md);
/// Foxglove's at its top-left corner, hence the half pixel.
pub fn annotations(d: &DetectionMsg) -> ImageAnnotations {
    let n = (d.hole_count as usize).min(d.holes.len());
    let at = |p: [f64; 2]| Point2 { x: p[0] + 0.5, y: p[1] + 0.5 };
    let circles = d.holes[..n]
        .iter()
        .map(|h| CircleAnnotation {
            timestamp: None,
            position: Some(at(h.pixel)),
            diameter: (6.0 * h.sigma_px).max(8.0),
            thickness: 2.0,
            fill_color: Some(kind_colour(h.kind, 0.15)),
            outline_color: Some(kind_colour(h.kind, 1.0)),
            metadata: Vec::new(),
        })
        .collect();
    let text = if n == 0 {
        format!("frame {}: no outlet ({:.1} ms)", d.frame_id, d.detect_ms)
    } else {
        format!("frame {}: {} holes, score {} ({:.1} ms)", d.frame_id, n, d.score, d.detect_ms)
    };
    ImageAnnotations {
        timestamp: Some(stamp(d.capture_time_ns)),
        circles,
        points: Vec::new(),
        texts: vec![TextAnnotation {
            timestamp: None,
            position: Some(Point2 { x: 8.0, y: 24.0 }),
            text,
            font_size: 16.0,
            text_color: Some(if n == 0 { colour(1.0, 0.3, 0.2, 1.0) } else { colour(1.0, 1.0, 1.0, 1.0) }),
            background_color: Some(colour(0.0, 0.0, 0.0, 0.6)),
            metadata: Vec::new(),
        }],
        metadata: Vec::new(),
    }
}

/// A covariance's 3-sigma ellipsoid: its axes as an orientation and its
/// diameters (m).
pub fn ellipsoid(covariance: &Matrix3<f64>) -> Option<(UnitQuaternion<f64>, Vector3<f64>)> {
    if !covariance.iter().all(|v| v.is_finite()) {
        return None;
    }
    let eig = SymmetricEigen::new((covariance + covariance.transpose()) * 0.5);
    let mut axes = eig.eigenvectors;
    // A rotation, not a reflection.
    if axes.determinant() < 0.0 {
        axes.column_mut(2).neg_mut();
    }
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(axes));
    Some((rotation, eig.eigenvalues.map(|l| 6.0 * l.max(0.0).sqrt())))
}

fn outlet_rotation(p: &HolePosesMsg) -> Option<(UnitQuaternion<f64>, Vector3<f64>)> {
    let r = Matrix3::from_row_slice(&p.rotation);
    let t = Vector3::from(p.translation_m);
    if p.status != pose_status::OK || !r.iter().chain(t.iter()).all(|v| v.is_finite()) {
        return None;
    }
    Some((UnitQuaternion::from_matrix(&r), t))
}

/// The outlet's pose on `/tf`: parent the camera frame, child [`OUTLET_FRAME`].
pub fn outlet_transform(p: &HolePosesMsg, frame_id: &str) -> Option<FrameTransform> {
    let (q, t) = outlet_rotation(p)?;
    Some(FrameTransform {
        timestamp: Some(stamp(p.capture_time_ns)),
        parent_frame_id: frame_id.to_string(),
        child_frame_id: OUTLET_FRAME.into(),
        translation: Some(vector(&t)),
        rotation: Some(quaternion(&q)),
    })
}

/// The holes (a 2 mm dot and the translucent 3-sigma ellipsoid each) and the
/// plate (the holes' extent in the outlet frame and 15 mm around, 1 mm thick).
/// Without a pose, the last holes and plate are taken away.
pub fn holes_scene(p: &HolePosesMsg, frame_id: &str) -> SceneUpdate {
    let Some((q, t)) = outlet_rotation(p) else {
        let delete = |id: &str| SceneEntityDeletion {
            timestamp: Some(stamp(p.capture_time_ns)),
            r#type: foxglove::messages::scene_entity_deletion::Type::MatchingId as i32,
            id: id.into(),
        };
        return SceneUpdate { deletions: vec![delete("holes"), delete("plate")], entities: Vec::new() };
    };
    let n = (p.hole_count as usize).min(p.positions_m.len());
    let mut spheres = Vec::with_capacity(2 * n);
    let (mut lo, mut hi) = (Vector3::repeat(f64::INFINITY), Vector3::repeat(f64::NEG_INFINITY));
    for k in 0..n {
        let position = Vector3::from(p.positions_m[k]);
        let local = q.inverse() * (position - t);
        lo = lo.inf(&local);
        hi = hi.sup(&local);
        spheres.push(SpherePrimitive {
            pose: Some(pose(&position, &UnitQuaternion::identity())),
            size: Some(vector(&Vector3::repeat(0.002))),
            color: Some(kind_colour(p.kinds[k], 1.0)),
        });
        if let Some((axes, size)) = ellipsoid(&Matrix3::from_row_slice(&p.covariances_m2[k])) {
            spheres.push(SpherePrimitive {
                pose: Some(pose(&position, &axes)),
                size: Some(vector(&size)),
                color: Some(kind_colour(p.kinds[k], 0.35)),
            });
        }
    }
    let entity = |id: &str| SceneEntity {
        timestamp: Some(stamp(p.capture_time_ns)),
        frame_id: frame_id.to_string(),
        id: id.into(),
        ..Default::default()
    };
    let mut entities = vec![SceneEntity { spheres, ..entity("holes") }];
    if n > 0 {
        let centre = (lo + hi) / 2.0;
        let size = Vector3::new(hi.x - lo.x + 0.03, hi.y - lo.y + 0.03, 0.001);
        entities.push(SceneEntity {
            cubes: vec![CubePrimitive {
                pose: Some(pose(&(t + q * centre), &q)),
                size: Some(vector(&size)),
                color: Some(colour(0.95, 0.95, 0.9, 0.5)),
            }],
            ..entity("plate")
        });
    }
    SceneUpdate { deletions: Vec::new(), entities }
}

/// The wall plane as a 0.6 m square, translucent, centred where the plane
/// meets the optical axis (or its foot from the camera when it does not).
pub fn wall_scene(p: &WallPlaneMsg, frame_id: &str) -> SceneUpdate {
    let normal = Vector3::from(p.normal);
    let Some(normal) = nalgebra::Unit::try_new(normal, 1e-9).filter(|_| p.distance_m.is_finite()) else {
        return SceneUpdate::default();
    };
    let centre = if normal.z.abs() > 0.2 {
        Vector3::z() * (p.distance_m / normal.z)
    } else {
        normal.into_inner() * p.distance_m
    };
    let orientation = UnitQuaternion::rotation_between(&Vector3::z(), &normal).unwrap_or_else(UnitQuaternion::identity);
    SceneUpdate {
        deletions: Vec::new(),
        entities: vec![SceneEntity {
            timestamp: Some(stamp(p.capture_time_ns)),
            frame_id: frame_id.to_string(),
            id: "wall".into(),
            cubes: vec![CubePrimitive {
                pose: Some(pose(&centre, &orientation)),
                size: Some(vector(&Vector3::new(0.6, 0.6, 0.0005))),
                color: Some(colour(0.6, 0.6, 0.65, 0.25)),
            }],
            ..Default::default()
        }],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use outlet_protocol::wire::{HoleMsg, MAX_HOLES, SCHEMA_VERSION};

    fn poses(status: u32) -> HolePosesMsg {
        let mut p = HolePosesMsg {
            schema_version: SCHEMA_VERSION,
            hole_count: 2,
            frame_id: 7,
            capture_time_ns: 1_500_000_000_250,
            published_ns: 0,
            mode: 3,
            status,
            outlier_mask: 0,
            reserved: 0,
            rotation: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            translation_m: [0.0, 0.0, 0.3],
            kinds: [0; MAX_HOLES],
            positions_m: [[0.0; 3]; MAX_HOLES],
            covariances_m2: [[0.0; 9]; MAX_HOLES],
        };
        p.kinds[0] = 1;
        p.kinds[1] = 2;
        p.positions_m[0] = [-0.006, 0.0, 0.3];
        p.positions_m[1] = [0.0, 0.01, 0.3];
        // sigma 0.1 mm in x, 0.2 mm in y, 1 mm in z.
        for c in &mut p.covariances_m2[..2] {
            *c = [1e-8, 0.0, 0.0, 0.0, 4e-8, 0.0, 0.0, 0.0, 1e-6];
        }
        p
    }

    #[test]
    fn ellipsoid_diameters_are_six_sigma_along_the_covariance_axes() {
        let c = Matrix3::new(4e-8, 0.0, 0.0, 0.0, 1e-6, 0.0, 0.0, 0.0, 1e-8);
        let (q, size) = ellipsoid(&c).expect("finite");
        // Each axis of the ellipsoid, turned into the camera frame, scaled by its
        // diameter: the largest (6 mm) must lie along y.
        let longest = (0..3).max_by(|&a, &b| size[a].total_cmp(&size[b])).expect("three axes");
        let axis = q * Vector3::ith(longest, 1.0);
        assert!((size[longest] - 0.006).abs() < 1e-12, "{size:?}");
        assert!(axis.y.abs() > 0.999, "{axis:?}");
        let mut sorted = [size[0], size[1], size[2]];
        sorted.sort_by(f64::total_cmp);
        assert!((sorted[0] - 0.0006).abs() < 1e-12 && (sorted[1] - 0.0012).abs() < 1e-12, "{size:?}");
        assert!(ellipsoid(&Matrix3::from_element(f64::NAN)).is_none());
    }

    #[test]
    fn scene_puts_each_hole_where_the_pose_service_did() {
        let p = poses(pose_status::OK);
        let scene = holes_scene(&p, "cam");
        let holes = scene.entities.iter().find(|e| e.id == "holes").expect("holes entity");
        assert_eq!(holes.frame_id, "cam");
        assert_eq!(holes.spheres.len(), 4, "a dot and an ellipsoid per hole");
        let dot = holes.spheres[2].pose.and_then(|p| p.position).expect("position");
        assert_eq!([dot.x, dot.y, dot.z], [0.0, 0.01, 0.3]);
        let plate = scene.entities.iter().find(|e| e.id == "plate").expect("plate entity");
        let size = plate.cubes[0].size.expect("size");
        assert!((size.x - 0.036).abs() < 1e-9 && (size.y - 0.04).abs() < 1e-9, "{size:?}");
        let stamp = holes.timestamp.expect("stamped");
        assert_eq!((stamp.sec(), stamp.nsec()), (1500, 250));
        let tf = outlet_transform(&p, "cam").expect("a pose");
        assert_eq!(tf.child_frame_id, OUTLET_FRAME);
        assert_eq!(tf.translation.map(|t| t.z), Some(0.3));
    }

    #[test]
    fn no_pose_takes_the_holes_away() {
        let mut p = poses(pose_status::PLANE_MISMATCH);
        p.hole_count = 0;
        let scene = holes_scene(&p, "cam");
        assert!(scene.entities.is_empty());
        assert_eq!(scene.deletions.len(), 2);
        assert!(outlet_transform(&p, "cam").is_none());
    }

    #[test]
    fn annotations_circle_each_hole_at_its_pixel() {
        let hole = |kind, x, sigma| HoleMsg {
            kind,
            refined: 1,
            pixel: [x, 100.0],
            score: 1.0,
            sigma_px: sigma,
            shape: [0.0; 3],
        };
        let mut d = DetectionMsg {
            schema_version: SCHEMA_VERSION,
            hole_count: 2,
            frame_id: 3,
            capture_time_ns: 5,
            score: 6,
            reserved: 0,
            detect_ms: 2.0,
            width: 640,
            height: 480,
            intrinsics: [525.0, 525.0, 320.0, 240.0],
            distortion: [0.0; 5],
            holes: [hole(0, 0.0, 0.0); MAX_HOLES],
        };
        d.holes[0] = hole(1, 200.0, 0.5);
        d.holes[1] = hole(2, 240.0, 4.0);
        let a = annotations(&d);
        assert_eq!(a.circles.len(), 2);
        let c = a.circles[1].position.expect("centre");
        assert_eq!((c.x, c.y), (240.5, 100.5), "Foxglove's origin is the corner of the first pixel");
        assert_eq!(a.circles[0].diameter, 8.0, "small sigmas still show");
        assert_eq!(a.circles[1].diameter, 24.0, "3 sigma each side");
        assert_ne!(a.circles[0].outline_color, a.circles[1].outline_color, "power and ground differ");
        assert!(a.texts[0].text.contains("2 holes"), "{}", a.texts[0].text);
        d.hole_count = 0;
        assert!(annotations(&d).texts[0].text.contains("no outlet"));
    }

    #[test]
    fn cloud_is_packed_float32_xyz() {
        let header =
            CloudHeader { schema_version: SCHEMA_VERSION, reserved: 0, frame_id: 1, capture_time_ns: 0, points: 2 };
        let xyz = [0.1f32, 0.2, 0.5, -0.1, 0.0, 0.6];
        let c = point_cloud(&header, &xyz, "cam");
        assert_eq!(c.point_stride, 12);
        assert_eq!(c.data.len(), 24);
        assert_eq!(&c.data[12..16], &(-0.1f32).to_le_bytes());
        assert_eq!(c.fields.iter().map(|f| f.offset).collect::<Vec<_>>(), [0, 4, 8]);
    }

    #[test]
    fn wall_square_lies_on_the_plane() {
        let n = Vector3::new(0.0, 0.6, 0.8);
        let p = WallPlaneMsg {
            schema_version: SCHEMA_VERSION,
            inliers: 100,
            frame_id: 1,
            capture_time_ns: 0,
            normal: [n.x, n.y, n.z],
            distance_m: 0.4,
            tangent: [[1.0, 0.0, 0.0], [0.0, 0.8, -0.6]],
            covariance: [0.0; 9],
        };
        let scene = wall_scene(&p, "cam");
        let cube = scene.entities[0].cubes[0];
        let c = cube.pose.and_then(|p| p.position).expect("centre");
        assert!((n.dot(&Vector3::new(c.x, c.y, c.z)) - 0.4).abs() < 1e-12);
        let o = cube.pose.and_then(|p| p.orientation).expect("orientation");
        let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(o.w, o.x, o.y, o.z));
        assert!((q * Vector3::z() - n).norm() < 1e-9, "the thin side along the normal");
    }
}
