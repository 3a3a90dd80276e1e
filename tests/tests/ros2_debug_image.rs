//! The bridge's debug image and rviz markers through the whole sidecar: a
//! ROS 2 participant in this test plays a camera driver (rendered scenes as
//! `sensor_msgs/Image`, their `CameraInfo` and stereo `PointCloud2`) and
//! subscribes to `/outlet/holes`, `/outlet/markers` and the debug images;
//! `outlet serve` runs detector, normal, pose and ros2-bridge. Checked: the
//! debug image is the camera's frame with the holes drawn where the detector
//! found them (which is where the scene has them), its JPEG is the same image,
//! and the markers' spheres are at the published hole positions, with the
//! plate and the wall.
//!
//! With `REGENERATE=1` it also writes `docs/ros2/debug_image.png`, the
//! bridge README's picture: a debug image as the bridge published it.
//!
//! LOOPBACK ONLY: the bridge runs with `[ros2] interfaces = ["lo"]` and this
//! test's participant likewise (a rustdds DomainParticipant whose only network
//! is 127.0.0.1, no multicast); the DDS domain id is the test process's own
//! (from its pid, in 1..=200), the iceoryx2 domain too.

use image::{Rgb, RgbImage};
use nalgebra::{Quaternion, Rotation3, UnitQuaternion, Vector3};
use outlet_detector::annotate;
use outlet_protocol::shm;
use outlet_protocol::wire::PixelFormat;
use outlet_protocol::wire::{DetectionMsg, service};
use outlet_ros2_bridge::Ros2Config;
use outlet_ros2_bridge::bridge::{self, RESULT_QOS};
use outlet_ros2_bridge::convert::{camera_info_of, cloud_of, image_of, image_of_compressed, time_to_ns};
use outlet_ros2_bridge::debug_image::{DebugImage, JPEG_QUALITY, hole_radius_px};
use outlet_ros2_bridge::markers::{HOLES_NS, PLATE_NS, WALL_NS};
use outlet_ros2_bridge::msgs::{CompressedImage, Header, Image, Marker, MarkerArray, PoseArray, Time};
use outlet_tests::{Sidecar, domain};
use std::collections::HashMap;
use std::path::Path;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

type TestResult = Result<(), Box<dyn std::error::Error>>;

fn now() -> Time {
    let ns = SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64);
    outlet_ros2_bridge::convert::ns_to_time(ns)
}

/// What came back for one capture (by its stamp, ns).
#[derive(Default)]
struct Capture {
    holes: Option<PoseArray>,
    markers: Option<MarkerArray>,
    debug: Option<Image>,
    jpeg: Option<CompressedImage>,
    detection: Option<DetectionMsg>,
}

impl Capture {
    fn complete(&self) -> bool {
        self.holes.is_some()
            && self.markers.is_some()
            && self.debug.is_some()
            && self.jpeg.is_some()
            && self.detection.is_some_and(|d| d.hole_count > 0)
    }
}

fn stamp_ns(header: &Header) -> u64 {
    time_to_ns(header.stamp).unwrap_or(0)
}

/// How many of 64 points on the circle of radius `r` about `c` have `colour`.
fn on_circle(image: &RgbImage, c: [f64; 2], r: f64, colour: Rgb<u8>) -> usize {
    (0..64)
        .filter(|k| {
            let a = *k as f64 * std::f64::consts::TAU / 64.0;
            let (x, y) = ((c[0] + r * a.cos()).round(), (c[1] + r * a.sin()).round());
            x >= 0.0 && y >= 0.0 && image.get_pixel_checked(x as u32, y as u32) == Some(&colour)
        })
        .count()
}

