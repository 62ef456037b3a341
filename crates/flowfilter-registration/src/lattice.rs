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

use std::collections::hash_map::DefaultHasher;
use std::hash::{Hash, Hasher};

/// Open-addressing hash table from lattice keys (`d` integers) to vertex indices.
struct KeyTable {
    d: usize,
    keys: Vec<i32>,
    slots: Vec<u32>,
}

const EMPTY: u32 = u32::MAX;

impl KeyTable {
    fn new(d: usize, capacity: usize) -> Self {
        let n = (capacity * 2).next_power_of_two().max(16);
        Self { d, keys: Vec::with_capacity(capacity * d), slots: vec![EMPTY; n] }
    }

    fn len(&self) -> usize {
        self.keys.len() / self.d
    }

    fn hash(key: &[i32]) -> usize {
        let mut h = DefaultHasher::new();
        key.hash(&mut h);
        h.finish() as usize
    }

    fn key(&self, i: u32) -> &[i32] {
        &self.keys[i as usize * self.d..(i as usize + 1) * self.d]
    }

    fn find(&self, key: &[i32]) -> Option<u32> {
        let mask = self.slots.len() - 1;
        let mut s = Self::hash(key) & mask;
        loop {
            let i = self.slots[s];
            if i == EMPTY {
                return None;
            }
            if self.key(i) == key {
                return Some(i);
            }
            s = (s + 1) & mask;
        }
    }

    fn insert(&mut self, key: &[i32]) -> u32 {
        if (self.len() + 1) * 2 > self.slots.len() {
            self.grow();
        }
        let mask = self.slots.len() - 1;
        let mut s = Self::hash(key) & mask;
        loop {
            let i = self.slots[s];
            if i == EMPTY {
                let id = self.len() as u32;
                self.keys.extend_from_slice(key);
                self.slots[s] = id;
                return id;
            }
            if self.key(i) == key {
                return i;
            }
            s = (s + 1) & mask;
        }
    }

    fn grow(&mut self) {
        let n = self.slots.len() * 2;
        self.slots = vec![EMPTY; n];
        for id in 0..self.len() as u32 {
            let mut s = Self::hash(self.key(id)) & (n - 1);
            while self.slots[s] != EMPTY {
                s = (s + 1) & (n - 1);
            }
            self.slots[s] = id;
        }
    }
}

/// The enclosing simplex of one point: `d + 1` vertex keys and barycentric weights.
struct Simplex {
    keys: Vec<i32>,
    weights: Vec<f64>,
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

