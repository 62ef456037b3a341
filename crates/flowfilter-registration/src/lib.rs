//! Rigid registration backends behind one [`Registrar`] trait: ICP (point-to-point,
//! point-to-plane), rigid CPD and FilterReg (permutohedral-lattice E-step), each configured by a
//! serde struct and selectable by name with [`registrar_by_name`].

#![warn(missing_docs)]

mod aggregate;
mod anderson;
mod cpd;
mod error;
mod evaluate;
mod filterreg;
mod flowfilter;
pub mod global;
mod gmm;
mod icp;
pub mod lattice;
pub mod plausibility;
mod problem;
mod registry;
mod reprojection;
#[cfg(test)]
mod test_clouds;
mod warning;

pub use cpd::{Cpd, CpdConfig, CpdEStep, MIN_LATTICE_NEIGHBOURS};
pub use error::RegistrationError;
pub use evaluate::{RobustKernel, correspondence_set, evaluate, visible_residual};
pub use filterreg::{
    DEFAULT_MAX_E_STEP_SWITCHES, FilterReg, FilterRegConfig, FilterRegEStep, FilterRegVariant, SigmaSchedule,
};
pub use flowfilter::{FlowFilter, FlowFilterConfig, FlowFilterMode, SCENE_MAX_E_STEP_SWITCHES, ransac_kabsch};
pub use gmm::mean_pair_distance2;
pub use icp::{Icp, IcpConfig, IcpVariant};
pub use plausibility::{Plausibility, assess, assess_with};
pub use problem::{
    Correspondences, IterationRecord, Registrar, Registration, RegistrationProblem, Uncertainty, validate_cloud,
    validate_problem,
};
pub use registry::{METHOD_NAMES, RegistrationConfig, registrar_by_name};
pub use reprojection::{Refinement, Shutter, refine_by_reprojection, refine_by_reprojection_with};
pub use warning::RegistrationWarning;

// The geometric types of this crate's signatures.
pub use flowfilter_geometry::{Point3, PointCloud, Pose, Vector3};

/// The README's examples, compiled and run as doctests.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
