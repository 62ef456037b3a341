//! `cargo xtask bench-bigbird`: per object, camera, base angle and rotation step, register the
//! object cloud of the model frame (base angle) to that of the target frame (base + step) with
//! every method, and score the estimate against the turntable ground truth.

use crate::dataset::{default_objects, ensure_object};
use anyhow::{Context, bail};
use clap::Args;
use flowfilter_bigbird::{BigBirdObject, FrameId, SensorId};
use flowfilter_eval::{PoseErrors, mean_median};
use flowfilter_pipeline::{Pipeline, PipelineConfig, PipelineWarning, PreparedFrame, StageTimes, load_bigbird_frame};
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `bench-bigbird`.
#[derive(Args)]
pub struct BenchArgs {
    /// Small protocol for CI: procedural objects, one camera, steps 3/15/30.
    #[arg(long)]
    pub quick: bool,
    /// A real BigBIRD download (a directory of object directories) instead of the embedded dataset.
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Directories of textured meshes (`*/textured.obj`) to add to the embedded dataset
    /// (default: ../shared/data/ycb when present; not used with --quick).
    #[arg(long)]
    pub meshes: Option<PathBuf>,
    /// The protocol (TOML; default configs/bench/full.toml, or configs/bench/quick.toml with
    /// --quick).
    #[arg(long)]
    pub protocol: Option<PathBuf>,
    /// Methods, comma separated (overrides the protocol's).
    #[arg(long, value_delimiter = ',')]
    pub methods: Option<Vec<String>>,
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
}

/// The experiment's protocol, read from TOML (`configs/bench/*.toml`).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Protocol {
    /// Cameras (`NP1`..`NP5`).
    pub cameras: Vec<String>,
    /// Model-frame angles.
    pub base_angles: Vec<u32>,
    /// Rotation steps (degrees).
    pub steps: Vec<u32>,
    /// Methods.
    pub methods: Vec<String>,
    /// Pipeline configuration shared by the methods (relative to the repository root).
    #[serde(default)]
    pub pipeline: Option<PathBuf>,
    /// Per-method pipeline configurations.
    #[serde(default)]
    pub method_configs: BTreeMap<String, PathBuf>,
}

/// The repository root (relative paths in protocols are resolved against it).
fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

impl Protocol {
    /// Parse a protocol; `origin` names it in errors.
    pub fn from_toml(text: &str, origin: &str) -> anyhow::Result<Self> {
        let p: Self = toml::from_str(text).map_err(|e| anyhow::anyhow!("{origin}: {}", e.message().trim()))?;
        if p.cameras.is_empty() || p.base_angles.is_empty() || p.steps.is_empty() || p.methods.is_empty() {
            bail!("{origin}: cameras, base_angles, steps and methods must not be empty");
        }
        p.sensors().map_err(|e| anyhow::anyhow!("{origin}: {e}"))?;
        Ok(p)
    }

    /// The cameras as sensor ids.
    pub fn sensors(&self) -> Result<Vec<SensorId>, String> {
        self.cameras.iter().map(|c| c.parse::<SensorId>().map_err(|e| format!("cameras: '{c}': {e}"))).collect()
    }

    /// The pipeline configuration of each method.
    fn method_configs(&self, voxel: Option<f64>) -> anyhow::Result<Vec<PipelineConfig>> {
        let load = |p: &Path| -> anyhow::Result<PipelineConfig> {
            let path = if p.is_absolute() { p.to_path_buf() } else { repo_root().join(p) };
            Ok(PipelineConfig::from_file(&path)?)
        };
        let base = self.pipeline.as_deref().map(load).transpose()?.unwrap_or_default();
        self.methods
            .iter()
            .map(|m| {
                let mut c = match self.method_configs.get(m) {
                    Some(p) => load(p)?,
                    None => base.clone(),
                };
                // "registrar@label" runs the registrar under its own label (and method_configs entry).
                c.method = m.split('@').next().unwrap_or(m).to_string();
                if let Some(v) = voxel {
                    c.cloud.voxel_m = v;
                }
                c.validate().map_err(|e| anyhow::anyhow!("method '{m}': {e}"))?;
                Ok(c)
            })
            .collect()
    }

