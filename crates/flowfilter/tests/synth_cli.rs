//! `flowfilter synth` writes a capture that `flowfilter inspect` accepts; bad options fail clearly.

use std::process::Command;

fn flowfilter(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_flowfilter")).args(args).output().unwrap();
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

#[test]
fn synth_then_inspect() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("can");
    let sheet = tmp.path().join("sheet.png");
    let (ok, stdout, stderr) = flowfilter(&[
        "synth",
        "--procedural",
        "can",
        "--out",
        out.to_str().unwrap(),
        "--cameras",
        "NP2,NP5",
        "--angles",
        "0:6:3",
        "--noise",
        "none",
        "--seed",
        "4",
        "--contact-sheet",
        sheet.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("wrote 6 frames (2 camera(s) x 3 angle(s))"), "{stdout}");
    assert!(image::open(&sheet).is_ok());
    let (ok, stdout, stderr) = flowfilter(&["inspect", out.to_str().unwrap()]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("NP2:     3 frames, colour 1280x1024, depth 640x480"), "{stdout}");
    assert!(stdout.contains("calibration: 5 Carmine sensor(s)"), "{stdout}");
}

#[test]
fn synth_rejects_bad_options() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("x");
    let o = out.to_str().unwrap();
    for (args, needle) in [
        (vec!["synth", "--procedural", "teapot", "--out", o], "invalid value 'teapot' for '--procedural <PROCEDURAL>'"),
        (vec!["synth", "--procedural", "box", "--out", o, "--angles", "0:357:0"], "step must be > 0"),
        (vec!["synth", "--procedural", "box", "--out", o, "--angles", "10:400:3"], "not in 0..360"),
        (vec!["synth", "--procedural", "box", "--out", o, "--cameras", "NP7"], "'NP7' is not a sensor name"),
        (vec!["synth", "--procedural", "box", "--out", o, "--noise", "/no/profile.toml"], "/no/profile.toml"),
        (vec!["synth", "--mesh", "/no/mesh.obj", "--out", o], "/no/mesh.obj"),
    ] {
        let (ok, _, stderr) = flowfilter(&args);
        assert!(!ok, "{args:?} should fail");
        assert!(stderr.contains(needle), "{args:?}: '{needle}' not in {stderr}");
    }
    let (ok, _, stderr) = flowfilter(&["synth", "--out", o]);
    assert!(!ok && stderr.contains("--mesh"), "{stderr}");
}

/// `synth --format bop` writes a BOP scene per camera; `estimate` takes its files (the whole
/// `scene_camera.json` as the camera file) with every method, and `--gt` scores them.
#[test]
fn synth_bop_then_estimate_with_every_method() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("test");
    let (ok, stdout, stderr) = flowfilter(&[
        "synth",
        "--format",
        "bop",
        "--procedural",
        "box",
        "--out",
        out.to_str().unwrap(),
        "--cameras",
        "NP3",
        "--angles",
        "0,0.5,5",
        "--obj-id",
        "12",
    ]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("wrote 1 BOP scene(s) of 3 image(s) (object 12"), "{stdout}");
    let scene = out.join("000003");
    let gt: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(scene.join("scene_gt.json")).unwrap()).unwrap();
    // T_ab = T_b * inv(T_a) from cam_R_m2c and cam_t_m2c (millimetres).
    let pose = |im: &str| {
        let e = &gt[im][0];
        assert_eq!(e["obj_id"], 12);
        let r = |i: usize| e["cam_R_m2c"][i].as_f64().unwrap();
        let t = |i: usize| e["cam_t_m2c"][i].as_f64().unwrap() * 1e-3;
        nalgebra::Matrix4::new(r(0), r(1), r(2), t(0), r(3), r(4), r(5), t(1), r(6), r(7), r(8), t(2), 0., 0., 0., 1.)
    };
    let truth = pose("2") * pose("0").try_inverse().unwrap();
    let gt_file = tmp.path().join("gt.json");
    let rows: Vec<Vec<f64>> = (0..4).map(|r| (0..4).map(|c| truth[(r, c)]).collect()).collect();
    std::fs::write(&gt_file, serde_json::json!({ "transform": rows }).to_string()).unwrap();
    let f = |rel: &str| scene.join(rel).to_str().unwrap().to_string();
    for method in ["flowfilter", "filterreg-pt2pt", "icp-pt2pl", "cpd"] {
        let (ok, stdout, stderr) = flowfilter(&[
            "estimate",
            "--model-color",
            &f("rgb/000000.png"),
            "--model-depth",
            &f("depth/000000.png"),
            "--model-mask",
            &f("mask_visib/000000_000000.png"),
            "--target-color",
            &f("rgb/000002.png"),
            "--target-depth",
            &f("depth/000002.png"),
            "--target-mask",
            &f("mask_visib/000002_000000.png"),
            "--camera",
            &f("scene_camera.json"),
            "--gt",
            gt_file.to_str().unwrap(),
            "--method",
            method,
            "--json",
        ]);
        assert!(ok, "{method}: {stderr}");
        let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
        let errors = &v["ground_truth"]["errors"];
        let geodesic = errors["geodesic_error_deg"].as_f64().unwrap();
        assert!(geodesic.is_finite(), "{method}: {errors}");
        if method == "flowfilter" {
            assert!(geodesic < 1.0 && errors["translation_error_m"].as_f64().unwrap() < 0.01, "{errors}");
        }
    }
}
