//! Rerun recordings of what Flow Filter did on a pair of RGB-D frames: both frames, their depth
//! and masks, the clouds before and after, the flow pairs coloured by whether they agree with the
//! estimate, the judge's candidates and scores, the pose with its bounds and its error when the
//! truth is known, and the stage times.
//!
//! - [`PairScene`] computes what is shown from the pipeline's outputs
//!   ([`flowfilter_pipeline::Pipeline::estimate_traced`]); it needs no Rerun.
//! - [`Recorder`] (feature `rerun`; without it [`Recorder::create`] says how to get it) writes scenes to a `.rrd` file for the Rerun viewer
//!   (`rerun pair.rrd`), at the entity paths and on the timeline of [`paths`].
//!
//! The `flowfilter` CLI records with `estimate --rerun FILE.rrd`, the benchmarks record their
//! failing pairs with `--rerun FILE.rrd` (both when built with `--features rerun`).

#![warn(missing_docs)]

mod error;
pub mod paths;
#[cfg(feature = "rerun")]
mod recorder;
#[cfg(not(feature = "rerun"))]
#[path = "recorder_disabled.rs"]
mod recorder;
mod scene;

pub use error::RecordError;
pub use recorder::Recorder;
pub use scene::{FlowPair, FrameInput, FrameLayer, INLIER_COLOR, OUTLIER_COLOR, PairScene, UNUSED_COLOR};

/// Whether this build can write recordings (the `rerun` feature).
pub const CAN_RECORD: bool = cfg!(feature = "rerun");

/// The README's example, compiled and run as a doctest.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
