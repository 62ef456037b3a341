//! Frames from files without any download: BOP scenes written by `flowfilter-synth` (registered
//! depth with sensor noise, masks a few pixels off, exposure changes, depth taken at another
//! instant) read back through the BOP reader, a sensor with a separate depth camera described by
//! a camera file, and bad inputs refused with file and field named.

use flowfilter_eval::PoseErrors;
use flowfilter_pipeline::bop::BopScene;
use flowfilter_pipeline::{CameraFile, FrameFiles, MaskSource, Pipeline, PipelineConfig, PipelineError, Pose};
use flowfilter_synth::{
    BopSceneOptions, FrameEffects, NoiseProfile, Rig, Scene, procedural, render_frame, world_from_table,
    write_bop_scene,
};
use image::{ImageBuffer, Luma};
use std::path::Path;

fn np(i: u8) -> flowfilter_pipeline::bigbird::SensorId {
    flowfilter_pipeline::bigbird::SensorId::new(i).unwrap()
}

fn box_scene() -> Scene {
    Scene::new(procedural("box", 5).unwrap().placed_on_table(0.01, -0.005), 5)
}

fn write_scene(dir: &Path, angles_deg: Vec<f64>) {
    let opts = BopSceneOptions {
        angles_deg,
        noise: Some(NoiseProfile::carmine()),
        effects: FrameEffects::REAL_SENSOR,
        seed: 5,
        obj_id: 4,
        depth_scale_mm: 0.1,
    };
    write_bop_scene(dir, &box_scene(), &Rig::bigbird_like().sensors[&np(3)], &opts, &|_, _| {}).unwrap();
}

fn pipeline(method: &str) -> Pipeline {
    Pipeline::from_config(PipelineConfig { method: method.into(), ..PipelineConfig::default() }).unwrap()
}

#[test]
fn synthesized_bop_scenes_read_back_and_every_method_estimates_them() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("000003");
    write_scene(&dir, vec![0.0, 0.25, 0.5, 6.0]);
    let scene = BopScene::open(&dir).unwrap();
    assert_eq!(scene.image_ids(), [0, 1, 2, 3]);
    let inst = scene.instance(0, 4).unwrap();
    assert!(inst.visib_fract.unwrap() > 0.95, "{inst:?}");
    // The ground truth is the turntable's rotation, seen in the camera frame.
    let truth = scene.relative_motion(0, 3, 4).unwrap();
    assert!((truth.rotation.angle().to_degrees() - 6.0).abs() < 1e-6);
    let frames: Vec<_> = (0..4).map(|im| scene.frame(im, 4).unwrap()).collect();
    for f in &frames {
        assert!(f.sensor.is_registered());
        assert_eq!((f.color.width(), f.color.height()), (1280, 1024));
        // Depth in 0.1 mm units: the box is 0.6-0.9 m from NP3 (the mask, a few pixels off, also
        // takes in some table behind it).
        let z: Vec<f64> = f
            .mask
            .as_slice()
            .iter()
            .zip(f.depth.as_slice())
            .filter(|(m, d)| **m && **d > 0)
            .map(|(_, d)| f64::from(*d) * 1e-4)
            .collect();
        let near = z.iter().filter(|z| (0.5..0.9).contains(*z)).count();
        let (lo, hi) = z.iter().fold((f64::MAX, 0.0f64), |(a, b), &z| (a.min(z), b.max(z)));
        assert!(z.len() > 10_000 && near as f64 > 0.97 * z.len() as f64, "{} points in {lo}..{hi} m", z.len());
    }
    // 6 degrees: every method returns a finite pose; Flow Filter is within a degree.
    for method in ["flowfilter", "filterreg-pt2pt", "icp-pt2pl", "cpd"] {
        let e = pipeline(method).estimate(&frames[0], &frames[3]).unwrap();
        let errors = PoseErrors::new(&e.pose, &truth, None);
        assert!(e.transform.iter().flatten().all(|v| v.is_finite()), "{method}");
        if method == "flowfilter" {
            assert!(errors.geodesic_error_deg < 1.0, "{method}: {errors:?}");
        }
    }
    // Motions of a quarter and half a degree: on average Flow Filter is closer than "no motion".
    let ff = pipeline("flowfilter");
    let (mut ours, mut none) = (0.0, 0.0);
    for (a, b) in [(0u32, 1u32), (1, 2), (0, 2)] {
        let truth = scene.relative_motion(a, b, 4).unwrap();
        let e = ff.estimate(&frames[a as usize], &frames[b as usize]).unwrap();
        ours += PoseErrors::new(&e.pose, &truth, None).geodesic_error_deg;
        none += PoseErrors::new(&Pose::identity(), &truth, None).geodesic_error_deg;
    }
    assert!(ours < none, "Flow Filter {:.3} deg against no motion {:.3} deg (sums of 3 pairs)", ours, none);
}

