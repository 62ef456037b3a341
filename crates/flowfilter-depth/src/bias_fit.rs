//! Fitting a depth sensor's own error ([`DepthBias`]) from views of a static scene whose
//! relative motions are known (unsupervised depth calibration in the manner of Teichman et
//! al.'s CLAMS, RSS 2013, on a coarse grid instead of per-pixel multipliers).
//!
//! Where one view's readings, moved by the pair's motion, land in the other view, the second
//! reading minus the predicted depth is `bias(u_b) - c * bias(u_a)`: the scene cancels, the
//! sensor's error at the two pixels stays (`c` is how a reading's error along view `a`'s ray
//! shows in view `b`'s depth). Over many pairs at different pixels these differences fix the
//! field up to what the pairs' rigid motions absorb. It is solved by least squares with a
//! smoothness term over the grid.

use flowfilter_camera::{CameraModel, DepthBias, Pixel};
use flowfilter_geometry::{Pose, RawDepth};
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// How the field is fitted.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BiasFitConfig {
    /// Control values across the image.
    pub cols: usize,
    /// Control values down the image.
    pub rows: usize,
    /// Weight of the grid's smoothness (squared differences of neighbouring values) against the
    /// data, per sample a control value sees on average.
    pub smoothness: f64,
    /// Weight pulling every value towards 0, on the same scale: where the differences are thin
    /// (the image's edges, what few pairs saw) the field stays small instead of following them.
    pub shrinkage: f64,
    /// Differences larger than this are other surfaces (occlusion, edges), not the sensor's
    /// error, metres.
    pub max_difference_m: f64,
    /// Every `pixel_step`-th pixel of each view is used, across and down.
    pub pixel_step: usize,
    /// Readings nearer than this are not used, metres.
    pub near_m: f64,
    /// Readings farther than this are not used, metres.
    pub far_m: f64,
}

impl Default for BiasFitConfig {
    fn default() -> Self {
        Self {
            cols: 32,
            rows: 24,
            smoothness: 0.04,
            shrinkage: 0.2,
            max_difference_m: 0.01,
            pixel_step: 2,
            near_m: 0.1,
            far_m: 4.0,
        }
    }
}

/// Two views of the static scene and the motion between them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewPair {
    /// The view whose readings are moved.
    pub from: usize,
    /// The view they are compared with.
    pub to: usize,
    /// Maps points of `from`'s depth camera frame into `to`'s.
    pub motion: Pose,
}

/// A fitted field and how well it explains the pairs.
#[derive(Debug, Clone, PartialEq)]
pub struct BiasFit {
    /// The field.
    pub bias: DepthBias,
    /// Compared readings.
    pub samples: usize,
    /// RMS of the depth differences before the correction, metres.
    pub rms_before_m: f64,
    /// RMS of what the field leaves of them, metres.
    pub rms_after_m: f64,
}

/// Why a field cannot be fitted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BiasFitError {
    /// A parameter is out of range.
    #[error("depth bias fit: {0}")]
    Config(String),
    /// A pair names a view that is not there, or the views differ in size.
    #[error("depth bias fit: {0}")]
    Input(String),
    /// Too few readings were compared to fix the field.
    #[error("depth bias fit: {found} depth readings were compared, at least {needed} are needed")]
    TooFewSamples {
        /// Readings compared.
        found: usize,
        /// Readings needed (ten per control value).
        needed: usize,
    },
}

/// One compared reading: the differences and the grid weights of both pixels.
struct Sample {
    difference: f64,
    /// `(index, coefficient)` of the field's values in the difference's prediction.
    terms: [(usize, f64); 8],
}

