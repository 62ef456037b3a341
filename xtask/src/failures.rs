//! `--rerun FILE.rrd` of the benchmarks: the failing pairs (a method's estimate not a success)
//! estimated again with their trace and written to one Rerun recording, one step of the `pair`
//! timeline each, up to `--rerun-limit` pairs.

use crate::pairs::{NO_MOTION, PairJob, PairResult, PreparedFrames};
use anyhow::Context;
use flowfilter_pipeline::{Pipeline, Pose, RgbdFrame};
use flowfilter_rerun::{FrameInput, PairScene, Recorder};
use std::fmt::Display;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// The recording of a benchmark's failing pairs.
pub struct FailureLog {
    recorder: Recorder,
    path: PathBuf,
    limit: usize,
    recorded: usize,
    /// Failing pairs beyond the limit (not recorded).
    left_out: usize,
}

impl FailureLog {
    /// A recording in `path`, of at most `limit` pairs.
    ///
    /// # Errors
    /// The file cannot be created, or this build has no Rerun (feature `rerun`).
    pub fn create(path: &Path, limit: usize) -> anyhow::Result<Mutex<Self>> {
        let recorder = Recorder::create(path, "flowfilter benchmark failures").context("--rerun")?;
        Ok(Mutex::new(Self { recorder, path: path.to_path_buf(), limit, recorded: 0, left_out: 0 }))
    }

    /// Record the failing rows of `rows` (the rows of `jobs` as [`crate::pairs::Methods::run`]
    /// returns them: per job, one row per method and the "no motion" row).
    ///
    /// # Errors
    /// A frame that cannot be loaded again, or an entity that cannot be written.
    pub fn record<K>(
        &mut self,
        (names, pipelines, groups): (&[String], &[Pipeline], &[usize]),
        jobs: &[PairJob<K>],
        prepared: &PreparedFrames<K>,
        rows: &[PairResult],
        load: &(dyn Fn(K) -> Result<RgbdFrame, String> + Sync),
    ) -> anyhow::Result<()>
    where
        K: Ord + Copy + Display,
    {
        let per_job = names.len() + 1;
        for (j, job) in jobs.iter().enumerate() {
            for (m, row) in rows[j * per_job..(j + 1) * per_job].iter().enumerate() {
                let failed = row.method != NO_MOTION && row.errors.as_ref().is_some_and(|e| !e.success);
                let Ok(truth) = job.truth.as_ref() else { continue };
                if !failed || m >= names.len() {
                    continue;
                }
                if self.recorded >= self.limit {
                    self.left_out += 1;
                    continue;
                }
                let key = |k: K| prepared.get(&(groups[m], k)).and_then(|p| p.as_ref().ok());
                let (Some(a), Some(b)) = (key(job.model), key(job.target)) else { continue };
                let (fa, fb) =
                    (load(job.model).map_err(anyhow::Error::msg)?, load(job.target).map_err(anyhow::Error::msg)?);
                let scene = traced_scene(&pipelines[m], (&fa, a), (&fb, b), truth)?;
                let step = i64::try_from(self.recorded).unwrap_or(i64::MAX);
                self.recorder.log_pair(step, &scene)?;
                tracing::info!(step, pair = %scene.label, method = %names[m], object = %job.object, "recorded a failing pair");
                self.recorded += 1;
            }
        }
        Ok(())
    }

    /// Close the file; a line says what it holds.
    ///
    /// # Errors
    /// The last entities cannot be written.
    pub fn finish(self) -> anyhow::Result<()> {
        let (path, recorded, left_out) = (self.path.clone(), self.recorded, self.left_out);
        self.recorder.finish()?;
        let more = if left_out > 0 { format!(" ({left_out} more beyond --rerun-limit)") } else { String::new() };
        println!(
            "rerun: {recorded} failing pair(s) recorded in {}{more}; open with `rerun {}`",
            path.display(),
            path.display()
        );
        Ok(())
    }
}

/// One pair estimated again with its trace, scored against `truth`.
fn traced_scene(
    pipeline: &Pipeline,
    (model_frame, model): (&RgbdFrame, &flowfilter_pipeline::PreparedFrame),
    (target_frame, target): (&RgbdFrame, &flowfilter_pipeline::PreparedFrame),
    truth: &Pose,
) -> anyhow::Result<PairScene> {
    let (e, trace) = pipeline.estimate_traced(model, target)?;
    let e = e.with_ground_truth(truth, Some(&model.cloud.points));
    let model = FrameInput { color: &model_frame.color, prepared: model };
    let target = FrameInput { color: &target_frame.color, prepared: target };
    Ok(PairScene::new(model, target, &e, &trace, Some(truth)))
}