    fn angles(&self) -> Vec<u32> {
        let mut set = BTreeSet::new();
        for &b in &self.base_angles {
            set.insert(b);
            for &s in &self.steps {
                set.insert((b + s) % 360);
            }
        }
        set.into_iter().collect()
    }
}

/// One registration.
#[derive(Debug, Clone, Serialize)]
pub struct PairResult {
    /// Object directory name.
    pub object: String,
    /// Camera.
    pub camera: String,
    /// Model angle.
    pub from: u32,
    /// Target angle.
    pub to: u32,
    /// Rotation step.
    pub step: u32,
    /// Method.
    pub method: String,
    /// Errors, when the pair ran.
    pub errors: Option<PoseErrors>,
    /// Whether the method reported convergence.
    pub converged: Option<bool>,
    /// Time of the pair (flow, correspondences, registration), seconds.
    pub seconds: Option<f64>,
    /// Per-stage times (the two frames' depth stages included).
    pub stage_ms: Option<StageTimes>,
    /// Warnings of the pipeline (fallbacks taken).
    pub warnings: Vec<PipelineWarning>,
    /// The stage that failed and why.
    pub failure: Option<String>,
}

/// The paper's reported mean rotation errors (degrees): Flow Filter, FilterReg, CPD.
const PAPER: [(&str, [f64; 3]); 5] = [
    ("Advil box", [2.95, 8.69, 5.8]),
    ("fish can", [11.12, 20.62, 16.43]),
    ("Pepto bottle", [2.19, 7.57, 10.69]),
    ("Quaker granola box", [2.12, 8.69, 5.81]),
    ("chicken noodle box", [1.51, 8.0, 9.33]),
];

fn timestamp() -> String {
    let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs());
    let (days, rem) = (secs / 86400, secs % 86400);
    // Civil date from days since 1970-01-01 (Howard Hinnant's algorithm).
    let z = days as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!("{y:04}-{m:02}-{d:02}T{:02}{:02}{:02}Z", rem / 3600, rem % 3600 / 60, rem % 60)
}

/// The protocol files shipped in `configs/bench/` (embedded: they work from any directory).
const FULL_PROTOCOL: &str = include_str!("../../configs/bench/full.toml");
const QUICK_PROTOCOL: &str = include_str!("../../configs/bench/quick.toml");

/// Run the benchmark: the protocol, one pipeline per method, the objects, then per object its
/// frames (prepared once per group of methods) and its pairs.
pub fn run(args: &BenchArgs) -> anyhow::Result<()> {
    let protocol = load_protocol(args)?;
    let cameras = protocol.sensors().map_err(anyhow::Error::msg)?;
    let configs = protocol.method_configs(args.voxel)?;
    let pipelines: Vec<Pipeline> = configs
        .iter()
        .map(|c| Pipeline::from_config(c.clone()).with_context(|| format!("method '{}'", c.method)))
        .collect::<anyhow::Result<_>>()?;
    let groups = preparation_groups(&configs);
    let started = Instant::now();
    let object_dirs = object_dirs(args, &protocol, &cameras)?;
    let mut results: Vec<PairResult> = Vec::new();
    let mut skipped: Vec<String> = Vec::new();
    for dir in &object_dirs {
        let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let obj = match BigBirdObject::open(dir) {
            Ok(o) => o,
            Err(e) => {
                tracing::warn!(object = %name, error = %e, "skipping object");
                skipped.push(format!("{name}: {e}"));
                continue;
            }
        };
        let bench = ObjectBench { name: &name, object: &obj, protocol: &protocol, cameras: &cameras };
        let prepared = bench.prepare_frames(&pipelines, &groups);
        results.append(&mut bench.run_pairs(&pipelines, &groups, &prepared));
    }
    write_outputs(args, &protocol, &results, &skipped, started.elapsed().as_secs_f64())
}

/// The protocol: `--protocol`, or the shipped quick or full one; `--methods` overrides its
/// methods.
fn load_protocol(args: &BenchArgs) -> anyhow::Result<Protocol> {
    let mut protocol = match &args.protocol {
        Some(p) => Protocol::from_toml(
            &std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?,
            &p.display().to_string(),
        )?,
        None if args.quick => Protocol::from_toml(QUICK_PROTOCOL, "configs/bench/quick.toml")?,
        None => Protocol::from_toml(FULL_PROTOCOL, "configs/bench/full.toml")?,
    };
    if let Some(m) = &args.methods {
        protocol.methods = m.clone();
    }
    Ok(protocol)
}

