//! Calibrated camera models.
//!
//! - [`Intrinsics`]: pinhole focal lengths and principal point (pixels, OpenCV convention: pixel
//!   centres at integer coordinates, `u = fx * x + cx`).
//! - [`Distortion`]: Brown-Conrady radial-tangential distortion `(k1, k2, p1, p2, k3)`, the model and
//!   coefficient order of OpenCV and of BigBIRD's `calibration.h5`, with exact forward distortion
//!   and iterative (Newton) undistortion.
//! - [`CameraModel`]: intrinsics + distortion + image size; `project` and `backproject`.
//! - [`raster`]: a z-buffer triangle rasteriser over projected vertices (perspective-correct
//!   barycentrics), shared by the renderer and by depth registration.
//! - [`RgbdSensor`]: a depth camera and a colour camera calibrated against each other, with the
//!   raw-depth scale; maps depth pixels into the colour image.
//! - [`DepthBias`]: a depth sensor's own error over its image, fitted from its stream.
//! - [`CameraFile`]: a camera from a JSON file (this project's layout, a BOP `scene_camera.json`
//!   entry or `camera.json`, Open3D's `PinholeCameraIntrinsic`).

#![warn(missing_docs)]

mod camera_file;
mod depth_bias;
mod distortion;
mod error;
mod intrinsics;
mod model;
pub mod raster;
mod rays;
mod sensor;

pub use camera_file::{CameraFile, CameraFileError, CameraFileLayout};
pub use depth_bias::{DepthBias, DepthBiasError, MAX_BIAS_CELLS, MAX_BIAS_M};
pub use distortion::Distortion;
pub use error::CameraError;
pub use intrinsics::Intrinsics;
pub use model::{CameraModel, ImageSize};
pub use rays::RayTable;
pub use sensor::{MAX_METRES_PER_UNIT, MIN_METRES_PER_UNIT, RgbdSensor};

/// A 2-D pixel position `(u, v)` in pixels.
pub type Pixel = nalgebra::Point2<f64>;

/// The README's examples, compiled and run as doctests.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
