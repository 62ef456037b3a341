//! Voxel aggregation of point sets for the coarse FilterReg iterations.
//!
//! While the kernel is wide (sigma several times the point spacing) the filtered sums hardly
//! change when the points of a small voxel are replaced by their centroid carrying their summed
//! values: the relative kernel error is about `h^2 / (4 sigma^2)` for voxels of edge `h`, below
//! the permutohedral lattice's own. Merging cuts the points the lattice splats and slices (and
//! the M-step visits) from thousands to hundreds. Levels double the voxel edge, so each is built
//! from the one below by merging eight voxels.

use flowfilter_geometry::fastmath::floor_i64;
use flowfilter_geometry::{Point3, Vector3, radix_order};

/// One level: merged points with their point counts, spreads and summed values.
#[derive(Debug, Clone)]
pub(crate) struct AggregateLevel {
    /// Voxel edge, metres.
    pub edge: f64,
    /// Centroids of the merged points.
    pub points: Vec<Point3>,
    /// How many input points each centroid stands for.
    pub counts: Vec<f64>,
    /// `sum |p - centroid|^2` over the merged points (invariant under rigid motions).
    pub spreads: Vec<f64>,
    /// Summed per-point values, `vd` per centroid.
    pub values: Vec<f64>,
    /// Integer voxel coordinates of each centroid at this edge.
    keys: Vec<[i64; 3]>,
}

/// Levels of doubling voxel edge, finest first.
#[derive(Debug, Clone)]
pub(crate) struct Pyramid {
    /// The levels, finest first.
    pub levels: Vec<AggregateLevel>,
}

/// Merges entries that share a key (after `keys` have been coarsened): sorted by key, so the
/// result does not depend on hashing or thread scheduling.
fn merge(
    edge: f64,
    vd: usize,
    keys: Vec<[i64; 3]>,
    points: &[Point3],
    counts: &[f64],
    spreads: &[f64],
    values: &[f64],
) -> AggregateLevel {
    let order = sorted_by_key(&keys);
    let mut out =
        AggregateLevel { edge, points: vec![], counts: vec![], spreads: vec![], values: vec![], keys: vec![] };
    let mut start = 0;
    while start < order.len() {
        let key = keys[order[start] as usize];
        let mut end = start;
        while end < order.len() && keys[order[end] as usize] == key {
            end += 1;
        }
        let members = &order[start..end];
        let n: f64 = members.iter().map(|&i| counts[i as usize]).sum();
        let centroid =
            members.iter().fold(Vector3::zeros(), |a, &i| a + points[i as usize].coords * counts[i as usize]) / n;
        // Parallel-axis theorem: each member's own spread plus its count times its offset^2.
        let spread: f64 = members
            .iter()
            .map(|&i| spreads[i as usize] + counts[i as usize] * (points[i as usize].coords - centroid).norm_squared())
            .sum();
        let base = out.values.len();
        out.values.resize(base + vd, 0.0);
        for &i in members {
            for (a, v) in out.values[base..].iter_mut().zip(&values[i as usize * vd..(i as usize + 1) * vd]) {
                *a += v;
            }
        }
        out.points.push(Point3::from(centroid));
        out.counts.push(n);
        out.spreads.push(spread);
        out.keys.push(key);
        start = end;
    }
    out
}

/// Indices `0..keys.len()` sorted by `(key, index)`. Keys whose offsets from the smallest fit in
/// 64 bits together (each axis packed in as many bits as its range needs: every cloud below
/// about two million voxels across) are packed into one `u64` and radix-sorted (stable, so equal
/// keys keep their index order), several times faster than comparing `[i64; 3]` keys through the
/// index; the order is the same either way.
fn sorted_by_key(keys: &[[i64; 3]]) -> Vec<u32> {
    let lo = keys.iter().fold([i64::MAX; 3], |m, k| [m[0].min(k[0]), m[1].min(k[1]), m[2].min(k[2])]);
    let hi = keys.iter().fold([i64::MIN; 3], |m, k| [m[0].max(k[0]), m[1].max(k[1]), m[2].max(k[2])]);
    // Bits each axis's offsets need (0 for an empty set or a constant axis).
    let width = |a: usize| {
        let range = (hi[a] as i128) - (lo[a] as i128);
        if range <= 0 { 0 } else { 128 - range.leading_zeros() }
    };
    let w = [width(0), width(1), width(2)];
    if w.iter().sum::<u32>() > 64 {
        let mut order: Vec<u32> = (0..keys.len() as u32).collect();
        order.sort_unstable_by_key(|&i| (keys[i as usize], i));
        return order;
    }
    // Lexicographic order of [k0, k1, k2] == numeric order of k0 | k1 | k2 (high to low bits).
    let pack = |k: &[i64; 3]| {
        let field = |a: usize| k[a].wrapping_sub(lo[a]) as u64;
        // A shift by 64 only happens for an empty field (width 0, value 0).
        let shifted = |a: usize, by: u32| field(a).checked_shl(by).unwrap_or(0);
        shifted(0, w[1] + w[2]) | shifted(1, w[2]) | field(2)
    };
    let packed: Vec<u64> = keys.iter().map(pack).collect();
    radix_order(packed, w.iter().sum())
}

