//! The renderer: every pixel's ray is cast onto the planes of the wall, the plates
//! and the receptacle faces (exact perspective, distortion included), shaded with a
//! point light, then blurred, exposed, given sensor noise and gamma.
//!
//! Anti-aliasing is adaptive: a pixel is shaded once where its four corners and its
//! centre see the same surface and no thin feature (crack, screw slot, spot) is
//! near, else with 3x3 samples. That keeps a 640x480 frame in a few milliseconds.

use crate::rng::SimRng;
use crate::scene::{Crack, Insert, Plate, Rgb, Scene};
use crate::shapes::{FaceShape, Opening, box_sd, face_sd, segment_distance};
use image::RgbImage;
use nalgebra::{Matrix3, Point2, Point3, Vector3};

/// Depth of a receptacle opening behind the face (mm).
const HOLE_DEPTH_MM: f64 = 7.0;
/// The gap between a face and the plate's opening around it (mm).
const FACE_GAP_MM: f64 = 0.6;
/// Receptacle face rim width (mm).
const RIM_MM: f64 = 0.9;
/// Keystone jack module and its opening, half sizes (mm).
const JACK_HALF_MM: [f64; 2] = [7.25, 9.75];
const JACK_OPENING_HALF_MM: [f64; 2] = [5.85, 5.2];
/// Toggle switch opening and lever, half sizes (mm).
const TOGGLE_OPENING_HALF_MM: [f64; 2] = [5.15, 11.9];
const TOGGLE_LEVER_HALF_MM: [f64; 2] = [3.2, 6.5];
/// Rocker (Decora) switch, half sizes (mm).
const ROCKER_HALF_MM: [f64; 2] = [16.65, 33.35];
/// Spacing of the coarse grid on which distortion is inverted exactly (pixels).
const UNDISTORT_GRID_PX: usize = 4;
/// Supersamples per side where a pixel straddles an edge.
const SUPERSAMPLE: usize = 3;

/// A rendered camera frame.
#[derive(Debug, Clone)]
pub struct Frame {
    /// The picture as a camera delivers it (after JPEG if the sensor compresses).
    pub image: RgbImage,
    /// The JPEG bytes when the sensor compresses: what `outlet render` writes.
    pub jpeg: Option<Vec<u8>>,
}

/// A ray through the outlet frame: its point on the face plane z = 0 and its
/// lateral shift per mm of depth, so that the point at depth z is `p0 + z * slope`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Ray {
    p0: [f64; 2],
    slope: [f64; 2],
}

impl Ray {
    #[inline]
    pub(crate) fn at(&self, z: f64) -> [f64; 2] {
        [self.p0[0] + z * self.slope[0], self.p0[1] + z * self.slope[1]]
    }
}

/// How a surface sample takes its light.
#[derive(Debug, Clone, Copy)]
enum Lit {
    /// Flat, facing out of the wall; `shadow` says whose cast shadow can fall on it.
    Flat { shadow: ShadowOn },
    /// A tilted surface with its own normal (outlet frame, unit).
    Tilted { normal: [f32; 3] },
    /// Inside an opening: the reflectance already holds how deep it is.
    Inside,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum ShadowOn {
    /// The receptacle faces and raised parts: nothing shades them but occluders.
    Raised,
    /// A plate top, which the faces standing on it can shade.
    Plate(usize),
    /// The wall, which the plates can shade.
    Wall,
}

#[derive(Debug, Clone, Copy)]
struct Hit {
    /// Which surface: equal ids on a pixel's corners mean one shading suffices.
    id: u32,
    albedo: Rgb,
    lit: Lit,
    gloss: f32,
    shininess: f32,
}

/// The scene in the form the inner loop wants: everything in outlet mm.
pub(crate) struct Prepared<'a> {
    scene: &'a Scene,
    /// Camera to outlet rotation.
    rot_t: Matrix3<f64>,
    camera_mm: Point3<f64>,
    light_mm: Point3<f64>,
    /// `irradiance = light_power / r^2`, r in mm.
    light_power: f64,
    texture: Vec<f32>,
    /// Image-space boxes around thin features that need supersampling.
    thin_boxes: Vec<[f64; 4]>,
}

const TEXTURE_SIZE: usize = 256;
/// Wall texture: fine grain of this size (mm per texel) over blotches this many texels wide.
const TEXEL_MM: f64 = 1.1;
const BLOTCH_TEXELS: usize = 32;

impl<'a> Prepared<'a> {
    pub(crate) fn new(scene: &'a Scene) -> Self {
        let rot_t = scene.pose.rotation.to_rotation_matrix().matrix().transpose();
        let camera_mm = scene.camera_in_outlet_mm();
        let light_mm = Point3::from(scene.pose.inverse_transform_point(&scene.light.position_cam_m).coords * 1000.0);
        let r0 = light_mm.coords.norm().max(1.0);
        let light_power = scene.light.intensity as f64 * r0 * r0;
        let texture = wall_texture(scene.noise_seed ^ 0x7E57, scene.wall_texture);
        let mut prepared = Self { scene, rot_t, camera_mm, light_mm, light_power, texture, thin_boxes: Vec::new() };
        prepared.thin_boxes = prepared.thin_feature_boxes();
        prepared
    }

    /// The ray through normalised undistorted camera coordinates.
    #[inline]
    pub(crate) fn ray(&self, xn: f64, yn: f64) -> Option<Ray> {
        let d = self.rot_t * Vector3::new(xn, yn, 1.0);
        // Rays that never reach the wall (beyond the horizon) hit nothing.
        if d.z <= 1e-9 {
            return None;
        }
        let slope = [d.x / d.z, d.y / d.z];
        let z0 = -self.camera_mm.z;
        Some(Ray { p0: [self.camera_mm.x + z0 * slope[0], self.camera_mm.y + z0 * slope[1]], slope })
    }

