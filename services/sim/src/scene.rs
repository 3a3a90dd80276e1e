//! What a rendered scene holds: the camera, the outlet's pose, the plates on the
//! wall with their inserts and flaws, the light and the sensor. All lengths on the
//! wall are millimetres in the outlet frame of `CONTRACT.md` (x right, y down seen
//! from the front, z into the wall, receptacle face at z = 0, wall at z =
//! [`Scene::wall_z_mm`], nominally +5).

use nalgebra::{Isometry3, Point3, Vector3};
use outlet_protocol::CameraModel;
use outlet_protocol::geometry::{FACE_OFFSET_MM, OutletGeometry};

/// Linear RGB reflectance or radiance.
pub type Rgb = [f32; 3];

/// The z of the wall surface in the outlet frame (mm) of `CONTRACT.md`: the
/// nominal face offset. Real plates and receptacles differ ([`Scene::wall_z_mm`]).
pub const WALL_Z_MM: f64 = FACE_OFFSET_MM;

/// A receptacle face: its centre relative to the plate centre, its colour, and
/// whether its holes are a full NEMA 5-15R set.
#[derive(Debug, Clone)]
pub struct Face {
    pub centre: [f64; 2],
    pub shape: crate::shapes::FaceShape,
    pub colour: Rgb,
    /// Darkness of the sloped rim at the face's edge (0 = none).
    pub rim: f32,
}

/// What a wall plate carries besides its screws.
#[derive(Debug, Clone)]
pub enum Insert {
    /// Receptacle faces (one per receptacle) with their holes.
    Receptacles(Vec<Face>),
    /// A toggle switch: a dark rectangular opening with a lever.
    Toggle { lever_up: bool },
    /// A rocker switch: a raised rectangle split across its middle.
    Rocker { colour: Rgb },
    /// Keystone data jacks: a module with a dark rectangular opening each.
    DataJacks { centres: Vec<[f64; 2]>, colour: Rgb },
    /// Nothing.
    Blank,
}

#[derive(Debug, Clone, Copy)]
pub struct Screw {
    pub centre: [f64; 2],
    pub radius: f64,
    /// Angle of the slot (radians).
    pub slot_angle: f64,
    pub colour: Rgb,
}

/// A thin dark line on a plate or face: a polyline in plate coordinates.
#[derive(Debug, Clone)]
pub struct Crack {
    pub points: Vec<[f64; 2]>,
    pub half_width: f64,
    pub darkness: f32,
}

impl Crack {
    /// Bounding box (x0, y0, x1, y1) of the crack and its width (mm).
    #[inline]
    pub fn bounds(&self) -> [f64; 4] {
        let h = self.half_width;
        self.points.iter().fold([f64::MAX, f64::MAX, f64::MIN, f64::MIN], |b, p| {
            [b[0].min(p[0] - h), b[1].min(p[1] - h), b[2].max(p[0] + h), b[3].max(p[1] + h)]
        })
    }
}

/// A dark round spot (dirt, a drill hole, paint) on any surface.
#[derive(Debug, Clone, Copy)]
pub struct Spot {
    pub centre: [f64; 2],
    pub radius: f64,
    /// Reflectance multiplier inside (0 = black).
    pub shade: f32,
}

/// One wall plate, axis-aligned with the outlet frame.
#[derive(Debug, Clone)]
pub struct Plate {
    /// Centre in the outlet frame (mm); the sought outlet's plate is at the origin.
    pub centre: [f64; 2],
    /// Outer width and height, bevel included (mm).
    pub size: [f64; 2],
    /// Width of the sloped edge (mm).
    pub bevel: f64,
    /// Height of the flat top above the wall (mm).
    pub proud: f64,
    pub colour: Rgb,
    /// Blinn-Phong specular weight and exponent of the plate and faces.
    pub gloss: f32,
    pub shininess: f32,
    pub insert: Insert,
    pub screws: Vec<Screw>,
    pub cracks: Vec<Crack>,
}

impl Plate {
    /// z of the plate's flat top in the outlet frame (mm), on a wall at `wall_z_mm`.
    pub fn top_z(&self, wall_z_mm: f64) -> f64 {
        wall_z_mm - self.proud
    }
}

/// A point light with fall-off, in the camera frame (metres).
#[derive(Debug, Clone, Copy)]
pub struct Light {
    pub position_cam_m: Point3<f64>,
    /// Direct irradiance at the outlet's origin on a surface facing the light.
    pub intensity: f32,
    pub ambient: f32,
    /// Size of the light seen from the outlet: softness of cast shadows (mm of
    /// penumbra per mm of height above the wall).
    pub softness: f64,
}

/// A soft shadow cast across the wall by something out of view (the robot's arm):
/// a band between two parallel lines on the wall, in outlet coordinates.
#[derive(Debug, Clone, Copy)]
pub struct Occluder {
    /// Unit direction across the band.
    pub normal: [f64; 2],
    /// The band is `offset_mm <= normal . p <= offset_mm + width_mm`.
    pub offset_mm: f64,
    pub width_mm: f64,
    pub penumbra_mm: f64,
    /// Fraction of the direct light blocked (0..1).
    pub strength: f32,
}

/// Everything between the radiance and the bytes.
#[derive(Debug, Clone, Copy)]
pub struct Sensor {
    /// Multiplier of radiance before clipping: under < 1 < over.
    pub exposure: f32,
    pub gamma: f32,
    /// Read noise (fraction of full scale) and shot-noise gain.
    pub read_noise: f32,
    pub shot_noise: f32,
    /// Gaussian defocus blur (pixels; 0 = sharp).
    pub blur_sigma: f32,
    /// JPEG quality when the frame is JPEG-compressed.
    pub jpeg_quality: Option<u8>,
}

