//! Sparse pyramidal Lucas-Kanade (Bouguet, "Pyramidal implementation of the Lucas Kanade
//! feature tracker", 2000): per point, coarse to fine, iterative Newton steps on the window's
//! brightness constancy with bilinear sampling; points whose spatial gradient matrix is
//! ill-conditioned (small minimum eigenvalue) are rejected.

use crate::pyramid::ImagePyramid;
use flowfilter_geometry::fastmath::floor_f32;
use flowfilter_geometry::{Grid, Mask};
use image::RgbImage;
use rayon::prelude::*;
use warped_window::WarpedWindow;
use wide::f32x8;

mod warped_window;

/// A grey image with values in [0, 1].
pub type Gray = Grid<f32>;

/// Luma of an RGB image (Rec. 601 weights), in [0, 1].
pub fn to_gray(img: &RgbImage) -> Gray {
    let luma = |p: &[u8]| (0.299 * f32::from(p[0]) + 0.587 * f32::from(p[1]) + 0.114 * f32::from(p[2])) / 255.0;
    // Straight over the raw bytes (a per-pixel `get_pixel` cost a few ms per sensor frame),
    // eight pixels to a vector: each lane sums and divides as `luma` does, the same bits.
    let raw = img.as_raw();
    let mut data = vec![0.0f32; raw.len() / 3];
    let mut pixels = data.chunks_exact_mut(8);
    let mut bytes = raw.chunks_exact(24);
    for (out, px) in (&mut pixels).zip(&mut bytes) {
        let channel = |c: usize| f32x8::new(std::array::from_fn(|l| f32::from(px[3 * l + c])));
        let sum =
            f32x8::splat(0.299) * channel(0) + f32x8::splat(0.587) * channel(1) + f32x8::splat(0.114) * channel(2);
        out.copy_from_slice(&(sum / f32x8::splat(255.0)).to_array());
    }
    for (out, px) in pixels.into_remainder().iter_mut().zip(bytes.remainder().chunks_exact(3)) {
        *out = luma(px);
    }
    Gray::from_vec(img.width() as usize, img.height() as usize, data).expect("one value per pixel")
}

/// An image from a per-pixel function, rows in parallel (at least 24 rows per task).
pub(crate) fn par_image(w: usize, h: usize, f: impl Fn(usize, usize) -> f32 + Sync) -> Gray {
    let mut data = crate::buffers::zeroed(w * h);
    data.par_chunks_mut(w.max(1)).enumerate().with_min_len(24).for_each(|(y, row)| {
        for (x, v) in row.iter_mut().enumerate() {
            *v = f(x, y);
        }
    });
    Gray::from_vec(w, h, data).expect("sizes")
}

/// Half-resolution image: separable `[1 4 6 4 1] / 16` blur, then every other pixel.
pub fn downsample(img: &Gray) -> Gray {
    let (w, h) = img.dims();
    let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
    let mut data = crate::buffers::zeroed(nw * nh);
    data.par_chunks_mut(nw.max(1)).enumerate().with_min_len(24).for_each(|(y, row)| downsample_row(img, y, row));
    Gray::from_vec(nw, nh, data).expect("sizes")
}

/// Row `y` of [`downsample`]'s image: each pixel the sum over the 5 x 5 taps (rows, then
/// columns, in order) of the weight times the value, over 256. Away from the border eight
/// pixels at a time whose taps are all inside, one per lane (the same sums, the same bits);
/// the rest read clamped taps (inside the image the clamp changes nothing).
fn downsample_row(img: &Gray, y: usize, row: &mut [f32]) {
    const K: [f32; 5] = [1.0, 4.0, 6.0, 4.0, 1.0];
    let (w, h) = img.dims();
    let d = img.as_slice();
    let at = |x: isize, y: isize| *img.at(x.clamp(0, w as isize - 1) as usize, y.clamp(0, h as isize - 1) as usize);
    let cy = 2 * y as isize;
    let clamped = |x: usize| {
        let cx = 2 * x as isize;
        let mut acc = 0.0f32;
        for (j, kj) in K.iter().enumerate() {
            for (i, ki) in K.iter().enumerate() {
                acc += kj * ki * at(cx + i as isize - 2, cy + j as isize - 2);
            }
        }
        acc / 256.0
    };
    // Pixels whose taps are all inside: 2 <= 2x and 2x + 2 < w, on a row with 2 <= 2y and
    // 2y + 2 < h.
    let (first, end) = if cy >= 2 && cy + 2 < h as isize { (1, (w.saturating_sub(1) / 2).max(1)) } else { (0, 0) };
    let inner = first..end.max(first);
    for (x, v) in row.iter_mut().enumerate().filter(|(x, _)| !inner.contains(x)) {
        *v = clamped(x);
    }
    if inner.is_empty() {
        return;
    }
    let rows: [&[f32]; 5] = std::array::from_fn(|j| &d[(cy as usize + j - 2) * w..][..w]);
    let mut runs = row[inner.clone()].chunks_exact_mut(8);
    for (c, out) in (&mut runs).enumerate() {
        // Eight pixels from `x0`: tap `i` of pixel `x0 + l` is column `2 (x0 + l) + i - 2`.
        let x0 = inner.start + 8 * c;
        let mut acc = f32x8::ZERO;
        for (row, kj) in rows.iter().zip(K) {
            for (i, ki) in K.iter().enumerate() {
                let taps = &row[2 * x0 + i - 2..][..15];
                acc += f32x8::splat(kj * ki) * f32x8::new(std::array::from_fn(|l| taps[2 * l]));
            }
        }
        out.copy_from_slice(&(acc / f32x8::splat(256.0)).to_array());
    }
    let done = inner.end - runs.into_remainder().len();
    for (x, v) in row.iter_mut().enumerate().take(inner.end).skip(done) {
        *v = clamped(x);
    }
}

