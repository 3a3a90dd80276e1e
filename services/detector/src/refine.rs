//! Beyond the paper: sub-pixel hole centres. Each hole's known outline (a slot or
//! a round ground hole), mapped into the image by the local linearisation of the
//! outlet-to-image map, is fitted to the pixels around it: the image is modelled as
//! the face's level outside the outline and a linear ramp inside it (the hole's
//! side wall on one side, its dark floor on the other, as the viewing angle
//! shows them). The outline's offset that best explains the pixels is the centre.

use image::GrayImage;
use nalgebra::{Matrix2, Matrix4, Point2, Vector2, Vector4};
use outlet_protocol::geometry::{GROUND_DIAMETER_MM, HOT_SLOT_MM, HoleKind, NEUTRAL_SLOT_MM, SLOT_PITCH_MM};

/// The outline of a hole in the outlet plane (mm, centred on the hole's centre).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HoleShape {
    /// A blade slot: width across x, length along y of the outlet frame.
    Slot { width_mm: f64, length_mm: f64 },
    /// A round hole, with a flat this far from its centre towards -y (the slots).
    Round { diameter_mm: f64, flat_mm: f64 },
}

impl HoleShape {
    /// The outlines of a US geometry's holes: in each receptacle (neutral, hot,
    /// ground) the power hole further left is the long neutral slot.
    pub fn us_outlines(geometry: &outlet_protocol::OutletGeometry) -> Vec<HoleShape> {
        let holes = &geometry.holes;
        holes
            .iter()
            .map(|h| match h.kind {
                HoleKind::Ground => HoleShape::Round { diameter_mm: GROUND_DIAMETER_MM, flat_mm: 1.6 },
                HoleKind::Power => {
                    // The other slot of the same receptacle: same row, a pitch away.
                    let partner = holes.iter().find(|o| {
                        o.kind == HoleKind::Power
                            && (o.position_mm[1] - h.position_mm[1]).abs() < 0.5
                            && ((o.position_mm[0] - h.position_mm[0]).abs() - SLOT_PITCH_MM).abs() < 1.0
                    });
                    let neutral = partner.is_none_or(|o| o.position_mm[0] > h.position_mm[0]);
                    let [width_mm, length_mm] = if neutral { NEUTRAL_SLOT_MM } else { HOT_SLOT_MM };
                    HoleShape::Slot { width_mm, length_mm }
                }
            })
            .collect()
    }

    /// Signed distance to the outline (mm, negative inside).
    #[inline]
    fn sd(&self, q: Vector2<f64>) -> f64 {
        match *self {
            HoleShape::Slot { width_mm, length_mm } => {
                let (dx, dy) = (q.x.abs() - width_mm / 2.0, q.y.abs() - length_mm / 2.0);
                (dx.max(0.0).powi(2) + dy.max(0.0).powi(2)).sqrt() + dx.max(dy).min(0.0)
            }
            HoleShape::Round { diameter_mm, flat_mm } => (q.norm() - diameter_mm / 2.0).max(-q.y - flat_mm),
        }
    }

    /// Half extent (mm) of a box around the outline.
    fn half_extent(&self) -> [f64; 2] {
        match *self {
            HoleShape::Slot { width_mm, length_mm } => [width_mm / 2.0, length_mm / 2.0],
            HoleShape::Round { diameter_mm, .. } => [diameter_mm / 2.0, diameter_mm / 2.0],
        }
    }
}

