//! Configuration of the depth stage (fed from TOML by the pipeline).

use crate::error::DepthError;
use serde::{Deserialize, Serialize};

/// A discontinuity filter: reject a pixel when the largest or smallest valid depth of its
/// window differs from it by more than a threshold (the BigBIRD tools' filter).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BigBirdFilterConfig {
    /// Apply it.
    pub enabled: bool,
    /// Odd window size (BigBIRD: 7).
    pub window: usize,
    /// Threshold in metres (BigBIRD: 1000 raw units = 0.1 m).
    pub threshold_m: f64,
}

impl BigBirdFilterConfig {
    /// The BigBIRD tools' filter on raw depth: 7x7, 10 cm. Off by default in [`DepthConfig`]:
    /// it also removes a 3-pixel band of valid depth on both sides of every large step.
    pub fn bigbird() -> Self {
        Self { enabled: false, window: 7, threshold_m: 0.1 }
    }

    /// The step filter applied after the Gaussian window filter: 3x3, 15 mm. It removes the
    /// flying pixels the Gaussian fit keeps (those within a few sigma of one surface).
    pub fn step() -> Self {
        Self { enabled: true, window: 3, threshold_m: 0.015 }
    }
}

/// The sensor's working range: readings outside it are dropped (as Open3D's `depth_trunc`
/// drops those beyond a distance).
///
/// A robot's camera sees parts of the robot fixed to it: the SR300 of the shared shelf
/// sequences sees the gripper's pads 4-13 cm away in every frame (some 20 000 readings, 7% of
/// a frame's), which move with the camera. They lie nearer than consumer depth cameras
/// measure (the SR300 from 0.2 m by Intel's datasheet; the Kinect, Carmine and Xtion from
/// 0.4-0.5 m). Off by default: on the shared sequences' whole frames a 0.2 m bound lost 4 of
/// their 141 successes (`docs/real.md`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RangeConfig {
    /// Readings nearer than this (metres) are dropped (0 = none are).
    pub min_m: f64,
    /// Readings farther than this (metres) are dropped (0 = none are).
    pub max_m: f64,
}

impl Default for RangeConfig {
    fn default() -> Self {
        Self { min_m: 0.0, max_m: 0.0 }
    }
}

impl RangeConfig {
    /// Whether a reading of `z` metres (positive) lies in the range.
    pub fn contains(&self, z: f64) -> bool {
        z >= self.min_m && (self.max_m <= 0.0 || z <= self.max_m)
    }

    /// Whether every reading lies in the range (the default: no bound set).
    pub fn is_unbounded(&self) -> bool {
        self.min_m <= 0.0 && self.max_m <= 0.0
    }
}

/// How the Gaussian window filter estimates the window's mean and spread.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WindowEstimator {
    /// The paper's eqs. 9-11: sample mean and standard deviation.
    MeanStd,
    /// Median and 1.4826 x median absolute deviation: the same Gaussian, fitted robustly, so
    /// that a window straddling a discontinuity is described by its majority surface.
    Robust,
}

/// The paper's Gaussian window edge filter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GaussianFilterConfig {
    /// Apply it.
    pub enabled: bool,
    /// Odd window size k.
    pub window: usize,
    /// Mean/std (paper) or median/MAD.
    pub estimator: WindowEstimator,
    /// Reject when `|z - mu| > k_sigma * max(sigma, sigma_floor_m)`.
    pub k_sigma: f64,
    /// Lower bound on sigma, metres (sensor noise: a flat window has sigma ~ 0).
    pub sigma_floor_m: f64,
    /// Reject pixels with fewer valid neighbours (centre included) than this in the window.
    pub min_support: usize,
    /// Robust estimator only: windows whose depth range (max - min) is at most this hold one
    /// surface and are judged by their mean and standard deviation (same decision, much cheaper).
    pub single_surface_range_m: f64,
}

impl Default for GaussianFilterConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            window: 5,
            estimator: WindowEstimator::Robust,
            k_sigma: 3.0,
            sigma_floor_m: 0.002,
            min_support: 6,
            single_surface_range_m: 0.015,
        }
    }
}

/// How depth is registered onto the colour grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RegistrationMethod {
    /// Project each depth pixel to the nearest colour pixel, nearest surface wins (BigBIRD tools).
    Splat,
    /// Triangulate neighbouring depth pixels (never across a step larger than `max_step_m`) and
    /// rasterise the triangles into the colour image with perspective-correct depth.
    Mesh,
}

/// Depth-to-colour registration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RegistrationConfig {
    /// Splat or mesh.
    pub method: RegistrationMethod,
    /// Largest depth difference between neighbouring depth pixels joined by a triangle, metres.
    pub max_step_m: f64,
    /// Only produce depth inside the object mask.
    pub restrict_to_mask: bool,
}

impl Default for RegistrationConfig {
    fn default() -> Self {
        Self { method: RegistrationMethod::Mesh, max_step_m: 0.01, restrict_to_mask: true }
    }
}

/// How holes inside the mask are filled.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InterpolationMethod {
    /// Leave holes.
    None,
    /// The nearest sample along the row or column.
    Nearest,
    /// Separable linear: between the nearest samples left/right and above/below, averaged.
    Linear,
}

/// Interpolation of mask pixels without depth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InterpolationConfig {
    /// Method.
    pub method: InterpolationMethod,
    /// Search radius, colour pixels.
    pub max_radius_px: usize,
    /// Never interpolate between samples differing by more than this, metres.
    pub max_step_m: f64,
}