    fn simplex(&self, pos: &[f64]) -> Simplex {
        let d = self.d;
        let dp1 = (d + 1) as f64;
        // Elevate onto the hyperplane x . 1 = 0 of R^(d+1).
        let mut elevated = vec![0.0; d + 1];
        let mut sm = 0.0;
        for i in (1..=d).rev() {
            let cf = pos[i - 1] * self.scale[i - 1];
            elevated[i] = sm - i as f64 * cf;
            sm += cf;
        }
        elevated[0] = sm;
        // The nearest remainder-0 lattice point, and the ranks of the differences.
        let mut rem0 = vec![0.0f64; d + 1];
        let mut sum = 0i64;
        for i in 0..=d {
            let v = elevated[i] / dp1;
            let (up, down) = (v.ceil() * dp1, v.floor() * dp1);
            rem0[i] = if up - elevated[i] < elevated[i] - down { up } else { down };
            sum += (rem0[i] / dp1).round() as i64;
        }
        let mut rank = vec![0i64; d + 1];
        for i in 0..d {
            for j in i + 1..=d {
                if elevated[i] - rem0[i] < elevated[j] - rem0[j] {
                    rank[i] += 1;
                } else {
                    rank[j] += 1;
                }
            }
        }
        let d1 = (d + 1) as i64;
        if sum > 0 {
            for i in 0..=d {
                if rank[i] >= d1 - sum {
                    rem0[i] -= dp1;
                    rank[i] += sum - d1;
                } else {
                    rank[i] += sum;
                }
            }
        } else if sum < 0 {
            for i in 0..=d {
                if rank[i] < -sum {
                    rem0[i] += dp1;
                    rank[i] += d1 + sum;
                } else {
                    rank[i] += sum;
                }
            }
        }
        // Barycentric coordinates.
        let mut b = vec![0.0f64; d + 2];
        for i in 0..=d {
            let delta = (elevated[i] - rem0[i]) / dp1;
            b[d - rank[i] as usize] += delta;
            b[d + 1 - rank[i] as usize] -= delta;
        }
        b[0] += 1.0 + b[d + 1];
        // Vertex keys: remainder-k vertices of the canonical simplex, permuted by rank.
        let mut keys = Vec::with_capacity((d + 1) * d);
        for k in 0..=d as i64 {
            for i in 0..d {
                let r = rank[i];
                let canonical = if r <= d1 - 1 - k { k } else { k - d1 };
                keys.push(rem0[i] as i32 + canonical as i32);
            }
        }
        Simplex { keys, weights: b[..=d].to_vec() }
    }
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
        let n = positions.len() / d;
        let embedding = Embedding::new(d);
        let mut table = KeyTable::new(d, n * (d + 1) / 2 + 16);
        let mut vals: Vec<f64> = Vec::new();
        for p in 0..n {
            let s = embedding.simplex(&positions[p * d..(p + 1) * d]);
            for r in 0..=d {
                let id = table.insert(&s.keys[r * d..(r + 1) * d]) as usize;
                if vals.len() < (id + 1) * vd {
                    vals.resize((id + 1) * vd, 0.0);
                }
                for c in 0..vd {
                    vals[id * vd + c] += s.weights[r] * values[p * vd + c];
                }
            }
        }
        let mut lattice = Self { d, vd, embedding, table, values: vals };
        lattice.blur();
        lattice
    }

    /// Number of lattice vertices.
    pub fn vertices(&self) -> usize {
        self.table.len()
    }

    fn blur(&mut self) {
        let (d, vd) = (self.d, self.vd);
        let n = self.table.len();
        // Neighbour indices along each direction, computed once per direction.
        let mut key = vec![0i32; d];
        for j in 0..=d {
            let mut next = self.values.clone();
            for v in 0..n {
                let base = self.table.key(v as u32).to_vec();
                let mut neighbour = |sign: i32| -> Option<u32> {
                    for i in 0..d {
                        key[i] = base[i] - sign;
                    }
                    if j < d {
                        key[j] = base[j] + sign * d as i32;
                    }
                    self.table.find(&key)
                };
                let (a, b) = (neighbour(1), neighbour(-1));
                for c in 0..vd {
                    let mut acc = 0.5 * self.values[v * vd + c];
                    if let Some(a) = a {
                        acc += 0.25 * self.values[a as usize * vd + c];
                    }
                    if let Some(b) = b {
                        acc += 0.25 * self.values[b as usize * vd + c];
                    }
                    next[v * vd + c] = acc;
                }
            }
            self.values = next;
        }
    }

    /// Interpolate the blurred values at `queries` (`d` per point) into `out` (`vd` per point).
    pub fn slice(&self, queries: &[f64], out: &mut [f64]) {
        let (d, vd) = (self.d, self.vd);
        assert!(queries.len().is_multiple_of(d) && out.len() == queries.len() / d * vd);
        for (q, o) in queries.chunks_exact(d).zip(out.chunks_exact_mut(vd)) {
            o.fill(0.0);
            let s = self.embedding.simplex(q);
            for r in 0..=d {
                if let Some(id) = self.table.find(&s.keys[r * d..(r + 1) * d]) {
                    let vals = &self.values[id as usize * vd..(id as usize + 1) * vd];
                    for (oc, v) in o.iter_mut().zip(vals) {
                        *oc += s.weights[r] * v;
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

    #[test]
    fn barycentric_weights_sum_to_one_and_reconstruct_the_point() {
        let e = Embedding::new(3);
        let mut seed = 1;
        for _ in 0..100 {
            let p: Vec<f64> = (0..3).map(|_| lcg(&mut seed) * 10.0 - 5.0).collect();
            let s = e.simplex(&p);
            let sum: f64 = s.weights.iter().sum();
            assert!((sum - 1.0).abs() < 1e-9, "{sum}");
            assert!(s.weights.iter().all(|&w| w >= -1e-9), "{:?}", s.weights);
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