/// Bilinear sample with clamped borders (shared by the estimators and the pipeline's judge).
pub fn bilinear(img: &Gray, x: f32, y: f32) -> f32 {
    BilinearTap::new(img.width(), img.height(), x, y).sample(img.as_slice())
}

/// The four indices and weights of a bilinear sample at `(x, y)` (clamped to the image), to
/// sample several images of the same size at one position with one set of weights.
#[derive(Debug, Clone, Copy)]
pub(crate) struct BilinearTap {
    k: [usize; 4],
    fx: f32,
    fy: f32,
}

impl BilinearTap {
    /// The tap at `(x, y)` in a `width x height` image.
    #[inline]
    pub(crate) fn new(width: usize, height: usize, x: f32, y: f32) -> Self {
        if x >= 0.0 && y >= 0.0 && x < (width - 1) as f32 && y < (height - 1) as f32 {
            return Self::interior(width, x, y);
        }
        let x = x.clamp(0.0, width as f32 - 1.0);
        let y = y.clamp(0.0, height as f32 - 1.0);
        let (x0, y0) = (floor_f32(x), floor_f32(y));
        let (fx, fy) = (x - x0, y - y0);
        let (ix, iy) = (x0 as usize, y0 as usize);
        let (ix1, iy1) = ((ix + 1).min(width - 1), (iy + 1).min(height - 1));
        Self { k: [iy * width + ix, iy * width + ix1, iy1 * width + ix, iy1 * width + ix1], fx, fy }
    }

    /// The tap at `(x, y)` with `0 <= x < width - 1` and `0 <= y < height - 1`: no clamp is
    /// needed there and the truncation is the floor (the same indices and weights as the
    /// clamped tap).
    #[inline]
    fn interior(width: usize, x: f32, y: f32) -> Self {
        let (ix, iy) = (x as usize, y as usize);
        let k = iy * width + ix;
        Self { k: [k, k + 1, k + width, k + width + 1], fx: x - ix as f32, fy: y - iy as f32 }
    }

    /// For a one-row image: the two columns and the weight of the second.
    pub(crate) fn column(&self) -> ([usize; 2], f32) {
        ([self.k[0], self.k[1]], self.fx)
    }

    /// For a one-column image: the two rows and the weight of the second.
    pub(crate) fn row(&self) -> ([usize; 2], f32) {
        ([self.k[0], self.k[2]], self.fy)
    }