/// For each method, the first method whose depth and cloud stages agree with it: methods of
/// one group share their prepared frames.
fn preparation_groups(configs: &[PipelineConfig]) -> Vec<usize> {
    let mut groups: Vec<usize> = vec![];
    for (i, c) in configs.iter().enumerate() {
        let same = (0..i).find(|&j| configs[j].depth == c.depth && configs[j].cloud == c.cloud);
        groups.push(same.map_or(i, |j| groups[j]));
    }
    groups
}

/// The object directories: a real download (`--data`), or the embedded dataset (synthesised
/// once, cached under `target/bigbird-default`).
fn object_dirs(args: &BenchArgs, protocol: &Protocol, cameras: &[SensorId]) -> anyhow::Result<Vec<PathBuf>> {
    if let Some(root) = &args.data {
        let mut dirs: Vec<PathBuf> = std::fs::read_dir(root)
            .with_context(|| format!("reading {}", root.display()))?
            .filter_map(Result::ok)
            .map(|e| e.path())
            .filter(|p| p.is_dir())
            .collect();
        dirs.sort();
        if dirs.is_empty() {
            bail!("{}: no object directories", root.display());
        }
        return Ok(dirs);
    }
    let meshes = if args.quick {
        None
    } else {
        args.meshes.clone().or_else(|| Some(PathBuf::from("../shared/data/ycb")).filter(|p| p.is_dir()))
    };
    let objects = default_objects(meshes.as_deref());
    let root = Path::new("target").join("bigbird-default");
    let angles = protocol.angles();
    let bar = progress(objects.len() as u64, "synthesising the default dataset (cached)");
    let dirs = objects
        .par_iter()
        .map(|o| {
            let d = ensure_object(&root, o, cameras, &angles, 7);
            bar.inc(1);
            d
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    bar.finish();
    Ok(dirs)
}

/// Frames prepared by a group's pipeline, or why they could not be.
type PreparedFrames = BTreeMap<(usize, FrameId), Result<PreparedFrame, String>>;

/// One object's part of the benchmark.
struct ObjectBench<'a> {
    name: &'a str,
    object: &'a BigBirdObject,
    protocol: &'a Protocol,
    cameras: &'a [SensorId],
}

impl ObjectBench<'_> {
    /// Every frame the protocol needs, prepared once per group of methods.
    fn prepare_frames(&self, pipelines: &[Pipeline], groups: &[usize]) -> PreparedFrames {
        let preparers: BTreeSet<usize> = groups.iter().copied().collect();
        let frames: Vec<FrameId> = self
            .cameras
            .iter()
            .flat_map(|&sensor| self.protocol.angles().into_iter().map(move |angle| FrameId { sensor, angle }))
            .filter(|id| self.object.has_frame(*id))
            .collect();
        let work: Vec<(usize, FrameId)> = preparers.iter().flat_map(|&g| frames.iter().map(move |&f| (g, f))).collect();
        let bar = progress(work.len() as u64, &format!("{}: depth stage", self.name));
        let prepared = work
            .par_iter()
            .map(|&(g, id)| {
                let data = load_bigbird_frame(self.object, id)
                    .map_err(|e| format!("loading: {e}"))
                    .and_then(|f| pipelines[g].prepare(&f).map_err(|e| e.to_string()));
                bar.inc(1);
                ((g, id), data)
            })
            .collect();
        bar.finish();
        prepared
    }

    /// Every (camera, base angle, step, method) of the protocol.
    fn jobs(&self) -> Vec<(SensorId, u32, u32, u32, usize)> {
        let mut jobs = vec![];
        for &sensor in self.cameras {
            for &base in &self.protocol.base_angles {
                for &step in &self.protocol.steps {
                    for m in 0..self.protocol.methods.len() {
                        jobs.push((sensor, base, (base + step) % 360, step, m));
                    }
                }
            }
        }
        jobs
    }

    /// Every pair of the protocol, estimated and scored.
    fn run_pairs(&self, pipelines: &[Pipeline], groups: &[usize], prepared: &PreparedFrames) -> Vec<PairResult> {
        let jobs = self.jobs();
        let bar = progress(jobs.len() as u64, &format!("{}: registration", self.name));
        let rows = jobs
            .par_iter()
            .map(|&(sensor, from, to, step, m)| {
                let mut row = PairResult {
                    object: self.name.to_string(),
                    camera: sensor.to_string(),
                    from,
                    to,
                    step,
                    method: self.protocol.methods[m].clone(),
                    errors: None,
                    converged: None,
                    seconds: None,
                    stage_ms: None,
                    warnings: vec![],
                    failure: None,
                };
                let get = |angle: u32| match prepared.get(&(groups[m], FrameId { sensor, angle })) {
                    Some(Ok(c)) => Ok(c),
                    Some(Err(e)) => Err(format!("frame {sensor}_{angle}: {e}")),
                    None => Err(format!("frame {sensor}_{angle}: not in the dataset")),
                };
                let outcome = (|| -> Result<(), String> {
                    let (model, target) = (get(from)?, get(to)?);
                    let truth =
                        self.object.relative_motion(sensor, from, to).map_err(|e| format!("ground truth: {e}"))?;
                    let t0 = Instant::now();
                    let e = pipelines[m].estimate_prepared(model, target).map_err(|e| e.to_string())?;
                    row.seconds = Some(t0.elapsed().as_secs_f64());
                    row.converged = Some(e.registration.converged);
                    row.errors = Some(PoseErrors::new(&e.pose, &truth, Some(&model.cloud.points)));
                    row.stage_ms = Some(e.stage_ms);
                    row.warnings = e.warnings;
                    Ok(())
                })();
                row.failure = outcome.err();
                bar.inc(1);
                row
            })
            .collect();
        bar.finish();
        rows
    }
}

