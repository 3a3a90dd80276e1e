//! A result as rviz draws it: a `visualization_msgs/MarkerArray` with each
//! hole as an ellipsoid of its 3-sigma position uncertainty, the outlet's
//! plate, and the wall plane the pose was solved against. Pure functions of the
//! PoseArray [`crate::convert::poses_of`] made (and checked) from the same
//! message, the message's covariances, and the wall plane nearest in time.

use crate::convert::{Rejection, quaternion_of, ros_quaternion};
use crate::msgs::{ColorRGBA, Header, Marker, MarkerArray, Point, Pose, PoseArray, Vector3};
use crate::perception::covariance_6x6;
use nalgebra::{Matrix3, Point3, Rotation3, SymmetricEigen, UnitQuaternion, Vector3 as V3};
use outlet_detector::annotate;
use outlet_protocol::geometry::{FACE_OFFSET_MM, PLATE_1GANG_MM};
use outlet_protocol::wire::{HolePosesMsg, WallPlaneMsg};
use outlet_protocol::{HoleKind, OutletGeometry};
use std::collections::VecDeque;

/// The markers' namespaces (with `id`, a marker's name in rviz).
pub const HOLES_NS: &str = "outlet/holes";
pub const PLATE_NS: &str = "outlet/plate";
pub const WALL_NS: &str = "outlet/wall";

/// A hole's ellipsoid spans this many sigmas each way along each axis.
pub const HOLE_SIGMAS: f64 = 3.0;
/// The smallest diameter of a hole's ellipsoid (m), so that a hole known to a
/// few micrometres still shows.
pub const MIN_HOLE_DIAMETER_M: f64 = 1e-3;
/// The wall plane's square, each side (m), and its thickness.
pub const WALL_SIDE_M: f64 = 1.0;
pub const WALL_THICKNESS_M: f64 = 0.002;

/// A wall plate about its outlet's holes: its centre, the outlet's rotation
/// (outlet frame to camera frame: x right and y down seen from the front, z
/// into the wall) and its size (m), all in the camera's optical frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plate {
    /// The centre of the plate's front face (the receptacles' face).
    pub face_centre_cam_m: Point3<f64>,
    pub rotation: Rotation3<f64>,
    /// Width (outlet x) and height (outlet y).
    pub size_m: [f64; 2],
    /// From the face back to the wall (outlet z).
    pub thickness_m: f64,
}

/// What a standard wall plate adds around the holes on each side (mm, x and
/// y): a NEMA one-gang plate (70 x 114.3 mm) about the holes of the `2x1`
/// duplex. Around a `2x2`'s holes the same margins give 116.0 x 114.3 mm, a
/// two-gang plate's 116.8 x 114.3 within a millimetre.
pub fn plate_margin_mm() -> [f64; 2] {
    let holes = OutletGeometry::us_2x1().holes;
    let extent = |axis: usize| {
        let (lo, hi) = holes.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), h| {
            (lo.min(h.position_mm[axis]), hi.max(h.position_mm[axis]))
        });
        hi - lo
    };
    [(PLATE_1GANG_MM[0] - extent(0)) / 2.0, (PLATE_1GANG_MM[1] - extent(1)) / 2.0]
}

impl Plate {
    /// The plate's front face corners, clockwise seen from the front
    /// (top-left, top-right, bottom-right, bottom-left), camera frame, metres.
    pub fn corners_cam_m(&self) -> [Point3<f64>; 4] {
        let [w, h] = [self.size_m[0] / 2.0, self.size_m[1] / 2.0];
        [(-w, -h), (w, -h), (w, h), (-w, h)].map(|(x, y)| self.face_centre_cam_m + self.rotation * V3::new(x, y, 0.0))
    }

    /// The plate's box centre (half its thickness behind the face), camera frame.
    pub fn centre_cam_m(&self) -> Point3<f64> {
        self.face_centre_cam_m + self.rotation * V3::new(0.0, 0.0, self.thickness_m / 2.0)
    }
}

