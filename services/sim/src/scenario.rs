//! The scenarios of the paper's Table I, as distributions of scenes. Each image's
//! scene is drawn from its own seed, so image `i` is the same whatever the count.

use crate::rng::SimRng;
use crate::scene::*;
use crate::shapes::Opening;
use nalgebra::{Isometry3, Point2, Point3, Rotation3, Translation3, Unit, UnitQuaternion, Vector3};
use outlet_protocol::CameraModel;
use outlet_protocol::geometry::{DUPLEX_PITCH_MM, GANG_PITCH_MM, OutletGeometry, PLATE_1GANG_MM, PLATE_2GANG_MM};

/// Every scenario, in the order of the paper's Table I, then the negatives.
pub const SCENARIOS: [&str; 8] =
    ["fw_2x1white", "orange2x1", "whitehall2x1", "cracked2x2", "fw_2x2orange", "specular2x2", "white2x2", "negative"];

/// The prefix of the realistic-stereo family: `rs_orange2x1` is the scene of
/// `orange2x1` (same seed, same draws) with the stereo of a real pair
/// ([`crate::scene::StereoModel::realistic`]) and the receptacle face 3-7 mm
/// ahead of the wall instead of the nominal 5.
pub const REALISTIC_STEREO_PREFIX: &str = "rs_";

/// [`SCENARIOS`] with realistic stereo ([`REALISTIC_STEREO_PREFIX`]), same order.
pub const REALISTIC_SCENARIOS: [&str; 8] = [
    "rs_fw_2x1white",
    "rs_orange2x1",
    "rs_whitehall2x1",
    "rs_cracked2x2",
    "rs_fw_2x2orange",
    "rs_specular2x2",
    "rs_white2x2",
    "rs_negative",
];

/// The scenario of this name, from [`SCENARIOS`] or [`REALISTIC_SCENARIOS`].
pub fn scenario_named(name: &str) -> Option<&'static str> {
    SCENARIOS.iter().chain(&REALISTIC_SCENARIOS).copied().find(|s| *s == name)
}

