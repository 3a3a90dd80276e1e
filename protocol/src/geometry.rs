//! The outlet geometry of `CONTRACT.md`: NEMA 5-15R duplex receptacles, built-in
//! templates `2x1` and `2x2`, and `GEOMETRY.json` files for any other outlet.

use nalgebra::Point2;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Blade slot pitch, centre to centre (mm).
pub const SLOT_PITCH_MM: f64 = 12.7;
/// Neutral (long, left) slot: width x length (mm).
pub const NEUTRAL_SLOT_MM: [f64; 2] = [2.0, 8.7];
/// Hot (short, right) slot: width x length (mm).
pub const HOT_SLOT_MM: [f64; 2] = [2.0, 7.1];
/// Diameter of the round ground hole (mm).
pub const GROUND_DIAMETER_MM: f64 = 5.0;
/// Ground hole centre below the line of the slot centres (mm).
pub const GROUND_BELOW_SLOTS_MM: f64 = 11.9;
/// Slot centres relative to the receptacle centre, y (mm).
pub const SLOT_Y_MM: f64 = -5.0;
/// Vertical pitch of the two receptacles of a duplex (mm).
pub const DUPLEX_PITCH_MM: f64 = 38.1;
/// Horizontal pitch of two duplexes side by side (mm).
pub const GANG_PITCH_MM: f64 = 46.04;
/// Receptacle face ahead of the wall surface (mm): the wall is the plane z = +5.
pub const FACE_OFFSET_MM: f64 = 5.0;
/// Wall plate of one gang, width x height (mm).
pub const PLATE_1GANG_MM: [f64; 2] = [70.0, 114.3];
/// Wall plate of two gangs, width x height (mm).
pub const PLATE_2GANG_MM: [f64; 2] = [116.8, 114.3];

/// What a hole receives.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum HoleKind {
    Power,
    Ground,
}

impl HoleKind {
    pub fn as_str(self) -> &'static str {
        match self {
            HoleKind::Power => "power",
            HoleKind::Ground => "ground",
        }
    }
}

/// One hole of a template: its kind and centre on the face plane z = 0
/// (outlet frame, mm).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TemplateHole {
    pub kind: HoleKind,
    pub position_mm: [f64; 2],
}

impl TemplateHole {
    pub fn position(&self) -> Point2<f64> {
        Point2::new(self.position_mm[0], self.position_mm[1])
    }
}

/// The holes of an outlet in its own frame (x right, y down seen from the front,
/// ground holes below the slots, z into the wall), and how far the face stands
/// ahead of the wall. This is the `GEOMETRY.json` format of `CONTRACT.md`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OutletGeometry {
    pub holes: Vec<TemplateHole>,
    pub face_offset_mm: f64,
}

/// Why a geometry was refused.
#[derive(Debug, thiserror::Error)]
pub enum GeometryError {
    #[error("cannot read geometry file {path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("geometry file {path} is not valid JSON of the GEOMETRY format: {source}")]
    Json { path: String, source: serde_json::Error },
    #[error("geometry {name} has {count} holes; at least 3 are needed")]
    TooFewHoles { name: String, count: usize },
    #[error("geometry {name}: hole {index} has a non-finite position")]
    NonFinite { name: String, index: usize },
    #[error("geometry {name}: holes {a} and {b} coincide")]
    Coincident { name: String, a: usize, b: usize },
    #[error("unknown template {0:?}: expected 2x1, 2x2 or a file")]
    UnknownName(String),
}

/// The three holes of one receptacle centred at `(cx, cy)`: neutral, hot, ground.
pub fn receptacle_holes(cx: f64, cy: f64) -> [TemplateHole; 3] {
    let half = SLOT_PITCH_MM / 2.0;
    [
        TemplateHole { kind: HoleKind::Power, position_mm: [cx - half, cy + SLOT_Y_MM] },
        TemplateHole { kind: HoleKind::Power, position_mm: [cx + half, cy + SLOT_Y_MM] },
        TemplateHole { kind: HoleKind::Ground, position_mm: [cx, cy + SLOT_Y_MM + GROUND_BELOW_SLOTS_MM] },
    ]
}

impl OutletGeometry {
    /// Receptacle centres of a built-in layout: `columns` duplexes side by side.
    pub fn duplex_centres(columns: usize) -> Vec<[f64; 2]> {
        let half_gang = GANG_PITCH_MM / 2.0;
        let xs: Vec<f64> = match columns {
            1 => vec![0.0],
            _ => (0..columns).map(|c| (c as f64 - (columns as f64 - 1.0) / 2.0) * 2.0 * half_gang).collect(),
        };
        let half_duplex = DUPLEX_PITCH_MM / 2.0;
        xs.iter().flat_map(|&x| [[x, -half_duplex], [x, half_duplex]]).collect()
    }