    /// The sample of `img` (row-major, the tap's size).
    #[inline]
    pub(crate) fn sample(&self, img: &[f32]) -> f32 {
        let (a, b, c, d) = (img[self.k[0]], img[self.k[1]], img[self.k[2]], img[self.k[3]]);
        let (fx, fy) = (self.fx, self.fy);
        (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (c * (1.0 - fx) + d * fx) * fy
    }
}

/// Parameters (defaults as OpenCV's `calcOpticalFlowPyrLK` with a 21x21 window and 3 levels).
#[derive(Debug, Clone, PartialEq)]
pub struct LkParams {
    /// Odd window size.
    pub window: usize,
    /// Pyramid levels above the full resolution.
    pub levels: usize,
    /// Newton iterations per level.
    pub max_iterations: usize,
    /// Stop when the update is below this (pixels).
    pub epsilon: f32,
    /// Reject when the gradient matrix's minimum eigenvalue / window area is below this
    /// (intensities in [0, 1]; the default is OpenCV's `minEigThreshold = 1e-4` converted from
    /// its scaled 0-255 derivatives: `1e-4 * 1024 / 255^2`).
    pub min_eigen: f32,
    /// Match each window's brightness: at every Newton step the window's grey levels are
    /// shifted by the offset that gives them the template's mean (over the template's pixels
    /// inside the mask). A real camera's exposure and white balance change between views, and
    /// a surface turned towards or away from the light darkens or brightens (regions of the
    /// shared RealSense shelves by up to 2.8x between frames), where plain Lucas-Kanade
    /// (OpenCV's) assumes constant brightness. The step keeps the plain gradient matrix:
    /// solving for the offset exactly (the gradients less their mean) lost 3 of 108 region
    /// successes on the tuning sequences, and a gain as well (the spreads' ratio) stretched
    /// nearly flat windows' noise.
    pub match_brightness: bool,
}

impl Default for LkParams {
    fn default() -> Self {
        Self { window: 21, levels: 3, max_iterations: 30, epsilon: 0.01, min_eigen: 1.6e-6, match_brightness: false }
    }
}

/// Track `points` (pixel coordinates in `from`) into `to`: the flow vector of each point, or
/// `None` when it is lost (ill-conditioned window or outside the image).
pub fn track(from: &Gray, to: &Gray, points: &[[f32; 2]], p: &LkParams) -> Vec<Option<[f32; 2]>> {
    track_masked(from, to, points, p, None)
}

/// Bilinear samples of several images of one size at `(x, y)` with one set of weights (the
/// same values as [`bilinear`] on each).
///
/// # Panics
/// When the images differ in size.
pub fn bilinear_many<const N: usize>(imgs: [&Gray; N], x: f32, y: f32) -> [f32; N] {
    let Some(first) = imgs.first() else { return [0.0; N] };
    assert!(imgs.iter().all(|img| img.dims() == first.dims()), "bilinear_many: images of different sizes");
    let tap = BilinearTap::new(first.width(), first.height(), x, y);
    imgs.map(|img| tap.sample(img.as_slice()))
}

/// Central differences `(I(x+1) - I(x-1)) / 2` along x and y, with clamped indices.
pub fn central_gradients(img: &Gray) -> (Gray, Gray) {
    let (w, h) = img.dims();
    let d = img.as_slice();
    let gx = par_image(w, h, |x, y| 0.5 * (d[y * w + (x + 1).min(w - 1)] - d[y * w + x.saturating_sub(1)]));
    let gy = par_image(w, h, |x, y| 0.5 * (d[(y + 1).min(h - 1) * w + x] - d[y.saturating_sub(1) * w + x]));
    (gx, gy)
}

/// A `side x side` window whose top-left sample is at `(x0 + fx, y0 + fy)`, fully inside the
/// image: every sample shares the fractional weights, so no per-pixel rounding or clamping.
struct Window {
    base: usize,
    w: usize,
    weights: [f32; 4],
}

impl Window {
    /// The window at `(x, y)` if all its bilinear taps lie inside `img`.
    #[inline]
    fn inside(img: &Gray, x: f32, y: f32, side: usize) -> Option<Self> {
        let (w, h) = img.dims();
        let (x0, y0) = (floor_f32(x), floor_f32(y));
        let ok = x0 >= 0.0 && y0 >= 0.0 && x0 as usize + side < w && y0 as usize + side < h;
        ok.then(|| {
            let (fx, fy) = (x - x0, y - y0);
            Self {
                base: y0 as usize * w + x0 as usize,
                w,
                weights: [(1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy],
            }
        })
    }

    /// The sample at window pixel `(i, j)` (what [`Window::for_row`] reads a row of).
    #[cfg(test)]
    fn sample(&self, img: &Gray, i: usize, j: usize) -> f32 {
        let d = img.as_slice();
        let k = self.base + j * self.w + i;
        let [a, b, c, e] = self.weights;
        a * d[k] + b * d[k + 1] + c * d[k + self.w] + e * d[k + self.w + 1]
    }

    /// Row `j` of the window's samples, `side` of them, passed to `f` in turn: [`Self::sample`]
    /// with the two image rows it reads sliced once (the same arithmetic, without a bounds
    /// check per tap).
    #[inline]
    fn for_row(&self, img: &Gray, j: usize, side: usize, mut f: impl FnMut(usize, f32)) {
        let d = img.as_slice();
        let top = &d[self.base + j * self.w..][..=side];
        let bottom = &d[self.base + (j + 1) * self.w..][..=side];
        let [a, b, c, e] = self.weights;
        for (i, (t, u)) in top.windows(2).zip(bottom.windows(2)).enumerate() {
            f(i, a * t[0] + b * t[1] + c * u[0] + e * u[1]);
        }
    }
}

/// Half-resolution mask: a pixel is set when all four of its children are.
fn downsample_mask(m: &Mask) -> Mask {
    let (w, h) = m.dims();
    let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
    let mut data = Vec::with_capacity(nw * nh);
    for y in 0..nh {
        // The children's rows and columns, clamped to the image (an odd side repeats its last).
        let (top, bottom) = (m.row(2 * y), m.row((2 * y + 1).min(h - 1)));
        data.extend((0..nw).map(|x| {
            let (a, b) = (2 * x, (2 * x + 1).min(w - 1));
            top[a] && top[b] && bottom[a] && bottom[b]
        }));
    }
    Mask::from_vec(nw, nh, data).expect("one value per pixel")
}

/// [`track`] with the window restricted to `mask` of the `from` image (at every pyramid level):
/// background and static silhouettes then do not pull the estimate, which matters for objects
/// whose outline does not move when they turn (cans, bottles).
pub fn track_masked(
    from: &Gray,
    to: &Gray,
    points: &[[f32; 2]],
    p: &LkParams,
    mask: Option<&Mask>,
) -> Vec<Option<[f32; 2]>> {
    track_guided(from, to, points, None, p, mask)
}

/// [`track_masked`] starting each point from a guessed flow (`guesses[i]` for `points[i]`)
/// instead of zero: large displacements that the pyramid cannot bridge become reachable when a
/// prediction (e.g. from a geometric pose estimate) is available.
pub fn track_guided(
    from: &Gray,
    to: &Gray,
    points: &[[f32; 2]],
    guesses: Option<&[[f32; 2]]>,
    p: &LkParams,
    mask: Option<&Mask>,
) -> Vec<Option<[f32; 2]>> {
    track_warped(from, to, points, guesses, None, p, mask)
}

/// A 2x2 linear map of window offsets, row-major: `(u, v) -> (m[0] u + m[1] v, m[2] u + m[3] v)`.
pub type WindowWarp = [f32; 4];

/// The identity [`WindowWarp`].
pub const IDENTITY_WARP: WindowWarp = [1.0, 0.0, 0.0, 1.0];

/// [`track_guided`] whose windows in `to` are warped: point `i`'s window offset `(u, v)` is
/// sampled at `guess + d + warps[i] (u, v)` (the local linear part of a predicted motion:
/// in-image rotation, scale and foreshortening), and each Newton step is mapped through the
/// warp. A translation-only window under a rotation of several degrees matches best short of
/// the true displacement (the window's outer pixels pull towards less motion, more the wider the
/// window); a window warped by the prediction sees an almost translated patch. The template
/// (in `from`) is not warped, so the gradient matrix is the plain one.
pub fn track_warped(
    from: &Gray,
    to: &Gray,
    points: &[[f32; 2]],
    guesses: Option<&[[f32; 2]]>,
    warps: Option<&[WindowWarp]>,
    p: &LkParams,
    mask: Option<&Mask>,
) -> Vec<Option<[f32; 2]>> {
    let (from, to) =
        rayon::join(|| ImagePyramid::new(from.clone(), p.levels), || ImagePyramid::new(to.clone(), p.levels));
    track_in(&from, &to, points, guesses, warps, p, mask)
}

/// [`track_warped`] on pyramids built beforehand (each at least `p.levels` deep, level 0 of
/// both and `mask` of one size): a pair's passes share one pyramid per image
/// ([`crate::pyramid::PyramidCache`]).
pub fn track_in(
    from: &ImagePyramid,
    to: &ImagePyramid,
    points: &[[f32; 2]],
    guesses: Option<&[[f32; 2]]>,
    warps: Option<&[WindowWarp]>,
    p: &LkParams,
    mask: Option<&Mask>,
) -> Vec<Option<[f32; 2]>> {
    let pyramids = Pyramids::new(from, to, mask, p.levels);
    let to = to.level(0);
    // A prediction is trusted to within a few pixels: refine it on the two finest levels only
    // (the coarse levels, where the silhouette dominates the object's texture, would pull it
    // back towards whatever does not move).
    let start_level = if guesses.is_some() { p.levels.min(1) } else { p.levels };
    let top = (1u32 << start_level) as f32;
    points
        .par_iter()
        .enumerate()
        .map(|(i, pt)| {
            let mut g = guesses.and_then(|gs| gs.get(i)).map_or([0.0f32; 2], |q| [q[0] / top, q[1] / top]);
            // A linear map is the same at every pyramid level (one window for all of them); the
            // identity needs no warping.
            let warp = warps.and_then(|ws| ws.get(i)).copied().filter(|m| *m != IDENTITY_WARP);
            let mut warped = warp.map(|m| WarpedWindow::new(m, (p.window / 2) as isize));
            for level in (0..=start_level).rev() {
                // Below the first level the coarser one has placed the window: a correction
                // beyond a window's width has left the basin its gradients describe.
                let reach = if level == start_level { f32::INFINITY } else { 2.0 * p.window as f32 };
                let d = pyramids.refine(level, *pt, g, warped.as_mut(), reach, p)?;
                g = if level > 0 { [2.0 * (g[0] + d[0]), 2.0 * (g[1] + d[1])] } else { [g[0] + d[0], g[1] + d[1]] };
            }
            let (qx, qy) = (pt[0] + g[0], pt[1] + g[1]);
            let inside = qx >= 0.0 && qy >= 0.0 && qx <= (to.width() - 1) as f32 && qy <= (to.height() - 1) as f32;
            (inside && g.iter().all(|v| v.is_finite())).then_some(g)
        })
        .collect()
}

/// The two images' pyramids (and the mask's), with central-difference gradients of the first
/// image at every level: sampled with the value's bilinear weights, they equal central
/// differences of bilinear samples (away from borders).
struct Pyramids<'p> {
    from: &'p [Gray],
    to: &'p [Gray],
    /// The mask at full resolution (the caller's), then its coarser levels.
    mask: Option<(&'p Mask, Vec<Mask>)>,
    grads: &'p [(Gray, Gray)],
}

/// One template pixel: its value and gradient (all zero outside the mask).
type TemplatePixel = (f32, f32, f32);

impl<'p> Pyramids<'p> {
    /// `levels` levels of `from` and `to` (both at least that deep) and of `mask`.
    fn new(from: &'p ImagePyramid, to: &'p ImagePyramid, mask: Option<&'p Mask>, levels: usize) -> Self {
        let mask = mask.map(|m| {
            let mut coarser: Vec<Mask> = Vec::with_capacity(levels);
            for _ in 0..levels {
                let next = downsample_mask(coarser.last().unwrap_or(m));
                coarser.push(next);
            }
            (m, coarser)
        });
        let (from_levels, to_levels) = (from.levels(), to.levels());
        Self { from: &from_levels[..=levels], to: &to_levels[..=levels], mask, grads: &from.gradients()[..=levels] }
    }

