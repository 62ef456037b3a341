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
/// `-inf` where the window holds none).
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

/// The BigBIRD tools' discontinuity filter: reject a pixel when the largest or smallest valid
/// depth in its `window x window` neighbourhood differs from it by more than `threshold_m`
/// (BigBIRD: 7x7 and 1000 raw units = 10 cm).
pub fn bigbird_discontinuity(depth: &DepthMap, window: usize, threshold_m: f64) -> (DepthMap, usize) {
    let (mn, mx) = window_min_max(depth, window);
    let t = threshold_m as f32;
    let mut rejected = 0;
    let out: Vec<f32> = depth
        .as_slice()
        .iter()
        .enumerate()
        .map(|(k, &z)| {
            if z > 0.0 && (mx[k] - z > t || z - mn[k] > t) {
                rejected += 1;
                0.0
            } else {
                z
            }
        })
        .collect();
    (DepthMap::from_vec(depth.width(), depth.height(), out).expect("same size"), rejected)
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
    let (wmin, wmax) = window_min_max(depth, cfg.window);
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
                    if std > cfg.sigma_floor_m
                        && f64::from(wmax[y * w + x] - wmin[y * w + x]) > cfg.single_surface_range_m =>
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

    #[test]
    fn isolated_pixels_lack_support() {
        let mut d = DepthMap::filled(9, 9, 0.0);
        *d.at_mut(4, 4) = 0.7;
        let (f, n) = gaussian_window(&d, &GaussianFilterConfig::default());
        assert_eq!((*f.at(4, 4), n), (0.0, 1));
    }
}
