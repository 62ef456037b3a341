//! The BOP scene reader on `fixtures/bop/000001`, a tiny scene written independently by
//! `tools/peers/bop_fixture.py` (the BOP toolkit's scene-wise layout, its units and file names).

use flowfilter_pipeline::bop::BopScene;
use flowfilter_pipeline::{Pipeline, PipelineConfig, PipelineError};
use std::path::{Path, PathBuf};

fn scene_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/bop/000001")
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn frames_masks_and_relative_motion_follow_the_bop_conventions() {
    let scene = BopScene::open(&scene_dir()).unwrap();
    assert_eq!(scene.image_ids(), [0, 1, 2]);
    // Instances in scene_gt.json order: the plate (7) then the box (3), which leaves after image 1.
    let ids = |im| scene.instances(im).iter().map(|i| (i.obj_id, i.gt_id)).collect::<Vec<_>>();
    assert_eq!(ids(0), [(7, 0), (3, 1)]);
    assert_eq!(ids(2), [(7, 0)]);
    let info = json(&scene_dir().join("scene_gt_info.json"));
    for im in [0u32, 1, 2] {
        for inst in scene.instances(im) {
            let frame = scene.frame(im, inst.obj_id).unwrap();
            assert!(frame.sensor.is_registered());
            assert_eq!((frame.color.width(), frame.color.height()), (64, 48));
            let expected = &info[im.to_string()][inst.gt_id];
            let pixels = frame.mask.as_slice().iter().filter(|m| **m).count();
            assert_eq!(
                pixels as u64,
                expected["px_count_visib"].as_u64().unwrap(),
                "image {im} object {}",
                inst.obj_id
            );
            assert_eq!(inst.visib_fract, expected["visib_fract"].as_f64());
            // Depth in 0.1 mm units: the plate is about 40 cm away.
            let z: Vec<f64> = (0..frame.depth.as_slice().len())
                .filter(|&k| frame.mask.as_slice()[k])
                .map(|k| f64::from(frame.depth.as_slice()[k]) * frame.sensor.metres_per_unit)
                .collect();
            assert!(z.iter().all(|z| (0.3..0.5).contains(z)), "depths {:?}", &z[..3]);
        }
    }
    // T_ab = T_cam_b_from_obj * inv(T_cam_a_from_obj), metres, against the script's own product.
    let truth = json(&scene_dir().join("truth.json"));
    for (a, b) in [(0u32, 1u32), (0, 2), (2, 1)] {
        let t = scene.relative_motion(a, b, 7).unwrap().to_homogeneous();
        let expected = &truth["relative_motion_m"][format!("{a}->{b}")];
        for r in 0..4 {
            for c in 0..4 {
                let e = expected[r][c].as_f64().unwrap();
                assert!((t[(r, c)] - e).abs() < 1e-9, "{a}->{b} ({r},{c}): {} vs {e}", t[(r, c)]);
            }
        }
    }
}

#[test]
fn every_method_estimates_on_a_bop_pair() {
    let scene = BopScene::open(&scene_dir()).unwrap();
    let (a, b) = (scene.frame(0, 7).unwrap(), scene.frame(1, 7).unwrap());
    for method in ["flowfilter", "filterreg-pt2pt", "icp-pt2pl", "cpd"] {
        let config = PipelineConfig { method: method.into(), ..PipelineConfig::default() };
        let e = Pipeline::from_config(config).unwrap().estimate(&a, &b).unwrap();
        assert!(e.transform.iter().flatten().all(|v| v.is_finite()), "{method}");
        assert!(e.registration.model_points > 50, "{method}: {} points", e.registration.model_points);
    }
}

#[test]
fn bad_bop_folders_are_named() {
    let tmp = tempfile::tempdir().unwrap();
    let copy = tmp.path().join("000001");
    std::fs::create_dir_all(&copy).unwrap();
    for entry in std::fs::read_dir(scene_dir()).unwrap() {
        let p = entry.unwrap().path();
        if p.is_dir() {
            let d = copy.join(p.file_name().unwrap());
            std::fs::create_dir_all(&d).unwrap();
            for f in std::fs::read_dir(&p).unwrap() {
                let f = f.unwrap().path();
                std::fs::copy(&f, d.join(f.file_name().unwrap())).unwrap();
            }
        } else {
            std::fs::copy(&p, copy.join(p.file_name().unwrap())).unwrap();
        }
    }
    // An object absent from an image.
    let scene = BopScene::open(&copy).unwrap();
    let e = scene.frame(2, 3).unwrap_err().to_string();
    assert!(e.contains("scene_gt.json") && e.contains("no object 3"), "{e}");
    assert!(scene.relative_motion(0, 2, 3).is_err());
    // A missing mask file.
    std::fs::remove_file(copy.join("mask_visib/000001_000000.png")).unwrap();
    let e = scene.frame(1, 7).unwrap_err().to_string();
    assert!(e.contains("000001_000000.png"), "{e}");
    // A camera entry with a zero depth scale.
    let mut cam = json(&copy.join("scene_camera.json"));
    cam["0"]["depth_scale"] = serde_json::json!(0.0);
    std::fs::write(copy.join("scene_camera.json"), cam.to_string()).unwrap();
    let e = BopScene::open(&copy).unwrap().frame(0, 7).unwrap_err();
    assert!(matches!(e, PipelineError::Camera(_)) && e.to_string().contains("depth_scale"), "{e}");
    // No scene_gt.json at all.
    std::fs::remove_file(copy.join("scene_gt.json")).unwrap();
    let e = BopScene::open(&copy).unwrap_err().to_string();
    assert!(e.contains("scene_gt.json") && e.contains("cannot read"), "{e}");
}
