//! The tracker on synthesised turntable streams (a textured box turning 3 degrees a frame, the
//! synth's sensor effects) and on a bad stream; the shared real sequences when present.

use flowfilter_bigbird::SensorId;
use flowfilter_geometry::Pose;
use flowfilter_pipeline::{Pipeline, PipelineConfig, RgbdFrame};
use flowfilter_synth::{NoiseProfile, Rig, Scene, procedural, render_frame, world_from_table};
use flowfilter_track::{TrackState, Tracker, TrackerConfig};

struct Stream {
    rig: Rig,
    scene: Scene,
    sensor: SensorId,
    /// The sensor's effects (none: exact images and depth).
    noise: Option<NoiseProfile>,
}

impl Stream {
    fn new() -> Self {
        Self::of("box", 3, None)
    }

    /// A procedural `object` turning on the table, seen by camera `NP{camera}` with `noise`.
    fn of(object: &str, camera: u8, noise: Option<NoiseProfile>) -> Self {
        let scene = Scene::new(procedural(object, 1).unwrap().placed_on_table(0.01, -0.005), 1);
        Self { rig: Rig::bigbird_like(), scene, sensor: SensorId::new(camera).unwrap(), noise }
    }

    /// The frame at `angle`, with its mask (`masked`) or without one.
    fn frame(&self, angle: u32, masked: bool) -> RgbdFrame {
        let f = render_frame(&self.scene, &self.rig, self.sensor, angle, self.noise.as_ref(), u64::from(angle) + 7);
        let sensor = self.rig.sensors[&self.sensor].rgbd;
        let mut frame = RgbdFrame {
            label: format!("{}_{angle}", self.sensor),
            color: f.color,
            depth: f.raw_depth,
            mask: f.mask,
            sensor,
        };
        if !masked {
            frame.mask.as_mut_slice().fill(true);
        }
        frame
    }

    /// The object's true motion from angle 0.
    fn truth(&self, angle: u32) -> Pose {
        let s = &self.rig.sensors[&self.sensor];
        let h = |a: u32| s.h_color_from_world * world_from_table(f64::from(a));
        h(angle) * h(0).inverse()
    }
}

fn tracker(stream: &Stream) -> Tracker {
    let pipeline = Pipeline::from_config(PipelineConfig::default()).unwrap();
    Tracker::new(pipeline, TrackerConfig::default(), &stream.frame(0, true)).unwrap()
}

/// ... and each frame's bounds from the first frame are its estimate's own composed with its
/// reference's (equal to the estimate's against the first frame, wider against a later
/// keyframe), hold on most frames, and are what the estimate from the first frame reports.
#[test]
fn an_object_is_tracked_from_its_first_mask_with_keyframes() {
    let stream = Stream::new();
    let mut t = tracker(&stream);
    assert_eq!(t.first().bound_from_first.map(|b| (b.rotation_deg, b.translation_m)), Some((0.0, 0.0)));
    let (mut worst, mut held, mut widened): (f64, usize, usize) = (0.0, 0, 0);
    for angle in (3..=30).step_by(3) {
        let r = t.update(Ok(stream.frame(angle, false)));
        assert_eq!(r.state, TrackState::Tracking, "{angle} deg: {:?}", r.reason);
        assert!(r.mask_px > 1000, "{angle} deg: the carried mask has {} pixels", r.mask_px);
        let error = (r.pose * stream.truth(angle).inverse()).rotation.angle().to_degrees();
        worst = worst.max(error);
        let bound = r.bound_from_first.expect("a tracked frame's pose has bounds");
        let own = r.estimate.as_ref().and_then(|e| e.registration.uncertainty).expect("the estimate's bounds");
        if r.reference == Some(0) {
            assert_eq!(bound, own, "{angle} deg: against the first frame the estimate's own bounds");
        } else {
            assert!(bound.rotation_deg > own.rotation_deg && bound.translation_m > own.translation_m, "{angle} deg");
            widened += 1;
        }
        held += usize::from(error <= bound.rotation_deg);
        assert_eq!(r.from_first("first", "flowfilter").registration.uncertainty, Some(bound));
    }
    assert!(worst < 1.0, "worst rotation error {worst} deg");
    assert!(widened > 0, "some frames measured against a later keyframe");
    assert!(held >= 8, "the bounds held on {held} of 10 frames");
    // 30 degrees of turn at a keyframe every 10 degrees or more: the first and 2-3 more.
    let k = t.keyframes();
    assert!(k.len() >= 3 && k[0] == 0, "keyframes {k:?}");
}

