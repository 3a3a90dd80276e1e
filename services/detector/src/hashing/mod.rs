//! Stage 3 of the detector, geometric filtering (paper, section III.C): among the
//! classified hole candidates, the one set of holes that the outlet template
//! explains, or none.
//!
//! Offline, [`HashTable::new`] takes every ordered triple of template holes with a
//! wide enough basis angle (a *model basis*), writes every other hole in the affine
//! frame of that triple and files the basis under the hole's quantised affine
//! coordinates. Buckets are also keyed by the classes of the three basis holes and
//! of the hashed hole, so a vote needs class agreement as well as position.
//!
//! Online, [`find_outlet`] takes each candidate with pairs of its nearest
//! neighbours as bases (enumerated, not drawn: the result is reproducible; each
//! triangle once, from its widest corner), hashes the candidates around it and
//! counts the votes of each model basis. Every model basis with enough votes gives
//! an affine transform, scored with the paper's equation (2): a template hole
//! counts when a candidate of its class lies within MaxDist of its projection,
//! each candidate used once.
//!
//! Beyond the paper:
//! - camera views are perspective, not affine: a hypothesis with 4 matches is
//!   refitted to them (least squares: affine below 6 matches, normalised DLT
//!   homography from 6), re-projected and re-scored until its matches settle;
//! - MaxDist and the size check scale with the hole's predicted apparent size;
//! - guards: orientation-preserving (the camera sees the front, never a mirror
//!   image), not degenerate, at most 60 degrees off-axis, bounded perspective,
//!   candidate sizes that agree with the transform's scale;
//! - verification: every match must be predicted by a fit to the others
//!   (leave-one-out), and the result must be unlikely as a coincidence among the
//!   candidates around it (a-contrario number of false alarms, [`HashParams::max_nfa`]):
//!   4 of 6 holes suffice among few candidates, among 150 random ones they do not;
//! - the answer is "none" when another interpretation of the candidates (another
//!   place, or the same holes relabelled, e.g. turned 180 degrees) scores as well.
//!
//! A false alarm costs far more than a miss: every doubt gives "none".

mod fit;
mod grid;
mod params;
mod search;
mod significance;
mod table;

pub use fit::Intrinsics;
pub use params::HashParams;
pub use table::HashTable;

use crate::Class;
use nalgebra::{Matrix2, Matrix3, Point2, Vector2};
use search::{Buffers, NONE, Online, Search, widest_corner};

/// Most holes a template may have. The table holds every ordered triple of holes,
/// each hashing all other holes, so its size grows as n^4 (24 holes: about a
/// million entries).
pub const MAX_TEMPLATE_HOLES: usize = 24;

/// Most candidates looked at; those beyond (in input order) are ignored. The
/// detector gives 30-150.
pub const MAX_CANDIDATES: usize = 2048;

/// Fewest template holes: with 3, every triple of candidates would be an outlet.
pub const MIN_TEMPLATE_HOLES: usize = 4;

/// The one outlet found.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct OutletMatch {
    /// Template (its units, mm) to image (pixels), homogeneous: a homography, or an
    /// affine transform (last row 0 0 1) when fewer than
    /// [`HashParams::min_homography_matches`] holes matched.
    pub transform: Matrix3<f64>,
    /// Template holes matched by a candidate of their class (equation (2)).
    pub score: usize,
    /// Per template hole (template order), the index of its candidate in the input.
    pub assignment: Vec<Option<usize>>,
    /// Per template hole (template order), its position predicted by `transform`.
    pub projected: Vec<Point2<f64>>,
}

pub(super) fn class_index(class: Class) -> Option<u8> {
    match class {
        Class::Power => Some(0),
        Class::Ground => Some(1),
        Class::Background => None,
    }
}

pub(super) fn finite_or(value: f64, fallback: f64) -> f64 {
    if value.is_finite() { value } else { fallback }
}

/// 2D cross product (z of the 3D one).
pub(super) fn cross(a: Vector2<f64>, b: Vector2<f64>) -> f64 {
    a.x * b.y - a.y * b.x
}

