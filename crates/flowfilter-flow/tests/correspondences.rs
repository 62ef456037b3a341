//! Flow correspondences between two synthesised views of a textured box agree with the
//! turntable ground truth.

use flowfilter_bigbird::SensorId;
use flowfilter_depth::{DepthConfig, DepthStage};
use flowfilter_flow::LucasKanade;
use flowfilter_flow::correspondences::{
    CorrespondenceParams, FlowGuide, FlowPairs, FlowView, flow_correspondences, flow_correspondences_guided,
};
use flowfilter_flow::lk::{Gray, to_gray};
use flowfilter_geometry::{DepthMap, Mask, Pose, weighted_kabsch};
use flowfilter_synth::{NoiseProfile, Rig, RigSensor, Scene, procedural, render_frame, world_from_table};

/// The procedural box seen by one camera at two turntable angles: noisy renders through the
/// default depth stage.
struct BoxViews {
    sensor: RigSensor,
    stage: DepthStage,
    angles: [u32; 2],
    grays: [Gray; 2],
    depths: [DepthMap; 2],
    masks: [Mask; 2],
}

impl BoxViews {
    /// Camera NP`camera`, turntable angles `angles` (degrees).
    fn render(camera: u8, angles: [u32; 2]) -> Self {
        let rig = Rig::bigbird_like();
        let id = SensorId::new(camera).unwrap();
        let sensor = rig.sensors[&id].clone();
        let scene = Scene::new(procedural("box", 1).unwrap().placed_on_table(0.01, -0.005), 1);
        let stage = DepthStage::new(DepthConfig::default()).unwrap();
        let noise = NoiseProfile::carmine();
        let frames = angles.map(|a| render_frame(&scene, &rig, id, a, Some(&noise), 1));
        let depths = [0, 1].map(|k| {
            stage.process(&frames[k].raw_depth, &frames[k].color, &frames[k].mask, &sensor.rgbd).unwrap().depth
        });
        Self {
            grays: [0, 1].map(|k| to_gray(&frames[k].color)),
            masks: frames.map(|f| f.mask),
            sensor,
            stage,
            angles,
            depths,
        }
    }

    fn view(&self, k: usize) -> FlowView<'_> {
        FlowView { gray: &self.grays[k], depth: &self.depths[k], mask: &self.masks[k], pyramids: None }
    }

    /// The motion from the first view to a view at turntable angle `to` (the colour frames).
    fn motion_to(&self, to: f64) -> Pose {
        let h = |angle: f64| self.sensor.h_color_from_world * world_from_table(angle);
        h(to) * h(f64::from(self.angles[0])).inverse()
    }

    /// The true motion between the two views.
    fn truth(&self) -> Pose {
        self.motion_to(f64::from(self.angles[1]))
    }

    /// Correspondence search between the two views, optionally guided by `guide`.
    fn pairs(&self, p: &CorrespondenceParams, guide: Option<&Pose>) -> FlowPairs {
        let rays = self.stage.rays(&self.sensor.rgbd.color);
        let guide = guide.map(|pose| FlowGuide { camera: &self.sensor.rgbd.color, pose });
        match guide {
            None => flow_correspondences(&LucasKanade::default(), &self.view(0), &self.view(1), &rays, p),
            Some(g) => {
                flow_correspondences_guided(&LucasKanade::default(), &self.view(0), &self.view(1), &rays, p, Some(g))
            }
        }
        .unwrap()
    }
}

/// The kept pairs' sorted 3-D errors against the true motion, and their indices.
fn kept_errors(pairs: &FlowPairs, truth: &Pose) -> (Vec<usize>, Vec<f64>) {
    let kept: Vec<usize> = (0..pairs.pairs.len()).filter(|&i| pairs.pairs.weights[i] > 0.0).collect();
    let mut errors: Vec<f64> =
        kept.iter().map(|&i| (truth * pairs.pairs.source[i] - pairs.pairs.target[i]).norm()).collect();
    errors.sort_by(f64::total_cmp);
    (kept, errors)
}

