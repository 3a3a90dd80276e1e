//! Drawing what the detector found on the image it found it in, for a person
//! to check: `outlet detect --annotate` ([`draw_report`]) and the ROS 2
//! bridge's debug image draw with these, so both look the same. Colours are
//! those of the paper's Fig. 2: yellow power, blue ground, red background.
//! Everything is clipped to the image: marks near or past its edges are cut,
//! never a panic.

use crate::Class;
use crate::detect::DetectReport;
use image::{Rgb, RgbImage};
use nalgebra::Point2;
use outlet_protocol::HoleKind;

/// Power holes and candidates (the paper's yellow).
pub const POWER: Rgb<u8> = Rgb([255, 220, 0]);
/// Ground holes and candidates (blue).
pub const GROUND: Rgb<u8> = Rgb([40, 120, 255]);
/// Background candidates (red).
pub const BACKGROUND: Rgb<u8> = Rgb([230, 40, 40]);
/// The cross on a found hole's centre, and the "found" label.
pub const CENTRE: Rgb<u8> = Rgb([0, 255, 0]);
/// The ring around a found hole, so that it shows on any plate colour.
pub const RING: Rgb<u8> = Rgb([0, 0, 0]);
/// The "nothing found" label.
pub const NOT_FOUND: Rgb<u8> = Rgb([255, 60, 60]);
/// Radius of a found hole's circle when nothing says otherwise (pixels).
pub const HOLE_RADIUS_PX: f64 = 7.0;
/// Radius of a candidate's circle (pixels).
pub const CANDIDATE_RADIUS_PX: f64 = 2.5;
/// Half the length of the cross on a found hole (pixels).
pub const CROSS_HALF_PX: i32 = 3;

/// The colour of a class.
pub fn class_colour(class: Class) -> Rgb<u8> {
    match class {
        Class::Power => POWER,
        Class::Ground => GROUND,
        Class::Background => BACKGROUND,
    }
}

/// The colour of a hole kind.
pub fn kind_colour(kind: HoleKind) -> Rgb<u8> {
    class_colour(kind.into())
}

/// Sets the pixel nearest to (x, y) when it is in the image.
pub fn put(image: &mut RgbImage, x: f64, y: f64, colour: Rgb<u8>) {
    let (x, y) = (x.round(), y.round());
    if x >= 0.0 && y >= 0.0 && x < f64::from(image.width()) && y < f64::from(image.height()) {
        image.put_pixel(x as u32, y as u32, colour);
    }
}

/// A circle of radius `r` about `c` (one pixel wide).
pub fn draw_circle(image: &mut RgbImage, c: Point2<f64>, r: f64, colour: Rgb<u8>) {
    if !(c.x.is_finite() && c.y.is_finite() && r.is_finite()) {
        return;
    }
    // Enough steps that neighbouring samples touch; bounded for absurd radii.
    let steps = (r * 8.0).clamp(16.0, 65_536.0) as usize;
    for k in 0..steps {
        let a = k as f64 * std::f64::consts::TAU / steps as f64;
        put(image, c.x + r * a.cos(), c.y + r * a.sin(), colour);
    }
}

/// A straight line from `a` to `b`, `width` pixels wide.
pub fn draw_line(image: &mut RgbImage, a: Point2<f64>, b: Point2<f64>, width: u32, colour: Rgb<u8>) {
    if !(a.x.is_finite() && a.y.is_finite() && b.x.is_finite() && b.y.is_finite()) {
        return;
    }
    // Bounded: a line far outside the image is cut to a sane number of steps.
    let steps = (b - a).amax().ceil().clamp(1.0, 65_536.0) as usize;
    let half = (f64::from(width.max(1)) - 1.0) / 2.0;
    for k in 0..=steps {
        let p = a + (b - a) * (k as f64 / steps as f64);
        for dy in 0..width.max(1) {
            for dx in 0..width.max(1) {
                put(image, p.x - half + f64::from(dx), p.y - half + f64::from(dy), colour);
            }
        }
    }
}

/// A candidate: a small circle in its class's colour.
pub fn draw_candidate(image: &mut RgbImage, centre: Point2<f64>, class: Class) {
    draw_circle(image, centre, CANDIDATE_RADIUS_PX, class_colour(class));
}

