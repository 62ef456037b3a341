//! Edge filters: the BigBIRD discontinuity filter and the paper's Gaussian window filter.
//!
//! Both work on metric depth maps (0 = no depth) of any grid and return the filtered map and the
//! number of pixels they rejected. Only valid pixels take part in window statistics.

use crate::config::{GaussianFilterConfig, WindowEstimator};
use flowfilter_geometry::{DepthMap, RawDepth};
use rayon::prelude::*;

/// Raw sensor depth to metres (`raw * metres_per_unit`, 0 stays 0).
pub fn metric_depth(raw: &RawDepth, metres_per_unit: f64) -> DepthMap {
    raw.map(|&d| if d == 0 { 0.0 } else { (f64::from(d) * metres_per_unit) as f32 })
}

/// Separable sliding min and max over valid pixels in a `window x window` square (`+inf` /
/// `-inf` where the window holds none): every pixel's, for dense maps.
fn window_min_max(depth: &DepthMap, window: usize) -> (Vec<f32>, Vec<f32>) {
    let (w, h) = depth.dims();
    let r = window / 2;
    let src = depth.as_slice();
    // Invalid pixels as the identities of min and max: the passes are then branch-free.
    let mut row_min = vec![f32::INFINITY; w * h];
    let mut row_max = vec![f32::NEG_INFINITY; w * h];
    row_min.par_chunks_mut(w).zip(row_max.par_chunks_mut(w)).enumerate().for_each(|(y, (mn, mx))| {
        let row = &src[y * w..(y + 1) * w];
        for x in 0..w {
            let (a, b) = (x.saturating_sub(r), (x + r).min(w - 1));
            let window = &row[a..=b];
            mn[x] = window.iter().fold(f32::INFINITY, |m, &v| m.min(if v > 0.0 { v } else { f32::INFINITY }));
            mx[x] = window.iter().fold(f32::NEG_INFINITY, |m, &v| m.max(if v > 0.0 { v } else { f32::NEG_INFINITY }));
        }
    });
    let mut out_min = vec![f32::INFINITY; w * h];
    let mut out_max = vec![f32::NEG_INFINITY; w * h];
    out_min.par_chunks_mut(w).zip(out_max.par_chunks_mut(w)).enumerate().for_each(|(y, (mn, mx))| {
        let (lo, hi) = (y.saturating_sub(r), (y + r).min(h - 1));
        for yy in lo..=hi {
            let (rmn, rmx) = (&row_min[yy * w..(yy + 1) * w], &row_max[yy * w..(yy + 1) * w]);
            for x in 0..w {
                mn[x] = mn[x].min(rmn[x]);
                mx[x] = mx[x].max(rmx[x]);
            }
        }
    });
    (out_min, out_max)
}

/// The smallest and largest valid depth of the window `xs x ys` (inclusive) of the `w`-wide
/// map `src` (`+inf` and `-inf` where it holds none): [`window_min_max`] at one pixel, for maps
/// whose holes are most of them.
fn valid_min_max(src: &[f32], w: usize, (x0, x1): (usize, usize), (y0, y1): (usize, usize)) -> (f32, f32) {
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for y in y0..=y1 {
        for &v in &src[y * w + x0..=y * w + x1] {
            if v > 0.0 {
                (lo, hi) = (lo.min(v), hi.max(v));
            }
        }
    }
    (lo, hi)
}

/// Each pixel's window extremes over valid depths: swept over the whole map where most pixels
/// hold a reading (every window is read), or read at the pixels that ask where most are holes
/// (an SR300 frame on the colour grid holds 25-35% readings: its step and Gaussian filters 2.5
/// and 7.6 ms -> 1.9 and 5.7 ms on one thread, and a dense Carmine frame's would be 15-35%
/// slower that way). The same values either way.
enum WindowExtremes<'a> {
    /// Every pixel's minimum and maximum, row by row of the map's width.
    Swept { min: Vec<f32>, max: Vec<f32>, width: usize },
    /// The map, read window by window (`half`: the window's half-width).
    Read { depth: &'a DepthMap, half: usize },
}

