//! One RGB-D view: colour image, raw depth, object mask and the sensor that took them.

use flowfilter_bigbird::{BigBirdError, BigBirdObject, FrameId};
use flowfilter_camera::{CameraFile, CameraFileError, RgbdSensor};
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

/// Why images in memory do not make a frame; the caller names the file or array at fault.
#[derive(Debug, thiserror::Error)]
pub enum ImagesError {
    /// The depth image does not fit the colour image or the camera.
    #[error("{0}")]
    Depth(String),
    /// The mask does not fit the colour image, or is empty.
    #[error("{0}")]
    Mask(String),
    /// The camera file does not fit the images.
    #[error(transparent)]
    Camera(#[from] CameraFileError),
}

impl RgbdFrame {
    /// A frame from images in memory and the camera that took them (what [`crate::FrameFiles`]
    /// and the Python package build frames with).
    ///
    /// Depth registered to colour (a camera file without a `depth` camera) must have the colour
    /// image's size; depth of a separate depth camera has that camera's size. Without a mask the
    /// object is the whole image: the scene's cloud is every pixel with depth, and the depth
    /// stage fills the holes of sparse depth as it does inside an object's mask.
    ///
    /// # Errors
    /// [`ImagesError::Depth`] for depth of the wrong size, [`ImagesError::Mask`] for a mask of
    /// another size than the colour image or without any object pixel, [`ImagesError::Camera`]
    /// when the camera does not fit the images (no depth unit, another size). A camera with a
    /// `depth_bias` corrects the raw depth by it ([`flowfilter_camera::DepthBias::correct`]);
    /// depth of another size than the field's is an [`ImagesError::Depth`].
    ///
    /// ```
    /// use flowfilter_pipeline::{CameraFile, RawDepth, RgbdFrame};
    /// let camera = CameraFile::from_json_str(
    ///     r#"{"K": [[500, 0, 31.5], [0, 500, 23.5], [0, 0, 1]], "depth_unit_m": 0.001}"#,
    ///     "camera.json",
    /// )?;
    /// let color = image::RgbImage::new(64, 48);
    /// let depth = RawDepth::from_fn(64, 48, |x, _| if x < 32 { 800 } else { 0 });
    /// let frame = RgbdFrame::from_images("a", color, depth, None, &camera)?;
    /// // Without a mask the object is the whole image.
    /// assert!(frame.mask.as_slice().iter().all(|m| *m));
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn from_images(
        label: &str,
        color: RgbImage,
        mut depth: RawDepth,
        mask: Option<Mask>,
        camera: &CameraFile,
    ) -> Result<Self, ImagesError> {
        let (w, h) = color.dimensions();
        let (dw, dh) = (depth.width() as u32, depth.height() as u32);
        if camera.is_registered() && (dw, dh) != (w, h) {
            return Err(ImagesError::Depth(format!(
                "the depth image is {dw}x{dh} but the colour image is {w}x{h} (depth registered to colour must have \
                 its size; a separate depth camera needs 'depth' and 'color_from_depth' in {})",
                camera.origin
            )));
        }
        let sensor = camera.sensor(Some((w, h)), Some((dw, dh)))?;
        if let Some(bias) = &camera.depth_bias {
            bias.correct(&mut depth, sensor.metres_per_unit)
                .map_err(|e| ImagesError::Depth(format!("{e} (the depth_bias of {})", camera.origin)))?;
        }
        let mask = match mask {
            Some(m) => checked_mask(m, (w, h))?,
            // The whole image, not only its pixels with depth: the depth stage fills holes inside
            // the mask, and sparse registered depth (an SR300's: 25-35% of the pixels at 0.5 m)
            // left as it is gives the flow few pairs with depth at both ends.
            None => Mask::filled(w as usize, h as usize, true),
        };
        Ok(Self { label: label.into(), color, depth, mask, sensor })
    }
}

/// `mask`, when it has the colour image's size and at least one object pixel.
fn checked_mask(mask: Mask, (w, h): (u32, u32)) -> Result<Mask, ImagesError> {
    let (mw, mh) = mask.dims();
    if (mw, mh) != (w as usize, h as usize) {
        return Err(ImagesError::Mask(format!("the mask is {mw}x{mh} but the colour image is {w}x{h}")));
    }
    if !mask.as_slice().iter().any(|m| *m) {
        return Err(ImagesError::Mask("the mask is empty (no non-zero pixel)".into()));
    }
    Ok(mask)
}

/// Load a frame of a BigBIRD-layout object with its sensor calibration.
pub fn load_bigbird_frame(object: &BigBirdObject, id: FrameId) -> Result<RgbdFrame, BigBirdError> {
    let f = object.load_frame(id)?;
    let sensor = object.rgbd_sensor(&f)?;
    Ok(RgbdFrame { label: id.to_string(), color: f.color, depth: f.depth, mask: f.mask, sensor })
}
