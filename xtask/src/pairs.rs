//! What both benchmarks share: frames prepared once per group of methods, every (pair, method)
//! estimated and scored against the ground truth, and the "no motion" answer scored beside them.

use crate::failures::FailureLog;
use anyhow::Context;
use flowfilter_eval::PoseErrors;
use flowfilter_pipeline::geometry::rigid_from_matrix;
use flowfilter_pipeline::{
    AlignReport, JudgeReport, Pipeline, PipelineConfig, PipelineWarning, Point3, Pose, PreparedFrame, RgbdFrame,
    StageTimes, Uncertainty,
};
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Display;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// The options every benchmark takes for its run and its outputs.
#[derive(clap::Args, Debug, Clone)]
pub struct RunArgs {
    /// Output root (a timestamped directory is created inside).
    #[arg(long, default_value = "results")]
    pub out: PathBuf,
    /// Voxel size of the clouds given to the registration, metres (overrides the pipeline
    /// configurations' `cloud.voxel_m`).
    #[arg(long)]
    pub voxel: Option<f64>,
    /// Exit non-zero unless results.json holds every method with every metric and no pair
    /// failed (what CI checks).
    #[arg(long)]
    pub check: bool,
    /// Run only shard K of N (e.g. 2/3): every N-th object (BigBIRD) or scene (BOP), each
    /// frame prepared in one shard only, written to OUT/shard-K-of-N/ with a manifest that
    /// `cargo xtask bench-merge` checks and merges.
    #[arg(long)]
    pub shard: Option<crate::shard::Shard>,
    /// Record the failing pairs (a method's estimate not a success) to this Rerun file: both
    /// frames, depth, masks, clouds, flow pairs, the judge's candidates, pose, bounds and
    /// error, one step of the `pair` timeline each (docs/rerun.md). Needs `--features rerun`.
    #[arg(long)]
    pub rerun: Option<PathBuf>,
    /// At most this many failing pairs are recorded (each holds both frames' images).
    #[arg(long, default_value_t = 20)]
    pub rerun_limit: usize,
}

/// The row of the identity estimate: what answering "it did not move" scores.
pub const NO_MOTION: &str = "no-motion";

/// One registration (or the "no motion" answer) of one pair (read back by `bench-merge`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PairResult {
    /// Object (BigBIRD: directory name; BOP: `obj_000001`, or its name when known).
    pub object: String,
    /// What took the sequence: the BigBIRD camera (`NP1`..`NP5`), or the BOP scene folder.
    pub camera: String,
    /// Model frame: turntable angle (BigBIRD) or image id (BOP).
    pub from: u32,
    /// Target frame, likewise.
    pub to: u32,
    /// Rotation step in degrees (BigBIRD) or image gap (BOP).
    pub step: u32,
    /// Rotation angle of the true motion, degrees (what "no motion" misses by).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub motion_deg: Option<f64>,
    /// Method (or [`NO_MOTION`]).
    pub method: String,
    /// Errors, when the pair ran.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub errors: Option<PoseErrors>,
    /// The estimated motion (4x4, row-major, `P_target = T * P_model`), when the pair ran with
    /// a method: to compare estimates of one pair, or an estimate with another truth.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transform: Option<[[f64; 4]; 4]>,
    /// Whether the method reported convergence.
    pub converged: Option<bool>,
    /// The method's error bounds, when it gives them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncertainty: Option<Uncertainty>,
    /// Time of the pair (flow, correspondences, registration), seconds.
    pub seconds: Option<f64>,
    /// Per-stage times (the two frames' depth stages included).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stage_ms: Option<StageTimes>,
    /// Warnings of the pipeline (fallbacks taken), as `{code, message}` objects.
    pub warnings: Vec<serde_json::Value>,
    /// What the photometric judge saw (Flow Filter methods).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub judge: Option<JudgeReport>,
    /// When the judge re-tracked a candidate: the geodesic error (degrees) of the result it did
    /// not take (the re-tracked one when it kept the answer, else the answer).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub judge_other_error_deg: Option<f64>,
    /// ... and of the one it took, before the alignment moved it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub judge_chosen_error_deg: Option<f64>,
    /// What the direct alignment did (Flow Filter methods).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub align: Option<AlignReport>,
    /// The stage that failed and why.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub failure: Option<String>,
}

impl PairResult {
    /// `job`'s row for `method`, before anything is scored.
    pub(crate) fn unscored<K>(job: &PairJob<K>, method: String) -> Self {
        PairResult {
            object: job.object.clone(),
            camera: job.camera.clone(),
            from: job.from,
            to: job.to,
            step: job.step,
            motion_deg: job.truth.as_ref().ok().map(|t| t.rotation.angle().to_degrees()),
            method,
            errors: None,
            transform: None,
            converged: None,
            uncertainty: None,
            seconds: None,
            stage_ms: None,
            warnings: vec![],
            judge: None,
            judge_other_error_deg: None,
            judge_chosen_error_deg: None,
            align: None,
            failure: None,
        }
    }

