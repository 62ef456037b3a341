//! The bad-input suite: every kind of input that once came out wrong without a word, and the
//! categories behind them, through the CLI. Each case asserts the exit code, that nothing
//! panicked, and the key words of the message (the file or field, and what to do).
//!
//! Exit codes (docs/limits.md): 0 success, 1 error (bad input, configuration, I/O), 2 usage
//! (arguments), 3 an estimate the data do not support.

use flowfilter_bigbird::{BigBirdObject, FrameId, H5Format, ObjectWriter, SensorId};
use flowfilter_depth::ply::{PlyFormat, write_ply};
use flowfilter_geometry::{Mask, Point3, PointCloud, Pose, RawDepth, Vector3};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

/// Run the CLI: (exit code, stdout, stderr); a panic fails the test.
fn run(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_flowfilter")).args(args).output().unwrap();
    let (stdout, stderr) =
        (String::from_utf8_lossy(&out.stdout).into_owned(), String::from_utf8_lossy(&out.stderr).into_owned());
    assert!(!stderr.contains("panicked"), "panic for {args:?}: {stderr}");
    let code = out.status.code().expect("exited, not killed");
    assert_ne!(code, 101, "panic exit for {args:?}: {stderr}");
    (code, stdout, stderr)
}

/// `run`, asserting the exit code and that stderr holds every key word.
fn expect(args: &[&str], code: i32, words: &[&str]) -> String {
    let (c, stdout, stderr) = run(args);
    assert_eq!(c, code, "{args:?}\nstdout: {stdout}\nstderr: {stderr}");
    for w in words {
        assert!(stderr.contains(w), "{args:?}: '{w}' missing from: {stderr}");
    }
    no_repeated_cause(&stderr);
    stderr
}

/// An error's causes are printed once ("... found 0: ... found 0" was a bug).
fn no_repeated_cause(stderr: &str) {
    for line in stderr.lines().filter(|l| l.starts_with("error: ")) {
        let parts: Vec<&str> = line.trim_start_matches("error: ").split(": ").filter(|p| p.len() > 12).collect();
        for (i, p) in parts.iter().enumerate() {
            assert!(!parts[i + 1..].contains(p), "cause printed twice: {line}");
        }
    }
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A box captured by NP3 at 0 and 15 degrees (rendered once per test binary).
fn capture() -> &'static Path {
    static DIR: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    &DIR.get_or_init(|| {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("box");
        let (c, _, err) =
            run(&["synth", "--procedural", "box", "--out", s(&out), "--cameras", "NP3", "--angles", "0:15:15"]);
        assert_eq!(c, 0, "synth: {err}");
        (tmp, out)
    })
    .1
}

/// A private copy of the capture, to damage.
fn copy_of_capture(tmp: &Path) -> PathBuf {
    fn copy(from: &Path, to: &Path) {
        std::fs::create_dir_all(to).unwrap();
        for e in std::fs::read_dir(from).unwrap() {
            let p = e.unwrap().path();
            let dest = to.join(p.file_name().unwrap());
            if p.is_dir() { copy(&p, &dest) } else { std::fs::copy(&p, &dest).map(|_| ()).unwrap() }
        }
    }
    let dir = tmp.join("box");
    copy(capture(), &dir);
    dir
}

fn estimate_args(dir: &Path) -> Vec<String> {
    ["estimate", "--object", s(dir), "--camera", "NP3", "--from", "0", "--to", "15"].map(String::from).to_vec()
}

fn with_estimate_args<R>(dir: &Path, extra: &[&str], f: impl FnOnce(&[&str]) -> R) -> R {
    let mut args = estimate_args(dir);
    args.extend(extra.iter().map(|a| a.to_string()));
    f(&args.iter().map(String::as_str).collect::<Vec<_>>())
}

/// `estimate` on NP3 0 -> 15 of `dir` with `extra` arguments, asserting code and key words.
fn estimate(dir: &Path, extra: &[&str], code: i32, words: &[&str]) -> String {
    with_estimate_args(dir, extra, |args| expect(args, code, words))
}

/// `estimate` on NP3 0 -> 15 of `dir` with `extra` arguments.
fn run_estimate(dir: &Path, extra: &[&str]) -> (i32, String, String) {
    with_estimate_args(dir, extra, run)
}

