//! Variational refinement of the DIS flow (Brox-style energy with brightness and gradient
//! constancy under a robust penalty and a robust smoothness term, linearised at the current flow
//! and solved by red-black successive over-relaxation), OpenCV's `VariationalRefinement`.
//!
//! Every per-pixel array lives in the red-black layout for the whole refinement: the data terms
//! are written there once per scale, and the smoothness weights, the linear systems and the
//! increments are computed there at every fixed-point iteration. A pixel's four neighbours are
//! in the other colour at fixed offsets, so each row of one colour is a branch-free loop over
//! contiguous arrays that the compiler vectorises; image borders are handled by 0/1 edge masks.

use super::{Img, ROWS_PER_TASK, gradient_y, gradients};
use crate::buffers::{recycle, zeroed};
use crate::dis::DisParams;
use crate::lk::BilinearTap;
use rayon::prelude::*;
use wide::f32x4;

/// Regularisation of the constancy terms' normalisation (`zeta^2`, OpenCV's value).
const ZETA2: f32 = 0.01;

/// Robust penalty derivative `Psi'(s2) = 1 / (2 sqrt(s2 + eps^2))`.
#[inline(always)]
fn psi_prime(s2: f32) -> f32 {
    0.5 / (s2 + 1e-6).sqrt()
}

/// Red-black layout of a `w x h` image: pixel `(x, y)` has colour `(x + y) % 2` and index
/// `x / 2` in its row of that colour. Each colour's arrays have one padding entry at both ends of
/// every row and a padding row above and below (stride `hw + 2`), so that neighbours are read
/// without bounds checks; the padding stays zero.
pub(super) struct Checker {
    w: usize,
    h: usize,
    hw: usize,
}

impl Checker {
    pub(super) fn new(w: usize, h: usize) -> Self {
        Self { w, h, hw: w.div_ceil(2) }
    }

    /// Row stride of the padded arrays.
    fn stride(&self) -> usize {
        self.hw + 2
    }

    /// Length of one padded array.
    fn len(&self) -> usize {
        self.stride() * (self.h + 2)
    }

    /// Column of the first pixel of colour `colour` in row `y`.
    fn start(&self, y: usize, colour: usize) -> usize {
        (y + colour) % 2
    }

    /// Pixels of colour `colour` in row `y`.
    fn count(&self, y: usize, colour: usize) -> usize {
        (self.w - self.start(y, colour)).div_ceil(2)
    }

    /// Index of pixel `(x, y)` in its colour's padded array.
    fn padded(&self, x: usize, y: usize) -> usize {
        (y + 1) * self.stride() + x / 2 + 1
    }

    /// Zeroed padded arrays of both colours.
    fn zeros(&self) -> [Vec<f32>; 2] {
        [zeroed(self.len()), zeroed(self.len())]
    }

    /// `full` (row-major) split into the colours' padded arrays.
    fn split(&self, full: &[f32]) -> [Vec<f32>; 2] {
        let mut out = self.zeros();
        for (colour, part) in out.iter_mut().enumerate() {
            part[self.stride()..(self.h + 1) * self.stride()]
                .par_chunks_mut(self.stride())
                .enumerate()
                .with_min_len(ROWS_PER_TASK)
                .for_each(|(y, row)| {
                    for x in (self.start(y, colour)..self.w).step_by(2) {
                        row[x / 2 + 1] = full[y * self.w + x];
                    }
                });
        }
        out
    }

    /// Adds the colours' padded arrays `parts` to `full` (row-major).
    fn add_to(&self, parts: &[Vec<f32>; 2], full: &mut [f32]) {
        full.par_chunks_mut(self.w).enumerate().with_min_len(ROWS_PER_TASK).for_each(|(y, row)| {
            for (x, v) in row.iter_mut().enumerate() {
                *v += parts[(x + y) % 2][self.padded(x, y)];
            }
        });
    }

    /// Offset, in the other colour's padded array, of the left neighbour of the first pixel of
    /// row `y` of `colour` (the right neighbour is one further).
    fn left_offset(&self, y: usize, colour: usize) -> usize {
        (y + 1) * self.stride() + self.start(y, colour)
    }
}

/// Several padded arrays of one colour stored back to back ("planes").
struct Planes {
    data: Vec<f32>,
    len: usize,
}

