//! Holes the pose cannot explain, and pixel noise larger than assumed.
//!
//! A refined hole centre can be caught by a shadow edge or a glint and land
//! several pixels off (rendered fw_2x1white view 184, seed 1: the upper hot slot
//! 6.6 px from its centre, on the edge of an occluder's shadow). Solved with the
//! others it pulls the pose and leaves a residual the covariance does not
//! admit. Here the pose is solved without each hole in turn; the hole whose
//! removal lowers the cost by more than chi-square's 99.9% point with 2 degrees
//! of freedom (scaled by the rest's cost per degree of freedom) is dropped (its
//! pixel no longer weighs), while at most a third of the holes are gone. The
//! covariance is then scaled by the kept holes' cost per degree of freedom where
//! that exceeds 1: pixels noisier than `pixel_sigma` (blur, a dark image) widen
//! the error bars instead of hiding in them.

use crate::Rays;
use crate::lm::{self, Fit};
use nalgebra::{Isometry3, Vector2};

/// Chi-square with 2 degrees of freedom, 99.9% point: a hole whose whitened
/// residual (over the robust scale) exceeds it is an outlier.
pub const OUTLIER_CHI2: f64 = 13.82;
/// A dropped hole's pixel sigma, relative to its own: it no longer pulls the pose.
const DROPPED_SIGMA_FACTOR: f64 = 1e4;

/// Multiplies hole `k`'s pixel sigma by `factor`.
pub(crate) fn inflate(rays: &mut Rays, k: usize, factor: f64) {
    rays.whiten[k] /= factor;
    rays.covariance[k] *= factor * factor;
    rays.sigma[k] *= factor;
}

/// The holes still kept, as a new set of rays (for solvers that ignore weights).
pub(crate) fn subset(rays: &Rays, kept: &[bool]) -> Rays {
    let pick = |k: &usize| kept.get(*k).copied().unwrap_or(false);
    Rays {
        xy: (0..rays.xy.len()).filter(pick).map(|k| rays.xy[k]).collect(),
        whiten: (0..rays.xy.len()).filter(pick).map(|k| rays.whiten[k]).collect(),
        covariance: (0..rays.xy.len()).filter(pick).map(|k| rays.covariance[k]).collect(),
        model: (0..rays.xy.len()).filter(pick).map(|k| rays.model[k]).collect(),
        sigma: (0..rays.xy.len()).filter(pick).map(|k| rays.sigma[k]).collect(),
        px_to_xy: (0..rays.xy.len()).filter(pick).map(|k| rays.px_to_xy[k]).collect(),
        share: rays.share,
    }
}

/// The kept holes' cost per degree of freedom over their own noise's share
/// squared, at least 1: the factor the covariance is scaled by. `fixed` is how
/// many pose parameters the pixels must determine (6, less what a prior fixes).
pub(crate) fn variance_factor(rays: &Rays, pose: &Isometry3<f64>, kept: &[bool], fixed: usize) -> f64 {
    let costs = lm::hole_costs(rays, pose);
    let n = kept.iter().filter(|k| **k).count();
    let cost: f64 = costs.iter().zip(kept).filter(|(_, k)| **k).map(|(c, _)| *c).sum();
    let dof = (2 * n).saturating_sub(fixed);
    // Against the holes' own noise, the share of their sigma that shows in residuals.
    if dof == 0 || !cost.is_finite() { 1.0 } else { (cost / dof as f64 / rays.share.powi(2)).max(1.0) }
}

/// The most holes dropped: a third (2 of 6, 4 of 12).
pub(crate) fn max_drops(n: usize) -> usize {
    n / 3
}

