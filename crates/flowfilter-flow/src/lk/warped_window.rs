//! The samples of a warped Lucas-Kanade window: the guided tracks' windows in the second image
//! are warped by the predicted motion's local linear map, so every sample has its own bilinear
//! weights. Eight samples of a row at a time: positions, weights and the bilinear blend in one
//! 8-lane vector (`wide`), the four image values of each gathered one by one. Each lane does
//! the scalar tap's arithmetic ([`BilinearTap`]) in the same order, so the samples are the same
//! bits; lanes outside the image's interior (where the tap clamps) take the scalar tap itself.
//!
//! Measured on `cargo xtask bench-speed --sections pipeline --methods flowfilter --no-peers
//! --threads 1`: the warped windows' samples were a fifth of the pipeline's time, taken one
//! tap at a time.

use super::{BilinearTap, Gray, WindowWarp};
use wide::f32x8;

/// Lanes per vector.
const LANES: usize = 8;

/// A warped window's offsets: sample `(i, j)` (column `i`, row `j` of a `side x side` window
/// centred on `(ox, oy)`) lies at `(ox + m0 u + m1 v, oy + m2 u + m3 v)`, `u = i - r`,
/// `v = j - r`, summed in that order.
pub(super) struct WarpedWindow {
    warp: WindowWarp,
    side: usize,
    /// `m0 u` and `m2 u` per column.
    columns: (Vec<f32>, Vec<f32>),
    /// `m1 v` and `m3 v` per row.
    rows: Vec<(f32, f32)>,
    /// The last samples, row-major.
    samples: Vec<f32>,
}

impl WarpedWindow {
    /// The window of half-size `r` warped by `m`.
    pub(super) fn new(m: WindowWarp, r: isize) -> Self {
        let side = 2 * r as usize + 1;
        let rf = r as f32;
        let offset = |k: usize| k as f32 - rf;
        Self {
            warp: m,
            side,
            columns: ((0..side).map(|i| m[0] * offset(i)).collect(), (0..side).map(|i| m[2] * offset(i)).collect()),
            rows: (0..side).map(|j| (m[1] * offset(j), m[3] * offset(j))).collect(),
            samples: vec![0.0; side * side],
        }
    }

    /// The warp.
    pub(super) fn warp(&self) -> WindowWarp {
        self.warp
    }

    /// The window's samples of `img` about `(ox, oy)`, row-major: those of
    /// `BilinearTap::new(.., x, y).sample(img)` at each sample's position.
    pub(super) fn sample(&mut self, img: &Gray, ox: f32, oy: f32) -> &[f32] {
        let (w, h) = img.dims();
        let data = img.as_slice();
        let side = self.side;
        let full = side - side % LANES;
        let (cx, cy) = (&self.columns.0, &self.columns.1);
        for (row, &(rx, ry)) in self.samples.chunks_exact_mut(side).zip(&self.rows) {
            for start in (0..full).step_by(LANES) {
                let xs = (f32x8::splat(ox) + lanes(&cx[start..])) + f32x8::splat(rx);
                let ys = (f32x8::splat(oy) + lanes(&cy[start..])) + f32x8::splat(ry);
                let out = &mut row[start..start + LANES];
                if interior(xs, ys, w, h) {
                    out.copy_from_slice(&interior_samples(data, w, xs, ys));
                } else {
                    for ((o, x), y) in out.iter_mut().zip(xs.to_array()).zip(ys.to_array()) {
                        *o = BilinearTap::new(w, h, x, y).sample(data);
                    }
                }
            }
            for i in full..side {
                let (x, y) = ((ox + cx[i]) + rx, (oy + cy[i]) + ry);
                row[i] = BilinearTap::new(w, h, x, y).sample(data);
            }
        }
        &self.samples
    }
}

/// Eight consecutive values.
#[inline(always)]
fn lanes(s: &[f32]) -> f32x8 {
    f32x8::new(s[..LANES].try_into().expect("eight values"))
}

/// Whether every lane lies where [`BilinearTap::new`] takes its interior tap:
/// `0 <= x < w - 1` and `0 <= y < h - 1`.
#[inline(always)]
fn interior(xs: f32x8, ys: f32x8, w: usize, h: usize) -> bool {
    let zero = f32x8::ZERO;
    let inside = xs.simd_ge(zero)
        & ys.simd_ge(zero)
        & xs.simd_lt(f32x8::splat((w - 1) as f32))
        & ys.simd_lt(f32x8::splat((h - 1) as f32));
    inside.all()
}

/// The interior taps' samples: truncation is the floor there, the weights are the fractions,
/// blended as [`BilinearTap::sample`] does.
#[inline(always)]
fn interior_samples(data: &[f32], w: usize, xs: f32x8, ys: f32x8) -> [f32; LANES] {
    // Truncated as integers and back, as the scalar tap's `x as usize` (a `-0.0` keeps its
    // fraction's sign that way).
    let (ix, iy) = (xs.trunc_int(), ys.trunc_int());
    let (fx, fy) = (xs - f32x8::from_i32x8(ix), ys - f32x8::from_i32x8(iy));
    let (ix, iy) = (ix.to_array(), iy.to_array());
    let (mut a, mut b, mut c, mut d) = ([0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES]);
    for l in 0..LANES {
        let k = iy[l] as usize * w + ix[l] as usize;
        let top = &data[k..k + 2];
        let bottom = &data[k + w..k + w + 2];
        (a[l], b[l], c[l], d[l]) = (top[0], top[1], bottom[0], bottom[1]);
    }
    let one = f32x8::ONE;
    let (a, b, c, d) = (f32x8::new(a), f32x8::new(b), f32x8::new(c), f32x8::new(d));
    ((a * (one - fx) + b * fx) * (one - fy) + (c * (one - fx) + d * fx) * fy).to_array()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Windows warped by rotations, scales and shears, inside the image, across its borders and
    /// beyond them: every sample is the scalar clamped tap's, to the bit.
    #[test]
    fn samples_are_the_scalar_taps() {
        let img = Gray::from_fn(37, 29, |x, y| ((x * 7 + y * 13) % 17) as f32 / 17.0 + 0.01 * x as f32);
        let warps: [WindowWarp; 4] =
            [[1.0, 0.0, 0.0, 1.0], [0.97, -0.26, 0.26, 0.97], [1.3, 0.1, -0.2, 0.8], [0.5, 0.7, -0.6, 1.1]];
        for m in warps {
            for r in [1isize, 4, 6, 10] {
                let mut window = WarpedWindow::new(m, r);
                for (ox, oy) in
                    [(18.3f32, 14.7f32), (2.2, 3.9), (35.6, 27.1), (-4.5, 12.0), (20.0, 40.25), (9.999, 0.001)]
                {
                    let samples = window.sample(&img, ox, oy).to_vec();
                    let rf = r as f32;
                    let side = 2 * r as usize + 1;
                    for j in 0..side {
                        let v = j as f32 - rf;
                        for i in 0..side {
                            let u = i as f32 - rf;
                            let (x, y) = (ox + m[0] * u + m[1] * v, oy + m[2] * u + m[3] * v);
                            let expected = BilinearTap::new(37, 29, x, y).sample(img.as_slice());
                            assert_eq!(
                                samples[j * side + i].to_bits(),
                                expected.to_bits(),
                                "{m:?} r {r} at ({ox}, {oy}) sample ({i}, {j})"
                            );
                        }
                    }
                }
            }
        }
    }
}
