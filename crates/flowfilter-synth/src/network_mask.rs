//! Object masks as a segmentation network gives them: the true mask eroded or dilated, shifted,
//! cut by a straight edge, bleeding onto the background beside it, or missing altogether.
//!
//! A [`NetworkMaskModel`] holds the bounds; [`NetworkMaskModel::draw`] draws one frame's
//! [`MaskDefects`] from a seeded generator, and [`MaskDefects::apply`] applies them to a true
//! mask. The same seed gives the same mask.

use flowfilter_geometry::Mask;
use rand::Rng;
use serde::{Deserialize, Serialize};

/// Bounds of the defects of a segmentation network's masks.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NetworkMaskModel {
    /// The boundary moves in (erosion) or out (dilation) by up to this many pixels.
    pub grow_px: f64,
    /// The mask is shifted by up to this many pixels along each axis.
    pub shift_px: f64,
    /// Chance that a straight edge cuts part of the object off.
    pub cut_probability: f64,
    /// The part cut off: between these fractions of the mask's extent across the cut.
    pub cut_fraction: (f64, f64),
    /// Chance that the mask bleeds onto the background: a blob beside the boundary.
    pub bleed_probability: f64,
    /// The blob's radius, as fractions of the mask's mean radius.
    pub bleed_radius: (f64, f64),
    /// Chance that the network gives no mask for this frame.
    pub missing_probability: f64,
}

impl NetworkMaskModel {
    /// What a segmentation network trained on the objects gives on a cluttered shelf: a
    /// boundary up to 8 px off, shifts of up to 6 px, a third of the masks cut short (10-30%
    /// of the object missing), a third bleeding onto the background (a blob of 30-60% of the
    /// object's radius), one mask in twelve missing.
    pub const SHELF_NETWORK: Self = Self {
        grow_px: 8.0,
        shift_px: 6.0,
        cut_probability: 0.33,
        cut_fraction: (0.1, 0.3),
        bleed_probability: 0.33,
        bleed_radius: (0.3, 0.6),
        missing_probability: 1.0 / 12.0,
    };

    /// Masks as they are.
    pub const EXACT: Self = Self {
        grow_px: 0.0,
        shift_px: 0.0,
        cut_probability: 0.0,
        cut_fraction: (0.0, 0.0),
        bleed_probability: 0.0,
        bleed_radius: (0.0, 0.0),
        missing_probability: 0.0,
    };

    /// Draw one frame's defects.
    pub fn draw(&self, rng: &mut impl Rng) -> MaskDefects {
        let grow_px = symmetric(rng, self.grow_px);
        let shift = (symmetric(rng, self.shift_px), symmetric(rng, self.shift_px));
        let cut = chance(rng, self.cut_probability)
            .then(|| (rng.random_range(0.0..std::f64::consts::TAU), within(rng, self.cut_fraction)));
        let bleed = chance(rng, self.bleed_probability)
            .then(|| (rng.random_range(0.0..std::f64::consts::TAU), within(rng, self.bleed_radius)));
        let missing = chance(rng, self.missing_probability);
        MaskDefects { grow_px, shift, cut, bleed, missing }
    }
}

fn symmetric(rng: &mut impl Rng, bound: f64) -> f64 {
    if bound > 0.0 { rng.random_range(-bound..=bound) } else { 0.0 }
}

fn chance(rng: &mut impl Rng, p: f64) -> bool {
    p > 0.0 && rng.random_bool(p.min(1.0))
}

fn within(rng: &mut impl Rng, (lo, hi): (f64, f64)) -> f64 {
    if hi > lo { rng.random_range(lo..=hi) } else { lo }
}

/// One frame's defects, drawn by [`NetworkMaskModel::draw`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MaskDefects {
    /// Boundary moved out (positive) or in, pixels.
    pub grow_px: f64,
    /// Shift along x and y, pixels.
    pub shift: (f64, f64),
    /// A cut: the direction (radians) from the mask's centre towards the part cut off, and the
    /// fraction of the mask's extent along it that is cut.
    pub cut: Option<(f64, f64)>,
    /// A bleed: the direction (radians) from the centre to the boundary point where a blob
    /// joins, and the blob's radius as a fraction of the mask's mean radius.
    pub bleed: Option<(f64, f64)>,
    /// The network gave no mask.
    pub missing: bool,
}

