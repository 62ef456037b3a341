//! `flowfilter estimate-batch`: the pipeline on every pair of a CSV pair list, one JSON line per
//! pair, resumable after a crash and shardable over processes (`--shard K/N`).

use anyhow::Context;
use clap::Args;
use flowfilter_pipeline::batch::{BatchPair, Shard, read_pairs, shard_pairs};
use flowfilter_pipeline::{CameraFile, FrameFiles, Pipeline, PreparedFrame};
use std::collections::{BTreeSet, HashMap};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Arguments of `estimate-batch`.
#[derive(Args)]
pub struct EstimateBatchArgs {
    /// The pair list (CSV with a header): model_color, model_depth, target_color, target_depth,
    /// camera, and optionally id, model_mask, target_mask, label, gt (paths relative to the
    /// CSV's folder).
    #[arg(long)]
    pub pairs: PathBuf,
    /// Output: one JSON object per line, `{"id", "estimate"}` or `{"id", "error"}`. Pairs
    /// already in it are skipped (a run that crashed resumes where it stopped).
    #[arg(long)]
    pub out: PathBuf,
    /// Run only shard K of N: pairs grouped by model frame, groups dealt round-robin (each
    /// shard writes its own --out).
    #[arg(long)]
    pub shard: Option<Shard>,
    /// Registration method (overrides the configuration's `method`).
    #[arg(long, value_parser = crate::method_parser())]
    pub method: Option<String>,
    /// Pipeline configuration (TOML; see configs/).
    #[arg(long)]
    pub config: Option<PathBuf>,
}

/// The ids already in `out`, after cutting off a last line that a crash left unfinished.
fn done_ids(out: &Path) -> anyhow::Result<BTreeSet<String>> {
    let Ok(text) = std::fs::read_to_string(out) else { return Ok(BTreeSet::new()) };
    let mut ids = BTreeSet::new();
    let mut complete = 0;
    for line in text.split_inclusive('\n') {
        let Some(body) = line.strip_suffix('\n') else { break };
        let Some(id) =
            serde_json::from_str::<serde_json::Value>(body).ok().and_then(|v| v["id"].as_str().map(String::from))
        else {
            break;
        };
        ids.insert(id);
        complete += line.len();
    }
    if complete < text.len() {
        let file =
            std::fs::OpenOptions::new().write(true).open(out).with_context(|| format!("opening {}", out.display()))?;
        file.set_len(complete as u64).with_context(|| format!("truncating {}", out.display()))?;
        eprintln!("{}: dropped an unfinished last line ({} bytes)", out.display(), text.len() - complete);
    }
    Ok(ids)
}

/// Prepared frames of the current group (pairs of one model frame follow one another), by
/// their files and camera.
struct FrameCache {
    frames: HashMap<String, PreparedFrame>,
    /// Camera files read, by path (most batches have one camera).
    cameras: HashMap<PathBuf, CameraFile>,
}

impl FrameCache {
    /// Frames kept: a group's model frame and the targets it is paired with.
    const CAPACITY: usize = 64;

    fn get(&mut self, pipeline: &Pipeline, files: &FrameFiles, camera_path: &Path) -> anyhow::Result<PreparedFrame> {
        let key = format!("{files:?} {}", camera_path.display());
        if let Some(f) = self.frames.get(&key) {
            return Ok(f.clone());
        }
        if !self.cameras.contains_key(camera_path) {
            self.cameras.insert(camera_path.to_path_buf(), CameraFile::from_file(camera_path)?);
        }
        let camera = &self.cameras[camera_path];
        let stem =
            files.color.file_stem().map_or_else(|| files.color.display().to_string(), |s| s.to_string_lossy().into());
        let prepared = pipeline.prepare(&files.load(camera, &stem)?)?;
        if self.frames.len() >= Self::CAPACITY {
            self.frames.clear();
        }
        self.frames.insert(key, prepared.clone());
        Ok(prepared)
    }
}

/// One pair's output line.
fn estimate_line(pipeline: &Pipeline, cache: &mut FrameCache, pair: &BatchPair) -> serde_json::Value {
    let mut run = || -> anyhow::Result<flowfilter_pipeline::Estimate> {
        let started = std::time::Instant::now();
        let a = cache.get(pipeline, &pair.model, &pair.camera)?;
        let b = cache.get(pipeline, &pair.target, &pair.camera)?;
        let mut e = pipeline.estimate_prepared(&a, &b)?;
        e.stage_ms.total = started.elapsed().as_secs_f64() * 1e3;
        if let Some(gt) = &pair.gt {
            e = e.with_ground_truth(&crate::matrix_file::read_pose(gt)?, Some(&a.cloud.points));
        }
        Ok(e)
    };
    match run() {
        Ok(e) => serde_json::json!({ "id": pair.id, "estimate": e }),
        Err(e) => serde_json::json!({ "id": pair.id, "error": format!("{e:#}") }),
    }
}

/// Run `estimate-batch`.
pub fn run(args: &EstimateBatchArgs) -> anyhow::Result<ExitCode> {
    let pipeline = crate::estimate::pipeline(args.config.as_deref(), args.method.as_deref())?;
    let pairs = read_pairs(&args.pairs)?;
    let shard = args.shard.unwrap_or(Shard::ALL);
    let mine = shard_pairs(&pairs, shard);
    let done = done_ids(&args.out)?;
    let todo: Vec<&BatchPair> = mine.iter().copied().filter(|p| !done.contains(&p.id)).collect();
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let mut out = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&args.out)
        .with_context(|| format!("opening {}", args.out.display()))?;
    eprintln!(
        "estimate-batch: shard {shard}: {} of {} pairs, {} already in {}, {} to run",
        mine.len(),
        pairs.len(),
        mine.len() - todo.len(),
        args.out.display(),
        todo.len()
    );
    let bar = crate::progress::bar(todo.len(), "pairs");
    bar.set_message("estimate-batch");
    let mut cache = FrameCache { frames: HashMap::new(), cameras: HashMap::new() };
    let mut failed = 0;
    for (i, pair) in todo.iter().enumerate() {
        let line = estimate_line(&pipeline, &mut cache, pair);
        failed += usize::from(line.get("error").is_some());
        // One write per line, flushed: a crash leaves at most one unfinished line.
        out.write_all((serde_json::to_string(&line)? + "\n").as_bytes())
            .and_then(|()| out.flush())
            .with_context(|| format!("writing {}", args.out.display()))?;
        crate::progress::advance(&bar, i + 1);
    }
    bar.finish_and_clear();
    eprintln!("estimate-batch: {} pairs run, {failed} failed; results in {}", todo.len(), args.out.display());
    Ok(if failed == 0 { ExitCode::SUCCESS } else { ExitCode::from(2) })
}