/// A found hole: a circle of radius `radius_px` in its kind's colour, a black
/// ring one pixel outside it, and a green cross on its centre.
pub fn draw_hole(image: &mut RgbImage, pixel: Point2<f64>, kind: HoleKind, radius_px: f64) {
    draw_circle(image, pixel, radius_px, kind_colour(kind));
    draw_circle(image, pixel, radius_px + 1.0, RING);
    for d in -CROSS_HALF_PX..=CROSS_HALF_PX {
        let d = f64::from(d);
        put(image, pixel.x.floor() + d, pixel.y.floor(), CENTRE);
        put(image, pixel.x.floor(), pixel.y.floor() + d, CENTRE);
    }
}

/// The image with classified candidates (small circles), the found holes
/// ([`draw_hole`]) and a label: what `outlet detect --annotate` writes.
pub fn draw_report(image: &RgbImage, report: &DetectReport) -> RgbImage {
    let mut out = image.clone();
    for (c, class) in &report.candidates {
        draw_candidate(&mut out, c.centre, *class);
    }
    if let Some(d) = &report.detection {
        for h in &d.holes {
            draw_hole(&mut out, h.pixel, h.kind, HOLE_RADIUS_PX);
        }
        draw_text(&mut out, &format!("outlet: score {}", d.score), 6, 6, 2, CENTRE);
    } else {
        draw_text(&mut out, "no outlet", 6, 6, 2, NOT_FOUND);
    }
    out
}

/// Rows of a glyph of the 5x7 bitmap font (no font files to ship or load), 5 bits each (bit 4 = leftmost column).
///
/// Why not a real font here, as the plots of `outlet eval` have (issue 16): it would
/// be cheap in time (DejaVu Sans through `ab_glyph`: about 28 µs for a 20 px line of
/// 18 characters, less than copying the 640x480 frame the debug image starts from),
/// but this library, which every detector process and the ROS 2 bridge link, would
/// carry the font (760 KB) and a rasteriser for three short lines, and the debug
/// image's label box (`debug_image.rs`, the interop tests' "label, top left, 200 x
/// 70" that must stay the frame elsewhere) is sized by these glyphs. The labels are
/// a score, a pose mode and a frame number: the 5x7 glyphs, scaled and shadowed,
/// read well enough for that.
fn glyph(c: char) -> [u8; 7] {
    match c.to_ascii_lowercase() {
        'a' => [0x00, 0x00, 0x0E, 0x01, 0x0F, 0x11, 0x0F],
        'b' => [0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x1E],
        'c' => [0x00, 0x00, 0x0E, 0x10, 0x10, 0x11, 0x0E],
        'd' => [0x01, 0x01, 0x0D, 0x13, 0x11, 0x11, 0x0F],
        'e' => [0x00, 0x00, 0x0E, 0x11, 0x1F, 0x10, 0x0E],
        'f' => [0x06, 0x09, 0x08, 0x1C, 0x08, 0x08, 0x08],
        'g' => [0x00, 0x0F, 0x11, 0x11, 0x0F, 0x01, 0x0E],
        'h' => [0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x11],
        'i' => [0x04, 0x00, 0x0C, 0x04, 0x04, 0x04, 0x0E],
        'j' => [0x02, 0x00, 0x06, 0x02, 0x02, 0x12, 0x0C],
        'k' => [0x10, 0x10, 0x12, 0x14, 0x18, 0x14, 0x12],
        'l' => [0x0C, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E],
        'm' => [0x00, 0x00, 0x1A, 0x15, 0x15, 0x11, 0x11],
        'n' => [0x00, 0x00, 0x16, 0x19, 0x11, 0x11, 0x11],
        'o' => [0x00, 0x00, 0x0E, 0x11, 0x11, 0x11, 0x0E],
        'p' => [0x00, 0x00, 0x1E, 0x11, 0x1E, 0x10, 0x10],
        'q' => [0x00, 0x00, 0x0D, 0x13, 0x0F, 0x01, 0x01],
        'r' => [0x00, 0x00, 0x16, 0x19, 0x10, 0x10, 0x10],
        's' => [0x00, 0x00, 0x0E, 0x10, 0x0E, 0x01, 0x1E],
        't' => [0x08, 0x08, 0x1C, 0x08, 0x08, 0x09, 0x06],
        'u' => [0x00, 0x00, 0x11, 0x11, 0x11, 0x13, 0x0D],
        'v' => [0x00, 0x00, 0x11, 0x11, 0x11, 0x0A, 0x04],
        'w' => [0x00, 0x00, 0x11, 0x11, 0x15, 0x15, 0x0A],
        'x' => [0x00, 0x00, 0x11, 0x0A, 0x04, 0x0A, 0x11],
        'y' => [0x00, 0x00, 0x11, 0x11, 0x0F, 0x01, 0x0E],
        'z' => [0x00, 0x00, 0x1F, 0x02, 0x04, 0x08, 0x1F],
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        '_' => [0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x1F],
        '-' => [0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00],
        '.' => [0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C],
        ':' => [0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x0C, 0x00],
        '/' => [0x00, 0x01, 0x02, 0x04, 0x08, 0x10, 0x00],
        '%' => [0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03],
        _ => [0; 7],
    }
}

