//! Dense Inverse Search (Kroeger, Timofte, Dai and Van Gool, ECCV 2016): coarse-to-fine dense
//! flow from a grid of overlapping patches.
//!
//! Per pyramid scale, from the coarsest to `finest_scale`:
//! 1. each patch of a regular grid starts from the flow of the coarser scale at its centre and,
//!    with spatial propagation, from its already-searched neighbours when they fit better;
//! 2. **inverse search**: inverse-compositional Gauss-Newton on the patch's translation, whose
//!    Hessian comes from the template alone (computed once per patch), with optional patch-mean
//!    normalisation (robust to brightness changes);
//! 3. **densification**: every pixel takes the average of the flows of the patches covering it,
//!    each weighted by `1 / max(1, |photometric error|)` at that pixel;
//! 4. optional **variational refinement** (Brox-style energy with brightness and gradient
//!    constancy under a robust penalty and a robust smoothness term, linearised at the current
//!    flow and solved by red-black successive over-relaxation).
//!
//! Intensities are handled on the 0-255 scale so that the energy weights (`alpha`, `delta`,
//! `gamma`) mean what they mean in OpenCV's implementation; the default parameters are its
//! "medium" preset. Rows of patches and of pixels run in parallel with rayon.

use crate::FlowField;
use crate::buffers::{recycle, zeroed};
use crate::estimator::{FlowError, FlowEstimator, check_pair};
use crate::lk::{BilinearTap, Gray, bilinear, par_image};
use flowfilter_geometry::fastmath::floor_f32;
use flowfilter_geometry::{Grid, Mask};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use wide::f32x8;

mod patch_sums;
mod refine;
use patch_sums::{Kernel, PatchInputs, lanes8};
use refine::refine;

/// Parameters of [`Dis`]; the defaults are OpenCV's `DISOpticalFlow` "medium" preset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DisParams {
    /// Finest scale searched (0 = full resolution); the result is upsampled from it.
    pub finest_scale: usize,
    /// Coarsest scale; `None` chooses it from the image size and patch size.
    pub coarsest_scale: Option<usize>,
    /// Patch side, pixels.
    pub patch_size: usize,
    /// Distance between neighbouring patches, pixels.
    pub patch_stride: usize,
    /// Gauss-Newton iterations per patch (split between the two propagation passes).
    pub iterations: usize,
    /// Subtract the patch means (robust to brightness changes).
    pub mean_normalization: bool,
    /// Try the neighbours' flow before searching (two raster passes).
    pub spatial_propagation: bool,
    /// Fixed-point iterations of the variational refinement (0 switches it off).
    pub refinement_iterations: usize,
    /// SOR sweeps per fixed-point iteration.
    pub sor_iterations: usize,
    /// Smoothness weight.
    pub alpha: f32,
    /// Brightness-constancy weight.
    pub delta: f32,
    /// Gradient-constancy weight.
    pub gamma: f32,
    /// SOR relaxation factor, in (0, 2).
    pub omega: f32,
    /// Gradients of the patch search.
    pub search_gradients: SearchGradients,
}

/// The image gradients the inverse patch search linearises with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SearchGradients {
    /// Central differences: full Gauss-Newton steps. Patches converge faster on large motions:
    /// the better choice on our turntable pairs (mean EPE 1.46 against 1.62 with `opencv_sobel`),
    /// and the pipeline configuration's choice.
    Central,
    /// OpenCV's `spatialGradient` (3x3 Sobel) at its unnormalised scale, eight times the
    /// derivative, so every Gauss-Newton step is an eighth of the full one: OpenCV's DIS exactly
    /// in this respect, and the presets' default. Damped and smoothed, patches overshoot less on
    /// Sintel (EPE 0.339 / 1.587 / 0.304 / 1.916 against 0.374 / 1.627 / 0.324 / 1.920 with
    /// `central`) but converge more slowly on large motions.
    #[default]
    OpencvSobel,
}

impl Default for DisParams {
    fn default() -> Self {
        Self {
            finest_scale: 1,
            coarsest_scale: None,
            patch_size: 8,
            patch_stride: 3,
            iterations: 25,
            mean_normalization: true,
            spatial_propagation: true,
            refinement_iterations: 5,
            sor_iterations: 5,
            alpha: 20.0,
            delta: 5.0,
            gamma: 10.0,
            omega: 1.6,
            search_gradients: SearchGradients::OpencvSobel,
        }
    }
}

impl DisParams {
    /// OpenCV's "ultrafast" preset.
    pub fn ultrafast() -> Self {
        Self { finest_scale: 2, patch_stride: 4, iterations: 12, refinement_iterations: 0, ..Self::default() }
    }

    /// OpenCV's "fast" preset.
    pub fn fast() -> Self {
        Self { finest_scale: 2, patch_stride: 4, iterations: 16, ..Self::default() }
    }

    /// OpenCV's "medium" preset (the default).
    pub fn medium() -> Self {
        Self::default()
    }

    /// Check ranges.
    pub fn validate(&self) -> Result<(), FlowError> {
        let fail = |m: String| Err(FlowError::Config(format!("dis: {m}")));
        if self.patch_size < 3 {
            return fail(format!("patch_size must be >= 3, found {}", self.patch_size));
        }
        if self.patch_stride == 0 || self.patch_stride > self.patch_size {
            return fail(format!("patch_stride must be in 1..=patch_size, found {}", self.patch_stride));
        }
        if self.iterations == 0 {
            return fail("iterations must be >= 1".into());
        }
        if !(self.omega > 0.0 && self.omega < 2.0) {
            return fail(format!("omega must be in (0, 2), found {}", self.omega));
        }
        if [self.alpha, self.delta, self.gamma].iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
            return fail("alpha, delta and gamma must be finite and >= 0".into());
        }
        if let Some(c) = self.coarsest_scale
            && c < self.finest_scale
        {
            return fail(format!("coarsest_scale {c} is finer than finest_scale {}", self.finest_scale));
        }
        Ok(())
    }
}

