//! The permutohedral lattice (Adams, Baek & Davis, "Fast High-Dimensional Filtering Using the
//! Permutohedral Lattice", Eurographics 2010): Gaussian filtering of values attached to points
//! in any dimension, in time linear in the number of points.
//!
//! Points are embedded in the `d`-dimensional permutohedral lattice (a hyperplane of
//! `Z^(d+1)`), values are *splatted* onto the vertices of each point's enclosing simplex with
//! barycentric weights, *blurred* along the `d + 1` lattice directions with a `[1 2 1]` kernel,
//! and *sliced* at query points (which may differ from the splatted points). With positions
//! divided by `sigma`, the result approximates `sum_k exp(-|q - p_k|^2 / (2 sigma^2)) v_k`
//! up to a constant factor; [`Lattice::kernel_scale`] estimates that factor.

use flowfilter_geometry::fastmath::floor_i64;
use rayon::prelude::*;

/// Open-addressing hash table from lattice keys (`d` integers) to vertex indices. Every method
/// takes `d`: the lattice's three-dimensional paths pass a constant, so the key loops unroll.
struct KeyTable {
    keys: Vec<i32>,
    slots: Vec<u32>,
}

const EMPTY: u32 = u32::MAX;

/// Key equality as a plain loop (short keys: cheaper than the `memcmp` call of `==`).
#[inline(always)]
fn same_key(a: &[i32], b: &[i32]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x == y)
}

impl KeyTable {
    fn new(d: usize, capacity: usize) -> Self {
        let n = (capacity * 2).next_power_of_two().max(16);
        Self { keys: Vec::with_capacity(capacity * d), slots: vec![EMPTY; n] }
    }

    #[inline(always)]
    fn len(&self, d: usize) -> usize {
        self.keys.len() / d
    }

    /// A multiplicative (Fx-style) hash of the key: lattice keys are small integers, so a
    /// keyed cryptographic hash buys nothing here and costs most of the splat and slice time.
    #[inline(always)]
    fn hash(key: &[i32]) -> usize {
        let mut h: u64 = 0;
        for &k in key {
            h = (h.rotate_left(5) ^ (k as u32 as u64)).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
        }
        (h ^ (h >> 29)) as usize
    }

    #[inline(always)]
    fn key(&self, d: usize, i: u32) -> &[i32] {
        &self.keys[i as usize * d..(i as usize + 1) * d]
    }

    #[inline(always)]
    fn find(&self, d: usize, key: &[i32]) -> Option<u32> {
        let mask = self.slots.len() - 1;
        let mut s = Self::hash(key) & mask;
        loop {
            let i = self.slots[s];
            if i == EMPTY {
                return None;
            }
            if same_key(self.key(d, i), key) {
                return Some(i);
            }
            s = (s + 1) & mask;
        }
    }

    #[inline(always)]
    fn insert(&mut self, d: usize, key: &[i32]) -> u32 {
        if (self.len(d) + 1) * 2 > self.slots.len() {
            self.grow(d);
        }
        let mask = self.slots.len() - 1;
        let mut s = Self::hash(key) & mask;
        loop {
            let i = self.slots[s];
            if i == EMPTY {
                let id = self.len(d) as u32;
                self.keys.extend_from_slice(key);
                self.slots[s] = id;
                return id;
            }
            if same_key(self.key(d, i), key) {
                return i;
            }
            s = (s + 1) & mask;
        }
    }

    fn grow(&mut self, d: usize) {
        let n = self.slots.len() * 2;
        self.slots = vec![EMPTY; n];
        for id in 0..self.len(d) as u32 {
            let mut s = Self::hash(self.key(d, id)) & (n - 1);
            while self.slots[s] != EMPTY {
                s = (s + 1) & (n - 1);
            }
            self.slots[s] = id;
        }
    }
}

/// Work space of one simplex computation (reused across points to avoid allocations).
struct Scratch {
    elevated: Vec<f64>,
    rem0: Vec<f64>,
    rank: Vec<i64>,
    b: Vec<f64>,
}

impl Scratch {
    fn new(d: usize) -> Self {
        Self { elevated: vec![0.0; d + 1], rem0: vec![0.0; d + 1], rank: vec![0; d + 1], b: vec![0.0; d + 2] }
    }
}

/// Embedding of positions into the lattice.
struct Embedding {
    d: usize,
    scale: Vec<f64>,
}

impl Embedding {
    fn new(d: usize) -> Self {
        // Scaling so that the [1 2 1] blur along every lattice direction amounts to a Gaussian
        // of unit standard deviation in the input space (Adams et al. 2010, section 3.1).
        let inv_std = (d as f64 + 1.0) * (2.0f64 / 3.0).sqrt();
        let scale = (0..d).map(|i| inv_std / (((i + 1) * (i + 2)) as f64).sqrt()).collect();
        Self { d, scale }
    }

