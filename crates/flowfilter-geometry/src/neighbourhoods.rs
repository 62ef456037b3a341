//! Every point's neighbours within one fixed radius, found once, for warm-started nearest-neighbour
//! queries.
//!
//! Iterative methods (ICP above all) ask for the nearest point of the same cloud again and again
//! from queries that barely move. When a query `q` is known to lie at distance `d` from an indexed
//! point `j` (its previous answer), its nearest point lies within `d` of `q`, so within `2 d` of
//! `j` (triangle inequality): if `2 d` is at most the radius, the nearest point is `j` or one of
//! `j`'s listed neighbours, and scanning that short list answers the query exactly, without a
//! k-d tree descent.

use crate::{Neighbour, Point3, RadiusGrid};

/// Relative margin kept below the radius when certifying a query, far above the rounding of the
/// distances involved: a query on the very edge of the certified ball is handed back rather than
/// answered from a list that rounding might have cut one point short.
const MARGIN: f64 = 1e-9;

/// For each point of a cloud, the other points within a fixed radius (in no particular order).
#[derive(Debug, Clone)]
pub struct Neighbourhoods {
    radius: f64,
    /// Point `i`'s lists are at position `slot[i]` (the grid's cell order).
    slot: Vec<u32>,
    /// `starts[s]..starts[s + 1]`: the run of the neighbours of the point at position `s`.
    starts: Vec<u32>,
    /// Neighbour indices, point by point.
    members: Vec<u32>,
}

impl Neighbourhoods {
    /// The neighbourhoods of radius `radius` of `points`; `None` when [`RadiusGrid::new`] cannot
    /// grid them (radius not positive and finite, no points, a non-finite point, too many cells)
    /// or the lists would not fit `u32` offsets.
    pub fn new(points: &[Point3], radius: f64) -> Option<Self> {
        let (slot, starts, members) = RadiusGrid::new(points, radius)?.all_within()?;
        Some(Self { radius, slot, starts, members })
    }

    /// The radius the lists were built for.
    pub fn radius(&self) -> f64 {
        self.radius
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.slot.len()
    }

    /// Whether there are no points.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The points other than `i` within the radius of point `i` (in no particular order).
    pub fn of(&self, i: usize) -> &[u32] {
        let s = self.slot[i] as usize;
        &self.members[self.starts[s] as usize..self.starts[s + 1] as usize]
    }

    /// The point of `points` (the cloud the lists were built from) nearest to `q`, given that
    /// point `from` lies at squared distance `from_dist2` from `q`; `None` when that distance is
    /// too large for the lists to certify the answer (`2 d` above the radius), in which case the
    /// caller must search otherwise (e.g. [`crate::KnnIndex::nearest`]). Among points at exactly
    /// the same distance the first scanned is returned (`from` first).
    pub fn nearest_from(&self, points: &[Point3], q: &Point3, from: usize, from_dist2: f64) -> Option<Neighbour> {
        if from_dist2.is_nan() || 4.0 * from_dist2 > self.radius * self.radius * (1.0 - MARGIN) {
            return None;
        }
        let mut best = Neighbour { index: from, dist2: from_dist2 };
        for &m in self.of(from) {
            let d2 = (points[m as usize] - q).norm_squared();
            if d2 < best.dist2 {
                best = Neighbour { index: m as usize, dist2: d2 };
            }
        }
        Some(best)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A noisy, curved surface sampled irregularly.
    fn surface(n: usize) -> Vec<Point3> {
        (0..n)
            .map(|i| {
                let (u, v) = ((i as f64 * 0.618_034).fract(), (i as f64 * 0.754_878).fract());
                let noise = ((i as f64) * 12.9898).sin().fract() * 4e-4;
                Point3::new(0.1 * u, 0.1 * v, 0.02 * (6.0 * u).sin() * (4.0 * v).cos() + noise)
            })
            .collect()
    }

    #[test]
    fn lists_hold_exactly_the_points_within_the_radius() {
        let pts = surface(1500);
        let radius = 0.006;
        let nb = Neighbourhoods::new(&pts, radius).unwrap();
        assert_eq!(nb.len(), pts.len());
        assert_eq!(nb.radius(), radius);
        for i in (0..pts.len()).step_by(7) {
            let mut got = nb.of(i).to_vec();
            got.sort_unstable();
            let want: Vec<u32> = (0..pts.len() as u32)
                .filter(|&j| j as usize != i && (pts[j as usize] - pts[i]).norm_squared() <= radius * radius)
                .collect();
            assert_eq!(got, want, "point {i}");
        }
        assert!(Neighbourhoods::new(&[], radius).is_none());
        assert!(Neighbourhoods::new(&pts, -1.0).is_none());
    }

    #[test]
    fn warm_queries_are_answered_exactly_or_handed_back() {
        let pts = surface(3000);
        let nb = Neighbourhoods::new(&pts, 0.008).unwrap();
        let brute = |q: &Point3| {
            (0..pts.len()).map(|j| ((pts[j] - q).norm_squared(), j)).min_by(|a, b| a.0.total_cmp(&b.0)).unwrap()
        };
        let (mut answered, mut handed_back) = (0, 0);
        for i in 0..400 {
            let t = i as f64;
            // Queries near the surface, each warm-started from some point close to it.
            let q = pts[(i * 7) % pts.len()] + nalgebra::Vector3::new(t.sin(), t.cos(), (0.3 * t).sin()) * 2.5e-3;
            let from = (i * 7 + i % 3) % pts.len();
            let d2 = (pts[from] - q).norm_squared();
            match nb.nearest_from(&pts, &q, from, d2) {
                Some(n) => {
                    let (bd2, bj) = brute(&q);
                    assert_eq!((n.index, n.dist2), (bj, bd2), "query {i}");
                    answered += 1;
                }
                None => {
                    assert!(4.0 * d2 > 0.008 * 0.008 * (1.0 - MARGIN));
                    handed_back += 1;
                }
            }
        }
        // Both branches are exercised.
        assert!(answered > 100 && handed_back > 10, "{answered} answered, {handed_back} handed back");
    }
}
