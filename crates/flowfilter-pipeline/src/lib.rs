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
//! [`Pipeline::estimate`] runs them and returns an [`Estimate`] with per-stage times and every
//! warning (a fallback taken, flow that failed). Configuration comes from TOML
//! ([`PipelineConfig::from_file`]; the commented files in the repository's `configs/`).

mod config;
mod error;
mod estimate;
mod frame;
mod pipeline;
mod stages;

pub use config::{CloudPrepConfig, FlowStageConfig, PipelineConfig};
pub use error::PipelineError;
pub use estimate::{CorrespondenceSummary, ESTIMATE_SCHEMA, Estimate, GroundTruth, RegistrationSummary, StageTimes};
pub use frame::{RgbdFrame, load_bigbird_frame};
pub use pipeline::Pipeline;
pub use stages::{
    CorrespondenceFinder, DepthPreparer, FlowCorrespondenceFinder, FramePreparer, PreparedFrame, flow_estimator_by_name,
};
