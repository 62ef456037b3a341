//! The pipeline's configuration: one TOML file with a table per stage. Unknown keys are errors
//! naming the key and the file.

use crate::error::PipelineError;
use flowfilter_depth::DepthConfig;
use flowfilter_flow::coarse_search::CoarseSearchParams;
use flowfilter_flow::correspondences::CorrespondenceParams;
use flowfilter_flow::dis::{DisParams, SearchGradients};
use flowfilter_flow::features::FeatureParams;
use flowfilter_flow::{FlowError, FlowEstimator, LucasKanade, flow_estimator_by_name};
use flowfilter_registration::{RegistrationConfig, registrar_by_name};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// How the object cloud handed to registration is thinned.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CloudPrepConfig {
    /// Voxel size (metres) of the registration clouds; 0 keeps every point.
    pub voxel_m: f64,
    /// At most this many points in a registration cloud: a larger one (a whole frame, an object
    /// close to the camera) is thinned with a coarser voxel until it fits, so the
    /// registration's cost is bounded by this budget, not by the object's size
    /// ([`flowfilter_depth::cloud::thin_to_budget`]). 0 = no limit.
    pub max_points: usize,
}

impl Default for CloudPrepConfig {
    fn default() -> Self {
        Self { voxel_m: 0.004, max_points: 6000 }
    }
}

impl FlowStageConfig {
    /// The configured flow estimator (for ONNX estimators: the model, loaded).
    ///
    /// # Errors
    /// As [`flowfilter_flow::flow_estimator_by_name`].
    pub fn estimator(&self) -> Result<Box<dyn FlowEstimator>, FlowError> {
        flow_estimator_by_name(&self.estimator, &self.lk, &self.dis)
    }
}

/// The flow and correspondence stages.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FlowStageConfig {
    /// Estimator name: `lk` (sparse pyramidal Lucas-Kanade) or `dis` (dense inverse search).
    pub estimator: String,
    /// Also track from the motion predicted by a geometric registration (FilterReg on the
    /// clouds) and keep whichever set of pairs agrees on a rigid motion more widely: reaches
    /// displacements the pyramid alone cannot bridge.
    pub guided: bool,
    /// The guided pass is skipped when the plain pairs agree on one rigid motion (`[flow.wide]
    /// settled_*`) that turns less than this (degrees): a small motion the pyramid followed,
    /// not one beyond its reach. 0 runs it on every pair.
    pub unguided_below_deg: f64,
    /// Lucas-Kanade parameters (default: a 9-pixel window, otherwise the tracker's defaults).
    pub lk: LucasKanade,
    /// Dense inverse search parameters (default: the medium preset with central-difference
    /// search gradients; a `[flow.dis]` table's omitted keys take the preset's values).
    pub dis: DisParams,
    /// Correspondence search and rejection.
    pub correspondences: CorrespondenceParams,
    /// The wide-baseline guide: where the region went when it moved beyond the pyramid's reach.
    pub wide: WideBaselineConfig,
}