    /// Image boxes (u0, v0, u1, v1) around features thinner than a pixel.
    fn thin_feature_boxes(&self) -> Vec<[f64; 4]> {
        let mut boxes_mm: Vec<([f64; 2], [f64; 2], f64)> = Vec::new(); // (min, max, z)
        for plate in &self.scene.plates {
            let z = plate.top_z(self.scene.wall_z_mm);
            let c = plate.centre;
            for s in &plate.screws {
                let r = s.radius;
                boxes_mm.push((
                    [c[0] + s.centre[0] - r, c[1] + s.centre[1] - r],
                    [c[0] + s.centre[0] + r, c[1] + s.centre[1] + r],
                    z,
                ));
            }
            // Cracks are long and thin: small boxes along them, not one big box
            // (which would supersample most of the plate).
            for crack in &plate.cracks {
                let r = crack.half_width + 0.6;
                for w in crack.points.windows(2) {
                    let steps = ((w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]) / 1.0).ceil().max(1.0) as usize;
                    for k in 0..=steps {
                        let t = k as f64 / steps as f64;
                        let (x, y) =
                            (c[0] + w[0][0] + t * (w[1][0] - w[0][0]), c[1] + w[0][1] + t * (w[1][1] - w[0][1]));
                        boxes_mm.push(([x - r, y - r], [x + r, y + r], z));
                    }
                }
            }
            if let Insert::Rocker { .. } = plate.insert {
                boxes_mm.push(([c[0] - ROCKER_HALF_MM[0], c[1] - 1.0], [c[0] + ROCKER_HALF_MM[0], c[1] + 1.0], z));
            }
        }
        for s in &self.scene.spots {
            let r = s.radius;
            for z in [0.0, 2.0, self.scene.wall_z_mm] {
                boxes_mm.push(([s.centre[0] - r, s.centre[1] - r], [s.centre[0] + r, s.centre[1] + r], z));
            }
        }
        let cam = &self.scene.camera;
        boxes_mm
            .iter()
            .filter_map(|&(lo, hi, z)| {
                let mut b = [f64::MAX, f64::MAX, f64::MIN, f64::MIN];
                for (x, y) in [(lo[0], lo[1]), (hi[0], lo[1]), (lo[0], hi[1]), (hi[0], hi[1])] {
                    let p = self.scene.pose * Point3::new(x / 1000.0, y / 1000.0, z / 1000.0);
                    let px = cam.project(&p)?;
                    b = [b[0].min(px.x), b[1].min(px.y), b[2].max(px.x), b[3].max(px.y)];
                }
                // Margin for the bow of distortion and the pixel footprint.
                Some([b[0] - 2.0, b[1] - 2.0, b[2] + 2.0, b[3] + 2.0])
            })
            .collect()
    }

    #[inline]
    fn texture_at(&self, x: f64, y: f64) -> f32 {
        // Integer floor and wrap: `floor` and `rem_euclid` are library calls here.
        let (xi, yi) = (x as i64 - (x < 0.0) as i64, y as i64 - (y < 0.0) as i64);
        let (tx, ty) = ((x - xi as f64) as f32, (y - yi as f64) as f32);
        let mask = TEXTURE_SIZE as i64 - 1;
        let (ix, iy) = ((xi & mask) as usize, (yi & mask) as usize);
        let (jx, jy) = ((ix + 1) & mask as usize, (iy + 1) & mask as usize);
        let t = &self.texture;
        let a = t[iy * TEXTURE_SIZE + ix] * (1.0 - tx) + t[iy * TEXTURE_SIZE + jx] * tx;
        let b = t[jy * TEXTURE_SIZE + ix] * (1.0 - tx) + t[jy * TEXTURE_SIZE + jx] * tx;
        a * (1.0 - ty) + b * ty
    }

    /// The first surface a ray meets.
    fn hit(&self, ray: &Ray) -> Hit {
        let p0 = ray.at(0.0);
        let pw = ray.at(self.scene.wall_z_mm);
        for (index, plate) in self.scene.plates.iter().enumerate() {
            let (hx, hy) = (plate.size[0] / 2.0, plate.size[1] / 2.0);
            let (cx, cy) = (plate.centre[0], plate.centre[1]);
            // The ray crosses the plate's volume only if its path from z = 0 to the
            // wall touches the plate's footprint.
            if p0[0].max(pw[0]) < cx - hx
                || p0[0].min(pw[0]) > cx + hx
                || p0[1].max(pw[1]) < cy - hy
                || p0[1].min(pw[1]) > cy + hy
            {
                continue;
            }
            if let Some(hit) = self.hit_plate(index, plate, ray) {
                return self.with_spots(hit, ray);
            }
        }
        let wall = self.scene.wall_colour;
        let t = self.texture_at(pw[0] / TEXEL_MM, pw[1] / TEXEL_MM);
        self.with_spots(
            Hit {
                id: 0,
                albedo: scale(wall, t),
                lit: Lit::Flat { shadow: ShadowOn::Wall },
                gloss: 0.0,
                shininess: 1.0,
            },
            ray,
        )
    }

    /// Dark spots darken whatever surface they lie on.
    #[inline]
    fn with_spots(&self, mut hit: Hit, ray: &Ray) -> Hit {
        if self.scene.spots.is_empty() {
            return hit;
        }
        let z = match hit.lit {
            Lit::Flat { shadow: ShadowOn::Wall } => self.scene.wall_z_mm,
            Lit::Flat { shadow: ShadowOn::Plate(i) } => self.scene.plates[i].top_z(self.scene.wall_z_mm),
            Lit::Inside => return hit,
            _ => 0.0,
        };
        let p = ray.at(z);
        for (k, s) in self.scene.spots.iter().enumerate() {
            let (dx, dy) = (p[0] - s.centre[0], p[1] - s.centre[1]);
            if dx * dx + dy * dy < s.radius * s.radius {
                hit.albedo = scale(hit.albedo, s.shade);
                hit.id = 0x8000 + k as u32;
                hit.gloss *= 0.3;
            }
        }
        hit
    }

    fn hit_plate(&self, index: usize, plate: &Plate, ray: &Ray) -> Option<Hit> {
        let id = (index as u32 + 1) << 8;
        let c = plate.centre;
        let local = |z: f64| {
            let p = ray.at(z);
            [p[0] - c[0], p[1] - c[1]]
        };
        let zt = plate.top_z(self.scene.wall_z_mm);
        let gloss = plate.gloss;
        let shininess = plate.shininess;
        // Receptacle faces stand on the plate, from its top up to z = 0.
        if let Insert::Receptacles(faces) = &plate.insert {
            let q0 = local(0.0);
            let qt = local(zt);
            for (f, face) in faces.iter().enumerate() {
                let id = id + 16 * (f as u32 + 1);
                let (x0, y0) = (q0[0] - face.centre[0], q0[1] - face.centre[1]);
                let sd_top = face_sd(x0, y0, &face.shape);
                if sd_top < 0.0 {
                    for (k, opening) in Opening::ALL.iter().enumerate() {
                        let [ox, oy] = opening.centre();
                        let t_slot = face.shape.t_slot;
                        let [ex, ey] = opening.half_extent(t_slot);
                        if (x0 - ox).abs() > ex || (y0 - oy).abs() > ey || opening.sd(x0, y0, t_slot) >= 0.0 {
                            continue;
                        }
                        return Some(self.inside_opening(
                            id + 4 + 2 * k as u32,
                            face.colour,
                            Ray { p0: [x0, y0], slope: ray.slope },
                            [ox, oy],
                            |x, y| opening.sd(x, y, t_slot) < 0.0,
                            *opening != Opening::Ground,
                        ));
                    }
                    if sd_top > -RIM_MM {
                        // The rounded rim slopes away from the face's centre.
                        let out = rim_direction(x0, y0, &face.shape);
                        let t = (1.0 + sd_top / RIM_MM) as f32; // 0 inner edge .. 1 outer edge
                        let s = 0.25 + 0.6 * t;
                        let albedo = scale(face.colour, 1.0 - face.rim * t);
                        return Some(Hit {
                            id: id + 1,
                            albedo,
                            lit: Lit::Tilted { normal: unit([out[0] as f32 * s, out[1] as f32 * s, -1.0]) },
                            gloss: gloss * 0.5,
                            shininess,
                        });
                    }
                    return Some(Hit {
                        id,
                        albedo: face.colour,
                        lit: Lit::Flat { shadow: ShadowOn::Raised },
                        gloss,
                        shininess,
                    });
                }
                let (xt, yt) = (qt[0] - face.centre[0], qt[1] - face.centre[1]);
                let sd_side = face_sd(xt, yt, &face.shape);
                if (0.0..FACE_GAP_MM).contains(&sd_side) {
                    // The dark gap between the face and the plate's opening.
                    return Some(Hit {
                        id: id + 3,
                        albedo: scale(plate.colour, 0.12),
                        lit: Lit::Inside,
                        gloss: 0.0,
                        shininess,
                    });
                }
                if sd_side < 0.0 {
                    // The face's vertical side, seen obliquely.
                    let out = rim_direction(xt, yt, &face.shape);
                    return Some(Hit {
                        id: id + 2,
                        albedo: scale(face.colour, 1.0 - face.rim),
                        lit: Lit::Tilted { normal: unit([out[0] as f32, out[1] as f32, -0.15]) },
                        gloss: 0.0,
                        shininess,
                    });
                }
            }
        }
        let q = local(zt);
        let (thx, thy) = (plate.size[0] / 2.0 - plate.bevel, plate.size[1] / 2.0 - plate.bevel);
        if q[0].abs() <= thx && q[1].abs() <= thy {
            return Some(self.plate_top(index, id, plate, ray, q));
        }
        let qw = local(self.scene.wall_z_mm);
        if qw[0].abs() <= plate.size[0] / 2.0 && qw[1].abs() <= plate.size[1] / 2.0 {
            // The bevel rises from the wall to the top: its normal leans outwards.
            let (ox, oy) =
                if (q[0].abs() - thx) > (q[1].abs() - thy) { (q[0].signum(), 0.0) } else { (0.0, q[1].signum()) };
            let lean = (plate.proud / plate.bevel.max(0.1)) as f32;
            return Some(Hit {
                id: id + 3,
                albedo: plate.colour,
                lit: Lit::Tilted { normal: unit([ox as f32 * lean, oy as f32 * lean, -1.0]) },
                gloss: gloss * 0.7,
                shininess,
            });
        }
        None
    }

    fn plate_top(&self, index: usize, id: u32, plate: &Plate, ray: &Ray, q: [f64; 2]) -> Hit {
        let flat = Lit::Flat { shadow: ShadowOn::Plate(index) };
        let mut hit =
            Hit { id: id + 5, albedo: plate.colour, lit: flat, gloss: plate.gloss, shininess: plate.shininess };
        for s in &plate.screws {
            let (dx, dy) = (q[0] - s.centre[0], q[1] - s.centre[1]);
            let r2 = dx * dx + dy * dy;
            if r2 < s.radius * s.radius {
                let (sin, cos) = s.slot_angle.sin_cos();
                let across = -dx * sin + dy * cos;
                if across.abs() < 0.45 {
                    return Hit {
                        id: id + 7,
                        albedo: scale(s.colour, 0.12),
                        lit: Lit::Inside,
                        gloss: 0.0,
                        shininess: 1.0,
                    };
                }
                let rho = (r2.sqrt() / s.radius) as f32;
                let n = unit([dx as f32 / s.radius as f32 * 0.8, dy as f32 / s.radius as f32 * 0.8, -1.0]);
                return Hit {
                    id: id + 6,
                    albedo: scale(s.colour, 1.0 - 0.3 * rho * rho),
                    lit: Lit::Tilted { normal: n },
                    gloss: plate.gloss,
                    shininess: plate.shininess,
                };
            }
        }
        match &plate.insert {
            Insert::Toggle { lever_up } => {
                let [hx, hy] = TOGGLE_OPENING_HALF_MM;
                if q[0].abs() < hx && q[1].abs() < hy {
                    let lever_y = if *lever_up { -4.0 } else { 4.0 };
                    let [lx, ly] = TOGGLE_LEVER_HALF_MM;
                    if box_sd(q[0], q[1] - lever_y, lx, ly) < 0.0 {
                        let n = unit([0.0, if *lever_up { -0.8 } else { 0.8 }, -1.0]);
                        return Hit {
                            id: id + 8,
                            albedo: plate.colour,
                            lit: Lit::Tilted { normal: n },
                            gloss: plate.gloss,
                            shininess: plate.shininess,
                        };
                    }
                    return Hit {
                        id: id + 9,
                        albedo: scale(plate.colour, 0.3),
                        lit: Lit::Inside,
                        gloss: 0.0,
                        shininess: 1.0,
                    };
                }
            }
            Insert::Rocker { colour } => {
                let [hx, hy] = ROCKER_HALF_MM;
                if q[0].abs() < hx && q[1].abs() < hy {
                    if q[1].abs() < 0.25 {
                        return Hit {
                            id: id + 10,
                            albedo: scale(*colour, 0.35),
                            lit: Lit::Inside,
                            gloss: 0.0,
                            shininess: 1.0,
                        };
                    }
                    let n = unit([0.0, if q[1] < 0.0 { -0.12 } else { 0.12 }, -1.0]);
                    return Hit {
                        id: id + 11,
                        albedo: *colour,
                        lit: Lit::Tilted { normal: n },
                        gloss: plate.gloss,
                        shininess: plate.shininess,
                    };
                }
            }
            Insert::DataJacks { centres, colour } => {
                for (k, jc) in centres.iter().enumerate() {
                    let (x, y) = (q[0] - jc[0], q[1] - jc[1]);
                    if x.abs() < JACK_HALF_MM[0] && y.abs() < JACK_HALF_MM[1] {
                        let [ox, oy] = JACK_OPENING_HALF_MM;
                        if box_sd(x, y - 1.5, ox, oy) < 0.0 {
                            return self.inside_opening(
                                id + 12 + 2 * k as u32,
                                *colour,
                                Ray { p0: [x, y], slope: ray.slope },
                                [0.0, 1.5],
                                |a, b| box_sd(a, b - 1.5, ox, oy) < 0.0,
                                false,
                            );
                        }
                        return Hit {
                            id: id + 13 + 2 * k as u32,
                            albedo: *colour,
                            lit: flat,
                            gloss: plate.gloss * 0.5,
                            shininess: plate.shininess,
                        };
                    }
                }
            }
            Insert::Receptacles(_) | Insert::Blank => {}
        }
        for crack in &plate.cracks {
            if on_crack(crack, q) {
                hit.albedo = scale(hit.albedo, crack.darkness);
                hit.id = id + 14;
                hit.lit = Lit::Inside;
                break;
            }
        }
        hit
    }

    /// A sample seen through an opening: the far side wall fading with depth, or
    /// the dark floor when the ray reaches it. `entry` is the ray from where it
    /// enters, in the opening's own coordinates (mm).
    fn inside_opening(
        &self,
        id: u32,
        colour: Rgb,
        entry: Ray,
        centre: [f64; 2],
        inside: impl Fn(f64, f64) -> bool,
        glints: bool,
    ) -> Hit {
        let at = |z: f64| {
            let p = entry.at(z);
            (p[0], p[1])
        };
        let (fx, fy) = at(HOLE_DEPTH_MM);
        if inside(fx, fy) {
            return Hit {
                id,
                albedo: scale(colour, self.scene.hole_floor),
                lit: Lit::Inside,
                gloss: 0.0,
                shininess: 1.0,
            };
        }
        let (mut lo, mut hi) = (0.0, HOLE_DEPTH_MM);
        for _ in 0..7 {
            let mid = 0.5 * (lo + hi);
            let (x, y) = at(mid);
            if inside(x, y) { lo = mid } else { hi = mid }
        }
        let depth = 0.5 * (lo + hi);
        let mut shade = 0.4 * (-depth / self.scene.hole_fade_mm).exp() as f32 + self.scene.hole_floor;
        // The brass contacts a few mm in, towards the slot's ends, catch the light.
        let (_, exit_y) = at(depth);
        if glints && self.scene.hole_glint > 0.0 && (2.2..3.0).contains(&depth) && (exit_y - centre[1]).abs() > 2.0 {
            shade += self.scene.hole_glint * 0.35;
        }
        Hit { id: id + 1, albedo: scale(colour, shade), lit: Lit::Inside, gloss: 0.0, shininess: 1.0 }
    }

    /// Fraction of the direct light that reaches a sample, from cast shadows.
    fn shadow(&self, on: ShadowOn, ray: &Ray) -> f32 {
        let l = &self.light_mm;
        let softness = self.scene.light.softness;
        match on {
            ShadowOn::Raised => 1.0,
            ShadowOn::Wall => {
                let p = ray.at(self.scene.wall_z_mm);
                let mut lit = 1.0f32;
                for plate in &self.scene.plates {
                    let to_light = [l.x - p[0], l.y - p[1], l.z - self.scene.wall_z_mm];
                    if to_light[2] >= -1e-9 {
                        continue;
                    }
                    // Where the path to the light crosses the plate's top.
                    let s = -plate.proud / to_light[2];
                    let q = [p[0] + s * to_light[0] - plate.centre[0], p[1] + s * to_light[1] - plate.centre[1]];
                    let (hx, hy) = (plate.size[0] / 2.0 - plate.bevel * 0.5, plate.size[1] / 2.0 - plate.bevel * 0.5);
                    let penumbra = softness * plate.proud + 0.3;
                    if q[0].abs() > hx + penumbra || q[1].abs() > hy + penumbra {
                        continue;
                    }
                    lit = lit.min(smoothstep(-1.0, 1.0, box_sd(q[0], q[1], hx, hy) / penumbra) as f32);
                }
                lit
            }
            ShadowOn::Plate(i) => {
                let plate = &self.scene.plates[i];
                let Insert::Receptacles(faces) = &plate.insert else { return 1.0 };
                let zt = plate.top_z(self.scene.wall_z_mm);
                let p = ray.at(zt);
                let to_light = [l.x - p[0], l.y - p[1], l.z - zt];
                if to_light[2] >= -1e-9 {
                    return 1.0;
                }
                let s = -zt / to_light[2];
                let q = [p[0] + s * to_light[0] - plate.centre[0], p[1] + s * to_light[1] - plate.centre[1]];
                let mut lit = 1.0f32;
                for face in faces {
                    let sd = face_sd(q[0] - face.centre[0], q[1] - face.centre[1], &face.shape);
                    lit = lit.min(smoothstep(-1.0, 1.0, sd / (softness * zt + 0.2)) as f32);
                }
                lit
            }
        }
    }

    /// Fraction of the direct light left by occluders out of view.
    fn occlusion(&self, p: [f64; 2]) -> f32 {
        let mut lit = 1.0f32;
        for o in &self.scene.occluders {
            let s = o.normal[0] * p[0] + o.normal[1] * p[1];
            let into = smoothstep(-o.penumbra_mm, o.penumbra_mm, s - o.offset_mm)
                * smoothstep(-o.penumbra_mm, o.penumbra_mm, o.offset_mm + o.width_mm - s);
            lit *= 1.0 - o.strength * into as f32;
        }
        lit
    }

    /// Radiance of one sample given the pixel's light.
    #[inline]
    fn shade(
        &self,
        hit: &Hit,
        light: &PixelLight,
        ray: &Ray,
        wall_shadow: &mut Option<f32>,
        plate_shadow: &mut Option<f32>,
    ) -> Rgb {
        let ambient = self.scene.light.ambient;
        match hit.lit {
            Lit::Flat { shadow } => {
                let cast = match shadow {
                    ShadowOn::Raised => 1.0,
                    ShadowOn::Wall => *wall_shadow.get_or_insert_with(|| self.shadow(shadow, ray)),
                    ShadowOn::Plate(_) => *plate_shadow.get_or_insert_with(|| self.shadow(shadow, ray)),
                };
                let direct = light.diffuse_flat * light.occlusion * cast;
                let spec = if hit.gloss > 0.0 && light.nh > 0.3 {
                    hit.gloss * light.nh.powf(hit.shininess) * direct
                } else {
                    0.0
                };
                let k = ambient + direct;
                [hit.albedo[0] * k + spec, hit.albedo[1] * k + spec, hit.albedo[2] * k + spec]
            }
            Lit::Tilted { normal } => {
                let cos = (normal[0] * light.dir[0] + normal[1] * light.dir[1] + normal[2] * light.dir[2]).max(0.0);
                let k = ambient + light.irradiance * cos * light.occlusion;
                scale(hit.albedo, k)
            }
            Lit::Inside => scale(hit.albedo, ambient + light.diffuse_flat * light.occlusion),
        }
    }

    /// Light at a pixel's centre, shared by its samples.
    fn pixel_light(&self, ray: &Ray) -> PixelLight {
        let p = ray.at(0.0);
        let point = Point3::new(p[0], p[1], 0.0);
        let to_light = self.light_mm - point;
        let r2 = to_light.norm_squared().max(1.0);
        let dir = to_light / r2.sqrt();
        let irradiance = (self.light_power / r2) as f32;
        let diffuse_flat = irradiance * (-dir.z).max(0.0) as f32;
        let to_camera = (self.camera_mm - point).normalize();
        let half = (dir + to_camera).normalize();
        let nh = -half.z as f32;
        PixelLight {
            dir: [dir.x as f32, dir.y as f32, dir.z as f32],
            irradiance,
            diffuse_flat,
            nh,
            occlusion: self.occlusion(p),
        }
    }
}

