//! The [`FlowEstimator`] seam: dense flow for an image pair and sparse flow at query points,
//! with typed errors for inputs no estimator can use, and the forward-backward consistency check.

use crate::FlowField;
use crate::lk::{Gray, LkParams, WindowWarp, track_in, track_masked};
use crate::pyramid::ImagePyramid;
use flowfilter_geometry::Mask;
use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Smallest image side any estimator accepts.
pub const MIN_IMAGE_SIDE: usize = 8;

/// Why a flow estimate could not be made.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum FlowError {
    /// The two images differ in size.
    #[error("image sizes differ: 'from' is {from:?} (width, height) but 'to' is {to:?}")]
    SizeMismatch {
        /// Size of the first image.
        from: (usize, usize),
        /// Size of the second image.
        to: (usize, usize),
    },
    /// An image is empty or too small to estimate flow on.
    #[error("the '{which}' image is {width}x{height}; flow needs at least {min}x{min} pixels")]
    TooSmall {
        /// Which image.
        which: &'static str,
        /// Its width.
        width: usize,
        /// Its height.
        height: usize,
        /// The minimum side.
        min: usize,
    },
    /// The mask does not have the images' size.
    #[error("the mask is {mask:?} (width, height) but the images are {image:?}")]
    MaskSize {
        /// Mask size.
        mask: (usize, usize),
        /// Image size.
        image: (usize, usize),
    },
    /// A parameter is out of range.
    #[error("invalid flow parameter: {0}")]
    Config(String),
    /// A learned model could not be loaded or run, or breaks its declared contract.
    #[error("flow model {path}: {message}")]
    Model {
        /// The model file.
        path: String,
        /// What is wrong.
        message: String,
    },
}

/// Check that an image pair (and an optional mask of the first image) can be used.
pub fn check_pair(from: &Gray, to: &Gray, mask: Option<&Mask>) -> Result<(), FlowError> {
    for (which, img) in [("from", from), ("to", to)] {
        let (width, height) = img.dims();
        if width < MIN_IMAGE_SIDE || height < MIN_IMAGE_SIDE {
            return Err(FlowError::TooSmall { which, width, height, min: MIN_IMAGE_SIDE });
        }
    }
    if from.dims() != to.dims() {
        return Err(FlowError::SizeMismatch { from: from.dims(), to: to.dims() });
    }
    if let Some(m) = mask
        && m.dims() != from.dims()
    {
        return Err(FlowError::MaskSize { mask: m.dims(), image: from.dims() });
    }
    Ok(())
}

/// An optical-flow estimator. Convention: `I_to(x + f(x)) = I_from(x)`.
pub trait FlowEstimator: Send + Sync {
    /// Short name (`lk`, `dis`, `onnx:...`).
    fn name(&self) -> &str;

    /// Dense flow of every pixel of `from`. With a mask, only pixels inside it are estimated
    /// (the others are invalid) and, where the method allows, only they inform the estimate.
    ///
    /// # Errors
    /// [`FlowError::TooSmall`], [`FlowError::SizeMismatch`] or [`FlowError::MaskSize`] for
    /// images (or a mask) that cannot be used together, [`FlowError::Config`] for parameters out
    /// of range, [`FlowError::Model`] when a learned model fails.
    ///
    /// ```
    /// use flowfilter_flow::dis::{Dis, DisParams};
    /// use flowfilter_flow::lk::Gray;
    /// use flowfilter_flow::FlowEstimator;
    ///
    /// // A smooth texture, and the same texture moved 2 px right and 1 px down.
    /// let texture = |x: f32, y: f32| 0.5 + 0.25 * (x * 0.31).sin() * (y * 0.23).cos() + 0.2 * ((x + y) * 0.11).sin();
    /// let from = Gray::from_fn(96, 80, |x, y| texture(x as f32, y as f32));
    /// let to = Gray::from_fn(96, 80, |x, y| texture(x as f32 - 2.0, y as f32 - 1.0));
    /// let flow = Dis::new(DisParams::medium())?.dense(&from, &to, None)?;
    /// let [u, v] = flow.at(48, 40).expect("estimated");
    /// assert!((u - 2.0).abs() < 0.2 && (v - 1.0).abs() < 0.2, "({u}, {v})");
    /// # Ok::<(), flowfilter_flow::FlowError>(())
    /// ```
    fn dense(&self, from: &Gray, to: &Gray, mask: Option<&Mask>) -> Result<FlowField, FlowError>;

