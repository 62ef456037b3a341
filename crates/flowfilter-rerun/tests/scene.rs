//! What a recording shows, checked without Rerun: a synthesised pair with known motion, its
//! flow pairs classified against the estimate, the clouds moved, the judge's table, and (with
//! the `rerun` feature) the recording written; without it, the error that says how to get it.

use flowfilter_bigbird::SensorId;
use flowfilter_geometry::{Pose, Vector3};
use flowfilter_pipeline::{Pipeline, PipelineConfig, PreparedFrame, RgbdFrame};
use flowfilter_rerun::{FrameInput, INLIER_COLOR, OUTLIER_COLOR, PairScene, Recorder, UNUSED_COLOR};
use flowfilter_synth::{Rig, Scene, procedural, render_frame, world_from_table};

struct Pair {
    frames: (RgbdFrame, RgbdFrame),
    prepared: (PreparedFrame, PreparedFrame),
    truth: Pose,
    pipeline: Pipeline,
}

fn pair(from: u32, to: u32) -> Pair {
    let (rig, sensor) = (Rig::bigbird_like(), SensorId::new(3).unwrap());
    let scene = Scene::new(procedural("box", 1).unwrap().placed_on_table(0.01, -0.005), 1);
    let frame = |angle| {
        let f = render_frame(&scene, &rig, sensor, angle, None, 7);
        let rgbd = rig.sensors[&sensor].rgbd;
        RgbdFrame { label: format!("NP3_{angle}"), color: f.color, depth: f.raw_depth, mask: f.mask, sensor: rgbd }
    };
    let pipeline = Pipeline::from_config(PipelineConfig::default()).unwrap();
    let (fa, fb) = (frame(from), frame(to));
    let (a, b) = (pipeline.prepare(&fa).unwrap(), pipeline.prepare(&fb).unwrap());
    let s = &rig.sensors[&sensor];
    let h = |angle: u32| s.h_color_from_world * world_from_table(f64::from(angle));
    let truth = h(to) * h(from).inverse();
    Pair { frames: (fa, fb), prepared: (a, b), truth, pipeline }
}

fn scene_of(p: &Pair, pose_override: Option<Pose>) -> PairScene {
    let (mut e, trace) = p.pipeline.estimate_traced(&p.prepared.0, &p.prepared.1).unwrap();
    if let Some(pose) = pose_override {
        e.pose = pose;
    }
    let e = e.with_ground_truth(&p.truth, Some(&p.prepared.0.cloud.points));
    let model = FrameInput { color: &p.frames.0.color, prepared: &p.prepared.0 };
    let target = FrameInput { color: &p.frames.1.color, prepared: &p.prepared.1 };
    PairScene::new(model, target, &e, &trace, Some(&p.truth))
}

#[test]
fn a_good_estimate_shows_its_flow_pairs_as_inliers_and_its_clouds_aligned() {
    let p = pair(0, 8);
    let scene = scene_of(&p, None);
    let (inliers, kept) = scene.kept_inliers();
    assert!(kept >= 30 && inliers * 10 >= kept * 7, "{inliers} of {kept} kept pairs agree");
    assert!(
        scene
            .flow
            .iter()
            .all(|f| f.color()
                == if f.kept { if f.inlier { INLIER_COLOR } else { OUTLIER_COLOR } } else { UNUSED_COLOR })
    );
    // On the images: the pairs move as the object turned (8 deg on the turntable: pixels, not zero).
    let moved = scene
        .flow
        .iter()
        .filter(|f| f.kept)
        .map(|f| (f.target_px[0] - f.model_px[0]).hypot(f.target_px[1] - f.model_px[1]));
    let mean = moved.clone().sum::<f32>() / moved.count() as f32;
    assert!(mean > 2.0, "mean image motion {mean} px");
    // The aligned cloud lies on the truth's (an estimate within a degree).
    let truth = scene.truth_cloud.as_ref().unwrap();
    let worst = scene.aligned_cloud.iter().zip(truth).map(|(a, t)| dist(a, t)).fold(0.0f32, f32::max);
    assert!(worst < 0.01, "aligned and true model clouds {worst} m apart");
    let (rot, _) = scene.errors.unwrap();
    assert!(rot < 1.0, "{rot}");
    let (bound_deg, _) = scene.bounds.expect("Flow Filter gives error bounds");
    assert!(bound_deg > 0.0 && bound_deg < 5.0, "{bound_deg}");
    assert_eq!(scene.timings_ms.len(), flowfilter_rerun::paths::STAGES.len());
    assert!(scene.summary_json.contains("\"transform\""));
    assert_eq!(scene.model.mask.as_slice(), p.prepared.0.mask.as_slice());
}

#[test]
fn a_wrong_pose_shows_the_same_pairs_as_outliers() {
    let p = pair(0, 8);
    let wrong = Pose::new(Vector3::new(0.03, 0.0, 0.0), Vector3::new(0.0, 0.3, 0.0));
    let scene = scene_of(&p, Some(wrong));
    let (inliers, kept) = scene.kept_inliers();
    assert!(kept >= 30 && inliers * 10 < kept, "{inliers} of {kept} kept pairs agree with a pose 17 deg off");
    let far = scene.aligned_cloud.iter().zip(scene.truth_cloud.as_ref().unwrap()).map(|(a, t)| dist(a, t));
    assert!(far.fold(0.0f32, f32::max) > 0.02);
}

#[test]
fn the_judges_candidates_are_tabled_best_first() {
    // 15 degrees: the judge runs (its gate skips small answers the flow agrees on).
    let p = pair(0, 15);
    let scene = scene_of(&p, None);
    assert!(!scene.candidates.is_empty(), "the judge weighed no candidate");
    let table = scene.candidates_table();
    assert!(table.starts_with("Answer's score: "), "{table}");
    let scores: Vec<f64> = table
        .lines()
        .filter(|l| l.starts_with("| ("))
        .filter_map(|l| l.rsplit('|').nth(1).and_then(|s| s.trim().parse().ok()))
        .collect();
    assert!(!scores.is_empty() && scores.windows(2).all(|w| w[0] <= w[1]), "{scores:?}");
    assert!(scene.best_candidate_cloud.is_some());
}

fn dist(a: &[f32; 3], b: &[f32; 3]) -> f32 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

#[cfg(not(feature = "rerun"))]
#[test]
fn without_the_feature_the_recorder_says_how_to_get_one() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("pair.rrd");
    let Err(e) = Recorder::create(&path, "test") else { panic!("recorded without the feature") };
    assert!(matches!(e, flowfilter_rerun::RecordError::NotBuilt { .. }));
    assert!(e.to_string().contains("--features rerun"), "{e}");
    assert!(!path.exists());
    const { assert!(!flowfilter_rerun::CAN_RECORD) };
}

#[cfg(feature = "rerun")]
#[test]
fn a_recording_of_two_pairs_is_written() {
    let p = pair(0, 8);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("pairs.rrd");
    let recorder = Recorder::create(&path, "test").unwrap();
    recorder.log_pair(0, &scene_of(&p, None)).unwrap();
    recorder.log_pair(1, &scene_of(&p, Some(Pose::identity()))).unwrap();
    recorder.finish().unwrap();
    let bytes = std::fs::read(&path).unwrap();
    // Two pairs' images (1280x1024 colour and depth, LZ4-compressed): megabytes, not a header.
    assert!(bytes.len() > 2_000_000, "{} bytes", bytes.len());
    assert_eq!(&bytes[..4], b"RRF2", "not an RRD file");
}
