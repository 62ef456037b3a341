//! The optical-flow stage (stage 3 of the method).
//!
//! - [`FlowField`]: dense flow `(u, v)` per pixel with a validity mask; convention
//!   `I_to(x + f(x)) = I_from(x)`.
//! - [`flo`]: Middlebury `.flo` read/write with typed errors.
//! - [`metrics`]: end-point error (all valid pixels, under a mask, at query points).
//! - [`viz`]: the Middlebury colour-wheel visualisation.
//! - [`FlowEstimator`]: the estimator seam ([`LucasKanade`], [`dis::Dis`]), with typed [`FlowError`]s.
//! - [`pyramid`]: image pyramids built once per frame and crop, shared by the tracking passes.
//! - [`features`]: wide-baseline matches of FAST corners by BRIEF descriptors, beyond the
//!   pyramid's reach.

#![warn(missing_docs)]

mod buffers;
pub mod coarse_search;
pub mod correspondences;
pub mod dis;
pub mod estimator;
pub mod features;
mod field;
pub mod flo;
pub mod lk;
pub mod metrics;
#[cfg(feature = "onnx")]
pub mod net;
#[cfg(feature = "onnx")]
pub mod onnx;
pub mod pyramid;
mod registry;
pub mod sintel;
pub mod viz;

pub use estimator::{FlowError, FlowEstimator, LucasKanade, WindowMatcher};
pub use field::FlowField;
pub use flo::FloError;
pub use registry::{
    DIS_PRESET_NAMES, FLOW_ESTIMATOR_NAMES, check_estimator_name, flow_estimator_by_name, flow_estimator_with_presets,
};

/// The README's examples, compiled and run as doctests.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