    /// Flow at sub-pixel query points of `from` (`None` where lost). The default samples the
    /// dense field bilinearly.
    fn sparse(
        &self,
        from: &Gray,
        to: &Gray,
        points: &[[f32; 2]],
        mask: Option<&Mask>,
    ) -> Result<Vec<Option<[f32; 2]>>, FlowError> {
        let field = self.dense(from, to, mask)?;
        Ok(points.iter().map(|p| field.sample(f64::from(p[0]), f64::from(p[1]))).collect())
    }

    /// [`FlowEstimator::sparse`] with a predicted flow per point to start from. Estimators that
    /// cannot use a prediction (the default) ignore it.
    fn sparse_guided(
        &self,
        from: &Gray,
        to: &Gray,
        points: &[[f32; 2]],
        guesses: &[[f32; 2]],
        mask: Option<&Mask>,
    ) -> Result<Vec<Option<[f32; 2]>>, FlowError> {
        let _ = guesses;
        self.sparse(from, to, points, mask)
    }

    /// The estimator as a [`WindowMatcher`], when it matches windows that a predicted local
    /// linear map can warp (Lucas-Kanade). The default: `None`.
    fn window_matcher(&self) -> Option<&dyn WindowMatcher> {
        None
    }

    /// The same estimator matching each window's brightness before comparing it (Lucas-Kanade
    /// with [`LucasKanade::match_brightness`]), for a pair whose exposure changed; `None` when
    /// the estimator has no such mode or is already in it (the default: `None`).
    fn brightness_matched(&self) -> Option<Box<dyn FlowEstimator>> {
        None
    }
}

/// Estimators that match image windows (Lucas-Kanade): they can also warp each window by the
/// predicted motion's local linear map (see [`track_warped`]), so that a window that turns with
/// the object is matched whole.
pub trait WindowMatcher: FlowEstimator {
    /// [`FlowEstimator::sparse_guided`] with, per point, the window's predicted linear map.
    ///
    /// # Errors
    /// As [`FlowEstimator::sparse`], and [`FlowError::Config`] when `guesses` or `warps` do not
    /// have one entry per point.
    fn sparse_warped(
        &self,
        from: &Gray,
        to: &Gray,
        points: &[[f32; 2]],
        guesses: &[[f32; 2]],
        warps: &[WindowWarp],
        mask: Option<&Mask>,
    ) -> Result<Vec<Option<[f32; 2]>>, FlowError>;

    /// Pyramid levels above the image that its tracking reads: the depth of the pyramids
    /// [`WindowMatcher::sparse_in`] needs.
    fn pyramid_levels(&self) -> usize;

    /// [`FlowEstimator::sparse`] (no `guesses`), [`FlowEstimator::sparse_guided`] or
    /// [`WindowMatcher::sparse_warped`] (with `warps`) on pyramids built beforehand
    /// ([`ImagePyramid::new`] with [`WindowMatcher::pyramid_levels`] levels at least): the same
    /// tracks, without building the pyramids again for each pass.
    ///
    /// # Errors
    /// As [`WindowMatcher::sparse_warped`], and [`FlowError::Config`] for pyramids shallower
    /// than [`WindowMatcher::pyramid_levels`].
    fn sparse_in(
        &self,
        from: &ImagePyramid,
        to: &ImagePyramid,
        points: &[[f32; 2]],
        guesses: Option<&[[f32; 2]]>,
        warps: Option<&[WindowWarp]>,
        mask: Option<&Mask>,
    ) -> Result<Vec<Option<[f32; 2]>>, FlowError>;
}

/// Pixels whose forward flow, followed by the backward flow sampled at the arrival point,
/// returns within `threshold` pixels of where they started.
pub fn forward_backward_mask(forward: &FlowField, backward: &FlowField, threshold: f32) -> Mask {
    Mask::from_fn(forward.width(), forward.height(), |x, y| {
        let Some(f) = forward.at(x, y) else { return false };
        let (qx, qy) = (x as f64 + f64::from(f[0]), y as f64 + f64::from(f[1]));
        backward.sample(qx, qy).is_some_and(|b| ((f[0] + b[0]).powi(2) + (f[1] + b[1]).powi(2)).sqrt() <= threshold)
    })
}

