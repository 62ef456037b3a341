//! Nearest-neighbour queries over 3-D points (a thin wrapper over kiddo's immutable k-d tree).

use crate::Point3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use std::num::NonZero;

/// A k-d tree over a fixed set of points; indices refer to the slice it was built from.
pub struct KnnIndex {
    tree: Option<ImmutableKdTree<f64, 3>>,
    len: usize,
}

/// A neighbour: index into the indexed points and squared distance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Neighbour {
    /// Index of the point.
    pub index: usize,
    /// Squared Euclidean distance.
    pub dist2: f64,
}

impl KnnIndex {
    /// Build the index. Non-finite points must have been rejected by the caller.
    pub fn new(points: &[Point3]) -> Self {
        let coords: Vec<[f64; 3]> = points.iter().map(|p| [p.x, p.y, p.z]).collect();
        let tree = if coords.is_empty() { None } else { ImmutableKdTree::new_from_slice(&coords).ok() };
        Self { tree, len: points.len() }
    }

    /// Number of indexed points.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether no point is indexed.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The nearest indexed point (`None` if the index is empty).
    pub fn nearest(&self, p: &Point3) -> Option<Neighbour> {
        let tree = self.tree.as_ref()?;
        let r = tree.query(&[p.x, p.y, p.z]).nearest_one::<SquaredEuclidean<f64>>().execute();
        Some(Neighbour { index: r.item as usize, dist2: r.distance })
    }

    /// All indexed points within `radius` (unordered).
    pub fn within(&self, p: &Point3, radius: f64) -> Vec<Neighbour> {
        let Some(tree) = self.tree.as_ref() else { return vec![] };
        tree.query(&[p.x, p.y, p.z])
            .within::<SquaredEuclidean<f64>>(radius * radius)
            .unsorted()
            .execute()
            .into_iter()
            .map(|r| Neighbour { index: r.item as usize, dist2: r.distance })
            .collect()
    }

    /// The median, over a strided sample of about `samples` of `points` (the indexed points), of
    /// the distance from a point to its `k`-th nearest indexed point, the point itself counting as
    /// the first (`k = 2`: the nearest other point). A cloud's typical spacing at the scale of
    /// `k` neighbours; `None` when there is nothing to sample.
    pub fn median_neighbour_distance(&self, points: &[Point3], k: usize, samples: usize) -> Option<f64> {
        let step = (points.len() / samples.max(1)).max(1);
        let mut d: Vec<f64> =
            points.iter().step_by(step).filter_map(|y| self.k_nearest(y, k).last().map(|n| n.dist2.sqrt())).collect();
        let mid = d.len() / 2;
        (!d.is_empty()).then(|| *d.select_nth_unstable_by(mid, f64::total_cmp).1)
    }

    /// The `k` nearest indexed points, nearest first (fewer if the index is smaller).
    pub fn k_nearest(&self, p: &Point3, k: usize) -> Vec<Neighbour> {
        let (Some(tree), Some(k)) = (self.tree.as_ref(), NonZero::new(k.min(self.len))) else { return vec![] };
        tree.query(&[p.x, p.y, p.z])
            .nearest_n::<SquaredEuclidean<f64>>(k)
            .execute()
            .into_iter()
            .map(|r| Neighbour { index: r.item as usize, dist2: r.distance })
            .collect()
    }
}

/// Spread the low 10 bits of `v` to every third bit.
fn spread3(v: u32) -> u32 {
    let mut x = v & 0x3ff;
    x = (x | (x << 16)) & 0x0300_00ff;
    x = (x | (x << 8)) & 0x0300_f00f;
    x = (x | (x << 4)) & 0x030c_30c3;
    (x | (x << 2)) & 0x0924_9249
}