impl<'a> WindowExtremes<'a> {
    /// The extremes of `depth`'s `window x window` windows, `valid` of its pixels holding a
    /// reading.
    fn new(depth: &'a DepthMap, window: usize, valid: usize) -> Self {
        if 2 * valid > depth.as_slice().len() {
            let (min, max) = window_min_max(depth, window);
            Self::Swept { min, max, width: depth.width() }
        } else {
            Self::Read { depth, half: window / 2 }
        }
    }

    /// The smallest and largest valid depth of the window about pixel `(x, y)` (clamped to the
    /// map).
    fn at(&self, x: usize, y: usize) -> (f32, f32) {
        match self {
            Self::Swept { min, max, width } => (min[y * width + x], max[y * width + x]),
            Self::Read { depth, half } => {
                let (w, h) = depth.dims();
                let xs = (x.saturating_sub(*half), (x + half).min(w - 1));
                let ys = (y.saturating_sub(*half), (y + half).min(h - 1));
                valid_min_max(depth.as_slice(), w, xs, ys)
            }
        }
    }
}

/// The BigBIRD tools' discontinuity filter: reject a pixel when the largest or smallest valid
/// depth in its `window x window` neighbourhood differs from it by more than `threshold_m`
/// (BigBIRD: 7x7 and 1000 raw units = 10 cm).
pub fn bigbird_discontinuity(depth: &DepthMap, window: usize, threshold_m: f64) -> (DepthMap, usize) {
    let (w, h) = depth.dims();
    let (src, t) = (depth.as_slice(), threshold_m as f32);
    let steps = |z: f32, (lo, hi): (f32, f32)| z > 0.0 && (hi - z > t || z - lo > t);
    let valid = src.iter().filter(|&&z| z > 0.0).count();
    let out: Vec<f32> = match WindowExtremes::new(depth, window, valid) {
        // Dense: one pass over the swept extremes (a serial map that vectorises; the per-pixel
        // loop below took a Carmine frame's step filter 0.58 -> 0.75 ms).
        WindowExtremes::Swept { min, max, .. } => src
            .iter()
            .zip(min.iter().zip(&max))
            .map(|(&z, (&lo, &hi))| if steps(z, (lo, hi)) { 0.0 } else { z })
            .collect(),
        read => {
            let mut out = vec![0.0f32; w * h];
            out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
                for (x, o) in row.iter_mut().enumerate() {
                    let z = src[y * w + x];
                    if z > 0.0 && !steps(z, read.at(x, y)) {
                        *o = z;
                    }
                }
            });
            out
        }
    };
    let rejected = src.iter().zip(&out).filter(|(a, b)| **a > 0.0 && **b <= 0.0).count();
    (DepthMap::from_vec(w, h, out).expect("same size"), rejected)
}

/// The median (element `n / 2` in order) of positive values and their median absolute
/// deviation from it (element `n / 2` of the deviations), with one sort: the deviations below
/// and above the median are already ordered, so the MAD is found by merging the two runs.
fn median_and_mad(bits: &mut Vec<u32>, vals: &[f32]) -> (f32, f32) {
    // Positive f32 values order like their bit patterns: sort integers.
    bits.clear();
    bits.extend(vals.iter().map(|v| v.to_bits()));
    bits.sort_unstable();
    let mid = bits.len() / 2;
    let med = f32::from_bits(bits[mid]);
    let (mut below, mut above) = (mid, mid); // next candidates: bits[below - 1], bits[above]
    let mut mad = 0.0;
    for _ in 0..=mid {
        let lo = (below > 0).then(|| med - f32::from_bits(bits[below - 1]));
        let hi = (above < bits.len()).then(|| f32::from_bits(bits[above]) - med);
        mad = match (lo, hi) {
            (Some(l), Some(h)) if l < h => {
                below -= 1;
                l
            }
            (_, Some(h)) => {
                above += 1;
                h
            }
            (Some(l), None) => {
                below -= 1;
                l
            }
            (None, None) => unreachable!("mid + 1 <= len deviations"),
        };
    }
    (med, mad)
}