/// The wide-baseline guide (`[flow.wide]`): a coarse search for where the model's region went
/// in the target image ([`flowfilter_flow::coarse_search`]); when it moved further than
/// `min_motion_px`, the region is tracked again from there (one more candidate set of pairs
/// for the registration's RANSAC).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct WideBaselineConfig {
    /// Run the search.
    pub enabled: bool,
    /// Track again from the search's answer only when it moves the region's pixels this far
    /// on average (pixels): nearer motions are within the pyramid's reach.
    pub min_motion_px: f64,
    /// Also weigh turns of the region about its own centre (a camera circling the object).
    pub orbit: bool,
    /// The region tracked again from a wide-baseline guide (the search's answer, the clouds'
    /// shapes, the feature matches' consensus) matches each window's brightness
    /// ([`crate::CorrespondenceFinder::find_guided_matched`]; Lucas-Kanade's
    /// [`flowfilter_flow::lk::LkParams::match_brightness`]). A region beyond the pyramid's reach
    /// is seen from another side, and a real camera's exposure and the surface's shading change
    /// with the view: regions of the shared RealSense shelves darken or brighten by 10% or more
    /// on half their pairs, up to 2.8x, and on such a region 25 deg away none of 885 tracks was
    /// forward-backward consistent with plain windows, 216 with matched ones. The other
    /// tracks keep plain windows, the more discriminating where the brightness holds: matched
    /// everywhere, texture-poor turning objects of the default protocol followed their static
    /// shading (two 30-deg pairs 22-29 deg off) and the shelves' whole frames their gripper.
    pub match_brightness: bool,
    /// Search only when the pyramid's own flow pairs are split: fewer than
    /// `settled_min_pairs` of them, or fewer than `settled_fraction` of the usable ones, agree on
    /// one rigid motion (RANSAC within `settled_distance_m`). A consensus that wide is the
    /// motion within the pyramid's reach, which the guide would leave alone; the search costs
    /// about a second on a 1280x1024 frame. 0 pairs: search on every pair.
    pub settled_min_pairs: usize,
    /// See `settled_min_pairs`.
    pub settled_fraction: f64,
    /// See `settled_min_pairs` (metres).
    pub settled_distance_m: f64,
    /// The search's pyramid level (`search.level`) is raised until the searched image's longer
    /// side is at most this many pixels, so that the search's cost (every shift of the region
    /// over the image) does not grow with the image: a 640x480 frame is searched at 1/8
    /// resolution, a 1280x1024 one at 1/16. 0: always `search.level`.
    pub max_search_side_px: usize,
    /// The search's parameters.
    pub search: CoarseSearchParams,
    /// Feature matches (FAST corners, BRIEF descriptors) beside the search, under the same
    /// condition; a consensus among them guides tracking as the search's answer does.
    pub features: FeatureParams,
    /// The clouds' own shapes beside the search, where it runs and no set of tracks so far
    /// has a rigid consensus of `settled_min_pairs`: a global registration (FPFH matches and
    /// RANSAC) guides tracking as the search's answer does.
    pub geometry: GeometryGuideConfig,
}

/// The geometric guide (`[flow.wide.geometry]`): where the coarse search runs and no set of
/// tracks has a rigid consensus of `[flow.wide] settled_min_pairs` pairs, both clouds are
/// thinned to a budget, registered globally by their FPFH matches
/// ([`flowfilter_registration::global`]) and refined by point-to-plane ICP; that motion guides
/// tracking as the coarse search's does. The clouds' shapes reach motions of any size where
/// the images' appearance changes too much for the search (a camera turned 25 deg about a
/// shelf's bin).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GeometryGuideConfig {
    /// Run it.
    pub enabled: bool,
    /// Both clouds are thinned to at most this many points (the model's count sets the voxel,
    /// at least `min_voxel_m`), so its cost does not grow with the region.
    pub max_points: usize,
    /// The finest voxel (metres).
    pub min_voxel_m: f64,
    /// Normals of the thinned clouds from this many nearest neighbours.
    pub normal_neighbours: usize,
    /// A point's descriptor covers this many voxels around it.
    pub feature_radius_voxels: f64,
    /// A match agrees with a motion within this many voxels (the ICP's gate as well).
    pub match_distance_voxels: f64,
    /// RANSAC samples at most.
    pub max_iterations: usize,
    /// Fewer matches agreeing give no guide.
    pub min_inliers: usize,
}

impl Default for GeometryGuideConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            max_points: 2500,
            min_voxel_m: 0.005,
            normal_neighbours: 30,
            feature_radius_voxels: 5.0,
            match_distance_voxels: 1.5,
            max_iterations: 20_000,
            min_inliers: 12,
        }
    }
}

impl GeometryGuideConfig {
    /// Check ranges.
    fn validate(&self) -> Result<(), String> {
        let ok = self.max_points >= 100
            && self.min_voxel_m > 0.0
            && self.normal_neighbours >= 3
            && self.feature_radius_voxels > 1.0
            && self.match_distance_voxels > 0.0
            && self.max_iterations > 0
            && self.min_inliers >= 3;
        if ok {
            Ok(())
        } else {
            Err("geometry: max_points >= 100, min_voxel_m > 0, normal_neighbours >= 3, feature_radius_voxels > 1, \
                 match_distance_voxels > 0, max_iterations > 0, min_inliers >= 3"
                .to_string())
        }
    }
}

