//! An RGB-D sensor: a depth camera and a colour camera calibrated against each other.

use crate::{CameraError, CameraModel, Pixel};
use flowfilter_geometry::{Point3, Pose};
use serde::{Deserialize, Serialize};

/// The smallest depth unit accepted: a micrometre per raw unit.
pub const MIN_METRES_PER_UNIT: f64 = 1e-6;

/// The largest depth unit accepted: a metre per raw unit (16-bit depth in metres would not
/// resolve an object).
pub const MAX_METRES_PER_UNIT: f64 = 1.0;

/// A depth (IR) camera and a colour camera of one RGB-D sensor, with their relative pose and
/// the conversion from raw depth values to metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RgbdSensor {
    /// The depth camera.
    pub depth: CameraModel,
    /// The colour camera.
    pub color: CameraModel,
    /// Maps points in the depth camera frame into the colour camera frame.
    pub color_from_depth: Pose,
    /// Metres per raw depth unit (BigBIRD: `ir_depth_scale * 1e-4`).
    pub metres_per_unit: f64,
}

impl RgbdSensor {
    /// A validated sensor (the depth unit must be in [`MIN_METRES_PER_UNIT`,
    /// `MAX_METRES_PER_UNIT`]).
    ///
    /// # Errors
    /// [`CameraError::BadDepthScale`] otherwise.
    pub fn new(
        depth: CameraModel,
        color: CameraModel,
        color_from_depth: Pose,
        metres_per_unit: f64,
    ) -> Result<Self, CameraError> {
        if !(MIN_METRES_PER_UNIT..=MAX_METRES_PER_UNIT).contains(&metres_per_unit) {
            return Err(CameraError::BadDepthScale { value: metres_per_unit });
        }
        Ok(Self { depth, color, color_from_depth, metres_per_unit })
    }

    /// The sensor of depth registered to colour (RealSense aligned depth, YCB-Video, BOP): one
    /// camera model for both images and identity extrinsics.
    ///
    /// # Errors
    /// [`CameraError::BadDepthScale`] unless `metres_per_unit` is positive and finite.
    pub fn registered(camera: CameraModel, metres_per_unit: f64) -> Result<Self, CameraError> {
        Self::new(camera, camera, Pose::identity(), metres_per_unit)
    }

    /// Whether depth is already registered to colour: the same camera and identity extrinsics
    /// (the depth stage then does not re-project it).
    pub fn is_registered(&self) -> bool {
        self.depth == self.color && self.color_from_depth == Pose::identity()
    }

    /// Metric depth of a raw depth value (`None` for 0, "no reading").
    pub fn metric_depth(&self, raw: u16) -> Option<f64> {
        (raw != 0).then_some(raw as f64 * self.metres_per_unit)
    }

    /// The 3-D point, in the colour camera frame, of depth pixel `(u, v)` with metric depth `z`.
    pub fn depth_pixel_to_color_frame(&self, pixel: &Pixel, z: f64) -> Option<Point3> {
        self.depth.backproject(pixel, z).map(|p| self.color_from_depth * p)
    }

    /// Where depth pixel `(u, v)` with metric depth `z` lands in the colour image, and its
    /// depth in the colour camera frame.
    pub fn depth_pixel_to_color_pixel(&self, pixel: &Pixel, z: f64) -> Option<(Pixel, f64)> {
        let p = self.depth_pixel_to_color_frame(pixel, z)?;
        self.color.project(&p).map(|q| (q, p.z))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Distortion, ImageSize, Intrinsics};
    use nalgebra::Vector3;

    #[test]
    fn depth_pixel_maps_through_extrinsics() {
        let depth = CameraModel::new(
            Intrinsics::new(570.0, 570.0, 319.5, 239.5).unwrap(),
            Distortion::NONE,
            ImageSize::new(640, 480).unwrap(),
        );
        let color = CameraModel::new(
            Intrinsics::new(1080.0, 1080.0, 639.5, 511.5).unwrap(),
            Distortion::NONE,
            ImageSize::new(1280, 1024).unwrap(),
        );
        let sensor = RgbdSensor::new(depth, color, Pose::translation(-0.025, 0.0, 0.0), 1e-4).unwrap();
        assert_eq!(sensor.metric_depth(0), None);
        assert!((sensor.metric_depth(10000).unwrap() - 1.0).abs() < 1e-12);
        // The depth principal point at 1 m lands 2.5 cm to the left in the colour camera.
        let (q, z) = sensor.depth_pixel_to_color_pixel(&Pixel::new(319.5, 239.5), 1.0).unwrap();
        assert!((z - 1.0).abs() < 1e-12);
        assert!((q - Pixel::new(639.5 - 0.025 * 1080.0, 511.5)).norm() < 1e-9);
        let p = sensor.depth_pixel_to_color_frame(&Pixel::new(319.5, 239.5), 1.0).unwrap();
        assert!((p.coords - Vector3::new(-0.025, 0.0, 1.0)).norm() < 1e-12);
        assert!(RgbdSensor::new(depth, color, Pose::identity(), f64::NAN).is_err());
        assert!(!sensor.is_registered());
        let registered = RgbdSensor::registered(color, 1e-3).unwrap();
        assert!(registered.is_registered());
        assert!(RgbdSensor::registered(color, 0.0).is_err());
    }
}
