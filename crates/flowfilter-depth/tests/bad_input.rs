//! Inconsistent inputs give typed errors.

use flowfilter_bigbird::SensorId;
use flowfilter_depth::{DepthConfig, DepthError, DepthStage};
use flowfilter_geometry::{Mask, RawDepth};
use flowfilter_synth::{Rig, Scene, procedural, render_frame};

#[test]
fn mismatched_empty_and_nan_inputs() {
    let rig = Rig::bigbird_like();
    let sensor = SensorId::new(3).unwrap();
    let scene = Scene::new(procedural("can", 1).unwrap(), 1);
    let f = render_frame(&scene, &rig, sensor, 0, None, 1);
    let rgbd = rig.sensors[&sensor].rgbd;
    let stage = DepthStage::new(DepthConfig::default()).unwrap();
    assert!(stage.process(&f.raw_depth, &f.color, &f.mask, &rgbd).is_ok());

    let small = RawDepth::filled(320, 240, 1000);
    let e = stage.process(&small, &f.color, &f.mask, &rgbd).unwrap_err();
    assert!(matches!(e, DepthError::SizeMismatch { what: "depth image", .. }), "{e}");
    assert!(e.to_string().contains("depth image is 320x240, expected 640x480"), "{e}");
    let e = stage.process(&f.raw_depth, &f.color, &Mask::filled(640, 480, true), &rgbd).unwrap_err();
    assert!(e.to_string().contains("mask is 640x480, expected 1280x1024"), "{e}");
    let e = stage.process(&f.raw_depth, &f.color, &Mask::filled(1280, 1024, false), &rgbd).unwrap_err();
    assert!(matches!(e, DepthError::EmptyMask), "{e}");
    let e = stage.process(&RawDepth::filled(640, 480, 0), &f.color, &f.mask, &rgbd).unwrap_err();
    assert!(matches!(e, DepthError::NoDepth), "{e}");
    let mut bad = rgbd;
    bad.color.intrinsics.fx = f64::NAN;
    let e = stage.process(&f.raw_depth, &f.color, &f.mask, &bad).unwrap_err();
    assert!(matches!(e, DepthError::NonFiniteCalibration { name: "colour fx", .. }), "{e}");
}

#[test]
fn a_mask_over_empty_space_gives_an_explicit_empty_cloud() {
    let rig = Rig::bigbird_like();
    let sensor = SensorId::new(3).unwrap();
    let f = render_frame(&Scene::new(procedural("can", 1).unwrap(), 1), &rig, sensor, 0, None, 1);
    // A mask in the image corner, where nothing is seen: a valid, empty result.
    let corner = Mask::from_fn(1280, 1024, |x, y| x < 20 && y < 20);
    let out = DepthStage::new(DepthConfig::default())
        .unwrap()
        .process(&f.raw_depth, &f.color, &corner, &rig.sensors[&sensor].rgbd)
        .unwrap();
    assert!(out.cloud.is_empty());
    assert_eq!(out.stats.registered, 0);
}

#[test]
fn config_from_toml_names_unknown_keys_and_bad_values() {
    let cfg: DepthConfig = toml::from_str("[gaussian_filter]\nwindow = 7\nestimator = \"mean_std\"\n").unwrap();
    assert_eq!(cfg.gaussian_filter.window, 7);
    let e = toml::from_str::<DepthConfig>("[gaussian_filter]\nwindw = 7\n").unwrap_err().to_string();
    assert!(e.contains("windw"), "{e}");
    let mut cfg = DepthConfig::default();
    cfg.bigbird_filter.window = 4;
    assert!(DepthStage::new(cfg).err().unwrap().to_string().contains("bigbird_filter.window"));
}