impl Default for WideBaselineConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            min_motion_px: 24.0,
            orbit: true,
            match_brightness: true,
            settled_min_pairs: 30,
            settled_fraction: 0.7,
            settled_distance_m: 0.005,
            max_search_side_px: 80,
            search: CoarseSearchParams::default(),
            features: FeatureParams::default(),
            geometry: GeometryGuideConfig::default(),
        }
    }
}

impl WideBaselineConfig {
    /// Check ranges.
    fn validate(&self) -> Result<(), String> {
        self.features.validate()?;
        self.geometry.validate()?;
        let s = &self.search;
        let ok = self.min_motion_px >= 0.0
            && (0.0..=1.0).contains(&self.settled_fraction)
            && self.settled_distance_m > 0.0
            && (1..=6).contains(&s.level)
            && s.max_pixels >= 16
            && s.turn_step_deg >= 0.0
            && s.max_turn_deg >= 0.0
            && s.max_turn_deg <= 180.0
            && (0.0..=1.0).contains(&s.min_overlap)
            && (-1.0..=1.0).contains(&s.min_score);
        if ok {
            Ok(())
        } else {
            Err(format!(
                "min_motion_px >= 0, settled_fraction in [0, 1], settled_distance_m > 0, search.level in 1..=6, search.max_pixels >= 16, turns >= 0 (at most 180 deg), \
                 min_overlap in [0, 1] and min_score in [-1, 1] required, found {self:?}"
            ))
        }
    }
}

impl Default for FlowStageConfig {
    fn default() -> Self {
        Self {
            estimator: "lk".into(),
            guided: true,
            unguided_below_deg: 10.0,
            // A 9-pixel window (see `LucasKanade::turntable`). A `[flow.lk]` table's omitted
            // keys take the tracker's own defaults.
            lk: LucasKanade::turntable(),
            // Central-difference patch search: better than the presets' OpenCV-like damped steps
            // on turntable pairs (mean EPE 1.46 against 1.62).
            dis: DisParams { search_gradients: SearchGradients::Central, ..DisParams::default() },
            correspondences: CorrespondenceParams::default(),
            wide: WideBaselineConfig::default(),
        }
    }
}

/// The whole pipeline.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PipelineConfig {
    /// Registration backend, by name (see `flowfilter_registration::registrar_by_name`).
    pub method: String,
    /// Depth stage.
    pub depth: DepthConfig,
    /// Registration clouds.
    pub cloud: CloudPrepConfig,
    /// Flow and correspondences (used by the Flow Filter methods only).
    pub flow: FlowStageConfig,
    /// Backend parameters.
    pub registration: RegistrationConfig,
    /// The photometric judge after the registration (Flow Filter methods only).
    pub judge: crate::judge::JudgeConfig,
    /// The direct alignment after the judge (Flow Filter methods only).
    pub align: crate::align::AlignConfig,
    /// What an estimate must show to be reported as converged.
    pub report: ReportConfig,
    /// Scenes registered by their geometry first, kept where the images confirm it (Flow
    /// Filter methods only).
    pub geometry_first: crate::geometry_first::GeometryFirstConfig,
}

/// What an estimate must show to be reported as converged (`[report]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReportConfig {
    /// An estimate whose rotation bound exceeds this (degrees) warns `wide_bounds` and is not
    /// converged: it may be that far off (0 = never).
    pub max_bound_deg: f64,
}

impl Default for ReportConfig {
    fn default() -> Self {
        Self { max_bound_deg: 5.0 }
    }
}

impl Default for PipelineConfig {
    fn default() -> Self {
        Self {
            method: "flowfilter".into(),
            depth: DepthConfig::default(),
            cloud: CloudPrepConfig::default(),
            flow: FlowStageConfig::default(),
            registration: RegistrationConfig::default(),
            judge: crate::judge::JudgeConfig::default(),
            align: crate::align::AlignConfig::default(),
            report: ReportConfig::default(),
            geometry_first: crate::geometry_first::GeometryFirstConfig::default(),
        }
    }
}