fn progress(len: u64, msg: &str) -> ProgressBar {
    let bar = ProgressBar::new(len);
    bar.set_style(ProgressStyle::with_template("{msg:40} [{bar:30}] {pos}/{len} {elapsed}").expect("valid template"));
    bar.set_message(msg.to_string());
    bar
}

/// Mean/median of the paper's metric, success rate and failure count per (object, method).
#[derive(Debug, Clone, Serialize)]
struct Summary {
    object: String,
    method: String,
    pairs: usize,
    failed: usize,
    mean_angle_error_deg: Option<f64>,
    median_angle_error_deg: Option<f64>,
    mean_geodesic_error_deg: Option<f64>,
    median_geodesic_error_deg: Option<f64>,
    mean_translation_error_mm: Option<f64>,
    median_translation_error_mm: Option<f64>,
    mean_add_s_mm: Option<f64>,
    median_add_s_mm: Option<f64>,
    success_rate: Option<f64>,
    mean_seconds: Option<f64>,
    /// Mean time per stage over the pairs that ran, ms.
    mean_stage_ms: Option<StageTimes>,
    /// Pairs with a pipeline warning (a fallback taken).
    warned: usize,
}

fn summarise(results: &[PairResult]) -> Vec<Summary> {
    let mut groups: BTreeMap<(String, String), Vec<&PairResult>> = BTreeMap::new();
    for r in results {
        groups.entry((r.object.clone(), r.method.clone())).or_default().push(r);
        groups.entry(("ALL".into(), r.method.clone())).or_default().push(r);
    }
    groups
        .into_iter()
        .map(|((object, method), rows)| {
            let ok: Vec<&PoseErrors> = rows.iter().filter_map(|r| r.errors.as_ref()).collect();
            let col = |f: &dyn Fn(&PoseErrors) -> f64| ok.iter().map(|e| f(e)).collect::<Vec<_>>();
            let angle = mean_median(&col(&|e| e.angle_error_deg));
            let geodesic = mean_median(&col(&|e| e.geodesic_error_deg));
            let translation = mean_median(&col(&|e| e.translation_error_m * 1e3));
            let add_s = mean_median(&ok.iter().filter_map(|e| e.add_s_m.map(|v| v * 1e3)).collect::<Vec<_>>());
            let secs: Vec<f64> = rows.iter().filter_map(|r| r.seconds).collect();
            Summary {
                object,
                method,
                pairs: rows.len(),
                failed: rows.iter().filter(|r| r.failure.is_some()).count(),
                mean_angle_error_deg: angle.map(|a| a.0),
                median_angle_error_deg: angle.map(|a| a.1),
                mean_geodesic_error_deg: geodesic.map(|a| a.0),
                median_geodesic_error_deg: geodesic.map(|a| a.1),
                mean_translation_error_mm: translation.map(|a| a.0),
                median_translation_error_mm: translation.map(|a| a.1),
                mean_add_s_mm: add_s.map(|a| a.0),
                median_add_s_mm: add_s.map(|a| a.1),
                success_rate: (!ok.is_empty())
                    .then(|| ok.iter().filter(|e| e.success).count() as f64 / ok.len() as f64),
                mean_seconds: mean_median(&secs).map(|a| a.0),
                mean_stage_ms: mean_stages(rows.iter().filter_map(|r| r.stage_ms.as_ref())),
                warned: rows.iter().filter(|r| !r.warnings.is_empty()).count(),
            }
        })
        .collect()
}