impl Planes {
    fn zeros(planes: usize, ck: &Checker) -> Self {
        Self { data: zeroed(planes * ck.len()), len: ck.len() }
    }

    fn plane(&self, k: usize) -> &[f32] {
        &self.data[k * self.len..(k + 1) * self.len]
    }

    /// Per image row, mutable views of that padded row in every plane (for row-parallel writes).
    fn rows_mut(&mut self, ck: &Checker) -> Vec<Vec<&mut [f32]>> {
        let stride = ck.stride();
        let mut rows: Vec<Vec<&mut [f32]>> = (0..ck.h).map(|_| Vec::new()).collect();
        for plane in self.data.chunks_mut(self.len) {
            for (row, slot) in plane[stride..(ck.h + 1) * stride].chunks_mut(stride).zip(rows.iter_mut()) {
                slot.push(row);
            }
        }
        rows
    }
}

/// Runs `f(y, colour, row)` for every image row `y` and both colours, where `row` holds the
/// mutable views of row `y` in each of that colour's `planes`; rows run in parallel, both colours
/// of a row in one task (one fork-join per phase, and the inputs of a row are read once).
fn for_each_row(ck: &Checker, planes: &mut [Planes; 2], f: impl Fn(usize, usize, &mut [&mut [f32]]) + Sync) {
    let [a, b] = planes;
    a.rows_mut(ck).into_par_iter().zip(b.rows_mut(ck)).enumerate().with_min_len(ROWS_PER_TASK).for_each(
        |(y, (mut ra, mut rb))| {
            f(y, 0, &mut ra);
            f(y, 1, &mut rb);
        },
    );
}

/// Planes of the linearised data term: the mean gradients `ix, iy`, the temporal difference
/// `iz`, the mean second derivatives, the gradients' temporal differences and the three
/// normalisations `1 / (|grad|^2 + zeta^2)` of the brightness and the two gradient constancies.
const IX: usize = 0;
const IY: usize = 1;
const IZ: usize = 2;
const IXX: usize = 3;
const IXY: usize = 4;
const IYY: usize = 5;
const IXZ: usize = 6;
const IYZ: usize = 7;
const N1: usize = 8;
const N2: usize = 9;
const N3: usize = 10;
const DATA_PLANES: usize = 11;

/// Planes of one colour's linear system per pixel: `a12`, `1 / (a11 + sum w)`,
/// `1 / (a22 + sum w)`, the right-hand sides `r1`, `r2` (with `r = -b + sum_q w_q (f_q - f_p)`)
/// and the four neighbour weights.
const A12: usize = 0;
const INV11: usize = 1;
const INV22: usize = 2;
const R1: usize = 3;
const R2: usize = 4;
const WL: usize = 5;
const WR: usize = 6;
const WU: usize = 7;
const WD: usize = 8;
const SYSTEM_PLANES: usize = 9;

/// Edge masks: 1 where the pixel has a left (right) neighbour, 0 at the image border.
const ML: usize = 0;
const MR: usize = 1;

/// The images the data term is linearised from.
struct Derivatives<'a> {
    i0: &'a Img,
    i1: &'a Img,
    i0x: &'a Img,
    i0y: &'a Img,
    i1x: &'a Img,
    i1y: &'a Img,
    i0xx: &'a Img,
    i0xy: &'a Img,
    i0yy: &'a Img,
    i1xx: &'a Img,
    i1xy: &'a Img,
    i1yy: &'a Img,
}

