//! What both benchmarks write: `results.json`, `pairs.csv`, `summary.md` (per-object and
//! per-step tables, the "no motion" row among the methods, per-stage times) and the SVG plots,
//! plus the check CI relies on.

use crate::pairs::{NO_MOTION, PairResult};
use anyhow::{Context, bail};
use flowfilter_eval::{PoseErrors, mean_median};
use flowfilter_pipeline::StageTimes;
use serde::Serialize;
use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Mean/median of each metric, success rate and failure count of a group of rows: one object
/// (or `ALL`) over every step, or every object at one step.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    /// Object, or `ALL`.
    pub object: String,
    /// The step of a per-step group (absent otherwise).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub step: Option<u32>,
    /// The true-rotation range of a per-motion group (absent otherwise).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub motion: Option<&'static str>,
    /// Method.
    pub method: String,
    /// Rows.
    pub pairs: usize,
    /// Rows that failed.
    pub failed: usize,
    /// Mean rotation angle of the true motions, degrees.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mean_motion_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    mean_angle_error_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    median_angle_error_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    mean_geodesic_error_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    median_geodesic_error_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    mean_translation_error_mm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    median_translation_error_mm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    mean_add_s_mm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    median_add_s_mm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    success_rate: Option<f64>,
    /// Rows with error bounds, and the fraction of them whose rotation and translation errors
    /// are both within the bounds.
    bounded: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    bounds_cover: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    mean_seconds: Option<f64>,
    /// Mean time per stage over the pairs that ran, ms.
    #[serde(skip_serializing_if = "Option::is_none")]
    mean_stage_ms: Option<StageTimes>,
    /// Pairs with a pipeline warning (a fallback taken).
    warned: usize,
}

/// What a summary groups by.
type GroupKey = (String, Option<u32>, Option<&'static str>);

fn summary_of((object, step, motion): GroupKey, method: String, rows: &[&PairResult]) -> Summary {
    let ok: Vec<&PoseErrors> = rows.iter().filter_map(|r| r.errors.as_ref()).collect();
    let col = |f: &dyn Fn(&PoseErrors) -> f64| ok.iter().map(|e| f(e)).collect::<Vec<_>>();
    let angle = mean_median(&col(&|e| e.angle_error_deg));
    let geodesic = mean_median(&col(&|e| e.geodesic_error_deg));
    let translation = mean_median(&col(&|e| e.translation_error_m * 1e3));
    let add_s = mean_median(&ok.iter().filter_map(|e| e.add_s_m.map(|v| v * 1e3)).collect::<Vec<_>>());
    let secs: Vec<f64> = rows.iter().filter_map(|r| r.seconds).collect();
    let motions: Vec<f64> = rows.iter().filter_map(|r| r.motion_deg).collect();
    let bounded: Vec<bool> = rows
        .iter()
        .filter_map(|r| {
            let (e, u) = (r.errors.as_ref()?, r.uncertainty?);
            Some(e.geodesic_error_deg <= u.rotation_deg && e.translation_error_m <= u.translation_m)
        })
        .collect();
    Summary {
        object,
        step,
        motion,
        method,
        pairs: rows.len(),
        failed: rows.iter().filter(|r| r.failure.is_some()).count(),
        mean_motion_deg: mean_median(&motions).map(|a| a.0),
        mean_angle_error_deg: angle.map(|a| a.0),
        median_angle_error_deg: angle.map(|a| a.1),
        mean_geodesic_error_deg: geodesic.map(|a| a.0),
        median_geodesic_error_deg: geodesic.map(|a| a.1),
        mean_translation_error_mm: translation.map(|a| a.0),
        median_translation_error_mm: translation.map(|a| a.1),
        mean_add_s_mm: add_s.map(|a| a.0),
        median_add_s_mm: add_s.map(|a| a.1),
        success_rate: (!ok.is_empty()).then(|| ok.iter().filter(|e| e.success).count() as f64 / ok.len() as f64),
        bounded: bounded.len(),
        bounds_cover: (!bounded.is_empty())
            .then(|| bounded.iter().filter(|b| **b).count() as f64 / bounded.len() as f64),
        mean_seconds: mean_median(&secs).map(|a| a.0),
        mean_stage_ms: mean_stages(rows.iter().filter_map(|r| r.stage_ms.as_ref())),
        warned: rows.iter().filter(|r| !r.warnings.is_empty()).count(),
    }
}

/// Ranges of the true rotation of the per-motion table: (upper bound in degrees, label).
const MOTION_BINS: [(f64, &str); 6] =
    [(1.0, "< 1"), (3.0, "1-3"), (10.0, "3-10"), (20.0, "10-20"), (45.0, "20-45"), (f64::INFINITY, ">= 45")];

/// The range of a true rotation (to a micro-degree, so that a 3-degree step computed as
/// 2.9999999 lands in "3-10").
fn motion_bin(deg: f64) -> &'static str {
    let deg = (deg * 1e6).round() / 1e6;
    MOTION_BINS.iter().find(|(hi, _)| deg < *hi).map_or(">= 45", |b| b.1)
}

