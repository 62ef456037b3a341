//! The pipeline's seams: frame preparation and correspondence search, each a trait with the
//! project's default implementation.

use crate::config::CloudPrepConfig;
use crate::error::PipelineError;
use crate::frame::RgbdFrame;
use flowfilter_camera::{RayTable, RgbdSensor};
use flowfilter_depth::cloud::{thin_to_budget, voxel_downsample};
use flowfilter_depth::{DepthConfig, DepthStage};
use flowfilter_flow::FlowEstimator;
use flowfilter_flow::correspondences::{
    CorrespondenceParams, FlowGuide, FlowPairs, FlowView, flow_correspondences, flow_correspondences_guided,
};
use flowfilter_flow::lk::{Gray, to_gray};
use flowfilter_flow::pyramid::PyramidCache;
use flowfilter_geometry::{DepthMap, Mask, PointCloud, Pose};
use flowfilter_photometric::{ImageView, TextureCache};
use std::sync::Arc;
use std::time::Instant;

/// A frame after the depth stage: what correspondence search and registration need.
#[derive(Debug, Clone)]
pub struct PreparedFrame {
    /// The frame's label.
    pub label: String,
    /// Grey image in [0, 1] (colour grid).
    pub gray: Gray,
    /// Dense depth on the colour grid, metres (0 = none).
    pub depth: DepthMap,
    /// Object mask.
    pub mask: Mask,
    /// The registration cloud (colour camera frame, thinned, with normals).
    pub cloud: PointCloud,
    /// Points of the full organised cloud before thinning.
    pub full_points: usize,
    /// How the registration cloud was thinned (the voxel, and the finer cloud where the
    /// budget bound).
    pub thinning: CloudThinning,
    /// The sensor.
    pub sensor: RgbdSensor,
    /// Rays of the colour camera.
    pub rays: Arc<RayTable>,
    /// Seconds spent preparing the frame.
    pub seconds: f64,
    /// The frame came without an object mask: its mask covers the image (or every pixel with
    /// depth). A target frame without one gets the model's mask propagated
    /// ([`crate::Pipeline::estimate_prepared`]).
    pub unmasked: bool,
    /// The frame's textures for the photometric stage, computed when first read and kept for
    /// every pair that reads the frame (shared by clones). They are the grey image's on the
    /// mask's box: a frame given another mask or image needs an empty cache
    /// ([`PreparedFrame::with_mask`] starts one).
    pub textures: Arc<TextureCache>,
    /// The grey image's pyramids for the window matcher, cut to the crop a pair tracks on,
    /// built when first read and kept for the pair's other passes (shared by clones, and by
    /// [`PreparedFrame::with_mask`]'s frame: the same image); let go when the pair's estimate
    /// ends. A frame given another image needs an empty cache.
    pub pyramids: Arc<PyramidCache>,
}

/// How a frame's registration cloud was thinned: the voxel of the cloud, and, where the cloud
/// budget (`cloud.max_points`) made it coarser than configured, the cloud at the configured
/// voxel (so that a mask applied later cuts the finer cloud and thins only what it keeps).
#[derive(Debug, Clone, Default)]
pub struct CloudThinning {
    /// The voxel edge the registration cloud was thinned with (metres; 0 = not thinned).
    pub voxel_m: f64,
    /// The configured voxel (metres).
    pub configured_voxel_m: f64,
    /// The cloud budget (points; 0 = none).
    pub max_points: usize,
    /// The cloud at the configured voxel, where the budget thinned it further.
    pub finer: Option<Arc<PointCloud>>,
}

/// The voxel `[registration.flowfilter] scene_points` is counted at (the default `[cloud]
/// voxel_m`, metres).
pub const SCENE_RULE_VOXEL_M: f64 = 0.004;

impl CloudThinning {
    /// `points` of a cloud at the configured voxel counted as the points its surface holds at
    /// [`SCENE_RULE_VOXEL_M`] (about one point per voxel face), what the scene rule reads: a
    /// whole frame is a scene, and an object an object, whatever voxel the clouds are thinned
    /// to. Without a voxel (every pixel's point) the points as they are.
    pub fn scene_rule_points(&self, points: usize) -> usize {
        match self.configured_voxel_m {
            v if v > 0.0 => (points as f64 * (v / SCENE_RULE_VOXEL_M).powi(2)).round() as usize,
            _ => points,
        }
    }

    /// `full` thinned with `cfg`'s voxel, then within its budget: the cloud and its record.
    pub fn thin(full: &PointCloud, cfg: &CloudPrepConfig) -> (PointCloud, Self) {
        let at_voxel = if cfg.voxel_m > 0.0 { voxel_downsample(full, cfg.voxel_m) } else { full.clone() };
        Self { voxel_m: cfg.voxel_m, configured_voxel_m: cfg.voxel_m, max_points: cfg.max_points, finer: None }
            .rethin(at_voxel)
    }

