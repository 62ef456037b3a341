//! `flowfilter flow` on a pair with known motion, and bad input.

use flowfilter_flow::{FlowField, flo};
use image::{GrayImage, Luma};
use std::process::Command;

fn flowfilter(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_flowfilter")).args(args).output().unwrap();
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

fn pattern(w: u32, h: u32, shift: (f32, f32)) -> GrayImage {
    GrayImage::from_fn(w, h, |x, y| {
        let (u, v) = (x as f32 - shift.0, y as f32 - shift.1);
        let s = 0.5
            + 0.2 * (u * 0.21).sin() * (v * 0.17).cos()
            + 0.15 * ((u + 2.0 * v) * 0.093).sin()
            + 0.1 * ((3.0 * u - v) * 0.051).cos();
        Luma([(s * 255.0).round().clamp(0.0, 255.0) as u8])
    })
}

#[test]
fn dense_flow_of_a_translation_with_epe_and_outputs() {
    let tmp = tempfile::tempdir().unwrap();
    let p = |n: &str| tmp.path().join(n);
    pattern(200, 150, (0.0, 0.0)).save(p("a.png")).unwrap();
    pattern(200, 150, (2.5, -1.5)).save(p("b.png")).unwrap();
    let mut gt = FlowField::zeros(200, 150);
    gt.flow.as_mut_slice().iter_mut().for_each(|f| *f = [2.5, -1.5]);
    flo::write(&gt, &p("gt.flo")).unwrap();
    for method in ["dis", "lk"] {
        let (ok, stdout, stderr) = flowfilter(&[
            "flow",
            "--from",
            p("a.png").to_str().unwrap(),
            "--to",
            p("b.png").to_str().unwrap(),
            "--method",
            method,
            "--gt",
            p("gt.flo").to_str().unwrap(),
            "--out",
            p("out.flo").to_str().unwrap(),
            "--viz",
            p("viz.png").to_str().unwrap(),
        ]);
        assert!(ok, "{method}: {stderr}");
        let epe: f64 = stdout.split("EPE ").nth(1).unwrap().split_whitespace().next().unwrap().parse().unwrap();
        assert!(epe < 0.15, "{method}: EPE {epe}\n{stdout}");
        assert_eq!(flo::read(&p("out.flo")).unwrap().width(), 200);
        assert_eq!(image::open(p("viz.png")).unwrap().width(), 200);
    }
}

#[test]
fn mismatched_sizes_and_unknown_methods_are_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let p = |n: &str| tmp.path().join(n);
    pattern(200, 150, (0.0, 0.0)).save(p("a.png")).unwrap();
    pattern(100, 150, (0.0, 0.0)).save(p("b.png")).unwrap();
    let (a, b) = (p("a.png"), p("b.png"));
    let (ok, _, err) = flowfilter(&["flow", "--from", a.to_str().unwrap(), "--to", b.to_str().unwrap()]);
    assert!(!ok && err.contains("image sizes differ"), "{err}");
    let (ok, _, err) =
        flowfilter(&["flow", "--from", a.to_str().unwrap(), "--to", a.to_str().unwrap(), "--method", "farneback"]);
    assert!(!ok && err.contains("farneback"), "{err}");
}

