//! Sharding a benchmark over processes: `--shard K/N` runs every N-th group of pairs (a group is
//! what shares frames: a BigBIRD object, a BOP scene), so each frame is prepared in one shard
//! only; each shard writes its results and, last, a manifest (`shard.json`). `bench-merge`
//! checks that the shards are one run's (same bench, protocol, data and code) and complete, and
//! writes the outputs one process would have written.

use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};
use std::path::Path;

pub use flowfilter_pipeline::batch::Shard;

/// Schema of `shard.json`.
pub const MANIFEST_SCHEMA: &str = "flowfilter shard v1";

/// What a shard's manifest says about the run it is part of; written last, so a shard without
/// one did not finish.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Always [`MANIFEST_SCHEMA`].
    pub schema: String,
    /// `bench-bigbird` or `bench-bop`.
    pub bench: String,
    /// This shard.
    pub shard: Shard,
    /// The code that ran ([`code_version`]).
    pub code_version: String,
    /// The data.
    pub dataset: String,
    /// The protocol, as in results.json.
    pub protocol: serde_json::Value,
    /// The protocol in one line (summary.md).
    pub protocol_line: String,
    /// The step column's meaning.
    pub step_label: String,
    /// The methods, in the tables' order.
    pub methods: Vec<String>,
    /// The reference answers' columns (`ReportSpec::references`).
    #[serde(default)]
    pub references: Vec<String>,
    /// summary.md's appendix.
    pub appendix: String,
    /// Which field of a pair names its group (`object` or `camera`).
    pub group_field: String,
    /// Every group of the run, in the run's order.
    pub all_groups: Vec<String>,
    /// This shard's groups.
    pub groups: Vec<String>,
    /// Rows this shard wrote to results.json.
    pub rows: usize,
    /// Groups skipped, with the reason, `(group, reason)`.
    pub skipped: Vec<(String, String)>,
    /// Wall time of the shard, seconds.
    pub seconds: f64,
}

/// The code that runs: the package version and, in a git checkout, the commit (with `+dirty`
/// when the tree has changes); else a hash of the executable.
pub fn code_version() -> String {
    let git = |args: &[&str]| {
        std::process::Command::new("git")
            .args(args)
            .current_dir(crate::repo_root())
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
    };
    let version = env!("CARGO_PKG_VERSION");
    if let Some(commit) = git(&["rev-parse", "HEAD"]) {
        // Untracked files (results, caches) are not code.
        let dirty = git(&["status", "--porcelain", "--untracked-files=no"]).is_some_and(|s| !s.is_empty());
        return format!("{version} {commit}{}", if dirty { "+dirty" } else { "" });
    }
    let exe = std::env::current_exe().ok().and_then(|p| std::fs::read(p).ok()).unwrap_or_default();
    format!("{version} exe:{:016x}", fnv1a(&exe))
}

/// FNV-1a, 64 bits.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, b| (h ^ u64::from(*b)).wrapping_mul(0x0000_0100_0000_01b3))
}

/// Write `text` to `path` whole or not at all.
pub fn write_atomic(path: &Path, text: &str) -> anyhow::Result<()> {
    flowfilter_pipeline::geometry::atomic::write_atomic(path, text.as_bytes())
        .with_context(|| format!("writing {}", path.display()))
}

/// Read a shard directory's manifest.
pub fn read_manifest(dir: &Path) -> anyhow::Result<Manifest> {
    let path = dir.join("shard.json");
    let text = std::fs::read_to_string(&path).map_err(|_| {
        anyhow::anyhow!(
            "{}: no shard.json: the shard did not finish (its output is partial); re-run it with the same --shard K/N",
            dir.display()
        )
    })?;
    let m: Manifest =
        serde_json::from_str(&text).with_context(|| format!("{}: not a shard manifest", path.display()))?;
    if m.schema != MANIFEST_SCHEMA {
        bail!("{}: schema '{}', expected '{MANIFEST_SCHEMA}'", path.display(), m.schema);
    }
    Ok(m)
}
