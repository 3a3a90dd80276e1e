//! Labels on plots: the 5x7 bitmap font of [`outlet_detector::annotate`] (no
//! font files to ship or load) and a percent grid.

use image::{Rgb, RgbImage};

/// The bitmap font's text, shared with the detector's annotations.
pub use outlet_detector::annotate::draw_text;

/// Horizontal grid lines at 0, 25, 50, 75 and 100% of a plot `w` x `h` whose
/// top left is (x0, y0), labelled to its left.
pub fn draw_percent_grid(img: &mut RgbImage, x0: u32, y0: u32, w: u32, h: u32) {
    for k in 0..=4 {
        let y = y0 + h - h * k / 4;
        for x in x0..x0 + w {
            if x < img.width() && y < img.height() {
                img.put_pixel(x, y, Rgb([210, 210, 210]));
            }
        }
        draw_text(img, &format!("{}%", k * 25), x0.saturating_sub(34), y.saturating_sub(3), 1, Rgb([80, 80, 80]));
    }
}