/// Fit the depth camera's bias field from `views` (raw depth of `camera`, `metres_per_unit`
/// metres per unit) and `pairs` of them with known motions.
///
/// # Errors
/// [`BiasFitError::Config`] for bad parameters, [`BiasFitError::Input`] for pairs naming
/// missing views or views of another size than the camera's, [`BiasFitError::TooFewSamples`]
/// when the views overlap too little.
///
/// ```
/// use flowfilter_camera::{CameraModel, Distortion, ImageSize, Intrinsics};
/// use flowfilter_depth::bias_fit::{BiasFitConfig, ViewPair, fit_depth_bias};
/// use flowfilter_geometry::{Pose, RawDepth};
/// use nalgebra::{Translation3, UnitQuaternion};
///
/// let camera = CameraModel::new(
///     Intrinsics::new(100.0, 100.0, 39.5, 29.5)?, Distortion::NONE, ImageSize::new(80, 60)?,
/// );
/// // A wall 1 m away, seen twice from a camera moved 5 cm sideways: nothing to correct.
/// let wall = RawDepth::from_fn(80, 60, |_, _| 1000);
/// let motion = Pose::from_parts(Translation3::new(0.05, 0.0, 0.0), UnitQuaternion::identity());
/// let config = BiasFitConfig { cols: 4, rows: 3, pixel_step: 1, ..BiasFitConfig::default() };
/// let fit = fit_depth_bias(&[&wall, &wall], 0.001, &camera, &[ViewPair { from: 0, to: 1, motion }], &config)?;
/// assert!(fit.bias.max_abs() < 1e-9);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn fit_depth_bias(
    views: &[&RawDepth],
    metres_per_unit: f64,
    camera: &CameraModel,
    pairs: &[ViewPair],
    config: &BiasFitConfig,
) -> Result<BiasFit, BiasFitError> {
    validate(config, views, camera, pairs)?;
    let (w, h) = (camera.size.width, camera.size.height);
    let zero = DepthBias::zeros(config.cols, config.rows, w, h).map_err(|e| BiasFitError::Config(e.to_string()))?;
    let samples: Vec<Sample> =
        pairs.par_iter().flat_map_iter(|p| compare(views, metres_per_unit, camera, p, config, &zero)).collect();
    let n = config.cols * config.rows;
    if samples.len() < 10 * n {
        return Err(BiasFitError::TooFewSamples { found: samples.len(), needed: 10 * n });
    }
    let values = solve(&samples, config);
    let rms =
        |f: &dyn Fn(&Sample) -> f64| (samples.iter().map(|s| f(s).powi(2)).sum::<f64>() / samples.len() as f64).sqrt();
    let rms_before_m = rms(&|s| s.difference);
    let rms_after_m = rms(&|s| s.difference - s.terms.iter().map(|&(i, c)| c * values[i]).sum::<f64>());
    let bias = DepthBias { metres: values.iter().copied().collect(), ..zero };
    Ok(BiasFit { bias, samples: samples.len(), rms_before_m, rms_after_m })
}

fn validate(
    config: &BiasFitConfig,
    views: &[&RawDepth],
    camera: &CameraModel,
    pairs: &[ViewPair],
) -> Result<(), BiasFitError> {
    let bad = |m: String| Err(BiasFitError::Config(m));
    if !(config.smoothness.is_finite() && config.smoothness >= 0.0) {
        return bad(format!("smoothness must be finite and >= 0, found {}", config.smoothness));
    }
    if !(config.shrinkage.is_finite() && config.shrinkage >= 0.0) {
        return bad(format!("shrinkage must be finite and >= 0, found {}", config.shrinkage));
    }
    if !(config.max_difference_m.is_finite() && config.max_difference_m > 0.0) {
        return bad(format!("max_difference_m must be positive, found {}", config.max_difference_m));
    }
    if config.pixel_step == 0 {
        return bad("pixel_step must be at least 1".into());
    }
    if !(config.near_m >= 0.0 && config.far_m > config.near_m) {
        return bad(format!(
            "near_m and far_m must satisfy 0 <= near < far, found {} and {}",
            config.near_m, config.far_m
        ));
    }
    let (w, h) = (camera.size.width as usize, camera.size.height as usize);
    if let Some((i, v)) = views.iter().enumerate().find(|(_, v)| (v.width(), v.height()) != (w, h)) {
        return Err(BiasFitError::Input(format!(
            "view {i} is {}x{}, the depth camera's images are {w}x{h}",
            v.width(),
            v.height()
        )));
    }
    if let Some(p) = pairs.iter().find(|p| p.from >= views.len() || p.to >= views.len()) {
        return Err(BiasFitError::Input(format!(
            "a pair names views {} and {}; there are {}",
            p.from,
            p.to,
            views.len()
        )));
    }
    Ok(())
}

