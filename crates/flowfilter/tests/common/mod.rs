//! What the CLI's integration tests share: running the binary and finding the shared data.

use std::path::{Path, PathBuf};
use std::process::Command;

/// `flowfilter ARGS`: success, stdout, stderr.
pub fn flowfilter(args: &[&str]) -> (bool, String, String) {
    flowfilter_with(args, &[])
}

/// [`flowfilter`] with environment variables set (`RAYON_NUM_THREADS`).
pub fn flowfilter_with(args: &[&str], env: &[(&str, &str)]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_flowfilter")).args(args).envs(env.iter().copied()).output().unwrap();
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

/// `../shared/data/<rel>` beside the repository, or `None` after saying that the test is skipped.
pub fn shared_data(rel: &str) -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data").join(rel);
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!("skipping: {} is absent (the shared data sits beside the repository)", dir.display());
        None
    }
}
