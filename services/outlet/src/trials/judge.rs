//! The judge of a simulated plug-in: where the plug's prongs land on the true
//! receptacle face, and what that makes of the trial. Strict and geometric
//! (issue 18): each prong within 1.0 mm of its hole's centre (ground 1.5 mm), the
//! plug's axis within 3 degrees of the face normal, the receptacle the controller
//! chose, the right polarity.
//!
//! Frames: the outlet frame of `CONTRACT.md` is the world (x right, y down seen
//! from the front, z into the wall, receptacle face at z = 0). The tool is the
//! camera: the plug is fixed to it, its axis the camera's z axis, its prong tips
//! [`TIP_AHEAD_M`] ahead of the camera centre laid out as a receptacle's holes
//! around its centre.

use nalgebra::{Isometry3, Point3, Vector3};
use outlet_protocol::geometry::{OutletGeometry, receptacle_holes};
use serde::Serialize;

/// How far ahead of the camera centre the prong tips are, along its axis (m):
/// at contact the camera is 17 cm from the face and sees the whole outlet.
pub const TIP_AHEAD_M: f64 = 0.17;
/// A power blade's tip must land this close to its slot's centre (mm).
pub const POWER_TOLERANCE_MM: f64 = 1.0;
/// The ground pin's tip must land this close to its hole's centre (mm).
pub const GROUND_TOLERANCE_MM: f64 = 1.5;
/// The plug's axis must be this close to the face normal (degrees).
pub const AXIS_TOLERANCE_DEG: f64 = 3.0;

/// The prongs in the tool's x-y plane (mm), neutral, hot, ground: a receptacle's
/// holes around its centre, so that an aligned plug lands each in its own.
pub fn prongs_mm() -> [[f64; 2]; 3] {
    receptacle_holes(0.0, 0.0).map(|h| h.position_mm)
}

/// The prong tolerances in prong order (mm).
pub const TOLERANCES_MM: [f64; 3] = [POWER_TOLERANCE_MM, POWER_TOLERANCE_MM, GROUND_TOLERANCE_MM];

/// What a trial ends with.
#[derive(Debug, Clone, Serialize, PartialEq, Eq, PartialOrd, Ord, Hash, Copy)]
#[serde(rename_all = "snake_case")]
pub enum Class {
    /// In, within the tolerances, in the chosen receptacle, polarity right.
    Success,
    /// No usable hole poses in any frame of the trial.
    NeverFound,
    /// Hole poses came, but the controller never committed, and a push from
    /// where it stopped would not have gone in either.
    TimedOut,
    /// The plug went where the sought outlet is not (another plate, the wall,
    /// or a scene without the outlet).
    WrongOutlet,
    /// The plug went into another receptacle of the outlet than the chosen one.
    WrongReceptacle,
    /// The right receptacle, the plug turned so that neutral and hot swap.
    WrongPolarity,
    /// The right receptacle and polarity, a prong or the axis beyond tolerance.
    OffTolerance,
    /// Never committed, but a push from where it stopped would have succeeded.
    RefusedWouldHaveSucceeded,
    /// A scene without the sought outlet, and no insertion: what should happen.
    CorrectlyRefused,
}

impl Class {
    pub const ALL: [Class; 9] = [
        Class::Success,
        Class::NeverFound,
        Class::TimedOut,
        Class::WrongOutlet,
        Class::WrongReceptacle,
        Class::WrongPolarity,
        Class::OffTolerance,
        Class::RefusedWouldHaveSucceeded,
        Class::CorrectlyRefused,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            Class::Success => "success",
            Class::NeverFound => "never_found",
            Class::TimedOut => "timed_out",
            Class::WrongOutlet => "wrong_outlet",
            Class::WrongReceptacle => "wrong_receptacle",
            Class::WrongPolarity => "wrong_polarity",
            Class::OffTolerance => "off_tolerance",
            Class::RefusedWouldHaveSucceeded => "refused_would_have_succeeded",
            Class::CorrectlyRefused => "correctly_refused",
        }
    }

    /// A plug pushed into a place it does not belong: never acceptable.
    pub fn is_wrong_insertion(self) -> bool {
        matches!(self, Class::WrongOutlet | Class::WrongReceptacle | Class::WrongPolarity)
    }

    /// What the trial counts as: the robot did the right thing.
    pub fn is_success(self) -> bool {
        matches!(self, Class::Success | Class::CorrectlyRefused)
    }
}

/// What the simulator knows about the scene.
#[derive(Debug, Clone)]
pub struct Truth {
    /// The sought outlet's holes (outlet frame), `None` when the scene has none.
    pub geometry: Option<OutletGeometry>,
    /// The sought outlet's wall plate, width and height (mm), centred on the origin.
    pub plate_size_mm: [f64; 2],
}

/// How the trial ended. Tool poses take the tool (camera) frame to the outlet
/// frame, metres.
#[derive(Debug, Clone)]
pub enum Ending {
    NeverFound,
    /// The frame budget ran out with the tool where it is.
    TimedOut {
        tool: Isometry3<f64>,
        target: Option<usize>,
    },
    /// The controller pushed: the tool at the end of the push.
    Inserted {
        tool: Isometry3<f64>,
        target: usize,
    },
}