/// The data-term planes of both colours at the flow `(u, v)` (row-major): the second image and
/// its derivatives sampled at the flowed position, averaged with the first image's. Pixels
/// flowed outside the image get no data term.
fn data_terms(ck: &Checker, d: &Derivatives<'_>, u: &[f32], v: &[f32]) -> [Planes; 2] {
    let (w, h) = (ck.w, ck.h);
    let mut planes = [Planes::zeros(DATA_PLANES, ck), Planes::zeros(DATA_PLANES, ck)];
    for_each_row(ck, &mut planes, |y, colour, row| {
        for x in (ck.start(y, colour)..w).step_by(2) {
            let k = y * w + x;
            let (fx, fy) = (x as f32 + u[k], y as f32 + v[k]);
            if !(fx >= 0.0 && fy >= 0.0 && fx <= (w - 1) as f32 && fy <= (h - 1) as f32) {
                continue;
            }
            let tap = BilinearTap::new(w, h, fx, fy);
            let s = |img: &Img| tap.sample(img.as_slice());
            let at = |img: &Img| img.as_slice()[k];
            let (wx, wy) = (s(d.i1x), s(d.i1y));
            let (ix, iy) = (0.5 * (wx + at(d.i0x)), 0.5 * (wy + at(d.i0y)));
            let ixx = 0.5 * (s(d.i1xx) + at(d.i0xx));
            let ixy = 0.5 * (s(d.i1xy) + at(d.i0xy));
            let iyy = 0.5 * (s(d.i1yy) + at(d.i0yy));
            let values = [
                ix,
                iy,
                s(d.i1) - at(d.i0),
                ixx,
                ixy,
                iyy,
                wx - at(d.i0x),
                wy - at(d.i0y),
                1.0 / (ix * ix + iy * iy + ZETA2),
                1.0 / (ixx * ixx + ixy * ixy + ZETA2),
                1.0 / (ixy * ixy + iyy * iyy + ZETA2),
            ];
            for (plane, value) in row.iter_mut().zip(values) {
                plane[x / 2 + 1] = value;
            }
        }
    });
    planes
}

/// The edge masks of both colours.
fn edge_masks(ck: &Checker) -> [Planes; 2] {
    let mut planes = [Planes::zeros(2, ck), Planes::zeros(2, ck)];
    for_each_row(ck, &mut planes, |y, colour, row| {
        for x in (ck.start(y, colour)..ck.w).step_by(2) {
            row[ML][x / 2 + 1] = if x > 0 { 1.0 } else { 0.0 };
            row[MR][x / 2 + 1] = if x + 1 < ck.w { 1.0 } else { 0.0 };
        }
    });
    planes
}

/// The contiguous segments of one row of a colour: the pixels themselves (from `p`, also the
/// offset of their up and down neighbours in the other colour, one stride away) and their left
/// and right neighbours in the other colour (from `l`), `n` long.
#[derive(Clone, Copy)]
struct Segments {
    p: usize,
    l: usize,
    stride: usize,
    n: usize,
}

impl Segments {
    fn new(ck: &Checker, y: usize, colour: usize) -> Self {
        Self { p: (y + 1) * ck.stride() + 1, l: ck.left_offset(y, colour), stride: ck.stride(), n: ck.count(y, colour) }
    }

    fn own<'a>(&self, a: &'a [f32]) -> &'a [f32] {
        &a[self.p..self.p + self.n]
    }

    /// Left, right, up and down neighbours in the other colour's array `a`.
    fn around<'a>(&self, a: &'a [f32]) -> [&'a [f32]; 4] {
        let (l, p, n, s) = (self.l, self.p, self.n, self.stride);
        [&a[l..l + n], &a[l + 1..l + 1 + n], &a[p - s..p - s + n], &a[p + s..p + s + n]]
    }
}

/// The flow of one fixed-point iteration, split by colour: the base flow `(u, v)` the energy is
/// linearised at and the increments `(du, dv)` being solved for.
struct Flow<'a> {
    bu: &'a [Vec<f32>; 2],
    bv: &'a [Vec<f32>; 2],
    du: &'a [Vec<f32>; 2],
    dv: &'a [Vec<f32>; 2],
}

/// Smoothness weights `alpha * Psi'(|grad (u + du)|^2 + |grad (v + dv)|^2)` of both colours
/// (forward differences; none across the right and bottom borders) into `out` (one plane each).
fn smoothness(ck: &Checker, f: &Flow<'_>, masks: &[Planes; 2], alpha: f32, out: &mut [Planes; 2]) {
    for_each_row(ck, out, |y, colour, row| {
        let sg = Segments::new(ck, y, colour);
        let (own, other) = (colour, 1 - colour);
        let down = if y + 1 < ck.h { 1.0f32 } else { 0.0 };
        let (bu0, du0, bv0, dv0) = (sg.own(&f.bu[own]), sg.own(&f.du[own]), sg.own(&f.bv[own]), sg.own(&f.dv[own]));
        let mr = sg.own(masks[colour].plane(MR));
        let [_, bur, _, bud] = sg.around(&f.bu[other]);
        let [_, dur, _, dud] = sg.around(&f.du[other]);
        let [_, bvr, _, bvd] = sg.around(&f.bv[other]);
        let [_, dvr, _, dvd] = sg.around(&f.dv[other]);
        let out = &mut row[0][1..1 + sg.n];
        for i in 0..sg.n {
            let (fu, fv) = (bu0[i] + du0[i], bv0[i] + dv0[i]);
            let (ur, vr) = (bur[i] + dur[i] - fu, bvr[i] + dvr[i] - fv);
            let (ud, vd) = (bud[i] + dud[i] - fu, bvd[i] + dvd[i] - fv);
            let g = mr[i] * (ur * ur + vr * vr) + down * (ud * ud + vd * vd);
            out[i] = alpha * psi_prime(g);
        }
    });
}

