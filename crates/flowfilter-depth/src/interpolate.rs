//! Filling mask pixels that received no depth, never across a discontinuity.

use crate::config::{InterpolationConfig, InterpolationMethod};
use flowfilter_geometry::{DepthMap, Mask};
use rayon::prelude::*;

/// The nearest valid sample of the `w x h` map `src` from `(x, y)` walking `dir`, within `r`
/// steps: `(distance, z)`.
fn walk(
    src: &[f32],
    (w, h): (usize, usize),
    (x, y): (usize, usize),
    (dx, dy): (isize, isize),
    r: usize,
) -> Option<(f32, f32)> {
    for s in 1..=r as isize {
        let (nx, ny) = (x as isize + dx * s, y as isize + dy * s);
        if nx < 0 || ny < 0 || nx >= w as isize || ny >= h as isize {
            return None;
        }
        let z = src[ny as usize * w + nx as usize];
        if z > 0.0 {
            return Some((s as f32, z));
        }
    }
    None
}

/// Fill mask pixels without depth from samples within `max_radius_px` along their row and
/// column. `Linear` interpolates between the samples on opposite sides (when they differ by at
/// most `max_step_m`) and averages the row and column estimates; `Nearest` copies the nearest
/// sample. Only original samples are used. Returns the filled map and the number of pixels filled.
pub fn fill_holes(depth: &DepthMap, mask: &Mask, cfg: &InterpolationConfig) -> (DepthMap, usize) {
    let mut out = depth.clone();
    let filled = fill_holes_in_place(&mut out, mask, cfg);
    (out, filled)
}

/// [`fill_holes`] without copying the map: the fills are computed from the original samples
/// (rayon over the mask's rows), then written. Returns the number of pixels filled.
pub fn fill_holes_in_place(depth: &mut DepthMap, mask: &Mask, cfg: &InterpolationConfig) -> usize {
    if cfg.method == InterpolationMethod::None {
        return 0;
    }
    fill_holes_in(depth, mask, crate::register::mask_bbox(mask), cfg)
}

/// [`fill_holes_in_place`] given the mask's bounding box (`None` for an empty mask).
pub(crate) fn fill_holes_in(
    depth: &mut DepthMap,
    mask: &Mask,
    mask_box: Option<(usize, usize, usize, usize)>,
    cfg: &InterpolationConfig,
) -> usize {
    let Some((x0, y0, x1, y1)) = mask_box.filter(|_| cfg.method != InterpolationMethod::None) else { return 0 };
    let (w, h) = depth.dims();
    let src = depth.as_slice();
    let m = mask.as_slice();
    let r = cfg.max_radius_px;
    let step = cfg.max_step_m as f32;
    let fills: Vec<(usize, f32)> = (y0..=y1)
        .into_par_iter()
        .flat_map_iter(|y| {
            let mut row = Vec::new();
            for x in x0..=x1 {
                let k = y * w + x;
                if src[k] > 0.0 || !m[k] {
                    continue;
                }
                let dirs = [(-1, 0), (1, 0), (0, -1), (0, 1)].map(|d| walk(src, (w, h), (x, y), d, r));
                let z = match cfg.method {
                    InterpolationMethod::Nearest => {
                        dirs.iter().flatten().min_by(|a, b| a.0.total_cmp(&b.0)).map_or(0.0, |&(_, z)| z)
                    }
                    _ => {
                        let mut acc = (0.0f32, 0u32);
                        for (a, b) in [(dirs[0], dirs[1]), (dirs[2], dirs[3])] {
                            if let (Some((da, za)), Some((db, zb))) = (a, b)
                                && (za - zb).abs() <= step
                            {
                                acc.0 += za + (zb - za) * da / (da + db);
                                acc.1 += 1;
                            }
                        }
                        if acc.1 > 0 { acc.0 / acc.1 as f32 } else { 0.0 }
                    }
                };
                if z > 0.0 {
                    row.push((k, z));
                }
            }
            row
        })
        .collect();
    let out = depth.as_mut_slice();
    for &(k, z) in &fills {
        out[k] = z;
    }
    fills.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn linear_fill_is_exact_on_planes_and_stops_at_steps() {
        // A plane z = 0.5 + 0.002 x with every other column missing, and a step at x = 10.
        let d = DepthMap::from_fn(20, 5, |x, _| {
            if x % 2 == 1 {
                0.0
            } else if x < 10 {
                0.5 + 0.002 * x as f32
            } else {
                0.9
            }
        });
        let mask = Mask::filled(20, 5, true);
        let (f, n) = fill_holes(&d, &mask, &InterpolationConfig::default());
        assert!((f.at(5, 2) - 0.51).abs() < 1e-6);
        assert_eq!(*f.at(9, 2), 0.0, "between 0.516 and 0.9: a step, not filled");
        assert!(n > 0);
        let near = InterpolationConfig { method: InterpolationMethod::Nearest, ..Default::default() };
        let (f, _) = fill_holes(&d, &mask, &near);
        assert!(*f.at(9, 2) > 0.0, "nearest copies one side");
        let none = InterpolationConfig { method: InterpolationMethod::None, ..Default::default() };
        assert_eq!(fill_holes(&d, &mask, &none).1, 0);
    }
}