/// Dense Inverse Search as a [`FlowEstimator`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Dis {
    /// Parameters.
    pub params: DisParams,
}

impl Dis {
    /// An estimator with these parameters.
    pub fn new(params: DisParams) -> Result<Self, FlowError> {
        params.validate()?;
        Ok(Self { params })
    }
}

type Img = Grid<f32>;

/// Half resolution by 2x2 box averaging (OpenCV's area interpolation for exact halves).
fn halve(img: &Img) -> Img {
    halve_scaled(img, 1.0)
}

/// [`halve`] with the values multiplied by `k`.
fn halve_scaled(img: &Img, k: f32) -> Img {
    let (w, h) = img.dims();
    let (nw, nh) = ((w / 2).max(1), (h / 2).max(1));
    let d = img.as_slice();
    let at = |x: usize, y: usize| d[y.min(h - 1) * w + x.min(w - 1)];
    let k = 0.25 * k;
    par_image(nw, nh, |x, y| {
        k * (at(2 * x, 2 * y) + at(2 * x + 1, 2 * y) + at(2 * x, 2 * y + 1) + at(2 * x + 1, 2 * y + 1))
    })
}

/// An image written row by row in parallel: `f(y, row)` fills row `y`.
fn row_image(w: usize, h: usize, f: impl Fn(usize, &mut [f32]) + Sync) -> Img {
    let mut data = zeroed(w * h);
    data.par_chunks_mut(w.max(1)).enumerate().with_min_len(ROWS_PER_TASK).for_each(|(y, row)| f(y, row));
    Img::from_vec(w, h, data).expect("sizes")
}

/// `out[x] = (r[x + 1] - r[x - 1]) / 2` inside the row, one-sided differences at its ends.
fn central_difference_row(r: &[f32], out: &mut [f32]) {
    let w = r.len();
    if w < 2 {
        out.fill(0.0);
        return;
    }
    out[0] = r[1] - r[0];
    for ((o, &a), &b) in out[1..w - 1].iter_mut().zip(&r[..w - 2]).zip(&r[2..]) {
        *o = (b - a) / 2.0;
    }
    out[w - 1] = r[w - 1] - r[w - 2];
}

/// Central-difference gradients (one-sided at the border).
fn gradients(img: &Img) -> (Img, Img) {
    let (w, h) = img.dims();
    let gx = row_image(w, h, |y, out| central_difference_row(img.row(y), out));
    (gx, gradient_y(img))
}

/// OpenCV's `spatialGradient` (3x3 Sobel, `[1 2 1]` smoothing across a central difference) at
/// its unnormalised scale, eight times the derivative (see [`SearchGradients::OpencvSobel`]);
/// replicated borders.
fn sobel(img: &Img) -> (Img, Img) {
    let (w, h) = img.dims();
    let rows = |y: usize| (img.row(y.saturating_sub(1)), img.row(y), img.row((y + 1).min(h - 1)));
    let (l, r) = (|x: usize| x.saturating_sub(1), |x: usize| (x + 1).min(w - 1));
    // Per column, the two replicated-border neighbours' offsets: fixed inside the row.
    let at = |row: &[f32], x: usize| (row[l(x)], row[x], row[r(x)]);
    let ends = |x: usize| x == 0 || x + 1 >= w;
    let gx = row_image(w, h, |y, out| {
        let (up, mid, down) = rows(y);
        for (x, o) in out.iter_mut().enumerate() {
            *o = if ends(x) {
                let ((a, _, b), (c, _, d), (e, _, f)) = (at(up, x), at(mid, x), at(down, x));
                (b - a) + 2.0 * (d - c) + (f - e)
            } else {
                (up[x + 1] - up[x - 1]) + 2.0 * (mid[x + 1] - mid[x - 1]) + (down[x + 1] - down[x - 1])
            };
        }
    });
    let gy = row_image(w, h, |y, out| {
        let (up, _, down) = rows(y);
        for (x, o) in out.iter_mut().enumerate() {
            *o = if ends(x) {
                let ((a, b, c), (d, e, f)) = (at(up, x), at(down, x));
                (d - a) + 2.0 * (e - b) + (f - c)
            } else {
                (down[x - 1] - up[x - 1]) + 2.0 * (down[x] - up[x]) + (down[x + 1] - up[x + 1])
            };
        }
    });
    (gx, gy)
}

/// The y component of [`gradients`].
fn gradient_y(img: &Img) -> Img {
    let (w, h) = img.dims();
    row_image(w, h, |y, out| {
        let (u, b) = (y.saturating_sub(1), (y + 1).min(h - 1));
        let (ru, rb) = (img.row(u), img.row(b));
        let scale = 1.0 / (b - u).max(1) as f32;
        for ((o, &a), &c) in out.iter_mut().zip(ru).zip(rb) {
            *o = (c - a) * scale;
        }
    })
}

/// Bilinear taps resampling `src` samples to `dst` (pixel centres aligned): per output index,
/// the two source indices and the weight of the second.
fn taps(src: usize, dst: usize) -> Vec<([usize; 2], f32)> {
    let s = dst as f32 / src as f32;
    (0..dst).map(|x| BilinearTap::new(src, 1, (x as f32 + 0.5) / s - 0.5, 0.0).column()).collect()
}

/// One output row of a bilinear resampling (pixel centres aligned): the source rows `top` and
/// `bottom` blended with weight `fy` on the second into `blended`, then spread over the output
/// columns into `out` (an exact doubling with its fixed 1/4, 3/4 weights, else the `columns`
/// taps), every value multiplied by `s`.
fn resample_row(
    (top, bottom, fy): (&[f32], &[f32], f32),
    columns: &[([usize; 2], f32)],
    s: f32,
    blended: &mut [f32],
    out: &mut [f32],
) {
    for ((b, &t), &d) in blended.iter_mut().zip(top).zip(bottom) {
        *b = t * (1.0 - fy) + d * fy;
    }
    let n = blended.len();
    if out.len() == 2 * n && n >= 2 {
        // Output column 2i samples i - 1/4, column 2i + 1 samples i + 1/4 (clamped at the ends).
        out[0] = s * blended[0];
        out[2 * n - 1] = s * blended[n - 1];
        for (i, pair) in blended.windows(2).enumerate() {
            out[2 * i + 1] = s * (pair[0] * 0.75 + pair[1] * 0.25);
            out[2 * i + 2] = s * (pair[0] * 0.25 + pair[1] * 0.75);
        }
        return;
    }
    for (o, &([x0, x1], fx)) in out.iter_mut().zip(columns) {
        *o = s * (blended[x0] * (1.0 - fx) + blended[x1] * fx);
    }
}

