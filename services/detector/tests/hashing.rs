//! Geometric hashing (paper, section III.C) on synthetic candidate sets: known
//! affine and perspective views of the 2x1 and 2x2 templates among clutter,
//! missing holes, pure clutter, and degenerate input.
//!
//! Candidates are the true holes (0.5 px noise, sizes off by up to 25%) plus
//! clutter of random class and hole-like size. Clutter never lies on a hole (within
//! half its size), present or missing: a candidate there would be that hole.

use nalgebra::{Matrix2, Matrix3, Point2, Point3, Rotation3, Vector2, Vector3};
use outlet_detector::Class;
use outlet_detector::hashing::{HashParams, HashTable, Intrinsics, OutletMatch, find_outlet};
use outlet_protocol::CameraModel;
use outlet_protocol::geometry::OutletGeometry;
use outlet_sim::rng::SimRng;
use std::f64::consts::{PI, TAU};
use std::time::Instant;

/// Apparent size of a template hole (mm): the larger side of its bounding box.
const SLOT_SIZE_MM: f64 = 8.0;
const GROUND_SIZE_MM: f64 = 5.0;

struct Template {
    points: Vec<Point2<f64>>,
    classes: Vec<Class>,
}

fn template(name: &str) -> Template {
    let geometry = OutletGeometry::builtin(name).expect("built-in template");
    Template {
        points: geometry.holes.iter().map(|h| h.position()).collect(),
        classes: geometry.holes.iter().map(|h| Class::from(h.kind)).collect(),
    }
}

fn table(t: &Template) -> HashTable {
    HashTable::new(&t.points, &t.classes, &HashParams::default())
}

fn hole_size_mm(class: Class) -> f64 {
    if class == Class::Ground { GROUND_SIZE_MM } else { SLOT_SIZE_MM }
}

/// Candidates for `find_outlet`, with the truth.
#[derive(Default)]
struct Candidates {
    points: Vec<Point2<f64>>,
    classes: Vec<Class>,
    sizes: Vec<f64>,
    /// Per template hole, the index of its candidate (`None`: the hole is missing).
    truth: Vec<Option<usize>>,
    /// Every template hole's true pixel and apparent size, present or missing.
    holes: Vec<(Point2<f64>, f64)>,
}

impl Candidates {
    fn push(&mut self, p: Point2<f64>, class: Class, size: f64) -> usize {
        self.points.push(p);
        self.classes.push(class);
        self.sizes.push(size);
        self.points.len() - 1
    }

    fn find(&self, table: &HashTable) -> Option<OutletMatch> {
        self.find_with(table, &HashParams::default())
    }

    fn find_with(&self, table: &HashTable, params: &HashParams) -> Option<OutletMatch> {
        find_outlet(table, &self.points, &self.classes, &self.sizes, params)
    }

    fn on_a_hole(&self, p: Point2<f64>) -> bool {
        self.holes.iter().any(|(h, size)| (p - h).norm() < 0.5 * size)
    }

    /// Shuffles the candidates, so that the true ones are not first.
    fn shuffle(&mut self, rng: &mut SimRng) {
        let n = self.points.len();
        let mut order: Vec<usize> = (0..n).collect();
        for i in (1..n).rev() {
            order.swap(i, rng.below(i + 1));
        }
        let mut new_index = vec![0; n];
        for (new, &old) in order.iter().enumerate() {
            new_index[old] = new;
        }
        self.points = order.iter().map(|&i| self.points[i]).collect();
        self.classes = order.iter().map(|&i| self.classes[i]).collect();
        self.sizes = order.iter().map(|&i| self.sizes[i]).collect();
        for t in &mut self.truth {
            *t = t.map(|i| new_index[i]);
        }
    }
}

/// A view of the template plane: template mm to image px.
trait View {
    fn map(&self, p: Point2<f64>) -> Point2<f64>;
    /// Local scale (px per mm): sqrt of the Jacobian's determinant.
    fn scale(&self, p: Point2<f64>) -> f64 {
        let c = self.map(p);
        let dx = self.map(p + Vector2::new(0.01, 0.0)) - c;
        let dy = self.map(p + Vector2::new(0.0, 0.01)) - c;
        Matrix2::from_columns(&[dx, dy]).determinant().abs().sqrt() / 0.01
    }
}

struct Affine(Matrix3<f64>);

impl View for Affine {
    fn map(&self, p: Point2<f64>) -> Point2<f64> {
        self.0.transform_point(&p)
    }
}

/// A pinhole camera (f = 525 px, VGA, no distortion) looking at the template plane.
struct Perspective {
    rotation: Rotation3<f64>,
    translation: Vector3<f64>,
}

impl View for Perspective {
    fn map(&self, p: Point2<f64>) -> Point2<f64> {
        let x = self.rotation * Vector3::new(p.x, p.y, 0.0) + self.translation;
        Point2::new(525.0 * x.x / x.z + 319.5, 525.0 * x.y / x.z + 239.5)
    }
}

