//! Fixed-radius neighbour search on a uniform grid: all points within `r` of a query, for one
//! radius chosen at construction. With cells of edge `r` or more a query visits at most 3 x 3 x 3 cells,
//! nine contiguous runs of a cell-sorted copy of the points; for the dense neighbourhoods of
//! surface scans (tens of points per query) this is several times cheaper than a k-d tree's
//! descent and result collection.

use crate::fastmath::floor_i64;
use crate::{Neighbour, Point3};
use rayon::prelude::*;
use std::ops::Range;

/// Non-empty cells per parallel task of [`RadiusGrid::all_within`].
const CELLS_PER_TASK: usize = 64;

/// Cells per axis beyond which [`RadiusGrid::nearest_within`] hands a search back.
const MAX_NEAREST_SPAN: usize = 4;

/// Grids never have more cells than this (see [`RadiusGrid::new`]).
const MAX_CELLS: usize = 1 << 22;

/// A grid has at most this many cells per point (and at least [`MIN_CELL_BUDGET`] cells
/// allowed): finer grids are coarsened. Zeroing, summing and copying an array of millions of
/// cells for a few thousand points cost more than the queries it served (the pipeline's
/// FilterReg at small sigma built grids of up to 3.6 million cells for 5000 points).
const CELLS_PER_POINT: usize = 16;

/// See [`CELLS_PER_POINT`].
const MIN_CELL_BUDGET: usize = 1 << 12;

/// The factor by which the cell edge grows until the grid fits its budget...
const CELL_GROWTH: f64 = 1.25;

/// ...up to this many radii; beyond that the points are too spread for a grid (`None`).
const MAX_CELL_IN_RADII: f64 = 4.0;

/// Points bucketed in cubic cells of edge `radius` (or somewhat more, see [`RadiusGrid::new`]).
pub struct RadiusGrid {
    origin: Point3,
    radius: f64,
    /// The cells' edge: the radius, or more where a grid of that edge would be mostly empty.
    cell: f64,
    dims: [usize; 3],
    /// `starts[c]..starts[c + 1]`: the run of cell `c` in `order` and `coords`.
    starts: Vec<u32>,
    /// Indices of the points (into the slice the grid was built from), cell by cell.
    order: Vec<u32>,
    /// Their coordinates, in the same order.
    coords: Vec<[f64; 3]>,
}