    /// `cloud` (at the configured voxel) within the budget: the cloud and its record (the finer
    /// cloud kept, a copy, only where the budget binds).
    fn rethin(&self, cloud: PointCloud) -> (PointCloud, Self) {
        let at_voxel = Self { voxel_m: self.configured_voxel_m, finer: None, ..self.clone() };
        if self.max_points == 0 || cloud.len() <= self.max_points {
            return (cloud, at_voxel);
        }
        let (thinned, voxel_m) = thin_to_budget(cloud.clone(), self.configured_voxel_m, self.max_points);
        (thinned, Self { voxel_m, finer: Some(Arc::new(cloud)), ..at_voxel })
    }
}

impl PreparedFrame {
    /// The frame with another object mask: its cloud cut to the points that project into the
    /// mask (the rest of the preparation kept; where the cloud budget had thinned the whole
    /// frame's cloud, the finer cloud is cut and thinned within the budget again). How a mask
    /// found later (propagated, carried by a tracker) applies to a frame prepared without one.
    pub fn with_mask(&self, mask: Mask) -> PreparedFrame {
        let camera = &self.sensor.color;
        let source = self.thinning.finer.as_deref().unwrap_or(&self.cloud);
        let inside: Vec<usize> = (0..source.len())
            .filter(|&i| {
                camera.project(&source.points[i]).is_some_and(|p| {
                    let (x, y) = (p.x.round(), p.y.round());
                    x >= 0.0 && y >= 0.0 && mask.get(x as usize, y as usize).copied().unwrap_or(false)
                })
            })
            .collect();
        let (cloud, thinning) = match &self.thinning.finer {
            Some(_) => self.thinning.rethin(source.select(&inside)),
            None => (source.select(&inside), self.thinning.clone()),
        };
        PreparedFrame {
            label: self.label.clone(),
            gray: self.gray.clone(),
            depth: self.depth.clone(),
            mask,
            cloud,
            full_points: self.full_points,
            thinning,
            sensor: self.sensor,
            rays: self.rays.clone(),
            seconds: self.seconds,
            unmasked: false,
            textures: Arc::default(),
            pyramids: self.pyramids.clone(),
        }
    }

    /// The frame as the photometric stage (judge, alignment) reads it.
    pub fn image_view(&self) -> ImageView<'_> {
        ImageView {
            gray: &self.gray,
            depth: &self.depth,
            mask: &self.mask,
            rays: &self.rays,
            camera: &self.sensor.color,
            textures: Some(&self.textures),
        }
    }

    /// The frame as the correspondence search sees it.
    pub fn view(&self) -> FlowView<'_> {
        FlowView { gray: &self.gray, depth: &self.depth, mask: &self.mask, pyramids: Some(&self.pyramids) }
    }
}

/// Turns an RGB-D frame into a [`PreparedFrame`].
pub trait FramePreparer: Send + Sync {
    /// Prepare one frame.
    ///
    /// # Errors
    /// [`PipelineError::Depth`] (or another variant for custom preparers) when the frame
    /// cannot be used.
    fn prepare(&self, frame: &RgbdFrame) -> Result<PreparedFrame, PipelineError>;
}

/// The default preparer: the depth stage, then a voxel grid on its object cloud.
pub struct DepthPreparer {
    stage: DepthStage,
    cloud: CloudPrepConfig,
}

impl DepthPreparer {
    /// A preparer with these stage configurations.
    ///
    /// # Errors
    /// [`PipelineError::Depth`] when the depth configuration is out of range.
    pub fn new(depth: DepthConfig, cloud: CloudPrepConfig) -> Result<Self, PipelineError> {
        let stage = DepthStage::new(depth).map_err(|source| PipelineError::Depth { frame: "config".into(), source })?;
        Ok(Self { stage, cloud })
    }
}

impl FramePreparer for DepthPreparer {
    fn prepare(&self, frame: &RgbdFrame) -> Result<PreparedFrame, PipelineError> {
        let t0 = Instant::now();
        crate::frame_checks::check_depth(frame)?;
        let p = self
            .stage
            .process(&frame.depth, &frame.color, &frame.mask, &frame.sensor)
            .map_err(|source| PipelineError::Depth { frame: frame.label.clone(), source })?;
        let full_points = p.cloud.len();
        let mut full = p.cloud;
        full.colors = None;
        let (cloud, thinning) = CloudThinning::thin(&full, &self.cloud);
        let prepared = PreparedFrame {
            label: frame.label.clone(),
            gray: to_gray(&frame.color),
            depth: p.depth,
            mask: frame.mask.clone(),
            full_points,
            thinning,
            cloud,
            sensor: frame.sensor,
            rays: self.stage.rays(&frame.sensor.color),
            seconds: t0.elapsed().as_secs_f64(),
            unmasked: crate::frame_checks::is_unmasked(frame),
            textures: Arc::default(),
            pyramids: Arc::default(),
        };
        crate::frame_checks::check_cloud(frame, &prepared)?;
        Ok(prepared)
    }
}

