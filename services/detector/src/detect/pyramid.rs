//! The half-resolution image and camera of the first look at large frames, and
//! the images a frame's levels and windows are made in, kept between frames.

use image::GrayImage;
use outlet_protocol::CameraModel;

thread_local! {
    /// Image buffers kept between frames: one per image in use at once (a
    /// window's crop, each half level below it).
    static IMAGES: std::cell::RefCell<Vec<Vec<u8>>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// The image at half resolution: each pixel the mean of a 2x2 block. None when
/// the image is too small to halve.
pub fn half_resolution(grey: &GrayImage) -> Option<GrayImage> {
    let (w, h) = half_size(grey)?;
    let mut out = vec![0u8; w as usize * h as usize];
    halve_into(grey, w, &mut out);
    GrayImage::from_raw(w, h, out)
}

/// [`half_resolution`] lent to `f`, made in one of this thread's buffers.
pub(super) fn with_half_resolution<R>(grey: &GrayImage, f: impl FnOnce(&GrayImage) -> R) -> Option<R> {
    let (w, h) = half_size(grey)?;
    Some(with_image(
        w,
        h,
        |out| {
            out.resize(w as usize * h as usize, 0);
            halve_into(grey, w, out);
        },
        f,
    ))
}

/// `window` (`[x, y, width, height]`, inside `grey`) of `grey` lent to `f` as an
/// image of its own, copied into one of this thread's buffers.
pub(crate) fn with_crop<R>(grey: &GrayImage, window: [u32; 4], f: impl FnOnce(&GrayImage) -> R) -> R {
    let [x, y, w, h] = window.map(|v| v as usize);
    let stride = grey.width() as usize;
    let raw = grey.as_raw();
    with_image(
        window[2],
        window[3],
        |out| {
            for row in y..y + h {
                out.extend_from_slice(&raw[row * stride + x..][..w]);
            }
        },
        f,
    )
}

/// A `width` x `height` image filled by `fill` (given an empty buffer) lent to
/// `f`: the buffer is this thread's, kept for the next image.
fn with_image<R>(width: u32, height: u32, fill: impl FnOnce(&mut Vec<u8>), f: impl FnOnce(&GrayImage) -> R) -> R {
    let mut buffer = crate::take_spare(&IMAGES);
    buffer.clear();
    fill(&mut buffer);
    // `fill` gives width x height pixels; were it not, an empty image would
    // stand in (never: both callers fill the whole image).
    let image = GrayImage::from_raw(width, height, buffer).unwrap_or_else(|| GrayImage::new(0, 0));
    let out = f(&image);
    crate::give_spare(&IMAGES, image.into_raw());
    out
}

/// The half image's size, None under 16 pixels a side.
fn half_size(grey: &GrayImage) -> Option<(u32, u32)> {
    let (w, h) = (grey.width() / 2, grey.height() / 2);
    (w >= 16 && h >= 16).then_some((w, h))
}

/// Fills `out` (`w` pixels a row) with the half image of `grey`.
fn halve_into(grey: &GrayImage, w: u32, out: &mut [u8]) {
    // Row slices, not per-pixel look-ups: on a 1567x1070 photograph the look-ups
    // cost 1 ms of a 26 ms detection (perf), the slices a fifth of that.
    let stride = grey.width() as usize;
    let raw = grey.as_raw();
    for (y, row) in out.chunks_exact_mut(w as usize).enumerate() {
        let top = &raw[2 * y * stride..][..2 * w as usize];
        let bottom = &raw[(2 * y + 1) * stride..][..2 * w as usize];
        // Blocks of 32 outputs: the rows' sum first, then pairs of it, two loops
        // the compiler turns into vector code (a pair of pairs at once does not).
        const BLOCK: usize = 32;
        let mut out_blocks = row.chunks_exact_mut(BLOCK);
        let (mut tops, mut bottoms) = (top.chunks_exact(2 * BLOCK), bottom.chunks_exact(2 * BLOCK));
        for ((o, t), b) in (&mut out_blocks).zip(&mut tops).zip(&mut bottoms) {
            let mut sum = [0u16; 2 * BLOCK];
            for ((s, &t), &b) in sum.iter_mut().zip(t).zip(b) {
                *s = u16::from(t) + u16::from(b);
            }
            for (o, pair) in o.iter_mut().zip(sum.chunks_exact(2)) {
                *o = ((pair[0] + pair[1] + 2) / 4) as u8;
            }
        }
        let rest = out_blocks.into_remainder();
        let (t, b) = (tops.remainder(), bottoms.remainder());
        for ((o, t), b) in rest.iter_mut().zip(t.chunks_exact(2)).zip(b.chunks_exact(2)) {
            let sum = u32::from(t[0]) + u32::from(t[1]) + u32::from(b[0]) + u32::from(b[1]);
            *o = ((sum + 2) / 4) as u8;
        }
    }
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
        // 20 and 75 columns: no full block of 32, and two with a remainder.
        for (width, height) in [(41, 35), (151, 35)] {
            // Scrambled, so that every rounding case (sum mod 4) occurs.
            let grey = GrayImage::from_fn(width, height, |x, y| {
                let (x, y) = (u64::from(x), u64::from(y));
                image::Luma([
                    ((((x * x * 31 + y * y * 17 + x * y * 13 + x * 5 + y * 3) * 2_654_435_761) >> 7) % 256) as u8
                ])
            });
            check_half(&grey, &half_resolution(&grey).expect("large enough"));
        }
    }

    fn check_half(grey: &GrayImage, half: &GrayImage) {
        assert_eq!(half.dimensions(), (grey.width() / 2, grey.height() / 2));
        for (x, y, p) in half.enumerate_pixels() {
            let sum: u32 = [(0, 0), (1, 0), (0, 1), (1, 1)]
                .iter()
                .map(|&(dx, dy)| u32::from(grey.get_pixel(2 * x + dx, 2 * y + dy).0[0]))
                .sum();
            assert_eq!(p.0[0], ((sum + 2) / 4) as u8, "at ({x}, {y})");
        }
        assert!(half_resolution(&GrayImage::new(31, 40)).is_none(), "under 16 px a side");
    }

    #[test]
    fn the_kept_buffers_make_the_same_images_at_any_depth() {
        let grey = GrayImage::from_fn(97, 70, |x, y| image::Luma([((x * 31 + y * 17 + x * y) % 256) as u8]));
        let half = half_resolution(&grey).expect("large enough");
        for window in [[0, 0, 97, 70], [5, 3, 40, 61], [96, 69, 1, 1], [10, 10, 0, 5]] {
            let [x, y, w, h] = window;
            let expected = image::imageops::crop_imm(&grey, x, y, w, h).to_image();
            // Twice: the second time in the buffers the first gave back.
            for _ in 0..2 {
                with_crop(&grey, window, |crop| {
                    assert_eq!(crop, &expected, "{window:?}");
                    // A level within a level takes a buffer of its own.
                    let inner = with_half_resolution(&grey, |inner| assert_eq!(inner, &half));
                    assert!(inner.is_some());
                    assert_eq!(crop, &expected, "{window:?} after the level within");
                });
            }
        }
        assert!(with_half_resolution(&GrayImage::new(40, 31), |_| ()).is_none(), "under 16 px a side");
    }
}
