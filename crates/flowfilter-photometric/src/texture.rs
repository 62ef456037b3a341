//! A frame's texture as the judge and the alignment compare it: the grey image less its local
//! mean ([`high_pass`]) on the object's rectangle, its gradients, and the object's pixels with
//! depth back-projected with their texture value.

use crate::view::ImageView;
use flowfilter_flow::lk::Gray;
use flowfilter_geometry::{Mask, Point3, mask_bbox};
use std::sync::{Arc, Mutex};

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

/// The central differences of a texture's grid (empty for an empty grid).
fn gradients_of(texture: &Texture) -> (Gray, Gray) {
    let (w, h) = texture.grid.dims();
    if w == 0 || h == 0 {
        (Gray::filled(0, 0, 0.0), Gray::filled(0, 0, 0.0))
    } else {
        flowfilter_flow::lk::central_gradients(&texture.grid)
    }
}

/// A frame's textures, each computed once and kept with the frame: the pipeline's prepared
/// frame holds one, so that the geometry-first try, the judge, its candidates' alignment and the
/// final alignment of a pair (and every pair of a stream that shares the frame) read one
/// [`high_pass`] texture per radius and smoothing, and one set of its gradients, instead of
/// building them again (a refused whole 640x480 frame: 16 textures of each frame before, 2 now).
/// Keyed by the texture's radius and smoothing; the mask's box is the frame's own, so a frame
/// with another mask needs another cache.
#[derive(Default)]
pub struct TextureCache {
    levels: Mutex<Vec<CachedLevel>>,
}

impl std::fmt::Debug for TextureCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let keys: Vec<(usize, usize)> = self.levels().iter().map(|l| (l.radius, l.smoothing)).collect();
        f.debug_struct("TextureCache").field("radius_and_smoothing", &keys).finish()
    }
}

/// One texture of a [`TextureCache`] and, once asked for, its gradients.
struct CachedLevel {
    radius: usize,
    smoothing: usize,
    texture: Arc<Texture>,
    gradients: Option<Arc<(Gray, Gray)>>,
}

/// A cached level's texture and, once computed, its gradients.
type Level = (Arc<Texture>, Option<Arc<(Gray, Gray)>>);

impl TextureCache {
    /// An empty cache.
    pub fn new() -> Self {
        Self::default()
    }

    fn levels(&self) -> std::sync::MutexGuard<'_, Vec<CachedLevel>> {
        self.levels.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// The level of `radius` and `smoothing`, when cached.
    fn lookup(&self, radius: usize, smoothing: usize) -> Option<Level> {
        let levels = self.levels();
        let l = levels.iter().find(|l| l.radius == radius && l.smoothing == smoothing)?;
        Some((l.texture.clone(), l.gradients.clone()))
    }

    /// Store a computed level (what another thread stored first is kept) and return the level
    /// as stored. Values are computed outside the lock: two threads asking at once compute the
    /// same values.
    fn store(&self, radius: usize, smoothing: usize, (texture, gradients): Level) -> Level {
        let mut levels = self.levels();
        match levels.iter_mut().find(|l| l.radius == radius && l.smoothing == smoothing) {
            Some(l) => {
                if l.gradients.is_none() {
                    l.gradients = gradients;
                }
                (l.texture.clone(), l.gradients.clone())
            }
            None => {
                levels.push(CachedLevel { radius, smoothing, texture: texture.clone(), gradients: gradients.clone() });
                (texture, gradients)
            }
        }
    }

    /// The texture of `frame` with `radius`, smoothed by `smoothing`.
    fn texture(&self, frame: &ImageView<'_>, radius: usize, smoothing: usize) -> Arc<Texture> {
        if let Some((texture, _)) = self.lookup(radius, smoothing) {
            return texture;
        }
        let texture = Arc::new(match smoothing {
            0 => Texture::new(frame.gray, frame.mask, radius),
            s => (*self.texture(frame, radius, 0)).clone().smoothed(s),
        });
        self.store(radius, smoothing, (texture, None)).0
    }

    /// [`TextureCache::texture`] with its gradients.
    fn gradient_texture(&self, frame: &ImageView<'_>, radius: usize, smoothing: usize) -> GradientTexture {
        let (texture, gradients) = match self.lookup(radius, smoothing) {
            Some((texture, Some(gradients))) => (texture, gradients),
            _ => {
                let texture = self.texture(frame, radius, smoothing);
                let gradients = Arc::new(gradients_of(&texture));
                let (texture, stored) = self.store(radius, smoothing, (texture, Some(gradients.clone())));
                (texture, stored.unwrap_or(gradients))
            }
        };
        GradientTexture { texture, gradients }
    }
}

impl ImageView<'_> {
    /// `read` on the frame's [`TextureCache`], or on one made for this call.
    fn with_cache<T>(&self, read: impl FnOnce(&TextureCache) -> T) -> T {
        match self.textures {
            Some(cache) => read(cache),
            None => read(&TextureCache::new()),
        }
    }

    /// The frame's texture with `radius` ([`Texture::new`] on its mask's box), smoothed by a box
    /// of half-width `smoothing` (0: as it is): from the frame's [`TextureCache`] when it has
    /// one.
    pub(crate) fn texture(&self, radius: usize, smoothing: usize) -> Arc<Texture> {
        self.with_cache(|cache| cache.texture(self, radius, smoothing))
    }

    /// [`ImageView::texture`] with its gradients.
    pub(crate) fn gradient_texture(&self, radius: usize, smoothing: usize) -> GradientTexture {
        self.with_cache(|cache| cache.gradient_texture(self, radius, smoothing))
    }
}

