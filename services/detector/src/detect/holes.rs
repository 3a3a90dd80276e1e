//! An outlet's holes refined where the hashing's homography puts them, and the
//! checks that verify the outlet from them: one plane, not mirrored, ground
//! holes where they should be (`ground`), the reading told from its half turn.

use super::ground::GroundEvidence;
use super::{DetectedHole, Detection, Detector, Lens, apply, centroid, fit_homography, local_jacobian};
use crate::refine::{HoleShape, RefineParams, Refined, outline_at, refine_hole};
use crate::verify::{hole_score, identity_gain};
use image::GrayImage;
use nalgebra::{Matrix2, Matrix3, Point2};

/// The per-hole vectors of one verification, kept by each thread between
/// calls: a frame verifies one outlet or a few, each taking some twenty.
#[derive(Default)]
struct RefineScratch {
    fits: Vec<Option<Refined>>,
    jacobians: Vec<Matrix2<f64>>,
    refined: Vec<Option<Point2<f64>>>,
    wants_prediction: Vec<bool>,
    predicted_only: Vec<bool>,
    sigmas: Vec<f64>,
    fitted: Vec<(Point2<f64>, Point2<f64>, f64)>,
    seen: Vec<(Point2<f64>, Matrix2<f64>, HoleShape)>,
    holes: Vec<DetectedHole>,
    fit: FitBuffers,
    agreement: Agreement,
}

/// The point pairs of the homography fits (`plane_fit`, `prediction_sigma`).
#[derive(Default)]
struct FitBuffers {
    pairs: Vec<(Point2<f64>, Point2<f64>)>,
    moved: Vec<(Point2<f64>, Point2<f64>)>,
}

/// [`agreement_sigmas`]'s vectors; `sigmas` is its answer.
#[derive(Default)]
struct Agreement {
    indexed: Vec<(usize, Point2<f64>, Point2<f64>)>,
    all: Vec<(Point2<f64>, Point2<f64>)>,
    others: Vec<(Point2<f64>, Point2<f64>)>,
    sigmas: Vec<Option<f64>>,
}

thread_local! {
    static REFINE_SCRATCH: std::cell::RefCell<RefineScratch> = std::cell::RefCell::new(RefineScratch::default());
}

impl Detector {
    /// Refines every hole from the hashing's homography, then verifies the
    /// outlet: every hole seen on one plane's homography, not mirrored, ground
    /// holes where they should be, and outlines that tell its reading from the
    /// swapped one. `Err` says which check refused it.
    pub(super) fn refine(
        &self,
        grey: &GrayImage,
        lens: &Lens,
        homography: &Matrix3<f64>,
        guesses: &[Option<Point2<f64>>],
        score: usize,
    ) -> Result<Detection, String> {
        crate::with_scratch(&REFINE_SCRATCH, |scratch| {
            self.refine_with(grey, lens, homography, guesses, score, scratch)
        })
    }