/// Rotation by any angle, 3-8 px/mm, anisotropy down to 0.6 along any direction,
/// shear up to 0.15.
fn random_affine(rng: &mut SimRng) -> Affine {
    let rot = |a: f64| Matrix2::new(a.cos(), -a.sin(), a.sin(), a.cos());
    let scale = rng.range(3.0, 8.0);
    let anisotropy = rng.range(0.6, 1.0);
    let shear = Matrix2::new(1.0, rng.range(-0.15, 0.15), 0.0, 1.0);
    let linear =
        rot(rng.range(0.0, TAU)) * Matrix2::new(scale, 0.0, 0.0, scale * anisotropy) * rot(rng.range(0.0, TAU)) * shear;
    let shift = Vector2::new(320.0 + rng.range(-50.0, 50.0), 240.0 + rng.range(-50.0, 50.0));
    let l = linear;
    Affine(Matrix3::new(l[(0, 0)], l[(0, 1)], shift.x, l[(1, 0)], l[(1, 1)], shift.y, 0.0, 0.0, 1.0))
}

/// The outlet 20-50 cm away, `off_axis` from the optical axis in any direction,
/// any roll, near the image centre.
fn random_perspective(rng: &mut SimRng, off_axis: f64) -> Perspective {
    let roll = Rotation3::from_axis_angle(&Vector3::z_axis(), rng.range(0.0, TAU));
    let azimuth = rng.range(0.0, TAU);
    let axis = nalgebra::Unit::new_normalize(Vector3::new(azimuth.cos(), azimuth.sin(), 0.0));
    let tilt = Rotation3::from_axis_angle(&axis, off_axis);
    let distance = rng.range(200.0, 500.0);
    let centre = Vector3::new(rng.range(-0.15, 0.15), rng.range(-0.1, 0.1), 1.0) * distance;
    Perspective { rotation: tilt * roll, translation: centre }
}

/// The template's holes seen through `view` with 0.5 px noise (each axis) and
/// sizes off by up to 25%; `keep` says which holes are there.
fn true_holes(rng: &mut SimRng, t: &Template, view: &dyn View, keep: &[bool]) -> Candidates {
    let mut c = Candidates::default();
    for (j, (&p, &class)) in t.points.iter().zip(&t.classes).enumerate() {
        let size = hole_size_mm(class) * view.scale(p);
        c.holes.push((view.map(p), size));
        if !keep[j] {
            c.truth.push(None);
            continue;
        }
        let q = view.map(p) + Vector2::new(rng.normal(), rng.normal()) * 0.5;
        let index = c.push(q, class, size * rng.range(0.8, 1.25));
        c.truth.push(Some(index));
    }
    c
}

fn all_holes(t: &Template, rng: &mut SimRng, view: &dyn View) -> Candidates {
    true_holes(rng, t, view, &vec![true; t.points.len()])
}

fn random_class(rng: &mut SimRng) -> Class {
    if rng.chance(0.5) { Class::Power } else { Class::Ground }
}

/// `count` clutter candidates inside the holes' bounding box grown 2x about its
/// centre, sized like holes at `scale` px/mm (4-9 mm).
fn add_clutter_around(rng: &mut SimRng, c: &mut Candidates, count: usize, scale: f64) {
    let (mut lo, mut hi) = (Point2::new(f64::MAX, f64::MAX), Point2::new(f64::MIN, f64::MIN));
    for (p, _) in &c.holes {
        lo = Point2::new(lo.x.min(p.x), lo.y.min(p.y));
        hi = Point2::new(hi.x.max(p.x), hi.y.max(p.y));
    }
    let (mid, span) = (nalgebra::center(&lo, &hi), hi - lo);
    let mut added = 0;
    while added < count {
        let p = Point2::new(mid.x + rng.range(-span.x, span.x), mid.y + rng.range(-span.y, span.y));
        if !c.on_a_hole(p) {
            let class = random_class(rng);
            c.push(p, class, scale * rng.range(4.0, 9.0));
            added += 1;
        }
    }
    c.shuffle(rng);
}

/// `count` clutter candidates anywhere in a VGA image, 4-20 px (the holes of
/// outlets 20-50 cm away).
fn add_clutter_anywhere(rng: &mut SimRng, c: &mut Candidates, count: usize) {
    let mut added = 0;
    while added < count {
        let p = Point2::new(rng.range(0.0, 640.0), rng.range(0.0, 480.0));
        if !c.on_a_hole(p) {
            let class = random_class(rng);
            c.push(p, class, rng.range(4.0, 20.0));
            added += 1;
        }
    }
    c.shuffle(rng);
}

