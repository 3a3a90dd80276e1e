//! Outlet detection after Eruhimov & Meeussen (section III of the paper), as
//! named stages on plain data: `candidates` (dark blobs at several thresholds,
//! kept by contrast), `descriptor` (one-way descriptor: power / ground /
//! background), `hashing` (geometric hashing: the one consistent outlet, or none).

pub mod annotate;
pub mod candidates;
pub mod descriptor;
pub mod detect;
pub mod hashing;
pub mod refine;
pub mod template;
pub mod track;
pub mod verify;

use nalgebra::Point2;
use serde::{Deserialize, Serialize};

/// What a hole candidate is taken for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Class {
    Power,
    Ground,
    Background,
}

impl From<outlet_protocol::HoleKind> for Class {
    fn from(kind: outlet_protocol::HoleKind) -> Self {
        match kind {
            outlet_protocol::HoleKind::Power => Class::Power,
            outlet_protocol::HoleKind::Ground => Class::Ground,
        }
    }
}

/// A small dark region surrounded by brighter ones: maybe a hole.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Candidate {
    /// Centre in the image as captured (OpenCV pixel convention).
    pub centre: Point2<f64>,
    /// Bounding box width and height (pixels).
    pub size: [u32; 2],
    /// Area (pixels) of the component.
    pub area: u32,
    /// Contrast ratio r_C of the paper's equation (1).
    pub contrast: f32,
    /// The threshold level at which the component was taken.
    pub level: u8,
}

/// The detector's grey of one colour pixel (any channel order): its brightest
/// channel, as [`grey_of`] takes it.
#[inline]
pub fn grey_of_pixel(p: &[u8]) -> u8 {
    match *p {
        // The usual pixel, without the iterator's per-element checks.
        [r, g, b] => r.max(g).max(b),
        _ => p.iter().copied().max().unwrap_or(0),
    }
}

/// Grey image for detection: the brightest channel (HSV value). Holes are dark in
/// every channel while plates of any colour are bright in at least one, so this
/// keeps hole contrast on orange, brown or white plates alike.
pub fn grey_of(image: &image::RgbImage) -> image::GrayImage {
    let (w, h) = image.dimensions();
    let rgb = image.as_raw();
    let mut data = vec![0u8; rgb.len() / 3];
    // Filled in place rather than collected: 5.7% of a VGA frame's detection
    // went to the collecting iterator.
    for (g, p) in data.iter_mut().zip(rgb.chunks_exact(3)) {
        *g = grey_of_pixel(p);
    }
    image::GrayImage::from_raw(w, h, data).unwrap_or_else(|| image::GrayImage::new(w, h))
}

/// Runs `f` with this thread's `T` from `key`: buffers a stage keeps between
/// frames instead of allocating them per call. A nested call on the same thread
/// (none today) gets fresh buffers rather than a panic.
pub(crate) fn with_scratch<T: Default + 'static, R>(
    key: &'static std::thread::LocalKey<std::cell::RefCell<T>>,
    f: impl FnOnce(&mut T) -> R,
) -> R {
    key.with(|cell| match cell.try_borrow_mut() {
        Ok(mut scratch) => f(&mut scratch),
        Err(_) => f(&mut T::default()),
    })
}

/// This thread's spare value from the pool `key` (a fresh one when it holds
/// none): for what one call may need several of at once, one per level of a
/// nesting (each pyramid level's image), or hands on to the next call (a
/// detection's holes). Give it back with [`give_spare`].
pub(crate) fn take_spare<T: Default + 'static>(key: &'static std::thread::LocalKey<std::cell::RefCell<Vec<T>>>) -> T {
    key.with(|pool| pool.try_borrow_mut().ok().and_then(|mut spares| spares.pop())).unwrap_or_default()
}

/// Puts `value` back in this thread's pool `key` for a later [`take_spare`];
/// a full pool drops it (a pool holds what one call uses at once).
pub(crate) fn give_spare<T: 'static>(key: &'static std::thread::LocalKey<std::cell::RefCell<Vec<T>>>, value: T) {
    key.with(|pool| {
        if let Ok(mut spares) = pool.try_borrow_mut()
            && spares.len() < 8
        {
            spares.push(value);
        }
    });
}