fn save_depth(path: &Path, depth: &flowfilter_pipeline::RawDepth) {
    let (w, h) = depth.dims();
    let img: ImageBuffer<Luma<u16>, Vec<u16>> =
        ImageBuffer::from_fn(w as u32, h as u32, |x, y| Luma([*depth.at(x as usize, y as usize)]));
    img.save(path).unwrap();
}

fn save_mask(path: &Path, mask: &flowfilter_pipeline::Mask) {
    let (w, h) = mask.dims();
    let img: ImageBuffer<Luma<u8>, Vec<u8>> =
        ImageBuffer::from_fn(w as u32, h as u32, |x, y| Luma([u8::from(*mask.at(x as usize, y as usize)) * 255]));
    img.save(path).unwrap();
}

/// The camera file of a rig sensor: colour camera, a separate depth camera and their pose.
fn camera_json(rig: &Rig) -> String {
    let s = &rig.sensors[&np(3)].rgbd;
    let k = |m: &flowfilter_pipeline::camera::CameraModel| {
        let i = m.intrinsics;
        serde_json::json!([[i.fx, 0.0, i.cx], [0.0, i.fy, i.cy], [0.0, 0.0, 1.0]])
    };
    let t = s.color_from_depth.to_homogeneous();
    serde_json::json!({
        "K": k(&s.color), "width": s.color.size.width, "height": s.color.size.height,
        "distortion": s.color.distortion.to_array(),
        "depth_unit_m": s.metres_per_unit,
        "depth": {"K": k(&s.depth), "width": s.depth.size.width, "height": s.depth.size.height},
        "color_from_depth": (0..4).map(|r| (0..4).map(|c| t[(r, c)]).collect::<Vec<f64>>()).collect::<Vec<_>>(),
    })
    .to_string()
}

#[test]
fn a_separate_depth_camera_in_the_camera_file_is_registered_by_the_depth_stage() {
    let tmp = tempfile::tempdir().unwrap();
    let (scene, rig) = (box_scene(), Rig::bigbird_like());
    let mut files = vec![];
    for angle in [0u32, 6] {
        let f = render_frame(&scene, &rig, np(3), angle, Some(&NoiseProfile::carmine()), 5);
        let p = |n: &str| tmp.path().join(format!("{angle}_{n}.png"));
        f.color.save(p("color")).unwrap();
        save_depth(&p("depth"), &f.raw_depth);
        save_mask(&p("mask"), &f.mask);
        files.push(FrameFiles { color: p("color"), depth: p("depth"), mask: MaskSource::Binary(p("mask")) });
    }
    let cam_path = tmp.path().join("camera.json");
    std::fs::write(&cam_path, camera_json(&rig)).unwrap();
    let camera = CameraFile::from_file(&cam_path).unwrap();
    assert!(!camera.is_registered());
    let (a, b) = (files[0].load(&camera, "a").unwrap(), files[1].load(&camera, "b").unwrap());
    assert!(!a.sensor.is_registered());
    let s = &rig.sensors[&np(3)].rgbd;
    assert_eq!((a.depth.width(), a.depth.height()), (640, 480));
    assert!((a.sensor.color_from_depth.translation.vector - s.color_from_depth.translation.vector).norm() < 1e-12);
    assert!((a.sensor.color_from_depth.rotation.angle_to(&s.color_from_depth.rotation)) < 1e-9);
    let cam_from_table = |deg: f64| rig.sensors[&np(3)].h_color_from_world * world_from_table(deg);
    let truth = cam_from_table(6.0) * cam_from_table(0.0).inverse();
    let e = pipeline("flowfilter").estimate(&a, &b).unwrap();
    let errors = PoseErrors::new(&e.pose, &truth, None);
    assert!(errors.geodesic_error_deg < 1.0 && errors.translation_error_m < 0.01, "{errors:?}");
    // The same depth image with the camera file told it is registered: refused, with the reason.
    let registered = CameraFile::from_json_str(
        &camera_json(&rig).replace("\"depth\":", "\"unused_depth\":").replace("\"color_from_depth\":", "\"unused\":"),
        "registered.json",
    )
    .unwrap();
    let e = files[0].load(&registered, "a").unwrap_err().to_string();
    assert!(e.contains("640x480") && e.contains("1280x1024") && e.contains("registered.json"), "{e}");
}

