//! Calibrating a depth sensor from its own stream: the [`DepthBias`](flowfilter_pipeline::camera::DepthBias) its readings are off by,
//! fitted without any truth.
//!
//! 1. The whole scene is tracked ([`Tracker`] without a mask): each frame's camera motion.
//! 2. Each consecutive pair of tracked frames is registered again on the depth camera's own
//!    readings (point-to-plane ICP from the tracked motion, gates narrowing to 8 mm), so that
//!    what is left between the two views is the sensor's error and the noise.
//! 3. [`fit_depth_bias`] finds the field over the depth image those differences follow.
//!
//! A pair whose registration moved more than [`DepthCalibrationConfig::max_refinement_deg`]
//! from the tracked motion, or overlaps too little, is left out (and reported).

use crate::{TrackError, TrackState, Tracker, TrackerConfig};
use flowfilter_pipeline::camera::RayTable;
use flowfilter_pipeline::depth::bias_fit::{BiasFit, BiasFitConfig, BiasFitError, ViewPair, fit_depth_bias};
use flowfilter_pipeline::depth::cloud::{knn_normals, organized_cloud, voxel_downsample};
use flowfilter_pipeline::depth::filter::metric_depth;
use flowfilter_pipeline::registration::{
    Icp, IcpConfig, IcpVariant, Registrar, RegistrationError, RegistrationProblem,
};
use flowfilter_pipeline::{Pipeline, Point3, PointCloud, Pose, RawDepth, RgbdFrame, RgbdSensor};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// How a stream calibrates its depth sensor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DepthCalibrationConfig {
    /// The field's grid and the fit.
    pub fit: BiasFitConfig,
    /// Voxel of the clouds the pairs are registered on, metres.
    pub voxel_m: f64,
    /// ICP's correspondence gates, one registration after the other, metres.
    pub gates_m: Vec<f64>,
    /// A pair whose registration turned the tracked motion by more than this is left out, degrees.
    pub max_refinement_deg: f64,
    /// A pair whose registration paired fewer than this fraction of the points is left out.
    pub min_overlap: f64,
    /// Readings farther than this are not registered, metres (beyond, the sensor's noise
    /// outweighs its bias).
    pub far_m: f64,
}

impl Default for DepthCalibrationConfig {
    fn default() -> Self {
        Self {
            fit: BiasFitConfig::default(),
            voxel_m: 0.004,
            gates_m: vec![0.03, 0.015, 0.008],
            max_refinement_deg: 5.0,
            min_overlap: 0.3,
            far_m: 1.5,
        }
    }
}

impl DepthCalibrationConfig {
    /// Check the values.
    ///
    /// # Errors
    /// [`CalibrationError::Config`] naming the value out of range.
    pub fn validate(&self) -> Result<(), CalibrationError> {
        let bad = |m: String| Err(CalibrationError::Config(m));
        if !(self.voxel_m.is_finite() && self.voxel_m > 0.0) {
            return bad(format!("voxel_m must be positive, found {}", self.voxel_m));
        }
        if self.gates_m.is_empty() || self.gates_m.iter().any(|g| !(g.is_finite() && *g > 0.0)) {
            return bad(format!("gates_m must be one or more positive distances, found {:?}", self.gates_m));
        }
        if !(self.max_refinement_deg.is_finite() && self.max_refinement_deg > 0.0) {
            return bad(format!("max_refinement_deg must be positive, found {}", self.max_refinement_deg));
        }
        if !(0.0..=1.0).contains(&self.min_overlap) {
            return bad(format!("min_overlap must be in [0, 1], found {}", self.min_overlap));
        }
        if !(self.far_m.is_finite() && self.far_m > 0.0) {
            return bad(format!("far_m must be positive, found {}", self.far_m));
        }
        Ok(())
    }

    /// Why a pair registered with these values is left out, if it is.
    fn leaves_out(&self, refinement_deg: f64, overlap: f64) -> Option<String> {
        if refinement_deg > self.max_refinement_deg {
            Some(format!(
                "the depth moved the tracked motion by {refinement_deg:.1} deg (more than {})",
                self.max_refinement_deg
            ))
        } else if overlap < self.min_overlap {
            Some(format!("{:.0}% of the points paired (fewer than {:.0}%)", overlap * 100.0, self.min_overlap * 100.0))
        } else {
            None
        }
    }
}

/// One consecutive pair of the stream.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationPair {
    /// Stream index of the first frame.
    pub from: usize,
    /// Stream index of the second.
    pub to: usize,
    /// How far the registration turned the tracked motion, degrees.
    pub refinement_deg: f64,
    /// Fraction of the first frame's points paired within the last gate.
    pub overlap: f64,
    /// Why the pair was left out, if it was.
    pub left_out: Option<String>,
}

/// What a stream's calibration found.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthCalibration {
    /// The fitted field and how much of the pairs' differences it explains.
    pub fit: BiasFit,
    /// Frames the tracker followed (of those given).
    pub frames_tracked: usize,
    /// Frames given.
    pub frames: usize,
    /// The consecutive pairs of tracked frames.
    pub pairs: Vec<CalibrationPair>,
}

