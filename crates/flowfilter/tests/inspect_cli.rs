//! `flowfilter inspect` on the h5py fixtures and on damaged copies.

use std::path::{Path, PathBuf};
use std::process::Command;

fn fixture(format: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/bigbird").join(format).join("tiny_spheres")
}

fn run(dir: &Path) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_flowfilter")).arg("inspect").arg(dir).output().unwrap();
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

#[test]
fn inspect_summarises_both_h5py_formats() {
    for format in ["earliest", "latest"] {
        let (ok, stdout, stderr) = run(&fixture(format));
        assert!(ok, "{format}: {stderr}");
        for needle in [
            "frames:  6 found, 6 valid; 3 angles (0..30 deg); 3 table poses",
            "NP1:     3 frames, colour 160x128, depth 80x60",
            "rgb fx=135.17 fy=135.11 cx=79.62 cy=63.45",
            "depth scale 1.01250",
            "calibration: 5 Carmine sensor(s)",
            "turntable: centre",
            "OK: no problems found",
        ] {
            assert!(stdout.contains(needle), "{format}: missing '{needle}' in\n{stdout}");
        }
    }
}

#[test]
fn inspect_lists_every_problem_and_fails() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("obj");
    std::fs::create_dir_all(dir.join("masks")).unwrap();
    std::fs::create_dir_all(dir.join("poses")).unwrap();
    let src = fixture("latest");
    for rel in [
        "calibration.h5",
        "NP1_0.h5",
        "NP1_0.jpg",
        "masks/NP1_0_mask.pbm",
        "NP5_0.h5",
        "NP5_0.jpg",
        "poses/turntable.h5",
    ] {
        std::fs::copy(src.join(rel), dir.join(rel)).unwrap();
    }
    // NP5_0 has no mask, the angle-0 pose is missing, and NP1_0's colour image is truncated.
    let jpg = std::fs::read(dir.join("NP1_0.jpg")).unwrap();
    std::fs::write(dir.join("NP1_0.jpg"), &jpg[..jpg.len() / 3]).unwrap();
    let (ok, _stdout, stderr) = run(&dir);
    assert!(!ok);
    assert!(stderr.contains("3 problem(s) found"), "{stderr}");
    for needle in ["NP5_0_pose.h5: not found", "NP5_0_mask.pbm: not found", "NP1_0.jpg: cannot decode image"] {
        assert!(stderr.contains(needle), "missing '{needle}' in\n{stderr}");
    }
    let (ok, _, stderr) = run(Path::new("/does/not/exist"));
    assert!(!ok && stderr.contains("/does/not/exist: not found"), "{stderr}");
}
