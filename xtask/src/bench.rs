//! `cargo xtask bench-bigbird`: per object, camera, base angle and rotation step, register the
//! object cloud of the model frame (base angle) to that of the target frame (base + step) with
//! every method, and score the estimate against the turntable ground truth.

use crate::dataset::{default_objects, ensure_object};
use anyhow::{Context, bail};
use clap::Args;
use flowfilter_bigbird::{BigBirdObject, FrameId, SensorId};
use flowfilter_depth::cloud::voxel_downsample;
use flowfilter_depth::{DepthConfig, DepthStage};
use flowfilter_eval::{PoseErrors, mean_median};
use flowfilter_flow::correspondences::{CorrespondenceParams, flow_correspondences};
use flowfilter_flow::lk::{Gray, to_gray};
use flowfilter_geometry::{DepthMap, Mask, PointCloud};
use flowfilter_registration::{
    Correspondences, FLOW_METHOD_NAMES, RegistrationConfig, RegistrationProblem, registrar_by_name,
};
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use serde::Serialize;
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
    /// Methods, comma separated.
    #[arg(long, value_delimiter = ',', default_value = "icp-pt2pl,cpd,filterreg-pt2pt,flowfilter")]
    pub methods: Vec<String>,
    /// Output root (a timestamped directory is created inside).
    #[arg(long, default_value = "results")]
    pub out: PathBuf,
    /// Voxel size of the clouds given to the registration, metres.
    #[arg(long, default_value_t = 0.004)]
    pub voxel: f64,
    /// Exit non-zero unless results.json holds every method with every metric and no pair
    /// failed (what CI checks).
    #[arg(long)]
    pub check: bool,
}

/// The experiment's protocol.
#[derive(Debug, Clone, Serialize)]
pub struct Protocol {
    /// Cameras.
    pub cameras: Vec<SensorId>,
    /// Model-frame angles.
    pub base_angles: Vec<u32>,
    /// Rotation steps (degrees).
    pub steps: Vec<u32>,
    /// Methods.
    pub methods: Vec<String>,
    /// Voxel size, metres.
    pub voxel_m: f64,
}

impl Protocol {
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
    /// Registration time, seconds.
    pub seconds: Option<f64>,
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

/// Run the benchmark.
pub fn run(args: &BenchArgs) -> anyhow::Result<()> {
    let all: Vec<SensorId> = SensorId::ALL.to_vec();
    let np = |c: u8| SensorId::new(c).expect("valid sensor");
    let protocol = if args.quick {
        Protocol {
            cameras: vec![np(3)],
            base_angles: vec![0, 120, 240],
            steps: vec![3, 15, 30],
            methods: args.methods.clone(),
            voxel_m: args.voxel,
        }
    } else {
        Protocol {
            cameras: vec![np(1), np(3), np(5)],
            base_angles: vec![0, 180],
            steps: vec![3, 9, 15, 21, 30],
            methods: args.methods.clone(),
            voxel_m: args.voxel,
        }
    };
    let reg_config = RegistrationConfig::default();
    for m in &protocol.methods {
        registrar_by_name(m, &reg_config).with_context(|| format!("--methods: '{m}'"))?;
    }
    let started = Instant::now();
    // The objects: a real download, or the embedded dataset (synthesised once, cached).
    let object_dirs: Vec<PathBuf> = match &args.data {
        Some(root) => {
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
            dirs
        }
        None => {
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
                    let d = ensure_object(
                        &root,
                        o,
                        &all.iter().copied().filter(|s| protocol.cameras.contains(s)).collect::<Vec<_>>(),
                        &angles,
                        7,
                    );
                    bar.inc(1);
                    d
                })
                .collect::<anyhow::Result<Vec<_>>>()?;
            bar.finish();
            dirs
        }
    };
    let depth = DepthStage::new(DepthConfig::default())?;
    let mut results: Vec<PairResult> = Vec::new();
    let mut skipped: Vec<String> = Vec::new();
    for dir in &object_dirs {
        let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let obj = match BigBirdObject::open(dir) {
            Ok(o) => o,
            Err(e) => {
                eprintln!("skipping object {name}: {e}");
                skipped.push(format!("{name}: {e}"));
                continue;
            }
        };
        // Clouds of every frame the protocol needs.
        let frames: Vec<FrameId> = protocol
            .cameras
            .iter()
            .flat_map(|&sensor| protocol.angles().into_iter().map(move |angle| FrameId { sensor, angle }))
            .filter(|id| obj.has_frame(*id))
            .collect();
        let bar = progress(frames.len() as u64, &format!("{name}: depth stage"));
        let wants_flow = protocol.methods.iter().any(|m| FLOW_METHOD_NAMES.contains(&m.as_str()));
        let clouds: BTreeMap<FrameId, Result<FrameData, String>> = frames
            .par_iter()
            .map(|&id| {
                let data = obj.load_frame(id).map_err(|e| format!("loading: {e}")).and_then(|f| {
                    let sensor = obj.rgbd_sensor(&f).map_err(|e| format!("calibration: {e}"))?;
                    let p =
                        depth.process(&f.depth, &f.color, &f.mask, &sensor).map_err(|e| format!("depth stage: {e}"))?;
                    let mut cloud = voxel_downsample(&p.cloud, protocol.voxel_m);
                    cloud.colors = None;
                    let flow_inputs = wants_flow.then(|| (to_gray(&f.color), p.depth, f.mask, sensor));
                    Ok(FrameData { cloud, flow_inputs })
                });
                bar.inc(1);
                (id, data)
            })
            .collect();
        bar.finish();
        let mut jobs = vec![];
        for &sensor in &protocol.cameras {
            for &base in &protocol.base_angles {
                for &step in &protocol.steps {
                    for method in &protocol.methods {
                        jobs.push((sensor, base, (base + step) % 360, step, method.clone()));
                    }
                }
            }
        }
        let bar = progress(jobs.len() as u64, &format!("{name}: registration"));
        let mut rows: Vec<PairResult> = jobs
            .par_iter()
            .map(|(sensor, from, to, step, method)| {
                let mut row = PairResult {
                    object: name.clone(),
                    camera: sensor.to_string(),
                    from: *from,
                    to: *to,
                    step: *step,
                    method: method.clone(),
                    errors: None,
                    converged: None,
                    seconds: None,
                    failure: None,
                };
                let get = |angle: u32| match clouds.get(&FrameId { sensor: *sensor, angle }) {
                    Some(Ok(c)) => Ok(c),
                    Some(Err(e)) => Err(format!("frame {sensor}_{angle}: {e}")),
                    None => Err(format!("frame {sensor}_{angle}: not in the dataset")),
                };
                let outcome = (|| -> Result<(), String> {
                    let (model, target) = (get(*from)?, get(*to)?);
                    let truth = obj.relative_motion(*sensor, *from, *to).map_err(|e| format!("ground truth: {e}"))?;
                    let reg = registrar_by_name(method, &reg_config).map_err(|e| e.to_string())?;
                    let t0 = Instant::now();
                    let mut problem = RegistrationProblem::new(model.cloud.clone(), target.cloud.clone());
                    if FLOW_METHOD_NAMES.contains(&method.as_str()) {
                        let (Some((ga, da, ma, sa)), Some((gb, db, mb, _))) = (&model.flow_inputs, &target.flow_inputs)
                        else {
                            return Err("flow: frame data missing".into());
                        };
                        let rays = depth.rays(&sa.color);
                        let pairs =
                            flow_correspondences(ga, gb, da, db, ma, mb, &rays, &CorrespondenceParams::default());
                        let c = Correspondences { source: pairs.model, target: pairs.target, weights: pairs.weights };
                        problem.correspondences = Some(c);
                    }
                    let source = &model.cloud;
                    let r = reg.register(&problem).map_err(|e| format!("registration: {e}"))?;
                    row.seconds = Some(t0.elapsed().as_secs_f64());
                    row.converged = Some(r.converged);
                    row.errors = Some(PoseErrors::new(&r.transform, &truth, Some(&source.points)));
                    Ok(())
                })();
                row.failure = outcome.err();
                bar.inc(1);
                row
            })
            .collect();
        bar.finish();
        results.append(&mut rows);
    }
    write_outputs(args, &protocol, &results, &skipped, started.elapsed().as_secs_f64())
}