    /// The enclosing simplex of `pos`: writes its `d + 1` vertex keys (`d` integers each) to
    /// `keys` and the barycentric weights to `weights`.
    fn simplex(&self, pos: &[f64], w: &mut Scratch, keys: &mut [i32], weights: &mut [f64]) {
        // Three dimensions (FilterReg's case) get their own copy with `d` a constant: the
        // loops unroll and most bounds checks go.
        match self.d {
            3 => {
                let mut w3 = ([0.0; 4], [0.0; 4], [0; 4], [0.0; 5]);
                let s = (&mut w3.0[..], &mut w3.1[..], &mut w3.2[..], &mut w3.3[..]);
                self.simplex_in(3, pos, s, keys, weights)
            }
            d => {
                let Scratch { elevated, rem0, rank, b } = w;
                self.simplex_in(d, pos, (elevated, rem0, rank, b), keys, weights)
            }
        }
    }

    /// Writes `pos` (`d` coordinates, `d == self.d`) elevated onto the hyperplane `x . 1 = 0` of
    /// `R^(d+1)` to `elevated` (`d + 1` entries).
    #[inline(always)]
    fn elevate(&self, d: usize, pos: &[f64], elevated: &mut [f64]) {
        let mut sm = 0.0;
        for i in (1..=d).rev() {
            let cf = pos[i - 1] * self.scale[i - 1];
            elevated[i] = sm - i as f64 * cf;
            sm += cf;
        }
        elevated[0] = sm;
    }

    /// [`Embedding::simplex`] for `d == self.d`, with work space `(elevated, rem0, rank, b)`
    /// of lengths `d + 1, d + 1, d + 1, d + 2`.
    #[inline(always)]
    fn simplex_in(
        &self,
        d: usize,
        pos: &[f64],
        (elevated, rem0, rank, b): (&mut [f64], &mut [f64], &mut [i64], &mut [f64]),
        keys: &mut [i32],
        weights: &mut [f64],
    ) {
        let dp1 = (d + 1) as f64;
        self.elevate(d, pos, elevated);
        // The nearest remainder-0 lattice point, and the ranks of the differences.
        let mut sum = 0i64;
        for i in 0..=d {
            let down_k = floor_i64(elevated[i] / dp1);
            let (down, up) = (down_k as f64 * dp1, (down_k + 1) as f64 * dp1);
            let take_up = up - elevated[i] < elevated[i] - down;
            rem0[i] = if take_up { up } else { down };
            sum += down_k + take_up as i64;
        }
        // Branch-free: the comparisons are data-dependent and mispredict half of the time.
        rank.fill(0);
        for i in 0..d {
            for j in i + 1..=d {
                let below = (elevated[i] - rem0[i] < elevated[j] - rem0[j]) as i64;
                rank[i] += below;
                rank[j] += 1 - below;
            }
        }
        let d1 = (d + 1) as i64;
        // sum > 0: the `sum` highest-ranked coordinates step down; sum < 0: the `-sum` lowest
        // step up; every rank shifts by `sum` modulo d + 1.
        for i in 0..=d {
            let down = (sum > 0 && rank[i] >= d1 - sum) as i64;
            let up = (sum < 0 && rank[i] < -sum) as i64;
            rem0[i] += (up - down) as f64 * dp1;
            rank[i] += sum + (up - down) * d1;
        }
        // Barycentric coordinates.
        b.fill(0.0);
        for i in 0..=d {
            let delta = (elevated[i] - rem0[i]) / dp1;
            b[d - rank[i] as usize] += delta;
            b[d + 1 - rank[i] as usize] -= delta;
        }
        b[0] += 1.0 + b[d + 1];
        // Vertex keys: remainder-k vertices of the canonical simplex, permuted by rank.
        for k in 0..=d as i64 {
            for i in 0..d {
                let r = rank[i];
                let canonical = if r <= d1 - 1 - k { k } else { k - d1 };
                keys[k as usize * d + i] = rem0[i] as i32 + canonical as i32;
            }
        }
        weights.copy_from_slice(&b[..=d]);
    }
}

/// `n` as the constant `N` where one is given (the code instantiated for it unrolls its loops
/// over coordinates or values), else `n` (`N == 0`).
#[inline(always)]
fn known<const N: usize>(n: usize) -> usize {
    debug_assert!(N == 0 || N == n);
    if N == 0 { n } else { N }
}

