//! The patch search's inner loop: warp an 8 x 8 patch of the second image (one set of bilinear
//! weights), subtract the template and reduce `[sum r, sum r^2, sum gx r, sum gy r]`, in one pass
//! with a patch row per SIMD vector. Portable 8-lane vectors (`wide`) everywhere, 256-bit AVX2
//! where the CPU has it (detected at run time). Both accumulate every lane with the same
//! operations in the same order and reduce the lanes in the same fixed order, so they give the
//! same bits.

use wide::f32x8;

/// Eight consecutive values as one portable vector.
#[inline(always)]
pub(super) fn lanes8(s: &[f32]) -> f32x8 {
    f32x8::new(s[..8].try_into().expect("eight values"))
}

/// Sum of eight lanes in a fixed order (pairs, then pairs of pairs).
#[inline(always)]
fn reduce(l: [f32; 8]) -> f32 {
    ((l[0] + l[4]) + (l[2] + l[6])) + ((l[1] + l[5]) + (l[3] + l[7]))
}

/// One patch's inputs: the image block under the patch, the bilinear weights and the template.
#[derive(Clone, Copy)]
pub(super) struct PatchInputs<'a> {
    /// The second image from the patch's top-left sample (at least 8 rows of stride `w` plus
    /// 9 values).
    pub block: &'a [f32],
    /// Row length of the image.
    pub w: usize,
    /// Bilinear weights `[w00, w10, w01, w11]`.
    pub weights: [f32; 4],
    /// Template values and gradients (64 each).
    pub values: &'a [f32],
    pub gx: &'a [f32],
    pub gy: &'a [f32],
    /// Subtracted from every residual.
    pub centre: f32,
}

/// Which implementation runs the patch sums.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Kernel {
    /// `wide` vectors (SSE2 on x86-64).
    Portable,
    /// 256-bit AVX2 vectors.
    #[cfg(target_arch = "x86_64")]
    Avx2,
}

impl Kernel {
    /// The fastest kernel this CPU runs.
    pub(super) fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            return Self::Avx2;
        }
        Self::Portable
    }

    /// `[sum r, sum r^2, sum gx r, sum gy r]` of the residual `r = warped - template - centre`.
    #[inline]
    pub(super) fn sums(self, p: &PatchInputs<'_>) -> [f32; 4] {
        match self {
            Self::Portable => portable(p),
            // SAFETY: `Avx2` is only chosen by `detect` on a CPU with AVX2.
            #[cfg(target_arch = "x86_64")]
            Self::Avx2 => unsafe { avx2(p) },
        }
    }
}

/// The portable kernel.
#[inline]
fn portable(p: &PatchInputs<'_>) -> [f32; 4] {
    let w = p.w;
    let [w00, w10, w01, w11] = p.weights.map(f32x8::splat);
    let c = f32x8::splat(p.centre);
    let (mut sr, mut sq, mut sx, mut sy) = (f32x8::ZERO, f32x8::ZERO, f32x8::ZERO, f32x8::ZERO);
    for j in 0..8 {
        let (r0, r1) = (&p.block[j * w..j * w + 9], &p.block[(j + 1) * w..(j + 1) * w + 9]);
        let warped = (w00 * lanes8(r0) + w10 * lanes8(&r0[1..])) + (w01 * lanes8(r1) + w11 * lanes8(&r1[1..]));
        let k = j * 8;
        let r = warped - lanes8(&p.values[k..]) - c;
        sr += r;
        sq += r * r;
        sx += lanes8(&p.gx[k..]) * r;
        sy += lanes8(&p.gy[k..]) * r;
    }
    [sr, sq, sx, sy].map(|v| reduce(v.to_array()))
}

