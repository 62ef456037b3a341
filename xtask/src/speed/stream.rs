//! The pipeline on consecutive frames of a stream in `bench-speed`: each object of the default
//! dataset turned by 3 degrees from one frame to the next (camera NP3, the Carmine sensor's
//! effects), every frame prepared once (depth stage, cloud) and every consecutive pair
//! estimated from the prepared frames, pairs side by side on the pool's threads: what a camera
//! at frame rate hands a chain of pairwise estimates.

use super::pipeline::{CAMERA, Throughput};
use crate::dataset::{DEFAULT_DATASET_SEED, embedded_objects, ensure_object};
use anyhow::Context;
use flowfilter_pipeline::bigbird::{BigBirdObject, FrameId, SensorId};
use flowfilter_pipeline::eval::PoseErrors;
use flowfilter_pipeline::{Estimate, Pipeline, PipelineConfig, Pose, RgbdFrame, load_bigbird_frame};
use rayon::prelude::*;
use std::path::Path;
use std::time::Instant;

/// Degrees the turntable turns between consecutive frames.
pub const STEP_DEG: u32 = 3;

/// Where the streams' frames are synthesised and cached (apart from the default dataset's cache,
/// which holds other angles; the quick streams apart from the full ones, so that neither run
/// synthesises the other's again).
const ROOT: &str = "target/bench-stream";
const QUICK_ROOT: &str = "target/bench-stream-quick";

/// One object's frames in order, and the true motion of each consecutive pair.
pub struct Stream {
    /// The object's name.
    pub name: String,
    /// The frames, loaded (decoding is not timed: a camera hands over raw frames).
    pub frames: Vec<RgbdFrame>,
    /// `truths[k]`: the motion from frame `k` to frame `k + 1`.
    pub truths: Vec<Pose>,
}

/// The streams of every embedded object (`quick`: the procedural ones, 4 frames each; else 11
/// frames, 30 degrees).
pub struct Streams {
    /// One per object.
    pub streams: Vec<Stream>,
    /// What they are, for the report.
    pub description: String,
}

impl Streams {
    /// Consecutive pairs over all streams.
    pub fn pairs(&self) -> usize {
        self.streams.iter().map(|s| s.truths.len()).sum()
    }
}

/// Synthesise (or read from the cache) and load the streams.
///
/// # Errors
/// A dataset that cannot be synthesised or read.
pub fn load(quick: bool) -> anyhow::Result<Streams> {
    let camera: SensorId = CAMERA.parse().map_err(|e| anyhow::anyhow!("{e}"))?;
    let frames_per_stream: u32 = if quick { 4 } else { 11 };
    let angles: Vec<u32> = (0..frames_per_stream).map(|k| k * STEP_DEG).collect();
    let objects = embedded_objects(quick, None);
    let root = crate::in_repo(Path::new(if quick { QUICK_ROOT } else { ROOT }));
    let mut streams = vec![];
    for o in &objects {
        let dir = ensure_object(&root, o, &[camera], &angles, DEFAULT_DATASET_SEED)?;
        let object = BigBirdObject::open(&dir).with_context(|| format!("opening {}", dir.display()))?;
        let frames = angles
            .iter()
            .map(|&angle| load_bigbird_frame(&object, FrameId { sensor: camera, angle }))
            .collect::<Result<Vec<_>, _>>()?;
        let truths =
            angles.windows(2).map(|w| object.relative_motion(camera, w[0], w[1])).collect::<Result<Vec<_>, _>>()?;
        streams.push(Stream { name: o.name.clone(), frames, truths });
    }
    let mut streams = Streams { streams, description: String::new() };
    streams.description = format!(
        "{} streams, one per object, of {frames_per_stream} frames ({} pairs): camera {CAMERA}, {STEP_DEG} deg between frames (1280x1024 colour, 640x480 depth)",
        streams.streams.len(),
        streams.pairs(),
    );
    Ok(streams)
}

/// One stream's pairs per second (its frames' preparation included).
#[derive(Debug, Clone, serde::Serialize)]
pub struct StreamRate {
    /// The object.
    pub object: String,
    /// Its consecutive pairs per second of wall time.
    pub pairs_per_second: f64,
}

/// Every stream through `config`'s pipeline in `pool`: its frames prepared once, side by side,
/// then its consecutive pairs, side by side. Pairs per second count both (the wall time of the
/// streams, the frames' preparation included); the first stage time is the preparation of one
/// frame, the others are per pair. Also each stream's own rate.
///
/// # Errors
/// A configuration that does not make a pipeline, a frame or pair that fails.
pub fn throughput(
    streams: &Streams,
    config: &PipelineConfig,
    pool: &rayon::ThreadPool,
) -> anyhow::Result<(Throughput, Vec<StreamRate>)> {
    let pipeline = Pipeline::from_config(config.clone())?;
    let mut estimates: Vec<(Estimate, PoseErrors)> = vec![];
    let mut prepare_s = vec![];
    let mut rates = vec![];
    let mut wall = 0.0;
    for s in &streams.streams {
        let t0 = Instant::now();
        let (prepared, pairs) = pool.install(|| -> anyhow::Result<_> {
            let prepared = s.frames.par_iter().map(|f| pipeline.prepare(f)).collect::<Result<Vec<_>, _>>()?;
            let pairs = (0..s.truths.len())
                .into_par_iter()
                .map(|k| {
                    let e = pipeline.estimate_prepared(&prepared[k], &prepared[k + 1])?;
                    let errors = PoseErrors::new(&e.pose, &s.truths[k], Some(&prepared[k].cloud.points));
                    Ok((e, errors))
                })
                .collect::<anyhow::Result<Vec<_>>>()?;
            Ok((prepared, pairs))
        })?;
        let seconds = t0.elapsed().as_secs_f64();
        wall += seconds;
        rates.push(StreamRate { object: s.name.clone(), pairs_per_second: pairs.len() as f64 / seconds });
        prepare_s.extend(prepared.iter().map(|p| p.seconds));
        estimates.extend(pairs);
    }
    let prepare_ms = 1e3 * prepare_s.iter().sum::<f64>() / prepare_s.len().max(1) as f64;
    let throughput = Throughput::of(&estimates, wall, prepare_ms);
    Ok((throughput, rates))
}