    /// The row of a reference answer that no method computed (another record of the same
    /// motion, [`crate::report::ReportSpec::references`]): `answer` scored against `job`'s
    /// truth, ADD-S over `model` (the model frame's cloud); a failure when either is missing.
    pub fn reference<K>(
        job: &PairJob<K>,
        method: &str,
        answer: Result<Pose, String>,
        model: Option<&[Point3]>,
    ) -> Self {
        let mut row = Self::unscored(job, method.to_string());
        let scored = || -> Result<PoseErrors, String> {
            let truth = job.truth.as_ref().map_err(|e| format!("ground truth: {e}"))?;
            let answer = answer.map_err(|e| format!("{method}: {e}"))?;
            let model = model.ok_or("the model frame could not be prepared")?;
            row.transform = Some(flowfilter_pipeline::matrix_rows(&answer));
            Ok(PoseErrors::new(&answer, truth, Some(model)))
        };
        match scored() {
            Ok(errors) => row.errors = Some(errors),
            Err(e) => row.failure = Some(e),
        }
        row
    }
}

/// A pipeline warning as its JSON object (`{code, message}`).
fn warning_json(w: &PipelineWarning) -> serde_json::Value {
    serde_json::to_value(w)
        .unwrap_or_else(|e| serde_json::json!({ "code": "unserialisable", "message": e.to_string() }))
}

/// One pair of a benchmark: its names, its frames' keys and its ground truth.
pub struct PairJob<K> {
    /// See [`PairResult::object`].
    pub object: String,
    /// See [`PairResult::camera`].
    pub camera: String,
    /// See [`PairResult::from`].
    pub from: u32,
    /// See [`PairResult::to`].
    pub to: u32,
    /// See [`PairResult::step`].
    pub step: u32,
    /// The model frame.
    pub model: K,
    /// The target frame.
    pub target: K,
    /// The true motion model -> target, or why it is unknown.
    pub truth: Result<Pose, String>,
}

/// Frames prepared by a group's pipeline, or why they could not be.
pub type PreparedFrames<K> = BTreeMap<(usize, K), Result<PreparedFrame, String>>;

/// Progress of a step: an indicatif bar on a terminal, else a plain line at every tenth of the
/// work and at the end (logs and CI output).
pub struct Progress {
    bar: ProgressBar,
    plain: bool,
    len: u64,
    done: AtomicU64,
    msg: String,
}

impl Progress {
    /// One more item done.
    pub fn inc(&self, n: u64) {
        self.bar.inc(n);
        let done = self.done.fetch_add(n, Ordering::Relaxed) + n;
        let tenth = self.len.div_ceil(10).max(1);
        if self.plain && done < self.len && done / tenth != (done - n) / tenth {
            eprintln!("{}: {done}/{}", self.msg, self.len);
        }
    }

    /// The step is over.
    pub fn finish(&self) {
        self.bar.finish();
        if self.plain {
            eprintln!(
                "{}: {}/{} in {:.1} s",
                self.msg,
                self.done.load(Ordering::Relaxed),
                self.len,
                self.bar.elapsed().as_secs_f64()
            );
        }
    }
}

/// The progress of a step of `len` items.
pub fn progress(len: u64, msg: &str) -> Progress {
    let bar = ProgressBar::new(len);
    bar.set_style(ProgressStyle::with_template("{msg:40} [{bar:30}] {pos}/{len} {elapsed}").expect("valid template"));
    bar.set_message(msg.to_string());
    let plain = !std::io::stderr().is_terminal();
    Progress { bar, plain, len, done: AtomicU64::new(0), msg: msg.to_string() }
}

/// One pipeline configuration per method: the file at `pipeline` (under the repository root
/// when relative) with its `method` key replaced by each name, and `voxel` as the clouds'
/// voxel size when given.
///
/// # Errors
/// A file that does not load, or a method the configuration does not validate with.
pub fn method_configs(
    pipeline: &std::path::Path,
    methods: &[String],
    voxel: Option<f64>,
) -> anyhow::Result<Vec<PipelineConfig>> {
    let base = PipelineConfig::from_file(&crate::in_repo(pipeline))?;
    methods
        .iter()
        .map(|m| {
            let mut c = base.clone();
            c.method = m.clone();
            if let Some(v) = voxel {
                c.cloud.voxel_m = v;
            }
            c.validate().map_err(|e| anyhow::anyhow!("method '{m}': {e}"))?;
            Ok(c)
        })
        .collect()
}