#[test]
fn the_debug_image_shows_the_holes_where_they_are_and_the_markers_sit_on_the_published_holes() -> TestResult {
    let domain = domain("ros2-debug");
    let mut sidecar = Sidecar::new(&domain)?;
    let dds_domain = (1 + std::process::id() % 200) as u16;
    let config = sidecar.write_ros2_loopback_config(u32::from(dds_domain), "camera_optical_frame")?;
    for service in ["normal", "pose", "detector", "ros2-bridge"] {
        sidecar.start_with_config(&config, service, &[])?;
    }
    // The detections, read beside the bridge: where the holes were drawn.
    let node = shm::node(&domain, "test")?;
    let detection_sub = shm::messages::<DetectionMsg>(&node, service::DETECTIONS)?.subscriber_builder().create()?;

    // Scenes of a white 2x1, as a camera driver with a registered depth camera sends them.
    let scenes: Vec<_> = (0..4)
        .map(|index| {
            let scene =
                outlet_sim::sample_scene("fw_2x1white", 1, index, &outlet_protocol::CameraModel::default_vga())?;
            Ok::<_, Box<dyn std::error::Error>>((scene.camera, outlet_sim::render_frame(&scene, "debug")))
        })
        .collect::<Result<_, _>>()?;

    let ros2 = Ros2Config { domain_id: dds_domain, interfaces: vec!["lo".into()], ..Ros2Config::default() };
    let topics = &ros2.topics;
    let context = bridge::context(&ros2)?;
    let mut peer = bridge::node(&context, "debug_image_test")?;
    let image_pub = bridge::publisher::<Image>(&mut peer, &topics.image, &RESULT_QOS)?;
    let info_pub =
        bridge::publisher::<outlet_ros2_bridge::msgs::CameraInfo>(&mut peer, &topics.camera_info, &RESULT_QOS)?;
    let cloud_pub = bridge::publisher::<outlet_ros2_bridge::msgs::PointCloud2>(&mut peer, &topics.points, &RESULT_QOS)?;
    let holes_sub = bridge::subscription::<PoseArray>(&mut peer, &topics.holes, &RESULT_QOS)?;
    let markers_sub = bridge::subscription::<MarkerArray>(&mut peer, &topics.markers, &RESULT_QOS)?;
    let debug_sub = bridge::subscription::<Image>(&mut peer, &topics.debug_image, &RESULT_QOS)?;
    let jpeg_sub = bridge::subscription::<CompressedImage>(&mut peer, &topics.debug_image_compressed, &RESULT_QOS)?;

    let mut captures: HashMap<u64, Capture> = HashMap::new();
    // The scene each capture showed.
    let mut shown: HashMap<u64, usize> = HashMap::new();
    let started = Instant::now();
    let mut next_send = Instant::now();
    let mut sent = 0usize;
    let done = loop {
        if let Some(service) = sidecar.dead() {
            return Err(format!("the service {service} died (logs in {})", sidecar.logs.display()).into());
        }
        if started.elapsed() > Duration::from_secs(120) {
            break None;
        }
        if Instant::now() >= next_send {
            let k = sent % scenes.len();
            let (camera, rendered) = &scenes[k];
            let header = Header { stamp: now(), frame_id: "camera_optical_frame".into() };
            let rgb = rendered.frame.image.as_raw();
            let image = image_of(header.clone(), camera.width, camera.height, rgb, PixelFormat::Rgb8, camera.width * 3)
                .ok_or("the rendered image")?;
            let _ = info_pub.publish(camera_info_of(camera, header.clone()));
            let _ = cloud_pub.publish(cloud_of(header.clone(), &rendered.cloud));
            let _ = image_pub.publish(image);
            shown.insert(stamp_ns(&header), k);
            sent += 1;
            next_send = Instant::now() + Duration::from_millis(400);
        }
        while let Ok(Some((m, _))) = holes_sub.take() {
            let at = stamp_ns(&m.header);
            captures.entry(at).or_default().holes = Some(m);
        }
        while let Ok(Some((m, _))) = markers_sub.take() {
            if let Some(at) = m.markers.first().map(|first| stamp_ns(&first.header)) {
                captures.entry(at).or_default().markers = Some(m);
            }
        }
        while let Ok(Some((m, _))) = debug_sub.take() {
            let at = stamp_ns(&m.header);
            captures.entry(at).or_default().debug = Some(m);
        }
        while let Ok(Some((m, _))) = jpeg_sub.take() {
            let at = stamp_ns(&m.header);
            captures.entry(at).or_default().jpeg = Some(m);
        }
        while let Ok(Some(d)) = detection_sub.receive() {
            captures.entry(d.payload().capture_time_ns).or_default().detection = Some(*d.payload());
        }
        let mut complete: Vec<u64> = captures.iter().filter(|(_, c)| c.complete()).map(|(&stamp, _)| stamp).collect();
        complete.sort();
        let mut scenes_seen: Vec<usize> = complete.iter().map(|stamp| shown[stamp]).collect();
        scenes_seen.sort();
        scenes_seen.dedup();
        if scenes_seen.len() >= SCENES_CHECKED {
            break Some(complete);
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let complete = done.ok_or_else(|| {
        format!(
            "not {SCENES_CHECKED} scenes with holes, markers, a debug image and its JPEG in 120 s ({sent} sent; {} \
             complete, {} debug images, {} hole poses came; logs in {})",
            captures.values().filter(|c| c.complete()).count(),
            captures.values().filter(|c| c.debug.is_some()).count(),
            captures.values().filter(|c| c.holes.is_some()).count(),
            sidecar.logs.display()
        )
    })?;
    let mut pictures = None;
    for &stamp in &complete {
        let (camera, rendered) = &scenes[shown[&stamp]];
        let checked = check(&captures[&stamp], stamp, camera, rendered).map_err(|e| {
            format!("capture {stamp} (scene {}): {e} (logs in {})", shown[&stamp], sidecar.logs.display())
        })?;
        pictures = pictures.or(Some(checked));
    }
    let (drawn, markers) = pictures.ok_or("no capture checked")?;
    // The first capture checked: the pictures.
    eprintln!("{} captures of {SCENES_CHECKED} scenes checked", complete.len());

    // The pictures of the bridge's README: the debug image about the outlet
    // (a whole noisy frame is a large PNG) and the markers as rviz draws them.
    let picture = about_the_outlet(&drawn);
    let scene = markers_picture(&markers)?;
    for (name, image) in [("debug_image.png", &picture), ("markers.png", &scene)] {
        image.save(sidecar.logs.join(name))?;
    }
    eprintln!("debug image and markers of capture {} in {}", complete[0], sidecar.logs.display());
    if std::env::var_os("REGENERATE").is_some() {
        let docs = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/ros2");
        std::fs::create_dir_all(&docs)?;
        for (name, image) in [("debug_image.png", &picture), ("markers.png", &scene)] {
            let path = docs.join(name);
            image.save(&path)?;
            let bytes = std::fs::metadata(&path)?.len();
            assert!(bytes < 300_000, "{} is {bytes} bytes", path.display());
            eprintln!("wrote {} ({bytes} bytes)", path.display());
        }
    }
    Ok(())
}

/// Scenes whose debug image, JPEG, hole poses and markers are each checked.
const SCENES_CHECKED: usize = 4;

/// Checks one capture's debug image, JPEG and markers against the scene it
/// showed; the debug image and the markers, for the pictures.
fn check(
    capture: &Capture,
    stamp: u64,
    camera: &outlet_protocol::CameraModel,
    rendered: &outlet_sim::RenderedFrame,
) -> Result<(RgbImage, MarkerArray), Box<dyn std::error::Error>> {
    let (Some(holes), Some(markers), Some(debug), Some(jpeg), Some(detection)) =
        (&capture.holes, &capture.markers, &capture.debug, &capture.jpeg, &capture.detection)
    else {
        return Err("not complete".into());
    };

    // The debug image: the camera's frame, rgb8, stamped with its capture time.
    assert_eq!((debug.width, debug.height, debug.encoding.as_str()), (camera.width, camera.height, "rgb8"));
    assert_eq!(debug.header, holes.header);
    let drawn = RgbImage::from_raw(debug.width, debug.height, debug.data.clone()).ok_or("debug image size")?;
    // Each hole drawn where the detector found it, which is where the scene has it.
    let truth = &rendered.truth.holes;
    assert_eq!(detection.hole_count as usize, truth.len());
    for (k, (h, t)) in detection.holes.iter().zip(truth).enumerate() {
        let off = ((h.pixel[0] - t.pixel[0]).powi(2) + (h.pixel[1] - t.pixel[1]).powi(2)).sqrt();
        assert!(off < 1.5, "hole {k} found {off:.2} px from where it is");
        let colour = if h.kind == 1 { annotate::POWER } else { annotate::GROUND };
        let ring = on_circle(&drawn, h.pixel, hole_radius_px(h.sigma_px), colour);
        assert!(ring >= 24, "hole {k}: {ring} of 64 points of its circle in its colour");
        let centre = drawn.get_pixel(h.pixel[0].floor() as u32, h.pixel[1].floor() as u32);
        assert_eq!(*centre, annotate::CENTRE, "hole {k}: the cross on its centre");
    }
    // Away from the outlet and the label, the frame as the camera sent it.
    let (cx, cy) =
        (truth.iter().map(|t| t.pixel[0]).sum::<f64>() / 6.0, truth.iter().map(|t| t.pixel[1]).sum::<f64>() / 6.0);
    let far: Vec<(u32, u32)> = (0..camera.height)
        .flat_map(|y| (0..camera.width).map(move |x| (x, y)))
        .filter(|&(x, y)| (x as f64 - cx).hypot(y as f64 - cy) > 150.0 && (y > 60 || x > 260))
        .collect();
    let same = far.iter().filter(|&&(x, y)| drawn.get_pixel(x, y) == rendered.frame.image.get_pixel(x, y)).count();
    assert!(same as f64 > 0.99 * far.len() as f64, "{same} of {} pixels away from the outlet unchanged", far.len());
    assert!(drawn.pixels().any(|p| *p == outlet_ros2_bridge::debug_image::OUTLINE), "the plate's outline");

    // The JPEG is the same picture: the bytes this build's encoder makes of the rgb8 image.
    assert_eq!(jpeg.header, debug.header);
    assert_eq!(jpeg.format, outlet_ros2_bridge::debug_image::JPEG_FORMAT);
    let decoded = image_of_compressed(jpeg)?;
    assert_eq!((decoded.width, decoded.height), (debug.width, debug.height));
    let again = DebugImage { frame_id: detection.frame_id, capture_time_ns: stamp, rgb: drawn.clone() };
    assert!(again.to_jpeg("camera_optical_frame", JPEG_QUALITY)?.data == jpeg.data, "the JPEG is the debug image's");

    // The markers: a sphere on each published hole, the plate, the wall.
    assert_eq!(markers.markers[0].action, Marker::DELETEALL);
    let spheres: Vec<&Marker> = markers.markers.iter().filter(|m| m.ns == HOLES_NS).collect();
    assert_eq!(spheres.len(), holes.poses.len());
    for (k, (s, p)) in spheres.iter().zip(&holes.poses).enumerate() {
        assert_eq!((s.id, s.type_), (k as i32, Marker::SPHERE));
        assert_eq!(s.pose.position, p.position, "hole {k}");
        assert_eq!(s.header, holes.header);
        // Within a millimetre of where the scene has the hole.
        let t = truth[k].position_m.ok_or("a hole without a position")?;
        let d = ((p.position.x - t[0]).powi(2) + (p.position.y - t[1]).powi(2) + (p.position.z - t[2]).powi(2)).sqrt();
        assert!(d < 1e-3, "hole {k} {d} m from the truth");
    }
    assert!(markers.markers.iter().any(|m| m.ns == PLATE_NS && m.type_ == Marker::CUBE));
    let wall = markers.markers.iter().find(|m| m.ns == WALL_NS).ok_or("the wall marker")?;
    let plane = rendered.truth.wall_plane;
    let w = [wall.pose.position.x, wall.pose.position.y, wall.pose.position.z];
    let on_plane = (0..3).map(|i| plane.normal[i] * w[i]).sum::<f64>() - plane.distance_m;
    assert!(on_plane.abs() < 5e-3, "the wall marker {on_plane} m off the scene's wall");

    Ok((drawn, markers.clone()))
}

/// The part of a debug image with the label and the plate's outline (40 px
/// about them), or about the outline alone when the two are far apart.
fn about_the_outlet(drawn: &RgbImage) -> RgbImage {
    let outline: Vec<(u32, u32)> = drawn
        .enumerate_pixels()
        .filter(|(_, _, p)| **p == outlet_ros2_bridge::debug_image::OUTLINE)
        .map(|(x, y, _)| (x, y))
        .collect();
    let (w, h) = drawn.dimensions();
    let x0 = outline.iter().map(|p| p.0).min().unwrap_or(0).saturating_sub(40);
    let y0 = outline.iter().map(|p| p.1).min().unwrap_or(0).saturating_sub(40);
    let x1 = (outline.iter().map(|p| p.0).max().unwrap_or(w) + 40).min(w);
    let y1 = (outline.iter().map(|p| p.1).max().unwrap_or(h) + 40).min(h);
    // With the label (top left, 200 x 70) when that keeps it within half the frame.
    let (lx1, ly1) = (x1.max(200), y1.max(70));
    let (x0, y0, x1, y1) = if lx1 * ly1 <= w * h / 2 { (0, 0, lx1, ly1) } else { (x0, y0, x1, y1) };
    image::imageops::crop_imm(drawn, x0, y0, x1 - x0, y1 - y0).to_image()
}

/// The markers from 16 cm (the outlet) and from 4 cm (the upper
/// receptacle's holes, their 3-sigma ellipsoids), side by side.
fn markers_picture(markers: &MarkerArray) -> Result<RgbImage, String> {
    let centre = |m: &Marker| Vector3::new(m.pose.position.x, m.pose.position.y, m.pose.position.z);
    let plate = markers.markers.iter().find(|m| m.ns == PLATE_NS).ok_or("no plate")?;
    let upper: Vec<Vector3<f64>> = markers.markers.iter().filter(|m| m.ns == HOLES_NS).take(3).map(centre).collect();
    let receptacle = upper.iter().sum::<Vector3<f64>>() / upper.len().max(1) as f64;
    let (w, h) = (360, 360);
    let mut picture = RgbImage::new(2 * w + 4, h);
    for (k, view) in [
        render_markers(&markers.markers, centre(plate), 0.16, w, h),
        render_markers(&markers.markers, receptacle, 0.04, w, h),
    ]
    .iter()
    .enumerate()
    {
        // Most of each view shows something other than the background.
        let shown = view.pixels().filter(|p| **p != BACKGROUND).count();
        if shown < (w * h / 2) as usize {
            return Err(format!("view {k}: {shown} pixels show markers"));
        }
        image::imageops::replace(&mut picture, view, i64::from(k as u32 * (w + 4)), 0);
    }
    Ok(picture)
}

/// rviz's background.
const BACKGROUND: Rgb<u8> = Rgb([48, 48, 48]);

/// A triangle of a marker's surface (camera frame), its colour and opacity.
struct Triangle {
    vertices: [Vector3<f64>; 3],
    colour: [f64; 3],
    alpha: f64,
}

/// The surface of a CUBE or SPHERE marker as triangles (other types: none).
fn triangles_of(m: &Marker) -> Vec<Triangle> {
    let o = m.pose.orientation;
    let rotation = UnitQuaternion::from_quaternion(Quaternion::new(o.w, o.x, o.y, o.z));
    let centre = Vector3::new(m.pose.position.x, m.pose.position.y, m.pose.position.z);
    let half = Vector3::new(m.scale.x, m.scale.y, m.scale.z) / 2.0;
    let place = |v: Vector3<f64>| centre + rotation * v.component_mul(&half);
    let colour = [m.color.r, m.color.g, m.color.b].map(f64::from);
    let alpha = f64::from(m.color.a);
    let quad = |a, b, c, d| [[a, b, c], [a, c, d]];
    let mut faces: Vec<[Vector3<f64>; 3]> = Vec::new();
    match m.type_ {
        Marker::CUBE => {
            let corner = |k: usize| {
                Vector3::new(
                    if k & 1 == 0 { -1.0 } else { 1.0 },
                    if k & 2 == 0 { -1.0 } else { 1.0 },
                    if k & 4 == 0 { -1.0 } else { 1.0 },
                )
            };
            // Each face in 16 x 16 pieces: a piece behind the eye is left out, not the whole face.
            let n = 16;
            for [a, b, c, d] in [[0, 1, 3, 2], [4, 5, 7, 6], [0, 1, 5, 4], [2, 3, 7, 6], [0, 2, 6, 4], [1, 3, 7, 5]] {
                let (a, b, d) = (corner(a), corner(b), corner(d));
                let (u, v) = ((b - a) / n as f64, (d - a) / n as f64);
                debug_assert_eq!(corner(c), a + u * n as f64 + v * n as f64);
                for i in 0..n {
                    for j in 0..n {
                        let p = a + u * i as f64 + v * j as f64;
                        faces.extend(quad(p, p + u, p + u + v, p + v));
                    }
                }
            }
        }
        Marker::SPHERE => {
            let (rings, segments) = (12, 24);
            let at = |i: usize, j: usize| {
                let (theta, phi) = (
                    std::f64::consts::PI * i as f64 / rings as f64,
                    std::f64::consts::TAU * j as f64 / segments as f64,
                );
                Vector3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos())
            };
            for i in 0..rings {
                for j in 0..segments {
                    faces.extend(quad(at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)));
                }
            }
        }
        _ => {}
    }
    faces.into_iter().map(|f| Triangle { vertices: f.map(place), colour, alpha }).collect()
}

