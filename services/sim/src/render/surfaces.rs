//! The scene's surfaces as the inner loop sees them: the rays' hits on the wall,
//! the plates and the receptacle faces, and their shading.

use super::{PixelLight, Ray};
use crate::rng::SimRng;
use crate::scene::{Crack, Insert, Plate, Rgb, Scene};
use crate::shapes::{FaceShape, Opening, box_sd, face_sd, segment_distance};
use nalgebra::{Matrix3, Point3, Vector3};

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
/// How a surface sample takes its light.
#[derive(Debug, Clone, Copy)]
pub(super) enum Lit {
    /// Flat, facing out of the wall; `shadow` says whose cast shadow can fall on it.
    Flat { shadow: ShadowOn },
    /// A tilted surface with its own normal (outlet frame, unit).
    Tilted { normal: [f32; 3] },
    /// Inside an opening: the reflectance already holds how deep it is.
    Inside,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum ShadowOn {
    /// The receptacle faces and raised parts: nothing shades them but occluders.
    Raised,
    /// A plate top, which the faces standing on it can shade.
    Plate(usize),
    /// The wall, which the plates can shade.
    Wall,
}

#[derive(Debug, Clone, Copy)]
pub(super) struct Hit {
    /// Which surface: equal ids on a pixel's corners mean one shading suffices.
    pub(super) id: u32,
    pub(super) albedo: Rgb,
    pub(super) lit: Lit,
    pub(super) gloss: f32,
    pub(super) shininess: f32,
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
    pub(super) thin_boxes: Vec<[f64; 4]>,
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
    pub(super) fn hit(&self, ray: &Ray) -> Hit {
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
    pub(super) fn shade(
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
    pub(super) fn pixel_light(&self, ray: &Ray) -> PixelLight {
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
pub(super) fn scale(c: Rgb, k: f32) -> Rgb {
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