/// For each method, the first method whose depth and cloud stages agree with it: methods of
/// one group share their prepared frames.
pub fn preparation_groups(configs: &[PipelineConfig]) -> Vec<usize> {
    let mut groups: Vec<usize> = vec![];
    for (i, c) in configs.iter().enumerate() {
        let same = (0..i).find(|&j| configs[j].depth == c.depth && configs[j].cloud == c.cloud);
        groups.push(same.map_or(i, |j| groups[j]));
    }
    groups
}

/// The methods' pipelines and how they share prepared frames.
pub struct Methods<'a> {
    /// Method names (labels).
    pub names: &'a [String],
    /// One pipeline per method.
    pub pipelines: Vec<Pipeline>,
    /// [`preparation_groups`] of their configurations.
    pub groups: Vec<usize>,
    /// Where failing pairs are recorded (`--rerun`), when asked.
    pub failures: Option<Mutex<FailureLog>>,
}

impl<'a> Methods<'a> {
    /// One pipeline per configuration (`names[i]` labels `configs[i]`).
    ///
    /// # Errors
    /// A configuration that does not make a pipeline, named by its method.
    pub fn new(names: &'a [String], configs: &[PipelineConfig]) -> anyhow::Result<Self> {
        let pipelines = configs
            .iter()
            .map(|c| Pipeline::from_config(c.clone()).with_context(|| format!("method '{}'", c.method)))
            .collect::<anyhow::Result<_>>()?;
        Ok(Self { names, pipelines, groups: preparation_groups(configs), failures: None })
    }
}

