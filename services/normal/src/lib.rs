//! The wall plane from a stereo point cloud.
//!
//! [`fit_wall_plane`] finds the dominant plane of a cloud in the camera frame
//! (REP 103 optical frame, metres): the wall around an outlet. The plate and the
//! receptacle faces standing a few millimetres proud of it are outliers, and so
//! are stereo mismatches; NaN points are ignored. The result carries the normal
//! (pointing into the wall), the distance, and an honest covariance that the pose
//! solver (`outlet-pose`, mode `plane`) uses as a prior. A cloud of more than
//! [`PlaneParams::max_points`] valid points is thinned first.
//!
//! [`measure_face`] then reads how far the receptacle face stands ahead of that
//! plane from the points around an outlet's holes, once a pose says where they are.
//!
//! ```
//! use outlet_normal::{PlaneParams, fit_wall_plane};
//! // A wall 40 cm ahead, seen on a 20x20 grid of rays.
//! let cloud: Vec<[f32; 3]> = (0..400)
//!     .map(|i| [((i % 20) as f32 - 10.0) * 0.01, ((i / 20) as f32 - 10.0) * 0.01, 0.4])
//!     .collect();
//! let wall = fit_wall_plane(&cloud, &PlaneParams::default()).unwrap();
//! assert!((wall.distance_m - 0.4).abs() < 1e-6 && wall.normal.z > 0.999);
//! ```

mod face;
mod fit;
mod moments;
mod params;
mod rng;

pub use face::{FaceOffset, FaceParams, measure_face};
pub use fit::{PlaneError, WallPlane, fit_wall_plane, tangent_basis};
pub use params::{PlaneParams, REFERENCE_BASELINE_M, REFERENCE_DISPARITY_SIGMA_PX, REFERENCE_FOCAL_PX};