/// Solves with `solve`, then tries the fit without each kept hole in turn: the
/// hole whose removal lowers the cost most is dropped when that drop exceeds
/// [`OUTLIER_CHI2`] times the rest's cost per degree of freedom (at least 1),
/// and the search goes on until no hole qualifies, [`max_drops`] are gone or
/// `min_kept` remain. `fixed` is how many pose parameters the pixels must
/// determine. Returns the last fit and the kept mask; `rays` keeps the dropped
/// holes' sigmas inflated. (A least-squares fit spreads one bad hole over the
/// others, so its own residual would not single it out; leaving it out does.)
pub(crate) fn refit<S>(rays: &mut Rays, min_kept: usize, fixed: usize, solve: S) -> Option<(Fit, Vec<bool>)>
where
    S: Fn(&Rays, &[bool]) -> Option<Fit>,
{
    let n = rays.model.len();
    let mut kept = vec![true; n];
    let mut fit = solve(rays, &kept)?;
    let kept_cost = |r: &Rays, pose: &Isometry3<f64>, kept: &[bool]| -> f64 {
        lm::hole_costs(r, pose).iter().zip(kept).filter(|(_, k)| **k).map(|(c, _)| *c).sum()
    };
    for _ in 0..max_drops(n) {
        let kept_count = kept.iter().filter(|k| **k).count();
        if kept_count <= min_kept {
            break;
        }
        let cost = kept_cost(rays, &fit.pose, &kept);
        let dof = (2 * (kept_count - 1)).saturating_sub(fixed).max(1) as f64;
        let mut best: Option<(usize, f64, Fit, Rays)> = None;
        for k in (0..n).filter(|k| kept[*k]) {
            let mut trial_kept = kept.clone();
            trial_kept[k] = false;
            let mut trial = robust_clone(rays);
            inflate(&mut trial, k, DROPPED_SIGMA_FACTOR);
            let Some(trial_fit) = solve(&trial, &trial_kept) else { continue };
            let rest = kept_cost(&trial, &trial_fit.pose, &trial_kept);
            if best.as_ref().is_none_or(|b| rest < b.1) {
                best = Some((k, rest, trial_fit, trial));
            }
        }
        match best {
            Some((k, rest, trial_fit, trial)) if (cost - rest) / (rest / dof).max(1.0) > OUTLIER_CHI2 => {
                kept[k] = false;
                *rays = trial;
                fit = trial_fit;
            }
            _ => break,
        }
    }
    Some((fit, kept))
}

fn robust_clone(rays: &Rays) -> Rays {
    subset(rays, &vec![true; rays.model.len()])
}

/// Which holes a kept mask dropped.
pub(crate) fn dropped(kept: &[bool]) -> Vec<usize> {
    kept.iter().enumerate().filter(|(_, k)| !**k).map(|(i, _)| i).collect()
}

/// A share of the pixel error that all holes have in common (pixels, each
/// axis), relative to the kept holes' median sigma, for an outlet seen at
/// [`COMMON_REFERENCE_PX_PER_MM`]. Blur, a hole's visible side wall and shading
/// shift every hole of a frame alike, which no residual shows and independent
/// noise does not cover; the shift grows with the holes' size in the image
/// (rendered scenes, 2100 frames: the common shift beyond independent noise
/// 0.07 px at 20-25 cm, 0.03 px at 40-60 cm, against median sigmas of 0.14 and
/// 0.19 px). A constant half of the median sigma (before) was twice too wide far
/// away and too narrow near: NEES means 0.65 x 3, 0.46 beyond 40 cm. A camera
/// with a longer focal length sees the holes larger and gets a larger share:
/// cautious where its blur in pixels is no wider than a VGA camera's.
pub const COMMON_SIGMA_FRACTION: f64 = 0.4;

/// The outlet's scale in the image (pixels per millimetre of its face) at which
/// [`COMMON_SIGMA_FRACTION`] holds: 525 px of focal length at 30 cm.
pub const COMMON_REFERENCE_PX_PER_MM: f64 = 1.75;

/// The common pixel sigma of a set of rays: [`COMMON_SIGMA_FRACTION`] of the
/// kept holes' median sigma, times the outlet's scale in the image over
/// [`COMMON_REFERENCE_PX_PER_MM`].
pub(crate) fn common_sigma(rays: &Rays, kept: &[bool]) -> f64 {
    let mut s: Vec<f64> = rays.sigma.iter().zip(kept).filter(|(_, k)| **k).map(|(s, _)| *s).collect();
    s.sort_by(f64::total_cmp);
    let median = s.get(s.len() / 2).copied().unwrap_or(0.0);
    let scale = px_per_mm(rays, kept).map_or(1.0, |p| p / COMMON_REFERENCE_PX_PER_MM);
    median * COMMON_SIGMA_FRACTION * scale
}

