//! The object's first mask from a box around it: the box's pixels at the object's depth.

use flowfilter_geometry::{DepthMap, Mask};
use flowfilter_pipeline::{Pipeline, PipelineError, RgbdFrame};

/// How far from the depth of a box's central half an object pixel may lie (metres): what
/// `flowfilter track --box` and Python's `Tracker(..., bbox=...)` give [`object_in_box`].
pub const DEPTH_BAND_M: f64 = 0.05;

/// A box in pixels: left, top, width, height.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PixelBox {
    /// Left column.
    pub x: usize,
    /// Top row.
    pub y: usize,
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
}

impl PixelBox {
    /// Whether pixel `(x, y)` lies inside the box.
    pub fn contains(&self, x: usize, y: usize) -> bool {
        (self.x..self.x + self.width).contains(&x) && (self.y..self.y + self.height).contains(&y)
    }

    /// The box's pixels as the mask of a `w` x `h` image.
    pub fn mask(&self, (w, h): (usize, usize)) -> Mask {
        Mask::from_fn(w, h, |x, y| self.contains(x, y))
    }
}

/// The object inside `rect` of a frame's depth on the colour grid (a frame prepared without a
/// mask: `PreparedFrame::depth`, metres): the box's pixels whose depth
/// lies within `band_m` of the median depth of the box's central half (what a box drawn around
/// an object holds mostly there), so that the table and the wall behind it are left out. Pixels
/// without depth inside the box are kept (sparse sensors leave holes on the object too). `None`
/// when the box leaves the image or its central half has no depth.
///
/// ```
/// use flowfilter_geometry::DepthMap;
/// use flowfilter_track::boxed::{PixelBox, object_in_box};
/// // A box 10 cm in front of a wall 1 m away, a hole in its depth.
/// let depth = DepthMap::from_fn(64, 48, |x, y| match (x, y) {
///     (25, 15) => 0.0,
///     _ if (20..40).contains(&x) && (10..30).contains(&y) => 0.9,
///     _ => 1.0,
/// });
/// let mask = object_in_box(&depth, PixelBox { x: 16, y: 6, width: 28, height: 28 }, 0.05).expect("inside");
/// assert_eq!(mask.as_slice().iter().filter(|m| **m).count(), 20 * 20);
/// assert!(object_in_box(&depth, PixelBox { x: 50, y: 6, width: 28, height: 28 }, 0.05).is_none());
/// ```
pub fn object_in_box(depth_map: &DepthMap, rect: PixelBox, band_m: f64) -> Option<Mask> {
    let (w, h) = depth_map.dims();
    let (x1, y1) = (rect.x.checked_add(rect.width)?, rect.y.checked_add(rect.height)?);
    if rect.width == 0 || rect.height == 0 || x1 > w || y1 > h {
        return None;
    }
    let depth = |x: usize, y: usize| depth_map.get(x, y).copied().filter(|z| z.is_finite() && *z > 0.0);
    let (qx, qy) = (rect.width / 4, rect.height / 4);
    let mut central: Vec<f32> =
        (rect.y + qy..y1 - qy).flat_map(|y| (rect.x + qx..x1 - qx).filter_map(move |x| depth(x, y))).collect();
    if central.is_empty() {
        return None;
    }
    let mid = central.len() / 2;
    let (_, median, _) = central.select_nth_unstable_by(mid, f32::total_cmp);
    let median = f64::from(*median);
    Some(Mask::from_fn(w, h, |x, y| {
        rect.contains(x, y) && depth(x, y).is_none_or(|z| (f64::from(z) - median).abs() <= band_m)
    }))
}

/// Why a box gives no first mask.
#[derive(Debug, thiserror::Error)]
pub enum BoxError {
    /// The frame cannot be prepared.
    #[error("the first frame: {0}")]
    Frame(#[from] PipelineError),
    /// The box leaves the image, is empty, or has no depth in its central half.
    #[error(
        "the box ({x}, {y}, {width}, {height}) must lie inside the {image_width}x{image_height} image, have a \
         positive size and depth in its central half"
    )]
    Unusable {
        /// Left column.
        x: usize,
        /// Top row.
        y: usize,
        /// Width.
        width: usize,
        /// Height.
        height: usize,
        /// The image's width.
        image_width: usize,
        /// The image's height.
        image_height: usize,
    },
}

/// The object's mask in `first` from a box around it, as `flowfilter track --box` and Python's
/// `Tracker(..., bbox=...)` take it: the frame prepared without a mask, then [`object_in_box`]
/// on its depth with [`DEPTH_BAND_M`].
///
/// # Errors
/// [`BoxError::Frame`] when the frame cannot be prepared, [`BoxError::Unusable`] for a box
/// outside the image or without depth.
pub fn first_mask(pipeline: &Pipeline, first: &RgbdFrame, rect: PixelBox) -> Result<Mask, BoxError> {
    let prepared = pipeline.prepare(first)?;
    let (image_width, image_height) = prepared.depth.dims();
    object_in_box(&prepared.depth, rect, DEPTH_BAND_M).ok_or(BoxError::Unusable {
        x: rect.x,
        y: rect.y,
        width: rect.width,
        height: rect.height,
        image_width,
        image_height,
    })
}