    /// The mask at `level` (`None` without one).
    fn mask(&self, level: usize) -> Option<&Mask> {
        let (full, coarser) = self.mask.as_ref()?;
        if level == 0 { Some(full) } else { coarser.get(level - 1) }
    }

    /// The template around `(px, py)` of `level` (row-major, `window` x `window`) and its
    /// spatial gradient matrix `(gxx, gxy, gyy)`.
    fn template(&self, level: usize, px: f32, py: f32, window: usize) -> (Vec<TemplatePixel>, [f32; 3]) {
        let r = (window / 2) as isize;
        let tmpl = match Window::inside(&self.from[level], px - r as f32, py - r as f32, window) {
            Some(win) => self.template_inside(level, &win, px, py, window),
            None => self.template_clamped(level, px, py, window),
        };
        let g = gradient_matrix(&tmpl);
        (tmpl, g)
    }

    /// [`Pyramids::template`] where the whole window lies inside the image (`win`): every
    /// pixel shares the fractional weights, and the mask's nearest pixel is the centre's
    /// offset by whole pixels.
    fn template_inside(&self, level: usize, win: &Window, px: f32, py: f32, window: usize) -> Vec<TemplatePixel> {
        let a = &self.from[level];
        let (gx, gy) = (&self.grads[level].0, &self.grads[level].1);
        let r = (window / 2) as isize;
        let mut tmpl = vec![(0.0, 0.0, 0.0); window * window];
        for (j, row) in tmpl.chunks_exact_mut(window).enumerate() {
            win.for_row(a, j, window, |i, v| row[i].0 = v);
            win.for_row(gx, j, window, |i, v| row[i].1 = v);
            win.for_row(gy, j, window, |i, v| row[i].2 = v);
        }
        // Outside the mask: no gradient, no residual.
        if let Some(m) = self.mask(level) {
            let (cx, cy) = (px.round() as isize, py.round() as isize);
            for (j, row) in tmpl.chunks_exact_mut(window).enumerate() {
                let my = cy + j as isize - r;
                for (i, pixel) in row.iter_mut().enumerate() {
                    let mx = cx + i as isize - r;
                    if !(mx >= 0 && my >= 0 && m.get(mx as usize, my as usize).copied().unwrap_or(false)) {
                        *pixel = (0.0, 0.0, 0.0);
                    }
                }
            }
        }
        tmpl
    }

