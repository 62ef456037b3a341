//! Where a masked region of one image went in another when it moved further than the flow's
//! pyramid reaches (100-250 px between frames of a moving camera): an exhaustive search over
//! image shifts and turns about the optical axis on a coarse pyramid level, scored by the
//! zero-mean normalised cross-correlation of the region's grey values (so an exposure or
//! white-balance change does not count), then refined one level finer.
//!
//! The answer is a guide for tracking, not a result: the pipeline turns it into a predicted
//! motion and tracks the region's pixels again from there, and the registration's RANSAC
//! decides between that set of pairs and the others.

use crate::lk::{Gray, downsample};
use flowfilter_geometry::Mask;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Parameters of the coarse search.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CoarseSearchParams {
    /// Pyramid level of the exhaustive search (3: 1/8 resolution).
    pub level: usize,
    /// At most this many region pixels are compared (evenly thinned): the search's cost is
    /// bounded by this budget, not by the region's area.
    pub max_pixels: usize,
    /// Turns about the optical axis tried on either side of none, degrees (each step).
    pub turn_step_deg: f64,
    /// ...up to this turn, degrees.
    pub max_turn_deg: f64,
    /// A placement counts when at least this fraction of the region's pixels lands inside the
    /// target image.
    pub min_overlap: f64,
    /// The best placement is trusted when its correlation is at least this.
    pub min_score: f64,
}

impl Default for CoarseSearchParams {
    fn default() -> Self {
        Self { level: 3, max_pixels: 700, turn_step_deg: 10.0, max_turn_deg: 30.0, min_overlap: 0.5, min_score: 0.5 }
    }
}

/// Where the region went: a turn by `turn_rad` about `centre` (model image, full resolution),
/// then a shift by `shift` (pixels): `x' = centre + shift + R(turn) (x - centre)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CoarseMatch {
    /// The region's centre in the model image (pixels).
    pub centre: [f64; 2],
    /// Where the centre went, less the centre (pixels).
    pub shift: [f64; 2],
    /// Turn of the image about the centre (radians, image x towards y).
    pub turn_rad: f64,
    /// Zero-mean normalised cross-correlation of the placement, in [-1, 1].
    pub score: f64,
}

impl CoarseMatch {
    /// Where model pixel `(x, y)` goes.
    pub fn apply(&self, x: f64, y: f64) -> [f64; 2] {
        let (s, c) = self.turn_rad.sin_cos();
        let (dx, dy) = (x - self.centre[0], y - self.centre[1]);
        [self.centre[0] + self.shift[0] + c * dx - s * dy, self.centre[1] + self.shift[1] + s * dx + c * dy]
    }
}

impl CoarseMatch {
    /// Where target pixel `(x, y)` came from (the inverse of [`CoarseMatch::apply`]).
    pub fn apply_inverse(&self, x: f64, y: f64) -> [f64; 2] {
        let (s, c) = self.turn_rad.sin_cos();
        let (dx, dy) = (x - self.centre[0] - self.shift[0], y - self.centre[1] - self.shift[1]);
        [self.centre[0] + c * dx + s * dy, self.centre[1] - s * dx + c * dy]
    }
}

/// The region's pixels at one level: offsets from their centre and grey values.
struct Template {
    centre: [f64; 2],
    offsets: Vec<[f32; 2]>,
    values: Vec<f32>,
}

impl Template {
    /// The masked pixels of level `level`'s image (a pixel is in the region when the full
    /// resolution pixel it samples is: level `l`'s pixel `x` is pixel `x * 2^l`), evenly thinned to `max_pixels`.
    fn new(image: &Gray, mask: &Mask, level: usize, max_pixels: usize) -> Option<Self> {
        Self::predicted(image, mask, level, max_pixels, &|x, y| Some([x, y]))
    }

