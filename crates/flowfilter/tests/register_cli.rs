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
        assert_eq!(out["registration"]["converged"], true, "{method}: {stdout}");
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
    // clap checks the method and lists the choices.
    let (ok, _, stderr) = flowfilter(&["register", "--source", s, "--target", s, "--method", "teaser"]);
    assert!(!ok && stderr.contains("'teaser'") && stderr.contains("filterreg-pt2pl"), "{stderr}");
    assert!(stderr.contains("flowfilter-init-only") && stderr.contains("possible values"), "{stderr}");
    let (ok, _, stderr) = flowfilter(&["register", "--source", s, "--target", "/no/such.ply"]);
    assert!(!ok && stderr.contains("/no/such.ply"), "{stderr}");
    // The source PLY has no normals: point-to-plane needs them on the target, so they are
    // estimated, with a warning (Open3D users call estimate_normals first).
    let (ok, _, stderr) = flowfilter(&["register", "--source", s, "--target", s, "--method", "icp-pt2pl"]);
    assert!(ok && stderr.contains("(target) has no normals, which icp-pt2pl needs"), "{stderr}");
    let bad = tempfile::NamedTempFile::new().unwrap();
    std::fs::write(bad.path(), "1 0 0 0 0 1 0 0 0 0 1 0").unwrap();
    let (ok, _, stderr) =
        flowfilter(&["register", "--source", s, "--target", s, "--init", bad.path().to_str().unwrap()]);
    assert!(!ok && stderr.contains("expected 16 numbers"), "{stderr}");
}

/// The configuration files shipped in `configs/` are accepted by `register --config` (they are
/// pipeline configurations: `method` and `[registration.*]` tables), and so is a file of bare
/// backend tables; the file's method is the default, `--method` overrides it.
#[test]
fn register_accepts_the_shipped_configs() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let dir = root.join("fixtures/peers/registration");
    let (s, t) = (dir.join("case_3_source.ply"), dir.join("case_3_target.ply"));
    let (s, t) = (s.to_str().unwrap(), t.to_str().unwrap());
    for (config, method) in [
        ("icp.toml", "icp-pt2pl"),
        ("filterreg.toml", "filterreg-pt2pt"),
        ("cpd.toml", "cpd"),
        ("cpd-full-cloud.toml", "cpd"),
        ("flowfilter.toml", "flowfilter"),
    ] {
        let path = root.join("configs").join(config);
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.contains(&format!("method = \"{method}\"")), "{config} names another method");
        let (ok, stdout, stderr) =
            flowfilter(&["register", "--source", s, "--target", t, "--config", path.to_str().unwrap(), "--json"]);
        assert!(ok, "{config}: {stderr}");
        let out: serde_json::Value = serde_json::from_str(&stdout).unwrap();
        assert_eq!(out["method"], method, "{config}");
    }
    let path = root.join("configs/icp.toml");
    let (ok, stdout, stderr) = flowfilter(&[
        "register",
        "--source",
        s,
        "--target",
        t,
        "--config",
        path.to_str().unwrap(),
        "--method",
        "icp-pt2pt",
        "--json",
    ]);
    assert!(ok, "{stderr}");
    assert_eq!(serde_json::from_str::<serde_json::Value>(&stdout).unwrap()["method"], "icp-pt2pt");
    let bare = tempfile::NamedTempFile::new().unwrap();
    std::fs::write(bare.path(), "[icp]\nmax_iterations = 5\n").unwrap();
    let (ok, stdout, stderr) = flowfilter(&[
        "register",
        "--source",
        s,
        "--target",
        t,
        "--config",
        bare.path().to_str().unwrap(),
        "--method",
        "icp-pt2pt",
        "--json",
    ]);
    assert!(ok, "{stderr}");
    let out: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert!(out["registration"]["iterations"].as_u64().unwrap() <= 5, "{stdout}");
    // A wrong key names the file and the key.
    std::fs::write(bare.path(), "method = \"icp-pt2pl\"\n[registration.icp]\nmax_iteration = 5\n").unwrap();
    let (ok, _, stderr) =
        flowfilter(&["register", "--source", s, "--target", t, "--config", bare.path().to_str().unwrap()]);
    assert!(!ok && stderr.contains("max_iteration") && stderr.contains(bare.path().to_str().unwrap()), "{stderr}");
}

