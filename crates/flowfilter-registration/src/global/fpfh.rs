//! Fast Point Feature Histograms (Rusu, Blodow and Beetz, ICRA 2009), as Open3D's
//! `compute_fpfh_feature` computes them (the same values within 2e-3, test
//! `tests/fpfh_open3d.rs`): a 33-bin description of the surface's shape around
//! each point, from the angles between its normal and its neighbours' normals, that does not
//! change when the cloud moves.

use flowfilter_geometry::{KnnIndex, Neighbour, Point3, PointCloud, Vector3};
use rayon::prelude::*;

/// Bins of each of the three angle histograms.
const BINS: usize = 11;
/// Length of a descriptor: three histograms of `BINS` bins.
pub const FPFH_LEN: usize = 3 * BINS;

/// A point's FPFH descriptor (three histograms of 11 bins, each summing to about 200 where the
/// point has neighbours).
pub type Fpfh = [f32; FPFH_LEN];

/// The FPFH descriptor of every point of `cloud` (which must hold a finite normal for every
/// point and finite points; `None` otherwise),
/// from its neighbours within `radius` metres, at most `max_neighbours` of them (the nearest:
/// Open3D's `KDTreeSearchParamHybrid`). A point without a neighbour gets a descriptor of zeros.
///
/// # Examples
///
/// ```
/// use flowfilter_registration::global::fpfh_features;
/// use flowfilter_registration::{Point3, PointCloud, Vector3};
///
/// // A gently curved sheet, normals up.
/// let points: Vec<Point3> = (0..400).map(|i| {
///     let (x, y) = ((i % 20) as f64 * 0.005, (i / 20) as f64 * 0.005);
///     Point3::new(x, y, 0.5 + 2.0 * x * x)
/// }).collect();
/// let normals = points.iter().map(|p| Vector3::new(-4.0 * p.x, 0.0, 1.0).normalize()).collect();
/// let cloud = PointCloud { points, normals: Some(normals), ..Default::default() };
/// let features = fpfh_features(&cloud, 0.02, 100).expect("normals");
/// assert_eq!(features.len(), 400);
/// // Each of the three histograms of a point with neighbours sums to 200.
/// let sum: f32 = features[210][..11].iter().sum();
/// assert!((sum - 200.0).abs() < 1e-3);
/// ```
pub fn fpfh_features(cloud: &PointCloud, radius: f64, max_neighbours: usize) -> Option<Vec<Fpfh>> {
    cloud.validate().ok()?;
    let normals = cloud.normals.as_ref().filter(|ns| ns.iter().all(|n| n.iter().all(|c| c.is_finite())))?;
    let points = &cloud.points;
    let index = KnnIndex::new(points);
    let neighbourhoods: Vec<Vec<Neighbour>> =
        points.par_iter().map(|p| neighbours(&index, p, radius, max_neighbours)).collect();
    let simple: Vec<Fpfh> =
        (0..points.len()).into_par_iter().map(|i| simple_histogram(points, normals, i, &neighbourhoods[i])).collect();
    Some((0..points.len()).into_par_iter().map(|i| weighted_histogram(&simple, i, &neighbourhoods[i])).collect())
}

/// The points within `radius` of `p` (itself included), the nearest `max_neighbours` of them,
/// nearest first.
fn neighbours(index: &KnnIndex, p: &Point3, radius: f64, max_neighbours: usize) -> Vec<Neighbour> {
    let mut found = index.within(p, radius);
    found.sort_by(|a, b| a.dist2.total_cmp(&b.dist2).then(a.index.cmp(&b.index)));
    found.truncate(max_neighbours);
    found
}

/// The simplified point feature histogram (SPFH) of point `i`: the three angles of each pair
/// with its neighbours, binned, each neighbour counting `100 / neighbours`.
fn simple_histogram(points: &[Point3], normals: &[Vector3], i: usize, neighbours: &[Neighbour]) -> Fpfh {
    let mut h = [0.0f32; FPFH_LEN];
    let others: Vec<usize> = neighbours.iter().map(|n| n.index).filter(|&j| j != i).collect();
    if others.is_empty() {
        return h;
    }
    let increment = 100.0 / others.len() as f64;
    for j in others {
        // A degenerate pair (coincident points, a normal along the line) counts as zero
        // angles, as in Open3D.
        let angles = pair_angles(&points[i], &normals[i], &points[j], &normals[j]).unwrap_or([0.0; 3]);
        add_bins(&mut h, angles, increment);
    }
    h
}

/// Adds `increment` to the bin of each of the three angles: the first in `[-pi, pi]`, the
/// others in `[-1, 1]`.
fn add_bins(h: &mut Fpfh, [alpha, phi, theta]: [f64; 3], increment: f64) {
    let bin = |v: f64| (v.floor().max(0.0) as usize).min(BINS - 1);
    let b = BINS as f64;
    h[bin(b * (alpha + std::f64::consts::PI) / std::f64::consts::TAU)] += increment as f32;
    h[BINS + bin(b * (phi + 1.0) * 0.5)] += increment as f32;
    h[2 * BINS + bin(b * (theta + 1.0) * 0.5)] += increment as f32;
}

