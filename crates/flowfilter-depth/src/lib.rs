//! The depth stage (stage 2 of the method): raw depth of a separate depth camera turned into a
//! dense, filtered depth map on the colour grid and an organised, coloured point cloud with
//! normals.
//!
//! - [`filter`]: the BigBIRD discontinuity filter on raw depth and the paper's Gaussian window
//!   filter (eqs. 9-11; mean/std or robust median/MAD estimates).
//! - [`register`]: depth-to-colour registration, by nearest-pixel splatting (the BigBIRD tools'
//!   algorithm) or by triangulating the depth grid (interpolates inside surfaces, never across
//!   discontinuities).
//! - [`interpolate`]: filling mask pixels without depth (nearest, separable linear).
//! - [`cloud`]: organised clouds, normals (organised and k-NN PCA), voxel downsampling and
//!   statistical outlier removal.
//! - [`bias_fit`]: the depth sensor's own error over its image ([`flowfilter_camera::DepthBias`])
//!   fitted from views of a static scene with known motions.
//! - [`ply`]: PLY import/export (ASCII and binary little-endian).
//! - [`DepthStage`]: the whole stage, configured by [`DepthConfig`] (serde/TOML).

#![warn(missing_docs)]

pub mod bias_fit;
pub mod cloud;
mod config;
mod error;
pub mod filter;
pub mod interpolate;
pub mod ply;
pub mod register;
mod stage;

pub use config::{
    BigBirdFilterConfig, CloudConfig, DepthConfig, GaussianFilterConfig, InterpolationConfig, InterpolationMethod,
    NormalMethod, RangeConfig, RegistrationConfig, RegistrationMethod, WindowEstimator,
};
pub use error::DepthError;
pub use stage::{DepthStage, ProcessedDepth};

/// The README's examples, compiled and run as doctests.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
