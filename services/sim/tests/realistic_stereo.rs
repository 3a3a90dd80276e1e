//! The realistic-stereo family (`rs_*`): the base scene with a real stereo pair's
//! cloud (sparse, range-proportional noise, outliers, few points on the plate,
//! none over the outlet in some views, a calibration bias) and the receptacle
//! face 3-7 mm ahead of the wall, the truth following the real face.

use nalgebra::Point3;
use outlet_protocol::CameraModel;
use outlet_sim::{ground_truth, sample_scene, stereo_cloud};

fn valid(cloud: &[[f32; 3]]) -> Vec<Point3<f64>> {
    cloud.iter().filter(|p| p[0].is_finite()).map(|p| Point3::new(p[0] as f64, p[1] as f64, p[2] as f64)).collect()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

#[test]
fn a_realistic_scene_is_the_base_scene_with_another_wall_and_stereo() {
    let camera = CameraModel::default_vga();
    for index in 0..12 {
        let base = sample_scene("orange2x1", 7, index, &camera).expect("scene");
        let real = sample_scene("rs_orange2x1", 7, index, &camera).expect("scene");
        assert_eq!(base.pose, real.pose, "#{index}: the same view");
        assert_eq!(base.wall_z_mm, 5.0);
        assert!((3.0..=7.0).contains(&real.wall_z_mm), "#{index}: face {} mm ahead of the wall", real.wall_z_mm);
        // The truth's holes stay on the face; its wall moves with the face offset.
        let (tb, tr) = (ground_truth(&base, "b.png"), ground_truth(&real, "r.png"));
        for (a, b) in tb.holes.iter().zip(&tr.holes) {
            assert_eq!(a.position_m, b.position_m);
        }
        let moved = (tr.wall_plane.distance_m - tb.wall_plane.distance_m) * 1000.0;
        assert!((moved - (real.wall_z_mm - 5.0)).abs() < 1e-6, "#{index}: wall moved {moved} mm");
    }
}

#[test]
fn a_realistic_cloud_is_sparse_noisy_biased_and_may_leave_the_outlet_bare() {
    let camera = CameraModel::default_vga();
    let mut bare = 0;
    for index in 0..12 {
        let scene = sample_scene("rs_white2x2", 3, index, &camera).expect("scene");
        let model = &scene.stereo;
        let max = model.max_points.expect("realistic clouds are sparse");
        assert!((1500..=5000).contains(&max));
        let points = valid(&stereo_cloud(&scene));
        assert!(points.len() <= max && points.len() * 2 > max, "#{index}: {} points of {max}", points.len());

        // Undo the calibration bias: the wall points scatter about the true wall by
        // about the range noise (1-2% of the range; median |e| is 0.67 sigma).
        let truth = ground_truth(&scene, "x.png");
        let unbiased: Vec<f64> =
            points.iter().map(|p| truth.wall_plane.signed_distance(&(model.bias.inverse() * p)).abs() / p.z).collect();
        let spread = median(unbiased) / (0.674 * model.range_sigma_fraction);
        assert!((0.6..1.6).contains(&spread), "#{index}: median wall error {spread} of the model's");

        // With the bias, the cloud's wall is off the true one at the outlet.
        let outlet = Point3::from(scene.pose.translation.vector);
        let off = truth.wall_plane.signed_distance(&(model.bias * outlet)) - truth.wall_plane.signed_distance(&outlet);
        let shift = (model.bias * outlet - outlet).norm();
        assert!((0.5e-3..=2.0e-3 + 1e-9).contains(&shift), "#{index}: bias moves the outlet {shift} m");
        assert!(off.abs() <= shift + 1e-12);

        if let Some(r) = model.outlet_dropout_mm {
            bare += 1;
            let inv = scene.pose.inverse();
            // Outliers are moved along their rays, anywhere: only points on the wall count.
            let on_wall = points
                .iter()
                .map(|p| model.bias.inverse() * p)
                .filter(|p| truth.wall_plane.signed_distance(p).abs() < 5.0 * model.range_sigma_fraction * p.z);
            for p in on_wall {
                let q = inv * p;
                assert!(
                    (q.x * 1000.0).hypot(q.y * 1000.0) > r - 15.0,
                    "#{index}: a point {:.0} mm from the outlet, inside the bare {r:.0} mm",
                    (q.x * 1000.0).hypot(q.y * 1000.0)
                );
            }
        }
    }
    assert!((1..=9).contains(&bare), "{bare} of 12 views without points over the outlet");
}