impl Default for InterpolationConfig {
    fn default() -> Self {
        Self { method: InterpolationMethod::Linear, max_radius_px: 6, max_step_m: 0.01 }
    }
}

/// Normal estimation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NormalMethod {
    /// No normals.
    None,
    /// Cross product of central differences on the organised grid.
    Organized,
    /// PCA over the k nearest neighbours (k-d tree), like Open3D's `estimate_normals`.
    Knn,
}

/// Point-cloud construction.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CloudConfig {
    /// Normal method.
    pub normals: NormalMethod,
    /// Neighbours for k-NN normals.
    pub knn: usize,
    /// Organised normals: pixel offset of the central differences (rounded up to a multiple of
    /// the cloud's pixel step).
    pub organized_step_px: usize,
    /// The cloud takes every `s`-th pixel in each direction, `s` the largest whole number that
    /// leaves at least this many of the mask's pixels with depth (objects of fewer than four
    /// times this many pixels keep every pixel), so that the cloud's cost (and its voxel grid's)
    /// is bounded by the budget, not by the object's area. 0 (the default) = every pixel. Off by
    /// default: at 30000 a whole 640x480 SR300 frame (some 142k pixels with depth) takes every
    /// second pixel and is prepared in 24 instead of 30 ms, but a region cut later from that
    /// frame (a tracked object, a propagated mask) registers a sparser cloud: the tote's
    /// whole-frame track ended 83 deg off instead of 3 (`cargo xtask bench-track --real-only`).
    pub pixel_budget: usize,
}

impl Default for CloudConfig {
    fn default() -> Self {
        Self { normals: NormalMethod::Organized, knn: 20, organized_step_px: 2, pixel_budget: 0 }
    }
}

impl CloudConfig {
    /// The pixel step of a cloud over `pixels` pixels with depth (see
    /// [`CloudConfig::pixel_budget`]).
    ///
    /// ```
    /// use flowfilter_depth::CloudConfig;
    /// let cfg = CloudConfig { pixel_budget: 30_000, ..CloudConfig::default() };
    /// assert_eq!(CloudConfig::default().pixel_step(1_000_000), 1);
    /// assert_eq!(cfg.pixel_step(40_000), 1);
    /// assert_eq!(cfg.pixel_step(142_000), 2);
    /// assert_eq!(cfg.pixel_step(1_000_000), 5);
    /// ```
    pub fn pixel_step(&self, pixels: usize) -> usize {
        if self.pixel_budget == 0 {
            return 1;
        }
        ((pixels as f64 / self.pixel_budget as f64).sqrt().floor() as usize).max(1)
    }
}

/// The whole depth stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DepthConfig {
    /// The sensor's working range (applied to the raw readings, before any filter).
    pub range: RangeConfig,
    /// The BigBIRD discontinuity filter on raw depth (first; off by default).
    #[serde(default = "BigBirdFilterConfig::bigbird")]
    pub bigbird_filter: BigBirdFilterConfig,
    /// Gaussian window filter on depth (second).
    pub gaussian_filter: GaussianFilterConfig,
    /// Small-window discontinuity filter (third).
    #[serde(default = "BigBirdFilterConfig::step")]
    pub step_filter: BigBirdFilterConfig,
    /// Registration onto the colour grid.
    pub registration: RegistrationConfig,
    /// Hole filling.
    pub interpolation: InterpolationConfig,
    /// Cloud and normals.
    pub cloud: CloudConfig,
}

impl Default for DepthConfig {
    fn default() -> Self {
        Self {
            range: RangeConfig::default(),
            bigbird_filter: BigBirdFilterConfig::bigbird(),
            gaussian_filter: GaussianFilterConfig::default(),
            step_filter: BigBirdFilterConfig::step(),
            registration: RegistrationConfig::default(),
            interpolation: InterpolationConfig::default(),
            cloud: CloudConfig::default(),
        }
    }
}

impl DepthConfig {
    /// Check value ranges.
    pub fn validate(&self) -> Result<(), DepthError> {
        let odd = |w: usize| w >= 3 && w % 2 == 1;
        let checks = [
            (self.range.min_m.is_finite() && self.range.min_m >= 0.0, "range.min_m must be >= 0"),
            (
                self.range.max_m.is_finite() && (self.range.max_m <= 0.0 || self.range.max_m > self.range.min_m),
                "range.max_m must be 0 (no limit) or above range.min_m",
            ),
            (odd(self.bigbird_filter.window), "bigbird_filter.window must be odd and >= 3"),
            (self.bigbird_filter.threshold_m > 0.0, "bigbird_filter.threshold_m must be > 0"),
            (odd(self.step_filter.window), "step_filter.window must be odd and >= 3"),
            (self.step_filter.threshold_m > 0.0, "step_filter.threshold_m must be > 0"),
            (odd(self.gaussian_filter.window), "gaussian_filter.window must be odd and >= 3"),
            (self.gaussian_filter.k_sigma > 0.0, "gaussian_filter.k_sigma must be > 0"),
            (self.gaussian_filter.sigma_floor_m >= 0.0, "gaussian_filter.sigma_floor_m must be >= 0"),
            (self.registration.max_step_m > 0.0, "registration.max_step_m must be > 0"),
            (self.interpolation.max_step_m > 0.0, "interpolation.max_step_m must be > 0"),
            (self.cloud.knn >= 3, "cloud.knn must be >= 3"),
            (self.cloud.organized_step_px >= 1, "cloud.organized_step_px must be >= 1"),
        ];
        match checks.iter().find(|(ok, _)| !ok) {
            Some((_, msg)) => Err(DepthError::Config((*msg).into())),
            None => Ok(()),
        }
    }
}