/// Parameters of the sub-pixel fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefineParams {
    /// Face around the outline taken into the fit (mm).
    pub margin_mm: f64,
    /// Gauss-Newton iterations on the offset.
    pub iterations: usize,
    /// The fit is refused if it moves the centre further than this (pixels).
    pub max_shift_px: f64,
    /// The opening must be at least this much darker than the face around it,
    /// as a fraction of the face's grey level: a predicted hole on a blank plate
    /// fits noise, not an opening.
    pub min_relative_contrast: f64,
    /// Where the face around a hole shows at least this grey level it is
    /// clipped (glare, over-exposure): its level says nothing of how much
    /// brighter it is, and a share of it understates an opening's contrast;
    /// [`Self::min_relative_contrast`] is then asked at
    /// [`Self::clipped_contrast_share`] of itself.
    pub clipped_face_level: f64,
    /// See [`Self::clipped_face_level`]. On a rendered approach with a
    /// receptacle in a specular highlight, its slots showed 11-19 grey levels
    /// below a face at 255 (relative 0.044-0.074) while clearly there; in Table
    /// I's specular2x2 view 1 a slot 6 levels below it (0.024) was under half of
    /// the faint look's 0.05, and a clipped face has no noise to be taken for an
    /// opening: 0.4 (0.5 before).
    pub clipped_contrast_share: f64,
    /// The centre's standard deviation (pixels per axis) is never taken below
    /// this: the outline model itself is no better than that on real holes.
    pub min_sigma_px: f64,
    /// The Gauss-Newton standard deviation times this (and times
    /// [`edge_sigma_factor`] of the edge's width) is the reported one. The
    /// normal equations take every pixel's residual as independent; blur and
    /// interpolation correlate neighbours, and the outline is not the exact hole,
    /// so the plain figure is too small. 4.5 alone made the RMS of error over sigma
    /// 1 on rendered scenes of every scenario, but 0.87 on sharp holes and 1.27 on
    /// blurred ones; with the edge's factor 4.1 kept the overall figure and made
    /// it even across edge widths (`tests/sigma.rs`; plain: 2.8). With
    /// [`Self::outline_sigma_mm`] beside it, 3.3 (session 11). With the soft
    /// first fit ([`Self::rough_edge_px`]) the holes' error tail shrank and 3.3
    /// left the pose NEES means at 0.55-0.58 of 3; 3.0 brings them to 0.61-0.64
    /// with fewer holes beyond the 99.9% bound than 3.3 had before. 2.7 (session
    /// 16) gave 0.67-0.79 in every mode and told mono's worst frame ambiguous,
    /// but the white2x2 demo's frame 95 (every hole 2 mm off along the normal,
    /// 4.6 sigma at 3.0) went beyond 5 sigma: a shared scale error of the
    /// holes is not in their own sigmas, and 3.0 is what covers it.
    pub sigma_scale: f64,
    /// A window with more pixels than this is sampled every k-th pixel in each
    /// direction (k the smallest that brings it under): a hole 150 px across
    /// (an HD camera at 10 cm) tells its centre to well under a pixel from a
    /// fraction of its edge, and its full window cost 5-10 times the rest of
    /// the detection.
    pub max_pixels: usize,
    /// Width (pixels) of the outline's edge in the model: the coverage ramps from
    /// face to opening over this many pixels across the outline.
    pub edge_px: f64,
    /// Width (pixels) of the outline's edge in the first, plain fit of
    /// [`refine_hole`]. With the fine fit's one-pixel edge the residual has a
    /// local minimum about every pixel along a blurred edge, and the fit kept
    /// the one nearest its start: from eight starts 1.2 px around each rendered
    /// hole, the results of one hole were up to 0.55 px apart in a tenth of the
    /// holes (a slot settling a pixel along its length). A two-pixel edge makes
    /// the first fit's residual smooth enough to reach the same basin from any
    /// of them (0.05 px apart), and the fine fit then settles in it.
    pub rough_edge_px: f64,
    /// The robust fit's Huber weights are computed in this many first
    /// iterations, then held. Recomputed in every one, each new weighting moved
    /// the optimum by about a hundredth of a pixel and the fit crept that way
    /// until the iteration cap (8.6 of 10 on average), discounting more and
    /// more of the very edge pixels that place the outline: held after two,
    /// it converges in 4.6 and the median hole error falls by a tenth in every
    /// scenario (BENCHMARKS.md, "Session 11"); but see
    /// [`Self::hold_weights_to_px_per_mm`].
    pub reweightings: usize,
    /// Weights are held after [`Self::reweightings`] only for holes seen at
    /// most this many pixels per mm of the face; larger ones reweight in every
    /// iteration. Up close the inside of a hole (its side walls, the contacts'
    /// shading) covers many pixels the outline does not draw, and the weights
    /// that keep discounting them placed those holes better: with the weights
    /// held, the median hole error of approaches at slot pitches of 44 px and
    /// more (3.5 px/mm) rose by 15-25%, while up to 33 px (2.6 px/mm) it fell by
    /// 5-15% (`outlet eval --approach`).
    pub hold_weights_to_px_per_mm: f64,
    /// The outline model's own error on the face (mm), added in quadrature to
    /// the fit's sigma: a hole's side wall, chamfer or the shading inside it
    /// moves the fitted centre by a share of the hole's size whatever the
    /// noise, so that near holes (many pixels, a tiny fit sigma) were the
    /// overconfident ones (error over sigma 1.5 times the far holes').
    pub outline_sigma_mm: f64,
    /// The inside's ramp (its shading, a side wall) is fitted along an axis of
    /// the opening only where the opening is at least this many pixels wide
    /// there: across a slot two pixels wide a ramp is the same as a shift, and
    /// took the place of one. Rendered Table I (seed 1000) with 3: hole RMS in
    /// plane mode 0.394 -> 0.377 mm, mono 1.193 -> 1.177 mm (p95 2.21 -> 1.87),
    /// sharp slots under 2 px wide 0.108 -> 0.082 px across (session 18).
    pub min_ramp_width_px: f64,
}

