//! The half-resolution image and camera of the first look at large frames.

use image::GrayImage;
use outlet_protocol::CameraModel;

/// The image at half resolution: each pixel the mean of a 2x2 block. None when
/// the image is too small to halve.
pub fn half_resolution(grey: &GrayImage) -> Option<GrayImage> {
    let (w, h) = (grey.width() / 2, grey.height() / 2);
    if w < 16 || h < 16 {
        return None;
    }
    // Row slices, not per-pixel look-ups: on a 1567x1070 photograph the look-ups
    // cost 1 ms of a 26 ms detection (perf), the slices a fifth of that.
    let stride = grey.width() as usize;
    let raw = grey.as_raw();
    let mut out = vec![0u8; w as usize * h as usize];
    for (y, row) in out.chunks_exact_mut(w as usize).enumerate() {
        let top = &raw[2 * y * stride..][..2 * w as usize];
        let bottom = &raw[(2 * y + 1) * stride..][..2 * w as usize];
        for ((o, t), b) in row.iter_mut().zip(top.chunks_exact(2)).zip(bottom.chunks_exact(2)) {
            let sum = u32::from(t[0]) + u32::from(t[1]) + u32::from(b[0]) + u32::from(b[1]);
            *o = ((sum + 2) / 4) as u8;
        }
    }
    GrayImage::from_raw(w, h, out)
}

/// The camera of the half-resolution image: focal lengths halved, the principal
/// point where the same ray lands (OpenCV pixel centres), the same distortion.
pub(super) fn half_camera(camera: &CameraModel, width: u32, height: u32) -> Option<CameraModel> {
    // Checked as a camera of its own size, unless it is a window cut from a
    // checked camera's frame (its principal point may lie far outside it).
    let half = CameraModel {
        width,
        height,
        fx: camera.fx / 2.0,
        fy: camera.fy / 2.0,
        cx: (camera.cx - 0.5) / 2.0,
        cy: (camera.cy - 0.5) / 2.0,
        distortion: camera.distortion,
    };
    let finite = [half.fx, half.fy, half.cx, half.cy].iter().all(|v| v.is_finite());
    (finite && half.fx >= 0.5 && half.fy >= 0.5 && width > 0 && height > 0).then_some(half)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_half_image_is_the_mean_of_each_2x2_block_rounded() {
        // Odd sides: the last row and column have no partner and are left out.
        let grey = GrayImage::from_fn(41, 35, |x, y| image::Luma([((x * 73 + y * 151 + x * y * 7) % 256) as u8]));
        let half = half_resolution(&grey).expect("large enough");
        assert_eq!(half.dimensions(), (20, 17));
        for (x, y, p) in half.enumerate_pixels() {
            let sum: u32 = [(0, 0), (1, 0), (0, 1), (1, 1)]
                .iter()
                .map(|&(dx, dy)| u32::from(grey.get_pixel(2 * x + dx, 2 * y + dy).0[0]))
                .sum();
            assert_eq!(p.0[0], ((sum + 2) / 4) as u8, "at ({x}, {y})");
        }
        assert!(half_resolution(&GrayImage::new(31, 40)).is_none(), "under 16 px a side");
    }
}
