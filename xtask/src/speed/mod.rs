//! `cargo xtask bench-speed`: ours and the peers (probreg, Open3D, OpenCV through
//! `tools/peers/speed_peers.py`) on the same inputs in the same minutes, with each thread count
//! in turn, and the pipeline's pairs per second for each method.
//!
//! Sections: registration on Kinect-sized cloud pairs (FilterReg both variants against
//! probreg, ICP both variants against Open3D with its parameters, our CPD on every point
//! against probreg's CPD on 2k-point subsets); DIS-medium against OpenCV's on the Sintel pairs
//! (when `../shared/data/sintel` exists); the pipeline (two frames in, pose out) on the default
//! benchmark's frames; the pipeline on consecutive frames of streams (3 degrees apart, each frame
//! prepared once). Writes `speed.json` and `speed.md` into a timestamped directory.

mod clouds;
mod ours;
mod peers;
mod pipeline;
mod report;
mod stream;

use crate::bench::Protocol;
use crate::pairs::progress;
use anyhow::Context;
use clap::Args;
use report::{PipelineRow, Row, SpeedReport};
use std::path::{Path, PathBuf};

/// Arguments of `bench-speed`.
#[derive(Args, Debug, Clone)]
pub struct SpeedArgs {
    /// CI-sized: 5k-point clouds, one run each, one Sintel pair, the quick protocol's procedural
    /// pairs from its first base angle.
    #[arg(long)]
    pub quick: bool,
    /// Source points of the synthetic registration pairs (the target has 11/12 of them)
    /// [default: 20000,40000,60000, or 5000 with --quick; none when --real is given].
    #[arg(long, value_delimiter = ',')]
    pub sizes: Option<Vec<usize>>,
    /// Real RGB-D sequences (folders of frames with `poses.json` and `camera.json`, as
    /// `bench-real` reads them), comma separated: each one's first two frames join the
    /// registration pairs as real clouds (the depth stage's whole-frame clouds with their normals,
    /// thinned to a 4 mm voxel, the source moved by the calibrated motion). Their truth is a
    /// calibration's: ours and the peer are compared with each other.
    #[arg(long, value_delimiter = ',')]
    pub real: Vec<PathBuf>,
    /// Thread counts, each run in turn (ours in a rayon pool of that size; the peers with
    /// OMP_NUM_THREADS, OPENBLAS_NUM_THREADS, MKL_NUM_THREADS and OpenCV's setNumThreads).
    #[arg(long, value_delimiter = ',', default_value = "1,2")]
    pub threads: Vec<usize>,
    /// Runs of each registration and flow timing; the fastest is kept (both sides).
    #[arg(long)]
    pub repeat: Option<usize>,
    /// After those runs, repeat a timing (both sides) while its runs took less than this many
    /// seconds in all, up to 50 runs: short runs' minima then settle [default: 1, 0 with --quick].
    #[arg(long)]
    pub min_seconds: Option<f64>,
    /// Pipeline methods timed on the default benchmark's frames (and on the streams).
    #[arg(long, value_delimiter = ',', default_value = "flowfilter,filterreg-pt2pt,icp-pt2pl,cpd")]
    pub methods: Vec<String>,
    /// The pipeline configuration of the pipeline section (TOML, as `flowfilter estimate
    /// --config` reads it; a relative path is taken from the repository root, as `bench-bop`'s;
    /// each of `--methods` replaces its `method`) [default: the protocol's,
    /// configs/flowfilter.toml].
    #[arg(long)]
    pub pipeline: Option<PathBuf>,
    /// The Python with the peers installed (`pip install -r tools/peers/requirements.txt`).
    #[arg(long, default_value = "python3")]
    pub python: String,
    /// Time ours only.
    #[arg(long)]
    pub no_peers: bool,
    /// Sections to run: registration, flow, pipeline, stream.
    #[arg(long, value_delimiter = ',', default_value = "registration,flow,pipeline,stream")]
    pub sections: Vec<String>,
    /// Output root (a timestamped directory is created inside).
    #[arg(long, default_value = "results")]
    pub out: PathBuf,
    /// Exit non-zero unless every timing of ours is present, finite and positive, and every
    /// registration ends within 1 degree of the truth.
    #[arg(long)]
    pub check: bool,
}