struct PixelLight {
    dir: [f32; 3],
    irradiance: f32,
    diffuse_flat: f32,
    /// Cosine between the surface normal and the half vector (Blinn-Phong).
    nh: f32,
    occlusion: f32,
}

#[inline]
fn on_crack(crack: &Crack, q: [f64; 2]) -> bool {
    let [x0, y0, x1, y1] = crack.bounds();
    if q[0] < x0 || q[0] > x1 || q[1] < y0 || q[1] > y1 {
        return false;
    }
    crack.points.windows(2).any(|w| segment_distance(q, w[0], w[1]) < crack.half_width)
}

#[inline]
fn rim_direction(x: f64, y: f64, shape: &FaceShape) -> [f64; 2] {
    // Near the flat top and bottom the rim faces straight up or down.
    if shape.half_height - y.abs() < shape.radius - (x * x + y * y).sqrt() {
        [0.0, y.signum()]
    } else {
        let r = (x * x + y * y).sqrt().max(1e-9);
        [x / r, y / r]
    }
}

#[inline]
fn scale(c: Rgb, k: f32) -> Rgb {
    [c[0] * k, c[1] * k, c[2] * k]
}

#[inline]
fn unit(v: [f32; 3]) -> [f32; 3] {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    [v[0] / n, v[1] / n, v[2] / n]
}