impl Default for RefineParams {
    fn default() -> Self {
        Self {
            margin_mm: 1.8,
            iterations: 10,
            max_shift_px: 3.0,
            min_relative_contrast: 0.12,
            clipped_face_level: 250.0,
            clipped_contrast_share: 0.4,
            min_sigma_px: 0.02,
            sigma_scale: 3.0,
            max_pixels: 3000,
            edge_px: 1.0,
            rough_edge_px: 2.0,
            reweightings: 2,
            hold_weights_to_px_per_mm: 3.0,
            outline_sigma_mm: 0.05,
            min_ramp_width_px: 3.0,
        }
    }
}

/// A refined hole centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Refined {
    pub centre: Point2<f64>,
    /// RMS of the model's residual (grey levels).
    pub rms: f64,
    /// Contrast between the face and the opening (grey levels): small means unsure.
    pub contrast: f64,
    /// Standard deviation of `centre` per axis (pixels): the Gauss-Newton
    /// covariance of the offset, sigma^2 (J^T W J)^-1 with sigma^2 the weighted
    /// residual variance, as the RMS of its two axes, times
    /// [`RefineParams::sigma_scale`], at least [`RefineParams::min_sigma_px`].
    /// From [`refine_hole`] also times [`edge_sigma_factor`] and with
    /// [`RefineParams::outline_sigma_mm`] in quadrature.
    pub sigma_px: f64,
    /// Share of the grey-level variance in the window that the outline model
    /// explains (R^2, 0..1): near 1 for a clear opening of the predicted shape.
    pub explained: f64,
    /// Pixels in the fit.
    pub pixels: usize,
    /// Sum of squared deviations of the window's grey levels from their mean.
    pub total_ss: f64,
    /// How wide the outline's edge shows in the image (pixels): of a few edge
    /// widths, the one whose model leaves the least residual at the centre (blur
    /// and defocus widen it). 0 where it was not measured.
    pub edge_px: f64,
    /// How the centre's variance divides among the image axes: symmetric, trace
    /// 2 (the identity where it is the same on both), so that the covariance of
    /// `centre` is `sigma_px² · shape` ([`Self::covariance_px`]). A slot tells
    /// its centre across its length from two long edges and along it from two
    /// short ends: on rendered scenes the error along a slot was 1.5 times the
    /// error across it, and one sigma for both axes made the slots' error bars
    /// too wide across and too narrow along.
    pub shape: Matrix2<f64>,
}

impl Refined {
    /// The covariance of `centre` (pixels²).
    pub fn covariance_px(&self) -> Matrix2<f64> {
        self.shape * self.sigma_px.powi(2)
    }

    /// The same fit with `sigma_px` at least `sigma`: what is added is error the
    /// fit did not see (the hole's disagreement with the others, a floor), the
    /// same on both axes.
    pub fn with_sigma_at_least(self, sigma: f64) -> Self {
        let raised = self.sigma_px.max(sigma);
        if raised == self.sigma_px {
            return self;
        }
        let added = raised.powi(2) - self.sigma_px.powi(2);
        let shape = shape_of(&(self.covariance_px() + Matrix2::identity() * added));
        Self { sigma_px: raised, shape, ..self }
    }
}

/// The least eigenvalue of a [`Refined::shape`] (the largest is then at most
/// 2 less it): a fit that claims one axis nearly exact is not believed.
const MIN_SHAPE_EIGENVALUE: f64 = 0.2;

/// A covariance's shape: scaled to trace 2, its eigenvalues kept within
/// [`MIN_SHAPE_EIGENVALUE`] and 2 less it; the identity where it is not
/// finite or not positive.
pub fn shape_of(covariance: &Matrix2<f64>) -> Matrix2<f64> {
    let c = (covariance + covariance.transpose()) * 0.5;
    let trace = c.trace();
    if !(trace > 0.0 && trace.is_finite()) {
        return Matrix2::identity();
    }
    let eig = (c * (2.0 / trace)).symmetric_eigen();
    let values = eig.eigenvalues.map(|v| v.clamp(MIN_SHAPE_EIGENVALUE, 2.0 - MIN_SHAPE_EIGENVALUE));
    let shape = eig.eigenvectors * Matrix2::from_diagonal(&values) * eig.eigenvectors.transpose();
    if shape.iter().all(|v| v.is_finite()) { shape * (2.0 / shape.trace()) } else { Matrix2::identity() }
}