/// A [`Texture`] with its central differences, `(T(x+1) - T(x-1)) / 2` and alike in y (clamped at
/// the grid's edges, which [`GradientTexture::bilinear_gradient`] never weighs): what the
/// alignment reads in the frame it aligns into.
#[derive(Clone)]
pub(crate) struct GradientTexture {
    texture: Arc<Texture>,
    gradients: Arc<(Gray, Gray)>,
}

impl GradientTexture {
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
/// image column and row.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ObjectSample {
    pub(crate) point: Point3,
    pub(crate) value: f64,
    pub(crate) column: usize,
    pub(crate) row: usize,
}

/// The same pixels with their values in another texture of the frame (the same box: another
/// smoothing of it).
pub(crate) fn revalued(samples: &[ObjectSample], texture: &Texture) -> Vec<ObjectSample> {
    samples.iter().filter_map(|s| Some(ObjectSample { value: texture.at(s.column, s.row)?, ..*s })).collect()
}

/// The object pixels of `model` with depth (every `stride`-th in each direction, evenly thinned
/// to at most `max_pixels` on a large object), back-projected, with their value in `texture`.
///
/// Counted first, then only the kept pixels are back-projected and stored: on a whole 640x480
/// frame the alignment keeps 3000 of some 250 000 object pixels. Also returns the thinning
/// (every how many'th of the usable pixels was kept).
pub(crate) fn object_samples(
    model: &ImageView<'_>,
    texture: &Texture,
    stride: usize,
    max_pixels: usize,
) -> (Vec<ObjectSample>, usize) {
    let usable = |x: usize, y: usize| {
        let z = f64::from(*model.depth.at(x, y));
        (*model.mask.at(x, y) && z > 0.0 && model.rays.ray(x, y).is_some()).then_some(z)
    };
    let pixels = || {
        let ((x0, y0), (x1, y1)) = texture.bounds();
        (y0.next_multiple_of(stride)..y1)
            .step_by(stride)
            .flat_map(move |y| (x0.next_multiple_of(stride)..x1).step_by(stride).map(move |x| (x, y)))
            .filter_map(move |(x, y)| usable(x, y).map(|z| (x, y, z)))
    };
    let every = pixels().count().div_ceil(max_pixels.max(1)).max(1);
    let samples = pixels()
        .step_by(every)
        .filter_map(|(x, y, z)| {
            let (point, value) = (model.rays.backproject(x, y, z)?, texture.at(x, y)?);
            Some(ObjectSample { point, value, column: x, row: y })
        })
        .collect();
    (samples, every)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{AlignConfig, align};
    use flowfilter_camera::{CameraModel, Distortion, ImageSize, Intrinsics, RayTable};
    use flowfilter_geometry::{Grid, Pose};

    /// A textured wall 0.6 m away and the same wall seen 3 mm to the right.
    fn walls() -> (CameraModel, RayTable, Gray, Gray, Grid<f32>, Mask) {
        let camera = CameraModel::new(
            Intrinsics::new(525.0, 525.0, 160.0, 120.0).unwrap(),
            Distortion::NONE,
            ImageSize::new(320, 240).unwrap(),
        );
        let rays = RayTable::new(&camera);
        let wall = |x: f64, y: f64| (0.5 + 0.2 * (x * 0.23).sin() * (y * 0.19).cos() + 0.1 * (x * 0.07).sin()) as f32;
        let shift = 525.0 * 0.003 / 0.6;
        let model = Grid::from_fn(320, 240, |x, y| wall(x as f64, y as f64));
        let target = Grid::from_fn(320, 240, |x, y| wall(x as f64 - shift, y as f64));
        let mask = Grid::from_fn(320, 240, |x, y| (60..260).contains(&x) && (40..200).contains(&y));
        (camera, rays, model, target, Grid::filled(320, 240, 0.6f32), mask)
    }

    #[test]
    fn a_cached_texture_is_the_texture_and_is_computed_once() {
        let (camera, rays, gray, _, depth, mask) = walls();
        let cache = TextureCache::new();
        let view =
            ImageView { gray: &gray, depth: &depth, mask: &mask, rays: &rays, camera: &camera, textures: Some(&cache) };
        let fresh = Texture::new(&gray, &mask, 4);
        let cached = view.texture(4, 0);
        assert_eq!(cached.grid.as_slice(), fresh.grid.as_slice());
        assert_eq!(view.texture(4, 2).grid.as_slice(), fresh.clone().smoothed(2).grid.as_slice());
        assert!(Arc::ptr_eq(&cached, &view.texture(4, 0)), "computed again");
        let (a, b) = (view.gradient_texture(4, 2), view.gradient_texture(4, 2));
        assert!(Arc::ptr_eq(&a.gradients, &b.gradients) && Arc::ptr_eq(&a.texture, &b.texture));
        assert_eq!(format!("{cache:?}"), "TextureCache { radius_and_smoothing: [(4, 0), (4, 2)] }");
    }

    #[test]
    fn an_alignment_from_cached_textures_is_the_same_to_the_bit() {
        let (camera, rays, model_gray, target_gray, depth, mask) = walls();
        let (mc, tc) = (TextureCache::new(), TextureCache::new());
        let view =
            |gray, textures| ImageView { gray, depth: &depth, mask: &mask, rays: &rays, camera: &camera, textures };
        let cfg = AlignConfig::default();
        let plain = align(&view(&model_gray, None), &view(&target_gray, None), &Pose::identity(), &cfg).unwrap();
        let (m, t) = (view(&model_gray, Some(&mc)), view(&target_gray, Some(&tc)));
        for _ in 0..2 {
            let cached = align(&m, &t, &Pose::identity(), &cfg).unwrap();
            assert_eq!(cached.0, plain.0);
            assert_eq!(cached.1, plain.1);
        }
    }
}