/// A box-shaped cloud of `n` points (no normals) at 0.6 m.
fn box_cloud(n: usize) -> PointCloud {
    let points = (0..n)
        .map(|i| {
            let (face, u, v) =
                (i % 6, ((i * 7919) % 997) as f64 / 498.5 - 1.0, ((i * 104729) % 991) as f64 / 495.5 - 1.0);
            let mut p = [0.0; 3];
            p[face / 2] = if face % 2 == 0 { 1.0 } else { -1.0 };
            p[(face / 2 + 1) % 3] = u;
            p[(face / 2 + 2) % 3] = v;
            Point3::new(p[0] * 0.05, p[1] * 0.03, p[2] * 0.08 + 0.6)
        })
        .collect();
    PointCloud::from_points(points)
}

fn write_cloud(path: &Path, cloud: &PointCloud) {
    write_ply(cloud, path, PlyFormat::BinaryLittleEndian).unwrap();
}

fn rotated(cloud: &PointCloud, deg: f64, offset: Vector3) -> PointCloud {
    let pose = Pose::from_parts(offset.into(), nalgebra::UnitQuaternion::from_euler_angles(0.0, 0.0, deg.to_radians()));
    cloud.transformed(&pose)
}

// ---- 1. limits ----

#[test]
fn cpd_above_its_work_limit_runs_on_a_subset_with_a_warning() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b, cfg) = (tmp.path().join("a.ply"), tmp.path().join("b.ply"), tmp.path().join("cpd.toml"));
    let cloud = box_cloud(3000);
    write_cloud(&a, &cloud);
    write_cloud(&b, &rotated(&cloud, 5.0, Vector3::zeros()));
    std::fs::write(&cfg, "[cpd]\nmax_points = 800\nmax_iterations = 20\n").unwrap();
    expect(
        &["register", "--method", "cpd", "--source", s(&a), "--target", s(&b), "--config", s(&cfg)],
        0,
        &["3000 points, above CPD's work limit of 800", "max_points"],
    );
}

// ---- 2. results the geometry does not support ----

#[test]
fn clouds_far_apart_give_a_warning_and_exit_code_3() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a.ply"), tmp.path().join("b.ply"));
    let cloud = box_cloud(2000);
    write_cloud(&a, &cloud);
    write_cloud(&b, &rotated(&cloud, 38.0, Vector3::new(1000.0, 0.0, 0.0)));
    for method in ["filterreg-pt2pt", "icp-pt2pt", "cpd"] {
        let err = expect(
            &["register", "--method", method, "--source", s(&a), "--target", s(&b), "--json"],
            3,
            &["not trustworthy"],
        );
        let _ = err;
        let (_, stdout, _) = run(&["register", "--method", method, "--source", s(&a), "--target", s(&b), "--json"]);
        let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
        assert_eq!(v["registration"]["converged"], false, "{method}");
        let codes: Vec<&str> = v["warnings"].as_array().unwrap().iter().map(|w| w["code"].as_str().unwrap()).collect();
        assert!(codes.contains(&"far_apart"), "{method}: {codes:?}");
        assert!(!stdout.contains("null") && !stdout.contains("NaN"), "{stdout}");
    }
}

// ---- 3. NaN and out-of-range settings ----

#[test]
fn nan_infinite_and_out_of_range_settings_name_file_key_and_rule() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = capture();
    for (text, words) in [
        (
            "[registration.flowfilter]\ninlier_threshold_m = nan\n",
            ["registration.flowfilter.inlier_threshold_m", "finite"],
        ),
        ("[registration.filterreg]\ntolerance = nan\n", ["registration.filterreg.tolerance", "NaN"]),
        ("[registration.cpd]\nw = 1.5\n", ["registration.cpd.w", "in [0, 1)"]),
        ("[registration.flowfilter]\ncorrespondence_weight = -1\n", ["correspondence_weight", ">= 0"]),
        ("[cloud]\nvoxel_m = inf\n", ["cloud.voxel_m", "finite"]),
        ("[flow.lk]\nepsilon = -inf\n", ["flow.lk.epsilon", "finite"]),
    ] {
        let cfg = tmp.path().join("bad.toml");
        std::fs::write(&cfg, text).unwrap();
        let err = estimate(dir, &["--config", s(&cfg)], 1, &words);
        assert!(err.contains("bad.toml"), "{err}");
        assert!(!err.contains("--method must be"), "{err}");
    }
    // Bare backend tables for `register`.
    let cfg = tmp.path().join("reg.toml");
    std::fs::write(&cfg, "[icp]\nmax_correspondence_distance = nan\n").unwrap();
    let ply = tmp.path().join("c.ply");
    write_cloud(&ply, &box_cloud(100));
    expect(
        &["register", "--source", s(&ply), "--target", s(&ply), "--config", s(&cfg)],
        1,
        &["reg.toml", "icp.max_correspondence_distance"],
    );
    // Command-line numbers.
    let tf = tmp.path().join("tf");
    for (tolerance, rule) in [("nan", "finite"), ("0", "> 0")] {
        let args = ["truth-flow", "--procedural", "box", "--from", "0", "--to", "10", "--out", s(&tf)];
        expect(&[&args[..], &["--tolerance", tolerance]].concat(), 2, &["--tolerance", rule]);
    }
    assert!(!tmp.path().join("tf").exists());
}