#[test]
fn bad_synthetic_frames_are_refused_naming_file_and_field() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("000003");
    write_scene(&dir, vec![0.0]);
    let camera = CameraFile::from_json_value(
        &serde_json::from_str::<serde_json::Value>(&std::fs::read_to_string(dir.join("scene_camera.json")).unwrap())
            .unwrap()["0"],
        "scene_camera.json",
    )
    .unwrap();
    let good = FrameFiles {
        color: dir.join("rgb/000000.png"),
        depth: dir.join("depth/000000.png"),
        mask: MaskSource::Binary(dir.join("mask_visib/000000_000000.png")),
    };
    good.load(&camera, "ok").unwrap();
    // A mask of another size.
    let small = tmp.path().join("small_mask.png");
    save_mask(&small, &flowfilter_pipeline::Mask::filled(64, 48, true));
    let e = FrameFiles { mask: MaskSource::Binary(small), ..good.clone() }.load(&camera, "x").unwrap_err();
    assert!(matches!(e, PipelineError::Input { .. }) && e.to_string().contains("small_mask.png"), "{e}");
    assert!(e.to_string().contains("64x48") && e.to_string().contains("1280x1024"), "{e}");
    // A label that does not occur in the label image (the binary mask read as labels: 255 only).
    let e = FrameFiles {
        mask: MaskSource::Label { path: dir.join("mask_visib/000000_000000.png"), id: 9 },
        ..good.clone()
    }
    .load(&camera, "x")
    .unwrap_err()
    .to_string();
    assert!(e.contains("000000_000000.png") && e.contains("label 9 does not occur"), "{e}");
    // Depth of another size than colour, for registered depth.
    let depth = tmp.path().join("depth_small.png");
    save_depth(&depth, &flowfilter_pipeline::RawDepth::filled(640, 480, 5000));
    let e = FrameFiles { depth, ..good.clone() }.load(&camera, "x").unwrap_err().to_string();
    assert!(e.contains("depth_small.png") && e.contains("640x480"), "{e}");
    // Camera entries that cannot make a sensor: zero focal length, a zero, negative or textual depth scale.
    for (text, field) in [
        (r#"{"cam_K": [0, 0, 640, 0, 1080, 512, 0, 0, 1], "depth_scale": 0.1}"#, "'cam_K'"),
        (r#"{"cam_K": [1080, 0, 640, 0, 1080, 512, 0, 0, 1], "depth_scale": 0}"#, "'depth_scale'"),
        (r#"{"cam_K": [1080, 0, 640, 0, 1080, 512, 0, 0, 1], "depth_scale": -0.1}"#, "'depth_scale'"),
        (r#"{"cam_K": [1080, 0, 640, 0, 1080, 512, 0, 0, 1], "depth_scale": "NaN"}"#, "'depth_scale'"),
    ] {
        let e = CameraFile::from_json_str(text, "cam.json").unwrap_err().to_string();
        assert!(e.starts_with("cam.json") && e.contains(field), "{text}: {e}");
    }
    // A separate depth camera with a broken pose.
    let bad_pose = r#"{"K": [1080, 0, 640, 0, 1080, 512, 0, 0, 1], "depth_unit_m": 0.001,
        "depth": {"K": [575, 0, 320, 0, 575, 240, 0, 0, 1], "width": 640, "height": 480},
        "color_from_depth": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}"#;
    let e = CameraFile::from_json_str(bad_pose, "cam.json").unwrap_err().to_string();
    assert!(e.contains("cam.json") && e.contains("'color_from_depth'") && e.contains("rigid"), "{e}");
    let no_k = r#"{"K": [1080, 0, 640, 0, 1080, 512, 0, 0, 1], "depth": {"width": 640, "height": 480},
        "color_from_depth": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]}"#;
    let e = CameraFile::from_json_str(no_k, "cam.json").unwrap_err().to_string();
    assert!(e.contains("cam.json (depth camera)") && e.contains("'K'"), "{e}");
}