/// The AVX2 kernel: the portable kernel's operations on 256-bit registers (no fused
/// multiply-add, so the same roundings).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn avx2(p: &PatchInputs<'_>) -> [f32; 4] {
    use std::arch::x86_64::*;
    let load = |s: &[f32]| {
        let a: &[f32; 8] = s[..8].try_into().expect("eight values");
        // SAFETY: `a` is eight valid, initialised floats; the load is unaligned.
        unsafe { _mm256_loadu_ps(a.as_ptr()) }
    };
    let w = p.w;
    let [w00, w10, w01, w11] = p.weights.map(|v| _mm256_set1_ps(v));
    let c = _mm256_set1_ps(p.centre);
    let z = _mm256_setzero_ps();
    let (mut sr, mut sq, mut sx, mut sy) = (z, z, z, z);
    for j in 0..8 {
        let (r0, r1) = (&p.block[j * w..j * w + 9], &p.block[(j + 1) * w..(j + 1) * w + 9]);
        let top = _mm256_add_ps(_mm256_mul_ps(w00, load(r0)), _mm256_mul_ps(w10, load(&r0[1..])));
        let bottom = _mm256_add_ps(_mm256_mul_ps(w01, load(r1)), _mm256_mul_ps(w11, load(&r1[1..])));
        let k = j * 8;
        let r = _mm256_sub_ps(_mm256_sub_ps(_mm256_add_ps(top, bottom), load(&p.values[k..])), c);
        sr = _mm256_add_ps(sr, r);
        sq = _mm256_add_ps(sq, _mm256_mul_ps(r, r));
        sx = _mm256_add_ps(sx, _mm256_mul_ps(load(&p.gx[k..]), r));
        sy = _mm256_add_ps(sy, _mm256_mul_ps(load(&p.gy[k..]), r));
    }
    let lanes = |v: __m256| {
        let mut out = [0.0f32; 8];
        // SAFETY: `out` has room for eight floats; the store is unaligned.
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), v) };
        reduce(out)
    };
    [lanes(sr), lanes(sq), lanes(sx), lanes(sy)]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every kernel this CPU runs gives the sums of the per-pixel definition, and the same
    /// bits as the portable kernel.
    #[test]
    fn kernels_agree_with_the_definition_and_each_other() {
        let w = 23;
        let image: Vec<f32> = (0..w * 12).map(|k| ((k * 37) % 101) as f32 * 0.7 + (k as f32 * 0.1).sin()).collect();
        let template: Vec<f32> = (0..192).map(|k| ((k * 13) % 29) as f32 - 9.5).collect();
        for (bx, by, fx, fy, centre) in
            [(0, 0, 0.3f32, 0.6f32, 0.0f32), (13, 2, 0.9, 0.05, 2.5), (5, 3, 0.0, 0.0, -1.0)]
        {
            let weights = [(1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy];
            let inputs = PatchInputs {
                block: &image[by * w + bx..],
                w,
                weights,
                values: &template[..64],
                gx: &template[64..128],
                gy: &template[128..],
                centre,
            };
            let mut want = [0.0f64; 4];
            for j in 0..8 {
                for i in 0..8 {
                    let at = |x: usize, y: usize| image[(by + y) * w + bx + x] as f64;
                    let warped = weights[0] as f64 * at(i, j)
                        + weights[1] as f64 * at(i + 1, j)
                        + weights[2] as f64 * at(i, j + 1)
                        + weights[3] as f64 * at(i + 1, j + 1);
                    let r = warped - template[j * 8 + i] as f64 - centre as f64;
                    want[0] += r;
                    want[1] += r * r;
                    want[2] += template[64 + j * 8 + i] as f64 * r;
                    want[3] += template[128 + j * 8 + i] as f64 * r;
                }
            }
            let portable = Kernel::Portable.sums(&inputs);
            for (g, w) in portable.iter().zip(want) {
                assert!((*g as f64 - w).abs() <= 1e-4 * w.abs().max(1.0), "{portable:?} vs {want:?}");
            }
            assert_eq!(Kernel::detect().sums(&inputs), portable, "the detected kernel's bits");
        }
    }
}