/// Ratio of the smaller to the larger singular value of a 2x2 matrix.
pub(super) fn axis_ratio(j: &Matrix2<f64>) -> f64 {
    let e = (j[(0, 0)] + j[(1, 1)]) / 2.0;
    let f = (j[(0, 0)] - j[(1, 1)]) / 2.0;
    let g = (j[(1, 0)] + j[(0, 1)]) / 2.0;
    let h = (j[(1, 0)] - j[(0, 1)]) / 2.0;
    // Values are pixels per template unit: no overflow, and hypot is slow.
    let q = (e * e + h * h).sqrt();
    let r = (f * f + g * g).sqrt();
    if q + r > 0.0 { (q - r).abs() / (q + r) } else { 0.0 }
}

/// [`axis_ratio`] of the outlet as seen along the ray through `at` (an
/// undistorted pixel), where the camera is known: the cosine of the angle
/// between that ray and the face's normal, wherever in the image the outlet
/// lies. In the image itself a face off the optical axis is also stretched
/// along the radius by 1/cos of the ray's angle from the axis (the image
/// plane is not square to the ray), so that the same view of an outlet read
/// 57 degrees at the image's centre and beyond 60 near its edge (the Willow
/// photographs seen by a turned camera: 11-12 holes matched, then refused).
/// Without a camera, the image's own ratio.
pub(super) fn view_axis_ratio(j: &Matrix2<f64>, at: Point2<f64>, intrinsics: Option<&Intrinsics>) -> f64 {
    let Some(k) = intrinsics else { return axis_ratio(j) };
    // Normalised image coordinates per template unit.
    let n = Matrix2::new(j[(0, 0)] / k.fx, j[(0, 1)] / k.fx, j[(1, 0)] / k.fy, j[(1, 1)] / k.fy);
    let (x, y) = ((at.x - k.cx) / k.fx, (at.y - k.cy) / k.fy);
    let r2 = x * x + y * y;
    if !(r2 > 1e-18 && r2.is_finite()) {
        return axis_ratio(&n);
    }
    // Onto the plane square to the ray: the radial component shrinks by
    // cos = 1 / sqrt(1 + r^2), the tangential one keeps (a common scale aside).
    let radial = Vector2::new(x, y) / r2.sqrt();
    let shrink = 1.0 - 1.0 / (1.0 + r2).sqrt();
    let onto_ray = Matrix2::identity() - radial * radial.transpose() * shrink;
    axis_ratio(&(onto_ray * n))
}

thread_local! {
    /// The search's vectors and sets, kept between calls.
    static BUFFERS: std::cell::RefCell<Buffers> = std::cell::RefCell::new(Buffers::default());
}

/// Finds the one outlet of `table`'s template among classified candidates, or
/// `None` (no outlet, or more than one way to see one).
///
/// - `points`: candidate centres in undistorted image pixels;
/// - `classes`: the classifier's verdicts (`Background` candidates are ignored);
/// - `sizes`: each candidate's apparent hole size in pixels, measured as
///   [`HashParams::hole_size`] is on the template (e.g. the larger side of its
///   bounding box). Candidates with a non-finite centre or a size that is not
///   finite and positive are ignored, as are indices beyond the shortest slice.
///
/// Deterministic: the same input gives the same answer.
pub fn find_outlet(
    table: &HashTable,
    points: &[Point2<f64>],
    classes: &[Class],
    sizes: &[f64],
    params: &HashParams,
) -> Option<OutletMatch> {
    let mut found = OutletMatch::default();
    find_outlet_into(table, points, classes, sizes, params, &mut found).then_some(found)
}

/// [`find_outlet`] into `found`, whose vectors are reused: true when an outlet
/// was found (`found` holds it), false when none (`found` is then stale). The
/// detector hashes every frame.
pub(crate) fn find_outlet_into(
    table: &HashTable,
    points: &[Point2<f64>],
    classes: &[Class],
    sizes: &[f64],
    params: &HashParams,
    found: &mut OutletMatch,
) -> bool {
    crate::with_scratch(&BUFFERS, |buffers| search_with(table, points, classes, sizes, params, buffers, found))
}

