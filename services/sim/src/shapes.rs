//! Point-in-shape tests and signed distances of the outlet's outlines, in mm of the
//! outlet plane. Negative distance = inside.

use outlet_protocol::geometry::{
    GROUND_BELOW_SLOTS_MM, GROUND_DIAMETER_MM, HOT_SLOT_MM, NEUTRAL_SLOT_MM, SLOT_PITCH_MM, SLOT_Y_MM,
};

/// Half height of a receptacle face and the radius of its rounded sides (mm).
pub const FACE_HALF_HEIGHT_MM: f64 = 14.0;
pub const FACE_RADIUS_MM: f64 = 17.5;
/// The flat of the ground hole, from its centre towards the slots (mm).
pub const GROUND_FLAT_MM: f64 = 1.6;

/// Signed distance to an axis-aligned box of half sizes `h` centred at the origin.
#[inline]
pub fn box_sd(x: f64, y: f64, hx: f64, hy: f64) -> f64 {
    let dx = x.abs() - hx;
    let dy = y.abs() - hy;
    let outside = (dx.max(0.0).powi(2) + dy.max(0.0).powi(2)).sqrt();
    outside + dx.max(dy).min(0.0)
}

/// The outline of a receptacle face: a disc cut by two horizontal lines (makers
/// differ), and whether its neutral slot is the T of a 20 A receptacle (5-20R).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaceShape {
    pub radius: f64,
    pub half_height: f64,
    pub t_slot: bool,
}

impl Default for FaceShape {
    fn default() -> Self {
        Self { radius: FACE_RADIUS_MM, half_height: FACE_HALF_HEIGHT_MM, t_slot: false }
    }
}

/// Signed distance to a receptacle face centred at the origin (approximate outside
/// the shape, exact sign).
#[inline]
pub fn face_sd(x: f64, y: f64, shape: &FaceShape) -> f64 {
    let disc = (x * x + y * y).sqrt() - shape.radius;
    disc.max(y.abs() - shape.half_height)
}

/// The sideways branch of a 5-20R neutral slot: towards the plate's edge, at the
/// slot's end nearer the ground hole (mm, from the slot's centre).
const T_BRANCH_LENGTH_MM: f64 = 3.0;

/// Which opening of a receptacle a point (receptacle coordinates, mm) falls in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Opening {
    Neutral,
    Hot,
    Ground,
}

impl Opening {
    pub const ALL: [Opening; 3] = [Opening::Neutral, Opening::Hot, Opening::Ground];

    /// Centre of the opening in receptacle coordinates (mm).
    pub fn centre(self) -> [f64; 2] {
        let half = SLOT_PITCH_MM / 2.0;
        match self {
            Opening::Neutral => [-half, SLOT_Y_MM],
            Opening::Hot => [half, SLOT_Y_MM],
            Opening::Ground => [0.0, SLOT_Y_MM + GROUND_BELOW_SLOTS_MM],
        }
    }

    /// Signed distance from the opening's outline (mm), point in receptacle coordinates.
    #[inline]
    pub fn sd(self, x: f64, y: f64, t_slot: bool) -> f64 {
        let [cx, cy] = self.centre();
        let (dx, dy) = (x - cx, y - cy);
        match self {
            Opening::Neutral => {
                let (hw, hl) = (NEUTRAL_SLOT_MM[0] / 2.0, NEUTRAL_SLOT_MM[1] / 2.0);
                let slot = box_sd(dx, dy, hw, hl);
                if !t_slot {
                    return slot;
                }
                let branch = box_sd(dx + T_BRANCH_LENGTH_MM / 2.0, dy - (hl - hw), hw + T_BRANCH_LENGTH_MM / 2.0, hw);
                slot.min(branch)
            }
            Opening::Hot => box_sd(dx, dy, HOT_SLOT_MM[0] / 2.0, HOT_SLOT_MM[1] / 2.0),
            Opening::Ground => {
                let disc = (dx * dx + dy * dy).sqrt() - GROUND_DIAMETER_MM / 2.0;
                // The flat faces the slots (smaller y).
                disc.max(-dy - GROUND_FLAT_MM)
            }
        }
    }

    /// Half extent of the opening's bounding box about its centre (mm), for quick rejection.
    pub fn half_extent(self, t_slot: bool) -> [f64; 2] {
        match self {
            Opening::Neutral if t_slot => [NEUTRAL_SLOT_MM[0] / 2.0 + T_BRANCH_LENGTH_MM, NEUTRAL_SLOT_MM[1] / 2.0],
            Opening::Neutral => [NEUTRAL_SLOT_MM[0] / 2.0, NEUTRAL_SLOT_MM[1] / 2.0],
            Opening::Hot => [HOT_SLOT_MM[0] / 2.0, HOT_SLOT_MM[1] / 2.0],
            Opening::Ground => [GROUND_DIAMETER_MM / 2.0, GROUND_DIAMETER_MM / 2.0],
        }
    }
}

/// Distance from a point to a segment.
#[inline]
pub fn segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (abx, aby) = (b[0] - a[0], b[1] - a[1]);
    let (apx, apy) = (p[0] - a[0], p[1] - a[1]);
    let len2 = abx * abx + aby * aby;
    let t = if len2 > 0.0 { ((apx * abx + apy * aby) / len2).clamp(0.0, 1.0) } else { 0.0 };
    ((apx - t * abx).powi(2) + (apy - t * aby).powi(2)).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn opening_centres_are_inside_and_the_ground_flat_cuts_towards_the_slots() {
        for o in Opening::ALL {
            let [x, y] = o.centre();
            assert!(o.sd(x, y, false) < -0.9 && o.sd(x, y, true) < -0.9, "{o:?}");
        }
        let [gx, gy] = Opening::Ground.centre();
        assert!(Opening::Ground.sd(gx, gy + 2.3, false) < 0.0, "round side away from the slots");
        assert!(Opening::Ground.sd(gx, gy - 2.3, false) > 0.0, "flat side towards the slots");
        let [nx, ny] = Opening::Neutral.centre();
        // The T's branch points away from the hot slot, near the ground end.
        assert!(
            Opening::Neutral.sd(nx - 3.0, ny + 3.3, true) < 0.0 && Opening::Neutral.sd(nx - 3.0, ny + 3.3, false) > 0.0
        );
        let shape = FaceShape::default();
        assert!(
            face_sd(0.0, 0.0, &shape) < -10.0 && face_sd(0.0, 15.0, &shape) > 0.0 && face_sd(18.0, 0.0, &shape) > 0.0
        );
    }
}