/// Why a stream cannot calibrate its sensor.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    /// Fewer than two frames.
    #[error("depth calibration needs at least two frames, found {0}")]
    TooFewFrames(usize),
    /// The frames are not of one sensor.
    #[error("depth calibration: frame '{0}' is of another sensor or size than the first frame")]
    MixedSensors(String),
    /// The first frame cannot be tracked from.
    #[error(transparent)]
    Track(#[from] TrackError),
    /// A configuration value is out of range.
    #[error("depth calibration: {0}")]
    Config(String),
    /// The field cannot be fitted (too few pairs kept, too little overlap).
    #[error(transparent)]
    Fit(#[from] BiasFitError),
}

/// Calibrate the depth sensor of `frames` (one static scene, the camera moving; their masks
/// are ignored: the whole scene is used) with `pipeline` for the tracking.
///
/// # Errors
/// [`CalibrationError`]: too few frames, frames of several sensors, a bad configuration, a
/// first frame the tracker cannot prepare, or too few kept pairs to fit the field (a pair whose
/// depth cannot be registered is left out, with the reason).
///
/// ```no_run
/// use flowfilter_pipeline::{CameraFile, FrameFiles, MaskSource, Pipeline, PipelineConfig};
/// use flowfilter_track::depth_calibration::{DepthCalibrationConfig, calibrate_depth};
/// let dir = std::path::Path::new("../shared/data/realsense-shelf/shelf-A");
/// let camera = CameraFile::from_file(&dir.join("camera.json"))?;
/// let frames = (0..15)
///     .map(|i| {
///         let files = FrameFiles {
///             color: dir.join(format!("frame-{i:06}.color.png")),
///             depth: dir.join(format!("frame-{i:06}.depth.png")),
///             mask: MaskSource::None,
///         };
///         files.load(&camera, &format!("frame-{i:06}"))
///     })
///     .collect::<Result<Vec<_>, _>>()?;
/// let pipeline = Pipeline::from_config(PipelineConfig::default())?;
/// let calibration = calibrate_depth(&frames, pipeline, &DepthCalibrationConfig::default())?;
/// println!("{:.2} -> {:.2} mm", calibration.fit.rms_before_m * 1e3, calibration.fit.rms_after_m * 1e3);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn calibrate_depth(
    frames: &[RgbdFrame],
    pipeline: Pipeline,
    config: &DepthCalibrationConfig,
) -> Result<DepthCalibration, CalibrationError> {
    let first = frames.first().ok_or(CalibrationError::TooFewFrames(0))?;
    if frames.len() < 2 {
        return Err(CalibrationError::TooFewFrames(frames.len()));
    }
    let sensor = first.sensor;
    if let Some(f) = frames.iter().find(|f| f.sensor != sensor || f.depth.dims() != first.depth.dims()) {
        return Err(CalibrationError::MixedSensors(f.label.clone()));
    }
    config.validate()?;
    let tracked = track_whole_frames(frames, pipeline)?;
    // Each tracked frame's cloud once: it is the target of one pair and the source of the next.
    let rays = RayTable::new(&sensor.depth);
    let clouds: BTreeMap<usize, PointCloud> =
        tracked.par_iter().map(|&(i, _)| (i, depth_cloud(&frames[i].depth, &sensor, &rays, config))).collect();
    let mut pairs = vec![];
    let mut kept = vec![];
    for w in tracked.windows(2) {
        let ((from, pose_a), (to, pose_b)) = (w[0], w[1]);
        let motion = depth_motion(&sensor, &(pose_b * pose_a.inverse()));
        let (pair, refined) = match refine(&clouds[&from], &clouds[&to], motion, config) {
            Ok(Refined { pose, refinement_deg, overlap }) => {
                let left_out = config.leaves_out(refinement_deg, overlap);
                (CalibrationPair { from, to, refinement_deg, overlap, left_out }, pose)
            }
            Err(e) => {
                let left_out = Some(format!("the depth could not be registered: {e}"));
                (CalibrationPair { from, to, refinement_deg: 0.0, overlap: 0.0, left_out }, motion)
            }
        };
        if pair.left_out.is_none() {
            kept.push(ViewPair { from, to, motion: refined });
        }
        pairs.push(pair);
    }
    let views: Vec<&RawDepth> = frames.iter().map(|f| &f.depth).collect();
    let fit = fit_depth_bias(&views, sensor.metres_per_unit, &sensor.depth, &kept, &config.fit)?;
    Ok(DepthCalibration { fit, frames_tracked: tracked.len(), frames: frames.len(), pairs })
}