/// The sigma of a scale error common to every hole (the holes' pattern seen
/// larger or smaller about its centre), as the move it gives a hole at the
/// kept holes' RMS distance from their centroid, relative to
/// [`common_sigma`]. A hole's visible side wall, chamfer or blur pulls each
/// dark opening towards or away from the others alike, and apparent size is
/// what depth comes from where the pixels decide it: rendered scenes (1044
/// frames, seed 1000) showed the fitted scale varying 1.4 times more than the
/// holes' own noise explains (2.2 times at 20-25 cm); 0.45 brings that ratio
/// to 1.0 overall, 1.07 near and 1.04 beyond 45 cm.
pub const COMMON_SCALE_SHARE: f64 = 0.45;

/// Unit draws of the errors common to every kept hole, as moves of every
/// hole's normalised coordinates: a pixel shift on each image axis
/// ([`common_sigma`]) and a scale about the kept holes' centroid
/// ([`COMMON_SCALE_SHARE`]).
pub(crate) fn common_modes(rays: &Rays, kept: &[bool]) -> Vec<Vec<Vector2<f64>>> {
    let sigma = common_sigma(rays, kept);
    let mut modes = Vec::with_capacity(3);
    if !(sigma > 0.0 && sigma.is_finite()) {
        return modes;
    }
    for axis in 0..2 {
        let mut shift = Vector2::zeros();
        shift[axis] = sigma;
        modes.push(rays.px_to_xy.iter().map(|j| j * shift).collect());
    }
    let picked: Vec<usize> = (0..rays.xy.len()).filter(|k| kept.get(*k).copied().unwrap_or(false)).collect();
    if picked.len() >= 2 {
        let centre = picked.iter().fold(Vector2::zeros(), |s, k| s + rays.xy[*k]) / picked.len() as f64;
        // The RMS distance from the centroid, in pixels through each hole's lens Jacobian.
        let radius_px = (picked
            .iter()
            .map(|k| rays.px_to_xy[*k].try_inverse().map_or(0.0, |j| (j * (rays.xy[*k] - centre)).norm_squared()))
            .sum::<f64>()
            / picked.len() as f64)
            .sqrt();
        if radius_px > 0.0 && radius_px.is_finite() {
            let scale = COMMON_SCALE_SHARE * sigma / radius_px;
            modes.push(rays.xy.iter().map(|xy| (xy - centre) * scale).collect());
        }
    }
    modes
}

/// The kept holes' spread in the image over their spread on the face: pixels
/// per millimetre, foreshortening averaged in. `None` below two holes.
fn px_per_mm(rays: &Rays, kept: &[bool]) -> Option<f64> {
    let picked = || rays.xy.iter().zip(&rays.model).zip(&rays.px_to_xy).zip(kept).filter(|(_, k)| **k).map(|(v, _)| v);
    let n = picked().count();
    if n < 2 {
        return None;
    }
    let (mut xy, mut m, mut f) = (Vector2::zeros(), Vector2::zeros(), 0.0);
    for ((p, q), j) in picked() {
        xy += p;
        m += q.coords.xy();
        // Pixels per unit of the normalised image plane, from d xy / d pixel.
        f += 1.0 / j.determinant().abs().sqrt();
    }
    let (xy, m, f) = (xy / n as f64, m / n as f64, f / n as f64);
    let (mut image, mut face) = (0.0, 0.0);
    for ((p, q), _) in picked() {
        image += (p - xy).norm_squared();
        face += (q.coords.xy() - m).norm_squared();
    }
    let ratio = f * (image / face).sqrt() / 1000.0;
    (face > 0.0 && ratio.is_finite()).then_some(ratio)
}