/// How the stereo camera sees the wall.
#[derive(Debug, Clone, Copy)]
pub struct StereoModel {
    /// Sample every `step` pixels of the image grid.
    pub step: u32,
    /// Stereo baseline (m) and disparity noise (px): depth noise grows with z².
    pub baseline_m: f64,
    pub disparity_sigma_px: f64,
    pub outlier_fraction: f64,
    /// Fraction of the image covered by blobs without stereo (NaN).
    pub dropout_fraction: f64,
    /// Depth noise proportional to the range (sigma as a fraction of z), as block
    /// matchers on plain walls give; 0 for none.
    pub range_sigma_fraction: f64,
    /// Keep at most this many valid points (a random subset, the rest NaN): the
    /// density of a real stereo pair's cloud on a plain wall.
    pub max_points: Option<usize>,
    /// The fraction of points kept on the plate and the faces (they are small and
    /// smooth: a matcher finds few points there).
    pub raised_keep: f64,
    /// No points within this radius (mm, outlet frame) of the outlet's centre.
    pub outlet_dropout_mm: Option<f64>,
    /// The stereo pair's calibration bias: every point moved by this rigid motion
    /// (camera frame), so the fitted wall is a little off the true one.
    pub bias: Isometry3<f64>,
}

impl Default for StereoModel {
    fn default() -> Self {
        Self {
            step: 2,
            baseline_m: 0.09,
            disparity_sigma_px: 0.15,
            outlier_fraction: 0.01,
            dropout_fraction: 0.08,
            range_sigma_fraction: 0.0,
            max_points: None,
            raised_keep: 1.0,
            outlet_dropout_mm: None,
            bias: Isometry3::identity(),
        }
    }
}

impl StereoModel {
    /// The cloud a real stereo pair gives at the outlet (`outlet_cam_m`, camera
    /// frame): 1,500-5,000 points, noise 0.8-2% of range, 5-15% outliers, few
    /// points on the plate, none over the outlet in a third of the views, and a
    /// calibration bias that puts the fitted wall 0.3-1 degree and 0.5-2 mm off.
    pub fn realistic(rng: &mut crate::rng::SimRng, outlet_cam_m: Point3<f64>) -> Self {
        let axis = nalgebra::Unit::new_normalize(Vector3::new(rng.normal(), rng.normal(), rng.normal()));
        let angle = rng.range(0.3, 1.0).to_radians();
        let rotation = nalgebra::UnitQuaternion::from_axis_angle(&axis, angle);
        // Turned about the outlet, so that the offset alone sets the error there.
        let offset_dir = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
        let offset = offset_dir * rng.range(0.5e-3, 2e-3);
        let about = outlet_cam_m.coords;
        let translation = about - rotation * about + offset;
        Self {
            step: 2,
            baseline_m: 0.09,
            disparity_sigma_px: 0.15,
            outlier_fraction: rng.range(0.05, 0.15),
            dropout_fraction: rng.range(0.0, 0.15),
            range_sigma_fraction: rng.range(0.008, 0.02),
            max_points: Some(rng.range(1500.0, 5000.0) as usize),
            raised_keep: rng.range(0.02, 0.2),
            outlet_dropout_mm: if rng.chance(1.0 / 3.0) { Some(rng.range(60.0, 120.0)) } else { None },
            bias: Isometry3::from_parts(translation.into(), rotation),
        }
    }
}

/// A complete scene: render it with [`crate::render()`].
#[derive(Debug, Clone)]
pub struct Scene {
    pub camera: CameraModel,
    /// Outlet frame (metres) to camera frame.
    pub pose: Isometry3<f64>,
    pub scenario: String,
    /// The outlet the sought template finds here, if any (`2x1`, `2x2`).
    pub template: Option<String>,
    pub search_template: String,
    pub plates: Vec<Plate>,
    pub wall_colour: Rgb,
    /// Amplitude of the wall's paint texture (fraction).
    pub wall_texture: f32,
    pub spots: Vec<Spot>,
    pub light: Light,
    pub occluders: Vec<Occluder>,
    /// Strength of the metal glint inside the slots (0 = none).
    pub hole_glint: f32,
    /// How fast light fades down a hole's side wall (mm), and the reflectance of
    /// its floor relative to the face.
    pub hole_fade_mm: f64,
    pub hole_floor: f32,
    pub sensor: Sensor,
    pub stereo: StereoModel,
    /// The wall surface's z in the outlet frame (mm): how far the receptacle face
    /// stands ahead of the wall. [`WALL_Z_MM`] nominally; 3-7 mm on real walls.
    pub wall_z_mm: f64,
    /// Seed of the per-pixel noise and of the cloud.
    pub noise_seed: u64,
}

impl Scene {
    /// The sought outlet's geometry, if the scene holds one.
    pub fn geometry(&self) -> Option<OutletGeometry> {
        self.template.as_deref().and_then(|t| OutletGeometry::builtin(t).ok())
    }

    /// The camera centre in the outlet frame (mm).
    pub fn camera_in_outlet_mm(&self) -> Point3<f64> {
        Point3::from(self.pose.inverse_transform_point(&Point3::origin()).coords * 1000.0)
    }

    /// Unit wall normal in the camera frame, pointing into the wall, and the
    /// wall's distance `d` with `n . X = d` (metres).
    pub fn wall_plane_cam(&self) -> (Vector3<f64>, f64) {
        let n = self.pose.rotation * Vector3::z();
        let on_wall = self.pose * Point3::new(0.0, 0.0, self.wall_z_mm / 1000.0);
        (n, n.dot(&on_wall.coords))
    }
}