/// `register --json` names its quantities as `estimate --json` does, and carries a schema tag.
#[test]
fn register_json_speaks_the_estimate_names() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/peers/registration");
    let (s, t) = (dir.join("case_3_source.ply"), dir.join("case_3_target.ply"));
    let (ok, stdout, stderr) =
        flowfilter(&["register", "--source", s.to_str().unwrap(), "--target", t.to_str().unwrap(), "--json"]);
    assert!(ok, "{stderr}");
    let out: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(out["schema"], "flowfilter register v1");
    for key in ["rotation_angle_deg", "rotation_axis", "translation_m", "transform", "warnings"] {
        assert!(!out[key].is_null(), "no '{key}': {stdout}");
    }
    for key in ["iterations", "converged", "fitness", "inlier_rmse_m", "sigma2", "model_points", "target_points"] {
        assert!(!out["registration"][key].is_null(), "no 'registration.{key}': {stdout}");
    }
    assert!(out["stage_ms"]["registration"].as_f64().unwrap() > 0.0, "{stdout}");
    assert!(out["rotation_deg"].is_null() && out["seconds"].is_null(), "old names: {stdout}");
}

/// `--procedural` is checked by clap, which lists the objects.
#[test]
fn procedural_names_are_checked_and_listed() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("x");
    let (ok, _, stderr) = flowfilter(&["synth", "--procedural", "sphere", "--out", out.to_str().unwrap()]);
    assert!(!ok && stderr.contains("'sphere'") && stderr.contains("box") && stderr.contains("bottle"), "{stderr}");
    assert!(!out.exists());
}

/// `--global`: a bumpy sheet and the same sheet turned by 40 degrees, far beyond ICP's reach
/// from identity; started from the global registration, ICP lands on the motion.
#[test]
fn a_global_start_reaches_a_40_degree_turn() {
    use flowfilter_depth::ply::{PlyFormat, write_ply};
    use flowfilter_geometry::{Point3, PointCloud, Pose};
    let points: Vec<Point3> = (0..6400)
        .map(|i| {
            let (x, y) = ((i % 80) as f64 * 0.0025, (i / 80) as f64 * 0.0025);
            Point3::new(x, y, 0.6 + 0.01 * (x * 40.0).sin() * (y * 30.0).cos())
        })
        .collect();
    let truth =
        Pose::new(nalgebra::Vector3::new(0.05, 0.0, 0.02), nalgebra::Vector3::new(0.0, 40f64.to_radians(), 0.0));
    let tmp = tempfile::tempdir().unwrap();
    let (s, t) = (tmp.path().join("source.ply"), tmp.path().join("target.ply"));
    write_ply(&PointCloud::from_points(points.clone()), &s, PlyFormat::BinaryLittleEndian).unwrap();
    write_ply(&PointCloud::from_points(points.iter().map(|p| truth * p).collect()), &t, PlyFormat::BinaryLittleEndian)
        .unwrap();
    let (s, t) = (s.to_str().unwrap(), t.to_str().unwrap());
    let turn_error = |extra: &[&str]| {
        let mut args = vec!["register", "--source", s, "--target", t, "--method", "icp-pt2pl", "--json"];
        args.extend(extra);
        // From identity the answer is implausible, and the exit code says so (3).
        let (_, stdout, stderr) = flowfilter(&args);
        let out: serde_json::Value =
            serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("{extra:?}: {e}: {stderr}"));
        let m = nalgebra::Matrix3::from_fn(|r, c| out["transform"][r][c].as_f64().unwrap());
        let r = nalgebra::Rotation3::from_matrix_unchecked(m);
        ((r.inverse() * truth.rotation.to_rotation_matrix()).angle().to_degrees(), stderr)
    };
    let (from_identity, _) = turn_error(&[]);
    assert!(from_identity > 10.0, "ICP from identity: {from_identity} deg");
    let (global, stderr) = turn_error(&["--global"]);
    assert!(global < 0.5, "from the global start: {global} deg");
    assert!(stderr.contains("global start:") && stderr.contains("descriptor matches agree"), "{stderr}");
    // Conflicting or bad arguments are refused.
    let (ok, _, stderr) = flowfilter(&["register", "--source", s, "--target", t, "--global", "--global-voxel=-1"]);
    assert!(!ok && stderr.contains("--global-voxel"), "{stderr}");
    let (ok, _, stderr) = flowfilter(&["register", "--source", s, "--target", t, "--global", "--init", s]);
    assert!(!ok && stderr.contains("cannot be used with"), "{stderr}");
}
