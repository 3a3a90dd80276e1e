fn main() {
    let camera = outlet_protocol::CameraModel::default_vga();
    let index: u64 = std::env::args().nth(1).unwrap().parse().unwrap();
    let scene = outlet_sim::sample_scene("fw_2x1white", 1, index / 10, &camera).unwrap();
    let frame = outlet_sim::render_frame(&scene, "x");
    frame.frame.image.save("/tmp/s18/f15130.png").unwrap();
    for h in &frame.truth.holes {
        println!("{:?}", h.pixel);
    }
    println!(
        "blur {} light {:?} off-axis {:?}",
        scene.sensor.blur_sigma,
        scene.light.position_cam_m,
        frame.truth.view.map(|v| (v.off_axis_deg, v.distance_m))
    );
}