/// Fits one hole's outline around `guess`. `mm_to_px` maps outlet-plane mm offsets
/// to image pixel offsets at the hole (the local Jacobian of the outlet-to-image
/// map, distortion included). `None` when the window leaves the image or the fit
/// does not converge to a dark opening in a bright face.
pub fn refine_hole(
    grey: &GrayImage,
    guess: Point2<f64>,
    mm_to_px: &Matrix2<f64>,
    shape: HoleShape,
    params: &RefineParams,
) -> Option<Refined> {
    // First converge with plain least squares and a soft edge (robust weights
    // would ignore the very pixels that pull the outline into place, and a sharp
    // edge has a local minimum every pixel), then re-centre the window and let
    // Huber weights discount what the outline does not explain.
    let window = shape.half_extent();
    let rough_params = RefineParams { edge_px: params.rough_edge_px, ..*params };
    let rough = fit(grey, guess, mm_to_px, shape, &rough_params, FitMode::ROUGH, window)?;
    let fine = fit(grey, rough.centre, mm_to_px, shape, params, FitMode::FINE, window)?;
    if (fine.centre - guess).norm() > params.max_shift_px {
        return None;
    }
    let px_per_mm = mm_to_px.determinant().abs().sqrt();
    let outline = params.outline_sigma_mm * px_per_mm;
    let fitted = fine.sigma_px * edge_sigma_factor(fine.edge_px);
    let sigma_px = fitted.hypot(outline).max(params.min_sigma_px);
    // The outline model's error is the same on both axes.
    let shape = shape_of(&(fine.shape * fitted.powi(2) + Matrix2::identity() * outline.powi(2)));
    Some(Refined { sigma_px, shape, ..fine })
}

/// How much more a centre errs, per axis, where the outline's edge shows
/// `edge_px` wide than where it is sharp (1 px): blur softens the edges the model
/// draws one pixel wide, and shading inside the hole then moves the centre more
/// than the residuals say. Measured on rendered holes of every scenario (2640
/// holes, guesses 1 px off): mean squared error over sigma 0.75 at 1 px, 0.93 at
/// 1.5, 1.17 at 2, 1.41 at 2.5, 1.61 at 3 (blur sigma 0.9-1.1 px): the variance
/// grows by 0.58 per pixel of edge width. Wider than 3 px is not told apart.
pub fn edge_sigma_factor(edge_px: f64) -> f64 {
    (1.0 + 0.58 * (edge_px.clamp(1.0, 3.0) - 1.0)).sqrt()
}

/// Huber weights of `residuals` into `weights`, the threshold 1.5 robust
/// standard deviations (from the median absolute residual, at least one grey
/// level). `abs` is scratch.
fn huber_weights(residuals: &[f64], abs: &mut Vec<f64>, weights: &mut [f64]) {
    // The median absolute residual (a selection, not a sort: this runs in
    // every fit).
    abs.clear();
    abs.extend(residuals.iter().map(|v| v.abs()));
    let mid = abs.len() / 2;
    let median = *abs.select_nth_unstable_by(mid, f64::total_cmp).1;
    let k = 1.5 * (median / 0.6745).max(1.0);
    for (w, v) in weights.iter_mut().zip(residuals) {
        *w = if v.abs() <= k { 1.0 } else { k / v.abs() };
    }
}

/// Edge widths (pixels) tried for [`Refined::edge_px`].
const EDGE_WIDTHS_PX: [f64; 6] = [1.0, 1.5, 2.0, 2.5, 3.0, 4.0];

/// The outline evaluated where it is put, without moving it: whether a dark
/// opening of that shape is at `centre` (contrast, explained share, residual).
/// `None` as for [`refine_hole`].
pub fn outline_at(
    grey: &GrayImage,
    centre: Point2<f64>,
    mm_to_px: &Matrix2<f64>,
    shape: HoleShape,
    params: &RefineParams,
) -> Option<Refined> {
    let fixed = RefineParams { iterations: 0, ..*params };
    fit(grey, centre, mm_to_px, shape, &fixed, FitMode::CHECK, shape.half_extent())
}