impl Methods<'_> {
    /// Every frame, loaded and prepared once per group.
    pub fn prepare<K>(
        &self,
        frames: &[K],
        load: &(dyn Fn(K) -> Result<RgbdFrame, String> + Sync),
        label: &str,
    ) -> PreparedFrames<K>
    where
        K: Ord + Copy + Send + Sync,
    {
        let preparers: BTreeSet<usize> = self.groups.iter().copied().collect();
        let work: Vec<(usize, K)> = preparers.iter().flat_map(|&g| frames.iter().map(move |&f| (g, f))).collect();
        let bar = progress(work.len() as u64, &format!("{label}: depth stage"));
        let prepared = work
            .par_iter()
            .map(|&(g, key)| {
                let data = load(key).and_then(|f| self.pipelines[g].prepare(&f).map_err(|e| e.to_string()));
                bar.inc(1);
                ((g, key), data)
            })
            .collect();
        bar.finish();
        prepared
    }

    /// Record the failing pairs of every later [`Methods::run`] in `path` (at most `limit`).
    ///
    /// # Errors
    /// The file cannot be created, or this build has no Rerun (feature `rerun`).
    pub fn record_failures(&mut self, path: Option<&Path>, limit: usize) -> anyhow::Result<()> {
        self.failures = path.map(|p| FailureLog::create(p, limit)).transpose()?;
        Ok(())
    }

    /// Close the recording of failing pairs, if any.
    ///
    /// # Errors
    /// The last entities cannot be written.
    pub fn finish_recording(&mut self) -> anyhow::Result<()> {
        match self.failures.take() {
            Some(log) => log.into_inner().map_err(|_| anyhow::anyhow!("--rerun: the recording was poisoned"))?.finish(),
            None => Ok(()),
        }
    }

    /// Every pair with every method, plus its "no motion" row, estimated and scored; the
    /// failing pairs recorded when [`Methods::record_failures`] asked for it (`load` gives
    /// their colour images again).
    ///
    /// # Errors
    /// Only the recording's: a failing pair that cannot be written.
    pub fn run<K>(
        &self,
        jobs: &[PairJob<K>],
        prepared: &PreparedFrames<K>,
        load: &(dyn Fn(K) -> Result<RgbdFrame, String> + Sync),
        label: &str,
    ) -> anyhow::Result<Vec<PairResult>>
    where
        K: Ord + Copy + Send + Sync + Display,
    {
        let rows = self.run_rows(jobs, prepared, label);
        if let Some(log) = &self.failures {
            let mut log = log.lock().map_err(|_| anyhow::anyhow!("--rerun: the recording was poisoned"))?;
            log.record((self.names, &self.pipelines, &self.groups), jobs, prepared, &rows, load)?;
        }
        Ok(rows)
    }

    fn run_rows<K>(&self, jobs: &[PairJob<K>], prepared: &PreparedFrames<K>, label: &str) -> Vec<PairResult>
    where
        K: Ord + Copy + Send + Sync + Display,
    {
        let rows_per_job = self.names.len() + 1;
        let work: Vec<(usize, usize)> = (0..jobs.len()).flat_map(|j| (0..rows_per_job).map(move |m| (j, m))).collect();
        let bar = progress(work.len() as u64, &format!("{label}: registration"));
        let rows = work
            .par_iter()
            .map(|&(j, m)| {
                let row = self.run_one(&jobs[j], (m < self.names.len()).then_some(m), prepared);
                bar.inc(1);
                row
            })
            .collect();
        bar.finish();
        rows
    }

    /// One pair with method `m`, or the "no motion" answer for `None`.
    fn run_one<K>(&self, job: &PairJob<K>, m: Option<usize>, prepared: &PreparedFrames<K>) -> PairResult
    where
        K: Ord + Copy + Display,
    {
        let mut row = PairResult::unscored(job, m.map_or(NO_MOTION.to_string(), |m| self.names[m].clone()));
        let group = self.groups[m.unwrap_or(0)];
        let get = |key: K| match prepared.get(&(group, key)) {
            Some(Ok(c)) => Ok(c),
            Some(Err(e)) => Err(format!("frame {key}: {e}")),
            None => Err(format!("frame {key}: not in the dataset")),
        };
        let outcome = (|| -> Result<(), String> {
            let (model, target) = (get(job.model)?, get(job.target)?);
            let truth = job.truth.as_ref().map_err(|e| format!("ground truth: {e}"))?;
            let Some(m) = m else {
                row.errors = Some(PoseErrors::new(&Pose::identity(), truth, Some(&model.cloud.points)));
                return Ok(());
            };
            let t0 = Instant::now();
            let e = self.pipelines[m].estimate_prepared(model, target).map_err(|e| e.to_string())?;
            row.seconds = Some(t0.elapsed().as_secs_f64());
            row.converged = Some(e.registration.converged);
            row.transform = Some(e.transform);
            row.uncertainty = e.registration.uncertainty;
            row.errors = Some(PoseErrors::new(&e.pose, truth, Some(&model.cloud.points)));
            row.stage_ms = Some(e.stage_ms);
            row.warnings = e.warnings.iter().map(warning_json).collect();
            let error_of = |m: &[[f64; 4]; 4]| {
                let pose = rigid_from_matrix(&nalgebra::Matrix4::from_fn(|r, c| m[r][c])).ok()?;
                Some(PoseErrors::new(&pose, truth, None).geodesic_error_deg)
            };
            if let Some(j) = e.judge.as_ref().filter(|j| j.retracked_transform.is_some()) {
                let (chosen, other) = if j.replaced {
                    (j.retracked_transform, Some(j.answer_transform))
                } else {
                    (Some(j.answer_transform), j.retracked_transform)
                };
                row.judge_chosen_error_deg = chosen.as_ref().and_then(error_of);
                row.judge_other_error_deg = other.as_ref().and_then(error_of);
            }
            row.judge = e.judge;
            row.align = e.align;
            Ok(())
        })();
        row.failure = outcome.err();
        row
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn job(truth: Result<Pose, String>) -> PairJob<u32> {
        PairJob {
            object: "region".into(),
            camera: "shelf-A".into(),
            from: 2,
            to: 3,
            step: 1,
            model: 2,
            target: 3,
            truth,
        }
    }

    /// A reference answer is scored like an estimate (its transform kept, ADD-S over the model
    /// cloud) but carries no times; without a truth, an answer or a model cloud it is a failed
    /// row that says which.
    #[test]
    fn a_reference_answer_is_scored_against_the_truth() {
        let truth = Pose::new(nalgebra::Vector3::new(0.05, 0.0, 0.0), nalgebra::Vector3::new(0.0, 0.2, 0.0));
        let answer = Pose::new(nalgebra::Vector3::new(0.05, 0.0, 0.0), nalgebra::Vector3::new(0.0, 0.21, 0.0));
        let model = [Point3::new(0.0, 0.0, 0.5), Point3::new(0.1, 0.0, 0.5)];
        let row = PairResult::reference(&job(Ok(truth)), "arm-record", Ok(answer), Some(&model));
        let e = row.errors.as_ref().unwrap();
        assert!((e.geodesic_error_deg - 0.01f64.to_degrees()).abs() < 1e-9, "{e:?}");
        assert!(e.add_s_m.is_some() && row.stage_ms.is_none() && row.seconds.is_none() && row.failure.is_none());
        assert_eq!((row.method.as_str(), row.transform.is_some()), ("arm-record", true));
        let failed = |r: PairResult| r.failure.unwrap();
        assert!(
            failed(PairResult::reference(&job(Err("no pose".into())), "arm-record", Ok(answer), Some(&model)))
                .contains("ground truth: no pose")
        );
        assert!(
            failed(PairResult::reference(&job(Ok(truth)), "arm-record", Err("frame 3: no pose".into()), Some(&model)))
                .contains("arm-record: frame 3")
        );
        assert!(failed(PairResult::reference(&job(Ok(truth)), "arm-record", Ok(answer), None)).contains("model frame"));
    }
}