/// Each new frame is estimated with the mask predicted by the constant-velocity motion: no
/// mask is propagated by the pipeline (no `mask_propagated`), and the poses are those of the
/// unmasked path to within 0.3 degrees.
#[test]
fn the_predicted_mask_replaces_the_propagated_one() {
    let stream = Stream::new();
    let pipeline = || Pipeline::from_config(PipelineConfig::default()).unwrap();
    let first = stream.frame(0, true);
    let mut predicted = Tracker::new(pipeline(), TrackerConfig::default(), &first).unwrap();
    let unmasked_config = TrackerConfig { predicted_splat_px: 0, ..TrackerConfig::default() };
    let mut unmasked = Tracker::new(pipeline(), unmasked_config, &first).unwrap();
    let propagated = |r: &flowfilter_track::TrackedFrame| {
        r.estimate.as_ref().is_some_and(|e| e.warnings.iter().any(|w| w.code() == "mask_propagated"))
    };
    for angle in (3..=15).step_by(3) {
        let (a, b) =
            (predicted.update(Ok(stream.frame(angle, false))), unmasked.update(Ok(stream.frame(angle, false))));
        assert_eq!(a.state, TrackState::Tracking, "{angle} deg: {:?}", a.reason);
        assert!(propagated(&b), "{angle} deg: the unmasked path propagates the mask");
        // The second frame's prediction is the first frame's mask where it was (no motion yet).
        assert!(!propagated(&a), "{angle} deg: the predicted mask is used");
        let apart = (a.pose * b.pose.inverse()).rotation.angle().to_degrees();
        assert!(apart < 0.3, "{angle} deg: {apart} deg between the two paths");
        let error = (a.pose * stream.truth(angle).inverse()).rotation.angle().to_degrees();
        assert!(error < 1.0, "{angle} deg: {error} deg off");
    }
}

/// A can seen from above (NP5, the Carmine's effects) turns about its own axis: its lid looks
/// alike at every turn, so the pipeline warns that other turns fit as well (`ambiguous_pose`) and
/// does not converge. The constant-velocity prediction tells the turns apart: those frames are
/// tracked, their reason says so, and no frame is lost. Without the motion gate the same stream is
/// not tracked.
#[test]
fn the_motion_settles_a_symmetric_objects_ambiguous_turns() {
    let stream = Stream::of("can", 5, Some(NoiseProfile::carmine()));
    let run = |config: TrackerConfig| {
        let pipeline = Pipeline::from_config(PipelineConfig::default()).unwrap();
        let mut t = Tracker::new(pipeline, config, &stream.frame(0, true)).unwrap();
        (3..=18).step_by(3).map(|angle| (angle, t.update(Ok(stream.frame(angle, false))))).collect::<Vec<_>>()
    };
    let gated = run(TrackerConfig::default());
    let settled =
        gated.iter().filter(|(_, r)| r.reason.as_deref().is_some_and(|s| s.contains("settled by the motion")));
    assert!(settled.count() >= 2, "{:?}", gated.iter().map(|(a, r)| (a, r.state, &r.reason)).collect::<Vec<_>>());
    for (angle, r) in &gated {
        assert_ne!(r.state, TrackState::Lost, "{angle} deg: {:?}", r.reason);
        let error = (r.pose * stream.truth(*angle).inverse()).rotation.angle().to_degrees();
        assert!(error < 1.0, "{angle} deg: {error} deg off ({:?})", r.reason);
    }
    let ungated = run(TrackerConfig { motion_gate_deg: 0.0, ..TrackerConfig::default() });
    let doubted = ungated.iter().filter(|(_, r)| r.state != TrackState::Tracking).count();
    assert!(doubted >= 3, "without the gate {doubted} frames are uncertain or lost");
}

