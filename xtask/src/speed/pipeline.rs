//! The pipeline's throughput in `bench-speed`: two frames in, pose out (both depth stages,
//! flow, correspondences, registration), pairs of the default benchmark's frames, run in a
//! pool of the asked size with pairs side by side.

use crate::bench::Protocol;
use crate::dataset::{embedded_objects, ensure_default_object};
use anyhow::Context;
use flowfilter_pipeline::bigbird::{BigBirdObject, FrameId, SensorId};
use flowfilter_pipeline::eval::PoseErrors;
use flowfilter_pipeline::{Estimate, Pipeline, PipelineConfig, Pose, RgbdFrame, load_bigbird_frame};
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Instant;

/// The pairs of one camera of the default dataset, frames loaded (decoding is not timed: a
/// camera hands over raw frames).
pub struct PipelinePairs {
    /// (model, target, true motion).
    pub pairs: Vec<(Arc<RgbdFrame>, Arc<RgbdFrame>, Pose)>,
    /// What they are, for the report.
    pub description: String,
}

/// The camera whose pairs are timed (the middle one of the rig).
pub(super) const CAMERA: &str = "NP3";

/// Load the pairs of `CAMERA` under `protocol` (its base angles and steps) from the embedded
/// dataset, synthesised and cached exactly as `bench-bigbird` does (same cameras and
/// `angles`, the protocol's as bench-bigbird reads it, so one cache serves both).
///
/// # Errors
/// A dataset that cannot be synthesised or read.
pub fn load(protocol: &Protocol, angles: &[u32], quick: bool) -> anyhow::Result<PipelinePairs> {
    let cameras = protocol.sensors().map_err(anyhow::Error::msg)?;
    let camera: SensorId = CAMERA.parse().map_err(|e| anyhow::anyhow!("{e}"))?;
    let objects = embedded_objects(quick, None);
    let mut pairs = vec![];
    for o in &objects {
        let dir = ensure_default_object(o, &cameras, angles)?;
        let object = BigBirdObject::open(&dir).with_context(|| format!("opening {}", dir.display()))?;
        let mut frames: BTreeMap<u32, Arc<RgbdFrame>> = BTreeMap::new();
        let mut frame = |angle: u32| -> anyhow::Result<Arc<RgbdFrame>> {
            if let Some(f) = frames.get(&angle) {
                return Ok(f.clone());
            }
            let f = Arc::new(load_bigbird_frame(&object, FrameId { sensor: camera, angle })?);
            frames.insert(angle, f.clone());
            Ok(f)
        };
        for &from in &protocol.base_angles {
            for &step in &protocol.steps {
                let to = (from + step) % 360;
                let truth = object.relative_motion(camera, from, to)?;
                pairs.push((frame(from)?, frame(to)?, truth));
            }
        }
    }
    let description = format!(
        "{} pairs: {} objects, camera {CAMERA}, base angles {:?}, steps {:?} (frames 1280x1024 colour, 640x480 depth)",
        pairs.len(),
        objects.len(),
        protocol.base_angles,
        protocol.steps
    );
    Ok(PipelinePairs { pairs, description })
}

/// One method's throughput.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Throughput {
    /// Pairs per second of wall time.
    pub pairs_per_second: f64,
    /// Mean rotation error (the paper's metric), degrees.
    pub mean_rotation_deg: f64,
    /// Fraction of pairs within the success thresholds.
    pub success: f64,
    /// Mean stage times (ms): depth (both frames of a pair; on a stream, one frame's
    /// preparation), then per pair flow, correspondences, registration, the photometric judge,
    /// the direct alignment.
    pub stage_ms: [f64; 6],
}

/// Every pair through `config`'s pipeline in `pool` (pairs side by side), both frames prepared
/// per pair.
///
/// # Errors
/// A configuration that does not make a pipeline, a pair that fails.
pub fn throughput(
    pairs: &PipelinePairs,
    config: &PipelineConfig,
    pool: &rayon::ThreadPool,
) -> anyhow::Result<Throughput> {
    let pipeline = Pipeline::from_config(config.clone())?;
    let t0 = Instant::now();
    let estimates = pool.install(|| {
        pairs
            .pairs
            .par_iter()
            .map(|(model, target, truth)| {
                let (e, a, _) = pipeline.estimate_against(model, target, None)?;
                let errors = PoseErrors::new(&e.pose, truth, Some(&a.cloud.points));
                Ok((e, errors))
            })
            .collect::<anyhow::Result<Vec<_>>>()
    })?;
    let wall = t0.elapsed().as_secs_f64();
    let depth_ms = |e: &Estimate| e.stage_ms.depth_model + e.stage_ms.depth_target;
    let depth_mean = estimates.iter().map(|(e, _)| depth_ms(e)).sum::<f64>() / estimates.len().max(1) as f64;
    Ok(Throughput::of(&estimates, wall, depth_mean))
}

impl Throughput {
    /// The throughput of `estimates` (with their errors) made in `wall` seconds, the first stage
    /// time `first_stage_ms` (the depth stage's, as the section counts it), the others the
    /// estimates' means.
    pub fn of(estimates: &[(Estimate, PoseErrors)], wall: f64, first_stage_ms: f64) -> Self {
        let n = estimates.len().max(1) as f64;
        let mean = |f: &dyn Fn(&(Estimate, PoseErrors)) -> f64| estimates.iter().map(f).sum::<f64>() / n;
        Self {
            pairs_per_second: estimates.len() as f64 / wall,
            mean_rotation_deg: mean(&|(_, e)| e.angle_error_deg),
            success: mean(&|(_, e)| f64::from(u8::from(e.success))),
            stage_ms: [
                first_stage_ms,
                mean(&|(e, _)| e.stage_ms.flow),
                mean(&|(e, _)| e.stage_ms.correspondences),
                mean(&|(e, _)| e.stage_ms.registration),
                mean(&|(e, _)| e.stage_ms.judge),
                mean(&|(e, _)| e.stage_ms.align),
            ],
        }
    }
}