/// The compared readings of one pair.
fn compare(
    views: &[&RawDepth],
    unit: f64,
    camera: &CameraModel,
    pair: &ViewPair,
    config: &BiasFitConfig,
    grid: &DepthBias,
) -> Vec<Sample> {
    let (from, to) = (views[pair.from], views[pair.to]);
    let (w, h) = (from.width(), from.height());
    let rotation = pair.motion.rotation;
    let reading = |d: &RawDepth, x: usize, y: usize| {
        let z = f64::from(*d.at(x, y)) * unit;
        (z > config.near_m && z < config.far_m).then_some(z)
    };
    let mut out = vec![];
    for y in (0..h).step_by(config.pixel_step) {
        for x in (0..w).step_by(config.pixel_step) {
            let Some(z) = reading(from, x, y) else { continue };
            let pixel = Pixel::new(x as f64, y as f64);
            let Some(p) = camera.backproject(&pixel, z) else { continue };
            let q = pair.motion * p;
            let Some(seen) = camera.project(&q) else { continue };
            let (u, v) = (seen.x.round(), seen.y.round());
            if u < 0.0 || v < 0.0 || u >= w as f64 || v >= h as f64 {
                continue;
            }
            let Some(zb) = reading(to, u as usize, v as usize) else { continue };
            let difference = zb - q.z;
            if difference.abs() > config.max_difference_m {
                continue;
            }
            // A reading off by e along `from`'s ray (z = 1 there) moves the predicted depth by c * e.
            let c = (rotation * (p.coords / p.z)).z;
            let (a, b) = (grid.weights(pixel.x, pixel.y), grid.weights(seen.x, seen.y));
            let mut terms = [(0, 0.0); 8];
            for k in 0..4 {
                terms[k] = (b[k].0, b[k].1);
                terms[4 + k] = (a[k].0, -c * a[k].1);
            }
            out.push(Sample { difference, terms });
        }
    }
    out
}