/// Image counts of the paper's Table I (300 for our negatives).
pub fn paper_count(scenario: &str) -> usize {
    match scenario.strip_prefix(REALISTIC_STEREO_PREFIX).unwrap_or(scenario) {
        "fw_2x1white" => 111,
        "orange2x1" | "whitehall2x1" => 103,
        "cracked2x2" => 100,
        "fw_2x2orange" => 34,
        "specular2x2" => 56,
        "white2x2" => 104,
        _ => 300,
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    #[error("unknown scenario {0:?}; known: {list}, each also with the prefix rs_ (realistic stereo)", list = SCENARIOS.join(", "))]
    Unknown(String),
    #[error("no pose with every hole inside the {width}x{height} image was found for {scenario} #{index}")]
    NoPose { scenario: String, index: u64, width: u32, height: u32 },
}

const WHITE: Rgb = [0.78, 0.78, 0.75];
const IVORY: Rgb = [0.76, 0.70, 0.54];
const ALMOND: Rgb = [0.62, 0.54, 0.42];
const ORANGE: Rgb = [0.78, 0.19, 0.035];
const GREY: Rgb = [0.40, 0.41, 0.42];
const BROWN: Rgb = [0.20, 0.11, 0.055];
const METAL: Rgb = [0.55, 0.55, 0.52];
const WALLS: [Rgb; 6] = [
    [0.68, 0.66, 0.56],
    [0.74, 0.74, 0.71],
    [0.55, 0.58, 0.54],
    [0.60, 0.54, 0.44],
    [0.45, 0.50, 0.58],
    [0.62, 0.60, 0.62],
];

/// What varies between the scenarios.
struct Style {
    /// The outlet that is there to be found; `None` for the negatives.
    template: Option<&'static str>,
    plates: &'static [Rgb],
    /// Receptacle colours; empty means the plate's own.
    faces: &'static [Rgb],
    cracks: bool,
    specular: bool,
    hallway: bool,
}

fn style(scenario: &str) -> Option<Style> {
    let s = |template, plates, faces, cracks, specular, hallway| Style {
        template,
        plates,
        faces,
        cracks,
        specular,
        hallway,
    };
    Some(match scenario {
        "fw_2x1white" => s(Some("2x1"), &[WHITE, WHITE, IVORY], &[], false, false, false),
        "orange2x1" => s(Some("2x1"), &[WHITE, IVORY, ORANGE, GREY], &[ORANGE], false, false, false),
        "whitehall2x1" => s(Some("2x1"), &[WHITE, IVORY, ALMOND, GREY, BROWN], &[], false, false, true),
        "cracked2x2" => s(Some("2x2"), &[WHITE, IVORY, ALMOND], &[], true, false, false),
        "fw_2x2orange" => s(Some("2x2"), &[WHITE, GREY, ORANGE], &[ORANGE], false, false, false),
        "specular2x2" => s(Some("2x2"), &[WHITE, IVORY, ALMOND, GREY, BROWN, ORANGE], &[], false, true, false),
        "white2x2" => s(Some("2x2"), &[WHITE, IVORY], &[], false, false, false),
        "negative" => s(None, &[WHITE, IVORY, ALMOND, ORANGE, GREY, BROWN], &[], false, false, false),
        _ => return None,
    })
}

/// A colour of the palette, varied a little in brightness and hue.
fn pick_colour(rng: &mut SimRng, palette: &[Rgb], amount: f64) -> Rgb {
    let c = *rng.pick(palette);
    let k = rng.range(1.0 - amount, 1.0 + amount) as f32;
    let mut out = [0.0; 3];
    for (o, v) in out.iter_mut().zip(c) {
        *o = (v * k * rng.range(1.0 - amount / 3.0, 1.0 + amount / 3.0) as f32).min(0.95);
    }
    out
}

/// The seed of image `index` of a scenario in a run seeded `seed`.
pub fn image_seed(seed: u64, scenario: &str, index: u64) -> u64 {
    let mut h: u64 = 0xCBF2_9CE4_8422_2325;
    for b in scenario.bytes().chain(seed.to_le_bytes()).chain(index.to_le_bytes()) {
        h = (h ^ b as u64).wrapping_mul(0x0100_0000_01B3);
    }
    h
}

/// What stands on the main plate.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Kind {
    Duplex(usize),
    Single,
    Toggle,
    Rocker,
    Jacks,
    Blank,
}

