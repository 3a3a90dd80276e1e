//! The arm controller of a trial, of the simplest honest kind: it aims the plug
//! at the chosen receptacle from the latest hole poses, goes to a stand-off in
//! front of it, and pushes only once every target hole's predicted error (the
//! pose's own in-plane sigma and the arm's, three times) is inside the
//! tolerance. Where the result is missing, ambiguous, a plane mismatch or too
//! uncertain it waits, then creeps on slowly. And the arm it drives: commanded
//! moves come out a little wrong, as a real arm's do.

use super::judge::{TIP_AHEAD_M, TOLERANCES_MM, prongs_mm};
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use outlet_client::HolePoses;
use outlet_sim::rng::SimRng;

/// How far in front of the face the prong tips wait before the push (m).
pub const STANDOFF_M: f64 = 0.03;
/// The longest move and the largest turn of one control step (a frame).
const MAX_STEP_M: f64 = 0.10;
const MAX_TURN_DEG: f64 = 25.0;
/// A step of this size or less counts as being at the stand-off.
const AT_STANDOFF_M: f64 = 0.003;
const AT_STANDOFF_DEG: f64 = 2.0;
/// Without any pose yet: how far to creep forward along the camera's axis per
/// step, and in all.
const CREEP_M: f64 = 0.03;
const MAX_CREEP_M: f64 = 0.06;
/// Missing results in a row after which the controller creeps towards the last
/// goal at a fraction of the step.
const PATIENCE: u32 = 2;
const SLOW_FRACTION: f64 = 0.3;

/// A pose whose own 3-sigma in-plane error is this many times a hole's
/// tolerance is followed slowly (seen: wrong poses with 3-sigma of 15-50 mm;
/// holding on them instead lost 2x1 outlets seen from 55 cm, 35 degrees).
const TOO_UNCERTAIN: f64 = 4.0;

/// The arm's repeatability, one sigma per axis: a translation is off by this
/// fraction of its length plus a floor, a turn by a fraction of its angle plus
/// a floor. A controller knows this from the arm's data sheet.
pub const ARM_TRANSLATION_FRACTION: f64 = 0.002;
pub const ARM_TRANSLATION_FLOOR_M: f64 = 0.02e-3;
pub const ARM_TURN_FRACTION: f64 = 0.01;
pub const ARM_TURN_FLOOR_RAD: f64 = 0.005 * std::f64::consts::PI / 180.0;

/// One hole of a usable result, as the controller uses it (camera frame).
#[derive(Debug, Clone, Copy)]
pub struct SeenHole {
    pub position_m: Vector3<f64>,
    /// The largest in-plane standard deviation (m).
    pub in_plane_sigma_m: f64,
}

/// A usable result: the outlet's orientation and its holes (camera frame).
#[derive(Debug, Clone)]
pub struct Estimate {
    /// Outlet frame to camera frame.
    pub rotation: Rotation3<f64>,
    pub holes: Vec<SeenHole>,
}

impl Estimate {
    /// The estimate of a result with a pose; `None` for any other result, or
    /// one whose rotation or covariances do not make sense.
    pub fn of(poses: &HolePoses) -> Option<Self> {
        if !poses.is_usable() {
            return None;
        }
        let r = Matrix3::from_fn(|i, j| poses.rotation[i][j]);
        let rotation = Rotation3::from_matrix_eps(&r, 1e-9, 50, Rotation3::identity());
        let holes = (0..poses.holes.len())
            .map(|k| {
                let f = poses.face_errors(k)?;
                Some(SeenHole {
                    position_m: Vector3::from(poses.holes[k].position_m),
                    in_plane_sigma_m: f.in_plane_max_sigma_m,
                })
            })
            .collect::<Option<Vec<_>>>()?;
        (holes.len() >= 3 && holes.len() % 3 == 0).then_some(Self { rotation, holes })
    }
}

/// What the controller does after a frame.
#[derive(Debug, Clone, PartialEq)]
pub enum Action {
    /// Stay and look again.
    Hold,
    /// Move the tool by this (the new camera frame in the current one).
    Move(Isometry3<f64>),
    /// Go to the stand-off pose and push in: the whole motion, from the current
    /// camera frame to the tool at contact.
    Insert(Isometry3<f64>),
}

/// The controller's state across the frames of one approach.
#[derive(Debug, Clone)]
pub struct Controller {
    /// The receptacle it aims at (template order), chosen on the first pose.
    pub target: Option<usize>,
    /// The camera pose it believes it has, from its own commands (odometry).
    belief: Isometry3<f64>,
    /// The last stand-off goal, in the odometry frame.
    goal: Option<Isometry3<f64>>,
    misses: u32,
    crept_m: f64,
    /// The largest predicted 3-sigma in-plane error over the target's holes at
    /// the last usable frame, relative to each hole's tolerance (mm, mm).
    pub last_prediction_mm: Option<f64>,
}

impl Default for Controller {
    fn default() -> Self {
        Self::new()
    }
}