#[inline]
fn smoothstep(lo: f64, hi: f64, x: f64) -> f64 {
    let t = ((x - lo) / (hi - lo)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// The wall's reflectance multiplier per texel: fine grain of amplitude `grain`
/// over smooth blotches of 4%, both tiling.
fn wall_texture(seed: u64, grain: f32) -> Vec<f32> {
    let mut rng = SimRng::new(seed);
    let n = TEXTURE_SIZE / BLOTCH_TEXELS;
    let blotches: Vec<f32> = (0..n * n).map(|_| rng.range(-1.0, 1.0) as f32).collect();
    let mut texture = Vec::with_capacity(TEXTURE_SIZE * TEXTURE_SIZE);
    for y in 0..TEXTURE_SIZE {
        for x in 0..TEXTURE_SIZE {
            let (gx, gy) = (x as f32 / BLOTCH_TEXELS as f32, y as f32 / BLOTCH_TEXELS as f32);
            let (i, j) = (gx as usize, gy as usize);
            let (tx, ty) = (gx - i as f32, gy - j as f32);
            let b = |i: usize, j: usize| blotches[(j % n) * n + i % n];
            let blotch = (b(i, j) * (1.0 - tx) + b(i + 1, j) * tx) * (1.0 - ty)
                + (b(i, j + 1) * (1.0 - tx) + b(i + 1, j + 1) * tx) * ty;
            texture.push(1.0 + 0.04 * blotch + grain * rng.range(-1.0, 1.0) as f32);
        }
    }
    texture
}

/// Normalised undistorted coordinates of pixel corners, exact on a coarse grid and
/// bilinear between (the distortion map is smooth: the error is ~1e-3 px).
pub(crate) struct UndistortGrid {
    cols: usize,
    rows: usize,
    xy: Vec<[f64; 2]>,
}

impl UndistortGrid {
    pub(crate) fn new(camera: &outlet_protocol::CameraModel) -> Self {
        let g = UNDISTORT_GRID_PX;
        let cols = (camera.width as usize).div_ceil(g) + 2;
        let rows = (camera.height as usize).div_ceil(g) + 2;
        let mut xy = Vec::with_capacity(cols * rows);
        for j in 0..rows {
            for i in 0..cols {
                let n = camera.undistort_pixel(Point2::new((i * g) as f64 - 0.5, (j * g) as f64 - 0.5));
                xy.push([n.x, n.y]);
            }
        }
        Self { cols, rows, xy }
    }

    /// At the pixel coordinates `(u, v)` (with u = -0.5 the left image edge).
    #[inline]
    pub(crate) fn at(&self, u: f64, v: f64) -> [f64; 2] {
        let (j, tv) = self.cell(v, self.rows);
        let (i, tu) = self.cell(u, self.cols);
        let a = self.xy[j * self.cols + i];
        let b = self.xy[j * self.cols + i + 1];
        let c = self.xy[(j + 1) * self.cols + i];
        let d = self.xy[(j + 1) * self.cols + i + 1];
        let mut out = [0.0; 2];
        for k in 0..2 {
            out[k] = (a[k] * (1.0 - tu) + b[k] * tu) * (1.0 - tv) + (c[k] * (1.0 - tu) + d[k] * tu) * tv;
        }
        out
    }

    #[inline]
    fn cell(&self, x: f64, n: usize) -> (usize, f64) {
        let g = ((x + 0.5) / UNDISTORT_GRID_PX as f64).max(0.0);
        let i = (g as usize).min(n - 2);
        (i, g - i as f64)
    }

    /// Every value along the row `v`, at `u = u0 + k` for k in 0..n.
    pub(crate) fn row(&self, v: f64, u0: f64, n: usize) -> Vec<[f64; 2]> {
        let (j, tv) = self.cell(v, self.rows);
        let coarse: Vec<[f64; 2]> = (0..self.cols)
            .map(|i| {
                let (a, c) = (self.xy[j * self.cols + i], self.xy[(j + 1) * self.cols + i]);
                [a[0] + (c[0] - a[0]) * tv, a[1] + (c[1] - a[1]) * tv]
            })
            .collect();
        (0..n)
            .map(|k| {
                let (i, tu) = self.cell(u0 + k as f64, self.cols);
                let (a, b) = (coarse[i], coarse[i + 1]);
                [a[0] + (b[0] - a[0]) * tu, a[1] + (b[1] - a[1]) * tu]
            })
            .collect()
    }
}

/// Pixel columns between exact light evaluations along a row: light varies slowly
/// across the wall, so it is interpolated between them.
const LIGHT_STEP_PX: usize = 4;

impl PixelLight {
    fn lerp(a: &PixelLight, b: &PixelLight, t: f32) -> PixelLight {
        let m = |x: f32, y: f32| x + (y - x) * t;
        PixelLight {
            dir: [m(a.dir[0], b.dir[0]), m(a.dir[1], b.dir[1]), m(a.dir[2], b.dir[2])],
            irradiance: m(a.irradiance, b.irradiance),
            diffuse_flat: m(a.diffuse_flat, b.diffuse_flat),
            nh: m(a.nh, b.nh),
            occlusion: m(a.occlusion, b.occlusion),
        }
    }
}

/// Linear radiance of every pixel, RGB interleaved, before the sensor.
pub(crate) fn render_radiance(scene: &Scene, prepared: &Prepared, grid: &UndistortGrid) -> Vec<f32> {
    let (w, h) = (scene.camera.width as usize, scene.camera.height as usize);
    let mut out = vec![0.0f32; w * h * 3];
    let background = Hit { id: u32::MAX, albedo: [0.05; 3], lit: Lit::Inside, gloss: 0.0, shininess: 1.0 };
    let ray_at = |u: f64, v: f64| {
        let n = grid.at(u, v);
        prepared.ray(n[0], n[1])
    };
    let corner_row = |v: f64| -> Vec<(Option<Ray>, Hit)> {
        grid.row(v, -0.5, w + 1)
            .into_iter()
            .map(|n| {
                let r = prepared.ray(n[0], n[1]);
                (r, r.as_ref().map_or(background, |r| prepared.hit(r)))
            })
            .collect()
    };
    let mut top = corner_row(-0.5);
    let mut thin_row = vec![false; w];
    let mut lights: Vec<Option<PixelLight>> = Vec::new();
    for y in 0..h {
        let bottom = corner_row(y as f64 + 0.5);
        thin_row.iter_mut().for_each(|t| *t = false);
        for b in &prepared.thin_boxes {
            if (y as f64) < b[1] || (y as f64) > b[3] {
                continue;
            }
            let (x0, x1) = (b[0].max(0.0) as usize, (b[2].max(0.0) as usize).min(w.saturating_sub(1)));
            for t in thin_row.iter_mut().take(x1 + 1).skip(x0) {
                *t = true;
            }
        }
        lights.clear();
        lights.extend(
            (0..w.div_ceil(LIGHT_STEP_PX) + 1)
                .map(|k| ray_at((k * LIGHT_STEP_PX) as f64, y as f64).map(|r| prepared.pixel_light(&r))),
        );
        for x in 0..w {
            let corners = [&top[x], &top[x + 1], &bottom[x], &bottom[x + 1]];
            let (k, t) = (x / LIGHT_STEP_PX, (x % LIGHT_STEP_PX) as f32 / LIGHT_STEP_PX as f32);
            let centre = match (corners[0].0, corners[1].0, corners[2].0, corners[3].0) {
                (Some(a), Some(b), Some(c), Some(d)) => Some(Ray {
                    p0: [(a.p0[0] + b.p0[0] + c.p0[0] + d.p0[0]) / 4.0, (a.p0[1] + b.p0[1] + c.p0[1] + d.p0[1]) / 4.0],
                    slope: [
                        (a.slope[0] + b.slope[0] + c.slope[0] + d.slope[0]) / 4.0,
                        (a.slope[1] + b.slope[1] + c.slope[1] + d.slope[1]) / 4.0,
                    ],
                }),
                _ => ray_at(x as f64, y as f64),
            };
            let (Some(centre), Some(l0), Some(l1)) = (centre, &lights[k], &lights[k + 1]) else {
                out[(y * w + x) * 3..][..3].copy_from_slice(&background.albedo);
                continue;
            };
            let light = PixelLight::lerp(l0, l1, t);
            let id = corners[0].1.id;
            let uniform = !thin_row[x] && corners.iter().all(|c| c.1.id == id);
            let (mut wall_shadow, mut plate_shadow) = (None, None);
            let px = if uniform {
                // One shading with the corners' mean reflectance.
                let mut hit = corners[0].1;
                for c in &corners[1..] {
                    for (a, b) in hit.albedo.iter_mut().zip(c.1.albedo) {
                        *a += b;
                    }
                }
                hit.albedo = scale(hit.albedo, 0.25);
                prepared.shade(&hit, &light, &centre, &mut wall_shadow, &mut plate_shadow)
            } else {
                let mut sum = [0.0f32; 3];
                let n = SUPERSAMPLE as f64;
                for sj in 0..SUPERSAMPLE {
                    for si in 0..SUPERSAMPLE {
                        let u = x as f64 - 0.5 + (si as f64 + 0.5) / n;
                        let v = y as f64 - 0.5 + (sj as f64 + 0.5) / n;
                        let c = match ray_at(u, v) {
                            Some(ray) => {
                                let hit = prepared.hit(&ray);
                                prepared.shade(&hit, &light, &ray, &mut wall_shadow, &mut plate_shadow)
                            }
                            None => background.albedo,
                        };
                        sum = [sum[0] + c[0], sum[1] + c[1], sum[2] + c[2]];
                    }
                }
                scale(sum, 1.0 / (SUPERSAMPLE * SUPERSAMPLE) as f32)
            };
            out[(y * w + x) * 3..][..3].copy_from_slice(&px);
        }
        top = bottom;
    }
    out
}

/// Separable Gaussian blur of interleaved RGB, in place (edges clamped). The
/// loops run over whole padded rows so that they vectorise.
fn blur(buf: &mut [f32], w: usize, h: usize, sigma: f32) {
    let radius = (3.0 * sigma).ceil() as usize;
    let mut kernel: Vec<f32> = (0..=2 * radius)
        .map(|i| {
            let d = i as f32 - radius as f32;
            (-(d * d) / (2.0 * sigma * sigma)).exp()
        })
        .collect();
    let total: f32 = kernel.iter().sum();
    kernel.iter_mut().for_each(|k| *k /= total);
    let stride = w * 3;
    let mut padded = vec![0.0f32; (w + 2 * radius) * 3];
    for y in 0..h {
        let row = &mut buf[y * stride..(y + 1) * stride];
        for k in 0..radius {
            padded[k * 3..k * 3 + 3].copy_from_slice(&row[..3]);
            let tail = (radius + w + k) * 3;
            padded[tail..tail + 3].copy_from_slice(&row[stride - 3..]);
        }
        padded[radius * 3..(radius + w) * 3].copy_from_slice(row);
        row.iter_mut().for_each(|v| *v = 0.0);
        for (j, &kj) in kernel.iter().enumerate() {
            for (o, &i) in row.iter_mut().zip(&padded[j * 3..j * 3 + stride]) {
                *o += kj * i;
            }
        }
    }
    let source = buf.to_vec();
    for y in 0..h {
        let row = &mut buf[y * stride..(y + 1) * stride];
        row.iter_mut().for_each(|v| *v = 0.0);
        for (j, &kj) in kernel.iter().enumerate() {
            let sy = (y + j).saturating_sub(radius).min(h - 1);
            for (o, &i) in row.iter_mut().zip(&source[sy * stride..(sy + 1) * stride]) {
                *o += kj * i;
            }
        }
    }
}

/// Exposure, sensor noise, clipping and gamma: radiance to 8-bit pixels.
fn expose(radiance: &[f32], scene: &Scene) -> Vec<u8> {
    const LUT_SIZE: usize = 4096;
    let sensor = &scene.sensor;
    let lut: Vec<u8> = (0..LUT_SIZE)
        .map(|i| ((i as f32 / (LUT_SIZE - 1) as f32).powf(1.0 / sensor.gamma) * 255.0 + 0.5) as u8)
        .collect();
    let mut rng = SimRng::new(scene.noise_seed);
    let sqrt3 = 3.0f32.sqrt();
    // Noise per channel; its sigma from the pixel's mean level (one square root
    // per pixel, not per channel).
    let mut out = Vec::with_capacity(radiance.len());
    for px in radiance.chunks_exact(3) {
        let v = [px[0] * sensor.exposure, px[1] * sensor.exposure, px[2] * sensor.exposure];
        let level = ((v[0] + v[1] + v[2]) * (1.0 / 3.0)).max(0.0);
        let sigma = (sensor.read_noise * sensor.read_noise + sensor.shot_noise * level).sqrt();
        for c in v {
            // Sum of four 16-bit uniforms: close to a Gaussian and four times cheaper.
            let bits = rng.next_u64();
            let sum = (bits & 0xFFFF) + ((bits >> 16) & 0xFFFF) + ((bits >> 32) & 0xFFFF) + (bits >> 48);
            let gauss = (sum as f32 / 65536.0 - 2.0) * sqrt3;
            let v = (c + sigma * gauss).clamp(0.0, 1.0);
            out.push(lut[(v * (LUT_SIZE - 1) as f32) as usize]);
        }
    }
    out
}

/// Renders the camera image of a scene.
pub fn render(scene: &Scene) -> Frame {
    let prepared = Prepared::new(scene);
    let grid = UndistortGrid::new(&scene.camera);
    render_with(scene, &prepared, &grid)
}

pub(crate) fn render_with(scene: &Scene, prepared: &Prepared, grid: &UndistortGrid) -> Frame {
    let (w, h) = (scene.camera.width as usize, scene.camera.height as usize);
    let mut radiance = render_radiance(scene, prepared, grid);
    if scene.sensor.blur_sigma >= 0.3 {
        blur(&mut radiance, w, h, scene.sensor.blur_sigma);
    }
    let bytes = expose(&radiance, scene);
    let image = RgbImage::from_raw(scene.camera.width, scene.camera.height, bytes)
        .unwrap_or_else(|| RgbImage::new(scene.camera.width, scene.camera.height));
    match scene.sensor.jpeg_quality {
        Some(q) => {
            let mut jpeg = Vec::new();
            let encoded = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, q).encode_image(&image);
            let decoded = encoded
                .ok()
                .and_then(|_| image::load_from_memory_with_format(&jpeg, image::ImageFormat::Jpeg).ok())
                .map(|d| d.to_rgb8());
            match decoded {
                Some(decoded) => Frame { image: decoded, jpeg: Some(jpeg) },
                None => Frame { image, jpeg: None },
            }
        }
        None => Frame { image, jpeg: None },
    }
}

/// Milliseconds spent in each stage of one frame: undistortion grid, ray casting,
/// blur, exposure, JPEG. For profiling; `render` is what to call.
pub fn phase_times(scene: &Scene) -> [(&'static str, f64); 5] {
    let (w, h) = (scene.camera.width as usize, scene.camera.height as usize);
    let t = std::time::Instant::now();
    let prepared = Prepared::new(scene);
    let grid = UndistortGrid::new(&scene.camera);
    let t_grid = t.elapsed().as_secs_f64() * 1e3;
    let t = std::time::Instant::now();
    let mut radiance = render_radiance(scene, &prepared, &grid);
    let t_cast = t.elapsed().as_secs_f64() * 1e3;
    let t = std::time::Instant::now();
    blur(&mut radiance, w, h, scene.sensor.blur_sigma.max(0.8));
    let t_blur = t.elapsed().as_secs_f64() * 1e3;
    let t = std::time::Instant::now();
    let bytes = expose(&radiance, scene);
    let t_expose = t.elapsed().as_secs_f64() * 1e3;
    let t = std::time::Instant::now();
    let image = RgbImage::from_raw(scene.camera.width, scene.camera.height, bytes).unwrap_or_default();
    let mut jpeg = Vec::new();
    let _ = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 80).encode_image(&image);
    let _ = image::load_from_memory_with_format(&jpeg, image::ImageFormat::Jpeg);
    let t_jpeg = t.elapsed().as_secs_f64() * 1e3;
    [("grid", t_grid), ("cast", t_cast), ("blur", t_blur), ("expose", t_expose), ("jpeg", t_jpeg)]
}