fn search_with(
    table: &HashTable,
    points: &[Point2<f64>],
    classes: &[Class],
    sizes: &[f64],
    params: &HashParams,
    buffers: &mut Buffers,
    out: &mut OutletMatch,
) -> bool {
    let _span = tracing::debug_span!("hashing").entered();
    let holes = table.holes();
    let usable = !table.bases.is_empty() && params.hole_size > 0.0 && params.size_tolerance >= 1.0;
    if !usable {
        return false;
    }
    let Buffers {
        cand,
        grid,
        sorted_sizes,
        used,
        tried,
        seen,
        refined,
        accepted,
        accepted_assignments,
        hood_start,
        hood,
        near: scratch,
        votes,
        touched,
        bases_seen,
    } = buffers;
    cand.fill(points, classes, sizes);
    let m = cand.len();
    if m < 3 {
        return false;
    }
    sorted_sizes.clear();
    sorted_sizes.extend_from_slice(&cand.size);
    sorted_sizes.sort_unstable_by(f64::total_cmp);
    grid.build(&cand.pos, sorted_sizes[m / 2]);
    let mut template_class = [u8::MAX; MAX_TEMPLATE_HOLES];
    for (t, &c) in template_class.iter_mut().zip(&table.classes) {
        *t = class_index(c).unwrap_or(u8::MAX);
    }
    used.clear();
    used.resize(m, 0);
    refined.clear();
    accepted.clear();
    accepted_assignments.clear();
    tried.clear();
    seen.clear();
    let mut search = Search {
        table,
        params,
        cand,
        grid,
        holes,
        template_class,
        min_score: params.min_score(holes),
        used,
        stamp: 0,
        tried,
        seen,
        refined,
        accepted,
        accepted_assignments,
        hypotheses: 0,
        half_turn: table.half_turn(),
        tests: 0,
    };
    if search.min_score > holes {
        return false;
    }

    // Each candidate's neighbourhood: candidates within the outlet's extent at the
    // largest scale its size allows, of compatible size; nearest first for the
    // first `k`, which make the online bases.
    let k_max = params.neighbours.max(2);
    let tol = params.size_tolerance;
    hood_start.clear();
    hood_start.resize(m + 1, 0);
    hood.clear();
    hood.reserve(m * 16);
    scratch.clear();
    scratch.reserve(m);
    for c in 0..m {
        let (pc, sc) = (search.cand.pos[c], search.cand.size[c]);
        let radius = table.extent * sc / params.hole_size * tol;
        scratch.clear();
        for (i, (p, &s)) in search.cand.pos.iter().zip(&search.cand.size).enumerate() {
            let d2 = (p - pc).norm_squared();
            if i != c && d2 <= radius * radius && s <= sc * tol * tol && s * tol * tol >= sc {
                scratch.push((d2, i as u32));
            }
        }
        let k = k_max.min(scratch.len());
        let by_distance = |a: &(f64, u32), b: &(f64, u32)| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1));
        if k > 0 && k < scratch.len() {
            scratch.select_nth_unstable_by(k - 1, by_distance);
        }
        scratch[..k].sort_unstable_by(by_distance);
        hood.extend(scratch.iter().map(|&(_, i)| i));
        hood_start[c + 1] = hood.len() as u32;
    }

    // Zero outside `vote`, as `Online` wants them.
    votes.clear();
    votes.resize(table.bases.len(), 0);
    touched.clear();
    touched.reserve(table.bases.len());
    let mut online = Online { votes, touched, min_votes: params.min_votes(holes).min(u16::MAX as usize) as u16 };
    let sin_online = finite_or(params.min_online_angle, 0.25).clamp(0.0, std::f64::consts::FRAC_PI_2).sin().max(1e-6);
    bases_seen.clear();
    bases_seen.reserve(m * 16);
    for c in 0..m {
        let list = &hood[hood_start[c] as usize..hood_start[c + 1] as usize];
        let k = k_max.min(list.len());
        for a in 0..k {
            for b in a + 1..k {
                // A triangle is one basis, from its widest corner: the model holds
                // every ordering, and the widest corner keeps its model angle wide.
                let Some([o, x, y]) =
                    widest_corner(&search.cand.pos, [c, list[a] as usize, list[b] as usize], sin_online)
                else {
                    continue;
                };
                let key = ((o as u64) << 42) | ((x.min(y) as u64) << 21) | x.max(y) as u64;
                if !bases_seen.insert(key) {
                    continue;
                }
                let hashed = &hood[hood_start[o] as usize..hood_start[o + 1] as usize];
                online.vote(&mut search, [o, x, y], hashed);
            }
        }
    }

    let found = search.decide();
    tracing::debug!(
        candidates = m,
        hypotheses = search.hypotheses,
        tests = search.tests,
        refined = search.tried.len(),
        verified = search.accepted.len(),
        found = found.is_some(),
        "geometric hashing"
    );
    let Some(found) = found else { return false };
    let best = &search.accepted[found];
    out.transform = best.transform;
    out.score = best.score;
    out.assignment.clear();
    out.assignment.extend(
        search.assignment_of(found).iter().map(|&i| if i == NONE { None } else { Some(search.cand.index[i as usize]) }),
    );
    out.projected.clear();
    out.projected.extend_from_slice(&best.projection.pos[..holes]);
    true
}

