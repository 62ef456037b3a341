//! RGB-D frames from files, for any camera: depth registered to its colour image (RealSense
//! aligned depth, Azure Kinect's transformed depth, YCB-Video, BOP datasets), or depth from a
//! separate depth camera that the camera file describes (raw Kinect or Azure depth, BigBIRD).
//!
//! - Colour: any PNG or JPEG (converted to 8-bit RGB).
//! - Depth: a 16-bit single-channel PNG, metres = value x the camera file's depth unit; 0 = no
//!   reading. Other depth encodings are refused with a message.
//! - Mask, on the colour image's grid: none (the object is then the whole image: the whole
//!   visible scene, so the registration aligns the scene, not the object), a binary PNG (any
//!   non-zero value is the object), or a label image (8- or 16-bit PNG) and the object's id.
//! - Camera: a [`CameraFile`] (this project's JSON, a BOP `scene_camera.json` entry or
//!   `camera.json`, or Open3D's `PinholeCameraIntrinsic`); its sizes must be the images'. With a
//!   separate depth camera the depth image has that camera's size and the depth stage registers
//!   it to colour; otherwise it must have the colour image's size and is used where it lies.

use crate::error::{PipelineError, input_error};
use crate::frame::{ImagesError, RgbdFrame};
use flowfilter_camera::CameraFile;
use flowfilter_geometry::{Mask, RawDepth};
use image::DynamicImage;
use std::path::{Path, PathBuf};

/// Where a frame's object mask comes from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum MaskSource {
    /// No mask: the whole image (the scene).
    None,
    /// A binary image: non-zero pixels are the object.
    Binary(PathBuf),
    /// A label image and the object's label.
    Label {
        /// The label image.
        path: PathBuf,
        /// The object's label.
        id: u16,
    },
}

/// The files of one RGB-D frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameFiles {
    /// Colour image.
    pub color: PathBuf,
    /// 16-bit depth PNG.
    pub depth: PathBuf,
    /// Object mask.
    pub mask: MaskSource,
}

fn open_image(path: &Path) -> Result<DynamicImage, PipelineError> {
    image::open(path).map_err(|e| input_error(path, format!("cannot read the image: {e}")))
}

fn size_of(img: &DynamicImage) -> (u32, u32) {
    (img.width(), img.height())
}

impl FrameFiles {
    /// Load the frame; `label` names it in messages and in the estimate.
    ///
    /// # Errors
    /// [`PipelineError::Input`] naming the file: an image that cannot be read, depth that is not
    /// 16-bit single-channel, images of different sizes, a label that does not occur, an empty
    /// mask; [`PipelineError::Camera`] when the camera file does not fit the images (no depth
    /// unit, another size).
    pub fn load(&self, camera: &CameraFile, label: &str) -> Result<RgbdFrame, PipelineError> {
        let color_image = open_image(&self.color)?;
        let (w, h) = size_of(&color_image);
        let depth_image = open_image(&self.depth)?;
        let DynamicImage::ImageLuma16(depth_pixels) = depth_image else {
            return Err(input_error(
                &self.depth,
                format!(
                    "depth must be a 16-bit single-channel PNG (value x depth unit = metres), found {:?}",
                    depth_image.color()
                ),
            ));
        };
        let depth = RawDepth::from_fn(depth_pixels.width() as usize, depth_pixels.height() as usize, |x, y| {
            depth_pixels.get_pixel(x as u32, y as u32).0[0]
        });
        let mask = self.mask_image((w, h))?;
        RgbdFrame::from_images(label, color_image.to_rgb8(), depth, mask, camera).map_err(|e| match e {
            ImagesError::Depth(message) => input_error(&self.depth, message),
            ImagesError::Mask(message) => input_error(self.mask_path().unwrap_or(&self.color), message),
            ImagesError::Camera(e) => PipelineError::Camera(e),
        })
    }

    /// The mask file's path, when there is one.
    fn mask_path(&self) -> Option<&Path> {
        match &self.mask {
            MaskSource::None => None,
            MaskSource::Binary(path) | MaskSource::Label { path, .. } => Some(path),
        }
    }

    /// The object mask read from its file, on the colour grid of size `(w, h)`; `None` without
    /// a mask file.
    fn mask_image(&self, (w, h): (u32, u32)) -> Result<Option<Mask>, PipelineError> {
        let (path, id) = match &self.mask {
            MaskSource::None => return Ok(None),
            MaskSource::Binary(path) => (path, None),
            MaskSource::Label { path, id } => (path, Some(*id)),
        };
        let img = open_image(path)?;
        if size_of(&img) != (w, h) {
            let (mw, mh) = size_of(&img);
            return Err(input_error(
                path,
                format!("the mask is {mw}x{mh} but the colour image {} is {w}x{h}", self.color.display()),
            ));
        }
        let values = img.to_luma16();
        // An 8-bit image widened to 16 bits holds v * 257.
        let eight_bit = img.color().bits_per_pixel() / u16::from(img.color().channel_count()) <= 8;
        let mask = Mask::from_fn(w as usize, h as usize, |x, y| {
            let v = values.get_pixel(x as u32, y as u32).0[0];
            let v = if eight_bit { v / 257 } else { v };
            id.map_or(v > 0, |id| v == id)
        });
        if let (Some(id), false) = (id, mask.as_slice().iter().any(|m| *m)) {
            return Err(input_error(path, format!("label {id} does not occur in the label image")));
        }
        Ok(Some(mask))
    }
}