    fn refine_with(
        &self,
        grey: &GrayImage,
        lens: &Lens,
        homography: &Matrix3<f64>,
        guesses: &[Option<Point2<f64>>],
        score: usize,
        scratch: &mut RefineScratch,
    ) -> Result<Detection, String> {
        let RefineScratch {
            fits,
            jacobians,
            refined,
            wants_prediction,
            predicted_only,
            sigmas: fitted_sigmas,
            fitted,
            seen: outlines_seen,
            holes,
            fit: fit_buffers,
            agreement,
        } = scratch;
        // The template's holes, as the hashing table holds them.
        let model = self.table.points();
        fits.clear();
        jacobians.clear();
        let degenerate = || "the homography maps a hole to infinity".to_string();
        for (i, t) in model.iter().enumerate() {
            let predicted = lens.distort(apply(homography, t).ok_or_else(degenerate)?);
            // The candidate's own centre where it is close to the prediction.
            let guess = match guesses.get(i).copied().flatten() {
                Some(g) if (g - predicted).norm() < 3.0 => g,
                _ => predicted,
            };
            let jacobian = local_jacobian(homography, lens, t).ok_or_else(degenerate)?;
            let fit = refine_hole(grey, guess, &jacobian, self.outlines[i], &self.params.refine);
            tracing::trace!(hole = i, ?guess, ?predicted, fitted = ?fit.map(|f| f.centre), "hole refined");
            fits.push(fit);
            jacobians.push(jacobian);
        }
        refined.clear();
        refined.extend(fits.iter().map(|f| f.map(|r| r.centre)));
        // The refined holes must lie where one plane puts them. Holes that do not
        // (a fit caught by a glint or a dark spot) are dropped one by one, worst
        // first; the outlet stands only if enough holes remain.
        let min_holes = self.params.hash.min_score(model.len()).max(4);
        // Pixels per mm along the outlet's least foreshortened direction.
        let scale = local_jacobian(homography, lens, &centroid(model)).ok_or_else(degenerate)?.singular_values().max();
        let tolerance = self.params.max_plane_px.max(self.params.max_plane_mm * scale);
        // Too few holes on one plane yet may be the hashing's homography, made
        // from a few candidates' centres, guessing the far holes too far off for
        // their outlines (blur, a real outlet a little off the nominal one): with
        // enough of them, the rest are looked for where the fitted holes put them.
        let least = min_holes.min(self.params.min_holes_to_look_again);
        let h = plane_fit(model, refined, lens, tolerance, least, &mut fit_buffers.pairs)?;
        // A hole not found (faint: washed out, in shadow; or its first guess too
        // far off) is looked for once more where the seen holes' homography puts
        // it, with less contrast; it counts only if it lands on that plane too.
        let faint = RefineParams { min_relative_contrast: self.params.verify.faint_contrast, ..self.params.refine };
        wants_prediction.clear();
        wants_prediction.resize(model.len(), false);
        let mut faint_found = false;
        for (i, t) in model.iter().enumerate() {
            if refined[i].is_some() {
                continue;
            }
            let Some(q) = apply(&h, t) else { continue };
            let Some(jacobian) = local_jacobian(&h, lens, t) else { continue };
            let moved = refine_hole(grey, lens.distort(q), &jacobian, self.outlines[i], &faint);
            tracing::trace!(hole = i, at = ?lens.distort(q), fitted = ?moved.map(|f| f.centre), "looked for again");
            match moved.map(|fit| (fit, (q - lens.undistort(fit.centre)).norm())) {
                Some((fit, d)) if d <= tolerance => {
                    tracing::debug!(hole = i, "faint hole fitted where the other holes put it");
                    refined[i] = Some(fit.centre);
                    fits[i] = Some(fit.with_sigma_at_least(tolerance / 2.0));
                    jacobians[i] = jacobian;
                    faint_found = true;
                }
                // An opening clearly beside the predicted place: the hole may be
                // there, or the outlet not where the homography says; not seen.
                Some((_, d)) if d.is_nan() || d > 2.0 * tolerance => {}
                // None found, or one pulled a little off (a dark dot beside a
                // ground hole): the outline must show at the predicted place.
                _ => wants_prediction[i] = true,
            }
        }
        // The faint holes join the fit and are checked by it (a faint fit off the
        // plane is dropped); any centre predicted below comes from this fit.
        let seen = refined.iter().flatten().count();
        let h = if faint_found || seen < min_holes {
            plane_fit(model, refined, lens, tolerance, min_holes, &mut fit_buffers.pairs)?
        } else {
            h
        };
        // A fitted hole's sigma is at least what the other holes say of it: its
        // outline fit measures the image noise, not the fit's bias (a T-slot's
        // branch, a blurred edge, a worn opening), which shows as the hole's
        // distance from where the rest of the outlet puts it.
        agreement_sigmas(model, refined, lens, agreement);
        for (i, &spread) in agreement.sigmas.iter().enumerate() {
            if let (Some(spread), Some(fit)) = (spread, fits[i].as_mut()) {
                *fit = fit.with_sigma_at_least(spread);
            }
        }
        // No hole is much surer than the outlet's typical one: the holes share
        // the blur, the noise and the outline model's error, and a fit that
        // claims far less than its neighbours is mostly one that was lucky in
        // its pixels (see `MIN_SIGMA_OF_MEDIAN`).
        fitted_sigmas.clear();
        fitted_sigmas
            .extend(fits.iter().zip(refined.iter()).filter_map(|(f, r)| r.and(f.as_ref()).map(|f| f.sigma_px)));
        if !fitted_sigmas.is_empty() {
            let mid = fitted_sigmas.len() / 2;
            let median = *fitted_sigmas.select_nth_unstable_by(mid, f64::total_cmp).1;
            for (fit, r) in fits.iter_mut().zip(refined.iter()) {
                if let (Some(fit), Some(_)) = (fit.as_mut(), r) {
                    *fit = fit.with_sigma_at_least(MIN_SIGMA_OF_MEDIAN * median);
                }
            }
        }
        // A centre taken from the homography is only as good as the fit it comes
        // from: it takes at least `min_fitted_for_prediction` fitted holes. Its outline
        // must show right there (`refined` false); its sigma carries the fitted
        // holes' error carried through the homography and the real outlet's
        // departure from the nominal geometry.
        fitted.clear();
        fitted.extend(
            model
                .iter()
                .zip(refined.iter())
                .zip(fits.iter())
                .filter_map(|((t, r), f)| Some((*t, lens.undistort((*r)?), f.as_ref()?.sigma_px))),
        );
        predicted_only.clear();
        predicted_only.resize(model.len(), false);
        for (i, t) in model.iter().enumerate() {
            if refined[i].is_some() || !wants_prediction[i] || fitted.len() < self.params.min_fitted_for_prediction {
                continue;
            }
            let Some(q) = apply(&h, t) else { continue };
            let predicted = lens.distort(q);
            let Some(jacobian) = local_jacobian(&h, lens, t) else { continue };
            let Some(fit) = outline_at(grey, predicted, &jacobian, self.outlines[i], &faint) else { continue };
            let carried = prediction_sigma(fitted, t, fit_buffers).unwrap_or(f64::INFINITY);
            let nominal = self.params.predicted_sigma_mm * jacobian.singular_values().max();
            let sigma_px = (fit.sigma_px.powi(2) + carried.powi(2) + nominal.powi(2)).sqrt().max(tolerance / 2.0);
            if !sigma_px.is_finite() {
                continue;
            }
            tracing::debug!(hole = i, sigma_px, "hole seen where the fitted holes put it");
            predicted_only[i] = true;
            refined[i] = Some(predicted);
            // Mostly the carried and nominal errors, the same on both axes.
            fits[i] = Some(Refined { sigma_px, shape: Matrix2::identity(), ..fit });
            jacobians[i] = jacobian;
        }
        // Every hole must have been seen: a hole predicted from the others may lie
        // on the bare plate (the arm would go there), so the outlet is refused.
        holes.clear();
        for (i, ((t, r), hole)) in model.iter().zip(refined.iter()).zip(&self.template.geometry.holes).enumerate() {
            let kind = hole.kind.as_str();
            let (Some(pixel), Some(fit)) = (r, fits[i]) else {
                return Err(match fits[i] {
                    None if wants_prediction[i] && fitted.len() < self.params.min_fitted_for_prediction => format!(
                        "hole {i} ({kind}): not fitted, and {} fitted holes are too few to predict it",
                        fitted.len()
                    ),
                    None => format!("hole {i} ({kind}): no opening of its outline found where the homography puts it"),
                    Some(_) => format!("hole {i} ({kind}): its opening is off the outlet's plane"),
                });
            };
            let predicted = apply(&h, t).map(|q| lens.distort(q)).ok_or_else(degenerate)?;
            let offset = (pixel - predicted).norm();
            if fit.explained < self.params.verify.min_explained {
                return Err(format!("hole {i} ({kind}): its outline explains only {:.2} of the pixels", fit.explained));
            }
            // A centre taken from the homography is weaker evidence than a fitted one.
            let score = hole_score(&fit, offset, tolerance) * if predicted_only[i] { 0.5 } else { 1.0 };
            let refined = !predicted_only[i];
            holes.push(DetectedHole {
                kind: hole.kind,
                pixel: *pixel,
                refined,
                score,
                sigma_px: fit.sigma_px,
                shape: fit.shape,
            });
        }
        // Never a mirror image: the camera sees the outlet's front.
        let det = local_jacobian(&h, lens, &centroid(model)).ok_or_else(degenerate)?.determinant();
        if det.is_nan() || det <= 0.0 {
            return Err("the refined holes read as a mirror image".to_string());
        }
        let ground = self.ground_evidence(grey, lens, &h);
        if ground == GroundEvidence::Against {
            return Err("the ground holes are no darker than where a half turn would put them".to_string());
        }
        // The outlines decide the reading against its half turn, unless the
        // ground holes did: then the mirror is all that is left, and a camera
        // never sees one (the determinant above), so the slots only veto a
        // reading they clearly contradict. Slot lengths are weak evidence on
        // real photographs (a T-slot and a hot slot 8-12 px long in blur).
        outlines_seen.clear();
        outlines_seen
            .extend(holes.iter().zip(jacobians.iter()).zip(&self.outlines).map(|((d, j), o)| (d.pixel, *j, *o)));
        if let Some(gain) = identity_gain(grey, outlines_seen, &self.outlines, &self.params.refine) {
            tracing::debug!(gain, ?ground, "outlines against the swapped reading");
            let least = match ground {
                GroundEvidence::Decides => -self.params.verify.max_identity_contradiction,
                _ => self.params.verify.min_identity_gain,
            };
            if gain.is_nan() || gain < least {
                return Err(format!(
                    "the slot outlines fit the swapped reading (neutral and hot exchanged) about as well: gain {gain:.3}"
                ));
            }
        }
        // The detection's own vector: one let go by an earlier detection.
        let mut kept = crate::take_spare(&super::SPARE_HOLES);
        kept.clear();
        kept.extend_from_slice(holes);
        Ok(Detection { holes: kept, score, homography: h })
    }
}