/// The linear systems of both colours at the current increments into `sys`.
fn build_systems(
    ck: &Checker,
    f: &Flow<'_>,
    (data, masks, smooth): (&[Planes; 2], &[Planes; 2], &[Planes; 2]),
    p: &DisParams,
    sys: &mut [Planes; 2],
) {
    for_each_row(ck, sys, |y, colour, row| {
        let sg = Segments::new(ck, y, colour);
        let n = sg.n;
        let (own, other) = (colour, 1 - colour);
        let (up, down) = (if y > 0 { 1.0f32 } else { 0.0 }, if y + 1 < ck.h { 1.0f32 } else { 0.0 });
        let [ix, iy, iz, ixx, ixy, iyy, ixz, iyz, n1, n2, n3] =
            [IX, IY, IZ, IXX, IXY, IYY, IXZ, IYZ, N1, N2, N3].map(|k| sg.own(data[own].plane(k)));
        let (a, b, ml, mr) =
            (sg.own(&f.du[own]), sg.own(&f.dv[own]), sg.own(masks[own].plane(ML)), sg.own(masks[own].plane(MR)));
        let sk = sg.own(smooth[own].plane(0));
        let [sl, sr, su, sd] = sg.around(smooth[other].plane(0));
        let (uk, vk) = (sg.own(&f.bu[own]), sg.own(&f.bv[own]));
        let [ul, ur, uu, ud] = sg.around(&f.bu[other]);
        let [vl, vr, vu, vd] = sg.around(&f.bv[other]);
        let [a12, inv11, inv22, r1, r2, wl, wr, wu, wd] = row else { unreachable!("nine planes") };
        let mut outputs = [a12, inv11, inv22, r1, r2, wl, wr, wu, wd].map(|r| &mut r[1..1 + n]);
        let (delta, gamma, half) = (f32x4::splat(p.delta), f32x4::splat(p.gamma), f32x4::splat(0.5));
        let (up, down) = (f32x4::splat(up), f32x4::splat(down));
        for i in (0..n).step_by(4) {
            let m = (n - i).min(4);
            let at = |s: &[f32]| lanes(s, i, m);
            let (ix, iy, iz, ixx, ixy, iyy, ixz, iyz) =
                (at(ix), at(iy), at(iz), at(ixx), at(ixy), at(iyy), at(ixz), at(iyz));
            let (a, b) = (at(a), at(b));
            let q1 = delta * psi_prime4(iz + ix * a + iy * b) * at(n1);
            let q2 = gamma * psi_prime4(ixz + ixx * a + ixy * b) * at(n2);
            let q3 = gamma * psi_prime4(iyz + ixy * a + iyy * b) * at(n3);
            let a11 = q1 * ix * ix + q2 * ixx * ixx + q3 * ixy * ixy;
            let a22 = q1 * iy * iy + q2 * ixy * ixy + q3 * iyy * iyy;
            let b1 = q1 * ix * iz + q2 * ixx * ixz + q3 * ixy * iyz;
            let b2 = q1 * iy * iz + q2 * ixy * ixz + q3 * iyy * iyz;
            let sk = at(sk);
            let l = at(ml) * half * (sk + at(sl));
            let r = at(mr) * half * (sk + at(sr));
            let u = up * half * (sk + at(su));
            let d = down * half * (sk + at(sd));
            let sw = l + r + u + d;
            let (uk, vk) = (at(uk), at(vk));
            let values = [
                q1 * ix * iy + q2 * ixx * ixy + q3 * ixy * iyy,
                f32x4::ONE / (a11 + sw).max(f32x4::splat(1e-9)),
                f32x4::ONE / (a22 + sw).max(f32x4::splat(1e-9)),
                l * (at(ul) - uk) + r * (at(ur) - uk) + u * (at(uu) - uk) + d * (at(ud) - uk) - b1,
                l * (at(vl) - vk) + r * (at(vr) - vk) + u * (at(vu) - vk) + d * (at(vd) - vk) - b2,
                l,
                r,
                u,
                d,
            ];
            for (out, value) in outputs.iter_mut().zip(values) {
                store_lanes(out, i, m, value);
            }
        }
    });
}