/// A permutohedral lattice holding blurred values.
pub struct Lattice {
    d: usize,
    vd: usize,
    embedding: Embedding,
    table: KeyTable,
    values: Vec<f64>,
}

impl Lattice {
    /// Splat `values` (`vd` per point) at `positions` (`d` per point, already divided by the
    /// Gaussian's standard deviation) and blur. Panics if slice lengths disagree with `d`/`vd`.
    pub fn new(d: usize, positions: &[f64], vd: usize, values: &[f64]) -> Self {
        assert!(d >= 1 && positions.len().is_multiple_of(d) && values.len() == positions.len() / d * vd);
        // FilterReg's shapes (three dimensions, five or eight values) get their own copies with
        // the sizes as constants.
        let mut lattice = match (d, vd) {
            (3, 5) => Self::splat::<3, 5>(d, positions, vd, values),
            (3, 8) => Self::splat::<3, 8>(d, positions, vd, values),
            _ => Self::splat::<0, 0>(d, positions, vd, values),
        };
        match (d, vd) {
            (3, 5) => lattice.blur::<3, 5>(),
            (3, 8) => lattice.blur::<3, 8>(),
            _ => lattice.blur::<0, 0>(),
        }
        lattice
    }

    /// The splatted (not yet blurred) lattice of dimension `d` with `vd` values per point (`D`,
    /// `VD`: the same as constants, or 0).
    fn splat<const D: usize, const VD: usize>(d: usize, positions: &[f64], vd: usize, values: &[f64]) -> Self {
        let (d, vd) = (known::<D>(d), known::<VD>(vd));
        let n = positions.len() / d;
        let embedding = Embedding::new(d);
        // Simplices in parallel; the insertion (which numbers the vertices) stays sequential, in
        // point order, so the result does not depend on the thread count.
        let (mut keys, mut weights) = (vec![0i32; n * (d + 1) * d], vec![0.0f64; n * (d + 1)]);
        const CHUNK: usize = 512;
        keys.par_chunks_mut(CHUNK * (d + 1) * d)
            .zip(weights.par_chunks_mut(CHUNK * (d + 1)))
            .zip(positions.par_chunks(CHUNK * d))
            .for_each(|((k, w), pos)| {
                let mut scratch = Scratch::new(d);
                for ((k, w), p) in
                    k.chunks_exact_mut((d + 1) * d).zip(w.chunks_exact_mut(d + 1)).zip(pos.chunks_exact(d))
                {
                    embedding.simplex(p, &mut scratch, k, w);
                }
            });
        let mut table = KeyTable::new(d, n * (d + 1) / 2 + 16);
        let mut vals: Vec<f64> = Vec::new();
        for ((k, w), v) in keys.chunks_exact((d + 1) * d).zip(weights.chunks_exact(d + 1)).zip(values.chunks_exact(vd))
        {
            for (key, &wr) in k.chunks_exact(d).zip(w) {
                let id = table.insert(d, key) as usize;
                if vals.len() < (id + 1) * vd {
                    vals.resize((id + 1) * vd, 0.0);
                }
                for (acc, vc) in vals[id * vd..(id + 1) * vd].iter_mut().zip(v) {
                    *acc += wr * vc;
                }
            }
        }
        Self { d, vd, embedding, table, values: vals }
    }

    /// Number of lattice vertices.
    pub fn vertices(&self) -> usize {
        self.table.len(self.d)
    }

    /// Blurs the splatted values (`D`, `VD`: `self.d` and `self.vd` as constants, or 0).
    fn blur<const D: usize, const VD: usize>(&mut self) {
        let (d, vd) = (known::<D>(self.d), known::<VD>(self.vd));
        let n = self.table.len(d);
        let table = &self.table;
        // Along each of the d + 1 lattice directions: [1 2 1] / 4 over the two neighbours
        // (missing vertices hold zero). Every vertex is independent within a pass.
        // Two buffers used in turn: every entry of the output is written, so neither is cleared,
        // and no pass allocates (fresh pages of a multi-megabyte buffer fault in one by one).
        let mut next = vec![0.0; n * vd];
        for j in 0..=d {
            let values = &self.values;
            next.par_chunks_mut(vd * 256).enumerate().for_each(|(chunk, out)| {
                let mut key = vec![0i32; d];
                for (o, v) in out.chunks_exact_mut(vd).zip(chunk * 256..) {
                    let base = table.key(d, v as u32);
                    let mut neighbour = |sign: i32| -> Option<u32> {
                        for i in 0..d {
                            key[i] = base[i] - sign;
                        }
                        if j < d {
                            key[j] = base[j] + sign * d as i32;
                        }
                        table.find(d, &key[..d])
                    };
                    let (a, b) = (neighbour(1), neighbour(-1));
                    for c in 0..vd {
                        let mut acc = 0.5 * values[v * vd + c];
                        if let Some(a) = a {
                            acc += 0.25 * values[a as usize * vd + c];
                        }
                        if let Some(b) = b {
                            acc += 0.25 * values[b as usize * vd + c];
                        }
                        o[c] = acc;
                    }
                }
            });
            std::mem::swap(&mut self.values, &mut next);
        }
    }