/// A fitted hole's sigma is at least this share of the median sigma of the
/// outlet's fitted holes. Rendered scenes (2100 frames), |error|^2 / 2 sigma^2
/// (1 on average if honest) by the hole's sigma over that median: below 0.5, 2.5
/// on average and 1% beyond 26; 0.5-0.7, 1.15; 0.7-0.85, 0.88; above, 0.7-0.75.
/// 0.8 rather than 0.7 trims the worst holes' NEES by a little more.
pub const MIN_SIGMA_OF_MEDIAN: f64 = 0.8;

/// The homography through the fitted holes (`refined`, template order), after
/// dropping one by one, worst first, the holes further than `tolerance` pixels
/// from it: a fit caught by a glint or a dark spot. `Err` when fewer than
/// `min_holes` remain.
fn plane_fit(
    model: &[Point2<f64>],
    refined: &mut [Option<Point2<f64>>],
    lens: &Lens,
    tolerance: f64,
    min_holes: usize,
    pairs: &mut Vec<(Point2<f64>, Point2<f64>)>,
) -> Result<Matrix3<f64>, String> {
    loop {
        pairs.clear();
        pairs.extend(model.iter().zip(refined.iter()).filter_map(|(t, r)| r.map(|r| (*t, lens.undistort(r)))));
        if pairs.len() < min_holes {
            return Err(format!("only {} holes lie on one plane", pairs.len()));
        }
        let h = fit_homography(pairs).ok_or("no homography through the refined holes")?;
        let worst = model
            .iter()
            .zip(refined.iter())
            .enumerate()
            .filter_map(|(i, (t, r))| {
                let r = lens.undistort((*r)?);
                apply(&h, t).map(|q| (i, (q - r).norm()))
            })
            .max_by(|a, b| a.1.total_cmp(&b.1));
        match worst {
            Some((i, e)) if e > tolerance || e.is_nan() => {
                tracing::debug!(hole = i, error_px = e, tolerance, "hole off the plane: dropped");
                refined[i] = None;
            }
            _ => return Ok(h),
        }
    }
}