impl MaskDefects {
    /// The true mask as the network would give it; `None` when it gives none, or when nothing
    /// is left of it.
    pub fn apply(&self, truth: &Mask) -> Option<Mask> {
        if self.missing {
            return None;
        }
        let (w, h) = truth.dims();
        let mut mask = grown(truth, self.grow_px);
        let stats = MaskShape::of(&mask)?;
        if let Some((angle, fraction)) = self.cut {
            let dir = (angle.cos(), angle.sin());
            let (lo, hi) = stats.extent_along(&mask, dir);
            let edge = hi - fraction * (hi - lo);
            mask = Mask::from_fn(w, h, |x, y| {
                *mask.at(x, y) && (x as f64 - stats.cx) * dir.0 + (y as f64 - stats.cy) * dir.1 <= edge
            });
        }
        if let Some((angle, radius)) = self.bleed {
            let dir = (angle.cos(), angle.sin());
            let (_, hi) = stats.extent_along(&mask, dir);
            let r = radius * stats.radius;
            let (bx, by) = (stats.cx + dir.0 * hi, stats.cy + dir.1 * hi);
            mask = Mask::from_fn(w, h, |x, y| {
                *mask.at(x, y) || (x as f64 - bx).powi(2) + (y as f64 - by).powi(2) <= r * r
            });
        }
        let moved = shifted(&mask, (self.shift.0.round() as i64, self.shift.1.round() as i64));
        moved.as_slice().iter().any(|m| *m).then_some(moved)
    }
}

/// Centre and mean radius of a mask.
struct MaskShape {
    cx: f64,
    cy: f64,
    radius: f64,
}

impl MaskShape {
    fn of(mask: &Mask) -> Option<Self> {
        let (w, _) = mask.dims();
        let (mut n, mut sx, mut sy) = (0usize, 0.0, 0.0);
        for (i, _) in mask.as_slice().iter().enumerate().filter(|(_, m)| **m) {
            n += 1;
            sx += (i % w) as f64;
            sy += (i / w) as f64;
        }
        (n > 0).then(|| Self { cx: sx / n as f64, cy: sy / n as f64, radius: (n as f64 / std::f64::consts::PI).sqrt() })
    }

    /// The smallest and largest offset of the mask's pixels from the centre along `dir`.
    fn extent_along(&self, mask: &Mask, dir: (f64, f64)) -> (f64, f64) {
        let (w, _) = mask.dims();
        let offsets = mask
            .as_slice()
            .iter()
            .enumerate()
            .filter(|(_, m)| **m)
            .map(|(i, _)| ((i % w) as f64 - self.cx) * dir.0 + ((i / w) as f64 - self.cy) * dir.1);
        offsets.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), o| (lo.min(o), hi.max(o)))
    }
}

/// `mask` moved by `(dx, dy)` pixels (what moves in from beyond the border is background).
pub(crate) fn shifted(mask: &Mask, (dx, dy): (i64, i64)) -> Mask {
    let (w, h) = mask.dims();
    Mask::from_fn(w, h, |x, y| {
        let (sx, sy) = (x as i64 - dx, y as i64 - dy);
        sx >= 0 && sy >= 0 && (sx as usize) < w && (sy as usize) < h && *mask.at(sx as usize, sy as usize)
    })
}

/// `mask` with its boundary moved out by `px` pixels (in for negative `px`): pixels within
/// that Euclidean distance of the mask (dilation), or further than it from the background
/// (erosion).
pub fn grown(mask: &Mask, px: f64) -> Mask {
    if px.abs() < 0.5 {
        return mask.clone();
    }
    let (w, h) = mask.dims();
    let outside = px > 0.0;
    // Distance to the nearest pixel of the other kind: object pixels when growing.
    let d2 = squared_distance_to(mask, outside);
    let r2 = px * px;
    Mask::from_fn(w, h, |x, y| {
        let d = d2[y * w + x];
        if outside { *mask.at(x, y) || d <= r2 } else { *mask.at(x, y) && d > r2 }
    })
}

/// Squared Euclidean distance of every pixel to the nearest pixel whose mask value is `to`
/// (Felzenszwalb and Huttenlocher's separable transform: exact, linear in the pixels).
fn squared_distance_to(mask: &Mask, to: bool) -> Vec<f64> {
    let (w, h) = mask.dims();
    let far = ((w * w + h * h) as f64) * 4.0;
    let mut d: Vec<f64> = mask.as_slice().iter().map(|&m| if m == to { 0.0 } else { far }).collect();
    let mut line = vec![0.0; w.max(h)];
    let mut out = vec![0.0; w.max(h)];
    for x in 0..w {
        for y in 0..h {
            line[y] = d[y * w + x];
        }
        lower_envelope(&line[..h], &mut out[..h]);
        for y in 0..h {
            d[y * w + x] = out[y];
        }
    }
    for y in 0..h {
        line[..w].copy_from_slice(&d[y * w..(y + 1) * w]);
        lower_envelope(&line[..w], &mut out[..w]);
        d[y * w..(y + 1) * w].copy_from_slice(&out[..w]);
    }
    d
}