/// Per (object, method) with `ALL` over every object, per (step, method) and per (range of the
/// true rotation, method).
pub fn summarise(results: &[PairResult]) -> Vec<Summary> {
    let mut groups: BTreeMap<(u8, GroupKey, String), Vec<&PairResult>> = BTreeMap::new();
    for r in results {
        let m = r.method.clone();
        groups.entry((0, (r.object.clone(), None, None), m.clone())).or_default().push(r);
        groups.entry((0, ("ALL".into(), None, None), m.clone())).or_default().push(r);
        groups.entry((1, ("ALL".into(), Some(r.step), None), m.clone())).or_default().push(r);
        if let Some(deg) = r.motion_deg {
            groups.entry((2, ("ALL".into(), None, Some(motion_bin(deg))), m)).or_default().push(r);
        }
    }
    groups.into_iter().map(|((_, key, m), rows)| summary_of(key, m, &rows)).collect()
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
        acc.judge += t.judge;
        acc.align += t.align;
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
            judge: acc.judge * k,
            align: acc.align * k,
            total: acc.total * k,
        }
    })
}

/// A number with `digits` decimals, `-` for none.
pub fn fmt(v: Option<f64>, digits: usize) -> String {
    v.map_or("-".into(), |x| format!("{x:.digits$}"))
}

/// UTC time as `YYYY-MM-DDTHHMMSSZ` (the name of a run's directory).
pub fn timestamp() -> String {
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

/// What a benchmark tells the report about itself.
pub struct ReportSpec<'a> {
    /// The command (`bench-bigbird`, `bench-bop`): the schema and the title.
    pub bench: &'a str,
    /// The data the run used.
    pub dataset: String,
    /// The protocol, as written to `results.json`.
    pub protocol: serde_json::Value,
    /// The protocol in one line of `summary.md`.
    pub protocol_line: String,
    /// What the step column means (`rotation step (deg)`, `image gap`).
    pub step_label: &'a str,
    /// The methods, in the tables' order (the "no motion" row is added after them).
    pub methods: &'a [String],
    /// Reference answers that no method computed, each a column after the methods' (bench-real:
    /// the other record of the camera's motion, scored against the truth: how far the truth
    /// itself can be trusted). Their rows carry errors but no times.
    pub references: &'a [String],
    /// More Markdown for the end of `summary.md` (e.g. published numbers).
    pub appendix: String,
    /// Output root: a timestamped directory is created inside.
    pub out: &'a Path,
    /// Exit non-zero unless `results.json` is complete and no pair failed.
    pub check: bool,
    /// When this run is one shard of a sharded run: what its manifest records.
    pub shard: Option<ShardRun>,
}

/// A shard's part of a run, for its manifest.
pub struct ShardRun {
    /// Which shard.
    pub shard: crate::shard::Shard,
    /// Which field of a pair names its group (`object` or `camera`).
    pub group_field: &'static str,
    /// Every group of the run, in order (the shard's are those it owns).
    pub all_groups: Vec<String>,
}