/// The FPFH of point `i`: its SPFH plus its neighbours' SPFHs weighted by the inverse of their
/// squared distance, each of the three histograms of the neighbours' sum scaled to 100.
fn weighted_histogram(simple: &[Fpfh], i: usize, neighbours: &[Neighbour]) -> Fpfh {
    let mut h = [0.0f64; FPFH_LEN];
    let mut sums = [0.0f64; 3];
    for n in neighbours.iter().filter(|n| n.index != i && n.dist2 > 0.0) {
        for (k, v) in simple[n.index].iter().enumerate() {
            let value = f64::from(*v) / n.dist2;
            h[k] += value;
            sums[k / BINS] += value;
        }
    }
    let mut out = [0.0f32; FPFH_LEN];
    for (k, o) in out.iter_mut().enumerate() {
        let s = sums[k / BINS];
        let scaled = if s > 0.0 { h[k] * 100.0 / s } else { h[k] };
        *o = (scaled + f64::from(simple[i][k])) as f32;
    }
    out
}

/// The Darboux frame angles of a pair of oriented points, the source chosen as the point whose
/// normal makes the smaller angle with the line between them: `(alpha, phi, theta)` = (the turn
/// of the second normal about the frame's `v` axis, `v . n2`, `n1 . d / |d|`). `None` when the
/// points coincide or the first normal lies along the line.
fn pair_angles(p1: &Point3, n1: &Vector3, p2: &Point3, n2: &Vector3) -> Option<[f64; 3]> {
    let mut d = p2 - p1;
    let dist = d.norm();
    if dist == 0.0 {
        return None;
    }
    let (a1, a2) = (n1.dot(&d) / dist, n2.dot(&d) / dist);
    let (u, n_other, theta) = if a1.abs().acos() > a2.abs().acos() {
        d = -d;
        (n2, n1, -a2)
    } else {
        (n1, n2, a1)
    };
    let v = d.cross(u);
    let v_norm = v.norm();
    if v_norm == 0.0 {
        return None;
    }
    let v = v / v_norm;
    let w = u.cross(&v);
    let phi = v.dot(n_other);
    let alpha = w.dot(n_other).atan2(u.dot(n_other));
    Some([alpha, phi, theta])
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowfilter_geometry::Pose;

    /// A bumpy patch: a sum of two waves, with its analytic normals.
    fn bumpy(n: usize) -> PointCloud {
        let height = |x: f64, y: f64| 0.01 * (x * 40.0).sin() * (y * 30.0).cos();
        let (points, normals) = (0..n * n)
            .map(|i| {
                let (x, y) = ((i % n) as f64 * 0.004, (i / n) as f64 * 0.004);
                let (dx, dy) = (0.4 * (x * 40.0).cos() * (y * 30.0).cos(), -0.3 * (x * 40.0).sin() * (y * 30.0).sin());
                (Point3::new(x, y, 0.6 + height(x, y)), Vector3::new(-dx, -dy, 1.0).normalize())
            })
            .unzip();
        PointCloud { points, normals: Some(normals), ..Default::default() }
    }

    #[test]
    fn the_features_do_not_change_when_the_cloud_moves() {
        let cloud = bumpy(30);
        let pose = Pose::new(nalgebra::Vector3::new(0.1, -0.2, 0.3), nalgebra::Vector3::new(0.4, -0.7, 1.1));
        let moved = PointCloud {
            points: cloud.points.iter().map(|p| pose * p).collect(),
            normals: cloud.normals.as_ref().map(|ns| ns.iter().map(|n| pose.rotation * n).collect()),
            ..Default::default()
        };
        let (a, b) = (fpfh_features(&cloud, 0.021, 100).unwrap(), fpfh_features(&moved, 0.021, 100).unwrap());
        let worst = a.iter().zip(&b).map(|(x, y)| x.iter().zip(y).map(|(u, v)| (u - v).abs()).fold(0.0, f32::max));
        let worst = worst.fold(0.0, f32::max);
        assert!(worst < 1e-2, "{worst}");
    }

    #[test]
    fn different_shapes_get_different_features() {
        let cloud = bumpy(30);
        let f = fpfh_features(&cloud, 0.02, 100).unwrap();
        // A crest (where the surface bends most) against a saddle's flank.
        let at = |x: usize, y: usize| f[y * 30 + x];
        let distance = |a: Fpfh, b: Fpfh| a.iter().zip(&b).map(|(u, v)| (u - v) * (u - v)).sum::<f32>().sqrt();
        let (crest, flank) = (at(10, 15), at(15, 7));
        assert!(distance(crest, flank) > 20.0, "{}", distance(crest, flank));
        // Nearly the same place, nearly the same feature.
        assert!(distance(crest, at(10, 15)) < 1e-6);
    }

    #[test]
    fn a_cloud_without_usable_normals_has_no_features() {
        let cloud = PointCloud { points: bumpy(5).points, ..Default::default() };
        assert!(fpfh_features(&cloud, 0.02, 100).is_none());
        let mut short = bumpy(5);
        short.normals.as_mut().unwrap().pop();
        assert!(fpfh_features(&short, 0.02, 100).is_none());
        let mut nan = bumpy(5);
        nan.normals.as_mut().unwrap()[3].x = f64::NAN;
        assert!(fpfh_features(&nan, 0.02, 100).is_none());
    }
}
