//! The composed pipeline (stages 2-6 of the method) from two RGB-D frames to a relative pose.
//!
//! Stages meet through traits, so each can be swapped:
//! - [`FramePreparer`] (default [`DepthPreparer`]: the depth stage and a voxel grid) turns an
//!   [`RgbdFrame`] into a [`PreparedFrame`] (dense colour-grid depth, object cloud, grey image);
//! - [`CorrespondenceFinder`] (default [`FlowCorrespondenceFinder`]: any
//!   [`flowfilter_flow::FlowEstimator`] plus the consistency and depth checks) gives weighted 3-D
//!   pairs between the two prepared frames;
//! - any [`flowfilter_registration::Registrar`], chosen by name, aligns the clouds.
//!
//! After a registration that used flow, the photometric stage ([`flowfilter_photometric`]) runs:
//! its [`judge`] weighs turned poses against the target image, and the direct image alignment
//! ([`align()`]) refines the pose on the two images themselves.
//!
//! Frames come from the BigBIRD layout ([`load_bigbird_frame`]) or, for any camera whose depth is
//! registered to colour, from image files and a camera file ([`FrameFiles`]).
//!
//! [`Pipeline::estimate`] runs them and returns an [`Estimate`] with per-stage times and every
//! warning (a fallback taken, flow that failed). Configuration comes from TOML
//! ([`PipelineConfig::from_file`]; the commented files in the repository's `configs/`).

#![warn(missing_docs)]

pub mod batch;
pub mod bop;
mod config;
mod error;
mod estimate;
mod frame;
pub mod frame_checks;
pub mod geometry_first;
mod global_start;
mod pipeline;
mod propagate;
mod source;
mod stages;
mod trace;
mod warning;
mod wide;

pub use config::{
    CloudPrepConfig, FlowStageConfig, GeometryGuideConfig, PipelineConfig, ReportConfig, WideBaselineConfig,
};
pub use error::PipelineError;
pub use estimate::{
    CorrespondenceSummary, ESTIMATE_SCHEMA, Estimate, GroundTruth, REGISTER_SCHEMA, RegisterReport, RegisterTimes,
    RegistrationSummary, StageTimes, matrix_rows,
};
pub use flowfilter_photometric::{
    Agreement, AlignConfig, AlignReport, ImageView, JudgeConfig, JudgeGate, JudgeReport, align, judge,
};
pub use frame::{ImagesError, RgbdFrame, load_bigbird_frame};
pub use geometry_first::{GeometryFirstConfig, GeometryFirstReport};
pub use global_start::{GlobalStart, global_start};
pub use pipeline::Pipeline;
pub use source::{FrameFiles, MaskSource};
pub use stages::{
    CloudThinning, CorrespondenceFinder, DepthPreparer, FlowCorrespondenceFinder, FramePreparer, PreparedFrame,
    SCENE_RULE_VOXEL_M,
};
pub use trace::{PairTrace, TracedCandidate, TracedSet};
pub use warning::PipelineWarning;

// What the stage traits' signatures speak, so that a custom stage needs no other import.
pub use flowfilter_camera::{CameraFile, RayTable, RgbdSensor};
pub use flowfilter_depth::DepthConfig;
pub use flowfilter_flow::correspondences::{CorrespondenceParams, FlowPairs, FlowView};
pub use flowfilter_flow::lk::Gray;
pub use flowfilter_flow::{FlowError, FlowEstimator};
pub use flowfilter_geometry::{Correspondences, DepthMap, Mask, Point3, PointCloud, Pose, RawDepth};
pub use flowfilter_registration::{
    Registrar, Registration, RegistrationError, RegistrationProblem, RegistrationWarning, Uncertainty,
};

// The stage crates themselves, for everything else they offer.
pub use flowfilter_bigbird as bigbird;
pub use flowfilter_camera as camera;
pub use flowfilter_depth as depth;
pub use flowfilter_eval as eval;
pub use flowfilter_flow as flow;
pub use flowfilter_geometry as geometry;
pub use flowfilter_photometric as photometric;
pub use flowfilter_registration as registration;

/// The README's examples, compiled and run as doctests.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