    /// [`Pyramids::template`] anywhere: each pixel's own (clamped) bilinear tap.
    fn template_clamped(&self, level: usize, px: f32, py: f32, window: usize) -> Vec<TemplatePixel> {
        let a = &self.from[level];
        let r = (window / 2) as isize;
        let mut tmpl = Vec::with_capacity(window * window);
        let inside = |x: f32, y: f32| {
            self.mask(level).is_none_or(|m| {
                let (ix, iy) = (x.round(), y.round());
                ix >= 0.0 && iy >= 0.0 && m.get(ix as usize, iy as usize).copied().unwrap_or(false)
            })
        };
        let (gx, gy) = (&self.grads[level].0, &self.grads[level].1);
        for dy in -r..=r {
            for dx in -r..=r {
                let (x, y) = (px + dx as f32, py + dy as f32);
                if !inside(x, y) {
                    // Outside the mask: no gradient, no residual.
                    tmpl.push((0.0, 0.0, 0.0));
                    continue;
                }
                let tap = BilinearTap::new(a.width(), a.height(), x, y);
                // Beyond the border the clamped image is flat: no gradient there.
                let beyond = x < 0.0 || y < 0.0 || x > (a.width() - 1) as f32 || y > (a.height() - 1) as f32;
                let (ix, iy) = if beyond { (0.0, 0.0) } else { (tap.sample(gx.as_slice()), tap.sample(gy.as_slice())) };
                tmpl.push((tap.sample(a.as_slice()), ix, iy));
            }
        }
        tmpl
    }