/// The paper's Gaussian window filter (eqs. 9-11): fit `N(mu, sigma^2)` to the valid depths of
/// the `k x k` window around each pixel and reject the pixel when
/// `|z - mu| > k_sigma * max(sigma, sigma_floor)`, or when the window holds fewer than
/// `min_support` valid depths. With [`WindowEstimator::Robust`], `mu` is the median and `sigma`
/// is 1.4826 times the median absolute deviation.
pub fn gaussian_window(depth: &DepthMap, cfg: &GaussianFilterConfig) -> (DepthMap, usize) {
    let (w, h) = depth.dims();
    let r = cfg.window / 2;
    let src = depth.as_slice();
    // Integral images of count, sum and sum of squares of the valid depths: the window's mean
    // and standard deviation in four lookups each.
    let stride = w + 1;
    let mut ic = vec![0.0f64; stride * (h + 1)];
    let mut is = vec![0.0f64; stride * (h + 1)];
    let mut iq = vec![0.0f64; stride * (h + 1)];
    for y in 0..h {
        let (mut c, mut s1, mut q) = (0.0, 0.0, 0.0);
        for x in 0..w {
            let z = f64::from(src[y * w + x]);
            if z > 0.0 {
                c += 1.0;
                s1 += z;
                q += z * z;
            }
            let k = (y + 1) * stride + x + 1;
            ic[k] = ic[k - stride] + c;
            is[k] = is[k - stride] + s1;
            iq[k] = iq[k - stride] + q;
        }
    }
    let boxed = |img: &[f64], x0: usize, y0: usize, x1: usize, y1: usize| {
        img[(y1 + 1) * stride + x1 + 1] - img[y0 * stride + x1 + 1] - img[(y1 + 1) * stride + x0]
            + img[y0 * stride + x0]
    };
    // Windows whose depth range is small hold one smooth surface; only the others (straddling a
    // discontinuity) need the robust fit.
    // The count integral's last cell: the map's readings.
    let extremes = WindowExtremes::new(depth, cfg.window, ic[h * stride + w] as usize);
    let mut out = vec![0.0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let mut vals: Vec<f32> = Vec::with_capacity(cfg.window * cfg.window);
        let mut bits: Vec<u32> = Vec::with_capacity(cfg.window * cfg.window);
        let (y0, y1) = (y.saturating_sub(r), (y + r).min(h - 1));
        for x in 0..w {
            let z = src[y * w + x];
            if z <= 0.0 {
                continue;
            }
            let (x0, x1) = (x.saturating_sub(r), (x + r).min(w - 1));
            let n = boxed(&ic, x0, y0, x1, y1);
            if (n as usize) < cfg.min_support {
                continue;
            }
            let mean = boxed(&is, x0, y0, x1, y1) / n;
            let std = (boxed(&iq, x0, y0, x1, y1) / n - mean * mean).max(0.0).sqrt();
            let (mu, sigma) = match cfg.estimator {
                // One smooth surface (small range or spread): the median equals the mean to within
                // the noise, so the cheap estimate decides.
                WindowEstimator::Robust
                    if std > cfg.sigma_floor_m && {
                        let (lo, hi) = extremes.at(x, y);
                        f64::from(hi - lo) > cfg.single_surface_range_m
                    } =>
                {
                    vals.clear();
                    for yy in y0..=y1 {
                        vals.extend(src[yy * w + x0..=yy * w + x1].iter().filter(|&&v| v > 0.0));
                    }
                    let (med, mad) = median_and_mad(&mut bits, &vals);
                    (f64::from(med), 1.4826 * f64::from(mad))
                }
                _ => (mean, std),
            };
            if (f64::from(z) - mu).abs() <= cfg.k_sigma * sigma.max(cfg.sigma_floor_m) {
                row[x] = z;
            }
        }
    });
    let rejected = src.iter().zip(&out).filter(|(a, b)| **a > 0.0 && **b <= 0.0).count();
    (DepthMap::from_vec(w, h, out).expect("same size"), rejected)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn step_edge_with_flyer() -> DepthMap {
        // Left half at 0.6 m, right half at 0.9 m, one flying pixel at 0.75 m on the edge.
        let mut d = DepthMap::from_fn(20, 20, |x, _| if x < 10 { 0.6 } else { 0.9 });
        *d.at_mut(10, 10) = 0.75;
        d
    }

    #[test]
    fn bigbird_filter_rejects_a_band_around_large_steps() {
        let (f, n) = bigbird_discontinuity(&step_edge_with_flyer(), 7, 0.1);
        assert_eq!(*f.at(10, 10), 0.0);
        assert_eq!(*f.at(7, 3), 0.0, "within 3 px of the step");
        assert_eq!(*f.at(6, 3), 0.6, "4 px from the step");
        // 6 columns along the step, plus the 7 pixels of column 13 that see the flyer (0.9 - 0.75 > 0.1).
        assert_eq!(n, 20 * 6 + 7);
        let (_, n) = bigbird_discontinuity(&step_edge_with_flyer(), 7, 0.5);
        assert_eq!(n, 0);
    }

    #[test]
    fn robust_gaussian_filter_rejects_the_flyer_and_keeps_both_surfaces() {
        let cfg = GaussianFilterConfig::default();
        let (f, n) = gaussian_window(&step_edge_with_flyer(), &cfg);
        assert_eq!(*f.at(10, 10), 0.0);
        assert_eq!(n, 1);
        assert_eq!(*f.at(9, 10), 0.6);
        assert_eq!(*f.at(11, 10), 0.9);
        // The paper's mean/std fit keeps it: the window's sigma is inflated by the step.
        let paper = GaussianFilterConfig { estimator: WindowEstimator::MeanStd, ..cfg };
        let (f, _) = gaussian_window(&step_edge_with_flyer(), &paper);
        assert_eq!(*f.at(10, 10), 0.75);
    }

    #[test]
    fn median_and_mad_equal_selection() {
        let mut bits = Vec::new();
        let mut state = 7u32;
        for n in 1..=25 {
            let vals: Vec<f32> = (0..n)
                .map(|_| {
                    state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                    0.5 + (state >> 24) as f32 * 0.01
                })
                .collect();
            let mut sorted = vals.clone();
            sorted.sort_by(f32::total_cmp);
            let med = sorted[n / 2];
            let mut dev: Vec<f32> = vals.iter().map(|v| (v - med).abs()).collect();
            dev.sort_by(f32::total_cmp);
            assert_eq!(median_and_mad(&mut bits, &vals), (med, dev[n / 2]), "n = {n}");
        }
    }

    /// The window's extremes read at one pixel are the sweep's, on a sparse map with steps.
    #[test]
    fn a_windows_extremes_are_the_sweeps() {
        let mut state = 11u32;
        let d = DepthMap::from_fn(37, 29, |x, y| {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let hole = (state >> 28) < 6;
            if hole {
                0.0
            } else {
                0.5 + 0.3 * f32::from(u8::from(x > 18)) + (state >> 20) as f32 * 1e-6 + y as f32 * 1e-3
            }
        });
        let (w, h) = d.dims();
        for window in [3, 5, 7] {
            let (mn, mx) = window_min_max(&d, window);
            // No reading counted: the windows are read pixel by pixel.
            let read = WindowExtremes::new(&d, window, 0);
            assert!(matches!(read, WindowExtremes::Read { .. }));
            for y in 0..h {
                for x in 0..w {
                    let k = y * w + x;
                    let (lo, hi) = read.at(x, y);
                    assert_eq!((lo.to_bits(), hi.to_bits()), (mn[k].to_bits(), mx[k].to_bits()), "{x} {y}");
                }
            }
        }
    }

    #[test]
    fn isolated_pixels_lack_support() {
        let mut d = DepthMap::filled(9, 9, 0.0);
        *d.at_mut(4, 4) = 0.7;
        let (f, n) = gaussian_window(&d, &GaussianFilterConfig::default());
        assert_eq!((*f.at(4, 4), n), (0.0, 1));
    }
}
