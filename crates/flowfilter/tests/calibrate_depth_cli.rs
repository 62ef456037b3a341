//! `flowfilter calibrate-depth` on a shared real sequence (skipped without ../shared): the field
//! it writes explains part of the depth differences between views and is applied to every
//! frame read with the camera file; a field of the wrong size is refused by name.

mod common;

use common::{flowfilter, shared_data};
use std::path::{Path, PathBuf};

fn shelf(name: &str) -> Option<PathBuf> {
    shared_data(&format!("realsense-shelf/{name}"))
}

fn read_json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// Calibrate the first six frames of `dir` with `camera`; the written camera file and report.
fn calibrate(dir: &Path, camera: &Path, out: &Path) -> (serde_json::Value, serde_json::Value) {
    let report = out.with_extension("report.json");
    let (ok, _, stderr) = flowfilter(&[
        "calibrate-depth",
        "--frames",
        dir.to_str().unwrap(),
        "--camera",
        camera.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--max-frames",
        "6",
        "--json",
        report.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    assert!(stderr.contains("consecutive pairs used"), "{stderr}");
    (read_json(out), read_json(&report))
}

fn field(camera: &serde_json::Value) -> Vec<f64> {
    camera["depth_bias"]["metres"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect()
}

#[test]
fn a_real_stream_calibrates_its_depth_sensor() {
    let Some(held_out) = shelf("shelf-J") else { return };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("camera-j.json");
    let (camera, report) = calibrate(&held_out, &held_out.join("camera.json"), &out);
    // The input's keys are kept; the field spans the depth camera's 640x480 image.
    assert!(camera["K"].is_array() && camera["color_from_depth"].is_array());
    assert_eq!((camera["depth_bias"]["cols"].as_u64(), camera["depth_bias"]["rows"].as_u64()), (Some(32), Some(24)));
    assert_eq!(camera["depth_bias"]["width"].as_u64(), Some(640));
    let pairs = report["pairs"].as_array().unwrap();
    assert_eq!(pairs.len(), 5, "{report}");
    assert!(pairs.iter().all(|p| p["left_out"].is_null()), "{report}");
    let (before, after) = (report["rms_before_m"].as_f64().unwrap(), report["rms_after_m"].as_f64().unwrap());
    assert!(after < 0.95 * before, "{before} -> {after}");
    // Frames read with the written camera file are corrected: a second calibration finds less.
    let (again, second) = calibrate(&held_out, &out, &tmp.path().join("camera-j2.json"));
    let second_before = second["rms_before_m"].as_f64().unwrap();
    assert!(second_before < 0.97 * before, "{before} -> {second_before}");
    assert_eq!(field(&again).len(), 32 * 24);
}

#[test]
fn a_depth_bias_of_another_size_is_refused_by_name() {
    let Some(dir) = shelf("shelf-J") else { return };
    let tmp = tempfile::tempdir().unwrap();
    let mut camera = read_json(&dir.join("camera.json"));
    camera["depth_bias"] = serde_json::json!({"cols": 1, "rows": 1, "width": 320, "height": 240, "metres": [0.001]});
    let path = tmp.path().join("camera.json");
    std::fs::write(&path, camera.to_string()).unwrap();
    let d = dir.to_str().unwrap();
    let (ok, _, stderr) = flowfilter(&[
        "estimate",
        "--camera",
        path.to_str().unwrap(),
        "--model-color",
        &format!("{d}/frame-000000.color.png"),
        "--model-depth",
        &format!("{d}/frame-000000.depth.png"),
        "--target-color",
        &format!("{d}/frame-000001.color.png"),
        "--target-depth",
        &format!("{d}/frame-000001.depth.png"),
    ]);
    assert!(!ok);
    assert!(stderr.contains("320x240") && stderr.contains("640x480") && stderr.contains("depth_bias"), "{stderr}");
}