/// Draws `text` in a 5x7 bitmap font with its top-left at `(x, y)`, each font
/// pixel `scale` pixels wide. Letters are drawn in lower case; characters
/// without a glyph are blank.
pub fn draw_text(image: &mut RgbImage, text: &str, x: u32, y: u32, scale: u32, colour: Rgb<u8>) {
    let scale = scale.max(1);
    for (k, c) in text.chars().enumerate() {
        let gx = x.saturating_add((k as u32).saturating_mul(6 * scale));
        for (row, bits) in glyph(c).iter().enumerate() {
            for col in 0..5u32 {
                if bits & (0x10 >> col) == 0 {
                    continue;
                }
                for dy in 0..scale {
                    for dx in 0..scale {
                        let (px, py) = (gx.saturating_add(col * scale + dx), y.saturating_add(row as u32 * scale + dy));
                        if px < image.width() && py < image.height() {
                            image.put_pixel(px, py, colour);
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_hole_is_a_ring_in_its_colour_with_a_cross_on_its_centre() {
        let mut image = RgbImage::from_pixel(40, 40, Rgb([128, 128, 128]));
        draw_hole(&mut image, Point2::new(20.0, 20.0), HoleKind::Ground, 7.0);
        assert_eq!(*image.get_pixel(27, 20), GROUND, "on the circle");
        assert_eq!(*image.get_pixel(20, 13), GROUND);
        assert_eq!(*image.get_pixel(28, 20), RING, "the ring outside it");
        assert_eq!(*image.get_pixel(20, 20), CENTRE, "the cross");
        assert_eq!(*image.get_pixel(23, 20), CENTRE);
        assert_eq!(*image.get_pixel(24, 24), Rgb([128, 128, 128]), "inside, off the cross: untouched");
        assert_eq!(*image.get_pixel(0, 0), Rgb([128, 128, 128]));
        draw_hole(&mut image, Point2::new(5.0, 30.0), HoleKind::Power, 3.0);
        assert_eq!(*image.get_pixel(7, 32), POWER, "on its circle, off the cross");
    }

    #[test]
    fn marks_off_the_image_are_clipped() {
        let mut image = RgbImage::new(10, 10);
        draw_hole(&mut image, Point2::new(-3.0, 12.0), HoleKind::Power, 7.0);
        draw_circle(&mut image, Point2::new(f64::NAN, 1.0), 3.0, POWER);
        draw_circle(&mut image, Point2::new(5.0, 5.0), 1e12, POWER);
        draw_line(&mut image, Point2::new(-1e9, 5.0), Point2::new(1e9, 5.0), 3, POWER);
        draw_text(&mut image, "no outlet", 8, 8, 3, NOT_FOUND);
        draw_text(&mut image, "x", u32::MAX - 2, 0, 2, NOT_FOUND);
        assert!(image.pixels().any(|p| *p == POWER));
    }

    #[test]
    fn lines_join_their_ends_at_the_width_asked() {
        let mut image = RgbImage::new(20, 20);
        draw_line(&mut image, Point2::new(2.0, 3.0), Point2::new(15.0, 3.0), 1, CENTRE);
        assert!((2..=15).all(|x| *image.get_pixel(x, 3) == CENTRE));
        assert_eq!(*image.get_pixel(2, 4), Rgb([0, 0, 0]));
        draw_line(&mut image, Point2::new(10.0, 5.0), Point2::new(10.0, 18.0), 3, POWER);
        assert!((5..=18).all(|y| (9..=11).all(|x| *image.get_pixel(x, y) == POWER)));
        assert_eq!(*image.get_pixel(12, 10), Rgb([0, 0, 0]));
    }

    #[test]
    fn text_is_drawn_in_the_bitmap_font() {
        let mut image = RgbImage::new(30, 10);
        draw_text(&mut image, "1", 0, 0, 1, CENTRE);
        // '1': the top row is one pixel at column 2, the bottom row columns 1..=3.
        assert_eq!(*image.get_pixel(2, 0), CENTRE);
        assert_eq!(*image.get_pixel(0, 0), Rgb([0, 0, 0]));
        assert!((1..=3).all(|x| *image.get_pixel(x, 6) == CENTRE));
    }
}