#[cfg(test)]
mod tests {
    use super::fit::{apply, fit_affine, fit_homography, fit_planar_pose};
    use super::significance::ln_binomial;
    use super::*;

    #[test]
    fn minimum_scores_are_two_thirds_of_the_holes() {
        let p = HashParams::default();
        assert_eq!((p.min_score(6), p.min_votes(6)), (4, 1));
        assert_eq!((p.min_score(12), p.min_votes(12)), (8, 4));
        assert_eq!(p.min_score(4), 4);
    }

    #[test]
    fn axis_ratio_is_the_ratio_of_singular_values() {
        let r = |a: f64| Matrix2::new(a.cos(), -a.sin(), a.sin(), a.cos());
        let m = r(0.3) * Matrix2::new(4.0, 0.0, 0.0, 2.0) * r(-1.1);
        assert!((axis_ratio(&m) - 0.5).abs() < 1e-12);
        assert!((axis_ratio(&Matrix2::new(3.0, 0.0, 0.0, -3.0)) - 1.0).abs() < 1e-12);
        assert_eq!(axis_ratio(&Matrix2::zeros()), 0.0);
    }

    /// A face 57 degrees off the ray to it, seen by a camera turned so that it
    /// lies near the image's corner: the image's own axis ratio departs from
    /// cos 57, the ray's does not (and a mirror image stays refused).
    #[test]
    fn the_axis_ratio_along_the_ray_is_the_cosine_of_the_off_axis_angle_anywhere_in_the_image() {
        use nalgebra::{Rotation3, Vector3};
        let k = Intrinsics { fx: 525.0, fy: 525.0, cx: 320.0, cy: 240.0 };
        let kmat = Matrix3::new(k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0);
        let off_axis = 57f64.to_radians();
        let mut image_departure = 0.0f64;
        for (turn_x, turn_y) in [(0.0, 0.0), (0.35, 0.2), (-0.3, 0.28), (0.1, -0.4)] {
            // The face 400 mm along the ray (0, 0, 1), tilted about x, then the
            // whole scene turned about the camera centre.
            let turn = Rotation3::from_euler_angles(turn_y, turn_x, 0.0);
            let face = turn * Rotation3::from_axis_angle(&Vector3::x_axis(), off_axis);
            let centre = turn * Vector3::new(0.0, 0.0, 400.0);
            let pose = Matrix3::from_columns(&[
                face.matrix().column(0).into_owned(),
                face.matrix().column(1).into_owned(),
                centre,
            ]);
            let h = kmat * pose;
            let at = apply(&h, Point2::origin());
            // d(pixel)/d(mm) at the face's centre.
            let step = 1e-4;
            let dx = (apply(&h, Point2::new(step, 0.0)) - at) / step;
            let dy = (apply(&h, Point2::new(0.0, step)) - at) / step;
            let j = Matrix2::from_columns(&[dx, dy]);
            let along_ray = view_axis_ratio(&j, at, Some(&k));
            assert!(
                (along_ray - off_axis.cos()).abs() < 1e-4,
                "turn {turn_x},{turn_y}: {along_ray} against {}",
                off_axis.cos()
            );
            image_departure = image_departure.max((axis_ratio(&j) - off_axis.cos()).abs());
            assert!((view_axis_ratio(&j, at, None) - axis_ratio(&j)).abs() < 1e-15);
        }
        assert!(image_departure > 0.03, "the image's own ratio strays from the angle's: {image_departure}");
    }

    #[test]
    fn fits_recover_exact_transforms() {
        let src: Vec<Point2<f64>> = [(0.0, 0.0), (12.7, 0.0), (6.35, 11.9), (0.0, 38.1), (12.7, 38.1), (6.35, 50.0)]
            .iter()
            .map(|&(x, y)| Point2::new(x, y))
            .collect();
        let h = Matrix3::new(3.1, -0.4, 320.0, 0.7, 2.6, 200.0, 0.002, -0.001, 1.0);
        let dst: Vec<Point2<f64>> = src.iter().map(|&p| apply(&h, p)).collect();
        let fitted = fit_homography(&src, &dst, Point2::new(6.0, 20.0)).expect("homography");
        for (s, d) in src.iter().zip(&dst) {
            assert!((apply(&fitted, *s) - d).norm() < 1e-9);
        }
        let a = Matrix3::new(3.1, -0.4, 320.0, 0.7, 2.6, 200.0, 0.0, 0.0, 1.0);
        let dst: Vec<Point2<f64>> = src.iter().map(|&p| apply(&a, p)).collect();
        let fitted = fit_affine(&src[..3], &dst[..3]).expect("affine");
        assert!((fitted - a).norm() < 1e-9);
        // Degenerate: too few or coincident points.
        assert!(fit_homography(&src[..3], &dst[..3], Point2::origin()).is_none());
        assert!(fit_affine(&[Point2::origin(); 3], &dst[..3]).is_none());
    }