/// The frames the tracker followed (tracking or recovered) with their motion from the first
/// (colour camera frame).
fn track_whole_frames(frames: &[RgbdFrame], pipeline: Pipeline) -> Result<Vec<(usize, Pose)>, CalibrationError> {
    let unmasked = |f: &RgbdFrame| {
        let mut f = f.clone();
        f.mask.as_mut_slice().fill(true);
        f
    };
    let mut tracker = Tracker::new(pipeline, TrackerConfig::default(), &unmasked(&frames[0]))?;
    let mut out = vec![(0, Pose::identity())];
    for (i, f) in frames.iter().enumerate().skip(1) {
        let t = tracker.update(Ok(unmasked(f)));
        if matches!(t.state, TrackState::Tracking | TrackState::Recovered) {
            out.push((i, t.pose));
        }
    }
    Ok(out)
}

/// The motion of the depth camera's frame for a motion of the colour camera's frame.
fn depth_motion(sensor: &RgbdSensor, color: &Pose) -> Pose {
    sensor.color_from_depth.inverse() * color * sensor.color_from_depth
}

/// A pair registered on the depth camera's readings.
struct Refined {
    /// The motion between the two depth cameras.
    pose: Pose,
    /// How far it turned the tracked motion, degrees.
    refinement_deg: f64,
    /// Fraction of the first frame's points paired within the last gate.
    overlap: f64,
}

/// Register `source` onto `target` (depth camera frames) from `motion`.
fn refine(
    source: &PointCloud,
    target: &PointCloud,
    motion: Pose,
    config: &DepthCalibrationConfig,
) -> Result<Refined, RegistrationError> {
    let mut refined = Refined { pose: motion, refinement_deg: 0.0, overlap: 0.0 };
    let mut problem = RegistrationProblem::new(source.clone(), target.clone());
    for &gate in &config.gates_m {
        let icp = Icp::new(IcpConfig {
            variant: IcpVariant::PointToPlane,
            max_correspondence_distance: gate,
            ..IcpConfig::default()
        })?;
        problem.init = refined.pose;
        let r = icp.register(&problem)?;
        (refined.pose, refined.overlap) = (r.transform, r.fitness);
    }
    refined.refinement_deg = (refined.pose * motion.inverse()).rotation.angle().to_degrees();
    Ok(refined)
}

/// A frame's depth readings nearer than [`DepthCalibrationConfig::far_m`] as points of the
/// depth camera's frame, on the voxel grid, with normals.
fn depth_cloud(depth: &RawDepth, sensor: &RgbdSensor, rays: &RayTable, config: &DepthCalibrationConfig) -> PointCloud {
    let near = metric_depth(depth, sensor.metres_per_unit).map(|&z| if f64::from(z) < config.far_m { z } else { 0.0 });
    let mut cloud = voxel_downsample(&organized_cloud(&near, rays, None, None).0, config.voxel_m);
    cloud.normals = Some(knn_normals(&cloud.points, 20, &Point3::origin()));
    cloud
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowfilter_pipeline::{CameraFile, PipelineConfig};

    fn frame(label: &str, width: u32) -> RgbdFrame {
        let camera = CameraFile::from_json_str(
            r#"{"K": [100, 0, 31.5, 0, 100, 23.5, 0, 0, 1], "depth_unit_m": 0.001}"#,
            "camera.json",
        )
        .unwrap();
        let color = image::RgbImage::new(width, 48);
        let depth = RawDepth::from_fn(width as usize, 48, |_, _| 800);
        RgbdFrame::from_images(label, color, depth, None, &camera).unwrap()
    }

    fn pipeline() -> Pipeline {
        Pipeline::from_config(PipelineConfig::default()).unwrap()
    }

    #[test]
    fn bad_streams_and_settings_are_named() {
        let config = DepthCalibrationConfig::default();
        let e = calibrate_depth(&[], pipeline(), &config).unwrap_err();
        assert!(matches!(e, CalibrationError::TooFewFrames(0)), "{e}");
        let e = calibrate_depth(&[frame("a", 64)], pipeline(), &config).unwrap_err();
        assert!(matches!(e, CalibrationError::TooFewFrames(1)), "{e}");
        let e = calibrate_depth(&[frame("a", 64), frame("b", 80)], pipeline(), &config).unwrap_err();
        assert!(e.to_string().contains("'b'"), "{e}");
        let bad = DepthCalibrationConfig { gates_m: vec![], ..config.clone() };
        let e = calibrate_depth(&[frame("a", 64), frame("b", 64)], pipeline(), &bad).unwrap_err();
        assert!(e.to_string().contains("gates_m"), "{e}");
        let bad = DepthCalibrationConfig { voxel_m: 0.0, ..config };
        assert!(bad.validate().unwrap_err().to_string().contains("voxel_m"));
    }

    #[test]
    fn a_pair_is_left_out_for_a_large_turn_or_a_small_overlap() {
        let config = DepthCalibrationConfig::default();
        assert!(config.leaves_out(1.0, 0.9).is_none());
        assert!(config.leaves_out(6.0, 0.9).unwrap().contains("6.0 deg"));
        assert!(config.leaves_out(1.0, 0.1).unwrap().contains("10%"));
    }
}