/// Forward-backward check of sparse tracks: `forward[i]` moved `points[i]`, `backward[i]` the
/// arrival point back. True where the round trip closes within `threshold` pixels.
pub fn forward_backward_sparse(
    forward: &[Option<[f32; 2]>],
    backward: &[Option<[f32; 2]>],
    threshold: f32,
) -> Vec<bool> {
    forward
        .iter()
        .zip(backward)
        .map(|(f, b)| match (f, b) {
            (Some(f), Some(b)) => ((f[0] + b[0]).powi(2) + (f[1] + b[1]).powi(2)).sqrt() <= threshold,
            _ => false,
        })
        .collect()
}

/// Pyramidal Lucas-Kanade as a [`FlowEstimator`]: sparse tracking natively; dense flow by
/// tracking a regular grid and interpolating bilinearly between tracked grid points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LucasKanade {
    /// Odd window size.
    pub window: usize,
    /// Pyramid levels above the full resolution.
    pub levels: usize,
    /// Newton iterations per level.
    pub max_iterations: usize,
    /// Stop when the update is below this (pixels).
    pub epsilon: f32,
    /// Reject when the gradient matrix's minimum eigenvalue / window area is below this.
    pub min_eigen: f32,
    /// Grid step (pixels) of the dense mode.
    pub dense_step: usize,
    /// Match each window's brightness to its template's on every pair
    /// ([`LkParams::match_brightness`]; off by default, as in OpenCV: the pipeline switches it on
    /// for the tracks started from a wide-baseline guide, `[flow.wide] match_brightness`).
    pub match_brightness: bool,
}

impl Default for LucasKanade {
    fn default() -> Self {
        let p = LkParams::default();
        Self {
            window: p.window,
            levels: p.levels,
            max_iterations: p.max_iterations,
            epsilon: p.epsilon,
            min_eigen: p.min_eigen,
            dense_step: 4,
            match_brightness: p.match_brightness,
        }
    }
}

impl LucasKanade {
    /// The defaults with a 9-pixel window: what the pipeline and the CLI use. OpenCV's 21-pixel
    /// window matches a turning surface short of its motion (turntable benchmark mean error
    /// 3.30 deg with 21, 2.11 with 9).
    pub fn turntable() -> Self {
        Self { window: 9, ..Self::default() }
    }

    /// The tracker's parameters.
    pub fn params(&self) -> LkParams {
        LkParams {
            window: self.window,
            levels: self.levels,
            max_iterations: self.max_iterations,
            epsilon: self.epsilon,
            min_eigen: self.min_eigen,
            match_brightness: self.match_brightness,
        }
    }

    /// Checked tracking, from zero or from per-point guesses: [`WindowMatcher::sparse_in`] on
    /// the two images' pyramids, built here (once the images are known to be usable).
    fn track(
        &self,
        from: &Gray,
        to: &Gray,
        points: &[[f32; 2]],
        guesses: Option<&[[f32; 2]]>,
        warps: Option<&[WindowWarp]>,
        mask: Option<&Mask>,
    ) -> Result<Vec<Option<[f32; 2]>>, FlowError> {
        check_pair(from, to, mask)?;
        let (from, to) =
            rayon::join(|| ImagePyramid::new(from.clone(), self.levels), || ImagePyramid::new(to.clone(), self.levels));
        self.sparse_in(&from, &to, points, guesses, warps, mask)
    }

    /// Check parameter ranges.
    pub fn validate(&self) -> Result<(), FlowError> {
        if self.window < 3 || self.window.is_multiple_of(2) {
            return Err(FlowError::Config(format!("lk.window must be odd and >= 3, found {}", self.window)));
        }
        if self.dense_step == 0 || self.max_iterations == 0 {
            return Err(FlowError::Config("lk.dense_step and lk.max_iterations must be >= 1".into()));
        }
        Ok(())
    }
}

