//! Flow Filter's photometric stage: what the two colour images say about a pose.
//!
//! - [`texture`]: a frame's texture, the grey image less its local mean ([`high_pass`]) on the
//!   object's rectangle, so that shading and exposure do not count, kept with the frame in a
//!   [`TextureCache`] for every pair that reads it;
//! - [`turns`]: the poses the clouds allow beside the registration's answer (turns about the
//!   model's axes), for motions the flow could not follow;
//! - [`gate`]: whether the judge is needed at all (the flow split, or a large motion);
//! - [`judge`]: those poses scored against the target image ([`photometric_score`], [`sweep`])
//!   and the ambiguity they leave;
//! - [`align()`]: direct RGB-D image alignment of the final pose, with a rolling shutter's row
//!   shear.
//!
//! Every function reads frames through [`ImageView`] (grey image, depth and mask on the colour
//! grid, the camera, and optionally the frame's texture cache), so the stage does not depend on
//! how a frame was prepared.

#![warn(missing_docs)]

pub mod align;
pub mod gate;
pub mod judge;
pub mod texture;
pub mod turns;
mod view;

pub use align::{AlignConfig, AlignReport, Aligner, Alignment, Scales, align, prepare_textures};
pub use gate::{JudgeGate, evidence_settled};
pub use judge::{Agreement, JudgeConfig, JudgeReport, Sweep, Textures, agreement, ambiguity, photometric_score, sweep};
pub use texture::{Texture, TextureCache, high_pass};
pub use turns::{TurnAxis, TurnCandidate, TurnHypotheses, TurnSweepConfig};
pub use view::ImageView;

/// The README's example, compiled and run as a doctest.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
