use outlet_normal::{PlaneParams, fit_wall_plane};
use outlet_protocol::CameraModel;
fn main() {
    let (width, height) = match std::env::args().nth(1).as_deref() {
        Some("vga") => (640u32, 480u32),
        _ => (1280u32, 960u32),
    };
    let f = 525.0 * width as f64 / 640.0;
    let camera =
        CameraModel::new(width, height, [f, f, (width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0], [0.0; 5])
            .unwrap();
    let mut all = vec![];
    for index in 0..4 {
        let scene = outlet_sim::sample_scene("white2x2", 1, index, &camera).unwrap();
        let params = PlaneParams::for_stereo(f, 0.09, 0.15);
        let cloud = outlet_sim::stereo_cloud(&scene);
        let mut times = vec![];
        for _ in 0..60 {
            let t = std::time::Instant::now();
            let p = fit_wall_plane(&cloud, &params).unwrap();
            times.push(t.elapsed().as_secs_f64() * 1e3);
            std::hint::black_box(p);
        }
        times.sort_by(f64::total_cmp);
        eprintln!("{} points #{index}: min {:.3} ms median {:.3} ms", cloud.len(), times[0], times[30]);
        all.push(times[0]);
    }
}