/// Mean of each stage's time.
fn mean_stages<'a>(times: impl Iterator<Item = &'a StageTimes>) -> Option<StageTimes> {
    let (mut acc, mut n) = (StageTimes::default(), 0usize);
    for t in times {
        acc.depth_model += t.depth_model;
        acc.depth_target += t.depth_target;
        acc.flow += t.flow;
        acc.correspondences += t.correspondences;
        acc.registration += t.registration;
        acc.total += t.total;
        n += 1;
    }
    (n > 0).then(|| {
        let k = 1.0 / n as f64;
        StageTimes {
            depth_model: acc.depth_model * k,
            depth_target: acc.depth_target * k,
            flow: acc.flow * k,
            correspondences: acc.correspondences * k,
            registration: acc.registration * k,
            total: acc.total * k,
        }
    })
}

fn fmt(v: Option<f64>, digits: usize) -> String {
    v.map_or("-".into(), |x| format!("{x:.digits$}"))
}

fn write_outputs(
    args: &BenchArgs,
    protocol: &Protocol,
    results: &[PairResult],
    skipped: &[String],
    seconds: f64,
) -> anyhow::Result<()> {
    let dir = args.out.join(timestamp());
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let summary = summarise(results);
    let json = serde_json::json!({
        "schema": "flowfilter bench-bigbird results v2",
        "dataset": args.data.as_ref().map_or("embedded synthetic (target/bigbird-default)".to_string(), |d| d.display().to_string()),
        "protocol": protocol,
        "seconds": seconds,
        "skipped_objects": skipped,
        "summary": summary,
        "pairs": results,
    });
    std::fs::write(dir.join("results.json"), serde_json::to_string_pretty(&json)? + "\n")?;
    let mut csv = String::from(
        "object,camera,from,to,step,method,angle_error_deg,geodesic_error_deg,translation_error_m,add_s_m,success,converged,seconds,failure\n",
    );
    for r in results {
        let e = r.errors;
        let _ = writeln!(
            csv,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            r.object,
            r.camera,
            r.from,
            r.to,
            r.step,
            r.method,
            fmt(e.map(|e| e.angle_error_deg), 6),
            fmt(e.map(|e| e.geodesic_error_deg), 6),
            fmt(e.map(|e| e.translation_error_m), 6),
            fmt(e.and_then(|e| e.add_s_m), 6),
            e.map_or("-".into(), |e| e.success.to_string()),
            r.converged.map_or("-".into(), |c| c.to_string()),
            fmt(r.seconds, 4),
            r.failure.clone().unwrap_or_default().replace(',', ";")
        );
    }
    std::fs::write(dir.join("pairs.csv"), csv)?;
    let plots = crate::plots::write_all(&dir, results, &summary_for_plots(&summary), &protocol.methods)?;
    // The paper-style table: mean rotation-angle error per object and method.
    let methods = &protocol.methods;
    let objects: BTreeSet<&str> = summary.iter().map(|s| s.object.as_str()).collect();
    let mut table = format!("| object | {} |\n| --- |{}\n", methods.join(" | "), " --- |".repeat(methods.len()));
    for o in &objects {
        let cells: Vec<String> = methods
            .iter()
            .map(|m| {
                summary.iter().find(|s| s.object == *o && &s.method == m).map_or("-".into(), |s| {
                    format!(
                        "{} ({}% ok{})",
                        fmt(s.mean_angle_error_deg, 2),
                        fmt(s.success_rate.map(|r| r * 100.0), 0),
                        if s.failed > 0 { format!(", {} failed", s.failed) } else { String::new() }
                    )
                })
            })
            .collect();
        let _ = writeln!(table, "| {o} | {} |", cells.join(" | "));
    }
    let mut paper = String::from("| paper object | Flow Filter | FilterReg | CPD |\n| --- | --- | --- | --- |\n");
    for (o, v) in PAPER {
        let _ = writeln!(paper, "| {o} | {} | {} | {} |", v[0], v[1], v[2]);
    }
    let failures = results.iter().filter(|r| r.failure.is_some()).count();
    let md = format!(
        "# bench-bigbird results\n\nMean absolute rotation-angle error (degrees; the paper's metric) and success rate (< 2 deg, < 1 cm) per object and method; {} pairs, {} failed, {:.0} s.\n\nProtocol: cameras {:?}, base angles {:?}, steps {:?}, pipeline {}.\n\n{}\n{}\nThe paper's published numbers (real BigBIRD objects, for reference):\n\n{}\n{}",
        results.len(),
        failures,
        seconds,
        protocol.cameras,
        protocol.base_angles,
        protocol.steps,
        protocol.pipeline.as_ref().map_or("defaults".into(), |p| p.display().to_string()),
        table,
        stage_table(&summary, &protocol.methods),
        paper,
        plots.iter().map(|p| format!("![{p}]({p})\n")).collect::<String>()
    );
    std::fs::write(dir.join("summary.md"), &md)?;
    println!(
        "\n{table}\n{}\npaper (real BigBIRD, mean rotation error in degrees):\n{paper}",
        stage_table(&summary, &protocol.methods)
    );
    println!("{} pairs, {} failed; results in {}", results.len(), failures, dir.display());
    for r in results.iter().filter(|r| r.failure.is_some()).take(10) {
        println!(
            "  failed: {} {} {}->{} {}: {}",
            r.object,
            r.camera,
            r.from,
            r.to,
            r.method,
            r.failure.as_deref().unwrap_or("")
        );
    }
    if args.check {
        check(&dir.join("results.json"), protocol)?;
        println!("check: results.json has every method and metric, and no pair failed");
    }
    Ok(())
}