/// The source rows and weight of output row `y` when resampling `fh` rows to `h`.
fn source_rows(d: &[f32], fw: usize, fh: usize, h: usize, y: usize) -> (&[f32], &[f32], f32) {
    let (r, fy) = BilinearTap::new(1, fh, 0.0, (y as f32 + 0.5) * fh as f32 / h as f32 - 0.5).row();
    (&d[r[0] * fw..(r[0] + 1) * fw], &d[r[1] * fw..(r[1] + 1) * fw], fy)
}

/// Resample a flow component to `(w, h)` (pixel centres aligned, bilinear) and multiply it by
/// `s`; the taps of each column are computed once.
fn resample(f: &Img, w: usize, h: usize, s: f32) -> Img {
    let (fw, fh) = f.dims();
    let columns = taps(fw, w);
    let d = f.as_slice();
    let mut out = zeroed(w * h);
    out.par_chunks_mut(w).enumerate().with_min_len(ROWS_PER_TASK).for_each_init(
        || vec![0.0f32; fw],
        |blended, (y, row)| resample_row(source_rows(d, fw, fh, h, y), &columns, s, blended, row),
    );
    Img::from_vec(w, h, out).expect("sizes")
}

/// Both flow components resampled to `(w, h)` as in [`resample`], `u` multiplied by the
/// horizontal and `v` by the vertical scale factor, written interleaved (the output layout).
fn resample_flow(u: &Img, v: &Img, w: usize, h: usize) -> Vec<[f32; 2]> {
    let (fw, fh) = u.dims();
    let (sx, sy) = (w as f32 / fw as f32, h as f32 / fh as f32);
    let columns = taps(fw, w);
    let (du, dv) = (u.as_slice(), v.as_slice());
    let mut out = vec![[0.0f32; 2]; w * h];
    out.par_chunks_mut(w).enumerate().with_min_len(ROWS_PER_TASK).for_each_init(
        || (vec![0.0f32; fw], vec![0.0f32; w], vec![0.0f32; w]),
        |(blended, ru, rv), (y, row)| {
            resample_row(source_rows(du, fw, fh, h, y), &columns, sx, blended, ru);
            resample_row(source_rows(dv, fw, fh, h, y), &columns, sy, blended, rv);
            for ((o, &a), &b) in row.iter_mut().zip(ru.iter()).zip(rv.iter()) {
                *o = [a, b];
            }
        },
    );
    out
}

/// Hands both images of a pair back to the buffer pool.
fn recycle_pair((a, b): (Img, Img)) {
    recycle(a.into_vec());
    recycle(b.into_vec());
}

/// Double-resolution flow of size `(w, h)` from a coarser one (values scaled by 2).
fn upsample(u: &Img, w: usize, h: usize) -> Img {
    resample(u, w, h, 2.0)
}

/// Patch origins along one axis: a regular stride, the last patch flush with the border.
fn patch_origins(len: usize, ps: usize, stride: usize) -> Vec<usize> {
    if len <= ps {
        return vec![0];
    }
    let mut o: Vec<usize> = (0..=(len - ps) / stride).map(|i| i * stride).collect();
    if *o.last().expect("non-empty") != len - ps {
        o.push(len - ps);
    }
    o
}

/// A patch's template (from the first image), its gradients and its inverse Hessian.
struct Template {
    values: Vec<f32>,
    gx: Vec<f32>,
    gy: Vec<f32>,
    /// Sums of `gx` and `gy` over the patch (for the mean normalisation of the steps).
    sum_gx: f32,
    sum_gy: f32,
    /// Inverse of the 2x2 Hessian `[[a, b], [b, c]]`, or `None` when singular (flat patch).
    inv_h: Option<[f32; 3]>,
}

/// Patch search context at one scale.
struct Scale<'a> {
    i0: &'a Img,
    i1: &'a Img,
    i0x: &'a Img,
    i0y: &'a Img,
    ps: usize,
    mean_norm: bool,
    /// The patch-sums kernel for this CPU.
    kernel: Kernel,
}

