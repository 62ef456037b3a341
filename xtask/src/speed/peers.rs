//! The peers' side of `bench-speed`: `tools/peers/speed_peers.py` (probreg, Open3D, OpenCV) run
//! with the thread count set in its environment, on the inputs listed in a manifest.

use super::clouds::CloudPair;
use super::ours::registration_config;
use anyhow::Context;
use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::process::Command;

/// What the script reports for one peer run.
#[derive(Debug, Clone, Deserialize)]
pub struct PeerRow {
    /// Registration pair name (`wavy-N`), absent for flow rows.
    #[serde(default)]
    pub pair: Option<String>,
    /// Sintel case, for flow rows.
    #[serde(default)]
    pub case: Option<String>,
    /// Our method name it is compared with.
    pub method: String,
    /// The library and version (and how its input differs from ours, if it does).
    pub peer: String,
    /// Fastest run, seconds.
    pub seconds: f64,
    /// The registration's 4x4 result.
    #[serde(default)]
    pub transform: Option<[[f64; 4]; 4]>,
    /// The flow's EPE over all pixels.
    #[serde(default)]
    pub epe: Option<f64>,
}

#[derive(Deserialize)]
struct PeerOutput {
    rows: Vec<PeerRow>,
}

/// Points of each cloud that probreg's CPD gets (its E-step is all-pairs in time and memory).
pub const CPD_PEER_SUBSAMPLE: usize = 2000;

/// Write the manifest the script reads: the pairs, the parameters of `registration_config`,
/// the Sintel cases.
///
/// # Errors
/// The file cannot be written.
pub fn write_manifest(
    dir: &Path,
    pairs: &[CloudPair],
    sintel: &[(String, PathBuf)],
    repeats: super::ours::Repeats,
) -> anyhow::Result<PathBuf> {
    let c = registration_config()?;
    let manifest = serde_json::json!({
        "repeat": repeats.min,
        "min_seconds": repeats.budget_s,
        "max_runs": super::ours::Repeats::MAX_RUNS,
        "pairs": pairs.iter().map(|p| serde_json::json!({
            "name": p.name, "source": p.source, "target": p.target,
        })).collect::<Vec<_>>(),
        "params": {
            "filterreg": { "w": c.filterreg.w, "max_iterations": c.filterreg.max_iterations, "tolerance": c.filterreg.tolerance },
            "icp": {
                "max_correspondence_distance": c.icp.max_correspondence_distance,
                "max_iterations": c.icp.max_iterations,
                "relative_fitness": c.icp.relative_fitness,
                "relative_rmse": c.icp.relative_rmse,
            },
            "cpd": { "w": c.cpd.w, "max_iterations": 100, "tolerance": 1e-6, "peer_subsample": CPD_PEER_SUBSAMPLE, "seed": 1 },
        },
        "flow": sintel.iter().map(|(case, dir)| serde_json::json!({
            "case": case,
            "from": dir.join("frame_0002.png"),
            "to": dir.join("frame_0003.png"),
            "gt": dir.join("gt/frame_0002.flo"),
        })).collect::<Vec<_>>(),
    });
    let path = dir.join("manifest.json");
    std::fs::write(&path, serde_json::to_string_pretty(&manifest)? + "\n")
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(path)
}

/// Run the script with `threads` threads (OpenMP, BLAS and OpenCV), or say why it could not be
/// run (`Err` holds a message for the report, not a failure of the benchmark).
pub fn run(python: &str, manifest: &Path, threads: usize) -> Result<Vec<PeerRow>, String> {
    let script = crate::repo_root().join("tools/peers/speed_peers.py");
    let out = manifest.with_file_name(format!("peers-{threads}-threads.json"));
    let n = threads.to_string();
    let status = Command::new(python)
        .arg(&script)
        .arg(manifest)
        .arg(&out)
        .envs(["OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"].map(|k| (k, n.as_str())))
        .output()
        .map_err(|e| format!("{python} could not be started ({e})"))?;
    if !status.status.success() {
        let stderr = String::from_utf8_lossy(&status.stderr);
        let last = stderr.lines().rev().find(|l| !l.trim().is_empty()).unwrap_or("no message");
        return Err(format!("{} exited with {}: {last}", script.display(), status.status));
    }
    let text = std::fs::read_to_string(&out).map_err(|e| format!("{}: {e}", out.display()))?;
    serde_json::from_str::<PeerOutput>(&text).map(|o| o.rows).map_err(|e| format!("{}: {e}", out.display()))
}
