//! The renderer's ground truth is exact and its images show what it claims.

use nalgebra::{Point3, Vector3};
use outlet_protocol::CameraModel;
use outlet_protocol::geometry::OutletGeometry;
use outlet_sim::{SCENARIOS, render_frame, sample_scene};

const POSITIVE: [&str; 7] =
    ["fw_2x1white", "orange2x1", "whitehall2x1", "cracked2x2", "fw_2x2orange", "specular2x2", "white2x2"];

fn grey(image: &image::RgbImage, u: f64, v: f64) -> f64 {
    // Bilinear, OpenCV pixel centres.
    let (x0, y0) = (u.floor(), v.floor());
    let (tx, ty) = (u - x0, v - y0);
    let px = |x: f64, y: f64| {
        let x = x.clamp(0.0, image.width() as f64 - 1.0) as u32;
        let y = y.clamp(0.0, image.height() as f64 - 1.0) as u32;
        let p = image.get_pixel(x, y).0;
        (p[0] as f64 + p[1] as f64 + p[2] as f64) / 3.0
    };
    (px(x0, y0) * (1.0 - tx) + px(x0 + 1.0, y0) * tx) * (1.0 - ty)
        + (px(x0, y0 + 1.0) * (1.0 - tx) + px(x0 + 1.0, y0 + 1.0) * tx) * ty
}

#[test]
fn every_hole_centre_is_darker_than_the_face_around_it() {
    let camera = CameraModel::default_vga();
    for scenario in POSITIVE {
        for index in 0..10 {
            let scene = sample_scene(scenario, 3, index, &camera).expect("scene");
            let frame = render_frame(&scene, "x.png");
            let geometry = scene.geometry().expect("positive scenes hold an outlet");
            for (k, hole) in geometry.holes.iter().enumerate() {
                let [hx, hy] = hole.position_mm;
                let centre = frame.truth.holes[k].pixel;
                let inside = grey(&frame.frame.image, centre[0], centre[1]);
                // The face on a ring 5.5 mm around the hole, as the camera sees it.
                let mut ring: Vec<f64> = (0..24)
                    .filter_map(|i| {
                        let a = i as f64 * std::f64::consts::TAU / 24.0;
                        let p = Point3::new((hx + 5.5 * a.cos()) / 1000.0, (hy + 5.5 * a.sin()) / 1000.0, 0.0);
                        let px = camera.project(&(scene.pose * p))?;
                        Some(grey(&frame.frame.image, px.x, px.y))
                    })
                    .collect();
                ring.sort_by(f64::total_cmp);
                let face = ring[ring.len() / 2];
                assert!(
                    inside < face,
                    "{scenario} #{index} hole {k}: centre grey {inside:.1} not darker than face {face:.1}"
                );
            }
        }
    }
}

#[test]
fn hole_pixels_are_the_distorted_projections_of_their_positions() {
    let camera = CameraModel { distortion: [-0.25, 0.08, 0.001, -0.002, 0.0], ..CameraModel::default_vga() };
    for scenario in POSITIVE {
        let scene = sample_scene(scenario, 9, 0, &camera).expect("scene");
        let truth = outlet_sim::ground_truth(&scene, "x.png");
        let geometry = OutletGeometry::builtin(truth.template.as_deref().expect("template")).expect("builtin");
        assert_eq!(truth.holes.len(), geometry.holes.len());
        for (hole, model) in truth.holes.iter().zip(&geometry.holes) {
            assert_eq!(hole.kind, model.kind);
            let p = hole.position_m.expect("position");
            let expected = scene.pose * Point3::new(model.position_mm[0] / 1000.0, model.position_mm[1] / 1000.0, 0.0);
            assert!((Point3::from(p) - expected).norm() < 1e-12);
            // plumb_bob written out here, independently of the library.
            let [k1, k2, p1, p2, k3] = camera.distortion;
            let (x, y) = (p[0] / p[2], p[1] / p[2]);
            let r2 = x * x + y * y;
            let radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
            let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
            let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
            let (u, v) = (camera.fx * xd + camera.cx, camera.fy * yd + camera.cy);
            assert!((u - hole.pixel[0]).abs() < 1e-9 && (v - hole.pixel[1]).abs() < 1e-9);
            assert!(camera.contains(nalgebra::Point2::new(u, v), 0.0), "{scenario}: hole outside the image");
        }
    }
}

#[test]
fn views_cover_the_asked_range_and_both_mountings() {
    let camera = CameraModel::default_vga();
    let (mut up, mut down, mut far_off_axis) = (0, 0, 0.0f64);
    for index in 0..120 {
        let scene = sample_scene("white2x2", 5, index, &camera).expect("scene");
        let view = outlet_sim::truth::view(&scene);
        assert!((0.195..=0.505).contains(&view.distance_m), "distance {}", view.distance_m);
        assert!(view.off_axis_deg <= 40.0 + 1e-9, "off axis {}", view.off_axis_deg);
        far_off_axis = far_off_axis.max(view.off_axis_deg);
        if view.ground_up { up += 1 } else { down += 1 }
    }
    assert!(up >= 15 && down >= 60, "ground up {up}, down {down}");
    assert!(far_off_axis > 30.0);
}