const SECTIONS: [&str; 4] = ["registration", "flow", "pipeline", "stream"];

/// Run the benchmark.
pub fn run(args: &SpeedArgs) -> anyhow::Result<()> {
    validate(args)?;
    let dir = args.out.join(crate::report::timestamp());
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let repeat = args.repeat.unwrap_or(if args.quick { 1 } else { 3 });
    let repeats =
        ours::Repeats { min: repeat, budget_s: args.min_seconds.unwrap_or(if args.quick { 0.0 } else { 1.0 }) };
    let sizes = args.sizes.clone().unwrap_or_else(|| match (args.quick, args.real.is_empty()) {
        (_, false) => vec![],
        (true, true) => vec![5000],
        (false, true) => vec![20_000, 40_000, 60_000],
    });
    let wants = |s: &str| args.sections.iter().any(|x| x == s);
    let pairs: Vec<clouds::CloudPair> = if wants("registration") {
        let synthetic = sizes.iter().map(|&n| clouds::write_pair(&dir.join("clouds"), n, n as u64));
        let real = args
            .real
            .iter()
            .map(|seq| clouds::write_real_pair(&dir.join("clouds"), seq).map_err(|e| anyhow::anyhow!("--real: {e:#}")));
        synthetic.chain(real).collect::<anyhow::Result<_>>()?
    } else {
        vec![]
    };
    let sintel = if wants("flow") { sintel_cases(args.quick) } else { vec![] };
    let manifest = peers::write_manifest(&dir, &pairs, &sintel, repeats)?;
    let mut report = SpeedReport::new(args, &sizes, repeats);
    if wants("flow") && sintel.is_empty() {
        report.notes.push("flow: skipped, ../shared/data/sintel is absent".into());
    }
    for &threads in &args.threads {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build()?;
        let peer_rows = peer_rows(args, &manifest, threads, &mut report);
        let bar = progress((pairs.len() + sintel.len()) as u64, &format!("bench-speed: ours, {threads} thread(s)"));
        let config = ours::registration_config()?;
        for pair in &pairs {
            for (method, t) in ours::registration(pair, &config, &pool, repeats)? {
                let peer = peer_rows.iter().find(|r| r.pair.as_deref() == Some(&pair.name) && r.method == method);
                report.rows.push(Row::registration(pair, &method, threads, t, peer));
            }
            bar.inc(1);
        }
        for (case, _) in &sintel {
            let t = ours::flow(&sintel_root(), case, &pool, repeats)?;
            let peer = peer_rows.iter().find(|r| r.case.as_deref() == Some(case));
            report.rows.push(Row::flow(case, threads, t, peer));
            bar.inc(1);
        }
        bar.finish();
    }
    if wants("pipeline") {
        (report.pipeline_pairs, report.pipeline) = pipeline_rows(args)?;
    }
    if wants("stream") {
        (report.stream_frames, report.stream) = stream_rows(args)?;
    }
    report.write(&dir)?;
    println!("{}", report.markdown());
    eprintln!("bench-speed: wrote {}", dir.display());
    if args.check {
        report.check()?;
    }
    Ok(())
}

/// Options that cannot work are refused before anything runs.
fn validate(args: &SpeedArgs) -> anyhow::Result<()> {
    if let Some(s) = args.sections.iter().find(|s| !SECTIONS.contains(&s.as_str())) {
        anyhow::bail!("--sections: unknown section '{s}' (expected some of {})", SECTIONS.join(", "));
    }
    if args.threads.is_empty() || args.threads.contains(&0) {
        anyhow::bail!("--threads: thread counts of at least 1 expected, found {:?}", args.threads);
    }
    if let Some(dir) = args.real.iter().find(|d| !crate::realsense::is_posed_folder(d)) {
        anyhow::bail!("--real: {} is not a posed sequence (camera.json and poses.json expected)", dir.display());
    }
    if let Some(n) = args.sizes.iter().flatten().find(|&&n| n < 100) {
        anyhow::bail!("--sizes: at least 100 points per cloud expected, found {n}");
    }
    if args.repeat == Some(0) {
        anyhow::bail!("--repeat: at least 1 run expected, found 0");
    }
    if let Some(s) = args.min_seconds.filter(|s| !(s.is_finite() && *s >= 0.0)) {
        anyhow::bail!("--min-seconds: a finite number of seconds, 0 or more, expected, found {s}");
    }
    for m in &args.methods {
        flowfilter_pipeline::registration::registrar_by_name(m, &Default::default())
            .map_err(|e| anyhow::anyhow!("--methods: {e}"))?;
    }
    if let Some(p) = &args.pipeline {
        flowfilter_pipeline::PipelineConfig::from_file(&crate::in_repo(p))
            .map_err(|e| anyhow::anyhow!("--pipeline: {e}"))?;
    }
    Ok(())
}