/// The cell of a table: mean rotation-angle error, success rate, failures.
fn cell(s: &Summary) -> String {
    format!(
        "{} ({}% ok{})",
        fmt(s.mean_angle_error_deg, 2),
        fmt(s.success_rate.map(|r| r * 100.0), 0),
        if s.failed > 0 { format!(", {} failed", s.failed) } else { String::new() }
    )
}

/// A table with one row per group key and one column per method.
fn table(summary: &[Summary], columns: &[String], first: &str, rows: &[Row]) -> String {
    let mut t = format!("| {first} | {} |\n| --- |{}\n", columns.join(" | "), " --- |".repeat(columns.len()));
    for (label, select) in rows {
        let cells: Vec<String> = columns
            .iter()
            .map(|m| summary.iter().find(|s| select(s) && &s.method == m).map_or("-".into(), cell))
            .collect();
        let _ = writeln!(t, "| {label} | {} |", cells.join(" | "));
    }
    t
}

/// A row selector of a table.
type Row<'a> = (String, Box<dyn Fn(&Summary) -> bool + 'a>);

/// The per-object, per-step and per-motion tables.
fn tables(summary: &[Summary], columns: &[String], step_label: &str) -> [String; 3] {
    let objects: BTreeSet<&str> =
        summary.iter().filter(|s| s.step.is_none() && s.motion.is_none()).map(|s| s.object.as_str()).collect();
    let object_rows: Vec<Row> = objects
        .iter()
        .map(|&o| {
            let select: Box<dyn Fn(&Summary) -> bool> =
                Box::new(move |s: &Summary| s.step.is_none() && s.motion.is_none() && s.object == o);
            (o.to_string(), select)
        })
        .collect();
    let steps: BTreeSet<u32> = summary.iter().filter_map(|s| s.step).collect();
    let step_rows: Vec<Row> = steps
        .iter()
        .map(|&st| {
            let motion = summary.iter().find(|s| s.step == Some(st)).and_then(|s| s.mean_motion_deg);
            let select: Box<dyn Fn(&Summary) -> bool> = Box::new(move |s: &Summary| s.step == Some(st));
            (format!("{st} ({} deg)", fmt(motion, 2)), select)
        })
        .collect();
    let motion_rows: Vec<Row> = MOTION_BINS
        .iter()
        .filter(|(_, bin)| summary.iter().any(|s| s.motion == Some(*bin)))
        .map(|&(_, bin)| {
            let pairs = summary.iter().find(|s| s.motion == Some(bin)).map_or(0, |s| s.pairs);
            let select: Box<dyn Fn(&Summary) -> bool> = Box::new(move |s: &Summary| s.motion == Some(bin));
            (format!("{bin} deg ({pairs} pairs)"), select)
        })
        .collect();
    [
        table(summary, columns, "object", &object_rows),
        table(summary, columns, &format!("{step_label} (mean true rotation)"), &step_rows),
        table(summary, columns, "true rotation", &motion_rows),
    ]
}