#[test]
fn negatives_hold_no_outlet_of_the_sought_kind() {
    let camera = CameraModel::default_vga();
    let mut sought = std::collections::HashSet::new();
    for index in 0..40 {
        let scene = sample_scene("negative", 2, index, &camera).expect("scene");
        let truth = outlet_sim::ground_truth(&scene, "n.png");
        assert!(truth.template.is_none() && truth.pose.is_none() && truth.holes.is_empty());
        sought.insert(truth.search_template.clone());
        // A 2x2 holds two 2x1s, so a scene seeking 2x1 may hold no duplex at all,
        // and one seeking 2x2 no two-gang duplex.
        for plate in &scene.plates {
            if let outlet_sim::scene::Insert::Receptacles(faces) = &plate.insert {
                let limit = if truth.search_template == "2x1" { 1 } else { 2 };
                assert!(faces.len() <= limit, "#{index}: {} faces seeking {}", faces.len(), truth.search_template);
            }
        }
    }
    assert_eq!(sought.len(), 2, "both templates are sought");
}

/// A plane fitted by RANSAC then least squares: written here, not borrowed from
/// the product, so the test checks the cloud and not a fitter.
fn fit_plane(points: &[Vector3<f64>]) -> (Vector3<f64>, f64) {
    let mut rng = outlet_sim::rng::SimRng::new(11);
    let (mut best, mut best_count) = ((Vector3::z(), 0.0), 0);
    for _ in 0..300 {
        let [a, b, c] = [0, 1, 2].map(|_| points[rng.below(points.len())]);
        let Some(n) = (b - a).cross(&(c - a)).try_normalize(1e-12) else { continue };
        let d = n.dot(&a);
        let count = points.iter().filter(|p| (n.dot(p) - d).abs() < 0.002).count();
        if count > best_count {
            (best, best_count) = ((n, d), count);
        }
    }
    let inliers: Vec<_> = points.iter().filter(|p| (best.0.dot(p) - best.1).abs() < 0.001).collect();
    let centroid = inliers.iter().fold(Vector3::zeros(), |s, p| s + **p) / inliers.len() as f64;
    let cov =
        inliers.iter().fold(nalgebra::Matrix3::zeros(), |s, p| s + (**p - centroid) * (**p - centroid).transpose());
    let eig = cov.symmetric_eigen();
    let n = eig.eigenvectors.column(eig.eigenvalues.imin()).into_owned();
    (n, n.dot(&centroid))
}

#[test]
fn the_clouds_plane_is_the_ground_truth_wall() {
    let camera = CameraModel::default_vga();
    for scenario in ["fw_2x1white", "white2x2", "specular2x2", "negative"] {
        for index in 0..3 {
            let scene = sample_scene(scenario, 4, index, &camera).expect("scene");
            let frame = render_frame(&scene, "x.png");
            let finite: Vec<Vector3<f64>> = frame
                .cloud
                .iter()
                .filter(|p| p.iter().all(|v| v.is_finite()))
                .map(|p| Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64))
                .collect();
            let nan = frame.cloud.len() - finite.len();
            assert!(nan > 0 && finite.len() > 10_000, "{scenario}: {nan} NaN of {}", frame.cloud.len());
            let (n, d) = fit_plane(&finite);
            let wall = frame.truth.wall_plane;
            let n_true = Vector3::from(wall.normal);
            let sign = n.dot(&n_true).signum();
            let angle = (n * sign).dot(&n_true).clamp(-1.0, 1.0).acos().to_degrees();
            assert!(angle < 0.5, "{scenario} #{index}: normal off by {angle:.3} deg");
            assert!(
                (d * sign - wall.distance_m).abs() < 0.001,
                "{scenario} #{index}: distance {} vs {}",
                d * sign,
                wall.distance_m
            );
            // The plate stands proud: some points lie clearly in front of the wall.
            let proud = finite.iter().filter(|p| wall.distance_m - n_true.dot(p) > 0.002).count();
            assert!(proud > 200, "{scenario} #{index}: {proud} points in front of the wall");
        }
    }
}

#[test]
fn the_same_seed_renders_the_same_pixels_and_another_seed_does_not() {
    let camera = CameraModel::default_vga();
    for scenario in SCENARIOS {
        let a = render_frame(&sample_scene(scenario, 8, 1, &camera).expect("scene"), "a");
        let b = render_frame(&sample_scene(scenario, 8, 1, &camera).expect("scene"), "a");
        let c = render_frame(&sample_scene(scenario, 9, 1, &camera).expect("scene"), "a");
        assert_eq!(a.frame.image.as_raw(), b.frame.image.as_raw());
        assert_eq!(a.frame.jpeg, b.frame.jpeg);
        assert!(a.cloud.iter().zip(&b.cloud).all(|(p, q)| p.iter().zip(q).all(|(x, y)| x.to_bits() == y.to_bits())));
        assert_ne!(a.frame.image.as_raw(), c.frame.image.as_raw());
    }
}

#[test]
fn every_size_from_vga_to_full_hd_renders_with_holes_inside() {
    for (w, h) in [(640, 480), (1280, 960), (1920, 1080)] {
        let f = 525.0 * w as f64 / 640.0;
        let camera =
            CameraModel::new(w, h, [f, f, (w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0], [-0.1, 0.02, 0.0, 0.0, 0.0])
                .expect("camera");
        let scene = sample_scene("orange2x1", 1, 0, &camera).expect("scene");
        let frame = render_frame(&scene, "x");
        assert_eq!(frame.frame.image.dimensions(), (w, h));
        assert!(
            frame
                .truth
                .holes
                .iter()
                .all(|hole| camera.contains(nalgebra::Point2::new(hole.pixel[0], hole.pixel[1]), 0.0))
        );
    }
}
