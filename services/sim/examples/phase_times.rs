//! Prints where a frame's render time goes (a development aid).
use outlet_protocol::CameraModel;
use outlet_sim::{render::phase_times, sample_scene};

fn main() {
    let vga = CameraModel::default_vga();
    for i in 0..4 {
        let scene = sample_scene("white2x2", 42, i, &vga).expect("scene");
        println!("{:?}", phase_times(&scene));
    }
}
