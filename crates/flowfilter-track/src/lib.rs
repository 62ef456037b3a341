//! Tracking one object through an RGB-D stream from one mask.
//!
//! - [`Tracker`]: frames pushed one at a time ([`Tracker::update`]), each prepared once and
//!   estimated by Flow Filter's [`flowfilter_pipeline::Pipeline`] against the current keyframe
//!   (not only the previous frame, so that drift stays bounded), the object's mask carried
//!   forward by the pose and refined on the new frame's depth ([`carry::carry_mask`]), a state
//!   per frame ([`TrackState`]: tracking, uncertain, lost, recovered) with its reason, and
//!   recovery after a loss by matching against every keyframe. Without a first mask the whole
//!   scene is tracked (camera odometry).
//! - [`FrameFolder`]: the frames of a folder (`frame-NNNNNN.color.png` + `.depth.png`,
//!   YCB-Video's `NNNNNN-color.png` + `-depth.png`).
//! - [`depth_calibration`]: the depth sensor's own error ([`flowfilter_pipeline::camera::DepthBias`])
//!   fitted from a stream of a static scene, without truth.
//! - [`tum`]: the TUM trajectory format and the true motion from a TUM file or `poses.json`.
//!
//! The `flowfilter track` command runs it on a folder (docs/tracking.md).

#![warn(missing_docs)]

pub mod boxed;
pub mod carry;
pub mod depth_calibration;
mod folder;
mod region;
mod reveal;
mod tracker;
pub mod tum;

pub use folder::{FolderError, FrameEntry, FrameFolder};
pub use tracker::{
    ReadyFrame, SettingsError, StreamPreparer, TracedPair, TrackError, TrackState, TrackedFrame, Tracker,
    TrackerConfig, chained_bound,
};
