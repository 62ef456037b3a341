//! `flowfilter register` on the recorded peer clouds.

use std::path::Path;
use std::process::Command;

fn flowfilter(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_flowfilter")).args(args).output().unwrap();
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

#[test]
fn registers_a_recorded_case_and_reports_json() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/peers/registration");
    let (s, t) = (dir.join("case_0_source.ply"), dir.join("case_0_target.ply"));
    let results: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("results.json")).unwrap()).unwrap();
    let truth = &results["cases"][0]["truth"];
    // ICP's default 2 cm gate needs a start near the answer: --init gives it the truth, and the
    // result must stay there.
    let tmp = tempfile::tempdir().unwrap();
    let init = tmp.path().join("init.txt");
    let rows: Vec<String> =
        (0..4).map(|r| (0..4).map(|c| truth[r][c].to_string()).collect::<Vec<_>>().join(" ")).collect();
    std::fs::write(&init, rows.join("\n")).unwrap();
    for method in ["icp-pt2pl", "filterreg-pt2pt"] {
        let mut args = vec![
            "register",
            "--source",
            s.to_str().unwrap(),
            "--target",
            t.to_str().unwrap(),
            "--method",
            method,
            "--json",
        ];
        if method.starts_with("icp") {
            args.extend(["--init", init.to_str().unwrap()]);
        }
        let (ok, stdout, stderr) = flowfilter(&args);
        assert!(ok, "{method}: {stderr}");
        let out: serde_json::Value = serde_json::from_str(&stdout).unwrap();
        assert_eq!(out["converged"], true, "{method}: {stdout}");
        for r in 0..4 {
            for c in 0..4 {
                let (a, b) = (out["transform"][r][c].as_f64().unwrap(), truth[r][c].as_f64().unwrap());
                assert!((a - b).abs() < 1e-6, "{method}: entry ({r},{c}) {a} vs {b}");
            }
        }
    }
}

#[test]
fn bad_arguments_fail_clearly() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/peers/registration");
    let s = dir.join("case_0_source.ply");
    let s = s.to_str().unwrap();
    let (ok, _, stderr) = flowfilter(&["register", "--source", s, "--target", s, "--method", "teaser"]);
    assert!(!ok && stderr.contains("unknown method 'teaser'"), "{stderr}");
    let (ok, _, stderr) = flowfilter(&["register", "--source", s, "--target", "/no/such.ply"]);
    assert!(!ok && stderr.contains("/no/such.ply"), "{stderr}");
    // The source PLY has no normals: point-to-plane needs them on the target.
    let (ok, _, stderr) = flowfilter(&["register", "--source", s, "--target", s, "--method", "icp-pt2pl"]);
    assert!(!ok && stderr.contains("needs normals"), "{stderr}");
    let bad = tempfile::NamedTempFile::new().unwrap();
    std::fs::write(bad.path(), "1 0 0 0 0 1 0 0 0 0 1 0").unwrap();
    let (ok, _, stderr) =
        flowfilter(&["register", "--source", s, "--target", s, "--init", bad.path().to_str().unwrap()]);
    assert!(!ok && stderr.contains("expected 16 numbers"), "{stderr}");
}