    /// Interpolate the blurred values at `queries` (`d` per point) into `out` (`vd` per point).
    pub fn slice(&self, queries: &[f64], out: &mut [f64]) {
        assert!(queries.len().is_multiple_of(self.d) && out.len() == queries.len() / self.d * self.vd);
        match (self.d, self.vd) {
            (3, 5) => self.slice_in::<3, 5>(queries, out),
            (3, 8) => self.slice_in::<3, 8>(queries, out),
            _ => self.slice_in::<0, 0>(queries, out),
        }
    }

    /// [`Lattice::slice`] (`D`, `VD`: `self.d` and `self.vd` as constants, or 0).
    fn slice_in<const D: usize, const VD: usize>(&self, queries: &[f64], out: &mut [f64]) {
        let (d, vd) = (known::<D>(self.d), known::<VD>(self.vd));
        let mut scratch = Scratch::new(d);
        let (mut keys, mut weights) = (vec![0i32; (d + 1) * d], vec![0.0f64; d + 1]);
        for (q, o) in queries.chunks_exact(d).zip(out.chunks_exact_mut(vd)) {
            o.fill(0.0);
            self.embedding.simplex(q, &mut scratch, &mut keys, &mut weights);
            for (key, w) in keys.chunks_exact(d).zip(&weights) {
                if let Some(id) = self.table.find(d, key) {
                    let vals = &self.values[id as usize * vd..(id as usize + 1) * vd];
                    for (oc, v) in o.iter_mut().zip(vals) {
                        *oc += w * v;
                    }
                }
            }
        }
    }

