//! Depth already registered to colour (RealSense aligned depth, YCB-Video, BOP): the stage
//! places it on the colour grid as it is (no re-projection), and still filters and fills it.

use flowfilter_camera::{CameraModel, Distortion, ImageSize, Intrinsics, RgbdSensor};
use flowfilter_depth::{DepthConfig, DepthStage};
use flowfilter_geometry::{Mask, RawDepth};
use image::RgbImage;

/// A 160x120 camera looking at a slanted plane (z = 0.7 + 0.2 x_normalised metres), depth in
/// 0.1 mm units, with a 3x3 hole inside the object's square mask.
fn frame() -> (RgbdSensor, RawDepth, Mask, RgbImage, impl Fn(usize, usize) -> f64) {
    let camera = CameraModel::new(
        Intrinsics::new(150.0, 150.0, 79.5, 59.5).unwrap(),
        Distortion::NONE,
        ImageSize::new(160, 120).unwrap(),
    );
    let sensor = RgbdSensor::registered(camera, 1e-4).unwrap();
    let z = |x: usize, _y: usize| 0.7 + 0.2 * (x as f64 - 79.5) / 150.0;
    let raw = RawDepth::from_fn(160, 120, |x, y| {
        if (70..73).contains(&x) && (55..58).contains(&y) { 0 } else { (z(x, y) * 1e4).round() as u16 }
    });
    let mask = Mask::from_fn(160, 120, |x, y| (40..120).contains(&x) && (30..90).contains(&y));
    let color = RgbImage::from_fn(160, 120, |x, y| image::Rgb([(x * 3) as u8, (y * 2) as u8, 128]));
    (sensor, raw, mask, color, z)
}

#[test]
fn registered_depth_is_placed_filtered_and_filled() {
    let (sensor, raw, mask, color, z) = frame();
    assert!(sensor.is_registered());
    let out = DepthStage::new(DepthConfig::default()).unwrap().process(&raw, &color, &mask, &sensor).unwrap();
    assert_eq!(out.depth.dims(), (160, 120));
    let mut worst: f64 = 0.0;
    for y in 32..88 {
        for x in 42..118 {
            let d = f64::from(*out.depth.at(x, y));
            assert!(d > 0.0, "no depth at ({x}, {y}) inside the mask");
            worst = worst.max((d - z(x, y)).abs());
        }
    }
    // Placed pixel for pixel: the filtered depth is the plane to within the 0.1 mm quantum and
    // the filters' smoothing; the hole is filled from its neighbours.
    assert!(worst < 5e-4, "worst depth error {worst} m");
    assert!(f64::from(*out.depth.at(71, 56)) > 0.0, "the hole is not filled");
    assert_eq!(*out.depth.at(10, 10), 0.0, "depth outside the mask");
    // One point per mask pixel with depth.
    let inside = mask.as_slice().iter().filter(|m| **m).count();
    assert!(out.cloud.len() as f64 > 0.97 * inside as f64, "{} points for {inside} mask pixels", out.cloud.len());
}

#[test]
fn a_registered_sensor_still_checks_sizes() {
    let (sensor, raw, mask, color, _) = frame();
    let small = RawDepth::from_fn(80, 60, |x, y| *raw.at(2 * x, 2 * y));
    let e = DepthStage::new(DepthConfig::default()).unwrap().process(&small, &color, &mask, &sensor).unwrap_err();
    assert!(e.to_string().contains("depth image") && e.to_string().contains("160x120"), "{e}");
}

/// A whole-image mask on a frame whose readings cover only part of it (a scene's object and
/// table, the rest too far for the sensor): the stage works on the box of the readings, and
/// still gives every pixel the fill reaches from them. With the nearest-sample fill, holes up
/// to its radius beyond the readings' edge are filled; none further out.
#[test]
fn a_whole_mask_keeps_what_the_fill_reaches_beyond_the_readings() {
    let (sensor, raw, _, color, _) = frame();
    let readings =
        RawDepth::from_fn(
            160,
            120,
            |x, y| {
                if (60..100).contains(&x) && (40..80).contains(&y) { *raw.at(x, y) } else { 0 }
            },
        );
    let whole = Mask::filled(160, 120, true);
    let mut cfg = DepthConfig::default();
    cfg.interpolation.method = flowfilter_depth::InterpolationMethod::Nearest;
    let r = cfg.interpolation.max_radius_px;
    let out = DepthStage::new(cfg.clone()).unwrap().process(&readings, &color, &whole, &sensor).unwrap();
    assert!(*out.depth.at(60 - r, 60) > 0.0 && *out.depth.at(99 + r, 60) > 0.0, "filled up to the radius along rows");
    assert!(*out.depth.at(80, 40 - r) > 0.0 && *out.depth.at(80, 79 + r) > 0.0, "and along columns");
    assert_eq!(*out.depth.at(60 - r - 1, 60), 0.0);
    assert_eq!(*out.depth.at(80, 79 + r + 1), 0.0);
    // The same depth and cloud as with a mask that covers only the readings' reach.
    let near = Mask::from_fn(160, 120, |x, y| (60 - r..100 + r).contains(&x) && (40 - r..80 + r).contains(&y));
    let cut = DepthStage::new(cfg).unwrap().process(&readings, &color, &near, &sensor).unwrap();
    assert_eq!(out.depth.as_slice(), cut.depth.as_slice());
    assert_eq!(out.cloud.points, cut.cloud.points);
}