/// How much better a hole's own outline explains the pixels than another one
/// would: both are fitted from `centre` over the same pixels (a window around
/// the larger of the two), and the result is (SSE of `other` - SSE of `own`) and
/// SSE of `own` (grey levels squared). `other_map` is the other outline's mm to
/// pixel map: `-mm_to_px` turns it by half a turn (a ground hole's flat away from
/// the slots). `None` where either fit fails; a fit that finds no opening counts
/// as the worst.
pub fn compare_outlines(
    grey: &GrayImage,
    centre: Point2<f64>,
    mm_to_px: &Matrix2<f64>,
    own: HoleShape,
    other: (HoleShape, Matrix2<f64>),
    params: &RefineParams,
) -> Option<[f64; 2]> {
    let [a, b] = [own.half_extent(), other.0.half_extent()];
    let window = [a[0].max(b[0]), a[1].max(b[1])];
    let sse = |r: &Refined| r.rms * r.rms * r.pixels as f64;
    // Both start at the refined centre: a few steps settle them (time).
    let params = &RefineParams { iterations: params.iterations.min(3), ..*params };
    let mine = fit(grey, centre, mm_to_px, own, params, FitMode::COMPARE, window)?;
    let theirs = fit(grey, centre, &other.1, other.0, params, FitMode::COMPARE, window);
    // The other outline finding no dark opening at all is evidence for this one:
    // it counts as explaining nothing beyond the window's mean.
    let theirs = theirs.map_or(mine.total_ss, |r| sse(&r));
    Some([theirs - sse(&mine), sse(&mine)])
}

/// The first fit of [`refine_hole`] only chooses the basin the fine fit
/// settles in: it stops at steps under this (px).
const ROUGH_STOP_PX: f64 = 0.05;

/// The final fit of [`refine_hole`] stops at steps under this (px).
/// At 0.01 it took 5 iterations instead of 6.7 with the same hole errors over
/// Table I, but found 5 fewer of 728 real-photo views (Willow views 156 -> 154,
/// 203 -> 201, near-head-on 55 -> 54): their holes land nearer the plane
/// check's edge.
const FINE_STOP_PX: f64 = 0.005;

/// The other fits (an outline checked or compared where it is put) stop at
/// steps under this (px): only their residuals and contrast are used.
const STOP_PX: f64 = 0.01;

/// What one outline fit is for: which of its results are wanted decides what it
/// computes (the sigma's normal equations and the edge width cost as much as a
/// few iterations, and most fits use neither).
#[derive(Debug, Clone, Copy)]
struct FitMode {
    /// Huber weights and the ramp inside the outline (the fine fit).
    robust: bool,
    /// Measure the edge's width ([`Refined::edge_px`]).
    measure_edge: bool,
    /// Compute the centre's covariance ([`Refined::sigma_px`]); without it the
    /// sigma is reported as `max_shift_px`.
    sigma: bool,
    /// The iterations stop once a step moves the outline less than this (px).
    stop_px: f64,
}

impl FitMode {
    /// The first, plain fit of [`refine_hole`]: only its centre is used.
    const ROUGH: Self = Self { robust: false, measure_edge: false, sigma: false, stop_px: ROUGH_STOP_PX };
    /// The final fit of [`refine_hole`].
    const FINE: Self = Self { robust: true, measure_edge: true, sigma: true, stop_px: FINE_STOP_PX };
    /// [`outline_at`]: the outline where it is put, with its sigma.
    const CHECK: Self = Self { robust: true, measure_edge: false, sigma: true, stop_px: STOP_PX };
    /// [`compare_outlines`]: only the residuals are used.
    const COMPARE: Self = Self { robust: true, measure_edge: false, sigma: false, stop_px: STOP_PX };
}

fn fit(
    grey: &GrayImage,
    guess: Point2<f64>,
    mm_to_px: &Matrix2<f64>,
    shape: HoleShape,
    params: &RefineParams,
    mode: FitMode,
    window_mm: [f64; 2],
) -> Option<Refined> {
    crate::with_scratch(&FIT_SCRATCH, |scratch| {
        fit_with(grey, guess, mm_to_px, shape, params, mode, window_mm, scratch)
    })
}

/// The per-pixel vectors of one outline fit, kept by each thread between fits:
/// a frame fits a dozen to a hundred outlines, each of up to `max_pixels` pixels.
#[derive(Default)]
struct FitScratch {
    pixels: Vec<(Vector2<f64>, f64)>,
    weights: Vec<f64>,
    cov: Vec<(f64, Vector2<f64>)>,
    cov_dx: Vec<(f64, Vector2<f64>)>,
    cov_dy: Vec<(f64, Vector2<f64>)>,
    abs: Vec<f64>,
    r: Vec<f64>,
}

thread_local! {
    static FIT_SCRATCH: std::cell::RefCell<FitScratch> = std::cell::RefCell::new(FitScratch::default());
}

/// Pixels of face an outline must keep inside the image beyond its own extent
/// for a fit: the edge's ramp and a pixel of face to level it against.
const EDGE_SPARE_PX: i64 = 3;