// ---- 4. absurd but finite inputs ----

#[test]
fn a_pose_with_an_absurd_translation_is_refused_everywhere() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = copy_of_capture(tmp.path());
    let writer = ObjectWriter::create(&dir, H5Format::V110).unwrap();
    let object = BigBirdObject::open(&dir).unwrap();
    let mut pose = object.table_poses[&15].clone();
    pose.h_table_from_reference.translation.vector.x = 1e300;
    writer.write_table_pose(15, &pose).unwrap();
    expect(&["inspect", s(&dir)], 1, &["NP5_15_pose.h5", "translation", "beyond"]);
    estimate(&dir, &["--json"], 1, &["NP5_15_pose.h5", "translation"]);
    // A pose file given to --init or --gt.
    let init = tmp.path().join("init.txt");
    std::fs::write(&init, "1 0 0 1e300\n0 1 0 0\n0 0 1 0\n0 0 0 1\n").unwrap();
    let ply = tmp.path().join("c.ply");
    write_cloud(&ply, &box_cloud(200));
    expect(
        &["register", "--source", s(&ply), "--target", s(&ply), "--init", s(&init)],
        1,
        &["init.txt", "translation"],
    );
}

#[test]
fn absurd_calibration_is_refused_naming_the_field() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = copy_of_capture(tmp.path());
    let writer = ObjectWriter::create(&dir, H5Format::V110).unwrap();
    let good = BigBirdObject::open(&dir).unwrap().calibration;
    let mut cal = good.clone();
    cal.sensors.get_mut(&SensorId::ALL[2]).unwrap().rgb_k.fx = 1e300;
    writer.write_calibration(&cal).unwrap();
    expect(&["inspect", s(&dir)], 1, &["calibration.h5", "NP3_rgb_K", "fx"]);
    estimate(&dir, &[], 1, &["NP3_rgb_K", "fx"]);
    let mut cal = good.clone();
    cal.sensors.get_mut(&SensorId::ALL[2]).unwrap().ir_depth_scale = 1e-3;
    writer.write_calibration(&cal).unwrap();
    estimate(&dir, &[], 1, &["NP3_ir_depth_scale", "0.01, 100"]);
    // A bias is recorded, not applied: said, not silent.
    let mut cal = good;
    cal.sensors.get_mut(&SensorId::ALL[2]).unwrap().ir_depth_bias = 5.0;
    writer.write_calibration(&cal).unwrap();
    let (code, stdout, _) = run(&["inspect", s(&dir)]);
    assert_eq!(code, 0);
    assert!(stdout.contains("NP3_ir_depth_bias = 5 is not applied"), "{stdout}");
    estimate(&dir, &[], 0, &["NP3_ir_depth_bias = 5 is not applied"]);
}