/// The plate of a result with a pose: the holes' extent in the outlet frame
/// plus [`plate_margin_mm`] on each side, on the holes' face plane, as thick
/// as the receptacle face stands ahead of the wall (`FACE_OFFSET_MM`). None
/// when the message has no holes or its rotation or positions are not valid.
pub fn plate_of(msg: &HolePosesMsg) -> Option<Plate> {
    let n = msg.hole_count as usize;
    let positions = msg.positions_m.get(..n).filter(|p| !p.is_empty())?;
    let rotation = quaternion_of(&msg.rotation)?.to_rotation_matrix();
    let t = V3::from(msg.translation_m);
    // The holes in the outlet frame.
    let local: Vec<V3<f64>> = positions.iter().map(|p| rotation.inverse() * (V3::from(*p) - t)).collect();
    if !local.iter().all(|p| p.iter().all(|v| v.is_finite())) || !t.iter().all(|v| v.is_finite()) {
        return None;
    }
    let lo = local.iter().fold(V3::repeat(f64::INFINITY), |m, p| m.inf(p));
    let hi = local.iter().fold(V3::repeat(f64::NEG_INFINITY), |m, p| m.sup(p));
    let face_z = local.iter().map(|p| p.z).sum::<f64>() / local.len() as f64;
    let margin = plate_margin_mm().map(|m| m / 1e3);
    let centre_local = V3::new((lo.x + hi.x) / 2.0, (lo.y + hi.y) / 2.0, face_z);
    Some(Plate {
        face_centre_cam_m: Point3::from(rotation * centre_local + t),
        rotation,
        size_m: [hi.x - lo.x + 2.0 * margin[0], hi.y - lo.y + 2.0 * margin[1]],
        thickness_m: FACE_OFFSET_MM / 1e3,
    })
}

/// A hole's 3-sigma ellipsoid from its 3x3 position covariance (m²): the
/// orientation of its principal axes (marker axes to camera frame, a proper
/// rotation) and its diameters along them, [`HOLE_SIGMAS`] x 2 x sigma, at
/// least [`MIN_HOLE_DIAMETER_M`]. None unless the covariance is one
/// ([`covariance_6x6`]'s checks).
pub fn hole_ellipsoid(covariance_m2: &[f64; 9]) -> Option<(UnitQuaternion<f64>, V3<f64>)> {
    covariance_6x6(covariance_m2)?;
    let c = Matrix3::from_row_slice(covariance_m2);
    let eigen = SymmetricEigen::new((c + c.transpose()) / 2.0);
    let mut axes = eigen.eigenvectors;
    if axes.determinant() < 0.0 {
        axes.set_column(2, &(-axes.column(2)));
    }
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(axes));
    let diameters = eigen.eigenvalues.map(|v| (2.0 * HOLE_SIGMAS * v.max(0.0).sqrt()).max(MIN_HOLE_DIAMETER_M));
    Some((rotation, diameters))
}

fn ros_point(p: &Point3<f64>) -> Point {
    Point { x: p.x, y: p.y, z: p.z }
}

/// A hole kind's colour, the debug image's ([`annotate::kind_colour`]), mostly opaque.
pub fn kind_color(kind: HoleKind) -> ColorRGBA {
    let [r, g, b] = annotate::kind_colour(kind).0.map(|c| f32::from(c) / 255.0);
    ColorRGBA { r, g, b, a: 0.9 }
}

/// The plate's colour: light grey, half transparent.
pub const PLATE_COLOR: ColorRGBA = ColorRGBA { r: 0.92, g: 0.92, b: 0.88, a: 0.6 };
/// The wall's colour: blue-grey, mostly transparent.
pub const WALL_COLOR: ColorRGBA = ColorRGBA { r: 0.45, g: 0.55, b: 0.75, a: 0.4 };

fn marker(header: &Header, ns: &str, id: i32, type_: i32, pose: Pose, scale: V3<f64>, color: ColorRGBA) -> Marker {
    Marker {
        header: header.clone(),
        ns: ns.to_string(),
        id,
        type_,
        action: Marker::ADD,
        pose,
        scale: Vector3 { x: scale.x, y: scale.y, z: scale.z },
        color,
        ..Marker::default()
    }
}

/// The wall as a thin square box centred where the plane meets the line
/// from `near` along the plane's normal (the plate's centre: the foot of the
/// outlet on the wall), its z axis the plane's normal, its x axis the plane's
/// first tangent. None when the plane is not finite or its normal is zero.
pub fn wall_pose(plane: &WallPlaneMsg, near: &Point3<f64>) -> Option<Pose> {
    let n = V3::from(plane.normal);
    let norm = n.norm();
    if !(norm > 0.0 && norm.is_finite() && plane.distance_m.is_finite()) {
        return None;
    }
    let (n, d) = (n / norm, plane.distance_m / norm);
    let foot = near - n * (n.dot(&near.coords) - d);
    // x: the first tangent made orthogonal to n (any orthogonal axis if it is not usable).
    let t = V3::from(plane.tangent[0]);
    let x = (t - n * n.dot(&t))
        .try_normalize(1e-9)
        .or_else(|| n.cross(&V3::x()).try_normalize(1e-9))
        .or_else(|| n.cross(&V3::y()).try_normalize(1e-9))?;
    let y = n.cross(&x);
    let rotation = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, n]));
    Some(Pose {
        position: ros_point(&foot),
        orientation: ros_quaternion(&UnitQuaternion::from_rotation_matrix(&rotation)),
    })
}

