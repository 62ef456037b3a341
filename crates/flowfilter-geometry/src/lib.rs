//! Shared geometric vocabulary of the Flow Filter workspace.
//!
//! Every stage crate speaks in these types: [`Pose`] (a rigid transform in SE(3), an alias of
//! nalgebra's `Isometry3<f64>`), [`PointCloud`] (points with optional normals, colours and the
//! pixel each point came from), [`Correspondences`] (weighted 3-D point pairs), the validation of 4x4 matrices read from files
//! ([`rigid_from_matrix`]), twist exponential/logarithm for Gauss-Newton on SE(3)
//! ([`se3`]) and the weighted Kabsch/Umeyama solver ([`kabsch`]).

#![warn(missing_docs)]

pub mod atomic;
pub mod cloud;
pub mod correspondences;
pub mod fastmath;
pub mod grid;
pub mod kabsch;
pub mod knn;
pub mod neighbourhoods;
pub mod params;
pub mod radius_grid;
pub mod radix;
pub mod rigid;
pub mod se3;

pub use cloud::{CloudError, PointCloud};
pub use correspondences::{CorrespondenceError, Correspondences};
pub use grid::{DepthMap, Grid, GridSizeError, Mask, RawDepth, mask_bbox};
pub use kabsch::{KabschError, weighted_kabsch, weighted_kabsch_by};
pub use knn::{KnnIndex, Neighbour, spatial_order};
pub use neighbourhoods::Neighbourhoods;
pub use params::ParamError;
pub use radius_grid::RadiusGrid;
pub use radix::radix_order;
pub use rigid::{RigidTransformError, matrix_from_pose, nearest_rotation, rigid_from_matrix, rotation_angle_deg};

/// A rigid transform in SE(3), mapping points of one frame into another.
///
/// By convention in this project `T_ab` maps points expressed in frame `b` into frame `a`
/// (`p_a = T_ab * p_b`), and the relative object motion `T_12` maps model-frame points onto the
/// same object points in the target frame (`P_target = T_12 * P_model`).
pub type Pose = nalgebra::Isometry3<f64>;

/// The largest coordinate or translation (metres) any input may hold: 10 km. No scene an RGB-D
/// camera sees spans more, and beyond it squared distances in f64 lose the millimetres the
/// registrations work in (a larger value is a unit or file error, reported as such).
pub const MAX_COORDINATE_M: f64 = 1e4;

/// A 3-D point in metres.
pub type Point3 = nalgebra::Point3<f64>;

/// A 3-D vector.
pub type Vector3 = nalgebra::Vector3<f64>;

/// The README's examples, compiled and run as doctests.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