/// Draws the scene of image `index` of a scenario.
pub fn sample_scene(scenario: &str, seed: u64, index: u64, camera: &CameraModel) -> Result<Scene, ScenarioError> {
    let (base, realistic) = match scenario.strip_prefix(REALISTIC_STEREO_PREFIX) {
        Some(base) => (base, true),
        None => (scenario, false),
    };
    let style = style(base).ok_or_else(|| ScenarioError::Unknown(scenario.to_string()))?;
    let mut rng = SimRng::new(image_seed(seed, base, index));
    let search_template = match style.template {
        Some(t) => t.to_string(),
        None => (if rng.chance(0.5) { "2x1" } else { "2x2" }).to_string(),
    };
    let main_kind = match style.template {
        Some("2x2") => Kind::Duplex(2),
        Some(_) => Kind::Duplex(1),
        None => {
            let mut kinds = vec![Kind::Single, Kind::Toggle, Kind::Rocker, Kind::Jacks, Kind::Blank];
            if search_template == "2x2" {
                kinds.extend([Kind::Duplex(1), Kind::Duplex(1), Kind::Duplex(1)]);
            }
            *rng.pick(&kinds)
        }
    };

    let mut looks = rng.fork(1);
    let plate_colour = pick_colour(&mut looks, style.plates, 0.08);
    let face_colour = if style.faces.is_empty() { plate_colour } else { pick_colour(&mut looks, style.faces, 0.08) };
    let gloss_range = if style.specular { (0.25, 0.9) } else { (0.0, 0.25) };
    let gloss = looks.range(gloss_range.0, gloss_range.1) as f32;
    let shininess = looks.range(12.0, 70.0) as f32;
    let mut main = make_plate(&mut looks, main_kind, plate_colour, face_colour, [0.0, 0.0], gloss, shininess);
    if style.cracks || looks.chance(0.04) {
        let n = if style.cracks { 1 + looks.below(3) } else { 1 };
        main.cracks = (0..n).map(|_| crack(&mut looks, &main)).collect();
    }

    let mut plates = vec![main];
    let mut neighbours = rng.fork(2);
    if neighbours.chance(0.35) {
        let mut kinds = vec![Kind::Toggle, Kind::Rocker, Kind::Jacks, Kind::Blank];
        if search_template == "2x2" && main_kind != Kind::Duplex(1) {
            kinds.push(Kind::Duplex(1));
        }
        let kind = *neighbours.pick(&kinds);
        let colour =
            if neighbours.chance(0.7) { plate_colour } else { pick_colour(&mut neighbours, style.plates, 0.08) };
        let side = if neighbours.chance(0.5) { -1.0 } else { 1.0 };
        let mut other = make_plate(&mut neighbours, kind, colour, colour, [0.0, 0.0], gloss, shininess);
        let gap = neighbours.range(8.0, 60.0);
        other.centre = [side * (plates[0].size[0] / 2.0 + gap + other.size[0] / 2.0), neighbours.range(-6.0, 6.0)];
        plates.push(other);
    }

    let pose = sample_pose(&mut rng.fork(3), scenario, index, camera, &plates[0], main_kind)?;

    let mut light_rng = rng.fork(4);
    let (light, sensor) = sample_light(&mut light_rng, &style, &pose, &plates[0]);
    let occluders = sample_occluders(&mut light_rng, &style);
    let hole_glint =
        if light_rng.chance(if style.specular { 0.6 } else { 0.25 }) { light_rng.range(0.3, 1.0) as f32 } else { 0.0 };

    // Deep narrow holes look black; shallow or wide ones show their walls.
    let hole_fade_mm = light_rng.range(1.0, 2.6);
    let hole_floor = light_rng.range(0.02, 0.15) as f32;

    let mut spot_rng = rng.fork(5);
    let spots = sample_spots(&mut spot_rng, &plates[0], main_kind);
    let wall_colour = pick_colour(&mut spot_rng, &WALLS, 0.1);
    let wall_texture = spot_rng.range(0.01, 0.06) as f32;

    let (stereo, wall_z_mm) = if realistic {
        // A stream of its own: the realistic scene is the base scene but for these.
        let mut real = SimRng::new(image_seed(seed, scenario, index));
        let wall_z_mm = real.range(3.0, 7.0);
        (StereoModel::realistic(&mut real, Point3::from(pose.translation.vector)), wall_z_mm)
    } else {
        (StereoModel::default(), WALL_Z_MM)
    };
    Ok(Scene {
        camera: *camera,
        pose,
        scenario: scenario.to_string(),
        template: style.template.map(str::to_string),
        search_template,
        plates,
        wall_colour,
        wall_texture,
        spots,
        light,
        occluders,
        hole_glint,
        hole_fade_mm,
        hole_floor,
        sensor,
        stereo,
        wall_z_mm,
        noise_seed: rng.next_u64(),
    })
}