    /// Built-in `2x1`: one duplex, upper then lower receptacle, each neutral, hot, ground.
    pub fn us_2x1() -> Self {
        Self::from_centres(&Self::duplex_centres(1))
    }

    /// Built-in `2x2`: the left duplex's 6 holes, then the right duplex's 6.
    pub fn us_2x2() -> Self {
        Self::from_centres(&Self::duplex_centres(2))
    }

    fn from_centres(centres: &[[f64; 2]]) -> Self {
        Self {
            holes: centres.iter().flat_map(|c| receptacle_holes(c[0], c[1])).collect(),
            face_offset_mm: FACE_OFFSET_MM,
        }
    }

    /// A built-in geometry by name (`2x1`, `2x2`).
    pub fn builtin(name: &str) -> Result<Self, GeometryError> {
        match name {
            "2x1" => Ok(Self::us_2x1()),
            "2x2" => Ok(Self::us_2x2()),
            other => Err(GeometryError::UnknownName(other.to_string())),
        }
    }

    /// A built-in name, or else a `GEOMETRY.json` file.
    pub fn builtin_or_file(name_or_path: &str) -> Result<Self, GeometryError> {
        match Self::builtin(name_or_path) {
            Ok(g) => Ok(g),
            Err(_) => Self::read(Path::new(name_or_path)),
        }
    }

    /// Reads and checks a `GEOMETRY.json` file.
    pub fn read(path: &Path) -> Result<Self, GeometryError> {
        let name = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| GeometryError::Io { path: name.clone(), source })?;
        let geometry: Self =
            serde_json::from_str(&text).map_err(|source| GeometryError::Json { path: name.clone(), source })?;
        geometry.validate(&name)?;
        Ok(geometry)
    }

    /// Checks that the holes are finite, distinct and at least three.
    pub fn validate(&self, name: &str) -> Result<(), GeometryError> {
        if self.holes.len() < 3 {
            return Err(GeometryError::TooFewHoles { name: name.into(), count: self.holes.len() });
        }
        for (i, h) in self.holes.iter().enumerate() {
            if !h.position_mm.iter().all(|v| v.is_finite()) {
                return Err(GeometryError::NonFinite { name: name.into(), index: i });
            }
            for (j, g) in self.holes.iter().enumerate().skip(i + 1) {
                if (h.position() - g.position()).norm() < 1e-6 {
                    return Err(GeometryError::Coincident { name: name.into(), a: i, b: j });
                }
            }
        }
        if !self.face_offset_mm.is_finite() {
            return Err(GeometryError::NonFinite { name: name.into(), index: self.holes.len() });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_2x1_matches_the_contract_table() {
        let g = OutletGeometry::us_2x1();
        assert_eq!(g.holes.len(), 6);
        let p: Vec<[f64; 2]> = g.holes.iter().map(|h| h.position_mm).collect();
        // Upper receptacle at y = -19.05: slots at y = -24.05, ground 11.9 below.
        assert!((p[0][0] + 6.35).abs() < 1e-12 && (p[0][1] + 24.05).abs() < 1e-12);
        assert!((p[1][0] - 6.35).abs() < 1e-12);
        assert!((p[2][1] - (-24.05 + 11.9)).abs() < 1e-12 && p[2][0] == 0.0);
        assert!((p[3][1] - (19.05 - 5.0)).abs() < 1e-12);
        assert_eq!(g.holes[2].kind, HoleKind::Ground);
        assert_eq!(g.holes[0].kind, HoleKind::Power);
    }

    #[test]
    fn builtin_2x2_has_left_column_first() {
        let g = OutletGeometry::us_2x2();
        assert_eq!(g.holes.len(), 12);
        assert!(g.holes[..6].iter().all(|h| (h.position_mm[0] + 23.02).abs() < 6.4));
        assert!(g.holes[6..].iter().all(|h| (h.position_mm[0] - 23.02).abs() < 6.4));
        assert!((g.holes[8].position_mm[0] - 23.02).abs() < 1e-12);
    }

    #[test]
    fn geometry_json_round_trips_and_rejects_two_holes() {
        let g = OutletGeometry::us_2x1();
        let text = serde_json::to_string(&g).expect("serialise");
        let back: OutletGeometry = serde_json::from_str(&text).expect("parse");
        assert_eq!(back, g);
        let two = OutletGeometry { holes: g.holes[..2].to_vec(), face_offset_mm: 5.0 };
        assert!(matches!(two.validate("x"), Err(GeometryError::TooFewHoles { count: 2, .. })));
    }
}