/// The peers with `threads` threads, or a note saying why they did not run.
fn peer_rows(args: &SpeedArgs, manifest: &Path, threads: usize, report: &mut SpeedReport) -> Vec<peers::PeerRow> {
    if args.no_peers {
        return vec![];
    }
    eprintln!("bench-speed: peers, {threads} thread(s) ({})", args.python);
    match peers::run(&args.python, manifest, threads) {
        Ok(rows) => rows,
        Err(why) => {
            tracing::warn!(%why, "peers skipped");
            report.notes.push(format!("peers with {threads} thread(s): skipped, {why}"));
            vec![]
        }
    }
}

fn sintel_root() -> PathBuf {
    Path::new("../shared/data/sintel").to_path_buf()
}

/// The Sintel cases present (one with `quick`).
fn sintel_cases(quick: bool) -> Vec<(String, PathBuf)> {
    let root = sintel_root();
    let take = if quick { 1 } else { ours::SINTEL_CASES.len() };
    ours::SINTEL_CASES
        .iter()
        .take(take)
        .map(|c| (c.to_string(), root.join(c)))
        .filter(|(_, d)| d.join("frame_0002.png").is_file())
        .collect()
}

/// Every pipeline method with every thread count on the default benchmark's pairs of one camera.
fn pipeline_rows(args: &SpeedArgs) -> anyhow::Result<(String, Vec<PipelineRow>)> {
    let (text, origin) = if args.quick {
        (include_str!("../../../configs/bench/quick.toml"), "configs/bench/quick.toml")
    } else {
        (include_str!("../../../configs/bench/full.toml"), "configs/bench/full.toml")
    };
    let mut protocol = Protocol::from_toml(text, origin)?;
    // CI-sized: the quick protocol's frames (one cache with bench-bigbird --quick), its first
    // base angle only.
    let angles = protocol.angles();
    if args.quick {
        protocol.base_angles.truncate(1);
    }
    let (base, origin) = base_config(args, protocol.pipeline.as_ref())?;
    let pairs = pipeline::load(&protocol, &angles, args.quick)?;
    let rows = each_method(args, &base, "bench-speed: pipeline", pairs.pairs.len(), |config, pool| {
        pipeline::throughput(&pairs, config, pool).map(|t| (t, vec![]))
    })?;
    Ok((format!("{}; pipeline configuration: {origin}", pairs.description), rows))
}

/// Every pipeline method with every thread count on the streams of consecutive frames.
fn stream_rows(args: &SpeedArgs) -> anyhow::Result<(String, Vec<PipelineRow>)> {
    let default = Path::new("configs/flowfilter.toml").to_path_buf();
    let (base, origin) = base_config(args, Some(&default))?;
    let streams = stream::load(args.quick)?;
    let rows = each_method(args, &base, "bench-speed: streams", streams.pairs(), |config, pool| {
        stream::throughput(&streams, config, pool)
    })?;
    Ok((format!("{}; pipeline configuration: {origin}", streams.description), rows))
}

/// The pipeline configuration: `--pipeline`, else `fallback` (a path from the repository root),
/// else the defaults; and where it came from.
fn base_config(
    args: &SpeedArgs,
    fallback: Option<&PathBuf>,
) -> anyhow::Result<(flowfilter_pipeline::PipelineConfig, String)> {
    Ok(match args.pipeline.as_ref().or(fallback) {
        Some(p) => (flowfilter_pipeline::PipelineConfig::from_file(&crate::in_repo(p))?, p.display().to_string()),
        None => (Default::default(), "the defaults".to_string()),
    })
}