#[cfg(feature = "onnx")]
#[test]
fn onnx_networks_run_from_the_cli() {
    let models = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/models");
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("net.flo");
    let method = format!("onnx:{}", models.join("tiny_warp.onnx").display());
    let (ok, stdout, stderr) = flowfilter(&[
        "flow",
        "--from",
        models.join("pair_a.png").to_str().unwrap(),
        "--to",
        models.join("pair_b.png").to_str().unwrap(),
        "--method",
        &method,
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("onnx:tiny_warp.onnx: 64x48"), "{stdout}");
    assert_eq!(flo::read(&out).unwrap().width(), 64);
}

/// `truth-flow` of the procedural box, NP3, 0 -> 3 degrees, into `dir`.
fn box_pair(dir: &std::path::Path) -> String {
    let d = dir.to_str().unwrap().to_string();
    let (ok, stdout, stderr) =
        flowfilter(&["truth-flow", "--procedural", "box", "--camera", "NP3", "--from", "0", "--to", "3", "--out", &d]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("object pixels"), "{stdout}");
    d
}

/// `flow --method METHOD` on a `truth-flow` directory with its exact flow and occlusion:
/// success, stdout, stderr and the non-occluded EPE when printed.
fn score(d: &str, method: &str) -> (bool, String, String, Option<f64>) {
    let (ok, stdout, stderr) = flowfilter(&[
        "flow",
        "--from",
        &format!("{d}/from.png"),
        "--to",
        &format!("{d}/to.png"),
        "--method",
        method,
        "--gt",
        &format!("{d}/flow.flo"),
        "--occlusion",
        &format!("{d}/occlusion.png"),
    ]);
    let epe = stdout
        .split("EPE (non-occluded) ")
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .and_then(|v| v.parse().ok());
    (ok, stdout, stderr, epe)
}

/// `truth-flow` writes a synthetic pair with its exact flow and occlusion; `flow --gt
/// --occlusion` scores an estimator on it (the project's own flow benchmark domain).
#[test]
fn truth_flow_pair_scores_dense_flow() {
    let tmp = tempfile::tempdir().unwrap();
    let d = box_pair(&tmp.path().join("box"));
    let truth = flo::read(&std::path::Path::new(&d).join("flow.flo")).unwrap();
    assert_eq!((truth.width(), truth.height()), (1280, 1024));
    let valid = truth.valid.as_slice().iter().filter(|&&v| v).count();
    assert!(valid > 10_000, "{valid}");
    // The box turns 3 degrees: its pixels move by a few pixels, not by zero and not by many.
    let mean: f32 = truth
        .flow
        .as_slice()
        .iter()
        .zip(truth.valid.as_slice())
        .filter(|(_, v)| **v)
        .map(|(f, _)| f[0].hypot(f[1]))
        .sum::<f32>()
        / valid as f32;
    assert!(mean > 0.5 && mean < 20.0, "mean flow {mean}");
    let (ok, stdout, stderr, epe) = score(&d, "dis");
    assert!(ok, "{stderr}");
    assert!(epe.is_some_and(|e| e < 1.0), "DIS on a 3-degree turn\n{stdout}");
    // A half turn hides most of what the first view saw.
    let (ok, stdout, stderr) = flowfilter(&[
        "truth-flow",
        "--procedural",
        "box",
        "--from",
        "0",
        "--to",
        "180",
        "--out",
        tmp.path().join("half").to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    let occluded: f64 = stdout.split(", ").nth(1).unwrap().split('%').next().unwrap().parse().unwrap();
    assert!(occluded > 60.0, "{stdout}");
}

/// `--method net` runs our shipped network in `onnx` builds and is a clear error without it.
#[test]
fn method_net_runs_the_shipped_network_or_names_the_feature() {
    let tmp = tempfile::tempdir().unwrap();
    let d = box_pair(&tmp.path().join("box"));
    let (ok, stdout, stderr, epe) = score(&d, "net");
    if cfg!(feature = "onnx") {
        assert!(ok, "{stderr}");
        assert!(epe.is_some_and(|e| e < NET_EPE_BOUND), "net on a 3-degree turn\n{stdout}");
    } else {
        assert!(!ok);
        assert!(stderr.contains("onnx") && stderr.contains("feature"), "{stderr}");
    }
}

/// Bound on the network's EPE for the 3-degree box pair above (0.45 px when the model was
/// trained; DIS-medium: 0.24 px; see crates/flowfilter-flow/models/MODEL_CARD.md).
const NET_EPE_BOUND: f64 = 1.0;
