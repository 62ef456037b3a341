//! One RGB-D view: colour image, raw depth, object mask and the sensor that took them.

use flowfilter_bigbird::{BigBirdError, BigBirdObject, FrameId};
use flowfilter_camera::RgbdSensor;
use flowfilter_geometry::{Mask, RawDepth};
use image::RgbImage;

/// One RGB-D view of the object.
#[derive(Debug, Clone)]
pub struct RgbdFrame {
    /// A name for messages (e.g. `NP3_0`).
    pub label: String,
    /// Colour image.
    pub color: RgbImage,
    /// Raw depth on the depth camera's grid (0 = no reading).
    pub depth: RawDepth,
    /// Object mask on the colour grid.
    pub mask: Mask,
    /// Calibration of the colour and depth cameras.
    pub sensor: RgbdSensor,
}

/// Load a frame of a BigBIRD-layout object with its sensor calibration.
pub fn load_bigbird_frame(object: &BigBirdObject, id: FrameId) -> Result<RgbdFrame, BigBirdError> {
    let f = object.load_frame(id)?;
    let sensor = object.rgbd_sensor(&f)?;
    Ok(RgbdFrame { label: id.to_string(), color: f.color, depth: f.depth, mask: f.mask, sensor })
}