/// Write `results.json`, `pairs.csv`, `summary.md` and the plots into a new timestamped
/// directory under `spec.out` (a shard's: `shard-K-of-N`, then its manifest), print the tables,
/// and check the JSON when asked. `skipped` holds the groups skipped, with the reason. Returns
/// the directory.
pub fn write_outputs(
    spec: &ReportSpec,
    results: &[PairResult],
    skipped: &[(String, String)],
    seconds: f64,
) -> anyhow::Result<PathBuf> {
    let dir = match &spec.shard {
        Some(s) => {
            // A shard run again replaces its earlier (perhaps partial) output.
            let dir = spec.out.join(s.shard.dir_name());
            if dir.exists() {
                std::fs::remove_dir_all(&dir).with_context(|| format!("removing {}", dir.display()))?;
            }
            dir
        }
        None => spec.out.join(timestamp()),
    };
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let summary = summarise(results);
    let json = serde_json::json!({
        "schema": format!("flowfilter {} results v3", spec.bench),
        "dataset": spec.dataset,
        "protocol": spec.protocol,
        "seconds": seconds,
        "skipped": skipped.iter().map(|(g, e)| format!("{g}: {e}")).collect::<Vec<_>>(),
        "summary": summary,
        "pairs": results,
    });
    std::fs::write(dir.join("results.json"), serde_json::to_string_pretty(&json)? + "\n")?;
    std::fs::write(dir.join("pairs.csv"), pairs_csv(results))?;
    let mut columns = spec.methods.to_vec();
    columns.extend(spec.references.iter().cloned());
    columns.push(NO_MOTION.into());
    let plots = crate::plots::write_all(&dir, results, &summary_for_plots(&summary), &columns)?;
    let [object_table, step_table, motion_table] = tables(&summary, &columns, spec.step_label);
    let stages = stage_table(&summary, spec.methods)
        + &bounds_lines(&summary, spec.methods)
        + &judge_lines(results, spec.methods);
    let failures = results.iter().filter(|r| r.failure.is_some()).count();
    let md = format!(
        "# {} results\n\nMean absolute rotation-angle error (degrees; the paper's metric) and success rate (< 2 deg, < 1 cm) per object and method; `{NO_MOTION}` is the identity answer (its error is the true motion). {} rows, {} failed, {:.0} s.\n\nDataset: {}. Protocol: {}.\n\n{object_table}\nPer {}:\n\n{step_table}\nPer range of the true rotation (where answering \"no motion\" is hard to beat):\n\n{motion_table}\n{stages}\n{}\n{}",
        spec.bench,
        results.len(),
        failures,
        seconds,
        spec.dataset,
        spec.protocol_line,
        spec.step_label,
        spec.appendix,
        plots.iter().map(|p| format!("![{p}]({p})\n")).collect::<String>()
    );
    std::fs::write(dir.join("summary.md"), &md)?;
    println!("\n{object_table}\n{step_table}\n{motion_table}\n{stages}\n{}", spec.appendix);
    println!("{} rows, {} failed; results in {}", results.len(), failures, dir.display());
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
    if spec.check {
        check(&dir.join("results.json"), spec.methods, spec.references)?;
        println!("check: results.json has every method and metric, and no pair failed");
    }
    if let Some(s) = &spec.shard {
        let groups = s.shard.select(&s.all_groups);
        write_manifest(spec, s, &groups, results.len(), skipped, seconds, &dir)?;
        println!(
            "shard {}: {} of {} groups; merge with `cargo xtask bench-merge {}`",
            s.shard,
            groups.len(),
            s.all_groups.len(),
            spec.out.display()
        );
    }
    Ok(dir)
}

/// The shard's manifest, written last (atomically): its presence says the shard finished.
fn write_manifest(
    spec: &ReportSpec,
    s: &ShardRun,
    groups: &[String],
    rows: usize,
    skipped: &[(String, String)],
    seconds: f64,
    dir: &Path,
) -> anyhow::Result<()> {
    let manifest = crate::shard::Manifest {
        schema: crate::shard::MANIFEST_SCHEMA.into(),
        bench: spec.bench.into(),
        shard: s.shard,
        code_version: crate::shard::code_version(),
        dataset: spec.dataset.clone(),
        protocol: spec.protocol.clone(),
        protocol_line: spec.protocol_line.clone(),
        step_label: spec.step_label.into(),
        methods: spec.methods.to_vec(),
        references: spec.references.to_vec(),
        appendix: spec.appendix.clone(),
        group_field: s.group_field.into(),
        all_groups: s.all_groups.clone(),
        groups: groups.to_vec(),
        rows,
        skipped: skipped.to_vec(),
        seconds,
    };
    crate::shard::write_atomic(&dir.join("shard.json"), &(serde_json::to_string_pretty(&manifest)? + "\n"))
}