#[test]
fn depth_out_of_range_empty_and_wrong_shape_are_named() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = copy_of_capture(tmp.path());
    let writer = ObjectWriter::create(&dir, H5Format::V110).unwrap();
    let id = FrameId { sensor: SensorId::ALL[2], angle: 15 };
    let depth = flowfilter_bigbird::read_depth(&id.depth_path(&dir)).unwrap();
    let (w, h) = depth.dims();
    writer.write_depth(id, &RawDepth::from_vec(w, h, vec![65535; w * h]).unwrap()).unwrap();
    estimate(&dir, &[], 1, &["frame NP3_15", "saturated", "65535"]);
    // Readings that are numbers but not depths: a unit 100 times too large puts the object at
    // tens of metres.
    let mut cal = BigBirdObject::open(&dir).unwrap().calibration;
    cal.sensors.get_mut(&SensorId::ALL[2]).unwrap().ir_depth_scale = 100.0;
    writer.write_calibration(&cal).unwrap();
    estimate(&dir, &[], 1, &["frame NP3_0", "the median depth is", "outside the 0.05-20 m", "depth unit"]);
    cal.sensors.get_mut(&SensorId::ALL[2]).unwrap().ir_depth_scale = 1.0;
    writer.write_calibration(&cal).unwrap();
    writer.write_depth(id, &RawDepth::from_vec(w, h, vec![0; w * h]).unwrap()).unwrap();
    estimate(&dir, &[], 1, &["frame NP3_15", "no reading"]);
    writer.write_depth(id, &RawDepth::from_vec(40, 30, vec![6000; 1200]).unwrap()).unwrap();
    let err = estimate(&dir, &[], 1, &["frame NP3_15", "depth image is 40x30", "wrong shape"]);
    assert!(!err.contains("cloud is empty"), "{err}");
}

#[test]
fn masks_empty_or_covering_the_image_are_reported() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = copy_of_capture(tmp.path());
    let writer = ObjectWriter::create(&dir, H5Format::V110).unwrap();
    let id = FrameId { sensor: SensorId::ALL[2], angle: 15 };
    let object = BigBirdObject::open(&dir).unwrap();
    let (w, h) = object.load_frame(id).unwrap().mask.dims();
    writer.write_mask(id, &Mask::from_fn(w, h, |_, _| true)).unwrap();
    // A target mask covering the image is a frame without a mask: the model's is propagated.
    let err =
        estimate(&dir, &["--json"], 0, &["frame NP3_15 came without an object mask", "model's mask was propagated"]);
    assert!(!err.contains("mask_covers_frame"), "{err}");
    writer.write_mask(id, &Mask::from_fn(w, h, |_, _| false)).unwrap();
    expect(&["inspect", s(&dir)], 1, &["NP3_15_mask.pbm", "mask is empty"]);
}

#[test]
fn coordinates_beyond_any_scene_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a.ply"), tmp.path().join("b.ply"));
    let cloud = box_cloud(300);
    write_cloud(&a, &cloud);
    let mut huge = cloud.clone();
    huge.points.iter_mut().for_each(|p| *p *= 1e30);
    write_cloud(&b, &huge);
    expect(&["register", "--source", s(&a), "--target", s(&b)], 1, &["target cloud", "beyond", "unit"]);
}

// ---- 5. synthesiser settings ----

#[test]
fn synth_refuses_nan_offsets() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("s");
    expect(&["synth", "--procedural", "box", "--offset", "nan,0", "--out", s(&out)], 2, &["--offset", "finite"]);
    expect(&["synth", "--procedural", "box", "--offset", "0.1", "--out", s(&out)], 2, &["two numbers"]);
    assert!(!out.exists());
    // The documented `dx,dy` form, negative values included.
    let (c, _, err) = run(&[
        "synth",
        "--procedural",
        "box",
        "--offset",
        "-0.01,0.02",
        "--cameras",
        "NP3",
        "--angles",
        "0",
        "--out",
        s(&out),
    ]);
    assert_eq!(c, 0, "{err}");
}

// ---- 6. partial outputs ----

#[test]
fn an_interrupted_capture_is_reported_incomplete_and_outputs_are_whole() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = copy_of_capture(tmp.path());
    let status = dir.join("capture-status.txt");
    assert!(std::fs::read_to_string(&status).unwrap().contains("status = complete"));
    // No temporary file is left behind by a finished writer.
    for e in std::fs::read_dir(&dir).unwrap() {
        assert!(!e.unwrap().file_name().to_string_lossy().contains(".partial"));
    }
    // What a killed synth leaves: the status written first, still incomplete.
    std::fs::write(&status, "flowfilter capture v1\nstatus = incomplete\nframes = 2\n").unwrap();
    expect(&["inspect", s(&dir)], 1, &["capture is incomplete", "write it again"]);
    // A truncated JPEG (as a writer killed mid-file would leave without atomic writes).
    std::fs::write(&status, "flowfilter capture v1\nstatus = complete\nframes = 2\n").unwrap();
    let jpg = dir.join("NP3_15.jpg");
    let bytes = std::fs::read(&jpg).unwrap();
    std::fs::write(&jpg, &bytes[..bytes.len() / 2]).unwrap();
    expect(&["inspect", s(&dir)], 1, &["NP3_15.jpg", "truncated"]);
}