    /// The masked pixels of level `level`'s image at the positions `moved` sends them to
    /// (full resolution in and out; scaled to the level), evenly thinned to `max_pixels`.
    fn predicted(
        image: &Gray,
        mask: &Mask,
        level: usize,
        max_pixels: usize,
        moved: &dyn Fn(f64, f64) -> Option<[f64; 2]>,
    ) -> Option<Self> {
        let s = 1usize << level;
        let (w, h) = image.dims();
        let (mw, mh) = mask.dims();
        let mut kept = vec![];
        for y in 0..h {
            for x in 0..w {
                let (fx, fy) = ((x * s).min(mw - 1), (y * s).min(mh - 1));
                if *mask.at(fx, fy)
                    && let Some(q) = moved(fx as f64, fy as f64)
                {
                    kept.push(([q[0] / s as f64, q[1] / s as f64], *image.at(x, y)));
                }
            }
        }
        if kept.len() < 16 {
            return None;
        }
        let step = kept.len().div_ceil(max_pixels.max(16));
        let kept: Vec<([f64; 2], f32)> = kept.into_iter().step_by(step).collect();
        let n = kept.len() as f64;
        let centre = [kept.iter().map(|k| k.0[0]).sum::<f64>() / n, kept.iter().map(|k| k.0[1]).sum::<f64>() / n];
        Some(Self {
            centre,
            offsets: kept.iter().map(|k| [(k.0[0] - centre[0]) as f32, (k.0[1] - centre[1]) as f32]).collect(),
            values: kept.iter().map(|k| k.1).collect(),
        })
    }

    /// The template turned by `(sin, cos)` and centred at `base` (whose fractional part every
    /// placement of a search shares), as whole-pixel offsets from `base`'s integer part: the
    /// nearest target pixel of each template pixel at every placement `base + (i, j)` is its
    /// offset plus `(i, j)`, so the search scores a placement without rounding a position.
    fn turned(&self, base: (f64, f64), (sin, cos): (f32, f32)) -> TurnedTemplate<'_> {
        let (fu, fv) = ((base.0 - base.0.floor()) as f32, (base.1 - base.1.floor()) as f32);
        let offsets = self
            .offsets
            .iter()
            .map(|o| {
                let x = fu + (cos * o[0] - sin * o[1]);
                let y = fv + (sin * o[0] + cos * o[1]);
                [(x + 0.5).floor() as i32, (y + 0.5).floor() as i32]
            })
            .collect();
        TurnedTemplate { offsets, values: &self.values }
    }
}

/// A [`Template`] turned for one search: whole-pixel offsets and the grey values.
struct TurnedTemplate<'a> {
    offsets: Vec<[i32; 2]>,
    values: &'a [f32],
}

impl TurnedTemplate<'_> {
    /// Correlation of the template placed with its offsets from `(x, y)` in `target` (nearest
    /// samples), when at least `min_overlap` of it lands inside.
    fn score(&self, target: &Gray, (x, y): (i64, i64), min_overlap: f64) -> Option<f64> {
        let (w, h) = target.dims();
        let data = target.as_slice();
        // A placement stops counting once more pixels have fallen outside than it may lose.
        let allowed_misses = ((1.0 - min_overlap) * self.offsets.len() as f64).max(0.0) as usize;
        let (mut misses, mut n) = (0usize, 0usize);
        let (mut sm, mut st, mut smm, mut stt, mut smt) = (0.0f64, 0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for (o, &m) in self.offsets.iter().zip(self.values) {
            let (xi, yi) = (x + i64::from(o[0]), y + i64::from(o[1]));
            if xi < 0 || yi < 0 || xi >= w as i64 || yi >= h as i64 {
                misses += 1;
                if misses > allowed_misses {
                    return None;
                }
                continue;
            }
            let t = data[yi as usize * w + xi as usize];
            let (m, t) = (f64::from(m), f64::from(t));
            n += 1;
            sm += m;
            st += t;
            smm += m * m;
            stt += t * t;
            smt += m * t;
        }
        if (n as f64) < min_overlap * self.offsets.len() as f64 || n < 16 {
            return None;
        }
        let nf = n as f64;
        let (vm, vt) = (smm - sm * sm / nf, stt - st * st / nf);
        if vm <= 1e-9 || vt <= 1e-9 {
            return None;
        }
        Some((smt - sm * st / nf) / (vm * vt).sqrt())
    }
}