fn pairs_csv(results: &[PairResult]) -> String {
    let mut csv = String::from(
        "object,camera,from,to,step,motion_deg,method,angle_error_deg,geodesic_error_deg,translation_error_m,add_s_m,success,converged,seconds,failure,judge_answer_score,judge_best_score,judge_best_turn_deg,judge_replaced,align_turn_deg,align_accepted,align_row_shear_x,align_row_shear_y\n",
    );
    for r in results {
        let e = r.errors;
        let _ = writeln!(
            csv,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            r.object,
            r.camera,
            r.from,
            r.to,
            r.step,
            fmt(r.motion_deg, 6),
            r.method,
            fmt(e.map(|e| e.angle_error_deg), 6),
            fmt(e.map(|e| e.geodesic_error_deg), 6),
            fmt(e.map(|e| e.translation_error_m), 6),
            fmt(e.and_then(|e| e.add_s_m), 6),
            e.map_or("-".into(), |e| e.success.to_string()),
            r.converged.map_or("-".into(), |c| c.to_string()),
            fmt(r.seconds, 4),
            r.failure.clone().unwrap_or_default().replace(',', ";"),
            fmt(r.judge.as_ref().map(|j| j.answer_score), 4),
            fmt(r.judge.as_ref().and_then(|j| j.best_score), 4),
            fmt(r.judge.as_ref().and_then(|j| j.best_turn_deg), 1),
            r.judge.as_ref().map_or("-".into(), |j| j.replaced.to_string()),
            fmt(r.align.as_ref().map(|p| p.turn_deg), 4),
            r.align.as_ref().map_or("-".into(), |p| p.accepted.to_string()),
            fmt(r.align.as_ref().map(|p| p.row_shear_px_per_row[0]), 5),
            fmt(r.align.as_ref().map(|p| p.row_shear_px_per_row[1]), 5),
        );
    }
    csv
}

/// A method's summary over every pair.
fn overall<'s>(summary: &'s [Summary], method: &str) -> Option<&'s Summary> {
    summary.iter().find(|s| s.object == "ALL" && s.step.is_none() && s.motion.is_none() && s.method == method)
}

/// Mean time per stage and method over all objects (ms).
fn stage_table(summary: &[Summary], methods: &[String]) -> String {
    let mut t = String::from(
        "| method | depth (per frame) | flow | correspondences | registration | judge | align | pair total | pairs with a warning |\n| --- | --- | --- | --- | --- | --- | --- | --- | --- |\n",
    );
    for m in methods {
        if let Some(s) = overall(summary, m)
            && let Some(st) = s.mean_stage_ms
        {
            let _ = writeln!(
                t,
                "| {m} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {} |",
                0.5 * (st.depth_model + st.depth_target),
                st.flow,
                st.correspondences,
                st.registration,
                st.judge,
                st.align,
                st.total,
                s.warned
            );
        }
    }
    t
}

/// For each method that gives error bounds: on how many rows, and how often they held.
fn bounds_lines(summary: &[Summary], methods: &[String]) -> String {
    let mut t = String::new();
    for m in methods {
        if let Some(s) = overall(summary, m)
            && let Some(cover) = s.bounds_cover
        {
            let _ = writeln!(
                t,
                "\n{m}: error bounds on {} of {} pairs; both errors within them on {:.0}%.",
                s.bounded,
                s.pairs,
                cover * 100.0
            );
        }
    }
    t
}

/// For each method with the photometric judge: how often it re-tracked a candidate, how often
/// the result replaced the answer, and how often it took the one of the two nearer the truth.
fn judge_lines(results: &[PairResult], methods: &[String]) -> String {
    let mut t = String::new();
    for m in methods {
        let rows: Vec<&PairResult> = results.iter().filter(|r| &r.method == m && r.judge.is_some()).collect();
        let tried: Vec<(&PairResult, f64)> =
            rows.iter().filter_map(|r| r.judge_other_error_deg.map(|o| (*r, o))).collect();
        if rows.is_empty() {
            continue;
        }
        let replaced = tried.iter().filter(|(r, _)| r.judge.as_ref().is_some_and(|j| j.replaced)).count();
        // The judge's choice as it left the judge (before the alignment moved it).
        let chosen = |r: &PairResult| r.judge_chosen_error_deg.or(r.errors.map(|e| e.geodesic_error_deg));
        let nearer = tried.iter().filter(|(r, other)| chosen(r).is_some_and(|c| c <= *other)).count();
        let _ = writeln!(
            t,
            "\n{m}: the judge ran on {} pairs, re-tracked a candidate on {}, took the re-tracked result on {}; it took the one of the two nearer the truth on {} of {}.",
            rows.len(),
            tried.len(),
            replaced,
            nearer,
            tried.len()
        );
    }
    t
}

