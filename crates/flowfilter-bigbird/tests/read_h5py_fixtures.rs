//! The reader accepts what libhdf5 (through h5py) writes, in the oldest and newest formats,
//! and its ground-truth motion points the right way.

mod common;

use flowfilter_bigbird::{BigBirdObject, FrameId, SensorId, inspect};
use flowfilter_camera::Pixel;
use flowfilter_geometry::Point3;

const FORMATS: [&str; 2] = ["earliest", "latest"];

fn np(c: u8) -> SensorId {
    SensorId::new(c).unwrap()
}

#[test]
fn opens_both_formats_with_documented_values() {
    for format in FORMATS {
        let obj = BigBirdObject::open(common::fixture(format)).unwrap();
        assert_eq!(obj.name, "tiny_spheres");
        assert_eq!(obj.sensors().into_iter().collect::<Vec<_>>(), vec![np(1), np(5)]);
        assert_eq!(obj.angles().into_iter().collect::<Vec<_>>(), vec![0, 3, 30]);
        assert_eq!(obj.calibration.sensors.len(), 5, "{format}: all five sensors are calibrated");
        let s1 = &obj.calibration.sensors[&np(1)];
        assert_eq!((s1.rgb_k.fx, s1.rgb_k.fy, s1.rgb_k.cx, s1.rgb_k.cy), (135.17, 135.11, 79.62, 63.45));
        assert_eq!(s1.rgb_d.to_array(), [0.0421, -0.1137, 0.00091, -0.00063, 0.0512]);
        assert_eq!(s1.depth_k_key, "NP1_ir_K");
        assert_eq!(obj.calibration.sensors[&np(2)].depth_k_key, "NP2_depth_K");
        assert_eq!(s1.ir_depth_scale, 1.0125);
        // The depth camera sits 2.5 cm along the colour camera's -x axis.
        let t = s1.color_from_depth().translation.vector;
        assert!((t - nalgebra::Vector3::new(-0.025, 0.0, 0.0)).norm() < 1e-12, "{t:?}");
        assert!((obj.turntable.normal.norm() - 1.0).abs() < 1e-12);

        let frame = obj.load_frame(FrameId { sensor: np(5), angle: 30 }).unwrap();
        assert_eq!(frame.depth.dims(), (80, 60));
        assert_eq!((frame.color.width(), frame.color.height()), (160, 128));
        assert_eq!(frame.mask.dims(), (160, 128));
        assert!(frame.mask.count() > 300, "{format}: mask has object pixels");
        let valid = frame.depth.as_slice().iter().filter(|&&d| d > 0).count();
        assert!(valid > 1000, "{format}: depth has readings");
        // Object pixels in the colour image are the sphere's saturated colours, background is light grey.
        let (mut object_grey, mut background_grey) = (0.0, 0.0);
        for (x, y, px) in frame.color.enumerate_pixels() {
            let spread = px.0.iter().max().unwrap() - px.0.iter().min().unwrap();
            if *frame.mask.at(x as usize, y as usize) {
                object_grey += f64::from(spread < 30);
            } else {
                background_grey += f64::from(spread < 30);
            }
        }
        eprintln!(
            "{format} grey fractions: object {} background {}",
            object_grey / frame.mask.count() as f64,
            background_grey / ((160 * 128 - frame.mask.count()) as f64)
        );
        assert!(object_grey / (frame.mask.count() as f64) < 0.2, "object pixels are coloured");
        assert!(background_grey / ((160 * 128 - frame.mask.count()) as f64) > 0.9, "background is grey");
    }
}

/// Fraction of the object's depth points at angle `a` that, moved by `motion`, project onto
/// the mask at angle `b`.
fn fraction_on_mask(obj: &BigBirdObject, sensor: SensorId, a: u32, b: u32, motion: &flowfilter_geometry::Pose) -> f64 {
    let fa = obj.load_frame(FrameId { sensor, angle: a }).unwrap();
    let fb = obj.load_frame(FrameId { sensor, angle: b }).unwrap();
    let rig = obj.rgbd_sensor(&fa).unwrap();
    let (mut on, mut total) = (0usize, 0usize);
    for y in 0..fa.depth.height() {
        for x in 0..fa.depth.width() {
            let Some(z) = rig.metric_depth(*fa.depth.at(x, y)) else { continue };
            let p: Point3 = rig.depth_pixel_to_color_frame(&Pixel::new(x as f64, y as f64), z).unwrap();
            let Some(q) = rig.color.project(&p) else { continue };
            let (u, v) = (q.x.round(), q.y.round());
            if u < 0.0 || v < 0.0 || !fa.mask.get(u as usize, v as usize).copied().unwrap_or(false) {
                continue; // not an object point at angle a
            }
            total += 1;
            let Some(q) = rig.color.project(&(motion * p)) else { continue };
            // On the mask, within the one pixel that rounding at this tiny resolution costs.
            let near = |du: f64, dv: f64| {
                let (u, v) = ((q.x + du).round(), (q.y + dv).round());
                u >= 0.0 && v >= 0.0 && fb.mask.get(u as usize, v as usize).copied().unwrap_or(false)
            };
            if [(0.0, 0.0), (1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)].iter().any(|&(du, dv)| near(du, dv)) {
                on += 1;
            }
        }
    }
    assert!(total > 50, "enough object points ({total})");
    on as f64 / total as f64
}

#[test]
fn ground_truth_motion_moves_object_points_onto_the_other_mask() {
    for format in FORMATS {
        let obj = BigBirdObject::open(common::fixture(format)).unwrap();
        for sensor in [np(1), np(5)] {
            let t_ab = obj.relative_motion(sensor, 0, 30).unwrap();
            assert!((t_ab.rotation.angle().to_degrees() - 30.0).abs() < 1e-6);
            let right = fraction_on_mask(&obj, sensor, 0, 30, &t_ab);
            let wrong = fraction_on_mask(&obj, sensor, 0, 30, &t_ab.inverse());
            let none = fraction_on_mask(&obj, sensor, 0, 30, &flowfilter_geometry::Pose::identity());
            eprintln!("{format} {sensor}: right {right:.3} wrong {wrong:.3} none {none:.3}");
            assert!(right > 0.97, "{format} {sensor}: only {right:.3} of moved points on the target mask");
            assert!(wrong < right - 0.1, "{format} {sensor}: the inverse motion fits too ({wrong:.3} vs {right:.3})");
            assert!(none < right - 0.05, "{format} {sensor}: no motion fits too ({none:.3} vs {right:.3})");
        }
    }
}

#[test]
fn inspect_finds_no_problem_in_fixtures() {
    for format in FORMATS {
        let report = inspect(common::fixture(format));
        assert!(report.is_ok(), "{format}: {:?}", report.problems);
        assert_eq!(report.summary.valid_frames, 6);
    }
}