/// Where the plug meets the true face.
#[derive(Debug, Clone, Serialize)]
pub struct Landing {
    /// Each prong's line along the plug's axis meets the face plane here (mm).
    pub tips_mm: [[f64; 2]; 3],
    /// The plug's centre line meets the face plane here (mm).
    pub centre_mm: [f64; 2],
    /// The receptacle whose centre is nearest `centre_mm`.
    pub receptacle: Option<usize>,
    /// Each prong's distance from its hole of the chosen receptacle (mm).
    pub errors_mm: Option<[f64; 3]>,
    /// The angle between the plug's axis and the face normal (degrees).
    pub axis_deg: f64,
}

/// Where the plug of a tool at `tool` lands when pushed along its axis; `None`
/// when the axis does not point into the wall.
pub fn landing(truth: &Truth, tool: &Isometry3<f64>, target: Option<usize>) -> Option<Landing> {
    let axis = tool.rotation * Vector3::z();
    if axis.z < 0.05 {
        return None;
    }
    let land = |x_mm: f64, y_mm: f64| {
        let p = tool * Point3::new(x_mm / 1e3, y_mm / 1e3, TIP_AHEAD_M);
        let q = p - axis * (p.z / axis.z);
        [q.x * 1e3, q.y * 1e3]
    };
    let tips_mm = prongs_mm().map(|p| land(p[0], p[1]));
    let centre_mm = land(0.0, 0.0);
    let centres = truth.geometry.as_ref().map(receptacle_centres).unwrap_or_default();
    let receptacle =
        (0..centres.len()).min_by(|&a, &b| dist(centres[a], centre_mm).total_cmp(&dist(centres[b], centre_mm)));
    let errors_mm = target.and_then(|t| centres.get(t)).map(|c| {
        let holes = receptacle_holes(c[0], c[1]);
        std::array::from_fn(|k| dist(tips_mm[k], holes[k].position_mm))
    });
    Some(Landing { tips_mm, centre_mm, receptacle, errors_mm, axis_deg: axis.z.clamp(-1.0, 1.0).acos().to_degrees() })
}

/// The trial's class and, where the plug was pushed or could be, its landing.
pub fn classify(truth: &Truth, ending: &Ending) -> (Class, Option<Landing>) {
    match ending {
        Ending::NeverFound if truth.geometry.is_none() => (Class::CorrectlyRefused, None),
        Ending::NeverFound => (Class::NeverFound, None),
        Ending::TimedOut { .. } if truth.geometry.is_none() => (Class::CorrectlyRefused, None),
        Ending::TimedOut { tool, target } => {
            let (would, landing) = judge_insertion(truth, tool, target.unwrap_or(0));
            let class = if target.is_some() && would == Class::Success {
                Class::RefusedWouldHaveSucceeded
            } else {
                Class::TimedOut
            };
            (class, landing)
        }
        Ending::Inserted { tool, target } => judge_insertion(truth, tool, *target),
    }
}

/// The class of a push of the tool at `tool` aimed at receptacle `target`.
fn judge_insertion(truth: &Truth, tool: &Isometry3<f64>, target: usize) -> (Class, Option<Landing>) {
    let Some(geometry) = &truth.geometry else {
        return (Class::WrongOutlet, landing(truth, tool, None));
    };
    let Some(l) = landing(truth, tool, Some(target)) else {
        // A plug not pointing at the wall reaches no outlet.
        return (Class::WrongOutlet, None);
    };
    let [w, h] = truth.plate_size_mm;
    if l.centre_mm[0].abs() > w / 2.0 || l.centre_mm[1].abs() > h / 2.0 {
        return (Class::WrongOutlet, Some(l));
    }
    let centres = receptacle_centres(geometry);
    let (Some(landed), Some(chosen)) = (l.receptacle, centres.get(target)) else {
        return (Class::WrongReceptacle, Some(l));
    };
    if landed != target {
        return (Class::WrongReceptacle, Some(l));
    }
    let holes = receptacle_holes(chosen[0], chosen[1]).map(|h| h.position_mm);
    let swapped = dist(l.tips_mm[0], holes[1]) < dist(l.tips_mm[0], holes[0])
        && dist(l.tips_mm[1], holes[0]) < dist(l.tips_mm[1], holes[1]);
    if swapped {
        return (Class::WrongPolarity, Some(l));
    }
    let within = l.errors_mm.is_some_and(|e| e.iter().zip(TOLERANCES_MM).all(|(e, t)| *e <= t));
    if !within || l.axis_deg > AXIS_TOLERANCE_DEG {
        return (Class::OffTolerance, Some(l));
    }
    (Class::Success, Some(l))
}