#[test]
fn box_correspondences_follow_the_true_motion() {
    let views = BoxViews::render(3, [0, 6]);
    let pairs = views.pairs(&CorrespondenceParams::default(), None);
    let (_, errors) = kept_errors(&pairs, &views.truth());
    let median = errors[errors.len() / 2];
    println!("{} tracked, {} pairs kept, median 3-D error {:.2} mm", pairs.tracked, errors.len(), median * 1e3);
    assert!(errors.len() > 200, "{} pairs", errors.len());
    assert!(median < 2e-3, "median error {median} m");
}

/// Guided tracking of a box turning 15 degrees under the top camera (rotation about the view
/// axis, the case where a translation-only window matches short of the motion): with windows
/// warped by the predicted motion, the pairs are closer to the truth and the rigid motion they
/// give is closer to the true turn than with translation-only windows. The guide is a
/// prediction 2 degrees short of the truth (a geometric registration's typical error).
#[test]
fn warped_windows_follow_a_turn_that_translated_windows_fall_short_of() {
    let views = BoxViews::render(5, [0, 15]);
    let truth = views.truth();
    let guess = views.motion_to(13.0);
    let run = |warp_windows: bool| {
        let pairs =
            views.pairs(&CorrespondenceParams { warp_windows, ..CorrespondenceParams::default() }, Some(&guess));
        let (kept, errors) = kept_errors(&pairs, &truth);
        let src: Vec<_> = kept.iter().map(|&i| pairs.pairs.source[i]).collect();
        let dst: Vec<_> = kept.iter().map(|&i| pairs.pairs.target[i]).collect();
        let pose = weighted_kabsch(&src, &dst, None).unwrap();
        let angle_error = (pose.rotation.angle() - truth.rotation.angle()).abs().to_degrees();
        (kept.len(), errors[errors.len() / 2], angle_error)
    };
    let (n_warped, median_warped, angle_warped) = run(true);
    let (n_plain, median_plain, angle_plain) = run(false);
    println!(
        "warped: {n_warped} pairs, median {:.2} mm, turn error {angle_warped:.3} deg; \
         translated: {n_plain} pairs, median {:.2} mm, turn error {angle_plain:.3} deg",
        median_warped * 1e3,
        median_plain * 1e3
    );
    assert!(n_warped > 200, "{n_warped} pairs");
    assert!(median_warped < median_plain, "median {median_warped} m vs {median_plain} m");
    assert!(angle_warped < 0.5 * angle_plain, "turn error {angle_warped} vs {angle_plain} deg");
    assert!(angle_warped < 0.3, "turn error {angle_warped} deg");
}

/// The plain and the guided pass of a pair read the frames' kept pyramids (one per frame and
/// crop, built by the first pass) and give the pairs that building them for each pass gives.
#[test]
fn kept_pyramids_give_the_same_pairs() {
    use flowfilter_flow::pyramid::PyramidCache;
    let views = BoxViews::render(3, [0, 9]);
    let caches = [PyramidCache::default(), PyramidCache::default()];
    let view = |k: usize, kept: bool| FlowView { pyramids: kept.then_some(&caches[k]), ..views.view(k) };
    let rays = views.stage.rays(&views.sensor.rgbd.color);
    let p = CorrespondenceParams::default();
    let guess = views.motion_to(8.0);
    let guide = || Some(FlowGuide { camera: &views.sensor.rgbd.color, pose: &guess });
    let lk = LucasKanade::default();
    let run = |kept: bool| {
        let plain = flow_correspondences(&lk, &view(0, kept), &view(1, kept), &rays, &p).unwrap();
        let guided = flow_correspondences_guided(&lk, &view(0, kept), &view(1, kept), &rays, &p, guide()).unwrap();
        (plain.pairs, guided.pairs)
    };
    let built = run(false);
    assert!(format!("{caches:?}").matches("PyramidKey").count() == 0, "nothing kept without a cache");
    let kept = run(true);
    assert_eq!(kept, built);
    assert!(built.0.len() > 200 && built.1.len() > 200, "{} and {} pairs", built.0.len(), built.1.len());
    for cache in &caches {
        assert_eq!(format!("{cache:?}").matches("PyramidKey").count(), 1, "{cache:?}");
    }
}