impl Controller {
    pub fn new() -> Self {
        Self {
            target: None,
            belief: Isometry3::identity(),
            goal: None,
            misses: 0,
            crept_m: 0.0,
            last_prediction_mm: None,
        }
    }

    /// Whether any usable result was ever seen.
    pub fn found(&self) -> bool {
        self.target.is_some()
    }

    /// The next action after a frame whose result is `estimate` (`None`: missing,
    /// not found, ambiguous or a plane mismatch).
    pub fn step(&mut self, estimate: Option<&Estimate>) -> Action {
        let Some(est) = estimate else {
            self.misses += 1;
            return self.without_pose();
        };
        let receptacles = est.holes.len() / 3;
        let target = self.target.unwrap_or_else(|| nearest_to_axis(est)).min(receptacles - 1);
        let pose_ratio = TOLERANCES_MM
            .iter()
            .enumerate()
            .map(|(k, t)| 3e3 * est.holes[3 * target + k].in_plane_sigma_m / t)
            .fold(0.0, f64::max);
        self.misses = 0;
        self.target = Some(target);
        let standoff = goal(est, target, STANDOFF_M);
        self.goal = Some(self.belief * standoff);
        let (moved_m, turned) = size(&standoff);
        // The final motion: to the stand-off, then the push along the axis.
        let insert = goal(est, target, 0.0);
        let (insert_m, insert_turn) = size(&insert);
        let arm = arm_sigma_at_tips(insert_m, insert_turn);
        let mut worst: f64 = 0.0;
        let mut inside = true;
        for (k, tolerance) in TOLERANCES_MM.iter().enumerate() {
            let sigma = est.holes[3 * target + k].in_plane_sigma_m.hypot(arm);
            let predicted_mm = 3.0 * sigma * 1e3;
            worst = worst.max(predicted_mm / tolerance);
            inside &= predicted_mm < *tolerance;
        }
        self.last_prediction_mm = Some(worst);
        let at_standoff = moved_m <= AT_STANDOFF_M && turned <= AT_STANDOFF_DEG.to_radians();
        if at_standoff && inside {
            return Action::Insert(insert);
        }
        if at_standoff {
            // Too uncertain: look again from here.
            return Action::Hold;
        }
        // A pose unsure by centimetres may be a wrong one: only a little way
        // towards it, to look again from nearer.
        let fraction = if pose_ratio > TOO_UNCERTAIN { SLOW_FRACTION } else { 1.0 };
        self.command(limit(&standoff, fraction))
    }

    fn without_pose(&mut self) -> Action {
        if self.misses < PATIENCE {
            return Action::Hold;
        }
        match self.goal {
            Some(goal) => {
                let towards = self.belief.inverse() * goal;
                if size(&towards).0 <= AT_STANDOFF_M {
                    return Action::Hold;
                }
                self.command(limit(&towards, SLOW_FRACTION))
            }
            None if self.crept_m + CREEP_M <= MAX_CREEP_M + 1e-9 => {
                self.crept_m += CREEP_M;
                self.command(Isometry3::translation(0.0, 0.0, CREEP_M))
            }
            None => Action::Hold,
        }
    }

    fn command(&mut self, motion: Isometry3<f64>) -> Action {
        self.belief *= motion;
        Action::Move(motion)
    }
}

/// The receptacle whose centre is nearest the plug's axis: the least motion.
fn nearest_to_axis(est: &Estimate) -> usize {
    let off_axis = |r: usize| {
        let c = receptacle_centre(est, r);
        c.x.hypot(c.y) / c.z.abs().max(1e-3)
    };
    (0..est.holes.len() / 3).min_by(|&a, &b| off_axis(a).total_cmp(&off_axis(b))).unwrap_or(0)
}

fn receptacle_centre(est: &Estimate, r: usize) -> Vector3<f64> {
    let holes = &est.holes[3 * r..3 * r + 3];
    let layout = prongs_mm();
    let sum: Vector3<f64> = holes
        .iter()
        .zip(layout)
        .map(|(h, p)| h.position_m - est.rotation * Vector3::new(p[0] / 1e3, p[1] / 1e3, 0.0))
        .sum();
    sum / 3.0
}

/// The tool pose (in the current camera frame) whose prong tips stand
/// `standoff_m` in front of receptacle `r`'s holes along the outlet's normal,
/// turned as the outlet is: the least-squares fit of the three prongs.
pub fn goal(est: &Estimate, r: usize, standoff_m: f64) -> Isometry3<f64> {
    let rotation = UnitQuaternion::from_rotation_matrix(&est.rotation);
    let ahead = TIP_AHEAD_M + standoff_m;
    let sum: Vector3<f64> = est.holes[3 * r..3 * r + 3]
        .iter()
        .zip(prongs_mm())
        .map(|(h, p)| h.position_m - rotation * Vector3::new(p[0] / 1e3, p[1] / 1e3, ahead))
        .sum();
    Isometry3::from_parts(Translation3::from(sum / 3.0), rotation)
}

/// A motion's length (m) and angle (rad).
pub fn size(m: &Isometry3<f64>) -> (f64, f64) {
    (m.translation.vector.norm(), m.rotation.angle())
}