/// A result as rviz markers, all with the PoseArray's header (capture time,
/// camera optical frame): first a DELETEALL (what an earlier result showed
/// goes), then one SPHERE per hole in template order (ns [`HOLES_NS`], id
/// `k`) at the hole's position, scaled and turned as its [`hole_ellipsoid`],
/// in its kind's colour; a CUBE for the plate ([`plate_of`], ns
/// [`PLATE_NS`]); and with `plane`, a thin CUBE for the wall (ns [`WALL_NS`],
/// [`wall_pose`], [`WALL_SIDE_M`] square). A hole whose kind or covariance is
/// not one rejects the result, as [`crate::perception::detections_of`] does.
pub fn markers_of(
    holes: &PoseArray,
    msg: &HolePosesMsg,
    plane: Option<&WallPlaneMsg>,
) -> Result<MarkerArray, Rejection> {
    let reject = |reason: String| Rejection::Poses { frame_id: msg.frame_id, reason };
    let header = &holes.header;
    let mut markers = vec![Marker { header: header.clone(), action: Marker::DELETEALL, ..Marker::default() }];
    for (k, pose) in holes.poses.iter().enumerate() {
        let kind = match msg.kinds[k] {
            1 => HoleKind::Power,
            2 => HoleKind::Ground,
            other => return Err(reject(format!("hole {k}: kind {other}"))),
        };
        let (rotation, diameters) = hole_ellipsoid(&msg.covariances_m2[k])
            .ok_or_else(|| reject(format!("hole {k}: covariance {:?} is not one", msg.covariances_m2[k])))?;
        let at = Pose { position: pose.position, orientation: ros_quaternion(&rotation) };
        markers.push(marker(header, HOLES_NS, k as i32, Marker::SPHERE, at, diameters, kind_color(kind)));
    }
    let plate = plate_of(msg).ok_or_else(|| reject("no plate: no holes or no valid pose".into()))?;
    let orientation = ros_quaternion(&UnitQuaternion::from_rotation_matrix(&plate.rotation));
    let at = Pose { position: ros_point(&plate.centre_cam_m()), orientation };
    let size = V3::new(plate.size_m[0], plate.size_m[1], plate.thickness_m);
    markers.push(marker(header, PLATE_NS, 0, Marker::CUBE, at, size, PLATE_COLOR));
    if let Some(at) = plane.and_then(|p| wall_pose(p, &plate.face_centre_cam_m)) {
        let size = V3::new(WALL_SIDE_M, WALL_SIDE_M, WALL_THICKNESS_M);
        markers.push(marker(header, WALL_NS, 0, Marker::CUBE, at, size, WALL_COLOR));
    }
    Ok(MarkerArray { markers })
}

/// The last wall planes, to find the one of a result's moment as the pose
/// service joins them: the closest in capture time, within a maximum age.
#[derive(Debug, Clone, Default)]
pub struct RecentPlanes {
    recent: VecDeque<WallPlaneMsg>,
}

impl RecentPlanes {
    /// Planes kept (the pose service's own number).
    pub const KEEP: usize = 16;

    pub fn insert(&mut self, plane: WallPlaneMsg) {
        if self.recent.len() == Self::KEEP {
            self.recent.pop_front();
        }
        self.recent.push_back(plane);
    }

