//! Test clouds and transforms for the registration tests.
#![allow(dead_code)]

use flowfilter_depth::cloud::knn_normals;
use flowfilter_geometry::{Point3, PointCloud, Pose, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// A bumpy, asymmetric closed surface about 10-14 cm across, sampled with `n` points, with
/// outward normals from k-NN PCA.
pub fn bumpy_shape(n: usize, seed: u64) -> PointCloud {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let points: Vec<Point3> = (0..n)
        .map(|_| {
            let z: f64 = rng.random_range(-1.0..1.0);
            let phi: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            let theta = z.acos();
            let r = 1.0 + 0.25 * (3.0 * theta).sin() * (2.0 * phi).cos() + 0.15 * (phi + 0.5).sin();
            let s = (1.0 - z * z).sqrt();
            Point3::new(0.07 * r * s * phi.cos(), 0.05 * r * s * phi.sin(), 0.06 * r * z + 0.01 * phi.cos())
        })
        .collect();
    let centroid = points.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n as f64;
    let mut normals = knn_normals(&points, 12, &Point3::origin());
    // Orient outwards (away from the centroid) rather than towards a viewpoint.
    for (nrm, p) in normals.iter_mut().zip(&points) {
        if nrm.dot(&(p.coords - centroid)) < 0.0 {
            *nrm = -*nrm;
        }
    }
    PointCloud { points, normals: Some(normals), colors: None, pixels: None }
}

/// A random rigid transform with rotation angle up to `max_deg` about a random axis and
/// translation up to `max_t` metres.
pub fn random_transform(rng: &mut ChaCha8Rng, max_deg: f64, max_t: f64) -> Pose {
    let axis =
        Vector3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)).normalize();
    let angle = rng.random_range(0.3 * max_deg..=max_deg).to_radians();
    let dir =
        Vector3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)).normalize();
    Pose::new(dir * rng.random_range(0.0..=max_t), axis * angle)
}

/// Rotation error (degrees) and translation error (metres) of `est` against `truth`.
pub fn errors(est: &Pose, truth: &Pose) -> (f64, f64) {
    let d = est * truth.inverse();
    (d.rotation.angle().to_degrees(), (est.translation.vector - truth.translation.vector).norm())
}

/// `cloud` moved by `t`, with Gaussian noise of `sigma` metres and `outlier_fraction * n` extra
/// uniform outliers in the bounding box grown by 5 cm.
pub fn corrupted(cloud: &PointCloud, t: &Pose, sigma: f64, outlier_fraction: f64, seed: u64) -> PointCloud {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = cloud.transformed(t);
    if sigma > 0.0 {
        let noise = Normal::new(0.0, sigma).unwrap();
        for p in &mut out.points {
            *p += Vector3::new(noise.sample(&mut rng), noise.sample(&mut rng), noise.sample(&mut rng));
        }
    }
    let extra = (outlier_fraction * cloud.len() as f64) as usize;
    if extra > 0 {
        let (lo, hi) = out
            .points
            .iter()
            .fold((Vector3::repeat(f64::INFINITY), Vector3::repeat(f64::NEG_INFINITY)), |(lo, hi), p| {
                (lo.inf(&p.coords), hi.sup(&p.coords))
            });
        let normals = out.normals.as_mut();
        let mut new_normals = vec![];
        for _ in 0..extra {
            let p = Vector3::new(
                rng.random_range(lo.x - 0.05..hi.x + 0.05),
                rng.random_range(lo.y - 0.05..hi.y + 0.05),
                rng.random_range(lo.z - 0.05..hi.z + 0.05),
            );
            out.points.push(Point3::from(p));
            new_normals.push(Vector3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), 1.0).normalize());
        }
        if let Some(n) = normals {
            n.extend(new_normals);
        }
    }
    out
}
