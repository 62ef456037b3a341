//! A frame's texture as the judge and the alignment compare it: the grey image less its local
//! mean ([`high_pass`]) on the object's rectangle, its gradients, and the object's pixels with
//! depth back-projected with their texture value.

use crate::view::ImageView;
use flowfilter_flow::lk::Gray;
use flowfilter_geometry::{Mask, Point3, mask_bbox};

/// The grey image less its local mean over a `(2r+1)^2` box (a high-pass): what stays is the
/// texture, not the shading or the contrast between large regions (a can's white lid against
/// its dark label), which do not turn with the surface.
pub fn high_pass(img: &Gray, r: usize) -> Gray {
    let (w, h) = img.dims();
    // Integral image, one row and column of zeros in front.
    let mut sum = vec![0.0f64; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = 0.0;
        for x in 0..w {
            row += f64::from(*img.at(x, y));
            sum[(y + 1) * (w + 1) + x + 1] = sum[y * (w + 1) + x + 1] + row;
        }
    }
    Gray::from_fn(w, h, |x, y| {
        let (x0, y0, x1, y1) = (x.saturating_sub(r), y.saturating_sub(r), (x + r + 1).min(w), (y + r + 1).min(h));
        let s = sum[y1 * (w + 1) + x1] - sum[y0 * (w + 1) + x1] - sum[y1 * (w + 1) + x0] + sum[y0 * (w + 1) + x0];
        let mean = s / ((x1 - x0) * (y1 - y0)) as f64;
        (f64::from(*img.at(x, y)) - mean) as f32
    })
}

/// A frame's texture ([`high_pass`]) on the rectangle where it is needed.
#[derive(Clone)]
pub struct Texture {
    x0: usize,
    y0: usize,
    grid: Gray,
}

impl Texture {
    /// The texture of `img` on the bounding box of the object's `mask` (its depth lies within
    /// it), exact there (the box is widened by `r` for the local means and clamped to the
    /// image). Empty with an empty mask.
    pub fn new(img: &Gray, mask: &Mask, r: usize) -> Self {
        let (w, h) = img.dims();
        let Some((bx0, by0, bx1, by1)) = mask_bbox(mask) else {
            return Self { x0: 0, y0: 0, grid: Gray::filled(0, 0, 0.0) };
        };
        let (x0, y0) = (bx0.saturating_sub(r), by0.saturating_sub(r));
        let (x1, y1) = ((bx1 + r + 1).min(w), (by1 + r + 1).min(h));
        Self { x0, y0, grid: high_pass(&img.crop(x0, y0, x1 - x0, y1 - y0), r) }
    }

    /// The texture smoothed by a box of half-width `r` (unchanged for 0).
    pub(crate) fn smoothed(self, r: usize) -> Self {
        if r == 0 {
            return self;
        }
        let detail = high_pass(&self.grid, r);
        let grid = Gray::from_fn(self.grid.dims().0, self.grid.dims().1, |x, y| self.grid.at(x, y) - detail.at(x, y));
        Self { grid, ..self }
    }

    /// The rectangle `((x0, y0), (x1, y1))` (exclusive ends) the texture covers.
    pub(crate) fn bounds(&self) -> ((usize, usize), (usize, usize)) {
        let (w, h) = self.grid.dims();
        ((self.x0, self.y0), (self.x0 + w, self.y0 + h))
    }

    /// The texture at pixel `(x, y)` of the full image; `None` outside the rectangle.
    pub(crate) fn at(&self, x: usize, y: usize) -> Option<f64> {
        let (gx, gy) = (x.checked_sub(self.x0)?, y.checked_sub(self.y0)?);
        self.grid.get(gx, gy).map(|v| f64::from(*v))
    }

    /// Bilinear texture at `(x, y)` of the full image; `None` outside the rectangle.
    pub(crate) fn bilinear(&self, x: f64, y: f64) -> Option<f64> {
        let (gx, gy) = (x - self.x0 as f64, y - self.y0 as f64);
        let (w, h) = self.grid.dims();
        let inside = w > 0 && h > 0 && gx >= 0.0 && gy >= 0.0 && gx <= (w - 1) as f64 && gy <= (h - 1) as f64;
        inside.then(|| f64::from(flowfilter_flow::lk::bilinear(&self.grid, gx as f32, gy as f32)))
    }
}