/// With the aligned path, frames the constant-velocity prediction follows are tracked by
/// direct alignment alone from it (`aligned_only`), at the full path's poses within 0.3
/// degrees; keyframes always come from the full path. When the object turns back, the prediction is 6 degrees off, beyond
/// the alignment's reach: that frame is not confirmed on the images and the full path gets it
/// right.
#[test]
fn a_followed_motion_is_tracked_by_alignment_alone() {
    let stream = Stream::new();
    let pipeline = || Pipeline::from_config(PipelineConfig::default()).unwrap();
    let first = stream.frame(0, true);
    let aligned_config = TrackerConfig { aligned_path: true, ..TrackerConfig::default() };
    let mut aligned = Tracker::new(pipeline(), aligned_config, &first).unwrap();
    let mut full = Tracker::new(pipeline(), TrackerConfig::default(), &first).unwrap();
    let mut by_alignment = 0;
    for angle in (3..=24).step_by(3) {
        let (a, b) = (aligned.update(Ok(stream.frame(angle, false))), full.update(Ok(stream.frame(angle, false))));
        assert_eq!(a.state, TrackState::Tracking, "{angle} deg: {:?}", a.reason);
        assert!(!b.aligned_only, "{angle} deg: the full path only");
        assert!(!(a.aligned_only && a.keyframe), "{angle} deg: a keyframe from the aligned path");
        let error = (a.pose * stream.truth(angle).inverse()).rotation.angle().to_degrees();
        assert!(error < 1.0, "{angle} deg: {error} deg off (aligned only: {})", a.aligned_only);
        if a.aligned_only {
            by_alignment += 1;
            let apart = (a.pose * b.pose.inverse()).rotation.angle().to_degrees();
            assert!(apart < 0.3, "{angle} deg: {apart} deg from the full path");
        }
    }
    assert!(by_alignment >= 3, "{by_alignment} frames by alignment alone");
    let back = aligned.update(Ok(stream.frame(21, false)));
    assert!(!back.aligned_only, "a turn back is not what the motion predicts");
    let error = (back.pose * stream.truth(21).inverse()).rotation.angle().to_degrees();
    assert!(error < 1.0, "turned back: {error} deg off");
}

#[test]
fn a_bad_stream_gives_a_state_and_a_reason_per_frame_and_recovers() {
    let stream = Stream::new();
    let mut t = tracker(&stream);
    assert_eq!(t.update(Ok(stream.frame(3, false))).state, TrackState::Tracking);
    // A missing file, as the CLI reports it.
    let r = t.update(Err("frame-000002.depth.png: cannot read the image: No such file".into()));
    assert_eq!(r.state, TrackState::Lost);
    assert!(r.reason.as_deref().unwrap().contains("depth.png"), "{:?}", r.reason);
    // A frame of another size.
    let mut small = stream.frame(6, false);
    small.color = image::imageops::crop_imm(&small.color, 0, 0, 320, 240).to_image();
    let r = t.update(Ok(small));
    assert_eq!(r.state, TrackState::Lost);
    assert!(r.reason.as_deref().unwrap().contains("another size"), "{:?}", r.reason);
    // The object gone (depth only of the background far away): lost, the pose held.
    let mut empty = stream.frame(9, false);
    let held = r.pose;
    empty.depth.as_mut_slice().fill(0);
    let r = t.update(Ok(empty));
    assert_eq!(r.state, TrackState::Lost, "{:?}", r.reason);
    assert_eq!(r.pose, held, "a lost frame holds the last pose");
    assert!(r.bound_from_first.is_none(), "a held pose is not bounded");
    // Back in view: recovered against the keyframes, at the right pose.
    let r = t.update(Ok(stream.frame(9, false)));
    assert_eq!(r.state, TrackState::Recovered, "{:?}", r.reason);
    let error = (r.pose * stream.truth(9).inverse()).rotation.angle().to_degrees();
    assert!(error < 1.0, "{error} deg after recovery");
    assert_eq!(t.update(Ok(stream.frame(12, false))).state, TrackState::Tracking);
}