/// Four values of `s` from `i` (`m < 4` of them at a row's end, the rest zero).
#[inline(always)]
fn lanes(s: &[f32], i: usize, m: usize) -> f32x4 {
    if m == 4 {
        return f32x4::new(s[i..i + 4].try_into().expect("four values"));
    }
    let mut a = [0.0f32; 4];
    a[..m].copy_from_slice(&s[i..i + m]);
    f32x4::new(a)
}

/// The first `m` lanes of `v` into `s` from `i`.
#[inline(always)]
fn store_lanes(s: &mut [f32], i: usize, m: usize, v: f32x4) {
    s[i..i + m].copy_from_slice(&v.to_array()[..m]);
}

/// [`psi_prime`] of the square of each lane.
#[inline(always)]
fn psi_prime4(t: f32x4) -> f32x4 {
    f32x4::splat(0.5) / (t * t + f32x4::splat(1e-6)).sqrt()
}

/// One SOR half-sweep over the pixels of `colour`: each reads only the other colour.
fn sor_sweep(ck: &Checker, colour: usize, sys: &Planes, du: &mut [Vec<f32>; 2], dv: &mut [Vec<f32>; 2], omega: f32) {
    let stride = ck.stride();
    let [du0, du1] = du;
    let [dv0, dv1] = dv;
    let (cur_u, other_u, cur_v, other_v) =
        if colour == 0 { (du0, &*du1, dv0, &*dv1) } else { (du1, &*du0, dv1, &*dv0) };
    let [a12, inv11, inv22, r1, r2, wl, wr, wu, wd] = [A12, INV11, INV22, R1, R2, WL, WR, WU, WD].map(|k| sys.plane(k));
    cur_u[stride..(ck.h + 1) * stride]
        .par_chunks_mut(stride)
        .zip(cur_v[stride..(ck.h + 1) * stride].par_chunks_mut(stride))
        .enumerate()
        .with_min_len(ROWS_PER_TASK)
        .for_each(|(y, (ru, rv))| {
            let sg = Segments::new(ck, y, colour);
            let n = sg.n;
            let [a12, inv11, inv22, r1, r2, wl, wr, wu, wd] =
                [a12, inv11, inv22, r1, r2, wl, wr, wu, wd].map(|a| sg.own(a));
            let [ul, ur, uu, ud] = sg.around(other_u);
            let [vl, vr, vu, vd] = sg.around(other_v);
            let (ru, rv) = (&mut ru[1..1 + n], &mut rv[1..1 + n]);
            for i in 0..n {
                let nu = wl[i] * ul[i] + wr[i] * ur[i] + wu[i] * uu[i] + wd[i] * ud[i];
                let nv = wl[i] * vl[i] + wr[i] * vr[i] + wu[i] * vu[i] + wd[i] * vd[i];
                let new_u = (r1[i] + nu - a12[i] * rv[i]) * inv11[i];
                let u = (1.0 - omega) * ru[i] + omega * new_u;
                ru[i] = u;
                let new_v = (r2[i] + nv - a12[i] * u) * inv22[i];
                rv[i] = (1.0 - omega) * rv[i] + omega * new_v;
            }
        });
}

