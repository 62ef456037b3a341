//! Flow correspondences between two synthesised views of a textured box agree with the
//! turntable ground truth.

use flowfilter_bigbird::SensorId;
use flowfilter_depth::{DepthConfig, DepthStage};
use flowfilter_flow::LucasKanade;
use flowfilter_flow::correspondences::{CorrespondenceParams, FlowView, flow_correspondences};
use flowfilter_flow::lk::to_gray;
use flowfilter_synth::{NoiseProfile, Rig, Scene, procedural, render_frame, world_from_table};

#[test]
fn box_correspondences_follow_the_true_motion() {
    let rig = Rig::bigbird_like();
    let sensor = SensorId::new(3).unwrap();
    let s = &rig.sensors[&sensor];
    let scene = Scene::new(procedural("box", 1).unwrap().placed_on_table(0.01, -0.005), 1);
    let stage = DepthStage::new(DepthConfig::default()).unwrap();
    let noise = NoiseProfile::carmine();
    let (a, b) = (0u32, 6u32);
    let fa = render_frame(&scene, &rig, sensor, a, Some(&noise), 1);
    let fb = render_frame(&scene, &rig, sensor, b, Some(&noise), 1);
    let da = stage.process(&fa.raw_depth, &fa.color, &fa.mask, &s.rgbd).unwrap();
    let db = stage.process(&fb.raw_depth, &fb.color, &fb.mask, &s.rgbd).unwrap();
    let (ga, gb) = (to_gray(&fa.color), to_gray(&fb.color));
    let pairs = flow_correspondences(
        &LucasKanade::default(),
        &FlowView { gray: &ga, depth: &da.depth, mask: &fa.mask },
        &FlowView { gray: &gb, depth: &db.depth, mask: &fb.mask },
        &stage.rays(&s.rgbd.color),
        &CorrespondenceParams::default(),
    )
    .unwrap();
    let h = |angle: u32| s.h_color_from_world * world_from_table(f64::from(angle));
    let truth = h(b) * h(a).inverse();
    let errors: Vec<f64> = pairs
        .model
        .iter()
        .zip(&pairs.target)
        .zip(&pairs.weights)
        .filter(|(_, w)| **w > 0.0)
        .map(|((p, q), _)| (truth * p - q).norm())
        .collect();
    let mut sorted = errors.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    println!("{} tracked, {} pairs kept, median 3-D error {:.2} mm", pairs.tracked, errors.len(), median * 1e3);
    assert!(errors.len() > 200, "{} pairs", errors.len());
    assert!(median < 2e-3, "median error {median} m");
}