/// A stream prepared ahead ([`Tracker::update_stream`]: the next frame prepared on another
/// thread while the tracker estimates the one before, as `flowfilter track` runs) gives the same poses, states and
/// reasons, to the bit, as frames pushed one at a time; a frame the preparer cannot use (another
/// size) is lost with its reason there too.
#[test]
fn frames_prepared_ahead_give_the_same_track() {
    let stream = Stream::new();
    let mut frames: Vec<RgbdFrame> = (3..=15).step_by(3).map(|a| stream.frame(a, false)).collect();
    frames[2].color = image::imageops::crop_imm(&frames[2].color, 0, 0, 320, 240).to_image();
    let mut one_by_one = tracker(&stream);
    let expected: Vec<_> = frames.iter().map(|f| one_by_one.update(Ok(f.clone()))).collect();
    let mut ahead = tracker(&stream);
    let mut got = vec![];
    let streamed = ahead.update_stream(frames.iter().enumerate().map(|(k, f)| (k, Ok(f.clone()))), |k, r| {
        got.push(r);
        if k + 1 == got.len() { Ok(()) } else { Err("out of order") }
    });
    assert_eq!(streamed, Ok(()));
    assert_eq!(got.len(), expected.len());
    for (a, b) in got.iter().zip(&expected) {
        assert_eq!((a.pose, a.state, &a.reason, &a.label), (b.pose, b.state, &b.reason, &b.label));
    }
    assert_eq!(got[2].state, TrackState::Lost);
    assert!(got[2].reason.as_deref().unwrap().contains("another size"), "{:?}", got[2].reason);
    // A frame prepared for another stream (of another size) is refused the same way.
    let small = small_frame();
    let other =
        Tracker::new(Pipeline::from_config(PipelineConfig::default()).unwrap(), TrackerConfig::default(), &small)
            .unwrap();
    let r = ahead.update_prepared(other.preparer().prepare(Ok(small)));
    assert_eq!(r.state, TrackState::Lost);
    assert!(r.reason.as_deref().unwrap().contains("another size: 160x120"), "{:?}", r.reason);
}

/// A 160 x 120 frame of registered depth: a textured plane 0.7 m away, a square object mask.
fn small_frame() -> RgbdFrame {
    use flowfilter_pipeline::camera::{CameraModel, Distortion, ImageSize, Intrinsics};
    let size = ImageSize::new(160, 120).unwrap();
    let camera = CameraModel::new(Intrinsics::new(150.0, 150.0, 79.5, 59.5).unwrap(), Distortion::NONE, size);
    RgbdFrame {
        label: "small".into(),
        color: image::RgbImage::from_fn(160, 120, |x, y| {
            image::Rgb([(x * 3) as u8, (y * 5) as u8, ((x * y) % 251) as u8])
        }),
        depth: flowfilter_geometry::RawDepth::from_fn(160, 120, |_, _| 700),
        mask: flowfilter_geometry::Mask::from_fn(160, 120, |x, y| (40..120).contains(&x) && (30..90).contains(&y)),
        sensor: flowfilter_pipeline::RgbdSensor::registered(camera, 1e-3).unwrap(),
    }
}