/// Least squares over the samples with the grid's smoothness term and the pull towards 0.
fn solve(samples: &[Sample], config: &BiasFitConfig) -> DVector<f64> {
    let (cols, rows) = (config.cols, config.rows);
    let n = cols * rows;
    // One pass in the samples' order (tens of millions of additions: milliseconds), so that the
    // sums, and the field, are the same with any thread count.
    let mut normal = DMatrix::<f64>::zeros(n, n);
    let mut rhs = DVector::<f64>::zeros(n);
    for s in samples {
        for &(i, ci) in &s.terms {
            rhs[i] += ci * s.difference;
            for &(j, cj) in &s.terms {
                normal[(i, j)] += ci * cj;
            }
        }
    }
    let per_value = normal.diagonal().sum() / n as f64;
    let weight = config.smoothness * per_value;
    let mut link = |i: usize, j: usize| {
        normal[(i, i)] += weight;
        normal[(j, j)] += weight;
        normal[(i, j)] -= weight;
        normal[(j, i)] -= weight;
    };
    for y in 0..rows {
        for x in 0..cols {
            if x + 1 < cols {
                link(y * cols + x, y * cols + x + 1);
            }
            if y + 1 < rows {
                link(y * cols + x, (y + 1) * cols + x);
            }
        }
    }
    for i in 0..n {
        normal[(i, i)] += config.shrinkage.max(1e-6) * per_value.max(1.0);
    }
    let solution = normal.clone().cholesky().map(|c| c.solve(&rhs)).unwrap_or_else(|| {
        // Semi-definite only when no reading was compared at all (the pull keeps it definite).
        rhs.fill(0.0);
        rhs.clone()
    });
    solution.map(|v| v.clamp(-flowfilter_camera::MAX_BIAS_M, flowfilter_camera::MAX_BIAS_M))
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowfilter_camera::{Distortion, ImageSize, Intrinsics};
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    fn camera() -> CameraModel {
        CameraModel::new(
            Intrinsics::new(300.0, 300.0, 159.5, 119.5).unwrap(),
            Distortion::NONE,
            ImageSize::new(320, 240).unwrap(),
        )
    }

    /// The true field: a smooth wave with a stripe, millimetres.
    fn true_bias(u: f64, v: f64) -> f64 {
        0.002 * (u / 50.0).sin() * (v / 70.0).cos() + if (150.0..180.0).contains(&u) { -0.002 } else { 0.0 }
    }

    /// Depth of a bumpy surface `z = 1 + 0.1 sin(x / 0.2) cos(y / 0.3)` (world frame) seen by
    /// a camera at `pose` (world from camera), with the sensor's field added.
    fn view(pose: &Pose, biased: bool) -> RawDepth {
        let cam = camera();
        RawDepth::from_fn(320, 240, |x, y| {
            let ray = cam.backproject(&Pixel::new(x as f64, y as f64), 1.0).unwrap().coords;
            let (o, d) = (pose.translation.vector, pose.rotation * ray);
            let mut t = 1.0;
            for _ in 0..30 {
                let p = o + d * t;
                let surface = 1.0 + 0.1 * (p.x / 0.2).sin() * (p.y / 0.3).cos();
                t += (surface - p.z) / d.z;
            }
            let z = t + if biased { true_bias(x as f64, y as f64) } else { 0.0 };
            (z * 1000.0).round() as u16
        })
    }

    fn poses() -> Vec<Pose> {
        (0..6)
            .map(|k| {
                let a = (k as f64 - 2.5) * 0.08;
                let turn = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), a)
                    * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 0.03 * k as f64);
                Pose::from_parts(Translation3::new(a * 0.5, 0.02 * k as f64, 0.0), turn)
            })
            .collect()
    }

    #[test]
    fn the_field_of_a_biased_sensor_is_recovered_from_its_views() {
        let poses = poses();
        let biased: Vec<RawDepth> = poses.iter().map(|p| view(p, true)).collect();
        let views: Vec<&RawDepth> = biased.iter().collect();
        let pairs: Vec<ViewPair> = (0..6)
            .flat_map(|a| (0..6).map(move |b| (a, b)))
            .filter(|(a, b)| a != b)
            .map(|(a, b)| ViewPair { from: a, to: b, motion: poses[b].inverse() * poses[a] })
            .collect();
        let config = BiasFitConfig { cols: 16, rows: 12, ..BiasFitConfig::default() };
        let fit = fit_depth_bias(&views, 0.001, &camera(), &pairs, &config).unwrap();
        assert!(fit.rms_after_m < 0.5 * fit.rms_before_m, "{} -> {}", fit.rms_before_m, fit.rms_after_m);
        // Up to a constant the pairs cannot see, the field is the sensor's.
        let pts: Vec<(f64, f64)> =
            (0..12).flat_map(|j| (0..16).map(move |i| (i as f64 * 20.0 + 10.0, j as f64 * 20.0 + 10.0))).collect();
        let truth: Vec<f64> = pts.iter().map(|&(u, v)| true_bias(u, v)).collect();
        let found: Vec<f64> = pts.iter().map(|&(u, v)| fit.bias.at(u, v)).collect();
        let mean = |x: &[f64]| x.iter().sum::<f64>() / x.len() as f64;
        let (mt, mf) = (mean(&truth), mean(&found));
        let cov: f64 = truth.iter().zip(&found).map(|(t, f)| (t - mt) * (f - mf)).sum();
        let norm = |x: &[f64], m: f64| x.iter().map(|v| (v - m).powi(2)).sum::<f64>().sqrt();
        let correlation = cov / (norm(&truth, mt) * norm(&found, mf));
        assert!(correlation > 0.9, "correlation {correlation}");
        // The same field with any thread count.
        let with_threads = |n: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
            pool.install(|| fit_depth_bias(&views, 0.001, &camera(), &pairs, &config).unwrap())
        };
        assert_eq!(with_threads(1), with_threads(3));
        // A sensor without a field gets (nearly) none.
        let clean: Vec<RawDepth> = poses.iter().map(|p| view(p, false)).collect();
        let clean: Vec<&RawDepth> = clean.iter().collect();
        let none = fit_depth_bias(&clean, 0.001, &camera(), &pairs, &config).unwrap();
        assert!(none.bias.max_abs() < 0.0006, "{}", none.bias.max_abs());
    }

    #[test]
    fn bad_input_is_named() {
        let v = RawDepth::from_fn(320, 240, |_, _| 1000);
        let pair = ViewPair { from: 0, to: 3, motion: Pose::identity() };
        let e = fit_depth_bias(&[&v], 0.001, &camera(), &[pair], &BiasFitConfig::default()).unwrap_err();
        assert!(e.to_string().contains("there are 1"), "{e}");
        let small = RawDepth::from_fn(32, 24, |_, _| 1000);
        let e = fit_depth_bias(&[&small], 0.001, &camera(), &[], &BiasFitConfig::default()).unwrap_err();
        assert!(e.to_string().contains("32x24"), "{e}");
        let e = fit_depth_bias(&[&v], 0.001, &camera(), &[], &BiasFitConfig::default()).unwrap_err();
        assert!(matches!(e, BiasFitError::TooFewSamples { found: 0, .. }), "{e}");
        let bad = BiasFitConfig { pixel_step: 0, ..BiasFitConfig::default() };
        assert!(fit_depth_bias(&[], 0.001, &camera(), &[], &bad).is_err());
    }
}