    /// The plane closest in time to `capture_time_ns`, if one is within `max_age_ms`.
    pub fn nearest(&self, capture_time_ns: u64, max_age_ms: f64) -> Option<&WallPlaneMsg> {
        self.recent
            .iter()
            .min_by_key(|p| p.capture_time_ns.abs_diff(capture_time_ns))
            .filter(|p| p.capture_time_ns.abs_diff(capture_time_ns) as f64 / 1e6 <= max_age_ms)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::convert::poses_of;
    use outlet_protocol::wire::{MAX_HOLES, SCHEMA_VERSION, pose_status};

    /// A 2x1 facing the camera 0.5 m away, turned 20 degrees about the optical
    /// axis, its holes where the template puts them.
    fn facing_2x1() -> (HolePosesMsg, Rotation3<f64>) {
        let geometry = OutletGeometry::us_2x1();
        let rotation = Rotation3::from_axis_angle(&V3::z_axis(), 20f64.to_radians());
        let t = V3::new(0.01, -0.02, 0.5);
        let mut msg = HolePosesMsg {
            schema_version: SCHEMA_VERSION,
            hole_count: geometry.holes.len() as u32,
            frame_id: 3,
            capture_time_ns: 1_700_000_000_000_000_000,
            published_ns: 0,
            mode: 3,
            status: pose_status::OK,
            outlier_mask: 0,
            reserved: 0,
            rotation: std::array::from_fn(|k| rotation[(k / 3, k % 3)]),
            translation_m: t.into(),
            kinds: [0; MAX_HOLES],
            positions_m: [[0.0; 3]; MAX_HOLES],
            covariances_m2: [[0.0; 9]; MAX_HOLES],
        };
        for (k, h) in geometry.holes.iter().enumerate() {
            let [x, y] = h.position_mm.map(|v| v / 1e3);
            msg.positions_m[k] = (rotation * V3::new(x, y, 0.0) + t).into();
            msg.kinds[k] = if h.kind == HoleKind::Power { 1 } else { 2 };
            // Sigmas 0.2, 0.3 and 1 mm along x, y, z.
            msg.covariances_m2[k] = [4e-8, 0.0, 0.0, 0.0, 9e-8, 0.0, 0.0, 0.0, 1e-6];
        }
        (msg, rotation)
    }

    fn plane(normal: [f64; 3], distance_m: f64, capture_time_ns: u64) -> WallPlaneMsg {
        WallPlaneMsg {
            schema_version: SCHEMA_VERSION,
            inliers: 1000,
            frame_id: 1,
            capture_time_ns,
            normal,
            distance_m,
            tangent: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            covariance: [0.0; 9],
        }
    }

    #[test]
    fn the_margins_make_a_one_gang_plate_of_the_2x1() {
        let [mx, my] = plate_margin_mm();
        assert!((mx - 28.65).abs() < 1e-9 && (my - 32.15).abs() < 1e-9, "{mx} {my}");
        let (msg, rotation) = facing_2x1();
        let plate = plate_of(&msg).expect("a plate");
        assert!((plate.size_m[0] - 0.070).abs() < 1e-9 && (plate.size_m[1] - 0.1143).abs() < 1e-9);
        assert_eq!(plate.thickness_m, 0.005);
        assert!((plate.rotation.matrix() - rotation.matrix()).norm() < 1e-12);
        // The holes span y from -24.05 to 25.95 mm: the plate's centre is 0.95 mm below the origin.
        let expected = rotation * V3::new(0.0, 0.00095, 0.0) + V3::new(0.01, -0.02, 0.5);
        assert!((plate.face_centre_cam_m.coords - expected).norm() < 1e-9);
        let corners = plate.corners_cam_m();
        assert!(((corners[0] - corners[1]).norm() - 0.070).abs() < 1e-9);
        assert!(((corners[1] - corners[2]).norm() - 0.1143).abs() < 1e-9);
        assert!((plate.centre_cam_m().z - 0.5025).abs() < 1e-9, "half the thickness behind the face");
        let none = HolePosesMsg { hole_count: 0, ..msg };
        assert!(plate_of(&none).is_none());
        let mut bad = msg;
        bad.rotation[0] = 2.0;
        assert!(plate_of(&bad).is_none());
    }

    #[test]
    fn each_hole_is_an_ellipsoid_of_three_sigmas_at_its_position() {
        let (msg, _) = facing_2x1();
        let (array, _) = poses_of(&msg, "cam").expect("converted");
        let wall = plane([0.0, 0.0, -1.0], -0.505, msg.capture_time_ns);
        let m = markers_of(&array, &msg, Some(&wall)).expect("markers");
        assert_eq!(m.markers[0].action, Marker::DELETEALL);
        let holes: Vec<&Marker> = m.markers.iter().filter(|m| m.ns == HOLES_NS).collect();
        assert_eq!(holes.len(), 6);
        for (k, h) in holes.iter().enumerate() {
            assert_eq!((h.id, h.type_, h.action), (k as i32, Marker::SPHERE, Marker::ADD));
            assert_eq!(h.header, array.header);
            assert_eq!(h.pose.position, array.poses[k].position, "hole {k}");
            let mut d = [h.scale.x, h.scale.y, h.scale.z];
            d.sort_by(f64::total_cmp);
            for (got, want) in d.iter().zip([1.2e-3, 1.8e-3, 6e-3]) {
                assert!((got - want).abs() < 1e-12, "hole {k}: {d:?}");
            }
            // The longest axis (6 sigma_z) is along the camera's z.
            let o = h.pose.orientation;
            let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(o.w, o.x, o.y, o.z));
            let longest = [h.scale.x, h.scale.y, h.scale.z].iter().position(|&s| s == d[2]).expect("axis");
            let axis = q * V3::from_fn(|i, _| if i == longest { 1.0 } else { 0.0 });
            assert!(axis.z.abs() > 1.0 - 1e-9, "{axis:?}");
            let color = if msg.kinds[k] == 1 { kind_color(HoleKind::Power) } else { kind_color(HoleKind::Ground) };
            assert_eq!(h.color, color);
        }
        assert_ne!(holes[0].color, holes[2].color, "power and ground differ");
        let plate = m.markers.iter().find(|m| m.ns == PLATE_NS).expect("plate");
        assert_eq!(plate.type_, Marker::CUBE);
        assert!((plate.scale.x - 0.070).abs() < 1e-9 && (plate.scale.z - 0.005).abs() < 1e-12);
        let wall = m.markers.iter().find(|m| m.ns == WALL_NS).expect("wall");
        // The plane z = 0.505 m, under the plate's face centre.
        assert!((wall.pose.position.z - 0.505).abs() < 1e-12);
        let face = plate_of(&msg).expect("plate").face_centre_cam_m;
        assert!((wall.pose.position.x - face.x).abs() < 1e-12 && (wall.pose.position.y - face.y).abs() < 1e-12);
        assert_eq!([wall.scale.x, wall.scale.y, wall.scale.z], [WALL_SIDE_M, WALL_SIDE_M, WALL_THICKNESS_M]);
        assert_eq!(markers_of(&array, &msg, None).expect("no wall").markers.len(), 1 + 6 + 1);
    }