/// What a frame contributes: its downsampled object cloud and, for flow methods, the grey
/// image, colour-grid depth, mask and sensor.
struct FrameData {
    cloud: PointCloud,
    flow_inputs: Option<(Gray, DepthMap, Mask, flowfilter_camera::RgbdSensor)>,
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
    mean_translation_error_mm: Option<f64>,
    mean_add_s_mm: Option<f64>,
    success_rate: Option<f64>,
    mean_seconds: Option<f64>,
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
            let secs: Vec<f64> = rows.iter().filter_map(|r| r.seconds).collect();
            Summary {
                object,
                method,
                pairs: rows.len(),
                failed: rows.iter().filter(|r| r.failure.is_some()).count(),
                mean_angle_error_deg: angle.map(|a| a.0),
                median_angle_error_deg: angle.map(|a| a.1),
                mean_geodesic_error_deg: mean_median(&col(&|e| e.geodesic_error_deg)).map(|a| a.0),
                mean_translation_error_mm: mean_median(&col(&|e| e.translation_error_m * 1e3)).map(|a| a.0),
                mean_add_s_mm: mean_median(&ok.iter().filter_map(|e| e.add_s_m.map(|v| v * 1e3)).collect::<Vec<_>>())
                    .map(|a| a.0),
                success_rate: (!ok.is_empty())
                    .then(|| ok.iter().filter(|e| e.success).count() as f64 / ok.len() as f64),
                mean_seconds: mean_median(&secs).map(|a| a.0),
            }
        })
        .collect()
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
        "schema": "flowfilter bench-bigbird results v1",
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
        "# bench-bigbird results\n\nMean absolute rotation-angle error (degrees; the paper's metric) and success rate (< 2 deg, < 1 cm) per object and method; {} pairs, {} failed, {:.0} s.\n\nProtocol: cameras {:?}, base angles {:?}, steps {:?}, voxel {} m.\n\n{}\nThe paper's published numbers (real BigBIRD objects, for reference):\n\n{}",
        results.len(),
        failures,
        seconds,
        protocol.cameras.iter().map(ToString::to_string).collect::<Vec<_>>(),
        protocol.base_angles,
        protocol.steps,
        protocol.voxel_m,
        table,
        paper
    );
    std::fs::write(dir.join("summary.md"), &md)?;
    println!("\n{table}\npaper (real BigBIRD, mean rotation error in degrees):\n{paper}");
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