/// The two frames' registration clouds at one density: the cloud thinned with the finer voxel
/// is thinned again with the other's (where the cloud budget bound on one frame only), so that
/// neither cloud outweighs the other in the registration's mixture. With a 4000-point budget, a
/// cracker box turned 21 deg, whose target view held 4.2k points (thinned to 2.9k) against 1.6k
/// in the model, landed 87 deg off at mixed densities and 0.28 deg off at one (as without the
/// budget).
pub(crate) fn registration_clouds(model: &PreparedFrame, target: &PreparedFrame) -> (PointCloud, PointCloud) {
    let coarse = model.thinning.voxel_m.max(target.thinning.voxel_m);
    let at_coarse = |f: &PreparedFrame| {
        if f.thinning.voxel_m < coarse { voxel_downsample(&f.cloud, coarse) } else { f.cloud.clone() }
    };
    (at_coarse(model), at_coarse(target))
}

/// Finds weighted 3-D pairs between two prepared frames.
pub trait CorrespondenceFinder: Send + Sync {
    /// A short name (the flow estimator's).
    fn name(&self) -> &str;
    /// The pairs, model frame to target frame.
    ///
    /// # Errors
    /// Whatever keeps the search from running ([`PipelineError::Flow`] for the default finder).
    /// The pipeline turns it into a [`crate::PipelineWarning::FlowFailed`].
    fn find(&self, model: &PreparedFrame, target: &PreparedFrame) -> Result<FlowPairs, PipelineError>;
    /// The pairs, searched around a predicted motion `guide` (`P_target ~ guide * P_model`).
    /// Finders that cannot use a prediction (the default) ignore it.
    ///
    /// # Errors
    /// As [`CorrespondenceFinder::find`].
    fn find_guided(
        &self,
        model: &PreparedFrame,
        target: &PreparedFrame,
        guide: &Pose,
    ) -> Result<FlowPairs, PipelineError> {
        let _ = guide;
        self.find(model, target)
    }

    /// [`CorrespondenceFinder::find_guided`] with each window's brightness matched to its
    /// template's, for a region tracked again from a wide-baseline guide
    /// ([`crate::WideBaselineConfig::match_brightness`]). Finders without such a mode (the
    /// default) search as `find_guided` does.
    ///
    /// # Errors
    /// As [`CorrespondenceFinder::find`].
    fn find_guided_matched(
        &self,
        model: &PreparedFrame,
        target: &PreparedFrame,
        guide: &Pose,
    ) -> Result<FlowPairs, PipelineError> {
        self.find_guided(model, target, guide)
    }
}

/// The default finder: optical flow by any [`FlowEstimator`], forward-backward consistency,
/// target mask and depth checks, depth-change outliers (stage 4 of the method).
pub struct FlowCorrespondenceFinder {
    estimator: Box<dyn FlowEstimator>,
    /// The estimator matching each window's brightness, when it has such a mode
    /// ([`FlowEstimator::brightness_matched`]).
    matched: Option<Box<dyn FlowEstimator>>,
    params: CorrespondenceParams,
}

impl FlowCorrespondenceFinder {
    /// A finder from an estimator and the rejection parameters.
    pub fn new(estimator: Box<dyn FlowEstimator>, params: CorrespondenceParams) -> Self {
        let matched = estimator.brightness_matched();
        Self { estimator, matched, params }
    }

    /// The pairs of `estimator` tracked from `guide`.
    fn tracked_from(
        &self,
        estimator: &dyn FlowEstimator,
        model: &PreparedFrame,
        target: &PreparedFrame,
        guide: &Pose,
    ) -> Result<FlowPairs, PipelineError> {
        let guide = FlowGuide { camera: &model.sensor.color, pose: guide };
        Ok(flow_correspondences_guided(
            estimator,
            &model.view(),
            &target.view(),
            &model.rays,
            &self.params,
            Some(guide),
        )?)
    }
}

impl CorrespondenceFinder for FlowCorrespondenceFinder {
    fn name(&self) -> &str {
        self.estimator.name()
    }

    fn find(&self, model: &PreparedFrame, target: &PreparedFrame) -> Result<FlowPairs, PipelineError> {
        Ok(flow_correspondences(self.estimator.as_ref(), &model.view(), &target.view(), &model.rays, &self.params)?)
    }

    fn find_guided(
        &self,
        model: &PreparedFrame,
        target: &PreparedFrame,
        guide: &Pose,
    ) -> Result<FlowPairs, PipelineError> {
        self.tracked_from(self.estimator.as_ref(), model, target, guide)
    }

    fn find_guided_matched(
        &self,
        model: &PreparedFrame,
        target: &PreparedFrame,
        guide: &Pose,
    ) -> Result<FlowPairs, PipelineError> {
        self.tracked_from(self.matched.as_deref().unwrap_or(self.estimator.as_ref()), model, target, guide)
    }
}
