//! Rounding without libm calls. On baseline x86-64 (no SSE4.1 `round` instructions) `f32::floor`
//! and `f64::floor` compile to calls into libm that are not inlined; the per-pixel and per-point
//! loops of the rasteriser, the optical flow and the permutohedral lattice call these instead.

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

#[cfg(test)]
mod tests {
    use super::*;

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