/// One dimension of the squared distance transform: `out[q] = min_p f[p] + (q - p)^2`.
fn lower_envelope(f: &[f64], out: &mut [f64]) {
    let n = f.len();
    let mut v = vec![0usize; n];
    let mut z = vec![0.0f64; n + 1];
    let mut k = 0usize;
    z[0] = f64::NEG_INFINITY;
    z[1] = f64::INFINITY;
    let cross = |q: usize, p: usize| {
        let (qf, pf) = (q as f64, p as f64);
        ((f[q] + qf * qf) - (f[p] + pf * pf)) / (2.0 * (qf - pf))
    };
    for q in 1..n {
        let mut s = cross(q, v[k]);
        while s <= z[k] {
            k -= 1;
            s = cross(q, v[k]);
        }
        k += 1;
        v[k] = q;
        z[k] = s;
        z[k + 1] = f64::INFINITY;
    }
    k = 0;
    for (q, o) in out.iter_mut().enumerate() {
        while z[k + 1] < q as f64 {
            k += 1;
        }
        let dq = q as f64 - v[k] as f64;
        *o = dq * dq + f[v[k]];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn disc(w: usize, h: usize, cx: f64, cy: f64, r: f64) -> Mask {
        Mask::from_fn(w, h, |x, y| (x as f64 - cx).powi(2) + (y as f64 - cy).powi(2) <= r * r)
    }

    fn area(m: &Mask) -> usize {
        m.as_slice().iter().filter(|v| **v).count()
    }

    #[test]
    fn growing_and_shrinking_move_a_disc_boundary_by_the_radius() {
        let d = disc(100, 80, 50.0, 40.0, 20.0);
        let pi = std::f64::consts::PI;
        for (px, r) in [(5.0, 25.0), (-5.0, 15.0), (0.2, 20.0)] {
            let a = area(&grown(&d, px)) as f64;
            assert!((a / (pi * r * r) - 1.0).abs() < 0.06, "{px}: {a}");
        }
        // Brute force agrees with the transform on a ring of pixels.
        let g = grown(&d, 3.0);
        for (x, y) in [(73usize, 40usize), (74, 40), (50, 63), (50, 64)] {
            let near = (0..100).any(|u| {
                (0..80).any(|v| *d.at(u, v) && ((u as f64 - x as f64).powi(2) + (v as f64 - y as f64).powi(2)) <= 9.0)
            });
            assert_eq!(*g.at(x, y), near, "({x}, {y})");
        }
    }

    #[test]
    fn defects_cut_bleed_shift_and_drop_masks_as_drawn() {
        let d = disc(120, 100, 60.0, 50.0, 25.0);
        let only = |defects: MaskDefects| defects.apply(&d);
        let none = MaskDefects { grow_px: 0.0, shift: (0.0, 0.0), cut: None, bleed: None, missing: false };
        assert_eq!(only(none).unwrap(), d);
        assert!(only(MaskDefects { missing: true, ..none }).is_none());
        // A cut of 30% of the extent towards +x keeps the left side.
        let cut = only(MaskDefects { cut: Some((0.0, 0.3)), ..none }).unwrap();
        assert!(!*cut.at(84, 50) && *cut.at(36, 50) && area(&cut) < area(&d) * 85 / 100);
        // A bleed towards -y adds pixels above the disc.
        let bled = only(MaskDefects { bleed: Some((-std::f64::consts::FRAC_PI_2, 0.5)), ..none }).unwrap();
        assert!(*bled.at(60, 20) && !*d.at(60, 20) && area(&bled) > area(&d));
        let moved = only(MaskDefects { shift: (4.0, -3.0), ..none }).unwrap();
        assert!(*moved.at(88, 47) && !*d.at(88, 47));
        // Seeded: the same seed draws the same defects; the shelf model drops some masks.
        let model = NetworkMaskModel::SHELF_NETWORK;
        let draws = |seed| (0..48).map(|_| model.draw(&mut ChaCha8Rng::seed_from_u64(seed))).collect::<Vec<_>>();
        assert_eq!(draws(3), draws(3));
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let all: Vec<MaskDefects> = (0..600).map(|_| model.draw(&mut rng)).collect();
        let missing = all.iter().filter(|d| d.missing).count();
        assert!((25..80).contains(&missing), "{missing}");
        assert!(all.iter().all(|d| d.grow_px.abs() <= 8.0 && d.shift.0.abs() <= 6.0));
        assert_eq!(NetworkMaskModel::EXACT.draw(&mut rng).apply(&d).unwrap(), d);
    }
}