/// `fraction` of the motion, cut to one step's longest move and largest turn.
fn limit(m: &Isometry3<f64>, fraction: f64) -> Isometry3<f64> {
    let (length, angle) = size(m);
    let mut f = fraction;
    if length * f > MAX_STEP_M {
        f = MAX_STEP_M / length;
    }
    if angle * f > MAX_TURN_DEG.to_radians() {
        f = MAX_TURN_DEG.to_radians() / angle;
    }
    let rotation = UnitQuaternion::identity().slerp(&m.rotation, f);
    Isometry3::from_parts(Translation3::from(m.translation.vector * f), rotation)
}

/// The arm's error at the prong tips after a motion (one sigma per axis, m).
pub fn arm_sigma_at_tips(length_m: f64, angle_rad: f64) -> f64 {
    let t = ARM_TRANSLATION_FRACTION * length_m + ARM_TRANSLATION_FLOOR_M;
    let r = ARM_TURN_FRACTION * angle_rad + ARM_TURN_FLOOR_RAD;
    t.hypot(r * TIP_AHEAD_M)
}

/// What the arm does when told to move by `command`: the motion with its error.
pub fn execute(command: &Isometry3<f64>, rng: &mut SimRng) -> Isometry3<f64> {
    let (length, angle) = size(command);
    let st = ARM_TRANSLATION_FRACTION * length + ARM_TRANSLATION_FLOOR_M;
    let sr = ARM_TURN_FRACTION * angle + ARM_TURN_FLOOR_RAD;
    let dt = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * st;
    let dr = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * sr;
    // The turn's error is about the wrist (the camera): the tips swing with it.
    command * Isometry3::from_parts(Translation3::from(dt), UnitQuaternion::from_scaled_axis(dr))
}

#[cfg(test)]
mod tests {
    use super::*;
    use outlet_protocol::OutletGeometry;

    /// A 2x1 outlet `distance` ahead, head-on, its upper receptacle on the
    /// camera's axis, its holes with `sigma` in-plane.
    fn seen(distance: f64, sigma: f64) -> Estimate {
        let holes = OutletGeometry::us_2x1()
            .holes
            .iter()
            .map(|h| SeenHole {
                position_m: Vector3::new(h.position_mm[0] / 1e3, (h.position_mm[1] + 19.05) / 1e3, distance),
                in_plane_sigma_m: sigma,
            })
            .collect();
        Estimate { rotation: Rotation3::identity(), holes }
    }

    #[test]
    fn a_far_outlet_is_approached_a_step_at_a_time() {
        let mut c = Controller::new();
        let Action::Move(m) = c.step(Some(&seen(0.5, 0.1e-3))) else { panic!("should move") };
        assert!((size(&m).0 - MAX_STEP_M).abs() < 1e-9, "{m}");
        assert!(c.target.is_some());
    }

    #[test]
    fn at_the_standoff_a_certain_pose_is_inserted_and_an_uncertain_one_waited_on() {
        let d = TIP_AHEAD_M + STANDOFF_M;
        let mut c = Controller::new();
        c.target = Some(0);
        let Action::Insert(m) = c.step(Some(&seen(d, 0.1e-3))) else { panic!("should insert") };
        assert!((m.translation.vector - Vector3::new(0.0, 0.0, STANDOFF_M)).norm() < 1e-9, "{m}");
        assert_eq!(c.step(Some(&seen(d, 0.4e-3))), Action::Hold);
    }

    #[test]
    fn a_pose_unsure_by_centimetres_is_followed_slowly() {
        let mut c = Controller::new();
        let Action::Move(m) = c.step(Some(&seen(0.4, 5e-3))) else { panic!("should move") };
        let full = 0.4 - TIP_AHEAD_M - STANDOFF_M;
        assert!((size(&m).0 - SLOW_FRACTION * full).abs() < 1e-9, "{m}");
        assert_eq!(c.target, Some(0));
    }

    #[test]
    fn missing_results_are_waited_on_then_crept_through() {
        let mut c = Controller::new();
        assert_eq!(c.step(None), Action::Hold);
        assert_eq!(c.step(None), Action::Move(Isometry3::translation(0.0, 0.0, CREEP_M)));
        assert_eq!(c.step(None), Action::Move(Isometry3::translation(0.0, 0.0, CREEP_M)));
        assert_eq!(c.step(None), Action::Hold);
        assert!(!c.found());
    }

    #[test]
    fn the_arm_errs_in_proportion_to_the_move() {
        let mut rng = SimRng::new(7);
        let command = Isometry3::translation(0.0, 0.0, 0.2);
        let errors: Vec<f64> =
            (0..2000).map(|_| (execute(&command, &mut rng).translation.vector.z - 0.2).abs()).collect();
        let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
        let expected = ARM_TRANSLATION_FRACTION * 0.2 + ARM_TRANSLATION_FLOOR_M;
        assert!((rms / expected - 1.0).abs() < 0.15, "{rms} vs {expected}");
    }
}