impl FlowEstimator for LucasKanade {
    fn name(&self) -> &str {
        "lk"
    }

    fn sparse(
        &self,
        from: &Gray,
        to: &Gray,
        points: &[[f32; 2]],
        mask: Option<&Mask>,
    ) -> Result<Vec<Option<[f32; 2]>>, FlowError> {
        self.track(from, to, points, None, None, mask)
    }

    fn sparse_guided(
        &self,
        from: &Gray,
        to: &Gray,
        points: &[[f32; 2]],
        guesses: &[[f32; 2]],
        mask: Option<&Mask>,
    ) -> Result<Vec<Option<[f32; 2]>>, FlowError> {
        self.track(from, to, points, Some(guesses), None, mask)
    }

    fn window_matcher(&self) -> Option<&dyn WindowMatcher> {
        Some(self)
    }

    fn brightness_matched(&self) -> Option<Box<dyn FlowEstimator>> {
        (!self.match_brightness)
            .then(|| Box::new(Self { match_brightness: true, ..self.clone() }) as Box<dyn FlowEstimator>)
    }

    fn dense(&self, from: &Gray, to: &Gray, mask: Option<&Mask>) -> Result<FlowField, FlowError> {
        self.validate()?;
        check_pair(from, to, mask)?;
        let (w, h) = from.dims();
        let s = self.dense_step;
        let (gw, gh) = ((w - 1) / s + 1, (h - 1) / s + 1);
        let points: Vec<[f32; 2]> =
            (0..gh).flat_map(|j| (0..gw).map(move |i| [(i * s) as f32, (j * s) as f32])).collect();
        let tracked = track_masked(from, to, &points, &self.params(), mask);
        let grid = FlowField {
            flow: flowfilter_geometry::Grid::from_fn(gw, gh, |i, j| tracked[j * gw + i].unwrap_or([0.0; 2])),
            valid: Mask::from_fn(gw, gh, |i, j| tracked[j * gw + i].is_some()),
        };
        let mut out = FlowField::zeros(w, h);
        for y in 0..h {
            for x in 0..w {
                let inside = mask.is_none_or(|m| *m.at(x, y));
                let (gx, gy) = ((x as f64 / s as f64).min((gw - 1) as f64), (y as f64 / s as f64).min((gh - 1) as f64));
                let v = if inside {
                    grid.sample(gx, gy).or_else(|| grid.at(gx.round() as usize, gy.round() as usize))
                } else {
                    None
                };
                *out.flow.at_mut(x, y) = v.unwrap_or([0.0; 2]);
                *out.valid.at_mut(x, y) = v.is_some();
            }
        }
        Ok(out)
    }
}

impl WindowMatcher for LucasKanade {
    fn sparse_warped(
        &self,
        from: &Gray,
        to: &Gray,
        points: &[[f32; 2]],
        guesses: &[[f32; 2]],
        warps: &[WindowWarp],
        mask: Option<&Mask>,
    ) -> Result<Vec<Option<[f32; 2]>>, FlowError> {
        self.track(from, to, points, Some(guesses), Some(warps), mask)
    }

    fn pyramid_levels(&self) -> usize {
        self.levels
    }

    fn sparse_in(
        &self,
        from: &ImagePyramid,
        to: &ImagePyramid,
        points: &[[f32; 2]],
        guesses: Option<&[[f32; 2]]>,
        warps: Option<&[WindowWarp]>,
        mask: Option<&Mask>,
    ) -> Result<Vec<Option<[f32; 2]>>, FlowError> {
        self.validate()?;
        check_pair(from.level(0), to.level(0), mask)?;
        for (what, n) in [("guesses", guesses.map(<[_]>::len)), ("warps", warps.map(<[_]>::len))] {
            if let Some(n) = n.filter(|n| *n != points.len()) {
                return Err(FlowError::Config(format!("{n} {what} for {} points", points.len())));
            }
        }
        if let Some(depth) = [from.depth(), to.depth()].into_iter().find(|d| *d < self.levels) {
            return Err(FlowError::Config(format!("a pyramid of {depth} levels for lk.levels = {}", self.levels)));
        }
        Ok(track_in(from, to, points, guesses, warps, &self.params(), mask))
    }
}