/// `measure` with each of `--methods` (`base` with its method) under each of `--threads`.
fn each_method(
    args: &SpeedArgs,
    base: &flowfilter_pipeline::PipelineConfig,
    label: &str,
    pairs: usize,
    measure: impl Fn(
        &flowfilter_pipeline::PipelineConfig,
        &rayon::ThreadPool,
    ) -> anyhow::Result<(pipeline::Throughput, Vec<stream::StreamRate>)>,
) -> anyhow::Result<Vec<PipelineRow>> {
    let mut rows = vec![];
    let bar = progress((args.methods.len() * args.threads.len()) as u64, label);
    for method in &args.methods {
        let config = flowfilter_pipeline::PipelineConfig { method: method.clone(), ..base.clone() };
        for &threads in &args.threads {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build()?;
            let (throughput, streams) = measure(&config, &pool)?;
            rows.push(PipelineRow { method: method.clone(), threads, pairs, throughput, streams });
            bar.inc(1);
        }
    }
    bar.finish();
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(out: &Path) -> SpeedArgs {
        SpeedArgs {
            quick: true,
            sizes: Some(vec![1500]),
            real: vec![],
            threads: vec![1, 2],
            repeat: Some(1),
            min_seconds: None,
            methods: vec!["flowfilter".into()],
            pipeline: None,
            python: "python3".into(),
            no_peers: false,
            sections: vec!["registration".into()],
            out: out.to_path_buf(),
            check: true,
        }
    }

    /// Run `a` into its empty `--out`: the run's directory and its `speed.json`.
    fn run_and_read(a: &SpeedArgs) -> (PathBuf, serde_json::Value) {
        run(a).unwrap();
        let dir = std::fs::read_dir(&a.out).unwrap().next().unwrap().unwrap().path();
        let v = serde_json::from_str(&std::fs::read_to_string(dir.join("speed.json")).unwrap()).unwrap();
        (dir, v)
    }

    /// Every method with every thread count is timed and checked; an interpreter that does not
    /// exist is reported as skipped peers, not a failure.
    #[test]
    fn registration_rows_for_every_method_and_thread_count() {
        let tmp = tempfile::tempdir().unwrap();
        let a = SpeedArgs { python: "/nonexistent/python3".into(), ..args(tmp.path()) };
        let (dir, v) = run_and_read(&a);
        let rows = v["rows"].as_array().unwrap();
        assert_eq!(rows.len(), ours::REGISTRATION_METHODS.len() * 2);
        for r in rows {
            assert!(r["ours_s"].as_f64().unwrap() > 0.0 && r.get("speedup").is_none(), "{r}");
        }
        let notes = v["notes"].as_array().unwrap();
        assert_eq!(notes.len(), 2, "{notes:?}");
        assert!(notes[0].as_str().unwrap().contains("could not be started"), "{notes:?}");
        assert!(std::fs::read_to_string(dir.join("speed.md")).unwrap().contains("| wavy-1500 | cpd | 2 |"));
    }

    /// A real sequence's first two frames become a cloud pair: the target with normals, the
    /// source moved by the calibrated motion onto it (most points within 1 cm of the target), and
    /// rows that the truth check does not hold to the calibration.
    #[test]
    fn a_real_sequence_gives_a_real_cloud_pair() {
        let Some(seq) = crate::shared_or_skip("data/realsense-shelf/shelf-D") else { return };
        let tmp = tempfile::tempdir().unwrap();
        let pair = clouds::write_real_pair(tmp.path(), &seq).unwrap();
        assert_eq!(pair.name, "real-shelf-D-0-1");
        assert!(!pair.exact_truth);
        let read = |p: &Path| flowfilter_pipeline::depth::ply::read_ply(p).unwrap();
        let (source, target) = (read(&pair.source), read(&pair.target));
        assert!(target.normals.is_some());
        assert!((10_000..80_000).contains(&source.len()), "{} source points", source.len());
        let index = flowfilter_pipeline::geometry::KnnIndex::new(&target.points);
        let near = source.points.iter().filter(|p| index.nearest(p).is_some_and(|n| n.dist2 < 1e-4)).count();
        assert!(near * 10 > source.len() * 6, "{near} of {} source points within 1 cm", source.len());
        // Only the real pair with --real and no --sizes; one thread, ours only.
        let a = SpeedArgs { sizes: None, real: vec![seq], threads: vec![1], no_peers: true, ..args(tmp.path()) };
        run(&a).unwrap();
        let dir = std::fs::read_dir(tmp.path()).unwrap().flatten().find(|e| e.path().join("speed.json").is_file());
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.unwrap().path().join("speed.json")).unwrap()).unwrap();
        let rows = v["rows"].as_array().unwrap();
        assert_eq!(rows.len(), ours::REGISTRATION_METHODS.len());
        assert!(rows.iter().all(|r| r["case"] == "real-shelf-D-0-1" && r["exact_truth"] == false), "{rows:?}");
    }

    #[test]
    fn options_that_cannot_work_are_refused() {
        let tmp = tempfile::tempdir().unwrap();
        for (a, want) in [
            (SpeedArgs { sections: vec!["gpu".into()], ..args(tmp.path()) }, "unknown section 'gpu'"),
            (SpeedArgs { threads: vec![0], ..args(tmp.path()) }, "--threads"),
            (SpeedArgs { sizes: Some(vec![10]), ..args(tmp.path()) }, "--sizes"),
            (SpeedArgs { real: vec![tmp.path().to_path_buf()], ..args(tmp.path()) }, "--real"),
            (SpeedArgs { repeat: Some(0), ..args(tmp.path()) }, "--repeat"),
            (SpeedArgs { min_seconds: Some(-1.0), ..args(tmp.path()) }, "--min-seconds"),
            (SpeedArgs { min_seconds: Some(f64::NAN), ..args(tmp.path()) }, "--min-seconds"),
            (SpeedArgs { methods: vec!["gicp".into()], ..args(tmp.path()) }, "--methods"),
            (SpeedArgs { pipeline: Some(tmp.path().join("absent.toml")), ..args(tmp.path()) }, "absent.toml"),
        ] {
            let e = run(&a).unwrap_err().to_string();
            assert!(e.contains(want), "{e}");
        }
        assert!(std::fs::read_dir(tmp.path()).unwrap().next().is_none(), "nothing written");
    }

    /// At least the asked runs; more only while under the budget, never past the cap.
    #[test]
    fn repeats_follow_the_minimum_the_budget_and_the_cap() {
        let exact = ours::Repeats { min: 3, budget_s: 0.0 };
        assert!(exact.again(2, 100.0) && !exact.again(3, 0.0));
        assert!(ours::Repeats { min: 0, budget_s: 0.0 }.again(0, 0.0), "one run at least");
        let budget = ours::Repeats { min: 3, budget_s: 1.0 };
        assert!(budget.again(3, 0.5) && !budget.again(3, 1.0) && !budget.again(3, 2.0));
        assert!(budget.again(ours::Repeats::MAX_RUNS - 1, 0.9) && !budget.again(ours::Repeats::MAX_RUNS, 0.0));
        // Runs are counted by `fastest` itself: a 1 ms run under a 20 ms budget runs about 20 times.
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let mut calls = 0;
        let (secs, ()) = ours::fastest(&pool, ours::Repeats { min: 2, budget_s: 0.02 }, || {
            calls += 1;
            std::thread::sleep(std::time::Duration::from_millis(1));
            Ok(())
        })
        .unwrap();
        assert!((2..=20).contains(&calls), "{calls}");
        assert!(secs >= 0.001, "{secs}");
        let mut calls = 0;
        ours::fastest(&pool, exact, || {
            calls += 1;
            Ok(())
        })
        .unwrap();
        assert_eq!(calls, 3);
    }

    /// The stream section: every quick stream's consecutive pairs, near the truth, the same
    /// poses with one thread and two.
    #[test]
    fn the_stream_section_chains_consecutive_frames_with_any_thread_count() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("out");
        let a = SpeedArgs { sections: vec!["stream".into()], no_peers: true, ..args(&out) };
        let (dir, v) = run_and_read(&a);
        let rows = v["stream"].as_array().unwrap();
        assert_eq!(rows.len(), 2, "one row per thread count: {rows:?}");
        for r in rows {
            // Box, can and bottle: 4 frames each, 3 pairs 3 degrees apart.
            assert_eq!(r["pairs"], 9, "{r}");
            assert!(r["pairs_per_second"].as_f64().unwrap() > 0.0, "{r}");
            assert!(r["mean_rotation_deg"].as_f64().unwrap() < 0.5, "{r}");
            assert!(r["stage_ms"][0].as_f64().unwrap() > 0.0, "each frame's preparation timed: {r}");
            let objects: Vec<&str> =
                r["streams"].as_array().unwrap().iter().map(|s| s["object"].as_str().unwrap()).collect();
            assert_eq!(objects, ["procedural_box", "procedural_can", "procedural_bottle"], "{r}");
        }
        // The same poses whatever the pool's size.
        assert_eq!(rows[0]["mean_rotation_deg"], rows[1]["mean_rotation_deg"], "{rows:?}");
        let md = std::fs::read_to_string(dir.join("speed.md")).unwrap();
        assert!(md.contains("## stream (consecutive frames, each prepared once)"), "{md}");
        assert!(md.contains("3 deg between frames") && md.contains("| slowest stream (pairs/s) |"), "{md}");
    }

    /// `--pipeline` replaces the protocol's configuration: with the judge and the alignment
    /// off, neither stage takes any time, and the report names the file.
    #[test]
    fn the_pipeline_section_runs_the_given_configuration() {
        let tmp = tempfile::tempdir().unwrap();
        let config = tmp.path().join("no-judge-no-align.toml");
        std::fs::write(&config, "[judge]\nenabled = false\n[align]\nenabled = false\n").unwrap();
        let out = tmp.path().join("out");
        let a = SpeedArgs {
            sections: vec!["pipeline".into()],
            threads: vec![1],
            no_peers: true,
            pipeline: Some(config.clone()),
            ..args(&out)
        };
        let (_, v) = run_and_read(&a);
        let rows = v["pipeline"].as_array().unwrap();
        assert_eq!(rows.len(), 1, "{rows:?}");
        let stage_ms = rows[0]["stage_ms"].as_array().unwrap();
        let ms: Vec<f64> = stage_ms.iter().map(|x| x.as_f64().unwrap()).collect();
        assert!(ms[1] > 0.0 && ms[3] > 0.0, "flow and registration ran: {ms:?}");
        // Off, the judge and the alignment only read a clock (microseconds).
        assert!(ms[4] + ms[5] < 0.01 * ms[3], "judge and alignment off: {ms:?}");
        assert!(v["pipeline_pairs"].as_str().unwrap().contains("no-judge-no-align.toml"), "{v}");
    }

    /// A check fails on a registration that ends far from the truth, unless that truth is a
    /// calibration's (a real pair).
    #[test]
    fn the_check_refuses_a_wrong_pose() {
        let mut report = SpeedReport::new(&args(Path::new("x")), &[1500], ours::Repeats { min: 1, budget_s: 0.0 });
        let t = ours::Timed { seconds: 0.1, error: 0.01, translation_m: Some(0.0), iterations: Some(3), pose: None };
        let pair = |name: &str, exact_truth| clouds::CloudPair {
            name: name.into(),
            source: PathBuf::new(),
            target: PathBuf::new(),
            truth: flowfilter_pipeline::Pose::identity(),
            exact_truth,
        };
        report.rows.push(Row::registration(&pair("wavy-1500", true), "icp-pt2pl", 1, t.clone(), None));
        report.check().unwrap();
        report.rows.push(Row::registration(
            &pair("real-x-0-1", false),
            "cpd",
            1,
            ours::Timed { error: 3.0, ..t.clone() },
            None,
        ));
        report.check().unwrap();
        report.rows.push(Row::registration(&pair("wavy-1500", true), "cpd", 1, ours::Timed { error: 3.0, ..t }, None));
        assert!(report.check().unwrap_err().to_string().contains("3.000 deg"));
    }
}