/// The two images at the search's pyramid level and one level finer, built once per pair and
/// shared by [`coarse_search`] and [`search_hypotheses`].
pub struct SearchImages {
    level: usize,
    coarse: [Gray; 2],
    fine: [Gray; 2],
}

impl SearchImages {
    /// The pyramids of `model` and `target` down to `level` (at least 1).
    pub fn new(model: &Gray, target: &Gray, level: usize) -> Self {
        let level = level.max(1);
        let down = |image: &Gray| {
            let fine = (1..level).fold(image.clone(), |img, _| downsample(&img));
            let coarse = downsample(&fine);
            (coarse, fine)
        };
        let ((cm, fm), (ct, ft)) = (down(model), down(target));
        Self { level, coarse: [cm, ct], fine: [fm, ft] }
    }

    /// The search's pyramid level.
    pub fn level(&self) -> usize {
        self.level
    }
}

/// Placements of a template's centre: `base` plus each whole-pixel step (the steps share
/// `base`'s fractional part, so each turn's offsets are rounded once).
struct Placements {
    base: (f64, f64),
    steps: Vec<(i64, i64)>,
}

impl Placements {
    /// Every pixel of a `(w, h)` image.
    fn everywhere((w, h): (usize, usize)) -> Self {
        let steps = (0..h as i64).flat_map(|y| (0..w as i64).map(move |x| (x, y))).collect();
        Self { base: (0.0, 0.0), steps }
    }

    /// `centre` and the pixels up to `reach` from it in either direction.
    fn around(centre: [f64; 2], reach: i64) -> Self {
        let steps = (-reach..=reach).flat_map(|j| (-reach..=reach).map(move |i| (i, j))).collect();
        Self { base: (centre[0], centre[1]), steps }
    }

    /// Placement `k`'s centre.
    fn centre(&self, k: usize) -> (f64, f64) {
        (self.base.0 + self.steps[k].0 as f64, self.base.1 + self.steps[k].1 as f64)
    }
}

/// The best placement of `template` in `target` over `placements` and `turns` (radians):
/// score, centre, turn. Ties go to the first in order (the same answer with any thread count).
fn best_placement(
    template: &Template,
    target: &Gray,
    placements: &Placements,
    turns: &[f64],
    min_overlap: f64,
) -> Option<(f64, (f64, f64), f64)> {
    let turned: Vec<TurnedTemplate<'_>> = turns
        .iter()
        .map(|t| {
            let (s, c) = t.sin_cos();
            template.turned(placements.base, (s as f32, c as f32))
        })
        .collect();
    let (bx, by) = (placements.base.0.floor() as i64, placements.base.1.floor() as i64);
    let work: Vec<(usize, usize)> =
        (0..turns.len()).flat_map(|t| (0..placements.steps.len()).map(move |c| (t, c))).collect();
    work.par_iter()
        .with_min_len(64)
        .filter_map(|&(t, c)| {
            let (i, j) = placements.steps[c];
            turned[t].score(target, (bx + i, by + j), min_overlap).map(|sc| (sc, t, c))
        })
        .reduce_with(|a, b| if b.0 > a.0 || (b.0 == a.0 && (b.1, b.2) < (a.1, a.2)) { b } else { a })
        .map(|(sc, t, c)| (sc, placements.centre(c), turns[t]))
}

