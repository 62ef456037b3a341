//! What the photometric stage reads of a frame.

use flowfilter_camera::{CameraModel, RayTable};
use flowfilter_flow::lk::Gray;
use flowfilter_geometry::{DepthMap, Mask};

/// One frame as the judge and the alignment read it, borrowed from whoever prepared it (the
/// pipeline's `PreparedFrame::image_view`): the grey image, the depth and the object mask on
/// the colour camera's grid, and that camera.
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
}
