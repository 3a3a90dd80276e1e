//! The ground check: an outlet whose power holes map onto themselves under a
//! half turn reads the same on them either way up; its ground holes, darker
//! than where the half turn would put them, tell the reading.

use super::{Detector, Lens, apply, centroid, local_jacobian};
use image::GrayImage;
use nalgebra::{Matrix3, Point2};
use outlet_protocol::HoleKind;

/// The template's ground holes and where a half turn of its power holes puts
/// them, for the ground check; `None` where that check has nothing to say (no
/// ground or no power holes, power holes not symmetric under the half turn, or
/// turned grounds on holes of the template).
#[derive(Debug, Clone)]
pub(super) struct GroundPlaces {
    /// The power holes' centroid (template mm).
    centre: Point2<f64>,
    ground: Vec<Point2<f64>>,
    turned: Vec<Point2<f64>>,
}

impl GroundPlaces {
    /// Found once per template (it depends on nothing else).
    pub(super) fn of(geometry: &outlet_protocol::OutletGeometry) -> Option<GroundPlaces> {
        let holes = &geometry.holes;
        let power: Vec<Point2<f64>> =
            holes.iter().filter(|t| t.kind == HoleKind::Power).map(|t| t.position()).collect();
        let ground: Vec<Point2<f64>> =
            holes.iter().filter(|t| t.kind == HoleKind::Ground).map(|t| t.position()).collect();
        if power.is_empty() || ground.is_empty() {
            return None;
        }
        let c = centroid(&power);
        let turn = |p: &Point2<f64>| Point2::from(2.0 * c.coords - p.coords);
        let symmetric = power.iter().all(|p| power.iter().any(|q| (turn(p) - q).norm() < 1.0));
        let turned: Vec<Point2<f64>> = ground.iter().map(turn).collect();
        // Where the turned grounds fall on holes of the template, nothing tells them apart.
        let on_holes = turned.iter().any(|g| holes.iter().any(|t| (t.position() - g).norm() < 2.0));
        (symmetric && !on_holes).then_some(GroundPlaces { centre: c, ground, turned })
    }
}

impl Detector {
    /// An outlet whose power holes map onto themselves under a half turn (every
    /// US duplex) matches its own half-turned self on the power holes alone: the
    /// ground holes then land on the plate, where nothing is (a false alarm that
    /// sends the arm beside the holes). The ground holes decide: where this
    /// detection puts them must be darker than where the half-turned one would.
    pub(super) fn ground_evidence(&self, grey: &GrayImage, lens: &Lens, h: &Matrix3<f64>) -> GroundEvidence {
        let Some(GroundPlaces { centre: c, ground, turned }) = &self.ground_places else {
            return GroundEvidence::Silent;
        };
        let Some(jacobian) = local_jacobian(h, lens, c) else { return GroundEvidence::Against };
        // Half the ground hole's width (4.8 mm) in pixels.
        let radius = (2.4 * jacobian.singular_values().min()).max(1.5);
        let darkness = |points: &[Point2<f64>]| -> Option<f64> {
            let mut sum = 0.0;
            for t in points {
                sum += dark_quartile(grey, lens.distort(apply(h, t)?), radius)?;
            }
            Some(sum / points.len() as f64)
        };
        match (darkness(ground), darkness(turned)) {
            (Some(here), Some(there)) => {
                // How much darker, relative to the half-turned places.
                let contrast = (there - here) / (there + 1.0);
                tracing::debug!(here, there, contrast, "ground holes against their half-turned places");
                if contrast.is_nan() || contrast <= self.params.ground_contrast {
                    GroundEvidence::Against
                } else if contrast >= self.params.ground_decides {
                    GroundEvidence::Decides
                } else {
                    GroundEvidence::Weak
                }
            }
            // A half-turned ground outside the image says nothing against this one.
            (Some(_), None) => GroundEvidence::Silent,
            _ => GroundEvidence::Against,
        }
    }
}

/// What the ground holes say about a reading against its half turn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum GroundEvidence {
    /// Nothing: no ground holes, an outlet not symmetric under a half turn, or
    /// the half-turned places outside the image.
    Silent,
    /// Darker than the half-turned places, but not by [`super::DetectorParams::ground_decides`].
    Weak,
    /// Clearly darker: the half turn is decided.
    Decides,
    /// Not darker: the reading is refused.
    Against,
}

/// The mean of the darkest quarter of the grey values within `radius` pixels of
/// `centre`; `None` when the disc leaves the image.
fn dark_quartile(grey: &GrayImage, centre: Point2<f64>, radius: f64) -> Option<f64> {
    let (w, h) = grey.dimensions();
    let r = radius.ceil();
    // In floating point first: a centre far outside (or not finite) fails here.
    let inside = |c: f64, size: u32| c.round() - r >= 0.0 && c.round() + r < size as f64;
    if !(radius.is_finite() && inside(centre.x, w) && inside(centre.y, h)) {
        return None;
    }
    let (r, cx, cy) = (r as i64, centre.x.round() as i64, centre.y.round() as i64);
    // A histogram, not a sorted copy: the darkest quarter's mean all the same.
    let mut histogram = [0u32; 256];
    let mut count = 0usize;
    for y in cy - r..=cy + r {
        for x in cx - r..=cx + r {
            let (dx, dy) = (x as f64 - centre.x, y as f64 - centre.y);
            if dx * dx + dy * dy <= radius * radius {
                histogram[grey.get_pixel(x as u32, y as u32)[0] as usize] += 1;
                count += 1;
            }
        }
    }
    if count == 0 {
        return None;
    }
    let quarter = (count / 4).max(1);
    let (mut left, mut sum) = (quarter, 0.0);
    for (value, &n) in histogram.iter().enumerate() {
        let take = left.min(n as usize);
        sum += (value * take) as f64;
        left -= take;
        if left == 0 {
            break;
        }
    }
    Some(sum / quarter as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_dark_quartile_sees_a_hole_and_refuses_discs_it_cannot_read() {
        // A grey face at 200 with a dark hole of radius 3 at (20, 20).
        let image = GrayImage::from_fn(40, 40, |x, y| {
            let (dx, dy) = (x as f64 - 20.0, y as f64 - 20.0);
            image::Luma([if dx * dx + dy * dy <= 9.0 { 20 } else { 200 }])
        });
        let on_hole = dark_quartile(&image, Point2::new(20.0, 20.0), 5.0).expect("inside");
        let on_face = dark_quartile(&image, Point2::new(8.0, 30.0), 5.0).expect("inside");
        assert_eq!((on_hole, on_face), (20.0, 200.0));
        for centre in [(2.0, 20.0), (20.0, 38.0), (f64::NAN, 20.0), (1e300, 20.0), (-1e300, f64::INFINITY)] {
            assert_eq!(dark_quartile(&image, Point2::new(centre.0, centre.1), 5.0), None, "{centre:?}");
        }
        assert_eq!(dark_quartile(&image, Point2::new(20.0, 20.0), f64::INFINITY), None);
    }
}