/// Where the `mask`ed region of `model` went in `target` (see the module documentation);
/// `None` when the region is too small at the search's level or no placement correlates at
/// least [`CoarseSearchParams::min_score`].
pub fn coarse_search(images: &SearchImages, mask: &Mask, p: &CoarseSearchParams) -> Option<CoarseMatch> {
    let level = images.level;
    let [coarse_model, coarse_target] = &images.coarse;
    let template = Template::new(coarse_model, mask, level, p.max_pixels)?;
    let steps = if p.turn_step_deg > 0.0 { (p.max_turn_deg / p.turn_step_deg).floor() as i64 } else { 0 };
    let turns: Vec<f64> = (-steps..=steps).map(|k| (k as f64 * p.turn_step_deg).to_radians()).collect();
    let everywhere = Placements::everywhere(coarse_target.dims());
    let (_, (u, v), turn) = best_placement(&template, coarse_target, &everywhere, &turns, p.min_overlap)?;
    // One level finer: +-3 px around the coarse placement, the turn within half a step.
    let finer = level - 1;
    let [fine_model, fine_target] = &images.fine;
    let fine = Template::new(fine_model, mask, finer, p.max_pixels * 2)?;
    // Level `finer`'s coordinates of the coarse placement's centre: the fine template's centre
    // goes where the coarse match sends it.
    let s = 2.0;
    let to_fine = |c: [f64; 2]| [c[0] * s, c[1] * s];
    let coarse_centre = to_fine(template.centre);
    let (sin, cos) = turn.sin_cos();
    let d = [fine.centre[0] - coarse_centre[0], fine.centre[1] - coarse_centre[1]];
    let guess = [u * s + cos * d[0] - sin * d[1], v * s + sin * d[0] + cos * d[1]];
    let near = Placements::around(guess, 3);
    let half = p.turn_step_deg.to_radians() / 2.0;
    let fine_turns = [turn - half / 2.0, turn, turn + half / 2.0];
    let (score, (fu, fv), fturn) = best_placement(&fine, fine_target, &near, &fine_turns, p.min_overlap)?;
    if score < p.min_score {
        return None;
    }
    let scale = f64::from(1u32 << finer);
    let full = |c: f64| c * scale;
    let centre = [full(fine.centre[0]), full(fine.centre[1])];
    Some(CoarseMatch { centre, shift: [full(fu) - centre[0], full(fv) - centre[1]], turn_rad: fturn, score })
}

/// A placement of a hypothesis's predicted template (see [`search_hypotheses`]): which
/// hypothesis, the shift of its predicted pixels (full resolution) and the correlation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HypothesisMatch {
    /// Index of the hypothesis.
    pub index: usize,
    /// Shift added to every predicted position (pixels).
    pub shift: [f64; 2],
    /// Zero-mean normalised cross-correlation of the placement.
    pub score: f64,
}

