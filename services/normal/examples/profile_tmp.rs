use outlet_normal::{PlaneParams, fit_wall_plane};
use outlet_protocol::CameraModel;
fn main() {
    let (width, height) = (1280u32, 960u32);
    let f = 525.0 * width as f64 / 640.0;
    let camera =
        CameraModel::new(width, height, [f, f, (width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0], [0.0; 5])
            .unwrap();
    let scene = outlet_sim::sample_scene("white2x2", 1, 0, &camera).unwrap();
    let params = PlaneParams::for_stereo(f, 0.09, 0.15);
    let cloud = outlet_sim::stereo_cloud(&scene);
    for _ in 0..20 {
        let t = std::time::Instant::now();
        let p = fit_wall_plane(&cloud, &params).unwrap();
        eprintln!("total {:.2} ms inliers {}", t.elapsed().as_secs_f64() * 1e3, p.inliers);
    }
}
