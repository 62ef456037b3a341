//! Rounding and exponentials without libm calls. On baseline x86-64 (no SSE4.1 `round`
//! instructions) `f32::floor` and `f64::floor` compile to calls into libm that are not inlined;
//! the per-pixel and per-point loops of the rasteriser, the optical flow and the permutohedral
//! lattice call these instead. [`exp`] is an inlinable, branch-free `e^x` for kernel weights
//! evaluated by the million (loops of it vectorise; libm's is an opaque call per value).

/// `x.floor()`, exact for `|x| < 2^31` (every image coordinate); larger values and NaN go
/// through `f32::floor`.
#[inline]
pub fn floor_f32(x: f32) -> f32 {
    if x.is_nan() || x.abs() >= 2_147_483_648.0 {
        return x.floor();
    }
    let t = x as i32 as f32;
    if t > x { t - 1.0 } else { t }
}

/// `x.ceil()` (see [`floor_f32`]).
#[inline]
pub fn ceil_f32(x: f32) -> f32 {
    -floor_f32(-x)
}

/// `x.floor()` as an integer, for `|x| < 2^63` (saturating beyond, as `as` casts do).
#[inline]
pub fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    t - ((t as f64) > x) as i64
}

/// `1 / k!` for `k = 0..=13`: the Taylor coefficients of `e^r` (each `k!` is exact in `f64`,
/// so each coefficient is the correctly rounded quotient).
const INV_FACTORIALS: [f64; 14] = {
    let mut c = [1.0; 14];
    let mut factorial = 1.0;
    let mut k = 1;
    while k < 14 {
        factorial *= k as f64;
        c[k] = 1.0 / factorial;
        k += 1;
    }
    c
};

/// `e^x`, within 2 ulp of the correctly rounded value over the whole `f64` range (within 1 ulp
/// of libm's on the tests' samples), subnormal results included; `+inf` above 709.78, `0` below
/// -745.13, NaN for NaN. Branch-free and inlinable, so loops of it vectorise.
///
/// `x = k ln 2 + r` with `k` the nearest integer to `x / ln 2` and `|r| <= ln 2 / 2` (Cody-Waite:
/// `ln 2` split in a high part with trailing zero bits, so `k ln2_hi` is exact, and a low part);
/// `e^r` is its Taylor polynomial of degree 13 (truncation error below `2^-57` relative on that
/// interval), evaluated by Estrin's scheme; `2^k` is applied as two exact power-of-two factors,
/// so results near the range ends neither overflow nor flush early.
#[inline(always)]
pub fn exp(x: f64) -> f64 {
    // ln 2 = LN2_HI + LN2_LO: LN2_HI has 21 trailing zero bits (k ln2_hi exact for |k| < 2^21),
    // LN2_LO is the double nearest ln 2 - LN2_HI (not `LN_2 - LN2_HI`, which would carry LN_2's
    // own rounding error, 2e-17, into r, multiplied by k: hundreds of ulp near the range ends).
    const LN2_HI: f64 = f64::from_bits(0x3fe6_2e42_fee0_0000);
    const LN2_LO: f64 = f64::from_bits(0x3dea_39ef_3579_3c76);
    // Adding 1.5 * 2^52 rounds to an integer, which then sits in the low mantissa bits.
    const SHIFTER: f64 = 6_755_399_441_055_744.0;
    // Beyond these every result is 0 or +inf; clamping keeps `k` small (NaN passes through).
    let x = x.clamp(-746.0, 710.0);
    let shifted = x * std::f64::consts::LOG2_E + SHIFTER;
    let kf = shifted - SHIFTER;
    let k = shifted.to_bits().wrapping_sub(SHIFTER.to_bits()) as i64;
    let r = (x - kf * LN2_HI) - kf * LN2_LO;
    // Estrin's scheme for the terms of degree 2 and up (a dependency chain of 4 multiply-adds
    // instead of Horner's 12: the loops that call this are latency-bound), then `1 + (r + ...)`
    // so that the leading terms are rounded once.
    let c = &INV_FACTORIALS;
    let (r2, r4) = (r * r, (r * r) * (r * r));
    let pair = |i: usize| c[i] + c[i + 1] * r;
    let tail = (pair(2) + pair(4) * r2) + (pair(6) + pair(8) * r2) * r4 + (pair(10) + pair(12) * r2) * (r4 * r4);
    let p = 1.0 + (r + r2 * tail);
    // 2^k as 2^k1 * 2^k2 with k1 = floor(k / 2): both factors are normal numbers for every
    // clamped x, and multiplying by a power of two is exact until the result is subnormal.
    let k1 = k >> 1;
    let k2 = k - k1;
    let scale = |e: i64| f64::from_bits(((e + 1023) as u64) << 52);
    p * scale(k1) * scale(k2)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Distance in units in the last place between two finite non-negative values.
    fn ulps(a: f64, b: f64) -> u64 {
        a.to_bits().abs_diff(b.to_bits())
    }

    #[test]
    fn exp_is_within_two_ulp_of_libm_everywhere() {
        let mut seed = 11u64;
        let mut uniform = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut worst = 0;
        // The kernel-weight range densely, then the whole range, then the subnormal tail.
        for (lo, hi, n) in [(-8.0, 0.0, 200_000), (-745.0, 709.7, 200_000), (-745.1, -708.0, 20_000)] {
            for _ in 0..n {
                let x = lo + (hi - lo) * uniform();
                let (got, want) = (exp(x), x.exp());
                // Subnormal results carry fewer bits: compare them absolutely.
                if want < f64::MIN_POSITIVE {
                    assert!((got - want).abs() <= 2.0 * f64::from_bits(1), "exp({x}) = {got}, libm {want}");
                } else {
                    worst = worst.max(ulps(got, want));
                }
            }
        }
        assert!(worst <= 2, "worst error {worst} ulp");
    }

    #[test]
    fn exp_special_values() {
        assert_eq!(exp(0.0), 1.0);
        assert_eq!(exp(-0.0), 1.0);
        assert!(ulps(exp(1.0), std::f64::consts::E) <= 1);
        assert_eq!(exp(f64::NEG_INFINITY), 0.0);
        assert_eq!(exp(-746.0), 0.0);
        assert_eq!(exp(f64::INFINITY), f64::INFINITY);
        assert_eq!(exp(709.8), f64::INFINITY);
        assert!(exp(709.78).is_finite());
        assert!(exp(-745.0) > 0.0);
        assert!(exp(f64::NAN).is_nan());
    }

    #[test]
    fn agree_with_libm() {
        let values =
            [-3.5f32, -3.0, -2.9999, -0.5, -0.0, 0.0, 1e-7, 0.5, 1.0, 2.5, 1023.999, 1e6 + 0.5, -1e6 - 0.25, 3e9, -3e9];
        for v in values {
            assert_eq!(floor_f32(v), v.floor(), "floor {v}");
            assert_eq!(ceil_f32(v), v.ceil(), "ceil {v}");
            assert_eq!(floor_i64(f64::from(v)), f64::from(v).floor() as i64, "floor_i64 {v}");
        }
        assert!(floor_f32(f32::NAN).is_nan());
        assert_eq!(floor_f32(f32::INFINITY), f32::INFINITY);
    }
}