#[test]
fn output_paths_are_checked_before_the_work() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("clouds");
    let err = estimate(capture(), &["--save-ply", s(&out), "--viz", "/proc/x.png"], 1, &["--viz", "/proc"]);
    assert!(!err.contains("vs ground truth"), "{err}");
    assert!(!out.join("model.ply").exists());
    expect(
        &["flow", "--from", "a.png", "--to", "b.png", "--out", "/no/such/dir/f.flo"],
        1,
        &["--out", "no such directory"],
    );
}

// ---- 7. messages that mislead ----

#[test]
fn messages_name_what_is_wrong() {
    let tmp = tempfile::tempdir().unwrap();
    // --object pointing at a file.
    let file = tmp.path().join("object.txt");
    std::fs::write(&file, "x").unwrap();
    expect(
        &["estimate", "--object", s(&file), "--camera", "NP3", "--from", "0", "--to", "15"],
        1,
        &["is a file, not an object directory"],
    );
    expect(&["inspect", s(&file)], 1, &["is a file"]);
    // Negative angles are parsed and explained.
    expect(
        &["estimate", "--object", s(capture()), "--camera", "NP3", "--from", "-3", "--to", "15"],
        2,
        &["0..360", "357"],
    );
    expect(
        &["truth-flow", "--procedural", "box", "--from", "-3", "--to", "10", "--out", s(&tmp.path().join("t"))],
        2,
        &["357"],
    );
    // Textureless images with a ground truth: the estimator found nothing, the sizes agree.
    let grey = image::RgbImage::from_pixel(64, 48, image::Rgb([128, 128, 128]));
    let (a, b, gt) = (tmp.path().join("a.png"), tmp.path().join("b.png"), tmp.path().join("gt.flo"));
    grey.save(&a).unwrap();
    grey.save(&b).unwrap();
    let mut truth = flowfilter_flow::FlowField::zeros(64, 48);
    truth.valid.as_mut_slice().iter_mut().for_each(|v| *v = true);
    flowfilter_flow::flo::write(&truth, &gt).unwrap();
    let err =
        expect(&["flow", "--from", s(&a), "--to", s(&b), "--method", "lk", "--gt", s(&gt)], 1, &["nothing to track"]);
    assert!(!err.contains("ground truth is 64x48"), "{err}");
}

// ---- 8. clouds ----

#[test]
fn ply_data_beyond_the_header_and_nan_normals_are_named() {
    let tmp = tempfile::tempdir().unwrap();
    let p = tmp.path().join("extra.ply");
    let header = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n";
    std::fs::write(&p, format!("{header}end_header\n0 0 1\n1 0 1\n0 1 1\n1 1 1\n")).unwrap();
    expect(&["register", "--source", s(&p), "--target", s(&p)], 1, &["extra.ply", "data continues after the elements"]);
    let n = tmp.path().join("nan_normals.ply");
    let normals = "property float nx\nproperty float ny\nproperty float nz\n";
    std::fs::write(&n, format!("{header}{normals}end_header\n0 0 1 0 0 1\n1 0 1 nan 0 1\n0 1 1 0 0 1\n")).unwrap();
    expect(&["register", "--source", s(&n), "--target", s(&n)], 1, &["nan_normals.ply", "normal"]);
}

#[test]
fn point_to_plane_methods_estimate_missing_normals_with_a_warning() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a.ply"), tmp.path().join("b.ply"));
    let cloud = box_cloud(3000);
    write_cloud(&a, &cloud);
    write_cloud(&b, &rotated(&cloud, 4.0, Vector3::new(0.003, 0.0, 0.0)));
    for method in ["icp-pt2pl", "filterreg-pt2pl"] {
        let err = expect(
            &["register", "--method", method, "--source", s(&a), "--target", s(&b)],
            0,
            &["b.ply (target) has no normals", "--estimate-normals"],
        );
        let _ = err;
    }
    let (c, stdout, err) = run(&[
        "register",
        "--method",
        "icp-pt2pl",
        "--estimate-normals",
        "--source",
        s(&a),
        "--target",
        s(&b),
        "--json",
    ]);
    assert_eq!(c, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert!((v["rotation_angle_deg"].as_f64().unwrap() - 4.0).abs() < 0.2, "{stdout}");
}