    /// The ratio of the lattice's filtered sums to exact unnormalised Gaussian sums
    /// `sum_k exp(-|q - p_k|^2 / 2)`, estimated once per dimension on a dense quasi-random
    /// cloud (the approximation's shape error is a few percent; this fixes its scale).
    pub fn kernel_scale(d: usize) -> f64 {
        // Halton-like low-discrepancy points in [-3, 3]^d.
        let primes = [2u64, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37];
        let radical = |mut i: u64, b: u64| {
            let (mut f, mut r) = (1.0, 0.0);
            while i > 0 {
                f /= b as f64;
                r += f * (i % b) as f64;
                i /= b;
            }
            r
        };
        let n = 3000usize;
        let pos: Vec<f64> = (1..=n as u64)
            .flat_map(|i| (0..d).map(move |k| radical(i, primes[k % primes.len()]) * 6.0 - 3.0))
            .collect();
        let queries: Vec<f64> = (1..=20u64)
            .flat_map(|i| (0..d).map(move |k| radical(i + 7, primes[(k + 1) % primes.len()]) - 0.5))
            .collect();
        let lattice = Lattice::new(d, &pos, 1, &vec![1.0; n]);
        let mut out = vec![0.0; 20];
        lattice.slice(&queries, &mut out);
        let exact: f64 = queries
            .chunks_exact(d)
            .map(|q| {
                pos.chunks_exact(d)
                    .map(|p| (-q.iter().zip(p).map(|(a, b)| (a - b).powi(2)).sum::<f64>() / 2.0).exp())
                    .sum::<f64>()
            })
            .sum();
        out.iter().sum::<f64>() / exact
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg(seed: &mut u64) -> f64 {
        *seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (*seed >> 11) as f64 / (1u64 << 53) as f64
    }

    /// In every dimension (the three-dimensional copy included): the weights are non-negative and
    /// sum to one, and the weighted vertices (keys, with the last coordinate implied by the
    /// hyperplane) reproduce the elevated point.
    #[test]
    fn barycentric_weights_sum_to_one_and_reconstruct_the_point() {
        for d in [1usize, 2, 3, 4, 6] {
            let e = Embedding::new(d);
            let mut seed = 1 + d as u64;
            let mut scratch = Scratch::new(d);
            let (mut keys, mut weights) = (vec![0i32; (d + 1) * d], vec![0.0f64; d + 1]);
            for _ in 0..500 {
                let p: Vec<f64> = (0..d).map(|_| lcg(&mut seed) * 40.0 - 20.0).collect();
                e.simplex(&p, &mut scratch, &mut keys, &mut weights);
                let sum: f64 = weights.iter().sum();
                assert!((sum - 1.0).abs() < 1e-9, "d = {d}: {sum}");
                assert!(weights.iter().all(|&w| w >= -1e-9), "d = {d}: {weights:?}");
                let mut want = vec![0.0; d + 1];
                e.elevate(d, &p, &mut want);
                let mut got = vec![0.0; d + 1];
                for (k, w) in keys.chunks_exact(d).zip(&weights) {
                    let last: i64 = -k.iter().map(|&c| c as i64).sum::<i64>();
                    for (g, c) in got.iter_mut().zip(k.iter().map(|&c| c as i64).chain([last])) {
                        *g += w * c as f64;
                    }
                }
                for i in 0..=d {
                    assert!(
                        (got[i] - want[i]).abs() < 1e-9 * (1.0 + want[i].abs()),
                        "d = {d}, {p:?}: {got:?} vs {want:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn approximates_gaussian_sums_in_3d() {
        // Filter a random cloud and compare with exact Gaussian sums (unit sigma).
        let mut seed = 42;
        let n = 400;
        let pos: Vec<f64> = (0..n * 3).map(|_| lcg(&mut seed) * 6.0).collect();
        let vals: Vec<f64> = (0..n).flat_map(|i| [1.0, pos[i * 3]]).collect();
        let lattice = Lattice::new(3, &pos, 2, &vals);
        let scale = Lattice::kernel_scale(3);
        let queries: Vec<f64> = (0..50 * 3).map(|_| 1.0 + lcg(&mut seed) * 4.0).collect();
        let mut out = vec![0.0; 50 * 2];
        lattice.slice(&queries, &mut out);
        let mut rel = vec![];
        for q in 0..50 {
            let exact: f64 = (0..n)
                .map(|k| {
                    let d2: f64 = (0..3).map(|i| (queries[q * 3 + i] - pos[k * 3 + i]).powi(2)).sum();
                    (-d2 / 2.0).exp()
                })
                .sum();
            rel.push((out[q * 2] / scale - exact).abs() / exact);
            // The weighted mean of the x coordinate is close to the exact one.
            let exact_x: f64 = (0..n)
                .map(|k| {
                    let d2: f64 = (0..3).map(|i| (queries[q * 3 + i] - pos[k * 3 + i]).powi(2)).sum();
                    (-d2 / 2.0).exp() * pos[k * 3]
                })
                .sum();
            assert!((out[q * 2 + 1] / out[q * 2] - exact_x / exact).abs() < 0.25, "query {q}");
        }
        let mean_rel = rel.iter().sum::<f64>() / rel.len() as f64;
        assert!(mean_rel < 0.25, "mean relative error {mean_rel}");
    }

    /// The copies with FilterReg's shapes as constants (three dimensions, five or eight values)
    /// give the general code's vertices, blurred values and slices to the bit.
    #[test]
    fn fixed_shape_copies_are_the_general_code() {
        let mut seed = 9;
        let n = 700;
        let pos: Vec<f64> = (0..n * 3).map(|_| lcg(&mut seed) * 8.0).collect();
        let queries: Vec<f64> = (0..60 * 3).map(|_| 1.0 + lcg(&mut seed) * 6.0).collect();
        for vd in [5, 8] {
            let vals: Vec<f64> = (0..n * vd).map(|_| lcg(&mut seed) - 0.3).collect();
            let fixed = Lattice::new(3, &pos, vd, &vals);
            let mut general = Lattice::splat::<0, 0>(3, &pos, vd, &vals);
            general.blur::<0, 0>();
            assert_eq!(fixed.table.keys, general.table.keys, "vd = {vd}");
            assert_eq!(fixed.values, general.values, "vd = {vd}");
            let (mut a, mut b) = (vec![0.0; 60 * vd], vec![0.0; 60 * vd]);
            fixed.slice(&queries, &mut a);
            general.slice_in::<0, 0>(&queries, &mut b);
            assert_eq!(a, b, "vd = {vd}");
            assert!(a.iter().any(|&v| v != 0.0));
        }
    }

    #[test]
    fn works_in_other_dimensions() {
        for d in [1usize, 2, 5] {
            let pos: Vec<f64> = (0..d * 30).map(|i| (i as f64 * 0.37).sin() * 2.0).collect();
            let l = Lattice::new(d, &pos, 1, &vec![1.0; 30]);
            let mut out = vec![0.0; 30];
            l.slice(&pos, &mut out);
            assert!(out.iter().all(|&v| v > 0.0), "d = {d}");
        }
    }
}