/// A spatially coherent visiting order of `points`: indices sorted by the Morton (Z-order) code of
/// the points quantised to 1024 steps per axis of their bounding box. Queries issued in this order
/// walk neighbouring branches of a k-d tree one after the other, which keeps them in cache;
/// rigid motions preserve the coherence, so the order can be computed once per cloud.
/// Non-finite points sort last.
pub fn spatial_order(points: &[Point3]) -> Vec<u32> {
    let (mut lo, mut hi) = (Point3::from([f64::INFINITY; 3]), Point3::from([f64::NEG_INFINITY; 3]));
    for p in points.iter().filter(|p| p.coords.iter().all(|c| c.is_finite())) {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    let code = |p: &Point3| -> u32 {
        if !p.coords.iter().all(|c| c.is_finite()) {
            return u32::MAX;
        }
        let q = |i: usize| {
            let extent = hi[i] - lo[i];
            if extent > 0.0 { ((p[i] - lo[i]) / extent * 1023.0) as u32 } else { 0 }
        };
        spread3(q(0)) | (spread3(q(1)) << 1) | (spread3(q(2)) << 2)
    };
    // Ties (equal codes) in index order, as a sort of (code, index) pairs would give.
    crate::radix_order(points.iter().map(|p| u64::from(code(p))).collect(), 32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_neighbour_distance_is_the_grid_spacing() {
        // A 20 x 20 grid of spacing 2 mm: every point's nearest other point is 2 mm away.
        let pts: Vec<Point3> =
            (0..400).map(|i| Point3::new((i % 20) as f64 * 0.002, (i / 20) as f64 * 0.002, 0.0)).collect();
        let index = KnnIndex::new(&pts);
        let d = index.median_neighbour_distance(&pts, 2, 64).unwrap();
        assert!((d - 0.002).abs() < 1e-12, "{d}");
        // The 9th nearest (self, 4 edge neighbours, 4 diagonal ones) of an interior point: 2 mm * sqrt 2.
        let d9 = index.median_neighbour_distance(&pts, 9, 64).unwrap();
        assert!((d9 - 0.002 * 2f64.sqrt()).abs() < 1e-12, "{d9}");
        assert!(KnnIndex::new(&[]).median_neighbour_distance(&[], 2, 64).is_none());
    }

    #[test]
    fn matches_brute_force() {
        let pts: Vec<Point3> = (0..500)
            .map(|i| Point3::new((i as f64 * 0.731).sin(), (i as f64 * 1.37).cos(), (i as f64 * 0.19).sin()))
            .collect();
        let index = KnnIndex::new(&pts);
        for q in [Point3::new(0.1, 0.2, 0.3), Point3::new(-0.9, 0.5, 0.0)] {
            let mut brute: Vec<(f64, usize)> =
                pts.iter().enumerate().map(|(i, p)| ((p - q).norm_squared(), i)).collect();
            brute.sort_by(|a, b| a.0.total_cmp(&b.0));
            assert_eq!(index.nearest(&q).unwrap().index, brute[0].1);
            // Bounded: found when the bound reaches it (exactly at the bound too), else none.
            let k: Vec<usize> = index.k_nearest(&q, 5).iter().map(|n| n.index).collect();
            assert_eq!(k, brute[..5].iter().map(|b| b.1).collect::<Vec<_>>());
            let mut w: Vec<usize> = index.within(&q, 0.3).iter().map(|n| n.index).collect();
            w.sort_unstable();
            let mut expected: Vec<usize> = brute.iter().filter(|b| b.0 <= 0.09).map(|b| b.1).collect();
            expected.sort_unstable();
            assert_eq!(w, expected);
        }
        assert!(KnnIndex::new(&[]).nearest(&Point3::origin()).is_none());
        // The spatial order is a permutation; along a line it is the order along the line,
        // and non-finite points come last.
        let mut line: Vec<Point3> = (0..50).map(|i| Point3::new(((i * 37) % 50) as f64, 0.0, 0.0)).collect();
        line.push(Point3::new(f64::NAN, 0.0, 0.0));
        let order = spatial_order(&line);
        let xs: Vec<f64> = order[..50].iter().map(|&i| line[i as usize].x).collect();
        assert_eq!(xs, (0..50).map(f64::from).collect::<Vec<_>>());
        assert_eq!(order[50], 50);
        let mut sorted = spatial_order(&pts);
        sorted.sort_unstable();
        assert_eq!(sorted, (0..500).collect::<Vec<u32>>());
        assert_eq!(KnnIndex::new(&pts[..3]).k_nearest(&Point3::origin(), 10).len(), 3);
    }
}