// ---- categories: damaged files of every format ----

#[test]
fn empty_garbage_and_truncated_files_of_every_format_are_errors_naming_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    let ply = tmp.path().join("good.ply");
    write_cloud(&ply, &box_cloud(500));
    let good_ply = std::fs::read(&ply).unwrap();
    let mut truth = flowfilter_flow::FlowField::zeros(16, 12);
    truth.valid.as_mut_slice().iter_mut().for_each(|v| *v = true);
    let good_flo = flowfilter_flow::flo::encode(&truth);
    let img = tmp.path().join("img.png");
    image::RgbImage::from_fn(16, 12, |x, y| image::Rgb([(x * 15) as u8, (y * 20) as u8, 3])).save(&img).unwrap();
    let good_png = std::fs::read(&img).unwrap();
    let good_toml = std::fs::read("../../configs/flowfilter.toml").unwrap();
    let variants = |good: &[u8]| -> Vec<(&'static str, Vec<u8>)> {
        vec![
            ("empty", vec![]),
            ("garbage", b"\x00\xffnot a file at all\x13\x37".repeat(9)),
            ("truncated", good[..good.len() / 2].to_vec()),
        ]
    };
    for (kind, bytes) in variants(&good_ply) {
        let p = tmp.path().join(format!("{kind}.ply"));
        std::fs::write(&p, bytes).unwrap();
        expect(&["register", "--source", s(&p), "--target", s(&ply)], 1, &[&format!("{kind}.ply")]);
    }
    for (kind, bytes) in variants(&good_flo) {
        let p = tmp.path().join(format!("{kind}.flo"));
        std::fs::write(&p, bytes).unwrap();
        expect(&["flow", "--from", s(&img), "--to", s(&img), "--gt", s(&p)], 1, &[&format!("{kind}.flo")]);
    }
    for (kind, bytes) in variants(&good_png) {
        let p = tmp.path().join(format!("{kind}.png"));
        std::fs::write(&p, bytes).unwrap();
        expect(&["flow", "--from", s(&p), "--to", s(&img)], 1, &[&format!("{kind}.png")]);
    }
    for (kind, bytes) in variants(&good_toml) {
        let p = tmp.path().join(format!("{kind}.toml"));
        std::fs::write(&p, bytes).unwrap();
        let (c, _, err) = run_estimate(capture(), &["--config", s(&p)]);
        // An empty or half configuration may still be valid TOML with defaults.
        assert!(c == 0 || (c == 1 && err.contains(&format!("{kind}.toml"))), "{kind}: {c} {err}");
    }
    // Every file of a BigBIRD object.
    for name in [
        "calibration.h5",
        "NP3_15.h5",
        "NP3_15.jpg",
        "masks/NP3_15_mask.pbm",
        "poses/NP5_15_pose.h5",
        "poses/turntable.h5",
    ] {
        let good = std::fs::read(capture().join(name)).unwrap();
        for (kind, bytes) in variants(&good) {
            let case = tmp.path().join(format!("{kind}-{}", name.replace('/', "-")));
            let dir = copy_of_capture(&case);
            std::fs::write(dir.join(name), bytes).unwrap();
            let file = Path::new(name).file_name().unwrap().to_str().unwrap();
            expect(&["inspect", s(&dir)], 1, &[file]);
            estimate(&dir, &[], 1, &[file]);
        }
    }
}

// ---- JSON outputs ----

#[test]
fn json_outputs_leave_out_what_they_cannot_give() {
    // ICP has no kernel width and no flow: `sigma2`, `flow_estimator` and `correspondences` are
    // absent, never null.
    let (code, stdout, err) = run_estimate(capture(), &["--method", "icp-pt2pl", "--json"]);
    assert_eq!(code, 0, "{err}");
    assert!(!stdout.contains("null") && !stdout.contains("NaN"), "{stdout}");
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(v["schema"], "flowfilter estimate v3");
    let o = v.as_object().unwrap();
    assert!(!o.contains_key("correspondences") && !o.contains_key("flow_estimator"), "{stdout}");
    assert!(!v["registration"].as_object().unwrap().contains_key("sigma2"), "{stdout}");
    assert!(o.contains_key("ground_truth"));
}