impl Pyramid {
    /// Levels with voxel edges `finest * 2^l` (voxels aligned on the origin) while a level still
    /// merges: construction stops once a level holds fewer than `min_points` centroids.
    /// `values` holds `vd` values per point (may be empty with `vd = 0`).
    pub fn new(points: &[Point3], values: &[f64], vd: usize, finest: f64, min_points: usize) -> Self {
        let key = |p: &Point3| [floor_i64(p.x / finest), floor_i64(p.y / finest), floor_i64(p.z / finest)];
        let ones = vec![1.0; points.len()];
        let zeros = vec![0.0; points.len()];
        let mut levels = vec![merge(finest, vd, points.iter().map(key).collect(), points, &ones, &zeros, values)];
        loop {
            let last = levels.last().expect("one level");
            if last.points.len() < min_points.max(2) {
                break;
            }
            // floor(x / 2h) == floor(floor(x / h) / 2): arithmetic shift floors negatives too.
            let keys = last.keys.iter().map(|k| [k[0] >> 1, k[1] >> 1, k[2] >> 1]).collect();
            let next = merge(2.0 * last.edge, vd, keys, &last.points, &last.counts, &last.spreads, &last.values);
            levels.push(next);
        }
        Self { levels }
    }

    /// The coarsest level whose voxel edge is at most `max_edge`, if any.
    pub fn level_for(&self, max_edge: f64) -> Option<&AggregateLevel> {
        self.levels.iter().rev().find(|l| l.edge <= max_edge)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The packed radix sort and the plain one agree, on small and medium keys and on keys too far
    /// apart to pack.
    #[test]
    fn packed_key_sort_is_the_plain_sort() {
        let plain = |keys: &[[i64; 3]]| {
            let mut order: Vec<u32> = (0..keys.len() as u32).collect();
            order.sort_unstable_by_key(|&i| (keys[i as usize], i));
            order
        };
        let mut s = 7u64;
        let mut next = |m: i64| {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 33) as i64 % (2 * m)) - m
        };
        let small: Vec<[i64; 3]> = (0..3000).map(|_| [next(20), next(20), next(20)]).collect();
        assert_eq!(sorted_by_key(&small), plain(&small));
        // Several radix passes (15 bits per axis), constant axes, no keys, one key.
        let medium: Vec<[i64; 3]> = (0..3000).map(|_| [next(1 << 14), next(1 << 14), next(1 << 14)]).collect();
        assert_eq!(sorted_by_key(&medium), plain(&medium));
        let flat: Vec<[i64; 3]> = (0..500).map(|_| [next(3), 7, next(3)]).collect();
        assert_eq!(sorted_by_key(&flat), plain(&flat));
        assert!(sorted_by_key(&[]).is_empty());
        assert_eq!(sorted_by_key(&[[5, -2, 9]]), vec![0]);
        // 64 bits in all, one axis constant.
        let full: Vec<[i64; 3]> = (0..300).map(|_| [4, next(1 << 31), next(1 << 31)]).collect();
        assert_eq!(sorted_by_key(&full), plain(&full));
        let mut wide = small.clone();
        wide[17] = [1 << 40, -5, 3];
        wide[99] = [-(1 << 40), 2, 1 << 30];
        assert_eq!(sorted_by_key(&wide), plain(&wide));
    }

    fn cloud(n: usize) -> Vec<Point3> {
        (0..n)
            .map(|i| {
                let t = i as f64 * 0.01;
                Point3::new(0.1 * t.sin() - 0.03, 0.07 * (1.7 * t).cos(), 0.02 * (0.3 * t).sin() - 0.01)
            })
            .collect()
    }

    /// Every level keeps the total count, the summed values, the centroid and the second moment
    /// of the whole set, and no voxel of a level is wider than its edge.
    #[test]
    fn levels_preserve_counts_sums_and_moments() {
        let pts = cloud(3000);
        let values: Vec<f64> = pts.iter().flat_map(|p| [1.0, p.x, p.y, p.z, p.coords.norm_squared()]).collect();
        let pyramid = Pyramid::new(&pts, &values, 5, 0.002, 10);
        assert!(pyramid.levels.len() >= 4, "{} levels", pyramid.levels.len());
        let n = pts.len() as f64;
        let mean = pts.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
        let second: f64 = pts.iter().map(|p| (p.coords - mean).norm_squared()).sum();
        let total: Vec<f64> = (0..5).map(|c| values.iter().skip(c).step_by(5).sum()).collect();
        for level in &pyramid.levels {
            assert!((level.counts.iter().sum::<f64>() - n).abs() < 1e-9);
            let m = level.points.iter().zip(&level.counts).fold(Vector3::zeros(), |a, (p, c)| a + p.coords * *c) / n;
            assert!((m - mean).norm() < 1e-12);
            // Total second moment = spreads + counts * offsets^2 of the centroids.
            let s: f64 = level
                .points
                .iter()
                .zip(&level.counts)
                .zip(&level.spreads)
                .map(|((p, c), s)| s + c * (p.coords - mean).norm_squared())
                .sum();
            assert!((s - second).abs() < 1e-9 * second);
            for (c, want) in total.iter().enumerate() {
                let got: f64 = level.values.iter().skip(c).step_by(5).sum();
                assert!((got - want).abs() < 1e-9 * want.abs().max(1.0), "value {c}: {got} vs {want}");
            }
            // A voxel's members lie within the voxel: the spread per member is below 3 edge^2.
            for (s, c) in level.spreads.iter().zip(&level.counts) {
                assert!(*s <= 3.0 * level.edge * level.edge * c + 1e-15);
            }
        }
        // Coarser levels merge: strictly fewer points, and the choice of level follows the edge.
        for w in pyramid.levels.windows(2) {
            assert!(w[1].points.len() < w[0].points.len());
            assert_eq!(w[1].edge, 2.0 * w[0].edge);
        }
        assert_eq!(pyramid.level_for(0.0019).map(|l| l.edge), None);
        assert_eq!(pyramid.level_for(0.0079).map(|l| l.edge), Some(0.004));
    }
}