/// Where the masked region went under each of `count` hypotheses of its motion:
/// `predict(h, x, y)` is where hypothesis `h` moves model pixel `(x, y)` (full resolution;
/// `None` when it cannot say, e.g. without depth), and `near` shifts every prediction first.
/// Each hypothesis's predicted template (the model's grey values at their predicted
/// positions) is placed at every shift of the search's level, as [`coarse_search`] places the
/// region, then refined one level finer; the best placement of all is returned. Hypotheses stand for motions that
/// are not a shift and a turn in the image (a camera circling the object).
pub fn search_hypotheses(
    images: &SearchImages,
    mask: &Mask,
    p: &CoarseSearchParams,
    near: &CoarseMatch,
    count: usize,
    predict: &(dyn Fn(usize, f64, f64) -> Option<[f64; 2]> + Sync),
) -> Option<HypothesisMatch> {
    let level = images.level;
    let ([coarse_model, coarse_target], [fine_model, fine_target]) = (&images.coarse, &images.fine);
    let everywhere = Placements::everywhere(coarse_target.dims());
    let searched: Vec<Option<(f64, [f64; 2])>> = (0..count)
        .into_par_iter()
        .map(|h| {
            let moved = |x: f64, y: f64| predict(h, x, y).map(|q| [q[0] + near.shift[0], q[1] + near.shift[1]]);
            let coarse = Template::predicted(coarse_model, mask, level, p.max_pixels, &moved)?;
            let s = f64::from(1u32 << level);
            let (_, (u, v), _) = best_placement(&coarse, coarse_target, &everywhere, &[0.0], p.min_overlap)?;
            let coarse_shift = [(u - coarse.centre[0]) * s, (v - coarse.centre[1]) * s];
            let fine = Template::predicted(fine_model, mask, level - 1, p.max_pixels * 2, &|x, y| {
                moved(x, y).map(|q| [q[0] + coarse_shift[0], q[1] + coarse_shift[1]])
            })?;
            let fs = s / 2.0;
            let near_fine = Placements::around(fine.centre, 3);
            let (score, (fu, fv), _) = best_placement(&fine, fine_target, &near_fine, &[0.0], p.min_overlap)?;
            let shift = [
                near.shift[0] + coarse_shift[0] + (fu - fine.centre[0]) * fs,
                near.shift[1] + coarse_shift[1] + (fv - fine.centre[1]) * fs,
            ];
            Some((score, shift))
        })
        .collect();
    let (index, (score, shift)) = searched.into_iter().enumerate().filter_map(|(h, r)| r.map(|r| (h, r))).fold(
        None,
        |best: Option<(usize, (f64, [f64; 2]))>, c| match best {
            Some(b) if b.1.0 >= c.1.0 => Some(b),
            _ => Some(c),
        },
    )?;
    (score >= p.min_score).then_some(HypothesisMatch { index, shift, score })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth random-looking texture.
    fn texture(w: usize, h: usize, phase: f64) -> impl Fn(f64, f64) -> f32 {
        move |x: f64, y: f64| {
            let _ = (w, h);
            let v = (x * 0.071 + phase).sin() * (y * 0.053).cos()
                + 0.6 * (x * 0.023 - y * 0.041).sin()
                + 0.4 * ((x + y) * 0.11).cos() * (x * 0.017).sin();
            (0.5 + 0.2 * v) as f32
        }
    }

    #[test]
    fn finds_a_region_moved_far_and_turned_under_an_exposure_change() {
        let (w, h) = (320, 240);
        let tex = texture(w, h, 0.3);
        let model = Gray::from_fn(w, h, |x, y| tex(x as f64, y as f64));
        let mask = Mask::from_fn(w, h, |x, y| (x as f64 - 110.0).powi(2) + (y as f64 - 100.0).powi(2) < 45.0 * 45.0);
        for (shift, turn_deg) in [([120.0, 60.0], 0.0), ([150.0, -40.0], 12.0), ([-90.0, 70.0], -20.0)] {
            let truth = CoarseMatch { centre: [110.0, 100.0], shift, turn_rad: f64::to_radians(turn_deg), score: 1.0 };
            // Target: the model warped by the inverse of the motion, 30% brighter.
            let inv = |x: f64, y: f64| {
                let (s, c) = truth.turn_rad.sin_cos();
                let (dx, dy) = (x - 110.0 - shift[0], y - 100.0 - shift[1]);
                (110.0 + c * dx + s * dy, 100.0 - s * dx + c * dy)
            };
            let target = Gray::from_fn(w, h, |x, y| {
                let (u, v) = inv(x as f64, y as f64);
                1.3 * tex(u, v) - 0.1
            });
            let found = coarse_search(&SearchImages::new(&model, &target, 3), &mask, &CoarseSearchParams::default())
                .expect("found");
            for (x, y) in [(110.0, 100.0), (140.0, 120.0), (80.0, 80.0)] {
                let (a, b) = (found.apply(x, y), truth.apply(x, y));
                let e = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
                assert!(e < 6.0, "{shift:?} {turn_deg}: ({x}, {y}) -> {a:?}, truth {b:?}");
            }
            assert!(found.score > 0.8, "{}", found.score);
            let back = found.apply_inverse(found.apply(90.0, 130.0)[0], found.apply(90.0, 130.0)[1]);
            assert!((back[0] - 90.0).abs() < 1e-9 && (back[1] - 130.0).abs() < 1e-9, "{back:?}");
        }
    }

    #[test]
    fn a_flat_region_or_an_unrelated_image_gives_no_match() {
        let (w, h) = (320, 240);
        let tex = texture(w, h, 0.0);
        let mask = Mask::from_fn(w, h, |x, y| (60..140).contains(&x) && (60..140).contains(&y));
        let flat = Gray::filled(w, h, 0.5);
        assert!(coarse_search(&SearchImages::new(&flat, &flat, 3), &mask, &CoarseSearchParams::default()).is_none());
        let model = Gray::from_fn(w, h, |x, y| tex(x as f64, y as f64));
        let noise = Gray::from_fn(w, h, |x, y| ((x * 7919 + y * 104_729) % 97) as f32 / 97.0);
        let m = coarse_search(&SearchImages::new(&model, &noise, 3), &mask, &CoarseSearchParams::default());
        assert!(m.is_none(), "{m:?}");
    }
}