/// A [`Texture`] with its central differences, `(T(x+1) - T(x-1)) / 2` and alike in y (clamped at
/// the grid's edges, which [`GradientTexture::bilinear_gradient`] never weighs): what the
/// alignment reads in the frame it aligns into.
#[derive(Clone)]
pub(crate) struct GradientTexture {
    texture: Texture,
    gradients: (Gray, Gray),
}

impl GradientTexture {
    /// `texture` and its central differences.
    pub(crate) fn new(texture: Texture) -> Self {
        let (w, h) = texture.grid.dims();
        let gradients = if w == 0 || h == 0 {
            (Gray::filled(0, 0, 0.0), Gray::filled(0, 0, 0.0))
        } else {
            flowfilter_flow::lk::central_gradients(&texture.grid)
        };
        Self { texture, gradients }
    }

    /// Bilinear texture at `(x, y)` and its gradient: the bilinear texture's central differences
    /// one pixel either side, `(B(x+1, y) - B(x-1, y)) / 2` and alike in y, read as the bilinear
    /// interpolation of the grid's central differences (the same values: interpolation commutes
    /// with whole-pixel shifts) with the value's weights. `None` where any of the five samples
    /// would leave the rectangle.
    pub(crate) fn bilinear_gradient(&self, x: f64, y: f64) -> Option<(f64, f64, f64)> {
        let (gx, gy) = self.gradient_support(x, y)?;
        let [v, dx, dy] =
            flowfilter_flow::lk::bilinear_many([&self.texture.grid, &self.gradients.0, &self.gradients.1], gx, gy);
        Some((f64::from(v), f64::from(dx), f64::from(dy)))
    }

    /// The bilinear texture at `(x, y)` where [`GradientTexture::bilinear_gradient`] has a value (the
    /// same domain, without the gradient).
    pub(crate) fn bilinear_with_gradient_support(&self, x: f64, y: f64) -> Option<f64> {
        let (gx, gy) = self.gradient_support(x, y)?;
        Some(f64::from(flowfilter_flow::lk::bilinear(&self.texture.grid, gx, gy)))
    }

    /// `(x, y)` on the grid when it lies at least a pixel inside every edge.
    fn gradient_support(&self, x: f64, y: f64) -> Option<(f32, f32)> {
        let (gx, gy) = (x - self.texture.x0 as f64, y - self.texture.y0 as f64);
        let (w, h) = self.texture.grid.dims();
        let inside = w > 2 && h > 2 && gx >= 1.0 && gy >= 1.0 && gx <= (w - 2) as f64 && gy <= (h - 2) as f64;
        inside.then_some((gx as f32, gy as f32))
    }
}

/// An object pixel of a frame with depth: back-projected, with its value in a texture and its
/// image row.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ObjectSample {
    pub(crate) point: Point3,
    pub(crate) value: f64,
    pub(crate) row: usize,
}

/// The object pixels of `model` with depth (every `stride`-th in each direction, evenly thinned
/// to at most `max_pixels` on a large object), back-projected, with their value in `texture`.
pub(crate) fn object_samples(
    model: &ImageView<'_>,
    texture: &Texture,
    stride: usize,
    max_pixels: usize,
) -> Vec<ObjectSample> {
    let ((x0, y0), (x1, y1)) = texture.bounds();
    let mut samples = Vec::new();
    for y in (y0.next_multiple_of(stride)..y1).step_by(stride) {
        for x in (x0.next_multiple_of(stride)..x1).step_by(stride) {
            let z = f64::from(*model.depth.at(x, y));
            if !*model.mask.at(x, y) || z <= 0.0 {
                continue;
            }
            if let (Some(point), Some(value)) = (model.rays.backproject(x, y, z), texture.at(x, y)) {
                samples.push(ObjectSample { point, value, row: y });
            }
        }
    }
    let every = samples.len().div_ceil(max_pixels.max(1)).max(1);
    samples.into_iter().step_by(every).collect()
}