/// What the plots need of the per-object summary.
fn summary_for_plots(summary: &[Summary]) -> Vec<crate::plots::MethodObject> {
    summary
        .iter()
        .filter(|s| s.step.is_none() && s.motion.is_none())
        .map(|s| crate::plots::MethodObject {
            object: s.object.clone(),
            method: s.method.clone(),
            mean_angle_error_deg: s.mean_angle_error_deg,
            stage_ms: s.mean_stage_ms,
        })
        .collect()
}

/// Re-read results.json and verify it (what `--check` and CI rely on): every method, every
/// reference and the "no motion" row have pairs, no pair failed, every registration has its
/// stage times, every row every metric.
pub fn check(path: &Path, methods: &[String], references: &[String]) -> anyhow::Result<()> {
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(path)?)?;
    let pairs = v["pairs"].as_array().context("results.json: no 'pairs' array")?;
    if pairs.is_empty() {
        bail!("results.json: no pairs");
    }
    for m in methods.iter().chain(references).map(String::as_str).chain([NO_MOTION]) {
        if !pairs.iter().any(|p| p["method"] == m) {
            bail!("results.json: method '{m}' has no pair");
        }
    }
    for p in pairs {
        let name = format!("{} {} {}->{} {}", p["object"], p["camera"], p["from"], p["to"], p["method"]);
        if !p["failure"].is_null() {
            bail!("results.json: pair {name} failed: {}", p["failure"]);
        }
        let estimated = p["method"] != NO_MOTION && !references.iter().any(|r| p["method"] == r.as_str());
        if estimated && (p["stage_ms"]["registration"].as_f64().is_none() || p["stage_ms"]["total"].as_f64().is_none())
        {
            bail!("results.json: pair {name} lacks per-stage times");
        }
        for metric in ["angle_error_deg", "geodesic_error_deg", "translation_error_m", "add_s_m", "success"] {
            if p["errors"][metric].is_null() {
                bail!("results.json: pair {name} lacks '{metric}'");
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(object: &str, step: u32, motion: f64, method: &str, error: f64) -> PairResult {
        let job = crate::pairs::PairJob {
            object: object.into(),
            camera: "NP3".into(),
            from: 0,
            to: step,
            step,
            model: 0u32,
            target: step,
            truth: Err("given as motion_deg".into()),
        };
        PairResult {
            motion_deg: Some(motion),
            errors: Some(PoseErrors {
                angle_error_deg: error,
                geodesic_error_deg: error,
                translation_error_m: 0.001,
                add_s_m: Some(0.001),
                success: error < 2.0,
            }),
            converged: Some(true),
            seconds: Some(0.1),
            ..PairResult::unscored(&job, method.into())
        }
    }

    #[test]
    fn the_judge_line_counts_its_choices_against_the_truth() {
        let judged = |error: f64, other: Option<f64>, replaced: bool| {
            let mut r = row("can", 30, 30.0, "flowfilter", error);
            r.judge = Some(flowfilter_pipeline::JudgeReport {
                answer_score: 0.5,
                candidates: 10,
                best_score: Some(0.2),
                best_turn_deg: Some(30.0),
                best_axis: Some(0),
                retracked_score: other.map(|_| 0.1),
                replaced,
                answer_transform: [[0.0; 4]; 4],
                retracked_transform: None,
                aligned_answer_score: None,
                aligned_candidate: false,
            });
            r.judge_other_error_deg = other;
            r
        };
        let rows = vec![
            judged(0.3, Some(29.0), true),  // re-tracked, taken, right
            judged(0.5, Some(0.9), false),  // re-tracked, kept the answer, right
            judged(20.0, Some(10.0), true), // taken, wrong
            judged(0.2, None, false),       // nothing re-tracked
            row("can", 30, 30.0, "icp-pt2pl", 1.0),
        ];
        let t = judge_lines(&rows, &["flowfilter".into(), "icp-pt2pl".into()]);
        assert!(
            t.contains("the judge ran on 4 pairs, re-tracked a candidate on 3, took the re-tracked result on 2"),
            "{t}"
        );
        assert!(t.contains("nearer the truth on 2 of 3"), "{t}");
        assert!(!t.contains("icp-pt2pl"), "{t}");
    }

    #[test]
    fn summaries_group_by_object_step_and_true_rotation() {
        let rows = [
            row("box", 1, 0.25, "flowfilter", 0.1),
            row("can", 1, 0.25, "flowfilter", 0.3),
            row("box", 10, 2.999_999_9, "flowfilter", 1.0),
            row("box", 1, 0.25, NO_MOTION, 0.25),
        ];
        let s = summarise(&rows);
        let find = |f: &dyn Fn(&Summary) -> bool| s.iter().find(|x| f(x) && x.method == "flowfilter").unwrap();
        let all = find(&|x| x.object == "ALL" && x.step.is_none() && x.motion.is_none());
        assert_eq!(all.pairs, 3);
        assert!((all.mean_angle_error_deg.unwrap() - 1.4 / 3.0).abs() < 1e-12);
        let step1 = find(&|x| x.step == Some(1));
        assert_eq!((step1.pairs, step1.mean_motion_deg), (2, Some(0.25)));
        assert!((step1.mean_angle_error_deg.unwrap() - 0.2).abs() < 1e-12);
        assert_eq!(find(&|x| x.motion == Some("< 1")).pairs, 2);
        // A 3-degree motion computed a hair short of 3 is still in the 3-10 range.
        assert_eq!(find(&|x| x.motion == Some("3-10")).pairs, 1);
        assert!(s.iter().all(|x| x.motion != Some("1-3")));
        let [objects, steps, motions] = tables(&s, &["flowfilter".to_string(), NO_MOTION.to_string()], "gap");
        assert!(objects.contains("| box | 0.55 (100% ok) | 0.25 (100% ok) |"), "{objects}");
        assert!(steps.contains("| 1 (0.25 deg) | 0.20 (100% ok) | 0.25 (100% ok) |"), "{steps}");
        assert!(motions.contains("| < 1 deg (2 pairs) |"), "{motions}");
    }

    /// `check` asks times of the methods' rows only: a reference answer's rows (another record
    /// of the motion) carry errors and no times, and a reference the run names must have rows.
    #[test]
    fn check_takes_reference_rows_without_times() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("results.json");
        let write = |rows: &[PairResult]| {
            std::fs::write(&path, serde_json::json!({ "pairs": rows }).to_string()).unwrap();
        };
        let mut estimate = row("box", 1, 12.0, "flowfilter", 0.5);
        estimate.stage_ms = Some(StageTimes { registration: 5.0, total: 20.0, ..StageTimes::default() });
        let (record, still) = (row("box", 1, 12.0, "arm-record", 0.7), row("box", 1, 12.0, NO_MOTION, 12.0));
        let (methods, references) = (["flowfilter".to_string()], ["arm-record".to_string()]);
        write(&[estimate.clone(), record.clone(), still.clone()]);
        check(&path, &methods, &references).unwrap();
        // Without its rows, or as a method (which must carry times), it is refused.
        write(&[estimate.clone(), still.clone()]);
        assert!(check(&path, &methods, &references).unwrap_err().to_string().contains("'arm-record' has no pair"));
        write(&[estimate, record, still]);
        let as_method = ["flowfilter".to_string(), "arm-record".to_string()];
        assert!(check(&path, &as_method, &[]).unwrap_err().to_string().contains("lacks per-stage times"));
    }
}