impl Scale<'_> {
    fn template(&self, ox: usize, oy: usize) -> Template {
        let (ps, w) = (self.ps, self.i0.width());
        let n = ps * ps;
        let (mut values, mut gx, mut gy) = (Vec::with_capacity(n), Vec::with_capacity(n), Vec::with_capacity(n));
        for y in oy..oy + ps {
            let r = y * w + ox;
            values.extend_from_slice(&self.i0.as_slice()[r..r + ps]);
            gx.extend_from_slice(&self.i0x.as_slice()[r..r + ps]);
            gy.extend_from_slice(&self.i0y.as_slice()[r..r + ps]);
        }
        let nf = n as f32;
        let (mut a, mut b, mut c) = (0.0f32, 0.0f32, 0.0f32);
        for k in 0..n {
            a += gx[k] * gx[k];
            b += gx[k] * gy[k];
            c += gy[k] * gy[k];
        }
        let (sum_gx, sum_gy) = (gx.iter().sum::<f32>(), gy.iter().sum::<f32>());
        if self.mean_norm {
            let (mx, my) = (sum_gx / nf, sum_gy / nf);
            a -= nf * mx * mx;
            b -= nf * mx * my;
            c -= nf * my * my;
        }
        let det = a * c - b * b;
        let inv_h = (det > 1e-6 * (a + c).powi(2).max(1e-12)).then(|| [c / det, -b / det, a / det]);
        Template { values, gx, gy, sum_gx, sum_gy, inv_h }
    }

    /// Warp the second image's patch at `(ox + u, oy + v)` into `out`; the warp is a pure
    /// translation, so all pixels share one set of bilinear weights.
    fn warp(&self, ox: usize, oy: usize, u: f32, v: f32, out: &mut [f32]) {
        let (w, h) = self.i1.dims();
        let ps = self.ps;
        let (x, y) = (ox as f32 + u, oy as f32 + v);
        let (x0, y0) = (floor_f32(x), floor_f32(y));
        let inside = x0 >= 0.0 && y0 >= 0.0 && (x0 as usize + ps) < w && (y0 as usize + ps) < h;
        if !inside && ps > MAX_PATCH {
            for j in 0..ps {
                for i in 0..ps {
                    out[j * ps + i] = bilinear(self.i1, x + i as f32, y + j as f32);
                }
            }
            return;
        }
        if !inside {
            // Near the border: clamped bilinear samples, which are separable, so the column and
            // row taps are computed once per patch (the same values as per-pixel `bilinear`).
            let d = self.i1.as_slice();
            let mut columns = [([0usize; 2], 0.0f32); MAX_PATCH];
            let mut rows = [([0usize; 2], 0.0f32); MAX_PATCH];
            for i in 0..ps {
                columns[i] = BilinearTap::new(w, 1, x + i as f32, 0.0).column();
                rows[i] = BilinearTap::new(1, h, 0.0, y + i as f32).row();
            }
            for (j, &([r0, r1], fy)) in rows[..ps].iter().enumerate() {
                let (top, bottom) = (&d[r0 * w..(r0 + 1) * w], &d[r1 * w..(r1 + 1) * w]);
                for (o, &([c0, c1], fx)) in out[j * ps..(j + 1) * ps].iter_mut().zip(&columns[..ps]) {
                    *o = (top[c0] * (1.0 - fx) + top[c1] * fx) * (1.0 - fy)
                        + (bottom[c0] * (1.0 - fx) + bottom[c1] * fx) * fy;
                }
            }
            return;
        }
        let (fx, fy) = (x - x0, y - y0);
        let (w00, w10, w01, w11) = ((1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy);
        let d = self.i1.as_slice();
        let (bx, by) = (x0 as usize, y0 as usize);
        let weights = [w00, w10, w01, w11];
        match ps {
            // The presets' patch size, with rows of a fixed length the compiler unrolls.
            8 => warp_rows::<8>(d, w, bx, by, weights, out),
            _ => {
                for j in 0..ps {
                    let r0 = &d[(by + j) * w + bx..(by + j) * w + bx + ps + 1];
                    let r1 = &d[(by + j + 1) * w + bx..(by + j + 1) * w + bx + ps + 1];
                    let o = &mut out[j * ps..(j + 1) * ps];
                    for i in 0..ps {
                        o[i] = w00 * r0[i] + w10 * r0[i + 1] + w01 * r1[i] + w11 * r1[i + 1];
                    }
                }
            }
        }
    }

    /// The warped patch minus the template into `diff`, and the mean-normalisation shift
    /// (the mean of `diff`; 0 without normalisation).
    fn difference(&self, t: &Template, ox: usize, oy: usize, f: [f32; 2], diff: &mut [f32]) -> f32 {
        self.warp(ox, oy, f[0], f[1], diff);
        let mut lanes = [0.0f32; LANES];
        let chunks = diff.chunks_exact_mut(LANES).zip(t.values.chunks_exact(LANES));
        for (d, v) in chunks {
            for j in 0..LANES {
                d[j] -= v[j];
                lanes[j] += d[j];
            }
        }
        let tail = diff.len() / LANES * LANES;
        let mut sum = lanes.iter().sum::<f32>();
        for (d, v) in diff[tail..].iter_mut().zip(&t.values[tail..]) {
            *d -= v;
            sum += *d;
        }
        if self.mean_norm { sum / diff.len() as f32 } else { 0.0 }
    }

    /// Sum of squared (mean-normalised) differences between the template and the warped patch.
    fn ssd(&self, t: &Template, ox: usize, oy: usize, f: [f32; 2], buf: &mut [f32]) -> f32 {
        let [sr, sq, _, _] = self.residual_sums(t, ox, oy, f, 0.0, buf);
        let nf = buf.len() as f32;
        if self.mean_norm { (sq - sr * sr / nf).max(0.0) } else { sq }
    }

    /// Sums over the patch of the residual `r = warped - template - centre`:
    /// `[sum r, sum r^2, sum gx r, sum gy r]`. Patches of the presets' side inside the image are
    /// warped, differenced and reduced in one pass; others go through `buf`.
    fn residual_sums(&self, t: &Template, ox: usize, oy: usize, f: [f32; 2], centre: f32, buf: &mut [f32]) -> [f32; 4] {
        let (w, h) = self.i1.dims();
        let (x, y) = (ox as f32 + f[0], oy as f32 + f[1]);
        let (x0, y0) = (floor_f32(x), floor_f32(y));
        if self.ps == 8 && x0 >= 0.0 && y0 >= 0.0 && (x0 as usize + 8) < w && (y0 as usize + 8) < h {
            let (fx, fy) = (x - x0, y - y0);
            let weights = [(1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy];
            let (bx, by) = (x0 as usize, y0 as usize);
            let block = &self.i1.as_slice()[by * w + bx..(by + 8) * w + bx + 9];
            let (values, gx, gy) = (&t.values[..64], &t.gx[..64], &t.gy[..64]);
            return self.kernel.sums(&PatchInputs { block, w, weights, values, gx, gy, centre });
        }
        self.warp(ox, oy, f[0], f[1], buf);
        let mut s = [0.0f32; 4];
        for (((d, v), gx), gy) in buf.iter().zip(&t.values).zip(&t.gx).zip(&t.gy) {
            let r = d - v - centre;
            s[0] += r;
            s[1] += r * r;
            s[2] += gx * r;
            s[3] += gy * r;
        }
        s
    }

    /// Inverse-compositional Gauss-Newton from `f`; returns the flow with the lowest SSD seen.
    /// Each step reduces the residual once: the mean normalisation is applied to the sums
    /// (`sum (r - m)^2 = sum r^2 - n m^2`, `sum g (r - m) = sum g r - m sum g`), with the residual
    /// taken about the previous step's mean so that the subtraction loses no precision.
    fn search(
        &self,
        t: &Template,
        ox: usize,
        oy: usize,
        f: [f32; 2],
        iterations: usize,
        buf: &mut [f32],
    ) -> ([f32; 2], f32) {
        let Some(ih) = t.inv_h else {
            let s = self.ssd(t, ox, oy, f, buf);
            return (f, s);
        };
        let nf = buf.len() as f32;
        let mut cur = f;
        let mut best = (f, f32::INFINITY);
        let mut centre = 0.0f32;
        for _ in 0..iterations {
            let [sr, sq, sx, sy] = self.residual_sums(t, ox, oy, cur, centre, buf);
            let m = if self.mean_norm { sr / nf } else { 0.0 };
            let ssd = (sq - nf * m * m).max(0.0);
            let (bx, by) = (sx - m * t.sum_gx, sy - m * t.sum_gy);
            if self.mean_norm {
                centre += m;
            }
            if ssd < best.1 {
                best = (cur, ssd);
            } else {
                break;
            }
            let du = [ih[0] * bx + ih[1] * by, ih[1] * bx + ih[2] * by];
            cur = [cur[0] - du[0], cur[1] - du[1]];
            if du[0] * du[0] + du[1] * du[1] < 1e-4 {
                let s = self.ssd(t, ox, oy, cur, buf);
                if s < best.1 {
                    best = (cur, s);
                }
                break;
            }
        }
        best
    }
}

/// [`Scale::warp`]'s interior case for patches of side `P`: `out` (P x P) from the image `d`
/// (row length `w`) at `(bx, by)` with the shared bilinear weights `[w00, w10, w01, w11]`.
#[inline]
fn warp_rows<const P: usize>(d: &[f32], w: usize, bx: usize, by: usize, weights: [f32; 4], out: &mut [f32]) {
    let [w00, w10, w01, w11] = weights;
    for (j, o) in out.chunks_exact_mut(P).take(P).enumerate() {
        let r0: &[f32; P] = d[(by + j) * w + bx..][..P].try_into().expect("P values");
        let r0n: &[f32; P] = d[(by + j) * w + bx + 1..][..P].try_into().expect("P values");
        let r1: &[f32; P] = d[(by + j + 1) * w + bx..][..P].try_into().expect("P values");
        let r1n: &[f32; P] = d[(by + j + 1) * w + bx + 1..][..P].try_into().expect("P values");
        for i in 0..P {
            o[i] = w00 * r0[i] + w10 * r0n[i] + w01 * r1[i] + w11 * r1n[i];
        }
    }
}

/// Largest patch side with the border warp's fixed tap arrays (larger patches take the
/// per-pixel path).
const MAX_PATCH: usize = 32;

/// Accumulator lanes of the patch reductions (independent partial sums, so that they vectorise).
const LANES: usize = 8;

/// Rows of patches searched together (each band runs its propagation sequentially; bands run
/// in parallel).
const BAND_ROWS: usize = 4;

/// Patch search over the grid: the per-patch flows, their mean differences (for densification).
fn patch_flows(sc: &Scale<'_>, init: &(Img, Img), p: &DisParams) -> (Vec<usize>, Vec<usize>, Vec<[f32; 2]>, Vec<f32>) {
    let (w, h) = sc.i0.dims();
    let ps = sc.ps;
    let xs = patch_origins(w, ps, p.patch_stride);
    let ys = patch_origins(h, ps, p.patch_stride);
    let (nx, ny) = (xs.len(), ys.len());
    let half = ps as f32 / 2.0;
    let passes = if p.spatial_propagation { 2 } else { 1 };
    let iters = (p.iterations / passes).max(1);
    let bands: Vec<(Vec<[f32; 2]>, Vec<f32>)> = (0..ny.div_ceil(BAND_ROWS))
        .into_par_iter()
        .map(|band| {
            let rows = band * BAND_ROWS..((band + 1) * BAND_ROWS).min(ny);
            let nr = rows.len();
            let mut buf = vec![0.0f32; ps * ps];
            let (xs, ys) = (&xs, &ys);
            let templates: Vec<Template> = rows
                .clone()
                .flat_map(|j| xs.iter().map(move |&x| (x, ys[j])))
                .map(|(x, y)| sc.template(x, y))
                .collect();
            let mut flows: Vec<[f32; 2]> = rows
                .clone()
                .flat_map(|j| xs.iter().map(move |&x| (x, ys[j])))
                .map(|(x, y)| {
                    [
                        bilinear(&init.0, x as f32 + half, y as f32 + half),
                        bilinear(&init.1, x as f32 + half, y as f32 + half),
                    ]
                })
                .collect();
            let initial = flows.clone();
            let mut ssd = vec![f32::INFINITY; flows.len()];
            for pass in 0..passes {
                let order: Vec<usize> = if pass == 0 { (0..nr * nx).collect() } else { (0..nr * nx).rev().collect() };
                for k in order {
                    let (lj, i) = (k / nx, k % nx);
                    let (ox, oy) = (xs[i], ys[rows.start + lj]);
                    let t = &templates[k];
                    let mut start = flows[k];
                    let mut start_ssd = sc.ssd(t, ox, oy, start, &mut buf);
                    if p.spatial_propagation {
                        let neighbours: [Option<usize>; 2] = if pass == 0 {
                            [(i > 0).then(|| k - 1), (lj > 0).then(|| k - nx)]
                        } else {
                            [(i + 1 < nx).then(|| k + 1), (lj + 1 < nr).then(|| k + nx)]
                        };
                        for q in neighbours.into_iter().flatten() {
                            let s = sc.ssd(t, ox, oy, flows[q], &mut buf);
                            if s < start_ssd {
                                start = flows[q];
                                start_ssd = s;
                            }
                        }
                    }
                    let (f, s) = sc.search(t, ox, oy, start, iters, &mut buf);
                    (flows[k], ssd[k]) = if s <= start_ssd { (f, s) } else { (start, start_ssd) };
                }
            }
            // A patch that wandered further than its own size from where it started is not
            // trusted: back to the initial flow.
            let mut shifts = Vec::with_capacity(flows.len());
            for k in 0..flows.len() {
                let d = ((flows[k][0] - initial[k][0]).powi(2) + (flows[k][1] - initial[k][1]).powi(2)).sqrt();
                if d > ps as f32 {
                    flows[k] = initial[k];
                }
                let (i, lj) = (k % nx, k / nx);
                let (ox, oy) = (xs[i], ys[rows.start + lj]);
                shifts.push(sc.difference(&templates[k], ox, oy, flows[k], &mut buf));
            }
            (flows, shifts)
        })
        .collect();
    let (mut flows, mut shifts) = (Vec::with_capacity(nx * ny), Vec::with_capacity(nx * ny));
    for (f, s) in bands {
        flows.extend(f);
        shifts.extend(s);
    }
    (xs, ys, flows, shifts)
}

/// Patches covering coordinate `c` along an axis with origins `o` (sorted) and side `ps`.
fn covering(o: &[usize], ps: usize, c: usize) -> std::ops::Range<usize> {
    let lo = o.partition_point(|&s| s + ps <= c);
    let hi = o.partition_point(|&s| s <= c);
    lo..hi
}

/// Densification: per pixel, the photometric-error-weighted average of the covering patches.
/// Row by row; within a row each covering patch contributes a segment warped with one set of
/// bilinear weights (its flow is constant).
fn densify(sc: &Scale<'_>, xs: &[usize], ys: &[usize], flows: &[[f32; 2]], shifts: &[f32]) -> (Img, Img) {
    let (w, h) = sc.i0.dims();
    let nx = xs.len();
    let ps = sc.ps;
    let d1 = sc.i1.as_slice();
    let mut u = zeroed(w * h);
    let mut v = zeroed(w * h);
    u.par_chunks_mut(w).zip(v.par_chunks_mut(w)).enumerate().with_min_len(ROWS_PER_TASK).for_each(|(y, (ur, vr))| {
        let i0 = sc.i0.row(y);
        let mut sw = vec![0.0f32; w];
        for j in covering(ys, ps, y) {
            for (i, &x0) in xs.iter().enumerate() {
                let k = j * nx + i;
                let f = flows[k];
                let (fx, fy) = (x0 as f32 + f[0], y as f32 + f[1]);
                let (bx, by) = (floor_f32(fx), floor_f32(fy));
                let (ax, ay) = (fx - bx, fy - by);
                let inside = bx >= 0.0 && by >= 0.0 && (bx as usize + ps) < w && (by as usize) + 1 < h;
                if inside && ps == 8 {
                    // The presets' patch side: the segment as one SIMD vector (the same operations
                    // per pixel as below, so the same values).
                    let (ix, iy) = (bx as usize, by as usize);
                    let (r0, r1) = (&d1[iy * w + ix..iy * w + ix + 9], &d1[(iy + 1) * w + ix..(iy + 1) * w + ix + 9]);
                    let (ax, ay) = (f32x8::splat(ax), f32x8::splat(ay));
                    let (bx, by) = (f32x8::ONE - ax, f32x8::ONE - ay);
                    let warped =
                        (lanes8(r0) * bx + lanes8(&r0[1..]) * ax) * by + (lanes8(r1) * bx + lanes8(&r1[1..]) * ax) * ay;
                    let residual = warped - lanes8(&i0[x0..]) - f32x8::splat(shifts[k]);
                    let wt = f32x8::ONE / residual.abs().max(f32x8::ONE);
                    let add = |acc: &mut [f32], v: f32x8| {
                        let acc = &mut acc[x0..x0 + 8];
                        acc.copy_from_slice(&(lanes8(acc) + v).to_array());
                    };
                    add(ur, wt * f32x8::splat(f[0]));
                    add(vr, wt * f32x8::splat(f[1]));
                    add(&mut sw, wt);
                    continue;
                }
                for dx in 0..ps {
                    let x = x0 + dx;
                    let warped = if inside {
                        let (ix, iy) = (bx as usize + dx, by as usize);
                        let (r0, r1) = (iy * w + ix, (iy + 1) * w + ix);
                        (d1[r0] * (1.0 - ax) + d1[r0 + 1] * ax) * (1.0 - ay)
                            + (d1[r1] * (1.0 - ax) + d1[r1 + 1] * ax) * ay
                    } else {
                        bilinear(sc.i1, fx + dx as f32, fy)
                    };
                    let wt = 1.0 / (warped - i0[x] - shifts[k]).abs().max(1.0);
                    ur[x] += wt * f[0];
                    vr[x] += wt * f[1];
                    sw[x] += wt;
                }
            }
        }
        for x in 0..w {
            if sw[x] > 0.0 {
                ur[x] /= sw[x];
                vr[x] /= sw[x];
            }
        }
    });
    (Img::from_vec(w, h, u).expect("sizes"), Img::from_vec(w, h, v).expect("sizes"))
}

/// Rows handed to one rayon task at least (small scales are not worth splitting finely).
const ROWS_PER_TASK: usize = 24;

impl Dis {
    /// The coarsest scale for an image of this size.
    fn coarsest(&self, w: usize, h: usize) -> usize {
        let p = &self.params;
        let auto = {
            let by_size = ((w.max(h) as f32 / (4.0 * p.patch_size as f32)).log2() + 0.5).floor().max(0.0) as usize;
            let by_min = (h.min(w) as f32 / p.patch_size as f32).log2().floor().max(0.0) as usize;
            by_size.min(by_min)
        };
        p.coarsest_scale.unwrap_or(auto).max(p.finest_scale)
    }

    /// Dense flow on the 0-255 scale images (no mask).
    fn compute(&self, from: &Gray, to: &Gray) -> Vec<[f32; 2]> {
        let p = &self.params;
        let (w, h) = from.dims();
        let coarsest = self.coarsest(w, h);
        // Pyramids on the 0-255 scale from scale `base` (the full resolution is only copied
        // when it is searched); `p0[s - base]` is scale `s`.
        let base = p.finest_scale.min(1);
        let first = |g: &Gray| {
            if base == 0 { par_image(w, h, |x, y| g.as_slice()[y * w + x] * 255.0) } else { halve_scaled(g, 255.0) }
        };
        let (a, b) = rayon::join(|| first(from), || first(to));
        let (mut p0, mut p1) = (vec![a], vec![b]);
        for _ in base + 1..=coarsest {
            let (a, b) = rayon::join(|| halve(p0.last().expect("one level")), || halve(p1.last().expect("one level")));
            p0.push(a);
            p1.push(b);
        }
        // Scales too small for one patch are skipped.
        let coarsest = (p.finest_scale..=coarsest)
            .rev()
            .find(|&s| p0[s - base].width() >= p.patch_size && p0[s - base].height() >= p.patch_size)
            .unwrap_or(p.finest_scale);
        let (cw, ch) = p0[coarsest - base].dims();
        let mut flow = (Img::filled(cw, ch, 0.0), Img::filled(cw, ch, 0.0));
        for s in (p.finest_scale..=coarsest).rev() {
            let (i0, i1) = (&p0[s - base], &p1[s - base]);
            let (sw, sh) = i0.dims();
            if flow.0.dims() != (sw, sh) {
                let finer = (upsample(&flow.0, sw, sh), upsample(&flow.1, sw, sh));
                recycle_pair(std::mem::replace(&mut flow, finer));
            }
            if sw < p.patch_size || sh < p.patch_size {
                continue;
            }
            let (i0x, i0y) = gradients(i0);
            let sobel_pair = (p.search_gradients == SearchGradients::OpencvSobel).then(|| sobel(i0));
            let (sx, sy) = sobel_pair.as_ref().map_or((&i0x, &i0y), |(x, y)| (x, y));
            let kernel = Kernel::detect();
            let sc = Scale { i0, i1, i0x: sx, i0y: sy, ps: p.patch_size, mean_norm: p.mean_normalization, kernel };
            let (xs, ys, flows, shifts) = patch_flows(&sc, &flow, p);
            recycle_pair(std::mem::replace(&mut flow, densify(&sc, &xs, &ys, &flows, &shifts)));
            refine(i0, i1, (&i0x, &i0y), &mut flow.0, &mut flow.1, p);
            recycle_pair((i0x, i0y));
            if let Some(pair) = sobel_pair {
                recycle_pair(pair);
            }
        }
        for img in p0.into_iter().chain(p1) {
            recycle(img.into_vec());
        }
        // Up to full resolution by doublings, the last one written in the output layout.
        loop {
            let (fw, fh) = flow.0.dims();
            let (nw, nh) = if fw * 2 >= w || fh * 2 >= h { (w, h) } else { (fw * 2, fh * 2) };
            if (nw, nh) == (w, h) {
                let out = resample_flow(&flow.0, &flow.1, w, h);
                recycle_pair(flow);
                return out;
            }
            let finer = (resample(&flow.0, nw, nh, 2.0), resample(&flow.1, nw, nh, 2.0));
            recycle_pair(std::mem::replace(&mut flow, finer));
        }
    }
}

impl FlowEstimator for Dis {
    fn name(&self) -> &str {
        "dis"
    }

    fn dense(&self, from: &Gray, to: &Gray, mask: Option<&Mask>) -> Result<FlowField, FlowError> {
        self.params.validate()?;
        check_pair(from, to, mask)?;
        let (w, h) = from.dims();
        // Run on a pool thread: the many short parallel loops are then forked from inside the
        // pool instead of each being injected into it (and the caller put to sleep) from outside.
        let flow = Grid::from_vec(w, h, rayon::scope(|_| self.compute(from, to))).expect("sizes");
        let valid = match mask {
            Some(m) => m.clone(),
            None => Mask::filled(w, h, true),
        };
        Ok(FlowField { flow, valid })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Patches warped across the border (the separable clamped taps) and inside it (shared
    /// weights) equal per-pixel clamped bilinear samples.
    #[test]
    fn warped_patches_equal_per_pixel_bilinear_samples() {
        let (w, h) = (40, 30);
        let i1 = Img::from_fn(w, h, |x, y| ((x * 7 + y * 13) % 17) as f32 + 0.1 * (x as f32 * 0.3).sin());
        let zeros = Img::filled(w, h, 0.0);
        let sc =
            Scale { i0: &zeros, i1: &i1, i0x: &zeros, i0y: &zeros, ps: 8, mean_norm: false, kernel: Kernel::detect() };
        let mut out = vec![0.0f32; 64];
        for (ox, oy, u, v) in
            [(0, 0, -2.3, -0.6), (32, 22, 0.4, 0.7), (32, 0, 3.9, -5.2), (10, 12, 1.25, -0.5), (5, 22, -7.5, 9.1)]
        {
            sc.warp(ox, oy, u, v, &mut out);
            for j in 0..8 {
                for i in 0..8 {
                    let want = bilinear(&i1, (ox + i) as f32 + u, (oy + j) as f32 + v);
                    let got = out[j * 8 + i];
                    assert!((got - want).abs() <= 1e-5 * want.abs().max(1.0), "({ox}, {oy}) + ({u}, {v}) at {i}, {j}");
                }
            }
        }
    }

    /// The one-pass residual sums of interior 8x8 patches equal the sums over the warped patch
    /// formed pixel by pixel, and the search's mean-normalised SSD equals the two-pass one.
    #[test]
    fn fused_patch_sums_equal_per_pixel_sums() {
        let (w, h) = (40, 30);
        let i0 = Img::from_fn(w, h, |x, y| ((x * 5 + y * 11) % 23) as f32 + 2.0 * (y as f32 * 0.2).cos());
        let i1 = Img::from_fn(w, h, |x, y| ((x * 7 + y * 13) % 17) as f32 + 0.1 * (x as f32 * 0.3).sin());
        let (gx, gy) = gradients(&i0);
        let sc = Scale { i0: &i0, i1: &i1, i0x: &gx, i0y: &gy, ps: 8, mean_norm: true, kernel: Kernel::detect() };
        let mut buf = vec![0.0f32; 64];
        for (ox, oy, u, v, centre) in [(10, 12, 1.25, -0.5, 0.0), (20, 5, -3.7, 2.2, 1.5), (3, 20, 0.1, 0.9, -4.0)] {
            let t = sc.template(ox, oy);
            let got = sc.residual_sums(&t, ox, oy, [u, v], centre, &mut buf);
            let mut want = [0.0f64; 4];
            for j in 0..8 {
                for i in 0..8 {
                    let r = bilinear(&i1, (ox + i) as f32 + u, (oy + j) as f32 + v) as f64
                        - t.values[j * 8 + i] as f64
                        - centre as f64;
                    want[0] += r;
                    want[1] += r * r;
                    want[2] += t.gx[j * 8 + i] as f64 * r;
                    want[3] += t.gy[j * 8 + i] as f64 * r;
                }
            }
            for (g, w) in got.iter().zip(want) {
                assert!((*g as f64 - w).abs() <= 1e-4 * w.abs().max(1.0), "({ox}, {oy}): {got:?} vs {want:?}");
            }
            let mean = want[0] / 64.0;
            let two_pass = want[1] - 64.0 * mean * mean;
            let ssd = sc.ssd(&t, ox, oy, [u, v], &mut buf) as f64;
            assert!((ssd - two_pass).abs() <= 1e-3 * two_pass.max(1.0), "({ox}, {oy}): {ssd} vs {two_pass}");
        }
    }

    /// The row kernels equal the per-pixel definitions with replicated borders: central
    /// differences (one-sided at the ends) and OpenCV's unnormalised 3x3 Sobel.
    #[test]
    fn gradient_kernels_equal_their_per_pixel_definitions() {
        for (w, h) in [(9, 7), (2, 3), (1, 4)] {
            let img = Img::from_fn(w, h, |x, y| ((x * 7 + y * 13) % 11) as f32 + 0.3 * (x * y) as f32);
            let at =
                |x: isize, y: isize| *img.at(x.clamp(0, w as isize - 1) as usize, y.clamp(0, h as isize - 1) as usize);
            let (gx, gy) = gradients(&img);
            let (sx, sy) = sobel(&img);
            for y in 0..h as isize {
                for x in 0..w as isize {
                    let span = |c: isize, n: usize| ((c + 1).min(n as isize - 1) - (c - 1).max(0)).max(1) as f32;
                    let cx = (at(x + 1, y) - at(x - 1, y)) / span(x, w);
                    let cy = (at(x, y + 1) - at(x, y - 1)) / span(y, h);
                    let sobel_x = (at(x + 1, y - 1) - at(x - 1, y - 1))
                        + 2.0 * (at(x + 1, y) - at(x - 1, y))
                        + (at(x + 1, y + 1) - at(x - 1, y + 1));
                    let sobel_y = (at(x - 1, y + 1) - at(x - 1, y - 1))
                        + 2.0 * (at(x, y + 1) - at(x, y - 1))
                        + (at(x + 1, y + 1) - at(x + 1, y - 1));
                    let (ux, uy) = (x as usize, y as usize);
                    assert_eq!(*gx.at(ux, uy), cx, "{w}x{h} gx at ({x}, {y})");
                    assert_eq!(*gy.at(ux, uy), cy, "{w}x{h} gy at ({x}, {y})");
                    assert_eq!(*sx.at(ux, uy), sobel_x, "{w}x{h} sobel x at ({x}, {y})");
                    assert_eq!(*sy.at(ux, uy), sobel_y, "{w}x{h} sobel y at ({x}, {y})");
                }
            }
        }
    }

    /// The exact-doubling fast path of a resampled row equals the general bilinear taps.
    #[test]
    fn doubled_rows_equal_the_general_taps() {
        for n in [2usize, 3, 8, 13] {
            let (top, bottom): (Vec<f32>, Vec<f32>) = (0..n).map(|i| ((i as f32 * 1.7).sin(), i as f32 * 0.3)).unzip();
            let columns = taps(n, 2 * n);
            let (mut blended, mut out) = (vec![0.0; n], vec![0.0; 2 * n]);
            resample_row((&top, &bottom, 0.25), &columns, 2.0, &mut blended, &mut out);
            for (x, &([x0, x1], fx)) in columns.iter().enumerate() {
                let row = |i: usize| top[i] * 0.75 + bottom[i] * 0.25;
                let want = 2.0 * (row(x0) * (1.0 - fx) + row(x1) * fx);
                assert!((out[x] - want).abs() <= 1e-6 * want.abs().max(1.0), "n {n}, column {x}: {} vs {want}", out[x]);
            }
        }
    }

    /// The fused final upsampling writes what resampling each component does.
    #[test]
    fn interleaved_resampling_equals_per_component_resampling() {
        let u = Img::from_fn(13, 7, |x, y| (x as f32 * 0.7).sin() + y as f32);
        let v = Img::from_fn(13, 7, |x, y| (y as f32 * 0.4).cos() - x as f32);
        let (w, h) = (26, 15);
        let both = resample_flow(&u, &v, w, h);
        let (ru, rv) = (resample(&u, w, h, 2.0), resample(&v, w, h, 15.0 / 7.0));
        for (k, f) in both.iter().enumerate() {
            assert!((f[0] - ru.as_slice()[k]).abs() < 1e-5 && (f[1] - rv.as_slice()[k]).abs() < 1e-5, "pixel {k}");
        }
    }
}