/// Variational refinement of `(u, v)` in place (see the module documentation).
/// `i0x`, `i0y` are the first image's gradients (already computed for the patch search).
pub(super) fn refine(i0: &Img, i1: &Img, (i0x, i0y): (&Img, &Img), u: &mut Img, v: &mut Img, p: &DisParams) {
    if p.refinement_iterations == 0 {
        return;
    }
    let (w, h) = i0.dims();
    let ck = Checker::new(w, h);
    let first = gradients(i1);
    // Second derivatives: xx and xy from the x-gradients, yy from the y-gradients.
    let second = rayon::join(
        || rayon::join(|| gradients(i0x), || gradient_y(i0y)),
        || rayon::join(|| gradients(&first.0), || gradient_y(&first.1)),
    );
    let (((i0xx, i0xy), i0yy), ((i1xx, i1xy), i1yy)) = &second;
    let derivatives =
        Derivatives { i0, i1, i0x, i0y, i1x: &first.0, i1y: &first.1, i0xx, i0xy, i0yy, i1xx, i1xy, i1yy };
    let (us, vs) = (u.as_slice(), v.as_slice());
    let data = data_terms(&ck, &derivatives, us, vs);
    let masks = edge_masks(&ck);
    let (base_u, base_v) = (ck.split(us), ck.split(vs));
    let (mut du, mut dv) = (ck.zeros(), ck.zeros());
    let mut smooth = [Planes::zeros(1, &ck), Planes::zeros(1, &ck)];
    let mut systems = [Planes::zeros(SYSTEM_PLANES, &ck), Planes::zeros(SYSTEM_PLANES, &ck)];
    for _ in 0..p.refinement_iterations {
        let flow = Flow { bu: &base_u, bv: &base_v, du: &du, dv: &dv };
        smoothness(&ck, &flow, &masks, p.alpha, &mut smooth);
        build_systems(&ck, &flow, (&data, &masks, &smooth), p, &mut systems);
        for _ in 0..p.sor_iterations {
            for (c, sys) in systems.iter().enumerate() {
                sor_sweep(&ck, c, sys, &mut du, &mut dv, p.omega);
            }
        }
    }
    ck.add_to(&du, u.as_mut_slice());
    ck.add_to(&dv, v.as_mut_slice());
    // Every work array back to the pool for the next scale or call.
    let planes = data.into_iter().chain(masks).chain(systems).chain(smooth).map(|pl| pl.data);
    for b in planes.chain(du).chain(dv).chain(base_u).chain(base_v) {
        recycle(b);
    }
    let (((i0xx, i0xy), i0yy), ((i1xx, i1xy), i1yy)) = second;
    for img in [first.0, first.1, i0xx, i0xy, i0yy, i1xx, i1xy, i1yy] {
        recycle(img.into_vec());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lk::bilinear;

    /// Deterministic values in [0, 1) per pixel.
    fn noise(x: usize, y: usize, seed: usize) -> f32 {
        ((x.wrapping_mul(73_856_093) ^ y.wrapping_mul(19_349_663) ^ seed.wrapping_mul(83_492_791)) % 1000) as f32
            / 1000.0
    }

    fn field(w: usize, h: usize, seed: usize, scale: f32) -> Img {
        Img::from_fn(w, h, |x, y| scale * (noise(x, y, seed) - 0.5))
    }

    /// One fixed-point iteration's inputs on a small odd-sized image, in both layouts.
    struct Case {
        ck: Checker,
        images: [Img; 2],
        full: [Img; 4],
        data: [Planes; 2],
        masks: [Planes; 2],
        split: [[Vec<f32>; 2]; 4],
        smooth: [Planes; 2],
        systems: [Planes; 2],
    }

    fn case(w: usize, h: usize, p: &DisParams) -> Case {
        let i0 = Img::from_fn(w, h, |x, y| 255.0 * noise(x, y, 1));
        let i1 = Img::from_fn(w, h, |x, y| 255.0 * noise(x, y, 2));
        let (i0x, i0y) = gradients(&i0);
        let (i1x, i1y) = gradients(&i1);
        let (i0xx, i0xy) = gradients(&i0x);
        let (i1xx, i1xy) = gradients(&i1x);
        let (i0yy, i1yy) = (gradient_y(&i0y), gradient_y(&i1y));
        let d = Derivatives {
            i0: &i0,
            i1: &i1,
            i0x: &i0x,
            i0y: &i0y,
            i1x: &i1x,
            i1y: &i1y,
            i0xx: &i0xx,
            i0xy: &i0xy,
            i0yy: &i0yy,
            i1xx: &i1xx,
            i1xy: &i1xy,
            i1yy: &i1yy,
        };
        let ck = Checker::new(w, h);
        let full = [field(w, h, 3, 1.0), field(w, h, 4, 1.0), field(w, h, 5, 0.5), field(w, h, 6, 0.5)];
        let data = data_terms(&ck, &d, full[0].as_slice(), full[1].as_slice());
        let masks = edge_masks(&ck);
        let split = [0, 1, 2, 3].map(|k| ck.split(full[k].as_slice()));
        let flow = Flow { bu: &split[0], bv: &split[1], du: &split[2], dv: &split[3] };
        let mut smooth = [Planes::zeros(1, &ck), Planes::zeros(1, &ck)];
        smoothness(&ck, &flow, &masks, p.alpha, &mut smooth);
        let mut systems = [Planes::zeros(SYSTEM_PLANES, &ck), Planes::zeros(SYSTEM_PLANES, &ck)];
        build_systems(&ck, &flow, (&data, &masks, &smooth), p, &mut systems);
        Case { ck, images: [i0, i1], full, data, masks, split, smooth, systems }
    }

    fn close(a: f32, b: f32) -> bool {
        (a - b).abs() <= 1e-4 * a.abs().max(b.abs()).max(1.0)
    }

    /// Splitting by colour and adding back restores the image; the padding stays zero.
    #[test]
    fn colour_split_round_trips() {
        for (w, h) in [(7, 5), (8, 6), (1, 3), (2, 1)] {
            let ck = Checker::new(w, h);
            let full: Vec<f32> = (0..w * h).map(|k| k as f32 + 0.5).collect();
            let parts = ck.split(&full);
            let mut back = vec![0.0; w * h];
            ck.add_to(&parts, &mut back);
            assert_eq!(back, full, "{w}x{h}");
            let total: f32 = parts.iter().flatten().sum();
            assert_eq!(total, full.iter().sum::<f32>(), "{w}x{h}: values in the padding");
        }
    }

    /// The colour-split smoothness weights and linear systems equal the per-pixel formulas
    /// evaluated in the row-major layout (neighbours, image borders, both colours).
    #[test]
    fn systems_equal_the_per_pixel_formulas() {
        let p = DisParams::default();
        for (w, h) in [(13, 9), (8, 6)] {
            let c = case(w, h, &p);
            let [u, v, du, dv] = c.full.each_ref().map(|f| f.as_slice());
            let fu = |k: usize| u[k] + du[k];
            let fv = |k: usize| v[k] + dv[k];
            let smooth: Vec<f32> = (0..w * h)
                .map(|k| {
                    let (x, y) = (k % w, k / w);
                    let (r, b) = (if x + 1 < w { k + 1 } else { k }, if y + 1 < h { k + w } else { k });
                    let g = (fu(r) - fu(k)).powi(2)
                        + (fu(b) - fu(k)).powi(2)
                        + (fv(r) - fv(k)).powi(2)
                        + (fv(b) - fv(k)).powi(2);
                    p.alpha * psi_prime(g)
                })
                .collect();
            for y in 0..h {
                for x in 0..w {
                    let (k, colour, at) = (y * w + x, (x + y) % 2, c.ck.padded(x, y));
                    assert!(close(c.smooth[colour].plane(0)[at], smooth[k]), "smoothness at ({x}, {y})");
                    let dt = |q: usize| c.data[colour].plane(q)[at];
                    let res = |g0: usize, g1: usize, t: usize| dt(t) + dt(g0) * du[k] + dt(g1) * dv[k];
                    let q1 = p.delta * psi_prime(res(IX, IY, IZ).powi(2)) * dt(N1);
                    let q2 = p.gamma * psi_prime(res(IXX, IXY, IXZ).powi(2)) * dt(N2);
                    let q3 = p.gamma * psi_prime(res(IXY, IYY, IYZ).powi(2)) * dt(N3);
                    let quad = |a: usize, b: usize, e: usize, f: usize, g: usize, i: usize| {
                        q1 * dt(a) * dt(b) + q2 * dt(e) * dt(f) + q3 * dt(g) * dt(i)
                    };
                    let weight = |has: bool, q: usize| if has { 0.5 * (smooth[k] + smooth[q]) } else { 0.0 };
                    let l = weight(x > 0, k.wrapping_sub(1));
                    let r = weight(x + 1 < w, k + 1);
                    let up = weight(y > 0, k.wrapping_sub(w));
                    let dn = weight(y + 1 < h, k + w);
                    let sw = l + r + up + dn;
                    let lap = |f: &[f32]| {
                        let term = |wq: f32, q: usize| if wq > 0.0 { wq * (f[q] - f[k]) } else { 0.0 };
                        term(l, k.wrapping_sub(1)) + term(r, k + 1) + term(up, k.wrapping_sub(w)) + term(dn, k + w)
                    };
                    let want = [
                        quad(IX, IY, IXX, IXY, IXY, IYY),
                        1.0 / (quad(IX, IX, IXX, IXX, IXY, IXY) + sw).max(1e-9),
                        1.0 / (quad(IY, IY, IXY, IXY, IYY, IYY) + sw).max(1e-9),
                        lap(u) - quad(IX, IZ, IXX, IXZ, IXY, IYZ),
                        lap(v) - quad(IY, IZ, IXY, IXZ, IYY, IYZ),
                        l,
                        r,
                        up,
                        dn,
                    ];
                    for (plane, want) in want.into_iter().enumerate() {
                        let got = c.systems[colour].plane(plane)[at];
                        assert!(close(got, want), "{w}x{h} ({x}, {y}) plane {plane}: {got} vs {want}");
                    }
                    let ml = c.masks[colour].plane(ML)[at];
                    assert_eq!(ml, if x > 0 { 1.0 } else { 0.0 });
                    // The data term's placement: the temporal difference at the flowed position
                    // (none where the flow leaves the image).
                    let (fx, fy) = (x as f32 + u[k], y as f32 + v[k]);
                    let inside = fx >= 0.0 && fy >= 0.0 && fx <= (w - 1) as f32 && fy <= (h - 1) as f32;
                    let iz = if inside { bilinear(&c.images[1], fx, fy) - c.images[0].as_slice()[k] } else { 0.0 };
                    assert!(close(dt(IZ), iz), "{w}x{h} ({x}, {y}): temporal difference {} vs {iz}", dt(IZ));
                }
            }
        }
    }

    /// Red-black SOR sweeps converge to the solution of the systems: every pixel's equation
    /// `(a11 + sum w) du + a12 dv - sum_q w_q du_q = r1` (and its `v` twin) holds afterwards.
    #[test]
    fn sor_sweeps_solve_the_systems() {
        let (w, h) = (13, 9);
        // A weak smoothness weight keeps the system well conditioned (fast convergence).
        let c = case(w, h, &DisParams { alpha: 0.5, ..DisParams::default() });
        let (mut du, mut dv) = (c.ck.zeros(), c.ck.zeros());
        for _ in 0..1000 {
            for (colour, sys) in c.systems.iter().enumerate() {
                sor_sweep(&c.ck, colour, sys, &mut du, &mut dv, 1.5);
            }
        }
        let mut full = [vec![0.0f32; w * h], vec![0.0f32; w * h]];
        c.ck.add_to(&du, &mut full[0]);
        c.ck.add_to(&dv, &mut full[1]);
        let [fu, fv] = &full;
        for y in 0..h {
            for x in 0..w {
                let (k, colour, at) = (y * w + x, (x + y) % 2, c.ck.padded(x, y));
                let s = |q: usize| c.systems[colour].plane(q)[at];
                let around = |f: &[f32]| {
                    let mut sum = 0.0;
                    if x > 0 {
                        sum += s(WL) * f[k - 1];
                    }
                    if x + 1 < w {
                        sum += s(WR) * f[k + 1];
                    }
                    if y > 0 {
                        sum += s(WU) * f[k - w];
                    }
                    if y + 1 < h {
                        sum += s(WD) * f[k + w];
                    }
                    sum
                };
                let terms_u = [fu[k] / s(INV11), s(A12) * fv[k], -around(fu), -s(R1)];
                let terms_v = [fv[k] / s(INV22), s(A12) * fu[k], -around(fv), -s(R2)];
                for terms in [terms_u, terms_v] {
                    // Zero up to float rounding of its largest term.
                    let scale = terms.iter().fold(1.0f32, |m, t| m.max(t.abs()));
                    let sum: f32 = terms.iter().sum();
                    assert!(sum.abs() <= 1e-5 * scale, "({x}, {y}): {terms:?} sum to {sum}");
                }
            }
        }
        // The inputs themselves were split consistently.
        assert_eq!(c.split[0][0][c.ck.padded(0, 0)], c.full[0].as_slice()[0]);
    }
}