fn make_plate(
    rng: &mut SimRng,
    kind: Kind,
    colour: Rgb,
    face_colour: Rgb,
    centre: [f64; 2],
    gloss: f32,
    shininess: f32,
) -> Plate {
    let two_gang = kind == Kind::Duplex(2);
    let base = if two_gang { PLATE_2GANG_MM } else { PLATE_1GANG_MM };
    // "Midway" and jumbo plates are a little larger than standard.
    let grow = if rng.chance(0.3) { rng.range(1.0, 1.1) } else { 1.0 };
    let size = [base[0] * grow, base[1] * grow];
    let screw_colour = if rng.chance(0.6) { colour } else { METAL };
    let screw = |rng: &mut SimRng, x: f64, y: f64| Screw {
        centre: [x, y],
        radius: rng.range(3.2, 3.9),
        slot_angle: rng.range(0.0, std::f64::consts::PI),
        colour: screw_colour,
    };
    let rim = rng.range(0.1, 0.4) as f32;
    let shape = crate::shapes::FaceShape {
        radius: rng.range(17.0, 19.5),
        half_height: rng.range(12.8, 14.2),
        t_slot: rng.chance(0.2),
    };
    let (insert, screws) = match kind {
        Kind::Duplex(columns) => {
            let xs: Vec<f64> = if columns == 2 { vec![-GANG_PITCH_MM / 2.0, GANG_PITCH_MM / 2.0] } else { vec![0.0] };
            let faces = xs
                .iter()
                .flat_map(|&x| {
                    [-DUPLEX_PITCH_MM / 2.0, DUPLEX_PITCH_MM / 2.0].map(|y| Face {
                        centre: [x, y],
                        shape,
                        colour: face_colour,
                        rim,
                    })
                })
                .collect();
            (Insert::Receptacles(faces), xs.iter().map(|&x| screw(rng, x, 0.0)).collect())
        }
        Kind::Single => (
            Insert::Receptacles(vec![Face { centre: [0.0, 0.0], shape, colour: face_colour, rim }]),
            vec![screw(rng, 0.0, -26.0), screw(rng, 0.0, 26.0)],
        ),
        Kind::Toggle => {
            (Insert::Toggle { lever_up: rng.chance(0.5) }, vec![screw(rng, 0.0, -30.16), screw(rng, 0.0, 30.16)])
        }
        Kind::Rocker => (Insert::Rocker { colour }, vec![screw(rng, 0.0, -48.0), screw(rng, 0.0, 48.0)]),
        Kind::Jacks => {
            let centres = if rng.chance(0.5) { vec![[0.0, 0.0]] } else { vec![[0.0, -14.0], [0.0, 14.0]] };
            let jack = if rng.chance(0.5) { colour } else { [0.05, 0.05, 0.05] };
            (Insert::DataJacks { centres, colour: jack }, vec![screw(rng, 0.0, -41.0), screw(rng, 0.0, 41.0)])
        }
        Kind::Blank => (Insert::Blank, vec![screw(rng, 0.0, -41.0), screw(rng, 0.0, 41.0)]),
    };
    Plate {
        centre,
        size,
        bevel: rng.range(3.0, 6.0),
        proud: rng.range(2.5, 3.8),
        colour,
        gloss,
        shininess,
        insert,
        screws,
        cracks: Vec::new(),
    }
}

fn crack(rng: &mut SimRng, plate: &Plate) -> Crack {
    let (hx, hy) = (plate.size[0] / 2.0 - plate.bevel, plate.size[1] / 2.0 - plate.bevel);
    let mut p = [rng.range(-hx, hx), rng.range(-hy, hy)];
    let mut heading = rng.range(0.0, std::f64::consts::TAU);
    let mut points = vec![p];
    for _ in 0..3 + rng.below(5) {
        heading += rng.range(-0.7, 0.7);
        let len = rng.range(3.0, 12.0);
        p = [(p[0] + len * heading.cos()).clamp(-hx, hx), (p[1] + len * heading.sin()).clamp(-hy, hy)];
        points.push(p);
    }
    Crack { points, half_width: rng.range(0.08, 0.3), darkness: rng.range(0.15, 0.5) as f32 }
}