/// The centre of each receptacle of `geometry` (mm, outlet frame), in template
/// order: the holes come three to a receptacle, neutral, hot, ground.
pub fn receptacle_centres(geometry: &OutletGeometry) -> Vec<[f64; 2]> {
    let layout = prongs_mm();
    geometry
        .holes
        .chunks_exact(3)
        .map(|r| {
            let [x, y] = r[0].position_mm;
            [x - layout[0][0], y - layout[0][1]]
        })
        .collect()
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn two_by_one() -> Truth {
        Truth { geometry: Some(OutletGeometry::us_2x1()), plate_size_mm: [70.0, 114.3] }
    }

    /// The tool whose prongs touch the face at receptacle `r`'s holes, shifted
    /// by `(dx, dy)` mm on the face, turned by `rotation` about the prong tips.
    fn at(r: usize, dx: f64, dy: f64, rotation: UnitQuaternion<f64>) -> Isometry3<f64> {
        let c = receptacle_centres(&OutletGeometry::us_2x1())[r];
        let tip = Vector3::new((c[0] + dx) / 1e3, (c[1] + dy) / 1e3, 0.0);
        let camera = tip - rotation * Vector3::new(0.0, 0.0, TIP_AHEAD_M);
        Isometry3::from_parts(Translation3::from(camera), rotation)
    }

    fn inserted(tool: Isometry3<f64>, target: usize) -> Class {
        classify(&two_by_one(), &Ending::Inserted { tool, target }).0
    }

    #[test]
    fn a_plug_on_the_holes_succeeds() {
        assert_eq!(inserted(at(0, 0.0, 0.0, UnitQuaternion::identity()), 0), Class::Success);
        assert_eq!(inserted(at(1, 0.6, -0.6, UnitQuaternion::identity()), 1), Class::Success);
    }

    #[test]
    fn a_prong_1_2_mm_off_is_off_tolerance() {
        assert_eq!(inserted(at(0, 1.2, 0.0, UnitQuaternion::identity()), 0), Class::OffTolerance);
        assert_eq!(inserted(at(0, 0.0, 0.9, UnitQuaternion::identity()), 0), Class::Success);
    }

    #[test]
    fn a_plug_tilted_4_degrees_is_off_tolerance() {
        let tilt = UnitQuaternion::from_euler_angles(4f64.to_radians(), 0.0, 0.0);
        let (class, landing) = classify(&two_by_one(), &Ending::Inserted { tool: at(0, 0.0, 0.0, tilt), target: 0 });
        assert_eq!(class, Class::OffTolerance);
        let landing = landing.expect("lands");
        assert!((landing.axis_deg - 4.0).abs() < 1e-6, "{}", landing.axis_deg);
        // The tips are on their holes: the axis alone fails.
        assert!(landing.errors_mm.expect("errors").iter().all(|e| *e < 0.1), "{landing:?}");
    }

    #[test]
    fn the_neighbour_receptacle_is_the_wrong_receptacle() {
        assert_eq!(inserted(at(1, 0.0, 0.0, UnitQuaternion::identity()), 0), Class::WrongReceptacle);
        assert_eq!(inserted(at(0, 0.0, 0.0, UnitQuaternion::identity()), 5), Class::WrongReceptacle);
    }

    #[test]
    fn a_plug_turned_half_a_turn_has_the_wrong_polarity() {
        let turned = UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::PI);
        assert_eq!(inserted(at(0, 0.0, 0.0, turned), 0), Class::WrongPolarity);
    }

    #[test]
    fn a_plug_beside_the_plate_or_in_a_scene_without_outlet_is_the_wrong_outlet() {
        assert_eq!(inserted(at(0, 60.0, 0.0, UnitQuaternion::identity()), 0), Class::WrongOutlet);
        let none = Truth { geometry: None, plate_size_mm: [70.0, 114.3] };
        let tool = at(0, 0.0, 0.0, UnitQuaternion::identity());
        assert_eq!(classify(&none, &Ending::Inserted { tool, target: 0 }).0, Class::WrongOutlet);
        assert_eq!(classify(&none, &Ending::NeverFound).0, Class::CorrectlyRefused);
    }

    #[test]
    fn a_timeout_is_too_cautious_only_where_the_push_would_have_gone_in() {
        let truth = two_by_one();
        let back = Translation3::new(0.0, 0.0, -0.03);
        let aligned = at(0, 0.3, 0.0, UnitQuaternion::identity()) * back;
        let off = at(0, 2.0, 0.0, UnitQuaternion::identity()) * back;
        let ends = |tool, target| classify(&truth, &Ending::TimedOut { tool, target }).0;
        assert_eq!(ends(aligned, Some(0)), Class::RefusedWouldHaveSucceeded);
        assert_eq!(ends(off, Some(0)), Class::TimedOut);
        assert_eq!(ends(aligned, None), Class::TimedOut);
        assert_eq!(classify(&truth, &Ending::NeverFound).0, Class::NeverFound);
    }

    #[test]
    fn every_class_has_its_own_name() {
        let names: std::collections::BTreeSet<&str> = Class::ALL.iter().map(|c| c.as_str()).collect();
        assert_eq!(names.len(), Class::ALL.len());
        let json = serde_json::to_string(&Class::RefusedWouldHaveSucceeded).expect("json");
        assert_eq!(json, "\"refused_would_have_succeeded\"");
    }
}