fn pure_clutter(rng: &mut SimRng, count: usize) -> Candidates {
    let mut c = Candidates::default();
    add_clutter_anywhere(rng, &mut c, count);
    c
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Outcome {
    /// Every present hole assigned its candidate, nothing else.
    Exact,
    /// Nothing reported.
    Miss,
    /// Only right pairs, but a present hole left unassigned.
    Incomplete,
    /// A hole assigned a candidate not its own, or an outlet where there is none.
    Wrong,
}

/// [`judge`] against the truth and against its half turn (power holes to the
/// half-turned power holes, grounds to none); the better outcome.
fn judge_either_way(found: &Option<OutletMatch>, truth: &[Option<usize>], table: &HashTable) -> Outcome {
    let upright = judge(found, truth);
    let Some((_, image)) = table.half_turn() else { return upright };
    let turned: Vec<Option<usize>> = image.iter().map(|k| k.and_then(|k| truth[k])).collect();
    match (upright, judge(found, &turned)) {
        (Outcome::Wrong, other) => other,
        (upright, _) => upright,
    }
}

fn judge(found: &Option<OutletMatch>, truth: &[Option<usize>]) -> Outcome {
    let Some(m) = found else { return Outcome::Miss };
    assert_eq!(m.assignment.len(), truth.len());
    assert_eq!(m.projected.len(), truth.len());
    assert_eq!(m.score, m.assignment.iter().flatten().count());
    let mut exact = true;
    for (got, want) in m.assignment.iter().zip(truth) {
        match (got, want) {
            (Some(g), Some(w)) if g == w => {}
            (Some(_), _) => return Outcome::Wrong,
            (None, Some(_)) => exact = false,
            (None, None) => {}
        }
    }
    if exact { Outcome::Exact } else { Outcome::Incomplete }
}

#[derive(Default, Debug)]
struct Tally {
    exact: usize,
    miss: usize,
    incomplete: usize,
    wrong: usize,
}

impl Tally {
    fn add(&mut self, o: Outcome) {
        match o {
            Outcome::Exact => self.exact += 1,
            Outcome::Miss => self.miss += 1,
            Outcome::Incomplete => self.incomplete += 1,
            Outcome::Wrong => self.wrong += 1,
        }
    }

    fn total(&self) -> usize {
        self.exact + self.miss + self.incomplete + self.wrong
    }

    /// Exact in at least `percent` % of the trials, and never wrong.
    fn check(&self, what: &str, percent: usize) {
        println!("{what}: {self:?}");
        assert_eq!(self.wrong, 0, "{what}: wrong assignments");
        assert!(self.exact * 100 >= percent * self.total(), "{what}: {self:?}");
    }
}

#[test]
fn hashing_recovers_known_affine_transforms_with_half_the_candidates_clutter() {
    for name in ["2x1", "2x2"] {
        let t = template(name);
        let table = table(&t);
        let mut rng = SimRng::new(11);
        let mut tally = Tally::default();
        for _ in 0..200 {
            let view = random_affine(&mut rng);
            let mut c = all_holes(&t, &mut rng, &view);
            add_clutter_around(&mut rng, &mut c, t.points.len(), view.scale(t.points[0]));
            tally.add(judge(&c.find(&table), &c.truth));
        }
        tally.check(&format!("{name}, affine, as many clutter candidates as holes"), 95);
    }
}

#[test]
fn hashing_recovers_perspective_views_up_to_40_degrees_off_axis() {
    for name in ["2x1", "2x2"] {
        let t = template(name);
        let table = table(&t);
        let mut rng = SimRng::new(12);
        let (mut any, mut steep) = (Tally::default(), Tally::default());
        for trial in 0..200 {
            // Half the trials at 35-40 degrees, the paper's hardest views.
            let off_axis = if trial % 2 == 0 { rng.range(0.0, 40.0) } else { rng.range(35.0, 40.0) };
            let view = random_perspective(&mut rng, off_axis.to_radians());
            let mut c = all_holes(&t, &mut rng, &view);
            add_clutter_around(&mut rng, &mut c, t.points.len(), view.scale(t.points[0]));
            let found = c.find(&table);
            let outcome = judge(&found, &c.truth);
            if trial % 2 == 0 {
                any.add(outcome)
            } else {
                steep.add(outcome)
            }
            if let Some(m) = &found {
                // The transform predicts every hole, matched or not.
                for (j, p) in t.points.iter().enumerate() {
                    let err = (m.projected[j] - view.map(*p)).norm();
                    let size = hole_size_mm(t.classes[j]) * view.scale(*p);
                    assert!(err < 0.5 * size, "{name} hole {j}: predicted {err:.2} px off");
                }
            }
        }
        any.check(&format!("{name}, perspective 0-40 degrees, clutter"), 95);
        steep.check(&format!("{name}, perspective 35-40 degrees, clutter"), 95);
    }
}

/// The arm's last centimetres: the outlet 9-12 cm away, 30-40 degrees off-axis,
/// where one receptacle is a third larger in the image than the other.
fn close_oblique_perspective(rng: &mut SimRng) -> Perspective {
    let roll = Rotation3::from_axis_angle(&Vector3::z_axis(), rng.range(0.0, TAU));
    let azimuth = rng.range(0.0, TAU);
    let axis = nalgebra::Unit::new_normalize(Vector3::new(azimuth.cos(), azimuth.sin(), 0.0));
    let tilt = Rotation3::from_axis_angle(&axis, rng.range(30.0f64, 40.0).to_radians());
    let distance = rng.range(90.0, 120.0);
    Perspective { rotation: tilt * roll, translation: Vector3::new(0.0, 0.0, distance) }
}

#[test]
fn close_oblique_views_are_found_when_the_camera_is_known() {
    // The test's pinhole camera (`Perspective`).
    let camera = Intrinsics { fx: 525.0, fy: 525.0, cx: 319.5, cy: 239.5 };
    let with_camera = HashParams { intrinsics: Some(camera), ..HashParams::default() };
    for name in ["2x1", "2x2"] {
        let t = template(name);
        let table = table(&t);
        let mut rng = SimRng::new(21);
        let (mut known, mut unknown) = (Tally::default(), Tally::default());
        for _ in 0..100 {
            let view = close_oblique_perspective(&mut rng);
            // One hole missing: the hypotheses grow through fits of 4-5 matches.
            let missing = rng.below(t.points.len());
            let keep: Vec<bool> = (0..t.points.len()).map(|j| j != missing).collect();
            let mut c = true_holes(&mut rng, &t, &view, &keep);
            add_clutter_around(&mut rng, &mut c, t.points.len(), view.scale(t.points[0]));
            known.add(judge(&c.find_with(&table, &with_camera), &c.truth));
            unknown.add(judge(&c.find(&table), &c.truth));
        }
        // Without the camera (affine fits below six matches) far fewer are
        // found; the 2x1 at this seed also gives one wrong assignment, which the
        // detector's refinement and plane check stand behind.
        println!("{name} without the camera: {unknown:?}");
        known.check(&format!("{name}, 9-12 cm, 30-40 degrees, camera known"), 60);
        assert!(known.exact > unknown.exact, "{name}: the camera did not help: {known:?} against {unknown:?}");
    }
}

/// A 2x2 seen 57-59 degrees off-axis at its centre, 20-30 cm away: the far holes'
/// rays are 60-63 degrees off the face's normal. The view is within the 60-degree
/// limit, which holds at the outlet's centre; each hole gets `hole_axis_slack`.
#[test]
fn steep_views_within_the_limit_at_the_centre_are_found_though_far_holes_are_beyond_it() {
    let camera = Intrinsics { fx: 525.0, fy: 525.0, cx: 319.5, cy: 239.5 };
    let params = HashParams { intrinsics: Some(camera), ..HashParams::default() };
    let every_hole = HashParams { hole_axis_slack: 0.0, ..params.clone() };
    let t = template("2x2");
    let table = table(&t);
    let mut rng = SimRng::new(12);
    let (mut centre, mut each) = (Tally::default(), Tally::default());
    for _ in 0..60 {
        let roll = Rotation3::from_axis_angle(&Vector3::z_axis(), rng.range(0.0, TAU));
        let azimuth = rng.range(0.0, TAU);
        let axis = nalgebra::Unit::new_normalize(Vector3::new(azimuth.cos(), azimuth.sin(), 0.0));
        let tilt = Rotation3::from_axis_angle(&axis, rng.range(57.0f64, 59.0).to_radians());
        let view = Perspective { rotation: tilt * roll, translation: Vector3::new(0.0, 0.0, rng.range(200.0, 300.0)) };
        let c = all_holes(&t, &mut rng, &view);
        centre.add(judge(&c.find_with(&table, &params), &c.truth));
        each.add(judge(&c.find_with(&table, &every_hole), &c.truth));
    }
    println!("limit at the centre: {centre:?}; at every hole: {each:?}");
    centre.check("2x2, 57-59 degrees at the centre, 20-30 cm", 90);
    assert!(centre.exact > each.exact, "{centre:?} against {each:?}");
}

/// Local scale (px per mm) at a template point of a rendered scene.
fn scene_scale(scene: &outlet_sim::Scene, hole_mm: Point2<f64>) -> f64 {
    let project = |x: f64, y: f64| {
        scene.camera.project(&(scene.pose * Point3::new(x / 1000.0, y / 1000.0, 0.0))).expect("in front")
    };
    let c = project(hole_mm.x, hole_mm.y);
    let dx = project(hole_mm.x + 0.1, hole_mm.y) - c;
    let dy = project(hole_mm.x, hole_mm.y + 0.1) - c;
    Matrix2::from_columns(&[dx, dy]).determinant().abs().sqrt() / 0.1
}

#[test]
fn poses_of_the_rendered_scenarios_are_recovered() {
    // The simulator's poses (20-50 cm, up to 40 degrees off-axis, any roll, 30%
    // ground up) through an undistorted camera, with as many clutter as holes.
    let camera = CameraModel { distortion: [0.0; 5], ..CameraModel::default_vga() };
    let mut rng = SimRng::new(13);
    let sets =
        [("2x1", ["fw_2x1white", "orange2x1", "whitehall2x1"]), ("2x2", ["cracked2x2", "white2x2", "specular2x2"])];
    for (name, scenarios) in sets {
        let t = template(name);
        let table = table(&t);
        let mut tally = Tally::default();
        for scenario in scenarios {
            for index in 0..40 {
                let scene = outlet_sim::sample_scene(scenario, 5, index, &camera).expect("scene");
                let truth = outlet_sim::ground_truth(&scene, "x.png");
                let mut c = Candidates::default();
                for (j, hole) in truth.holes.iter().enumerate() {
                    let class = Class::from(hole.kind);
                    let size = hole_size_mm(class) * scene_scale(&scene, t.points[j]);
                    let pixel = Point2::new(hole.pixel[0], hole.pixel[1]);
                    c.holes.push((pixel, size));
                    let noisy = pixel + Vector2::new(rng.normal(), rng.normal()) * 0.5;
                    let index = c.push(noisy, class, size * rng.range(0.8, 1.25));
                    c.truth.push(Some(index));
                }
                add_clutter_around(&mut rng, &mut c, t.points.len(), scene_scale(&scene, t.points[0]));
                tally.add(judge(&c.find(&table), &c.truth));
            }
        }
        tally.check(&format!("{name}, rendered scenario poses, clutter"), 95);
    }
}

#[test]
fn outlets_among_150_candidates_are_found() {
    // The outlet seen in perspective, and clutter over the whole image up to 150
    // candidates: the detector's worst case.
    for name in ["2x1", "2x2"] {
        let t = template(name);
        let table = table(&t);
        let mut rng = SimRng::new(23);
        let mut tally = Tally::default();
        for _ in 0..200 {
            let off_axis = rng.range(0.0, 40.0).to_radians();
            let view = random_perspective(&mut rng, off_axis);
            let mut c = all_holes(&t, &mut rng, &view);
            add_clutter_anywhere(&mut rng, &mut c, 150 - t.points.len());
            tally.add(judge(&c.find(&table), &c.truth));
        }
        tally.check(&format!("{name}, perspective, 150 candidates"), 95);
    }
}

#[test]
fn a_2x1_with_two_holes_missing_is_found_with_score_4() {
    let t = template("2x1");
    let table = table(&t);
    let mut rng = SimRng::new(14);
    let mut tally = Tally::default();
    for a in 0..6 {
        for b in a + 1..6 {
            let both_grounds = t.classes[a] == Class::Ground && t.classes[b] == Class::Ground;
            for _ in 0..10 {
                let view = random_affine(&mut rng);
                let keep: Vec<bool> = (0..6).map(|j| j != a && j != b).collect();
                let mut c = true_holes(&mut rng, &t, &view, &keep);
                c.shuffle(&mut rng);
                let found = c.find(&table);
                let outcome = judge(&found, &c.truth);
                if both_grounds {
                    // Four slots alone look the same upright and turned 180 degrees:
                    // either reading, never other candidates (the detector then
                    // tells the two apart by the ground holes in the image).
                    assert_ne!(judge_either_way(&found, &c.truth, &table), Outcome::Wrong, "only the four slots");
                    continue;
                }
                tally.add(outcome);
                if let Some(m) = found {
                    assert_eq!(m.score, 4);
                }
            }
        }
    }
    tally.check("2x1 with 2 of 6 holes missing (not both grounds), no clutter", 95);
}

#[test]
fn missing_holes_among_clutter_are_missed_rather_than_misassigned() {
    missing_holes_among_clutter(&HashParams::default());
}

/// Views steeper than 60 degrees allowed, as on the Willow photographs at 61-66
/// degrees: without more holes there, a 5-of-6 with two clutter points comes out.
#[test]
fn steep_views_need_more_holes_than_the_minimum_score() {
    let steep = HashParams { min_axis_ratio: 0.38, ..HashParams::default() };
    missing_holes_among_clutter(&steep);
    let unguarded = HashParams { oblique_extra_holes: 0, ..steep };
    let wrong = missing_holes_among_clutter_tally(&unguarded).wrong;
    assert!(wrong > 0, "the steep-view rule guards nothing here");
}

fn missing_holes_among_clutter(params: &HashParams) {
    let tally = missing_holes_among_clutter_tally(params);
    println!("2x1 with 2 of 6 holes missing, 4 clutter candidates: {tally:?}");
    assert_eq!(tally.wrong, 0);
}

fn missing_holes_among_clutter_tally(params: &HashParams) -> Tally {
    // 4 of 6 holes with 4 clutter candidates around: whether 4 holes are a
    // coincidence depends on the clutter; never a wrong assignment.
    let t = template("2x1");
    let table = table(&t);
    let mut rng = SimRng::new(24);
    let mut tally = Tally::default();
    for a in 0..6 {
        for b in a + 1..6 {
            if t.classes[a] == Class::Ground && t.classes[b] == Class::Ground {
                continue;
            }
            for _ in 0..20 {
                let view = random_affine(&mut rng);
                let keep: Vec<bool> = (0..6).map(|j| j != a && j != b).collect();
                let mut c = true_holes(&mut rng, &t, &view, &keep);
                add_clutter_around(&mut rng, &mut c, 4, view.scale(t.points[0]));
                tally.add(judge(&c.find_with(&table, params), &c.truth));
            }
        }
    }
    tally
}

#[test]
fn slots_alone_give_the_slots_upright_or_half_turned() {
    // Without ground holes the slots look the same turned 180 degrees: hashing
    // gives one reading of the right candidates; the image decides which.
    for name in ["2x1", "2x2"] {
        let t = template(name);
        let table = table(&t);
        let mut rng = SimRng::new(25);
        let keep: Vec<bool> = t.classes.iter().map(|&c| c == Class::Power).collect();
        let mut found = 0;
        for _ in 0..50 {
            let view = random_affine(&mut rng);
            let mut c = true_holes(&mut rng, &t, &view, &keep);
            c.shuffle(&mut rng);
            let m = c.find(&table);
            found += usize::from(m.is_some());
            assert_ne!(judge_either_way(&m, &c.truth, &table), Outcome::Wrong, "{name}");
        }
        assert!(found >= 45, "{name}: {found} of 50 found");
    }
}

#[test]
fn a_duplex_knows_its_half_turn() {
    for name in ["2x1", "2x2"] {
        let t = template(name);
        let table = table(&t);
        let (centre, image) = table.half_turn().expect("a duplex is symmetric in its power holes");
        for (j, k) in image.iter().enumerate() {
            match (t.classes[j], k) {
                (Class::Power, Some(k)) => {
                    let turned = Point2::from(2.0 * centre.coords - t.points[j].coords);
                    assert!((t.points[*k] - turned).norm() < 1e-6, "{name}: hole {j} -> {k}");
                }
                (Class::Ground, None) => {}
                other => panic!("{name}: hole {j}: {other:?}"),
            }
        }
    }
}

#[test]
fn a_2x1_with_only_three_holes_is_not_found() {
    let t = template("2x1");
    let table = table(&t);
    let mut rng = SimRng::new(15);
    for a in 0..6 {
        for b in a + 1..6 {
            for d in b + 1..6 {
                for _ in 0..5 {
                    let view = random_affine(&mut rng);
                    let keep: Vec<bool> = (0..6).map(|j| j == a || j == b || j == d).collect();
                    let c = true_holes(&mut rng, &t, &view, &keep);
                    assert!(c.find(&table).is_none(), "holes {a} {b} {d} only");
                }
            }
        }
    }
}

#[test]
fn pure_clutter_gives_no_outlet() {
    // 30-150 candidates anywhere, power or ground at random (none background),
    // 4-20 px: harsher than classified images, where most clutter is background.
    for name in ["2x1", "2x2"] {
        let table = table(&template(name));
        let mut rng = SimRng::new(16);
        let trials = 500;
        let mut alarms = 0;
        for trial in 0..trials {
            let count = 30 + trial * 121 / trials;
            let c = pure_clutter(&mut rng, count);
            if let Some(m) = c.find(&table) {
                alarms += 1;
                println!("{name}: false alarm among {count} candidates, score {}", m.score);
            }
        }
        println!("{name}, pure clutter of 30-150 candidates: {alarms} false alarms in {trials}");
        assert!(alarms * 100 <= trials, "{name}: more than 1% false alarms");
        if name == "2x2" {
            assert_eq!(alarms, 0);
        }
    }
}

#[test]
fn a_2x1_outlet_is_not_taken_for_a_2x2() {
    let t1 = template("2x1");
    let table2 = table(&template("2x2"));
    let mut rng = SimRng::new(17);
    for _ in 0..200 {
        let view = random_affine(&mut rng);
        let mut c = all_holes(&t1, &mut rng, &view);
        c.shuffle(&mut rng);
        assert!(c.find(&table2).is_none());
    }
}

#[test]
fn a_2x2_outlet_is_two_2x1_outlets_and_gives_none() {
    // Either column is a 2x1: which one is meant cannot be told.
    let t2 = template("2x2");
    let table1 = table(&template("2x1"));
    let mut rng = SimRng::new(26);
    for _ in 0..100 {
        let view = random_affine(&mut rng);
        let mut c = all_holes(&t2, &mut rng, &view);
        c.shuffle(&mut rng);
        assert!(c.find(&table1).is_none());
    }
}

#[test]
fn ground_up_outlet_is_found_with_the_right_assignment() {
    for name in ["2x1", "2x2"] {
        let t = template(name);
        let table = table(&t);
        let mut rng = SimRng::new(18);
        for _ in 0..50 {
            let (s, a) = (rng.range(2.0, 5.0), PI + rng.range(-0.2, 0.2));
            let view =
                Affine(Matrix3::new(s * a.cos(), -s * a.sin(), 320.0, s * a.sin(), s * a.cos(), 240.0, 0.0, 0.0, 1.0));
            let mut c = all_holes(&t, &mut rng, &view);
            c.shuffle(&mut rng);
            let found = c.find(&table);
            assert_eq!(judge(&found, &c.truth), Outcome::Exact, "{name} ground up");
            // The ground hole is above its slots in the image.
            let m = found.expect("found");
            assert!(m.projected[2].y < m.projected[0].y, "{name}: ground hole not above its slot");
        }
    }
}

#[test]
fn a_mirror_image_is_not_reported() {
    // The camera sees an outlet's front, never its mirror image. The built-in
    // templates are mirror-symmetric, so this uses a chiral one.
    let p = |x: f64, y: f64| Point2::new(x, y);
    let t = Template {
        points: vec![p(0.0, 0.0), p(20.0, 0.0), p(0.0, 12.0), p(35.0, 5.0), p(10.0, 30.0), p(28.0, 25.0)],
        classes: vec![Class::Power, Class::Power, Class::Ground, Class::Power, Class::Ground, Class::Power],
    };
    let table = table(&t);
    let mut rng = SimRng::new(19);
    for _ in 0..100 {
        let (s, a) = (rng.range(2.0, 6.0), rng.range(0.0, TAU));
        let similarity = Matrix3::new(s * a.cos(), -s * a.sin(), 320.0, s * a.sin(), s * a.cos(), 240.0, 0.0, 0.0, 1.0);
        let mut c = all_holes(&t, &mut rng, &Affine(similarity));
        c.shuffle(&mut rng);
        assert_eq!(judge(&c.find(&table), &c.truth), Outcome::Exact, "direct view");
        let mirror = similarity * Matrix3::new(-1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0);
        let mut c = all_holes(&t, &mut rng, &Affine(mirror));
        c.shuffle(&mut rng);
        assert!(c.find(&table).is_none(), "mirror image reported");
    }
}

#[test]
fn an_outlet_partly_out_of_view_is_not_reported_when_the_image_size_is_known() {
    let t = template("2x1");
    let table = table(&t);
    let params = HashParams { image_size: Some([640.0, 480.0]), ..HashParams::default() };
    let mut rng = SimRng::new(27);
    for _ in 0..50 {
        // Turned 90 degrees at 4 px/mm: the lower ground hole (y = 26.95 mm) 10-40 px
        // left of the image, the other holes at least 11 px inside.
        let shift = Vector2::new(26.95 * 4.0 - rng.range(10.0, 40.0), rng.range(150.0, 330.0));
        let view = Affine(Matrix3::new(0.0, -4.0, shift.x, 4.0, 0.0, shift.y, 0.0, 0.0, 1.0));
        let keep: Vec<bool> = (0..6).map(|j| view.map(t.points[j]).x >= 0.0).collect();
        let c = true_holes(&mut rng, &t, &view, &keep);
        assert!(c.find_with(&table, &params).is_none());
        assert_eq!(judge(&c.find(&table), &c.truth), Outcome::Exact, "found when the image size is unknown");
    }
}

#[test]
fn results_are_reproducible() {
    let t = template("2x2");
    let table = table(&t);
    let mut rng = SimRng::new(20);
    for _ in 0..20 {
        let view = random_affine(&mut rng);
        let mut c = all_holes(&t, &mut rng, &view);
        add_clutter_around(&mut rng, &mut c, 40, view.scale(t.points[0]));
        assert_eq!(c.find(&table), c.find(&table));
    }
}

#[test]
fn degenerate_inputs_do_not_panic() {
    let params = HashParams::default();
    let t = template("2x1");
    let good = table(&t);
    let p = |x: f64, y: f64| Point2::new(x, y);
    // Empty, short and mismatched inputs.
    assert!(find_outlet(&good, &[], &[], &[], &params).is_none());
    assert!(find_outlet(&good, &[p(1.0, 2.0), p(3.0, 4.0)], &[Class::Power; 2], &[5.0; 2], &params).is_none());
    assert!(find_outlet(&good, &t.points, &t.classes, &[5.0; 2], &params).is_none());
    // Collinear, coincident, all background.
    let line: Vec<_> = (0..20).map(|i| p(i as f64 * 10.0, 5.0)).collect();
    assert!(find_outlet(&good, &line, &[Class::Power; 20], &[8.0; 20], &params).is_none());
    let same = vec![p(100.0, 100.0); 20];
    assert!(find_outlet(&good, &same, &[Class::Power; 20], &[8.0; 20], &params).is_none());
    assert!(find_outlet(&good, &line, &[Class::Background; 20], &[8.0; 20], &params).is_none());
    // NaN and infinite centres, NaN, infinite, zero and negative sizes.
    let mut rng = SimRng::new(21);
    let mut c = pure_clutter(&mut rng, 60);
    for i in (0..60).step_by(3) {
        c.points[i] = p(f64::NAN, 3.0);
        c.sizes[i + 1] = [f64::NAN, f64::INFINITY, 0.0, -4.0][i % 4];
        c.points[i + 2] = p(f64::INFINITY, f64::NEG_INFINITY);
    }
    let _ = c.find(&good);
    // Huge coordinates.
    let far = [p(1e300, -1e300), p(-1e300, 1e300), p(0.0, 0.0), p(1e-300, 0.0)];
    let _ = find_outlet(&good, &far, &[Class::Power; 4], &[1e300, 1e-300, 5.0, 5.0], &params);
    // Degenerate templates give tables in which nothing is found.
    for (points, classes) in [
        (vec![], vec![]),
        (t.points[..3].to_vec(), t.classes[..3].to_vec()),
        (line[..6].to_vec(), vec![Class::Power; 6]),
        (vec![p(1.0, 1.0); 6], vec![Class::Ground; 6]),
        (vec![p(f64::NAN, 0.0), p(1.0, 0.0), p(0.0, 1.0), p(1.0, 1.0)], vec![Class::Power; 4]),
        (t.points.clone(), vec![Class::Background; 6]),
        (t.points.clone(), t.classes[..2].to_vec()),
    ] {
        let bad = HashTable::new(&points, &classes, &params);
        assert_eq!(bad.bases(), 0);
        assert!(find_outlet(&bad, &t.points, &t.classes, &[8.0; 6], &params).is_none());
    }
    // Nonsense parameters.
    let silly = HashParams {
        bins: 0,
        range: f64::NAN,
        hole_size: -1.0,
        min_basis_angle: f64::NAN,
        max_nfa: f64::NAN,
        size_tolerance: 0.5,
        ..params.clone()
    };
    let silly_table = HashTable::new(&t.points, &t.classes, &silly);
    assert!(find_outlet(&silly_table, &t.points, &t.classes, &[8.0; 6], &silly).is_none());
    assert!(find_outlet(&good, &t.points, &t.classes, &[8.0; 6], &silly).is_none());
    let wild = HashParams { neighbours: usize::MAX, min_votes: Some(0), vote_tolerance: 1e9, ..params };
    let wild_table = HashTable::new(&t.points, &t.classes, &wild);
    let _ = find_outlet(&wild_table, &t.points, &t.classes, &[8.0; 6], &wild);
}

#[test]
fn time_per_call_is_reported() {
    // Figures for the report, not assertions: the best of 5 runs over 20 inputs,
    // the outlet in perspective with clutter anywhere (or clutter only).
    // `cargo test --release -p outlet-detector --test hashing time -- --nocapture`.
    for name in ["2x1", "2x2"] {
        let t = template(name);
        let table = table(&t);
        for count in [30, 80, 150] {
            let mut rng = SimRng::new(22);
            let with_outlet: Vec<Candidates> = (0..20)
                .map(|_| {
                    let off_axis = rng.range(0.0, 40.0).to_radians();
                    let view = random_perspective(&mut rng, off_axis);
                    let mut c = all_holes(&t, &mut rng, &view);
                    add_clutter_anywhere(&mut rng, &mut c, count - t.points.len());
                    c
                })
                .collect();
            let clutter: Vec<Candidates> = (0..20).map(|_| pure_clutter(&mut rng, count)).collect();
            for (what, set) in [("outlet + clutter", &with_outlet), ("clutter only", &clutter)] {
                let mut best = f64::INFINITY;
                let mut found = 0;
                for _ in 0..5 {
                    let start = Instant::now();
                    found = set.iter().filter(|c| std::hint::black_box(c.find(&table)).is_some()).count();
                    best = best.min(start.elapsed().as_secs_f64() * 1e3 / set.len() as f64);
                }
                println!("{name}, {count} candidates, {what}: {best:.3} ms per call, found {found}/{}", set.len());
            }
        }
    }
}

#[test]
fn max_nfa_trades_missing_hole_recall_for_false_alarms() {
    // Figures for the report: 4 of 6 holes alone, and pure clutter, at several
    // thresholds. Asserts only that wrong assignments never occur.
    let t = template("2x1");
    let table = table(&t);
    for max_nfa in [1e-3, 1e-2, 1e-1] {
        let params = HashParams { max_nfa, ..HashParams::default() };
        let mut rng = SimRng::new(14);
        let mut four = Tally::default();
        for a in 0..6 {
            for b in a + 1..6 {
                if t.classes[a] == Class::Ground && t.classes[b] == Class::Ground {
                    continue;
                }
                for _ in 0..10 {
                    let view = random_affine(&mut rng);
                    let keep: Vec<bool> = (0..6).map(|j| j != a && j != b).collect();
                    let c = true_holes(&mut rng, &t, &view, &keep);
                    four.add(judge(&c.find_with(&table, &params), &c.truth));
                }
            }
        }
        let mut rng = SimRng::new(16);
        let alarms = (0..500)
            .filter(|&trial| pure_clutter(&mut rng, 30 + trial * 121 / 500).find_with(&table, &params).is_some())
            .count();
        println!(
            "max_nfa {max_nfa}: 4 of 6 holes found {}/{}; pure clutter false alarms {alarms}/500",
            four.exact,
            four.total()
        );
        assert_eq!(four.wrong, 0);
    }
}
