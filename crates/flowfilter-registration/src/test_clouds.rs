//! Seeded random clouds for the unit tests (a linear congruential generator: no dependency, the
//! same points on every platform).

use flowfilter_geometry::Point3;

/// `n` points uniform in the box `[0, extent.0] x [0, extent.1] x [0, extent.2]`, seeded.
pub(crate) fn uniform_box(n: usize, seed: u64, extent: (f64, f64, f64)) -> Vec<Point3> {
    let mut s = seed;
    let mut r = || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..n).map(|_| Point3::new(r() * extent.0, r() * extent.1, r() * extent.2)).collect()
}