    /// The displacement `d` beyond the guess `g` that Newton's iterations find for point `pt`
    /// at `level`; `None` where the window's gradients are too weak to track, or where the
    /// iterations carry `d` beyond `reach` (pixels of the level, in either coordinate: lost).
    /// `warped`: the point's window in `to`, warped (of `p.window`'s half-size).
    fn refine(
        &self,
        level: usize,
        pt: [f32; 2],
        g: [f32; 2],
        mut warped: Option<&mut WarpedWindow>,
        reach: f32,
        p: &LkParams,
    ) -> Option<[f32; 2]> {
        let s = (1u32 << level) as f32;
        let b = &self.to[level];
        let (px, py) = (pt[0] / s, pt[1] / s);
        let r = (p.window / 2) as isize;
        let area = (p.window * p.window) as f32;
        let (tmpl, [gxx, gxy, gyy]) = self.template(level, px, py, p.window);
        let moments = p.match_brightness.then(|| TemplateMoments::of(&tmpl));
        let tr = gxx + gyy;
        let min_eig = 0.5 * (tr - ((gxx - gyy).powi(2) + 4.0 * gxy * gxy).sqrt());
        if min_eig / area < p.min_eigen {
            return None;
        }
        let det = gxx * gyy - gxy * gxy;
        let warp = warped.as_ref().map(|w| w.warp());
        let mut d = [0.0f32; 2];
        for _ in 0..p.max_iterations {
            let corner = (px + g[0] + d[0] - r as f32, py + g[1] + d[1] - r as f32);
            let (bx, by) = mismatch(b, &tmpl, corner, r, warped.as_deref_mut(), moments.as_ref());
            let step = [(gyy * bx - gxy * by) / det, (gxx * by - gxy * bx) / det];
            // The template's shift, seen through the warp, is the window's.
            let step = warp.map_or(step, |m| [m[0] * step[0] + m[1] * step[1], m[2] * step[0] + m[3] * step[1]]);
            d[0] += step[0];
            d[1] += step[1];
            if d[0].abs() > reach || d[1].abs() > reach {
                return None;
            }
            if step[0].abs() < p.epsilon && step[1].abs() < p.epsilon {
                break;
            }
        }
        Some(d)
    }
}

/// The spatial gradient matrix `(gxx, gxy, gyy)` of a template (pixels outside the mask add
/// nothing: their gradient is 0).
fn gradient_matrix(tmpl: &[TemplatePixel]) -> [f32; 3] {
    let mut g = [0.0f32; 3];
    for &(_, ix, iy) in tmpl {
        g[0] += ix * ix;
        g[1] += ix * iy;
        g[2] += iy * iy;
    }
    g
}

/// A template's pixels inside the mask (those with a value or a gradient): the sum of their
/// values and the mean of their gradients, for matching a window's brightness to the
/// template's ([`LkParams::match_brightness`]).
struct TemplateMoments {
    sum: f32,
    mean_grad: [f32; 2],
}

impl TemplateMoments {
    fn of(tmpl: &[TemplatePixel]) -> Self {
        let (mut n, mut sum, mut grad) = (0.0f32, 0.0f32, [0.0f32; 2]);
        for &(t, ix, iy) in tmpl.iter().filter(|p| **p != (0.0, 0.0, 0.0)) {
            n += 1.0;
            sum += t;
            grad = [grad[0] + ix, grad[1] + iy];
        }
        let n = n.max(1.0);
        Self { sum, mean_grad: [grad[0] / n, grad[1] / n] }
    }
}

/// `sum_k (T_k - I(x_k)) grad T_k` over the window of half-size `r` whose top-left corner in
/// `b` is `(cx, cy)`, warped by `warped` (of the same half-size) about its centre. With the
/// template's `moments`, the window's values are first shifted by the offset that gives its
/// pixels inside the mask the template's mean ([`LkParams::match_brightness`]): over those
/// pixels, `I -> I + c` with `n c = sum (T - I)`, so the sum is `sum (T - I) grad T - g sum
/// (T - I)` (`g` the template's mean gradient), gathered in the same pass.
fn mismatch(
    b: &Gray,
    tmpl: &[TemplatePixel],
    (cx, cy): (f32, f32),
    r: isize,
    warped: Option<&mut WarpedWindow>,
    moments: Option<&TemplateMoments>,
) -> (f32, f32) {
    let side = 2 * r as usize + 1;
    let (mut bx, mut by) = (0.0f32, 0.0f32);
    // The window's sum over the template's pixels inside the mask.
    let mut si = 0.0f32;
    let matched = moments.is_some();
    let mut add = |k: usize, sample: f32| {
        let (t, ix, iy) = tmpl[k];
        let diff = t - sample;
        bx += diff * ix;
        by += diff * iy;
        if matched && tmpl[k] != (0.0, 0.0, 0.0) {
            si += sample;
        }
    };
    if let Some(window) = warped {
        // A warped window: every sample has its own bilinear weights (unclamped inside the
        // image, see `BilinearTap::new`).
        for (k, &sample) in window.sample(b, cx + r as f32, cy + r as f32).iter().enumerate() {
            add(k, sample);
        }
    } else if let Some(win) = Window::inside(b, cx, cy, side) {
        // The whole window in the image: one set of bilinear weights.
        for j in 0..side {
            win.for_row(b, j, side, |i, sample| add(j * side + i, sample));
        }
    } else {
        for j in 0..side {
            for i in 0..side {
                add(j * side + i, bilinear(b, cx + i as f32, cy + j as f32));
            }
        }
    }
    match moments {
        Some(m) => {
            let residual = m.sum - si;
            (bx - m.mean_grad[0] * residual, by - m.mean_grad[1] * residual)
        }
        None => (bx, by),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The interior fast path gives the clamped sum's bits.
    #[test]
    fn downsampling_is_the_clamped_binomial_sum() {
        for (w, h) in [(23, 18), (24, 17), (1, 1), (2, 3), (3, 2), (4, 5), (5, 6), (6, 7), (64, 9)] {
            let img = Gray::from_fn(w, h, |x, y| ((x * 7 + y * 13) % 17) as f32 / 17.0 + 0.001 * y as f32);
            let at =
                |x: isize, y: isize| *img.at(x.clamp(0, w as isize - 1) as usize, y.clamp(0, h as isize - 1) as usize);
            let k = [1.0f32, 4.0, 6.0, 4.0, 1.0];
            let half = downsample(&img);
            assert_eq!(half.dims(), (w.div_ceil(2), h.div_ceil(2)));
            for y in 0..half.height() {
                for x in 0..half.width() {
                    let mut acc = 0.0;
                    for (j, kj) in k.iter().enumerate() {
                        for (i, ki) in k.iter().enumerate() {
                            acc += kj * ki * at(2 * x as isize + i as isize - 2, 2 * y as isize + j as isize - 2);
                        }
                    }
                    assert_eq!(half.at(x, y).to_bits(), (acc / 256.0).to_bits(), "{w} x {h} at ({x}, {y})");
                }
            }
        }
    }

    /// A half-resolution mask pixel is set where its four children are (an odd side's last
    /// pixel counting twice).
    #[test]
    fn mask_downsampling_keeps_pixels_whose_children_are_all_set() {
        for (w, h) in [(9, 7), (8, 8), (1, 1), (1, 4), (5, 1)] {
            let m = Mask::from_fn(w, h, |x, y| (x * 5 + y * 3) % 7 != 0 || (x + y) % 4 == 1);
            let get = |x: usize, y: usize| *m.at(x.min(w - 1), y.min(h - 1));
            let half = downsample_mask(&m);
            assert_eq!(half.dims(), (w.div_ceil(2), h.div_ceil(2)));
            for (x, y) in (0..half.height()).flat_map(|y| (0..half.width()).map(move |x| (x, y))) {
                let want =
                    get(2 * x, 2 * y) && get(2 * x + 1, 2 * y) && get(2 * x, 2 * y + 1) && get(2 * x + 1, 2 * y + 1);
                assert_eq!(*half.at(x, y), want, "{w} x {h} at ({x}, {y})");
            }
        }
    }

    /// The raw-byte conversion is the per-pixel Rec. 601 luma.
    #[test]
    fn gray_is_the_per_pixel_luma() {
        // 91 pixels: eleven vectors of eight and three left over.
        let img = RgbImage::from_fn(13, 7, |x, y| image::Rgb([(x * 19) as u8, (y * 37) as u8, (x * y * 5) as u8]));
        let g = to_gray(&img);
        for (x, y, p) in img.enumerate_pixels() {
            let want = (0.299 * f32::from(p[0]) + 0.587 * f32::from(p[1]) + 0.114 * f32::from(p[2])) / 255.0;
            assert_eq!(g.at(x as usize, y as usize).to_bits(), want.to_bits());
        }
    }

    /// The clamped bilinear sample written out with libm's floor: what every tap must equal.
    fn reference_bilinear(img: &Gray, x: f32, y: f32) -> f32 {
        let (w, h) = img.dims();
        let (x, y) = (x.clamp(0.0, (w - 1) as f32), y.clamp(0.0, (h - 1) as f32));
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (ix, iy) = (x0 as usize, y0 as usize);
        let (ix1, iy1) = ((ix + 1).min(w - 1), (iy + 1).min(h - 1));
        let (a, b, c, d) = (*img.at(ix, iy), *img.at(ix1, iy), *img.at(ix, iy1), *img.at(ix1, iy1));
        (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (c * (1.0 - fx) + d * fx) * fy
    }

    /// Inside the image, on its edges and beyond them, the taps (with [`BilinearTap::new`]'s
    /// interior shortcut, [`BilinearTap::interior`]) give the clamped sample's bits.
    #[test]
    fn interior_samples_are_the_bilinear_samples() {
        let img = Gray::from_fn(37, 29, |x, y| ((x * 7 + y * 13) % 17) as f32 / 17.0 + 0.001 * x as f32);
        let mut s = 3u64;
        for _ in 0..2000 {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let x = (s >> 40) as f32 / (1u64 << 24) as f32 * 35.999;
            let y = (s & 0xff_ffff) as f32 / (1u64 << 24) as f32 * 27.999;
            let reference = reference_bilinear(&img, x, y).to_bits();
            let interior = BilinearTap::interior(img.width(), x, y).sample(img.as_slice());
            assert_eq!(interior.to_bits(), reference, "({x}, {y})");
            assert_eq!(bilinear(&img, x, y).to_bits(), reference, "({x}, {y})");
        }
        for (x, y) in [(36.0, 3.5), (2.5, 28.0), (36.0, 28.0), (-1.5, 4.25), (40.0, -3.0), (0.0, 0.0)] {
            assert_eq!(bilinear(&img, x, y).to_bits(), reference_bilinear(&img, x, y).to_bits(), "({x}, {y})");
        }
    }

    /// A window's rows read as slices are its samples read one by one, to the bit.
    #[test]
    fn window_rows_are_the_window_samples() {
        let img = Gray::from_fn(23, 19, |x, y| ((x * 5 + y * 11) % 13) as f32 / 13.0 + 0.003 * y as f32);
        for (x, y) in [(0.25f32, 0.5f32), (3.7, 8.1), (12.99, 9.0)] {
            let win = Window::inside(&img, x, y, 9).expect("inside");
            for j in 0..9 {
                let mut row = vec![];
                win.for_row(&img, j, 9, |i, v| row.push((i, v.to_bits())));
                let one_by_one: Vec<(usize, u32)> = (0..9).map(|i| (i, win.sample(&img, i, j).to_bits())).collect();
                assert_eq!(row, one_by_one, "window at ({x}, {y}), row {j}");
            }
        }
    }

    fn texture(w: usize, h: usize, shift: (f32, f32)) -> Gray {
        // A smooth random-looking pattern evaluated at (x - shift): moving content by +shift.
        Gray::from_fn(w, h, |x, y| {
            let (u, v) = (x as f32 - shift.0, y as f32 - shift.1);
            0.5 + 0.2 * (u * 0.21).sin() * (v * 0.17).cos()
                + 0.15 * ((u + 2.0 * v) * 0.093).sin()
                + 0.1 * ((3.0 * u - v) * 0.051).cos()
        })
    }

    #[test]
    fn a_correction_beyond_the_reach_is_lost() {
        // Content moved by 3 px: found from no guess with room to reach it, lost with a reach of
        // 1 px (the coarser level's guess would have been 3 px off).
        let (a, b) = (texture(120, 100, (0.0, 0.0)), texture(120, 100, (3.0, 0.0)));
        let p = LkParams { window: 9, ..LkParams::default() };
        let (a, b) = (ImagePyramid::new(a, 0), ImagePyramid::new(b, 0));
        let pyramids = Pyramids::new(&a, &b, None, 0);
        let d = pyramids.refine(0, [60.0, 50.0], [0.0, 0.0], None, f32::INFINITY, &p).expect("tracked");
        assert!((d[0] - 3.0).abs() < 0.05 && d[1].abs() < 0.05, "{d:?}");
        assert_eq!(pyramids.refine(0, [60.0, 50.0], [0.0, 0.0], None, 1.0, &p), None);
    }

    #[test]
    fn an_inside_template_is_the_clamped_one() {
        let a = texture(90, 70, (0.0, 0.0));
        let mask = Mask::from_fn(90, 70, |x, y| (x as f32 - 40.0).hypot(y as f32 - 30.0) < 20.0);
        let a = ImagePyramid::new(a, 1);
        let pyramids = Pyramids::new(&a, &a, Some(&mask), 1);
        for (level, px, py) in [(0, 37.3f32, 28.5f32), (0, 52.5, 41.7), (1, 18.2, 14.9), (1, 25.5, 20.5)] {
            let win = Window::inside(&pyramids.from[level], px - 4.0, py - 4.0, 9).expect("inside");
            let (fast, slow) =
                (pyramids.template_inside(level, &win, px, py, 9), pyramids.template_clamped(level, px, py, 9));
            let (g_fast, g_slow) = (gradient_matrix(&fast), gradient_matrix(&slow));
            for (f, s) in fast.iter().zip(&slow) {
                assert!(
                    (f.0 - s.0).abs() < 1e-6 && (f.1 - s.1).abs() < 1e-6 && (f.2 - s.2).abs() < 1e-6,
                    "{f:?} {s:?}"
                );
            }
            assert_eq!(fast.iter().filter(|t| t.1 != 0.0).count(), slow.iter().filter(|t| t.1 != 0.0).count());
            assert!(g_fast.iter().zip(&g_slow).all(|(f, s)| (f - s).abs() < 1e-5 * s.abs().max(1e-3)));
        }
    }

    #[test]
    fn recovers_subpixel_translations() {
        for shift in [(0.3f32, -0.7f32), (4.6, 2.2), (-11.3, 7.9)] {
            let (a, b) = (texture(160, 120, (0.0, 0.0)), texture(160, 120, shift));
            let pts: Vec<[f32; 2]> =
                (0..5).flat_map(|i| (0..4).map(move |j| [40.0 + 20.0 * i as f32, 30.0 + 20.0 * j as f32])).collect();
            let flow = track(&a, &b, &pts, &LkParams::default());
            for f in flow {
                let f = f.expect("tracked");
                let e = ((f[0] - shift.0).powi(2) + (f[1] - shift.1).powi(2)).sqrt();
                assert!(e < 0.1, "shift {shift:?}: estimate {f:?}, error {e}");
            }
        }
    }

    /// The same texture moved and brightened (as a camera's exposure or a surface's shading
    /// changes between views): windows whose brightness is matched track it as if nothing
    /// changed; plain windows, which take the brightness for a shift, land away from it or are
    /// lost. With the brightness unchanged both agree.
    #[test]
    fn matched_windows_track_a_texture_whose_brightness_changed() {
        let shift = (4.6f32, 2.2f32);
        let a = texture(160, 120, (0.0, 0.0));
        let brighter = Gray::from_fn(160, 120, |x, y| *texture(160, 120, shift).at(x, y) + 0.25);
        let pts: Vec<[f32; 2]> =
            (0..5).flat_map(|i| (0..4).map(move |j| [40.0 + 20.0 * i as f32, 30.0 + 20.0 * j as f32])).collect();
        let matched = LkParams { window: 9, match_brightness: true, ..LkParams::default() };
        let plain = LkParams { match_brightness: false, ..matched.clone() };
        let error = |f: Option<[f32; 2]>| {
            f.map_or(f32::INFINITY, |f| ((f[0] - shift.0).powi(2) + (f[1] - shift.1).powi(2)).sqrt())
        };
        let errors = |p: &LkParams, b: &Gray| track(&a, b, &pts, p).into_iter().map(error).collect::<Vec<f32>>();
        assert!(errors(&matched, &brighter).iter().all(|e| *e < 0.1), "{:?}", errors(&matched, &brighter));
        let off = errors(&plain, &brighter).iter().filter(|e| **e > 0.5).count();
        assert!(off * 2 > pts.len(), "plain windows: {:?}", errors(&plain, &brighter));
        let same = texture(160, 120, shift);
        assert!(errors(&matched, &same).iter().chain(&errors(&plain, &same)).all(|e| *e < 0.1));
    }

    /// A texture turned by 12 degrees about the image centre (and shifted): tracks started from
    /// the exact displacement stay on it when the window is warped by the rotation, and drift
    /// short of it with translation-only windows; a warp that is the identity changes nothing.
    #[test]
    fn warped_windows_track_a_rotated_texture() {
        let (w, h) = (200usize, 200usize);
        let (c, shift, theta) = (100.0f32, [2.5f32, -1.5f32], 12f32.to_radians());
        let (sn, cs) = theta.sin_cos();
        let pattern = |u: f32, v: f32| {
            0.5 + 0.2 * (u * 0.23).sin() * (v * 0.19).cos()
                + 0.15 * ((u + 2.0 * v) * 0.11).sin()
                + 0.1 * ((3.0 * u - v) * 0.07).cos()
        };
        let a = Gray::from_fn(w, h, |x, y| pattern(x as f32, y as f32));
        // b(q) = a(R^-1 (q - c - shift) + c): point p of `a` moves to c + shift + R (p - c).
        let b = Gray::from_fn(w, h, |x, y| {
            let (dx, dy) = (x as f32 - c - shift[0], y as f32 - c - shift[1]);
            pattern(cs * dx + sn * dy + c, -sn * dx + cs * dy + c)
        });
        let pts: Vec<[f32; 2]> =
            (0..4).flat_map(|i| (0..4).map(move |j| [70.0 + 20.0 * i as f32, 70.0 + 20.0 * j as f32])).collect();
        let truth: Vec<[f32; 2]> = pts
            .iter()
            .map(|p| {
                let (dx, dy) = (p[0] - c, p[1] - c);
                [c + shift[0] + cs * dx - sn * dy - p[0], c + shift[1] + sn * dx + cs * dy - p[1]]
            })
            .collect();
        let rotation: Vec<WindowWarp> = vec![[cs, -sn, sn, cs]; pts.len()];
        let identity: Vec<WindowWarp> = vec![IDENTITY_WARP; pts.len()];
        let p = LkParams::default();
        let mean_error = |warps: Option<&[WindowWarp]>| {
            let flow = track_warped(&a, &b, &pts, Some(&truth), warps, &p, None);
            flow.iter()
                .zip(&truth)
                .map(|(f, t)| {
                    let f = f.expect("tracked");
                    ((f[0] - t[0]).powi(2) + (f[1] - t[1]).powi(2)).sqrt()
                })
                .sum::<f32>()
                / pts.len() as f32
        };
        let (warped, plain) = (mean_error(Some(&rotation)), mean_error(None));
        assert!(warped < 0.05, "warped windows: mean error {warped} px");
        assert!(plain > 4.0 * warped, "translation-only windows: mean error {plain} px (warped {warped})");
        assert_eq!(
            track_warped(&a, &b, &pts, Some(&truth), Some(&identity), &p, None),
            track_guided(&a, &b, &pts, Some(&truth), &p, None)
        );
    }

    #[test]
    fn flat_windows_are_rejected() {
        let flat = Gray::filled(64, 64, 0.5);
        assert_eq!(track(&flat, &flat, &[[32.0, 32.0]], &LkParams::default()), vec![None]);
    }
}

#[cfg(test)]
mod mask_tests {
    use super::*;

    #[test]
    fn masked_tracking_ignores_a_static_background() {
        // A textured square moves by (3, 1) over a textured background that stays still: the
        // unmasked window is pulled towards zero, the masked one follows the square.
        let pattern = |x: f32, y: f32| 0.5 + 0.25 * (x * 0.31).sin() * (y * 0.27).cos() + 0.1 * ((x + y) * 0.13).sin();
        let inside = |x: usize, y: usize| (40..80).contains(&x) && (40..80).contains(&y);
        let a = Gray::from_fn(120, 120, |x, y| {
            if inside(x, y) { pattern(x as f32, y as f32) } else { pattern(y as f32 * 1.3, x as f32 * 0.7) }
        });
        let b = Gray::from_fn(120, 120, |x, y| {
            let (sx, sy) = (x as f32 - 3.0, y as f32 - 1.0);
            if (43..83).contains(&x) && (41..81).contains(&y) {
                pattern(sx, sy)
            } else {
                pattern(y as f32 * 1.3, x as f32 * 0.7)
            }
        });
        let mask = Mask::from_fn(120, 120, inside);
        let p = LkParams { levels: 1, ..LkParams::default() };
        let masked = track_masked(&a, &b, &[[45.0, 60.0]], &p, Some(&mask))[0].unwrap();
        assert!((masked[0] - 3.0).abs() < 0.2 && (masked[1] - 1.0).abs() < 0.2, "{masked:?}");
    }
}