/// Per fitted hole, the standard deviation per axis (pixels) its disagreement
/// with the other holes implies: with e its residual from the homography
/// through all of them and r from the homography through the others
/// (leave-one-out), e r / 2 estimates its variance per axis (the studentised
/// residual of least squares: e shrinks by the hole's leverage and r grows by
/// it, their product does neither). `None` for a hole not fitted, or where
/// fewer than five others are. Into `buffers.sigmas`, one per template hole.
fn agreement_sigmas(model: &[Point2<f64>], refined: &[Option<Point2<f64>>], lens: &Lens, buffers: &mut Agreement) {
    let Agreement { indexed: pairs, all, others, sigmas: out } = buffers;
    pairs.clear();
    pairs.extend(model.iter().zip(refined).enumerate().filter_map(|(i, (t, r))| Some((i, *t, lens.undistort((*r)?)))));
    out.clear();
    out.resize(model.len(), None);
    if pairs.len() < 6 {
        return;
    }
    all.clear();
    all.extend(pairs.iter().map(|(_, t, p)| (*t, *p)));
    let Some(full) = fit_homography(all) else { return };
    for (k, (i, t, p)) in pairs.iter().enumerate() {
        others.clear();
        others.extend(all.iter().enumerate().filter(|(j, _)| *j != k).map(|(_, pair)| *pair));
        let (Some(e), Some(r)) = (
            apply(&full, t).map(|q| (q - p).norm()),
            fit_homography(others).and_then(|h| apply(&h, t)).map(|q| (q - p).norm()),
        ) else {
            continue;
        };
        let sigma = (e * r / 2.0).sqrt();
        if let Some(slot) = out.get_mut(*i) {
            *slot = sigma.is_finite().then_some(sigma);
        }
    }
}

