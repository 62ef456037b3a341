//! `flowfilter track` on a shared real sequence (whole frames, with the calibrated poses as the
//! truth; skipped without ../shared), its JSON lines and TUM trajectory, and a bad stream.

use std::path::{Path, PathBuf};
use std::process::Command;

fn flowfilter(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_flowfilter")).args(args).output().unwrap();
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

fn shelf() -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/realsense-shelf/shelf-D");
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!("skipping: {} is absent (the real-frame tests need ../shared)", dir.display());
        None
    }
}

/// The rows of a `--json` file (one JSON object per line).
fn json_lines(path: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(path).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect()
}

#[test]
fn a_real_sequence_is_tracked_with_json_lines_and_a_tum_trajectory() {
    let Some(dir) = shelf() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let (json, tum, viz) = (tmp.path().join("track.jsonl"), tmp.path().join("track.tum"), tmp.path().join("viz"));
    let d = dir.to_str().unwrap();
    let camera = format!("{d}/camera.json");
    let gt = format!("{d}/poses.json");
    let (ok, stdout, stderr) = flowfilter(&[
        "track",
        "--frames",
        d,
        "--camera",
        &camera,
        "--gt",
        &gt,
        "--max-frames",
        "5",
        "--json",
        json.to_str().unwrap(),
        "--tum",
        tum.to_str().unwrap(),
        "--viz",
        viz.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("5 frames: ") && stdout.contains("vs ground truth (5 frames): ATE"), "{stdout}");
    assert!(stdout.contains("frames per second after the first (4 in "), "{stdout}");
    let rows = json_lines(&json);
    assert_eq!(rows.len(), 5);
    assert_eq!(rows[0]["state"], "tracking");
    assert_eq!(rows[0]["keyframe"], true);
    for r in &rows[1..] {
        assert_eq!(r["state"], "tracking", "{r}");
        assert!(r["estimate"]["transform"].is_array() && r["reference"].is_u64());
        // Frames 10-15 deg apart, four of them: each within 2 deg of the calibrated truth.
        assert!(r["errors"]["rotation_deg"].as_f64().unwrap() < 2.0, "{r}");
    }
    let lines: Vec<String> = std::fs::read_to_string(&tum).unwrap().lines().map(String::from).collect();
    assert!(lines[0].starts_with('#'));
    assert_eq!(lines.len(), 6);
    let first: Vec<f64> = lines[1].split_whitespace().map(|v| v.parse().unwrap()).collect();
    assert_eq!(first, vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
    let last: Vec<f64> = lines[5].split_whitespace().map(|v| v.parse().unwrap()).collect();
    assert!((last[0] - 4.0 / 30.0).abs() < 1e-6, "timestamps are frame number / fps");
    // An overlay per frame, the moved cloud drawn in green.
    let overlay = image::open(viz.join("frame-000004.png")).unwrap().to_rgb8();
    assert!(overlay.pixels().filter(|p| p.0 == [40, 230, 60]).count() > 500);
    assert_eq!(std::fs::read_dir(&viz).unwrap().count(), 5);
    let q = (last[4] * last[4] + last[5] * last[5] + last[6] * last[6] + last[7] * last[7]).sqrt();
    assert!((q - 1.0).abs() < 1e-6);
}

#[test]
fn a_missing_depth_file_is_a_lost_frame_not_a_crash() {
    let Some(dir) = shelf() else { return };
    let tmp = tempfile::tempdir().unwrap();
    for n in 0..3 {
        for kind in ["color", "depth"] {
            if (n, kind) == (1, "depth") {
                continue;
            }
            let name = format!("frame-{n:06}.{kind}.png");
            std::fs::copy(dir.join(&name), tmp.path().join(&name)).unwrap();
        }
    }
    std::fs::write(tmp.path().join("notes.txt"), "ignored").unwrap();
    let json = tmp.path().join("t.jsonl");
    let camera = dir.join("camera.json");
    let (ok, stdout, stderr) = flowfilter(&[
        "track",
        "--frames",
        tmp.path().to_str().unwrap(),
        "--camera",
        camera.to_str().unwrap(),
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    let rows = json_lines(&json);
    assert_eq!(rows.len(), 3, "{stdout}");
    assert_eq!(rows[1]["state"], "lost");
    assert!(rows[1]["reason"].as_str().unwrap().contains("frame-000001.depth.png"), "{}", rows[1]);
    // The first frame's pose is exact; a lost frame's held pose has no bounds.
    assert_eq!(rows[0]["bound_from_first"], serde_json::json!({"rotation_deg": 0.0, "translation_m": 0.0}));
    assert!(rows[1]["bound_from_first"].is_null(), "{}", rows[1]);
    // Frame 2 is matched against the keyframes again (frame 0, 25 deg away).
    assert!(["recovered", "uncertain", "lost"].contains(&rows[2]["state"].as_str().unwrap()));
}

#[test]
fn bad_arguments_are_reported() {
    let tmp = tempfile::tempdir().unwrap();
    let empty = tmp.path().to_str().unwrap();
    let camera = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/bop/000001/scene_camera.json");
    let (ok, _, stderr) = flowfilter(&["track", "--frames", empty, "--camera", camera.to_str().unwrap()]);
    assert!(!ok && stderr.contains("no RGB-D frames"), "{stderr}");
    let (ok, _, stderr) = flowfilter(&["track", "--frames", empty, "--camera", camera.to_str().unwrap(), "--fps", "0"]);
    assert!(!ok && stderr.contains("--fps"), "{stderr}");
    let rrd = tmp.path().join("t.rrd");
    let (ok, _, stderr) = flowfilter(&[
        "track",
        "--frames",
        empty,
        "--camera",
        camera.to_str().unwrap(),
        "--rerun",
        rrd.to_str().unwrap(),
    ]);
    let expected = if cfg!(feature = "rerun") { "no RGB-D frames" } else { "--features rerun" };
    assert!(!ok && stderr.contains(expected), "{stderr}");
}

#[test]
fn an_image_list_with_a_box_around_the_object() {
    let Some(dir) = shelf() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let d = dir.to_str().unwrap();
    // TUM's associated list: the colour timestamps are kept in the trajectory.
    let list = tmp.path().join("associate.txt");
    let lines: Vec<String> = (0..3)
        .map(|n| {
            let t = 100.0 + 0.5 * f64::from(n);
            format!("{t:.3} {d}/frame-{n:06}.color.png {:.3} {d}/frame-{n:06}.depth.png", t + 0.01)
        })
        .collect();
    std::fs::write(&list, format!("# color depth\n{}\n", lines.join("\n"))).unwrap();
    let (json, tum) = (tmp.path().join("track.jsonl"), tmp.path().join("track.tum"));
    let (camera, gt) = (format!("{d}/camera.json"), format!("{d}/poses.json"));
    let (ok, _, stderr) = flowfilter(&[
        "track",
        "--frames",
        list.to_str().unwrap(),
        "--camera",
        &camera,
        "--box",
        "220,140,200,200",
        "--gt",
        &gt,
        "--json",
        json.to_str().unwrap(),
        "--tum",
        tum.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    let rows = json_lines(&json);
    assert_eq!(rows.len(), 3);
    // The box's pixels at the object's depth: a region, not the whole frame.
    let first_px = rows[0]["mask_px"].as_u64().unwrap();
    assert!(first_px > 10_000 && first_px <= 200 * 200, "{}", rows[0]);
    for r in &rows[1..] {
        assert_eq!(r["state"], "tracking", "{r}");
        // A region 12 and 25 deg from the first frame: real regions land 1-2 deg off per link
        // (docs/real.md), the second frame's pose chains two.
        assert!(r["errors"]["rotation_deg"].as_f64().unwrap() < 3.0, "{r}");
    }
    let stamps: Vec<f64> = std::fs::read_to_string(&tum)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split_whitespace().next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(stamps, vec![100.0, 100.5, 101.0]);
    // A box outside the image, and a malformed one.
    for (bad, expected) in [("600,400,100,100", "inside the 640x480 image"), ("1,2,3", "X,Y,W,H")] {
        let (ok, _, stderr) =
            flowfilter(&["track", "--frames", list.to_str().unwrap(), "--camera", &camera, "--box", bad]);
        assert!(!ok && stderr.contains(expected), "{stderr}");
    }
    // A list line of another shape is named.
    std::fs::write(&list, "a.png\n").unwrap();
    let (ok, _, stderr) = flowfilter(&["track", "--frames", list.to_str().unwrap(), "--camera", &camera]);
    assert!(!ok && stderr.contains("associate.txt:1") && stderr.contains("COLOR DEPTH"), "{stderr}");
}

#[test]
fn a_bop_scene_object_is_tracked_with_its_annotations_as_the_truth() {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/bop/000001");
    let tmp = tempfile::tempdir().unwrap();
    let json = tmp.path().join("track.jsonl");
    let (ok, stdout, stderr) =
        flowfilter(&["track", "--bop", scene.to_str().unwrap(), "--object", "7", "--json", json.to_str().unwrap()]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("vs ground truth (3 frames)"), "{stdout}");
    let rows = json_lines(&json);
    assert_eq!(rows.iter().map(|r| r["frame"].as_u64().unwrap()).collect::<Vec<_>>(), [0, 1, 2]);
    for r in &rows[1..] {
        assert_eq!(r["state"], "tracking", "{r}");
        assert!(r["errors"]["rotation_deg"].as_f64().unwrap() < 1.0, "{r}");
        // Bounds on the pose from the first frame: at least the estimate's own.
        let (bound, own) = (&r["bound_from_first"]["rotation_deg"], &r["estimate"]["registration"]["uncertainty"]);
        assert!(bound.as_f64().unwrap() >= own["rotation_deg"].as_f64().unwrap(), "{r}");
    }
    // The tracker's settings from a file: the aligned path on (the first motion has nothing to
    // be predicted from); a key the tracker does not have is refused, naming the file.
    let settings = tmp.path().join("tracker.toml");
    std::fs::write(&settings, "aligned_path = true\n").unwrap();
    let s = settings.to_str().unwrap();
    let args = ["track", "--bop", scene.to_str().unwrap(), "--object", "7", "--json", json.to_str().unwrap()];
    let (ok, _, stderr) = flowfilter(&[&args[..], &["--tracker", s]].concat());
    assert!(ok, "{stderr}");
    let rows = json_lines(&json);
    assert!(rows[1..].iter().all(|r| r["state"] == "tracking"), "{rows:?}");
    assert_eq!(rows[1]["aligned_only"], false, "{}", rows[1]);
    std::fs::write(&settings, "aligned_paths = true\n").unwrap();
    let (ok, _, stderr) = flowfilter(&[&args[..], &["--tracker", s]].concat());
    assert!(!ok && stderr.contains("--tracker") && stderr.contains("aligned_paths"), "{stderr}");
    // An object the scene does not annotate, and --bop without --object.
    let (ok, _, stderr) = flowfilter(&["track", "--bop", scene.to_str().unwrap(), "--object", "1"]);
    assert!(!ok && stderr.contains("object 1 is annotated in none"), "{stderr}");
    let (ok, _, stderr) = flowfilter(&["track", "--bop", scene.to_str().unwrap()]);
    assert!(!ok && stderr.contains("--object"), "{stderr}");
}