    /// A 2x1's holes seen by a VGA camera 10 cm away, 38 degrees off-axis
    /// (the arm's last centimetres), in pixels.
    fn close_oblique_view(src: &[Point2<f64>], k: &Intrinsics) -> Vec<Point2<f64>> {
        use nalgebra::{Rotation3, Vector3};
        let rotation =
            Rotation3::from_axis_angle(&Vector3::x_axis(), 0.66) * Rotation3::from_axis_angle(&Vector3::z_axis(), 0.4);
        let t = Vector3::new(-8.0, -30.0, 100.0);
        src.iter()
            .map(|s| {
                let p = rotation * Vector3::new(s.x, s.y, 0.0) + t;
                Point2::new(k.fx * p.x / p.z + k.cx, k.fy * p.y / p.z + k.cy)
            })
            .collect()
    }

    #[test]
    fn a_rigid_plate_fit_holds_the_perspective_of_a_close_view_where_an_affine_fit_does_not() {
        let src: Vec<Point2<f64>> = [(0.0, 0.0), (12.7, 0.0), (6.35, 11.9), (0.0, 38.1), (12.7, 38.1), (6.35, 50.0)]
            .iter()
            .map(|&(x, y)| Point2::new(x, y))
            .collect();
        let k = Intrinsics { fx: 525.0, fy: 525.0, cx: 320.0, cy: 240.0 };
        let dst = close_oblique_view(&src, &k);
        // Leave the last hole out and predict it from the other five.
        let centre = Point2::new(6.35, 25.0);
        let plate = fit_planar_pose(&src[..5], &dst[..5], &k, centre).expect("pose");
        let affine = fit_affine(&src[..5], &dst[..5]).expect("affine");
        let plate_error = (apply(&plate, src[5]) - dst[5]).norm();
        let affine_error = (apply(&affine, src[5]) - dst[5]).norm();
        assert!(plate_error < 1e-6, "plate fit off by {plate_error} px");
        assert!(affine_error > 10.0, "the view is not perspective enough to test: affine off by {affine_error} px");
        // Four points fix it too; noise moves the prediction by about its size.
        let noisy: Vec<Point2<f64>> = dst
            .iter()
            .enumerate()
            .map(|(i, p)| p + nalgebra::Vector2::new(0.3 * (i as f64).sin(), -0.3 * (i as f64).cos()))
            .collect();
        let four = fit_planar_pose(&src[..4], &noisy[..4], &k, centre).expect("pose from four");
        assert!((apply(&four, src[5]) - dst[5]).norm() < 3.0);
        // w = 1 at the centre, as the homography's.
        assert!((plate[(2, 0)] * centre.x + plate[(2, 1)] * centre.y + plate[(2, 2)] - 1.0).abs() < 1e-9);
        // Too few points, or a camera without focal length: none.
        assert!(fit_planar_pose(&src[..3], &dst[..3], &k, centre).is_none());
        assert!(fit_planar_pose(&src, &dst, &Intrinsics { fx: 0.0, ..k }, centre).is_none());
    }

    #[test]
    fn a_triangle_is_based_at_its_widest_corner() {
        let pos = [Point2::new(0.0, 0.0), Point2::new(10.0, 0.0), Point2::new(5.0, 1.0), Point2::new(20.0, 0.0)];
        assert_eq!(widest_corner(&pos, [0, 1, 2], 0.1), Some([2, 0, 1]));
        assert_eq!(widest_corner(&pos, [0, 1, 3], 0.1), None);
    }

    #[test]
    fn binomials() {
        assert!((ln_binomial(9, 3) - 84f64.ln()).abs() < 1e-12);
        assert_eq!(ln_binomial(3, 0), 0.0);
    }
}