/// Mean time per stage and method over all objects (ms).
fn stage_table(summary: &[Summary], methods: &[String]) -> String {
    let mut t = String::from(
        "| method | depth (per frame) | flow | correspondences | registration | pair total | pairs with a warning |\n| --- | --- | --- | --- | --- | --- | --- |\n",
    );
    for m in methods {
        if let Some(s) = summary.iter().find(|s| s.object == "ALL" && &s.method == m)
            && let Some(st) = s.mean_stage_ms
        {
            let _ = writeln!(
                t,
                "| {m} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {} |",
                0.5 * (st.depth_model + st.depth_target),
                st.flow,
                st.correspondences,
                st.registration,
                st.total,
                s.warned
            );
        }
    }
    t
}

/// What the plots need of the summary.
fn summary_for_plots(summary: &[Summary]) -> Vec<crate::plots::MethodObject> {
    summary
        .iter()
        .map(|s| crate::plots::MethodObject {
            object: s.object.clone(),
            method: s.method.clone(),
            mean_angle_error_deg: s.mean_angle_error_deg,
            stage_ms: s.mean_stage_ms,
        })
        .collect()
}

/// Re-read results.json and verify it (what `--check` and CI rely on).
fn check(path: &Path, protocol: &Protocol) -> anyhow::Result<()> {
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(path)?)?;
    let pairs = v["pairs"].as_array().context("results.json: no 'pairs' array")?;
    if pairs.is_empty() {
        bail!("results.json: no pairs");
    }
    for m in &protocol.methods {
        if !pairs.iter().any(|p| p["method"] == m.as_str()) {
            bail!("results.json: method '{m}' has no pair");
        }
    }
    for p in pairs {
        if !p["failure"].is_null() {
            bail!(
                "results.json: pair {} {} {}->{} {} failed: {}",
                p["object"],
                p["camera"],
                p["from"],
                p["to"],
                p["method"],
                p["failure"]
            );
        }
        if p["stage_ms"]["registration"].as_f64().is_none() || p["stage_ms"]["total"].as_f64().is_none() {
            bail!(
                "results.json: pair {} {} {}->{} {} lacks per-stage times",
                p["object"],
                p["camera"],
                p["from"],
                p["to"],
                p["method"]
            );
        }
        for metric in ["angle_error_deg", "geodesic_error_deg", "translation_error_m", "add_s_m", "success"] {
            if p["errors"][metric].is_null() {
                bail!(
                    "results.json: pair {} {} {}->{} {} lacks '{metric}'",
                    p["object"],
                    p["camera"],
                    p["from"],
                    p["to"],
                    p["method"]
                );
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A real-layout object (the h5py fixture) beside a damaged one: the damaged one is skipped
    /// with its reason, the other runs, and results.json passes the check.
    #[test]
    fn damaged_objects_are_skipped_and_the_run_continues() {
        let tmp = tempfile::tempdir().unwrap();
        let data = tmp.path().join("data");
        std::fs::create_dir_all(data.join("broken_object")).unwrap();
        std::fs::write(data.join("broken_object/calibration.h5"), b"not hdf5").unwrap();
        let fixture = repo_root().join("fixtures/bigbird/latest/tiny_spheres");
        let good = data.join("tiny_spheres");
        std::fs::create_dir_all(&good).unwrap();
        for entry in walk(&fixture) {
            let rel = entry.strip_prefix(&fixture).unwrap();
            std::fs::create_dir_all(good.join(rel).parent().unwrap()).unwrap();
            std::fs::copy(&entry, good.join(rel)).unwrap();
        }
        let protocol = tmp.path().join("protocol.toml");
        std::fs::write(
            &protocol,
            "cameras = [\"NP1\", \"NP5\"]\nbase_angles = [0]\nsteps = [3, 30]\nmethods = [\"icp-pt2pl\", \"filterreg-pt2pt\"]\n\
             pipeline = \"configs/flowfilter.toml\"\n",
        )
        .unwrap();
        let out = tmp.path().join("results");
        let args = BenchArgs {
            quick: false,
            data: Some(data),
            meshes: None,
            protocol: Some(protocol),
            methods: None,
            out: out.clone(),
            voxel: Some(0.002),
            check: true,
        };
        run(&args).unwrap();
        let run_dir = std::fs::read_dir(&out).unwrap().next().unwrap().unwrap().path();
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(run_dir.join("results.json")).unwrap()).unwrap();
        let skipped = v["skipped_objects"].as_array().unwrap();
        assert_eq!(skipped.len(), 1);
        assert!(skipped[0].as_str().unwrap().starts_with("broken_object:"), "{skipped:?}");
        assert_eq!(v["pairs"].as_array().unwrap().len(), 2 * 2 * 2);
        for f in ["pairs.csv", "summary.md", "error_vs_step.svg", "per_object.svg", "stage_times.svg"] {
            assert!(run_dir.join(f).is_file(), "{f} missing");
        }
    }

    fn walk(dir: &Path) -> Vec<PathBuf> {
        let mut out = vec![];
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() { out.extend(walk(&p)) } else { out.push(p) }
        }
        out
    }

    #[test]
    fn protocols_reject_unknown_keys_and_cameras() {
        let e = Protocol::from_toml(
            "cameras = [\"NP1\"]\nbase_angles = [0]\nsteps = [3]\nmethods = [\"cpd\"]\nstep = 3\n",
            "p.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("p.toml") && e.contains("step"), "{e}");
        let e =
            Protocol::from_toml("cameras = [\"NP9\"]\nbase_angles = [0]\nsteps = [3]\nmethods = [\"cpd\"]\n", "p.toml")
                .unwrap_err()
                .to_string();
        assert!(e.contains("NP9"), "{e}");
        for text in [FULL_PROTOCOL, QUICK_PROTOCOL] {
            Protocol::from_toml(text, "shipped").unwrap();
        }
    }
}