impl PipelineConfig {
    /// Parse TOML text; `origin` names the source in errors.
    pub fn from_toml_str(text: &str, origin: &Path) -> Result<Self, PipelineError> {
        let config_error = |message: String| PipelineError::Config { path: origin.to_path_buf(), message };
        // Parsed twice: the table for the finiteness walk, then the struct from the text, whose
        // errors keep their line numbers (deserialising the table would lose the spans).
        let table: toml::Table = toml::from_str(text).map_err(|e| config_error(describe_toml_error(&e, text)))?;
        flowfilter_geometry::params::reject_non_finite(&table).map_err(|e| config_error(e.to_string()))?;
        let config: Self = toml::from_str(text).map_err(|e| config_error(describe_toml_error(&e, text)))?;
        config.validate().map_err(config_error)?;
        Ok(config)
    }

    /// Read and parse a TOML file.
    pub fn from_file(path: &Path) -> Result<Self, PipelineError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| PipelineError::Config { path: path.to_path_buf(), message: format!("cannot read: {e}") })?;
        Self::from_toml_str(&text, path)
    }

    /// The configuration as TOML.
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("the configuration serialises")
    }

    /// Check values that serde cannot: names and ranges of every stage. Nothing costly is
    /// built (an ONNX model is not loaded).
    ///
    /// # Errors
    /// A message naming the key or table at fault.
    pub fn validate(&self) -> Result<(), String> {
        check_method_name(&self.method)?;
        flowfilter_flow::check_estimator_name(&self.flow.estimator)
            .map_err(|e| format!("key 'flow.estimator': {e}"))?;
        self.validate_stages()
    }

    /// [`PipelineConfig::validate`] without the names of the method and the flow estimator
    /// (checked when they are built).
    pub(crate) fn validate_stages(&self) -> Result<(), String> {
        self.depth.validate().map_err(|e| format!("table [depth]: {e}"))?;
        if !(self.cloud.voxel_m >= 0.0 && self.cloud.voxel_m.is_finite()) {
            return Err(format!("key 'cloud.voxel_m' must be >= 0, found {}", self.cloud.voxel_m));
        }
        if !(self.flow.unguided_below_deg >= 0.0 && self.flow.unguided_below_deg.is_finite()) {
            return Err(format!("key 'flow.unguided_below_deg' must be >= 0, found {}", self.flow.unguided_below_deg));
        }
        self.flow.lk.validate().map_err(|e| format!("table [flow.lk]: {e}"))?;
        self.flow.dis.validate().map_err(|e| format!("table [flow.dis]: {e}"))?;
        self.flow.correspondences.validate().map_err(|e| format!("table [flow.correspondences]: {e}"))?;
        self.flow.wide.validate().map_err(|e| format!("table [flow.wide]: {e}"))?;
        self.judge.validate().map_err(|e| e.within("judge").to_string())?;
        self.align.validate().map_err(|e| e.within("align").to_string())?;
        if !(self.report.max_bound_deg >= 0.0 && self.report.max_bound_deg.is_finite()) {
            return Err(format!("key 'report.max_bound_deg' must be >= 0, found {}", self.report.max_bound_deg));
        }
        self.geometry_first.validate().map_err(|e| e.within("geometry_first").to_string())?;
        self.registration.validate().map_err(|e| e.within("registration").to_string())
    }
}

/// `Ok` for a name [`registrar_by_name`] knows.
fn check_method_name(name: &str) -> Result<(), String> {
    match registrar_by_name(name, &Default::default()) {
        Err(flowfilter_registration::RegistrationError::Config(e)) => Err(format!("key 'method': {e}")),
        _ => Ok(()),
    }
}

/// toml's message with the line number, as one line a user can act on.
fn describe_toml_error(e: &toml::de::Error, text: &str) -> String {
    let msg = e.message().trim().to_string();
    match e.span() {
        Some(span) => {
            let start = span.start.min(text.len());
            let line = text[..start].matches('\n').count() + 1;
            let source_line = text.lines().nth(line - 1).unwrap_or("").trim();
            format!("line {line} (`{source_line}`): {msg}")
        }
        None => msg,
    }
}
