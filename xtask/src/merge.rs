//! `cargo xtask bench-merge DIR...`: the shards of one sharded run merged into the outputs one
//! process would have written (results.json, pairs.csv, summary.md, plots).

use crate::pairs::PairResult;
use crate::report::{ReportSpec, write_outputs};
use crate::shard::{Manifest, read_manifest};
use anyhow::{Context, bail};
use clap::Args;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Arguments of `bench-merge`.
#[derive(Args)]
pub struct MergeArgs {
    /// Shard directories (`shard-K-of-N`, holding `shard.json`), or directories holding them.
    #[arg(required = true)]
    pub dirs: Vec<PathBuf>,
    /// Output root (a timestamped directory is created inside).
    #[arg(long, default_value = "results")]
    pub out: PathBuf,
    /// Exit non-zero unless the merged results.json holds every method with every metric and
    /// no pair failed.
    #[arg(long)]
    pub check: bool,
    /// A results directory of the same protocol run in one process: exit non-zero unless the
    /// merged per-pair results and summaries are the same (times aside).
    #[arg(long)]
    pub compare: Option<PathBuf>,
}

/// The shard directories named by `dirs`: each one holding `shard.json` or named
/// `shard-K-of-N`, or their children that are.
fn shard_dirs(dirs: &[PathBuf]) -> anyhow::Result<Vec<PathBuf>> {
    let is_shard = |d: &Path| {
        d.join("shard.json").is_file() || d.file_name().is_some_and(|n| n.to_string_lossy().starts_with("shard-"))
    };
    let mut out = vec![];
    for d in dirs {
        if is_shard(d) {
            out.push(d.clone());
            continue;
        }
        let mut children: Vec<PathBuf> = std::fs::read_dir(d)
            .with_context(|| format!("reading {}", d.display()))?
            .filter_map(Result::ok)
            .map(|e| e.path())
            .filter(|p| p.is_dir() && is_shard(p))
            .collect();
        if children.is_empty() {
            bail!(
                "{}: neither a shard directory (shard.json) nor a directory of shard-K-of-N directories",
                d.display()
            );
        }
        children.sort();
        out.append(&mut children);
    }
    Ok(out)
}

/// The fields that must agree between shards of one run, as (name, value).
fn identity(m: &Manifest) -> [(&'static str, String); 6] {
    [
        ("bench", m.bench.clone()),
        ("code version", m.code_version.clone()),
        ("dataset", m.dataset.clone()),
        ("protocol", m.protocol.to_string()),
        ("group list", m.all_groups.join(",")),
        ("shard count", m.shard.count.to_string()),
    ]
}

/// Check that the manifests are the shards of one run, each once, none missing, each with the
/// groups its index owns.
fn check_shards(shards: &[(PathBuf, Manifest)]) -> anyhow::Result<()> {
    let (first_dir, first) = &shards[0];
    for (dir, m) in &shards[1..] {
        for ((name, want), (_, got)) in identity(first).iter().zip(identity(m).iter()) {
            if want != got {
                let short = |s: &str| if s.len() > 120 { format!("{}...", &s[..120]) } else { s.to_string() };
                bail!(
                    "{} and {} are not shards of one run: their {name} differs ({} against {})",
                    first_dir.display(),
                    dir.display(),
                    short(want),
                    short(got)
                );
            }
        }
    }
    let count = first.shard.count;
    let mut seen: BTreeMap<usize, &PathBuf> = BTreeMap::new();
    for (dir, m) in shards {
        if let Some(other) = seen.insert(m.shard.index, dir) {
            bail!("shard {} is given twice: {} and {}", m.shard, other.display(), dir.display());
        }
        let owned = m.shard.select(&m.all_groups);
        if m.groups != owned {
            bail!("{}: shard {} holds groups {:?}, but owns {:?}", dir.display(), m.shard, m.groups, owned);
        }
    }
    let missing: Vec<String> = (1..=count).filter(|k| !seen.contains_key(k)).map(|k| format!("{k}/{count}")).collect();
    if !missing.is_empty() {
        bail!("missing shard(s) {} of {count}: run each with --shard K/N, then merge again", missing.join(", "));
    }
    Ok(())
}

/// A shard's rows, checked against its manifest.
fn read_rows(dir: &Path, m: &Manifest) -> anyhow::Result<Vec<PairResult>> {
    let path = dir.join("results.json");
    let text = std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let v: serde_json::Value = serde_json::from_str(&text).with_context(|| format!("{}: not JSON", path.display()))?;
    let rows: Vec<PairResult> = serde_json::from_value(v["pairs"].clone())
        .with_context(|| format!("{}: 'pairs' is not a list of pair results", path.display()))?;
    if rows.len() != m.rows {
        bail!(
            "{}: {} rows, but its shard.json says {}: the shard's output is damaged; re-run it",
            path.display(),
            rows.len(),
            m.rows
        );
    }
    Ok(rows)
}

/// The group a row belongs to.
fn group_of<'a>(row: &'a PairResult, field: &str) -> &'a str {
    if field == "object" { &row.object } else { &row.camera }
}

