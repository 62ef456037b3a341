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

#[cfg(test)]
mod tests {
    use super::*;

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
            let k: Vec<usize> = index.k_nearest(&q, 5).iter().map(|n| n.index).collect();
            assert_eq!(k, brute[..5].iter().map(|b| b.1).collect::<Vec<_>>());
            let mut w: Vec<usize> = index.within(&q, 0.3).iter().map(|n| n.index).collect();
            w.sort_unstable();
            let mut expected: Vec<usize> = brute.iter().filter(|b| b.0 <= 0.09).map(|b| b.1).collect();
            expected.sort_unstable();
            assert_eq!(w, expected);
        }
        assert!(KnnIndex::new(&[]).nearest(&Point3::origin()).is_none());
        assert_eq!(KnnIndex::new(&pts[..3]).k_nearest(&Point3::origin(), 10).len(), 3);
    }
}
