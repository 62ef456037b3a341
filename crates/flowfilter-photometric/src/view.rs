//! What the photometric stage reads of a frame.

use crate::texture::TextureCache;
use flowfilter_camera::{CameraModel, RayTable};
use flowfilter_flow::lk::Gray;
use flowfilter_geometry::{DepthMap, Mask};

/// One frame as the judge and the alignment read it, borrowed from whoever prepared it (the
/// pipeline's `PreparedFrame::image_view`): the grey image, the depth and the object mask on
/// the colour camera's grid, that camera, and the frame's cache of textures.
#[derive(Debug, Clone, Copy)]
pub struct ImageView<'a> {
    /// Grey image in [0, 1].
    pub gray: &'a Gray,
    /// Depth on the colour grid, metres (0 = none).
    pub depth: &'a DepthMap,
    /// The object's pixels.
    pub mask: &'a Mask,
    /// The colour camera's rays (back-projection).
    pub rays: &'a RayTable,
    /// The colour camera (projection).
    pub camera: &'a CameraModel,
    /// The frame's textures, computed once for every pair that reads them (`None`: each
    /// judgement or alignment computes its own).
    pub textures: Option<&'a TextureCache>,
}

impl<'a> ImageView<'a> {
    /// The view reading `cache` when it has no cache of its own (else as it is).
    pub fn or_cache(&self, cache: &'a TextureCache) -> ImageView<'a> {
        ImageView { textures: Some(self.textures.unwrap_or(cache)), ..*self }
    }
}