fn sample_spots(rng: &mut SimRng, plate: &Plate, kind: Kind) -> Vec<Spot> {
    let holes: Vec<[f64; 2]> = match &plate.insert {
        Insert::Receptacles(faces) => faces
            .iter()
            .flat_map(|f| Opening::ALL.map(|o| [f.centre[0] + o.centre()[0], f.centre[1] + o.centre()[1]]))
            .collect(),
        _ => Vec::new(),
    };
    let clear_of_holes =
        |p: [f64; 2], r: f64| holes.iter().all(|h| ((p[0] - h[0]).powi(2) + (p[1] - h[1]).powi(2)).sqrt() > r + 4.0);
    let mut spots = Vec::new();
    for _ in 0..rng.below(5) {
        let r = rng.range(0.5, 2.5);
        let c = [rng.range(-plate.size[0], plate.size[0]), rng.range(-plate.size[1], plate.size[1])];
        if clear_of_holes(c, r) {
            spots.push(Spot { centre: c, radius: r, shade: rng.range(0.1, 0.6) as f32 });
        }
    }
    // Dots beside a ground hole, as on the real Willow outlet.
    if matches!(kind, Kind::Duplex(_)) && rng.chance(0.25) {
        let h = holes[2 + 3 * rng.below(holes.len() / 3)];
        let a = rng.range(0.0, std::f64::consts::TAU);
        let (r, d) = (rng.range(0.6, 1.4), rng.range(5.5, 8.0));
        let c = [h[0] + d * a.cos(), h[1] + d * a.sin()];
        if clear_of_holes(c, r) {
            spots.push(Spot { centre: c, radius: r, shade: rng.range(0.15, 0.5) as f32 });
        }
    }
    spots
}

/// The points that must be in view: every hole, or the plate's inner corners.
fn key_points_mm(plate: &Plate, kind: Kind) -> Vec<[f64; 2]> {
    match kind {
        Kind::Duplex(1) => OutletGeometry::us_2x1().holes.iter().map(|h| h.position_mm).collect(),
        Kind::Duplex(_) => OutletGeometry::us_2x2().holes.iter().map(|h| h.position_mm).collect(),
        _ => {
            let (hx, hy) = (plate.size[0] / 2.0 - 15.0, plate.size[1] / 2.0 - 15.0);
            vec![[-hx, -hy], [hx, -hy], [-hx, hy], [hx, hy], [0.0, 0.0]]
        }
    }
}

/// Places the outlet 20-50 cm away, up to 40 degrees off-axis, any roll, ground
/// down or up, with every key point inside the image.
fn sample_pose(
    rng: &mut SimRng,
    scenario: &str,
    index: u64,
    camera: &CameraModel,
    plate: &Plate,
    kind: Kind,
) -> Result<Isometry3<f64>, ScenarioError> {
    let keys = key_points_mm(plate, kind);
    for _ in 0..200 {
        let distance = rng.range(0.20, 0.50);
        let off_axis = rng.range(0.0, 40f64.to_radians());
        let azimuth = rng.range(0.0, std::f64::consts::TAU);
        let mut roll = if rng.chance(0.15) { rng.range(-180.0, 180.0) } else { rng.range(-15.0, 15.0) }.to_radians();
        if rng.chance(0.3) {
            roll += std::f64::consts::PI; // mounted ground up
        }
        let target = Point2::new(
            camera.cx + rng.range(-0.25, 0.25) * camera.width as f64,
            camera.cy + rng.range(-0.25, 0.25) * camera.height as f64,
        );
        let sight = camera.ray(target).normalize();
        let pose = pose_looking(sight, distance, off_axis, azimuth, roll);
        let inside = keys.iter().all(|k| {
            camera
                .project(&(pose * Point3::new(k[0] / 1000.0, k[1] / 1000.0, 0.0)))
                .is_some_and(|px| camera.contains(px, 12.0))
        });
        if inside {
            return Ok(pose);
        }
    }
    Err(ScenarioError::NoPose { scenario: scenario.to_string(), index, width: camera.width, height: camera.height })
}