/// A mask larger than four times the cloud's pixel budget: the cloud takes every second pixel in
/// each direction, and each of its points (and its normal) is the full cloud's point at that
/// pixel; a budget the mask fits keeps every pixel.
#[test]
fn a_large_mask_gives_a_cloud_of_every_second_pixel_with_the_same_points_and_normals() {
    let (sensor, raw, mask, color, _) = frame();
    let with_budget = |budget| {
        let mut cfg = DepthConfig::default();
        cfg.cloud.pixel_budget = budget;
        DepthStage::new(cfg).unwrap().process(&raw, &color, &mask, &sensor).unwrap()
    };
    let full = with_budget(0);
    let fits = with_budget(full.cloud.len() / 3);
    assert_eq!(fits.stats.cloud_step, 1);
    assert_eq!(fits.cloud.points, full.cloud.points);
    let budgeted = with_budget(1000);
    assert_eq!(budgeted.stats.cloud_step, 2, "{} pixels with depth", full.cloud.len());
    let (pixels, normals) = (budgeted.cloud.pixels.as_ref().unwrap(), budgeted.cloud.normals.as_ref().unwrap());
    assert!(pixels.iter().all(|p| p[0] % 2.0 == 0.0 && p[1] % 2.0 == 0.0), "odd pixels in the cloud");
    let expected = full
        .point_index
        .iter()
        .enumerate()
        .filter(|(k, i)| **i != u32::MAX && k % 160 % 2 == 0 && k / 160 % 2 == 0)
        .count();
    assert_eq!(budgeted.cloud.len(), expected);
    let full_normals = full.cloud.normals.as_ref().unwrap();
    for (i, p) in pixels.iter().enumerate() {
        let k = full.point_index[p[1] as usize * 160 + p[0] as usize] as usize;
        assert_eq!(budgeted.cloud.points[i], full.cloud.points[k]);
        assert!((normals[i] - full_normals[k]).norm() < 1e-12, "the normal at {p:?} differs");
    }
}

/// The sensor's working range (`[depth.range]`): a robot's camera sees its own gripper a few
/// centimetres away in every frame. Readings nearer than `min_m` (or farther than `max_m`) are
/// dropped before any filter: neither the depth nor the cloud holds them, and the stage counts
/// them; by default every reading is kept. A range that is empty or not finite is refused,
/// naming the key.
#[test]
fn readings_outside_the_working_range_are_dropped() {
    let (sensor, mut raw, mask, color, z) = frame();
    // A "gripper" 8 cm away over the mask's top-left corner.
    for y in 30..45 {
        for x in 40..60 {
            *raw.at_mut(x, y) = 800;
        }
    }
    let run = |cfg: DepthConfig| DepthStage::new(cfg).unwrap().process(&raw, &color, &mask, &sensor).unwrap();
    let kept = run(DepthConfig::default());
    assert!((f64::from(*kept.depth.at(45, 35)) - 0.08).abs() < 1e-3, "by default every reading is kept");
    assert_eq!(kept.stats.out_of_range, 0);
    let mut cfg = DepthConfig::default();
    cfg.range.min_m = 0.2;
    let cut = run(cfg.clone());
    assert_eq!(cut.stats.out_of_range, 20 * 15);
    assert!(cut.cloud.points.iter().all(|p| p.z > 0.2), "a point nearer than the range");
    assert!((f64::from(*cut.depth.at(100, 60)) - z(100, 60)).abs() < 5e-4, "the rest is kept");
    cfg.range.max_m = 0.7;
    let near = run(cfg.clone());
    assert!(near.cloud.points.iter().all(|p| p.z > 0.2 && p.z <= 0.7 + 1e-3), "a point outside the range");
    assert_eq!(*near.depth.at(110, 60), 0.0, "beyond max_m");
    for (min, max, key) in [(-0.1, 0.0, "range.min_m"), (0.5, 0.3, "range.max_m"), (f64::NAN, 0.0, "range.min_m")] {
        let mut bad = DepthConfig::default();
        (bad.range.min_m, bad.range.max_m) = (min, max);
        let e = DepthStage::new(bad).err().expect("refused").to_string();
        assert!(e.contains(key), "{e}");
    }
    let e = toml::from_str::<DepthConfig>("[range]\nmin = 0.2\n").unwrap_err().to_string();
    assert!(e.contains("min"), "{e}");
}