/// The markers as rviz draws them (flat-shaded, lit from the eye), seen from
/// beside and above the camera, `distance_m` from `target`: a z-buffered
/// rasterisation, each surface's opacity blended over rviz's background.
fn render_markers(markers: &[Marker], target: Vector3<f64>, distance_m: f64, width: u32, height: u32) -> RgbImage {
    // Toward the camera, turned 40 degrees to the side and 25 up.
    let back = Rotation3::from_axis_angle(&Vector3::x_axis(), 25f64.to_radians())
        * Rotation3::from_axis_angle(&Vector3::y_axis(), 40f64.to_radians())
        * (-target.normalize());
    let eye = target + back * distance_m;
    let forward = (target - eye).normalize();
    let right = Vector3::new(0.0, 1.0, 0.0).cross(&forward).normalize();
    let down = forward.cross(&right);
    let f = 0.9 * f64::from(width);
    let view = |p: &Vector3<f64>| {
        let d = p - eye;
        Vector3::new(right.dot(&d), down.dot(&d), forward.dot(&d))
    };
    let mut image = RgbImage::from_pixel(width, height, BACKGROUND);
    let mut depth = vec![f64::INFINITY; (width * height) as usize];
    for t in markers.iter().flat_map(triangles_of) {
        let v = t.vertices.map(|p| view(&p));
        if v.iter().any(|p| p.z < 0.01) {
            continue;
        }
        let s = v.map(|p| (f * p.x / p.z + f64::from(width) / 2.0, f * p.y / p.z + f64::from(height) / 2.0));
        let area = (s[1].0 - s[0].0) * (s[2].1 - s[0].1) - (s[2].0 - s[0].0) * (s[1].1 - s[0].1);
        if area.abs() < 1e-12 {
            continue;
        }
        let normal = (t.vertices[1] - t.vertices[0]).cross(&(t.vertices[2] - t.vertices[0])).normalize();
        let light = 0.35 + 0.65 * normal.dot(&forward).abs();
        let x0 = s.iter().map(|p| p.0).fold(f64::INFINITY, f64::min).max(0.0).floor() as u32;
        let x1 = s.iter().map(|p| p.0).fold(f64::NEG_INFINITY, f64::max).min(f64::from(width - 1)).ceil() as u32;
        let y0 = s.iter().map(|p| p.1).fold(f64::INFINITY, f64::min).max(0.0).floor() as u32;
        let y1 = s.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max).min(f64::from(height - 1)).ceil() as u32;
        for y in y0..=y1 {
            for x in x0..=x1 {
                let (px, py) = (f64::from(x) + 0.5, f64::from(y) + 0.5);
                let w0 = ((s[1].0 - px) * (s[2].1 - py) - (s[2].0 - px) * (s[1].1 - py)) / area;
                let w1 = ((s[2].0 - px) * (s[0].1 - py) - (s[0].0 - px) * (s[2].1 - py)) / area;
                let w2 = 1.0 - w0 - w1;
                if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                    continue;
                }
                // 1/z is linear on the screen.
                let z = 1.0 / (w0 / v[0].z + w1 / v[1].z + w2 / v[2].z);
                let k = (y * width + x) as usize;
                if z >= depth[k] {
                    continue;
                }
                depth[k] = z;
                let rgb = std::array::from_fn(|c| {
                    let lit = 255.0 * t.colour[c] * light;
                    (t.alpha * lit + (1.0 - t.alpha) * f64::from(BACKGROUND.0[c])).clamp(0.0, 255.0) as u8
                });
                image.put_pixel(x, y, Rgb(rgb));
            }
        }
    }
    image
}
