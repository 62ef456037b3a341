//! Shared helpers of the BigBIRD integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// `fixtures/bigbird/<format>/tiny_spheres`, written by h5py (`tools/peers/bigbird_fixtures.py`).
pub fn fixture(format: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/bigbird").join(format).join("tiny_spheres")
}

/// Copy a fixture object into a fresh temporary directory that the test may damage.
pub fn scratch_copy(format: &str) -> (tempfile::TempDir, PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    let dst = tmp.path().join("tiny_spheres");
    copy_dir(&fixture(format), &dst);
    (tmp, dst)
}

fn copy_dir(src: &Path, dst: &Path) {
    std::fs::create_dir_all(dst).unwrap();
    for entry in std::fs::read_dir(src).unwrap() {
        let entry = entry.unwrap();
        let to = dst.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_dir(&entry.path(), &to);
        } else {
            std::fs::copy(entry.path(), to).unwrap();
        }
    }
}
