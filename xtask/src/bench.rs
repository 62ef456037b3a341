//! `cargo xtask bench-bigbird`: per object, camera, base angle and rotation step, register the
//! object cloud of the model frame (base angle) to that of the target frame (base + step) with
//! every method, and score the estimate against the turntable ground truth.

use crate::dataset::{embedded_objects, ensure_default_object};
use crate::pairs::{Methods, PairJob, PairResult, RunArgs, progress};
use crate::report::{ReportSpec, ShardRun, write_outputs};
use crate::shard::Shard;
use crate::{dir_name, in_repo};
use anyhow::{Context, bail};
use clap::Args;
use flowfilter_bigbird::{BigBirdObject, FrameId, SensorId};
use flowfilter_pipeline::{PipelineConfig, load_bigbird_frame};
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
    /// Outputs, voxel size, check.
    #[command(flatten)]
    pub run: RunArgs,
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
        let load = |p: &Path| -> anyhow::Result<PipelineConfig> { Ok(PipelineConfig::from_file(&in_repo(p))?) };
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

    pub(crate) fn angles(&self) -> Vec<u32> {
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

/// The paper's reported mean rotation errors (degrees): Flow Filter, FilterReg, CPD.
const PAPER: [(&str, [f64; 3]); 5] = [
    ("Advil box", [2.95, 8.69, 5.8]),
    ("fish can", [11.12, 20.62, 16.43]),
    ("Pepto bottle", [2.19, 7.57, 10.69]),
    ("Quaker granola box", [2.12, 8.69, 5.81]),
    ("chicken noodle box", [1.51, 8.0, 9.33]),
];

/// The protocol files shipped in `configs/bench/` (embedded: they work from any directory).
const FULL_PROTOCOL: &str = include_str!("../../configs/bench/full.toml");
const QUICK_PROTOCOL: &str = include_str!("../../configs/bench/quick.toml");

/// Run the benchmark: the protocol, one pipeline per method, the objects, then per object its
/// frames (prepared once per group of methods) and its pairs.
pub fn run(args: &BenchArgs) -> anyhow::Result<()> {
    let protocol = load_protocol(args)?;
    let cameras = protocol.sensors().map_err(anyhow::Error::msg)?;
    let configs = protocol.method_configs(args.run.voxel)?;
    let mut methods = Methods::new(&protocol.methods, &configs)?;
    methods.record_failures(args.run.rerun.as_deref(), args.run.rerun_limit)?;
    let started = Instant::now();
    let (all_objects, object_dirs) = object_dirs(args, &protocol, &cameras)?;
    let mut results: Vec<PairResult> = Vec::new();
    let mut skipped: Vec<(String, String)> = Vec::new();
    for dir in &object_dirs {
        let name = dir_name(dir);
        let obj = match BigBirdObject::open(dir) {
            Ok(o) => o,
            Err(e) => {
                tracing::warn!(object = %name, error = %e, "skipping object");
                skipped.push((name, e.to_string()));
                continue;
            }
        };
        let bench = ObjectBench { name: &name, object: &obj, protocol: &protocol, cameras: &cameras };
        results.append(&mut bench.run(&methods)?);
    }
    let mut paper = String::from(
        "The paper's published numbers (real BigBIRD objects, for reference):\n\n| paper object | Flow Filter | FilterReg | CPD |\n| --- | --- | --- | --- |\n",
    );
    for (o, v) in PAPER {
        let _ = writeln!(paper, "| {o} | {} | {} | {} |", v[0], v[1], v[2]);
    }
    let spec = ReportSpec {
        bench: "bench-bigbird",
        dataset: args
            .data
            .as_ref()
            .map_or("embedded synthetic (target/bigbird-default)".to_string(), |d| d.display().to_string()),
        protocol: serde_json::to_value(&protocol)?,
        protocol_line: format!(
            "cameras {:?}, base angles {:?}, steps {:?}, pipeline {}",
            protocol.cameras,
            protocol.base_angles,
            protocol.steps,
            protocol.pipeline.as_ref().map_or("defaults".into(), |p| p.display().to_string())
        ),
        step_label: "rotation step (deg)",
        methods: &protocol.methods,
        references: &[],
        appendix: paper,
        out: &args.run.out,
        check: args.run.check,
        shard: args.run.shard.map(|shard| ShardRun { shard, group_field: "object", all_groups: all_objects }),
    };
    methods.finish_recording()?;
    write_outputs(&spec, &results, &skipped, started.elapsed().as_secs_f64())?;
    Ok(())
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

/// Every object of the run (in its order) and the directories of this shard's objects: a real
/// download (`--data`), or the embedded dataset (synthesised once, cached under
/// `target/bigbird-default`; a shard synthesises only its objects).
fn object_dirs(
    args: &BenchArgs,
    protocol: &Protocol,
    cameras: &[SensorId],
) -> anyhow::Result<(Vec<String>, Vec<PathBuf>)> {
    let shard = args.run.shard.unwrap_or(Shard::ALL);
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
        return Ok((dirs.iter().map(|d| dir_name(d)).collect(), shard.select(&dirs)));
    }
    let objects = embedded_objects(args.quick, args.meshes.as_deref());
    let names = objects.iter().map(|o| o.name.clone()).collect();
    let mine = shard.select(&objects);
    let angles = protocol.angles();
    let bar = progress(mine.len() as u64, "synthesising the default dataset (cached)");
    let dirs = mine
        .par_iter()
        .map(|o| {
            let d = ensure_default_object(o, cameras, &angles);
            bar.inc(1);
            d
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    bar.finish();
    Ok((names, dirs))
}

/// One object's part of the benchmark.
struct ObjectBench<'a> {
    name: &'a str,
    object: &'a BigBirdObject,
    protocol: &'a Protocol,
    cameras: &'a [SensorId],
}

impl ObjectBench<'_> {
    /// Every frame the protocol needs that the object has.
    fn frames(&self) -> Vec<FrameId> {
        self.cameras
            .iter()
            .flat_map(|&sensor| self.protocol.angles().into_iter().map(move |angle| FrameId { sensor, angle }))
            .filter(|id| self.object.has_frame(*id))
            .collect()
    }

    /// Every (camera, base angle, step) of the protocol, with its ground truth.
    fn jobs(&self) -> Vec<PairJob<FrameId>> {
        let mut jobs = vec![];
        for &sensor in self.cameras {
            for &from in &self.protocol.base_angles {
                for &step in &self.protocol.steps {
                    let to = (from + step) % 360;
                    jobs.push(PairJob {
                        object: self.name.to_string(),
                        camera: sensor.to_string(),
                        from,
                        to,
                        step,
                        model: FrameId { sensor, angle: from },
                        target: FrameId { sensor, angle: to },
                        truth: self.object.relative_motion(sensor, from, to).map_err(|e| e.to_string()),
                    });
                }
            }
        }
        jobs
    }

    /// The object's frames prepared and its pairs run.
    fn run(&self, methods: &Methods) -> anyhow::Result<Vec<PairResult>> {
        let load = |id: FrameId| load_bigbird_frame(self.object, id).map_err(|e| format!("loading: {e}"));
        let prepared = methods.prepare(&self.frames(), &load, self.name);
        methods.run(&self.jobs(), &prepared, &load, self.name)
    }
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
        let fixture = crate::repo_root().join("fixtures/bigbird/latest/tiny_spheres");
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
            run: RunArgs {
                out: out.clone(),
                voxel: Some(0.002),
                check: true,
                shard: None,
                rerun: None,
                rerun_limit: 20,
            },
        };
        run(&args).unwrap();
        let run_dir = std::fs::read_dir(&out).unwrap().next().unwrap().unwrap().path();
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(run_dir.join("results.json")).unwrap()).unwrap();
        let skipped = v["skipped"].as_array().unwrap();
        assert_eq!(skipped.len(), 1);
        assert!(skipped[0].as_str().unwrap().starts_with("broken_object:"), "{skipped:?}");
        // Two cameras, two steps, two methods and the "no motion" row.
        assert_eq!(v["pairs"].as_array().unwrap().len(), 2 * 2 * 3);
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