    #[test]
    fn a_tilted_wall_is_turned_to_its_normal() {
        let n = V3::new(0.0, 0.5f64.sin(), 0.5f64.cos());
        let p = plane(n.into(), 0.6, 0);
        let pose = wall_pose(&p, &Point3::new(0.1, 0.0, 0.5)).expect("pose");
        let foot = V3::new(pose.position.x, pose.position.y, pose.position.z);
        assert!((n.dot(&foot) - 0.6).abs() < 1e-12, "on the plane");
        let o = pose.orientation;
        let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(o.w, o.x, o.y, o.z));
        assert!((q * V3::z() - n).norm() < 1e-12);
        assert!(wall_pose(&plane([0.0; 3], 1.0, 0), &Point3::origin()).is_none());
        assert!(wall_pose(&plane([0.0, 0.0, 1.0], f64::NAN, 0), &Point3::origin()).is_none());
    }

    #[test]
    fn holes_without_a_kind_or_a_covariance_reject_the_markers() {
        let (msg, _) = facing_2x1();
        let (array, _) = poses_of(&msg, "cam").expect("converted");
        let mut unknown = msg;
        unknown.kinds[4] = 7;
        assert!(matches!(markers_of(&array, &unknown, None), Err(Rejection::Poses { frame_id: 3, .. })));
        let mut nan = msg;
        nan.covariances_m2[1][8] = f64::NAN;
        assert!(markers_of(&array, &nan, None).is_err());
        // A point known exactly is drawn at the smallest size.
        let (_, d) = hole_ellipsoid(&[0.0; 9]).expect("zero is a covariance");
        assert_eq!([d.x, d.y, d.z], [MIN_HOLE_DIAMETER_M; 3]);
    }

    #[test]
    fn the_plane_nearest_in_time_is_taken_if_recent_enough() {
        let mut planes = RecentPlanes::default();
        assert!(planes.nearest(100, 1e3).is_none());
        for k in 0..(RecentPlanes::KEEP as u64 + 4) {
            planes.insert(plane([0.0, 0.0, 1.0], k as f64, k * 100_000_000));
        }
        assert_eq!(planes.nearest(1_040_000_000, 50.0).map(|p| p.distance_m), Some(10.0));
        assert_eq!(planes.nearest(1_060_000_000, 50.0).map(|p| p.distance_m), Some(11.0));
        assert!(planes.nearest(0, 50.0).is_none(), "the oldest are gone");
        assert!(planes.nearest(5_000_000_000, 200.0).is_none(), "too old");
    }
}