impl RadiusGrid {
    /// The grid over `points` for queries of radius `radius`; `None` when the radius is not
    /// positive and finite, there are no points, or a point is not finite. Where cells of edge
    /// `radius` would number more than 16 per point (at least 4096, at most about four
    /// million), the edge is widened until they do not; `None` (use a k-d tree then) when that
    /// takes an edge of more than 4 radii (points spread far beyond the radius).
    pub fn new(points: &[Point3], radius: f64) -> Option<Self> {
        if !(radius.is_finite() && radius > 0.0) || points.is_empty() || u32::try_from(points.len()).is_err() {
            return None;
        }
        let (mut lo, mut hi) = (points[0], points[0]);
        for p in points {
            if !p.coords.iter().all(|c| c.is_finite()) {
                return None;
            }
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        // Cells of edge `radius`, widened while there would be many more cells than points (a
        // surface fills few of a fine grid's cells, and every cell costs in the build).
        let budget = (CELLS_PER_POINT * points.len()).clamp(MIN_CELL_BUDGET, MAX_CELLS);
        let mut cell = radius;
        let (dims, cells) = loop {
            let dims = [0, 1, 2].map(|a| ((hi[a] - lo[a]) / cell).floor() + 1.0);
            let cells = dims.iter().product::<f64>();
            if cells <= budget as f64 {
                break (dims.map(|n| n as usize), cells as usize);
            }
            cell *= CELL_GROWTH;
            if cell > MAX_CELL_IN_RADII * radius {
                return None;
            }
        };
        let cell_of = |p: &Point3| -> usize {
            let c = |a: usize| (((p[a] - lo[a]) / cell) as usize).min(dims[a] - 1);
            (c(2) * dims[1] + c(1)) * dims[0] + c(0)
        };
        // Counting sort by cell (stable: ascending point index within a cell). Counted one slot
        // ahead, `starts[c + 1]` is cell c's first slot after the prefix sum, and its end once
        // the cell's points are placed, which is where cell c + 1 starts.
        let mut starts = vec![0u32; cells + 2];
        let cell_index: Vec<usize> = points.iter().map(cell_of).collect();
        for &c in &cell_index {
            starts[c + 2] += 1;
        }
        for c in 0..cells {
            starts[c + 2] += starts[c + 1];
        }
        let mut order = vec![0u32; points.len()];
        for (i, &c) in cell_index.iter().enumerate() {
            order[starts[c + 1] as usize] = i as u32;
            starts[c + 1] += 1;
        }
        starts.truncate(cells + 1);
        let coords = order.iter().map(|&i| points[i as usize].coords.into()).collect();
        Some(Self { origin: lo, radius, cell, dims, starts, order, coords })
    }

    /// For every gridded point, the other points within the radius: `(slot, starts, members)`
    /// where point `i`'s neighbours (indices into the slice the grid was built from, in no
    /// particular order) are `members[starts[s]..starts[s + 1]]` with `s = slot[i]`. Built
    /// cell by cell: the candidates of a cell's points are the same 3 x 3 x 3 cells, gathered
    /// once into a contiguous block and tested against each point of the cell. `None` if the
    /// lists would not fit `u32` offsets.
    pub fn all_within(&self) -> Option<(Vec<u32>, Vec<u32>, Vec<u32>)> {
        let nonempty: Vec<u32> =
            (0..self.starts.len() - 1).filter(|&c| self.starts[c] < self.starts[c + 1]).map(|c| c as u32).collect();
        let r2 = self.radius * self.radius;
        let blocks: Vec<(Vec<u32>, Vec<u32>)> = nonempty
            .par_chunks(CELLS_PER_TASK)
            .map(|cells| {
                let (mut counts, mut members) = (vec![], vec![]);
                let (mut cand, mut cand_id) = (Vec::<[f64; 3]>::new(), Vec::<u32>::new());
                let mut hits = Vec::<u32>::new();
                for &c in cells {
                    let c = c as usize;
                    let (x, y, z) =
                        (c % self.dims[0], (c / self.dims[0]) % self.dims[1], c / (self.dims[0] * self.dims[1]));
                    cand.clear();
                    cand_id.clear();
                    let around = |v: usize, a: usize| (v.saturating_sub(1), (v + 1).min(self.dims[a] - 1));
                    self.for_each_run([around(x, 0), around(y, 1), around(z, 2)], |run| {
                        cand.extend_from_slice(&self.coords[run.clone()]);
                        cand_id.extend_from_slice(&self.order[run]);
                    });
                    for k in self.starts[c] as usize..self.starts[c + 1] as usize {
                        let (q, me) = (Point3::from(self.coords[k]), self.order[k]);
                        // Branch-free compaction: every candidate is written, the count
                        // advances only for the kept ones (a kept/dropped branch would be
                        // mispredicted for a good share of them).
                        hits.resize(cand.len(), 0);
                        let mut n = 0;
                        for (p, &id) in cand.iter().zip(&cand_id) {
                            let d2 = dist2(p, &q);
                            hits[n] = id;
                            n += usize::from((d2 <= r2) & (id != me));
                        }
                        members.extend_from_slice(&hits[..n]);
                        counts.push(n as u32);
                    }
                }
                (counts, members)
            })
            .collect();
        let total: usize = blocks.iter().map(|b| b.1.len()).sum();
        u32::try_from(total).ok()?;
        let mut slot = vec![0u32; self.order.len()];
        for (k, &i) in self.order.iter().enumerate() {
            slot[i as usize] = k as u32;
        }
        let mut starts = Vec::with_capacity(self.order.len() + 1);
        let mut members = Vec::with_capacity(total);
        starts.push(0u32);
        for (counts, m) in blocks {
            for n in counts {
                starts.push(starts.last().copied().unwrap_or(0) + n);
            }
            members.extend_from_slice(&m);
        }
        Some((slot, starts, members))
    }

    /// The gridded point nearest to `q`, given that point `from` (an index into the slice the
    /// grid was built from) lies at squared distance `from_dist2` from `q`: the nearest point is
    /// within that distance, so only the cells of the cube of half-side `sqrt(from_dist2)`
    /// around `q` are scanned. `None` when that cube spans more than a few cells per axis (the
    /// caller searches otherwise, e.g. with [`crate::KnnIndex::nearest`]). Among points at
    /// exactly the same distance the first scanned is returned (`from` first). The cells' edge
    /// is the grid's radius (or more): choose it near the expected distances.
    pub fn nearest_within(&self, q: &Point3, from: usize, from_dist2: f64) -> Option<Neighbour> {
        let cells = self.cell_box(q, from_dist2.sqrt(), MAX_NEAREST_SPAN)?;
        let mut best = Neighbour { index: from, dist2: from_dist2 };
        let [(x0, x1), (y0, y1), (z0, z1)] = cells;
        for z in z0..=z1 {
            for y in y0..=y1 {
                let row = (z * self.dims[1] + y) * self.dims[0];
                let run = self.starts[row + x0] as usize..self.starts[row + x1 + 1] as usize;
                for (c, &i) in self.coords[run.clone()].iter().zip(&self.order[run]) {
                    let d2 = dist2(c, q);
                    if d2 < best.dist2 {
                        best = Neighbour { index: i as usize, dist2: d2 };
                    }
                }
            }
        }
        Some(best)
    }

    /// The radius the grid answers for.
    pub fn radius(&self) -> f64 {
        self.radius
    }

    /// Appends to `out` the indices of all points within the grid's radius of `q` (in no
    /// particular order).
    pub fn within(&self, q: &Point3, out: &mut Vec<u32>) {
        // A cube of half-side the cell edge spans at most 3 cells per axis.
        let Some(cells) = self.cell_box(q, self.radius, usize::MAX) else { return };
        let r2 = self.radius * self.radius;
        self.for_each_run(cells, |run| {
            // Branch-free compaction: every candidate is written, the kept ones advance (a
            // kept/dropped branch is mispredicted for a good share of the candidates).
            let mut n = out.len();
            out.resize(n + run.len(), 0);
            for (c, &i) in self.coords[run.clone()].iter().zip(&self.order[run]) {
                out[n] = i;
                n += usize::from(dist2(c, q) <= r2);
            }
            out.truncate(n);
        });
    }

    /// Per axis, the first and last cell coordinates of the cells meeting the cube of half-side
    /// `half` around `q`; `None` when the cube misses the grid (or is NaN) or spans more than
    /// `max_span` cells along an axis (checked axis by axis, so a wide cube is handed back
    /// early). No libm floor calls: this runs per query.
    #[inline(always)]
    fn cell_box(&self, q: &Point3, half: f64, max_span: usize) -> Option<[(usize, usize); 3]> {
        let mut cells = [(0usize, 0usize); 3];
        for (a, c) in cells.iter_mut().enumerate() {
            let lo = (q[a] - half - self.origin[a]) / self.cell;
            let hi = (q[a] + half - self.origin[a]) / self.cell;
            if lo.is_nan() || hi.is_nan() {
                return None;
            }
            let (lo, hi) = (floor_i64(lo).max(0), floor_i64(hi).min(self.dims[a] as i64 - 1));
            // hi < lo: the cube lies beyond the grid's first or last cell along this axis.
            if hi < lo || (hi - lo) as usize >= max_span {
                return None;
            }
            *c = (lo as usize, hi as usize);
        }
        Some(cells)
    }

    /// Calls `f` with the runs of `coords` and `order` holding the points of the cells `cells`
    /// (first and last cell coordinate per axis): one contiguous run per row of cells along the
    /// first axis. (Plain loops: an iterator chain here costs a fifth more instructions in ICP.)
    #[inline(always)]
    fn for_each_run(&self, cells: [(usize, usize); 3], mut f: impl FnMut(Range<usize>)) {
        let [(x0, x1), (y0, y1), (z0, z1)] = cells;
        for z in z0..=z1 {
            for y in y0..=y1 {
                let row = (z * self.dims[1] + y) * self.dims[0];
                f(self.starts[row + x0] as usize..self.starts[row + x1 + 1] as usize);
            }
        }
    }
}

/// Squared distance between a gridded point and `q`.
#[inline]
fn dist2(c: &[f64; 3], q: &Point3) -> f64 {
    (c[0] - q.x).powi(2) + (c[1] - q.y).powi(2) + (c[2] - q.z).powi(2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sparse_grid_is_coarsened_and_a_spread_cloud_gets_none() {
        // 2000 points on a 20 cm square: 1 mm cells would be 40 000 per point.
        let square: Vec<Point3> =
            (0..2000).map(|i| Point3::new((i % 50) as f64 * 0.004, (i / 50) as f64 * 0.005, 1.0)).collect();
        let grid = RadiusGrid::new(&square, 0.001).unwrap();
        assert!(grid.cell > 0.001 && grid.dims.iter().product::<usize>() <= 16 * 2000, "{} {:?}", grid.cell, grid.dims);
        let mut out = vec![];
        grid.within(&Point3::new(0.0405, 0.05, 1.0), &mut out);
        assert_eq!(out, vec![510]); // (0.04, 0.05): column 10, row 10; its neighbours are 4 mm away
        // Two points a kilometre apart: no cell edge within 4 radii keeps the grid small.
        assert!(RadiusGrid::new(&[Point3::origin(), Point3::new(1000.0, 1000.0, 1000.0)], 0.01).is_none());
    }

    #[test]
    fn matches_brute_force() {
        let pts: Vec<Point3> = (0..2000)
            .map(|i| {
                let t = i as f64;
                Point3::new((t * 0.731).sin() * 0.2, (t * 1.37).cos() * 0.1, (t * 0.19).sin() * 0.05 - 1.0)
            })
            .collect();
        for radius in [0.004, 0.02, 0.3, 5.0] {
            let grid = RadiusGrid::new(&pts, radius).unwrap();
            assert_eq!(grid.radius(), radius);
            let queries = pts.iter().step_by(37).copied().chain([
                Point3::new(0.0, 0.0, -1.0),
                Point3::new(0.25, -0.12, -0.9),
                Point3::new(3.0, 3.0, 3.0),
                Point3::new(0.2 + radius * 0.5, 0.0, -1.0),
            ]);
            for q in queries {
                let mut got = vec![];
                grid.within(&q, &mut got);
                got.sort_unstable();
                let want: Vec<u32> = (0..pts.len() as u32)
                    .filter(|&i| (pts[i as usize] - q).norm_squared() <= radius * radius)
                    .collect();
                assert_eq!(got, want, "radius {radius}, query {q}");
            }
        }
        assert!(RadiusGrid::new(&pts, 0.0).is_none());
        assert!(RadiusGrid::new(&[], 1.0).is_none());
        assert!(RadiusGrid::new(&[Point3::new(f64::NAN, 0.0, 0.0)], 1.0).is_none());
        // A box needing far too many cells: the caller falls back to a k-d tree.
        assert!(RadiusGrid::new(&[Point3::origin(), Point3::new(1000.0, 1000.0, 1000.0)], 0.001).is_none());
    }

    /// Bounded nearest-point searches agree with brute force wherever they answer, from
    /// partners near and far, and hand back searches whose cube is too wide.
    #[test]
    fn nearest_within_is_the_brute_force_nearest() {
        let pts: Vec<Point3> = (0..3000)
            .map(|i| {
                let t = i as f64;
                Point3::new((t * 0.731).sin() * 0.1, (t * 1.37).cos() * 0.1, 0.02 * (t * 0.19).sin())
            })
            .collect();
        let grid = RadiusGrid::new(&pts, 0.01).unwrap();
        let (mut answered, mut handed_back) = (0, 0);
        for k in 0..400 {
            let t = k as f64;
            let q = Point3::new((t * 0.37).cos() * 0.11, (t * 0.91).sin() * 0.11, 0.03 * (t * 0.53).cos());
            let brute = (0..pts.len())
                .map(|i| Neighbour { index: i, dist2: (pts[i] - q).norm_squared() })
                .min_by(|a, b| a.dist2.total_cmp(&b.dist2))
                .unwrap();
            // Partners: the nearest itself, a close point, a far one.
            for from in [brute.index, (brute.index + 1) % pts.len(), (k * 7) % pts.len()] {
                match grid.nearest_within(&q, from, (pts[from] - q).norm_squared()) {
                    Some(n) => {
                        assert_eq!(n.index, brute.index, "query {k} from {from}");
                        assert_eq!(n.dist2, (pts[n.index] - q).norm_squared());
                        answered += 1;
                    }
                    None => handed_back += 1,
                }
            }
        }
        assert!(answered > 400 && handed_back > 50, "{answered} answered, {handed_back} handed back");
        assert!(grid.nearest_within(&Point3::origin(), 0, f64::NAN).is_none());
    }
}
