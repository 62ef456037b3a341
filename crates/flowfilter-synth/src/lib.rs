//! Synthetic BigBIRD-layout turntable RGB-D captures with exact ground truth.
//!
//! - [`TexturedMesh`]: OBJ + MTL + texture loading (YCB scans) and [`procedural`] objects.
//! - [`Rig`]: a BigBIRD-like five-sensor rig (colour 1280x1024 with lens distortion, depth
//!   640x480 from a separate IR camera, projector baseline).
//! - [`render_frame`]: z-buffer rasterisation with perspective-correct texturing and Lambertian
//!   shading; depth from the IR camera; masks from the colour camera; optional structured-light
//!   noise ([`NoiseProfile`]).
//! - [`true_flow`]: exact optical flow between any two colour views, with occlusion.
//! - [`write_capture`]: a whole capture in the BigBIRD layout through `flowfilter-bigbird`.
//! - [`surface_from_rgbd`] and [`render_surface_view`]: a real RGB-D frame as a textured surface,
//!   seen again from another pose through the same sensor (twins of captured scenes).
//! - [`write_bop_scene`]: a scene in the BOP layout (depth registered to colour, visible masks,
//!   `scene_gt.json`), with the per-frame [`FrameEffects`] of real captures.

#![warn(missing_docs)]

mod bop;
mod capture;
mod captured;
mod effects;
mod error;
mod mesh;
mod network_mask;
mod noise;
mod procedural;
mod rig;
mod scene;
mod texture;
mod truth_flow;
mod twin;

pub use bop::{BopSceneOptions, BopView, bop_sensor, render_bop_view, write_bop_scene};
pub use capture::{
    CaptureOptions, RenderedFrame, contact_sheet, parse_angles, parse_fractional_angles, render_frame, write_capture,
};
pub use captured::{SurfaceOptions, render_surface_view, surface_from_rgbd};
pub use effects::{FrameDraw, FrameEffects};
pub use error::SynthError;
pub use mesh::TexturedMesh;
pub use network_mask::{MaskDefects, NetworkMaskModel, grown};
pub use noise::{CARMINE_TOML, ColorNoise, DepthNoise, DepthNoiseTruth, NoiseProfile};
pub use procedural::{PROCEDURAL_NAMES, procedural};
pub use rig::{Rig, RigSensor, look_at, world_from_table};
pub use scene::{Scene, TABLE_RADIUS};
pub use truth_flow::{TrueFlow, true_flow};
pub use twin::{Occluder, TwinOptions, TwinView, render_twin_view};

/// The README's examples, compiled and run as doctests.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