/// An object's frames are prepared on the region where the object is predicted, not the whole
/// 1280 x 1024 image, and give the poses whole frames give; a region without a margin, which
/// cannot hold the object's carried mask, is given up for the whole frame, and the frame is
/// tracked all the same.
#[test]
fn frames_are_prepared_on_the_objects_predicted_region() {
    let stream = Stream::new();
    let angles: Vec<u32> = (3..=15).step_by(3).collect();
    let run = |settings: TrackerConfig| {
        let pipeline = Pipeline::from_config(PipelineConfig::default()).unwrap();
        let mut t = Tracker::new(pipeline, settings, &stream.frame(0, true)).unwrap();
        angles.iter().map(|&a| t.update(Ok(stream.frame(a, false)))).collect::<Vec<_>>()
    };
    let regional = run(TrackerConfig::default());
    // Prepared ahead (each frame's region predicted two frames back), the same track.
    let pipeline = Pipeline::from_config(PipelineConfig::default()).unwrap();
    let mut ahead = Tracker::new(pipeline, TrackerConfig::default(), &stream.frame(0, true)).unwrap();
    let mut streamed = vec![];
    let frames = angles.iter().map(|&a| ((), Ok(stream.frame(a, false))));
    let done: Result<(), ()> = ahead.update_stream(frames, |(), r| {
        streamed.push(r);
        Ok(())
    });
    assert_eq!((done, streamed.len()), (Ok(()), angles.len()));
    for (a, b) in streamed.iter().zip(&regional) {
        assert_eq!((a.pose, a.state, &a.reason, a.prepared_region), (b.pose, b.state, &b.reason, b.prepared_region));
    }
    let whole = run(TrackerConfig { prepare_region: false, ..TrackerConfig::default() });
    let tight = run(TrackerConfig { region_margin: 0.0, ..TrackerConfig::default() });
    let truth_deg = |f: &flowfilter_track::TrackedFrame, angle: u32| {
        (f.pose * stream.truth(angle).inverse()).rotation.angle().to_degrees()
    };
    for (k, &angle) in angles.iter().enumerate() {
        for f in [&regional[k], &whole[k], &tight[k]] {
            assert_eq!(f.state, TrackState::Tracking, "{angle} deg: {:?}", f.reason);
            assert!(truth_deg(f, angle) < 0.2, "{angle} deg: {} deg off", truth_deg(f, angle));
        }
        let apart = (regional[k].pose * whole[k].pose.inverse()).rotation.angle().to_degrees();
        assert!(apart < 1e-3, "{angle} deg: {apart} deg from the whole frame's pose");
        // A quarter of the image or less, around the object.
        let flowfilter_track::boxed::PixelBox { x, y, width: w, height: h } =
            regional[k].prepared_region.expect("prepared on a region");
        assert!(w * h < 1280 * 1024 / 4 && x + w <= 1280 && y + h <= 1024, "{:?}", regional[k].prepared_region);
        assert_eq!((whole[k].prepared_region, tight[k].prepared_region), (None, None));
    }
}

/// Seen level with the turntable (NP1), the box shows one face at the start; turned 90 deg, that
/// face is edge-on and the next one faces the camera. With `TrackerConfig::reveal` (an option)
/// the carried mask takes in the face that turns into view: at 90 deg it covers nearly all of
/// what the camera sees of the box, and the track holds. Without it the mask keeps what the
/// first frame saw (two thirds of the box's pixels at 90 deg, and falling). The turntable
/// turns with the box: both masks creep onto it alike.
#[test]
fn the_carried_mask_takes_in_the_faces_that_turn_into_view() {
    let stream = Stream::of("box", 1, None);
    let angles: Vec<u32> = (6..=90).step_by(6).collect();
    // Per frame: the share of the object's visible pixels the carried mask covers, and the
    // pixels it covers off the object.
    let run = |settings: TrackerConfig| {
        let pipeline = Pipeline::from_config(PipelineConfig::default()).unwrap();
        let mut t = Tracker::new(pipeline, settings, &stream.frame(0, true)).unwrap();
        let mut out = vec![];
        for &angle in &angles {
            let r = t.update(Ok(stream.frame(angle, false)));
            assert_eq!(r.state, TrackState::Tracking, "{angle} deg: {:?}", r.reason);
            let error = (r.pose * stream.truth(angle).inverse()).rotation.angle().to_degrees();
            assert!(error < 0.5, "{angle} deg: {error} deg off");
            let (carried, truth) = (t.object_mask().expect("a mask"), stream.frame(angle, true).mask);
            assert_eq!(carried.count(), r.mask_px);
            let both = carried.as_slice().iter().zip(truth.as_slice()).filter(|(a, b)| **a && **b).count();
            out.push((both as f64 / truth.count() as f64, carried.count() - both));
        }
        out
    };
    let grown = run(TrackerConfig { reveal: true, ..TrackerConfig::default() });
    let kept = run(TrackerConfig::default());
    let last = angles.len() - 1;
    assert!(grown[last].0 > 0.9, "at 90 deg the grown mask covers {:.2} of the object", grown[last].0);
    assert!(kept[last].0 < 0.75, "at 90 deg the kept mask covers {:.2} of the object", kept[last].0);
    for (k, &angle) in angles.iter().enumerate() {
        assert!(grown[k].0 >= kept[k].0 - 0.01, "{angle} deg: {:?} against {:?}", grown[k], kept[k]);
        // What it adds is the object's: off the object, at most a few percent more than the
        // carried mask alone.
        assert!(grown[k].1 <= kept[k].1 + 3000, "{angle} deg: {:?} against {:?}", grown[k], kept[k]);
    }
}
