//! Pieces shared by the Gaussian-mixture methods (CPD, FilterReg).

use flowfilter_geometry::Point3;

/// The mean squared distance over all pairs, `1/(M N) sum_m sum_n |x_n - y_m|^2`, computed in
/// O(M + N) from first and second moments (no all-pairs matrix): the initial sigma^2 of CPD
/// times the dimension.
pub fn mean_pair_distance2(a: &[Point3], b: &[Point3]) -> f64 {
    let moments = |v: &[Point3]| {
        let n = v.len() as f64;
        let mean = v.iter().fold(nalgebra::Vector3::zeros(), |s, p| s + p.coords) / n;
        let sq = v.iter().map(|p| p.coords.norm_squared()).sum::<f64>() / n;
        (mean, sq)
    };
    let (ma, sa) = moments(a);
    let (mb, sb) = moments(b);
    sa + sb - 2.0 * ma.dot(&mb)
}

/// The uniform-outlier term of the GMM posterior with unnormalised Gaussian kernels in 3-D:
/// `(2 pi sigma^2)^(3/2) * w / (1 - w) * components / observations` (Myronenko & Song 2010, eq. 7).
pub fn outlier_term(sigma2: f64, w: f64, components: usize, observations: usize) -> f64 {
    if w <= 0.0 {
        return 0.0;
    }
    (2.0 * std::f64::consts::PI * sigma2).powf(1.5) * w / (1.0 - w) * components as f64 / observations as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moment_formula_equals_all_pairs() {
        let a: Vec<Point3> =
            (0..30).map(|i| Point3::new((i as f64).sin(), (i as f64 * 0.3).cos(), i as f64 * 0.01)).collect();
        let b: Vec<Point3> =
            (0..20).map(|i| Point3::new((i as f64 * 0.7).cos(), 0.1 * i as f64, -(i as f64 * 0.2).sin())).collect();
        let brute: f64 = a.iter().flat_map(|p| b.iter().map(move |q| (p - q).norm_squared())).sum::<f64>() / 600.0;
        assert!((mean_pair_distance2(&a, &b) - brute).abs() < 1e-12);
    }
}