/// Merge the shards.
pub fn run(args: &MergeArgs) -> anyhow::Result<()> {
    let dirs = shard_dirs(&args.dirs)?;
    let shards: Vec<(PathBuf, Manifest)> =
        dirs.iter().map(|d| read_manifest(d).map(|m| (d.clone(), m))).collect::<anyhow::Result<_>>()?;
    check_shards(&shards)?;
    let first = &shards[0].1;
    let order: BTreeMap<&str, usize> = first.all_groups.iter().enumerate().map(|(i, g)| (g.as_str(), i)).collect();
    let mut rows: Vec<PairResult> = vec![];
    let mut skipped: Vec<(String, String)> = vec![];
    for (dir, m) in &shards {
        rows.extend(read_rows(dir, m)?);
        skipped.extend(m.skipped.iter().cloned());
    }
    // The single run's order: groups in the run's order, each group's rows as its shard wrote them.
    let rank = |g: &str| order.get(g).copied().unwrap_or(usize::MAX);
    rows.sort_by_key(|r| rank(group_of(r, &first.group_field)));
    skipped.sort_by_key(|(g, _)| rank(g));
    if rows.is_empty() {
        bail!(
            "no pair in any shard: {}",
            skipped.iter().map(|(g, e)| format!("{g}: {e}")).collect::<Vec<_>>().join("; ")
        );
    }
    let seconds: f64 = shards.iter().map(|(_, m)| m.seconds).sum();
    let spec = ReportSpec {
        bench: &first.bench,
        dataset: first.dataset.clone(),
        protocol: first.protocol.clone(),
        protocol_line: first.protocol_line.clone(),
        step_label: &first.step_label,
        methods: &first.methods,
        references: &first.references,
        appendix: first.appendix.clone(),
        out: &args.out,
        check: args.check,
        shard: None,
    };
    let dir = write_outputs(&spec, &rows, &skipped, seconds)?;
    println!(
        "merged {} shards ({} rows; {seconds:.0} s of shard time) into {}",
        shards.len(),
        rows.len(),
        dir.display()
    );
    if let Some(other) = &args.compare {
        compare(&dir.join("results.json"), &other.join("results.json"))?;
        println!("compare: the same pairs, errors and summaries as {} (times aside)", other.display());
    }
    Ok(())
}

/// The keys of results.json's rows that measure time.
const TIMING_KEYS: [&str; 4] = ["seconds", "stage_ms", "mean_seconds", "mean_stage_ms"];

/// `pairs` and `summary` of a results.json, without timings.
fn untimed(path: &Path) -> anyhow::Result<[Vec<serde_json::Value>; 2]> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let v: serde_json::Value = serde_json::from_str(&text).with_context(|| format!("{}: not JSON", path.display()))?;
    let strip = |key: &str| -> anyhow::Result<Vec<serde_json::Value>> {
        let items = v[key].as_array().with_context(|| format!("{}: no '{key}' list", path.display()))?;
        Ok(items
            .iter()
            .map(|item| {
                let mut item = item.clone();
                if let Some(o) = item.as_object_mut() {
                    o.retain(|k, _| !TIMING_KEYS.contains(&k.as_str()));
                }
                item
            })
            .collect())
    };
    Ok([strip("pairs")?, strip("summary")?])
}

/// Fail unless two results.json hold the same rows and summaries, times aside; the message
/// shows the first difference.
fn compare(a: &Path, b: &Path) -> anyhow::Result<()> {
    let (x, y) = (untimed(a)?, untimed(b)?);
    for (name, (p, q)) in ["pairs", "summary"].iter().zip(x.iter().zip(y.iter())) {
        if p.len() != q.len() {
            bail!("{name}: {} has {} entries, {} has {}", a.display(), p.len(), b.display(), q.len());
        }
        if let Some((i, (u, v))) = p.iter().zip(q.iter()).enumerate().find(|(_, (u, v))| u != v) {
            bail!("{name}[{i}] differs:\n  {}: {u}\n  {}: {v}", a.display(), b.display());
        }
    }
    Ok(())
}