/// Standard deviation per axis (pixels) of the point the homography through
/// `fitted` (template mm, undistorted pixel, that pixel's sigma) puts `t` at,
/// from the fitted pixels' own errors carried through the fit (numerically:
/// each pixel moved in turn). Large where `t` lies far outside the fitted holes.
fn prediction_sigma(
    fitted: &[(Point2<f64>, Point2<f64>, f64)],
    t: &Point2<f64>,
    buffers: &mut FitBuffers,
) -> Option<f64> {
    let FitBuffers { pairs, moved } = buffers;
    pairs.clear();
    pairs.extend(fitted.iter().map(|(m, p, _)| (*m, *p)));
    let base = apply(&fit_homography(pairs)?, t)?;
    let step = 0.01;
    let mut variance = 0.0;
    for (k, (_, _, sigma)) in fitted.iter().enumerate() {
        for axis in 0..2 {
            moved.clear();
            moved.extend_from_slice(pairs);
            moved[k].1[axis] += step;
            let q = apply(&fit_homography(moved)?, t)?;
            variance += ((q - base) / step).norm_squared() * sigma * sigma;
        }
    }
    // Per axis: half the trace.
    let sigma = (variance / 2.0).sqrt();
    sigma.is_finite().then_some(sigma)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector2;

    fn sigmas_of(model: &[Point2<f64>], refined: &[Option<Point2<f64>>], lens: &Lens) -> Vec<Option<f64>> {
        let mut buffers = Agreement::default();
        agreement_sigmas(model, refined, lens, &mut buffers);
        buffers.sigmas
    }

    fn predicted_sigma(fitted: &[(Point2<f64>, Point2<f64>, f64)], t: &Point2<f64>) -> Option<f64> {
        prediction_sigma(fitted, t, &mut FitBuffers::default())
    }

    /// A 2x1's six holes (template mm) seen at 3 px per mm, shifted to (300, 200).
    fn seen_2x1() -> (Vec<Point2<f64>>, Vec<Point2<f64>>) {
        let model: Vec<Point2<f64>> =
            outlet_protocol::OutletGeometry::us_2x1().holes.iter().map(|h| h.position()).collect();
        let image = model.iter().map(|t| Point2::new(300.0 + 3.0 * t.x, 200.0 + 3.0 * t.y)).collect();
        (model, image)
    }

    #[test]
    fn the_plane_fit_drops_a_hole_off_the_plane_and_refuses_when_too_few_remain() {
        let (model, image) = seen_2x1();
        let lens = Lens { camera: None };
        let mut refined: Vec<Option<Point2<f64>>> = image.iter().map(|p| Some(*p)).collect();
        refined[1] = Some(image[1] + Vector2::new(6.0, -2.0));
        let h = plane_fit(&model, &mut refined, &lens, 1.0, 4, &mut Vec::new()).expect("five holes remain");
        assert_eq!(refined[1], None, "the moved hole is dropped");
        assert!(refined.iter().filter(|r| r.is_some()).count() == 5);
        let q = apply(&h, &model[1]).expect("finite");
        assert!((q - image[1]).norm() < 1e-6, "the fit puts the dropped hole back at {q}");
        let mut refined: Vec<Option<Point2<f64>>> = image.iter().map(|p| Some(*p)).collect();
        refined[1] = Some(image[1] + Vector2::new(6.0, -2.0));
        let why = plane_fit(&model, &mut refined, &lens, 1.0, 6, &mut Vec::new()).expect_err("only five on the plane");
        assert!(why.contains("only 5 holes"), "{why}");
    }

    #[test]
    fn a_hole_the_others_disagree_with_gets_the_disagreement_as_its_sigma() {
        let (model, image) = seen_2x1();
        let lens = Lens { camera: None };
        let exact: Vec<Option<Point2<f64>>> = image.iter().map(|p| Some(*p)).collect();
        let sigmas = sigmas_of(&model, &exact, &lens);
        assert!(sigmas.iter().all(|s| s.is_some_and(|s| s < 1e-6)), "{sigmas:?}");
        // One hole 0.8 px off, as a fit pulled by a T-slot's branch would be.
        let mut moved = exact.clone();
        moved[4] = Some(image[4] + Vector2::new(0.8, 0.0));
        let sigmas = sigmas_of(&model, &moved, &lens);
        let own = sigmas[4].expect("fitted");
        assert!(own > 0.3 && own < 0.8, "the moved hole: {own:.3} px");
        let others = sigmas.iter().enumerate().filter(|(i, _)| *i != 4).filter_map(|(_, s)| *s).fold(0.0, f64::max);
        assert!(others < own, "the others {others:.3} px, the moved hole {own:.3} px");
        // Too few fitted holes to tell: no claim.
        let mut few = exact;
        few[0] = None;
        assert!(sigmas_of(&model, &few, &lens).iter().all(Option::is_none));
    }

    #[test]
    fn a_prediction_from_four_holes_is_less_sure_than_one_from_five() {
        let (model, image) = seen_2x1();
        let with = |ks: &[usize]| -> Vec<(Point2<f64>, Point2<f64>, f64)> {
            ks.iter().map(|&k| (model[k], image[k], 0.2)).collect()
        };
        // Hole 5 (the lower ground) from the upper receptacle and the lower slots.
        let four = predicted_sigma(&with(&[0, 1, 3, 4]), &model[5]).expect("four");
        let five = predicted_sigma(&with(&[0, 1, 2, 3, 4]), &model[5]).expect("five");
        assert!(four.is_finite() && five.is_finite());
        assert!(four > five, "four holes {four:.3} px, five {five:.3} px");
        // Extrapolating far beyond the fitted holes is less sure than between them.
        let far = predicted_sigma(&with(&[0, 1, 2, 3, 4]), &Point2::new(0.0, 120.0)).expect("far");
        assert!(far > 2.0 * five, "far {far:.3} px, near {five:.3} px");
        // Sure pixels make a sure prediction: the sigma scales with theirs.
        let sure: Vec<_> = with(&[0, 1, 2, 3, 4]).into_iter().map(|(m, p, _)| (m, p, 0.02)).collect();
        let sure = predicted_sigma(&sure, &model[5]).expect("sure");
        assert!((sure * 10.0 - five).abs() < 1e-3 * five, "{sure} against {five}");
    }
}