#[allow(clippy::too_many_arguments)]
fn fit_with(
    grey: &GrayImage,
    guess: Point2<f64>,
    mm_to_px: &Matrix2<f64>,
    shape: HoleShape,
    params: &RefineParams,
    mode: FitMode,
    window_mm: [f64; 2],
    scratch: &mut FitScratch,
) -> Option<Refined> {
    let FitMode { robust, measure_edge, sigma, stop_px } = mode;
    let FitScratch { pixels, weights, cov, cov_dx, cov_dy, abs, r } = scratch;
    let px_to_mm = mm_to_px.try_inverse()?;
    let [ex, ey] = window_mm;
    let (ex, ey) = (ex + params.margin_mm, ey + params.margin_mm);
    // Pixel window covering the outline plus margin, wherever it is turned.
    let corners = [[-ex, -ey], [ex, -ey], [-ex, ey], [ex, ey]].map(|[x, y]| mm_to_px * Vector2::new(x, y));
    let rx = corners.iter().map(|c| c.x.abs()).fold(0.0, f64::max).ceil() as i64 + 1;
    let ry = corners.iter().map(|c| c.y.abs()).fold(0.0, f64::max).ceil() as i64 + 1;
    let (gx, gy) = (guess.x.round() as i64, guess.y.round() as i64);
    let (w, h) = (grey.width() as i64, grey.height() as i64);
    if !guess.x.is_finite() || !guess.y.is_finite() {
        return None;
    }
    // The window may run off the image (a hole near its edge, seen close up:
    // the margin alone is tens of pixels), the outline itself may not: it must
    // lie inside with `EDGE_SPARE_PX` of face beyond it.
    let inner = [[-ex, -ey], [ex, -ey], [-ex, ey], [ex, ey]]
        .map(|[x, y]| mm_to_px * Vector2::new(x - params.margin_mm * x.signum(), y - params.margin_mm * y.signum()));
    let ix = inner.iter().map(|c| c.x.abs()).fold(0.0, f64::max).ceil() as i64 + EDGE_SPARE_PX;
    let iy = inner.iter().map(|c| c.y.abs()).fold(0.0, f64::max).ceil() as i64 + EDGE_SPARE_PX;
    if gx - ix < 0 || gy - iy < 0 || gx + ix >= w || gy + iy >= h {
        return None;
    }
    if rx * ry > 40_000 {
        return None; // a hole that large is not a hole at this scale
    }
    let (x0, x1, y0, y1) = ((gx - rx).max(0), (gx + rx).min(w - 1), (gy - ry).max(0), (gy + ry).min(h - 1));
    // Pixels inside the elliptic window (in mm: within the margin box).
    let window_pixels = ((x1 - x0 + 1) * (y1 - y0 + 1)) as f64;
    let stride = (window_pixels / params.max_pixels.max(1) as f64).sqrt().ceil().max(1.0) as usize;
    pixels.clear();
    for y in (y0..=y1).step_by(stride) {
        for x in (x0..=x1).step_by(stride) {
            let d = Vector2::new(x as f64 - guess.x, y as f64 - guess.y);
            let q = px_to_mm * d;
            if q.x.abs() <= ex && q.y.abs() <= ey {
                pixels.push((d, grey.get_pixel(x as u32, y as u32)[0] as f64));
            }
        }
    }
    if pixels.len() < 12 {
        return None;
    }
    let pixels: &[(Vector2<f64>, f64)] = pixels;
    // A pixel's width in mm, for the coverage ramp across the outline.
    let pixel_mm = px_to_mm.determinant().abs().sqrt() * params.edge_px.max(0.1);
    // Coverage (smooth in the offset, so that its derivative is useful) and mm
    // coordinates of each pixel for the outline offset `t` (px).
    let coverage_with = |t: Vector2<f64>, ramp_mm: f64, out: &mut Vec<(f64, Vector2<f64>)>| {
        out.clear();
        for (d, _) in pixels {
            let q = px_to_mm * (d - t);
            out.push(((0.5 - shape.sd(q) / ramp_mm).clamp(0.0, 1.0), q));
        }
    };
    let coverage = |t: Vector2<f64>, out: &mut Vec<(f64, Vector2<f64>)>| coverage_with(t, pixel_mm, out);
    // The coverage at `t` and one finite-difference step along x and along y,
    // in one pass over the pixels (the same values as three passes).
    let step = 0.05;
    let coverage3 = |t: Vector2<f64>,
                     out: &mut Vec<(f64, Vector2<f64>)>,
                     out_dx: &mut Vec<(f64, Vector2<f64>)>,
                     out_dy: &mut Vec<(f64, Vector2<f64>)>| {
        out.clear();
        out_dx.clear();
        out_dy.clear();
        let (tx, ty) = (t + Vector2::new(step, 0.0), t + Vector2::new(0.0, step));
        // The outline's distance moves by at most the step's length in mm (a
        // distance is 1-Lipschitz): away from the edge all three coverages are
        // the same 0 or 1, and only the edge's band needs the shifted distances.
        let band = step * px_to_mm.column(0).norm().max(px_to_mm.column(1).norm()) / pixel_mm + 1e-9;
        for (d, _) in pixels {
            let q = px_to_mm * (d - t);
            let (qx, qy) = (px_to_mm * (d - tx), px_to_mm * (d - ty));
            let level = 0.5 - shape.sd(q) / pixel_mm;
            if level >= 1.0 + band || level <= -band {
                let m = level.clamp(0.0, 1.0);
                out.push((m, q));
                out_dx.push((m, qx));
                out_dy.push((m, qy));
            } else {
                out.push((level.clamp(0.0, 1.0), q));
                out_dx.push(((0.5 - shape.sd(qx) / pixel_mm).clamp(0.0, 1.0), qx));
                out_dy.push(((0.5 - shape.sd(qy) / pixel_mm).clamp(0.0, 1.0), qy));
            }
        }
    };
    // A ramp inside across an opening only a few pixels wide is the same as a
    // shift of it: there the outline's place decides alone.
    let narrow = |mm: f64, axis: Vector2<f64>| (mm_to_px * axis).norm() * mm < params.min_ramp_width_px;
    let [wx, wy] = shape.half_extent();
    let ramp_across = if narrow(2.0 * wx, Vector2::x()) { 0.0 } else { 1.0 };
    let ramp_along = if narrow(2.0 * wy, Vector2::y()) { 0.0 } else { 1.0 };
    // Best linear parameters (face level a, inside level b, ramp cx, cy) for an
    // offset, and the residual vector.
    let solve = |cov: &[(f64, Vector2<f64>)], weights: &[f64], r: &mut Vec<f64>| -> Option<Vector4<f64>> {
        let mut ata = Matrix4::zeros();
        let mut atb = Vector4::zeros();
        // Without the ramp while the outline is still far off: a ramp inside a
        // misplaced outline would mimic the shift and stall the fit.
        let ramp = if robust { 1.0 } else { 0.0 };
        let (ramp_x, ramp_y) = (ramp * ramp_across, ramp * ramp_along);
        for (((m, q), (_, v)), w) in cov.iter().zip(pixels).zip(weights) {
            // Most of the window is face (three quarters of a slot's): its row
            // is (1, 0, 0, 0).
            if *m == 0.0 {
                ata[(0, 0)] += *w;
                atb[0] += *v * *w;
                continue;
            }
            let row = [1.0 - m, *m, m * q.x * ramp_x, m * q.y * ramp_y];
            // The upper triangle only (the matrix is symmetric; each entry is
            // the same product as in the full outer product).
            for i in 0..4 {
                for j in i..4 {
                    ata[(i, j)] += row[i] * row[j] * *w;
                }
                atb[i] += row[i] * *v * *w;
            }
        }
        for i in 0..4 {
            for j in 0..i {
                ata[(i, j)] = ata[(j, i)];
            }
        }
        ata += Matrix4::identity() * 1e-6;
        let p = ata.cholesky()?.solve(&atb);
        r.clear();
        r.extend(
            cov.iter()
                .zip(pixels)
                .map(|((m, q), (_, v))| v - (p[0] * (1.0 - m) + m * (p[1] + p[2] * q.x + p[3] * q.y))),
        );
        Some(p)
    };
    let mut t = Vector2::zeros();
    // Huber weights: what the outline does not explain (a T-slot's branch, a dark
    // spot, a glint) should not drag the centre.
    weights.clear();
    weights.resize(pixels.len(), 1.0);
    // Large holes keep reweighting (see `RefineParams::hold_weights_to_px_per_mm`).
    let reweightings = if px_to_mm.determinant().abs().sqrt().recip() <= params.hold_weights_to_px_per_mm {
        params.reweightings
    } else {
        usize::MAX
    };
    for iteration in 0..params.iterations {
        coverage3(t, cov, cov_dx, cov_dy);
        let p = solve(cov, weights, r)?;
        if robust && iteration < reweightings {
            huber_weights(r, abs, weights);
        }
        // d(model)/dt by finite differences of the coverage, linear parameters held.
        let model = |(m, q): &(f64, Vector2<f64>)| p[0] * (1.0 - m) + m * (p[1] + p[2] * q.x + p[3] * q.y);
        let mut jtj = Matrix2::zeros();
        let mut jtr = Vector2::zeros();
        for i in 0..pixels.len() {
            // Outside the outline and its edge the model is the face's level
            // wherever the outline moves: no gradient.
            if cov[i].0 == 0.0 && cov_dx[i].0 == 0.0 && cov_dy[i].0 == 0.0 {
                continue;
            }
            let base = model(&cov[i]);
            let j = Vector2::new((model(&cov_dx[i]) - base) / step, (model(&cov_dy[i]) - base) / step);
            jtj += j * j.transpose() * weights[i];
            jtr += j * r[i] * weights[i];
        }
        let delta = (jtj + Matrix2::identity() * 1e-9).try_inverse()? * jtr;
        let delta = if delta.norm() > 1.0 { delta / delta.norm() } else { delta };
        t += delta;
        if delta.norm() < stop_px {
            break;
        }
    }
    if sigma {
        coverage3(t, cov, cov_dx, cov_dy);
    } else {
        coverage(t, cov);
    }
    let p = solve(cov, weights, r)?;
    let rms = (r.iter().map(|v| v * v).sum::<f64>() / r.len() as f64).sqrt();
    let mut shape = Matrix2::identity();
    let sigma_px = if sigma {
        // The offset's covariance from the normal equations at the solution, scaled
        // by the residual variance (6 parameters: two offsets, four linear).
        let model = |(m, q): &(f64, Vector2<f64>)| p[0] * (1.0 - m) + m * (p[1] + p[2] * q.x + p[3] * q.y);
        let (mut jtj, mut wrr, mut wsum) = (Matrix2::zeros(), 0.0, 0.0);
        for i in 0..pixels.len() {
            let base = model(&cov[i]);
            let j = Vector2::new((model(&cov_dx[i]) - base) / step, (model(&cov_dy[i]) - base) / step);
            jtj += j * j.transpose() * weights[i];
            wrr += weights[i] * r[i] * r[i];
            wsum += weights[i];
        }
        let dof = (pixels.len() as f64 - 6.0).max(1.0);
        // Weights below 1 count as fewer pixels: the variance per unit weight.
        let variance = wrr / dof * (pixels.len() as f64 / wsum.max(1e-9));
        let covariance = jtj.try_inverse().map(|inv| inv * variance);
        if let Some(c) = covariance {
            shape = shape_of(&c);
        }
        covariance
            .map(|c| ((c[(0, 0)] + c[(1, 1)]) / 2.0).max(0.0).sqrt() * params.sigma_scale)
            .filter(|s| s.is_finite())
            .unwrap_or(params.max_shift_px)
            .max(params.min_sigma_px)
    } else {
        params.max_shift_px
    };
    let mean = pixels.iter().map(|(_, v)| v).sum::<f64>() / pixels.len() as f64;
    let total = pixels.iter().map(|(_, v)| (v - mean) * (v - mean)).sum::<f64>();
    let residual = r.iter().map(|v| v * v).sum::<f64>();
    let explained = if total > 0.0 { (1.0 - residual / total).clamp(0.0, 1.0) } else { 0.0 };
    // How wide the edge shows: of a few ramp widths, the one that leaves the least
    // residual at the fitted centre (plain least squares, the same pixels).
    let mut edge_px = 0.0;
    if measure_edge {
        let one_px_mm = pixel_mm / params.edge_px.max(0.1);
        abs.clear();
        abs.resize(pixels.len(), 1.0);
        let mut least = f64::INFINITY;
        for &width in &EDGE_WIDTHS_PX {
            coverage_with(t, one_px_mm * width, cov);
            if solve(cov, abs, r).is_some() {
                let sse = r.iter().map(|v| v * v).sum::<f64>();
                if sse < least {
                    (least, edge_px) = (sse, width);
                }
            }
        }
    }
    // Mean level inside the outline against the face's.
    let contrast = p[0] - p[1];
    let relative = contrast / p[0].max(1.0);
    let least = if p[0] >= params.clipped_face_level {
        params.min_relative_contrast * params.clipped_contrast_share
    } else {
        params.min_relative_contrast
    };
    if t.norm() > params.max_shift_px || relative < least || !t.x.is_finite() || !t.y.is_finite() {
        return None;
    }
    Some(Refined {
        centre: guess + t,
        rms,
        contrast,
        sigma_px,
        explained,
        pixels: pixels.len(),
        total_ss: total,
        edge_px,
        shape,
    })
}