/// The outlet at `distance` along the line of sight `sight`, its wall normal
/// tilted `off_axis` from the line of sight towards `azimuth`, rolled in its plane.
pub fn pose_looking(sight: Vector3<f64>, distance: f64, off_axis: f64, azimuth: f64, roll: f64) -> Isometry3<f64> {
    let sight = sight.normalize();
    let e1 = sight.cross(&Vector3::y()).try_normalize(1e-9).unwrap_or_else(Vector3::x);
    let e2 = sight.cross(&e1);
    let axis = Unit::new_normalize(e1 * azimuth.cos() + e2 * azimuth.sin());
    let into_wall = Rotation3::from_axis_angle(&axis, off_axis) * sight;
    // Upright: the outlet's x follows the image's x projected on the wall.
    let x0 = (Vector3::x() - into_wall * into_wall.x).normalize();
    let y0 = into_wall.cross(&x0);
    let (s, c) = roll.sin_cos();
    let x = x0 * c + y0 * s;
    let y = into_wall.cross(&x);
    let rotation = Rotation3::from_basis_unchecked(&[x, y, into_wall]);
    Isometry3::from_parts(Translation3::from(sight * distance), UnitQuaternion::from_rotation_matrix(&rotation))
}

fn sample_light(rng: &mut SimRng, style: &Style, pose: &Isometry3<f64>, plate: &Plate) -> (Light, Sensor) {
    let wall_normal_out = -(pose.rotation * Vector3::z());
    let outlet = Point3::from(pose.translation.vector);
    let mut position = Point3::new(rng.range(-0.6, 0.6), rng.range(-0.9, 0.2), rng.range(-0.4, 0.2));
    if style.specular && rng.chance(0.7) {
        // Put the light where the plate mirrors it into the camera: a highlight.
        let on_plate = pose
            * Point3::new(
                rng.range(-plate.size[0] / 2.0, plate.size[0] / 2.0) / 1000.0,
                rng.range(-plate.size[1] / 2.0, plate.size[1] / 2.0) / 1000.0,
                0.0,
            );
        let view = on_plate.coords.normalize();
        let mirrored = view - wall_normal_out * 2.0 * view.dot(&wall_normal_out);
        position = on_plate - mirrored * rng.range(0.4, 1.5);
    }
    // Keep the light in front of the wall.
    let height = wall_normal_out.dot(&(position - outlet));
    if height < 0.08 {
        position += wall_normal_out * (0.08 - height);
    }
    let (mut exposure, ambient) = if style.hallway {
        (rng.range(0.5, 1.0), rng.range(0.25, 0.5))
    } else {
        (rng.range(0.75, 1.25), rng.range(0.12, 0.4))
    };
    if style.specular {
        exposure = match rng.below(3) {
            0 => rng.range(0.15, 0.4),
            1 => rng.range(1.5, 3.0),
            _ => exposure,
        };
    }
    let light = Light {
        position_cam_m: position,
        intensity: rng.range(0.5, 0.8) as f32,
        ambient: ambient as f32,
        softness: rng.range(0.02, 0.3),
    };
    let sensor = Sensor {
        exposure: exposure as f32,
        gamma: rng.range(2.0, 2.4) as f32,
        read_noise: rng.range(0.002, 0.012) as f32,
        shot_noise: rng.range(0.0003, 0.002) as f32,
        blur_sigma: if rng.chance(0.5) { rng.range(0.3, 1.2) as f32 } else { 0.0 },
        jpeg_quality: if rng.chance(0.3) { Some(rng.range(55.0, 95.0) as u8) } else { None },
    };
    (light, sensor)
}

fn sample_occluders(rng: &mut SimRng, style: &Style) -> Vec<Occluder> {
    let p = if style.specular { 0.7 } else { 0.2 };
    if !rng.chance(p) {
        return Vec::new();
    }
    let a = rng.range(0.0, std::f64::consts::TAU);
    vec![Occluder {
        normal: [a.cos(), a.sin()],
        offset_mm: rng.range(-70.0, 30.0),
        width_mm: rng.range(30.0, 200.0),
        penumbra_mm: rng.range(2.0, 15.0),
        strength: rng.range(if style.specular { 0.6 } else { 0.3 }, 0.9) as f32,
    }]
}
