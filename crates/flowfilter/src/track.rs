//! `flowfilter track`: an RGB-D stream in (a folder of frames), the object's pose in every frame
//! relative to the first out, with a state and a reason per frame.

use anyhow::Context;
use clap::Args;
use flowfilter_eval::trajectory::trajectory_errors;
use flowfilter_eval::{geodesic_error_deg, translation_error_m};
use flowfilter_geometry::Pose;
use flowfilter_geometry::atomic::{check_writable_dir, check_writable_file, write_atomic_with};
use flowfilter_pipeline::bop::BopScene;
use flowfilter_pipeline::{CameraFile, FrameFiles, MaskSource, RgbdFrame, matrix_rows};
use flowfilter_rerun::{FrameInput, PairScene, Recorder};
use flowfilter_track::boxed::{self, PixelBox};
use flowfilter_track::{FrameEntry, FrameFolder, TrackState, TrackedFrame, Tracker, TrackerConfig, tum};
use image::RgbImage;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Arguments of `track`.
#[derive(Args)]
pub struct TrackArgs {
    /// A folder of frames: `frame-NNNNNN.color.png|jpg` + `frame-NNNNNN.depth.png`, or
    /// YCB-Video's `NNNNNN-color.png` + `NNNNNN-depth.png` (other files are ignored); or an image
    /// list: a text file of `COLOR DEPTH` lines or TUM's associated `T_COLOR COLOR T_DEPTH DEPTH`
    /// lines, paths relative to the list (frames numbered in list order).
    #[arg(long, required_unless_present = "bop", conflicts_with = "bop")]
    pub frames: Option<PathBuf>,
    /// The camera file (JSON: ours, BOP's, Open3D's PinholeCameraIntrinsic); with --bop, the
    /// scene's own.
    #[arg(long, required_unless_present = "bop")]
    pub camera: Option<PathBuf>,
    /// A BOP scene folder (`scene_camera.json`, `scene_gt.json`, `rgb/`, `depth/`,
    /// `mask_visib/`) instead of --frames: the images where `--object` is annotated, in order;
    /// its visible mask in the first one; the annotations as the truth (unless --gt).
    #[arg(long, requires = "object")]
    pub bop: Option<PathBuf>,
    /// With --bop: the object's id (`obj_id`).
    #[arg(long, requires = "bop")]
    pub object: Option<u32>,
    /// The object's mask in the first frame (binary PNG). Without it (and without --box) the
    /// whole scene is tracked.
    #[arg(long, conflicts_with = "bbox")]
    pub mask: Option<PathBuf>,
    /// A box around the object in the first frame instead of a mask: `X,Y,W,H` (pixels: left,
    /// top, width, height). The object is the box's pixels within 5 cm of the depth of the
    /// box's central half (the background behind it is left out).
    #[arg(long = "box", id = "bbox", value_name = "X,Y,W,H")]
    pub bbox: Option<String>,
    /// Frames to use: at most this many, from the first.
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Pipeline configuration (TOML; default: configs/flowfilter.toml's values).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// The tracker's settings (TOML: the keys of `flowfilter_track::TrackerConfig`, e.g.
    /// `aligned_path = true`); default: its defaults.
    #[arg(long)]
    pub tracker: Option<PathBuf>,
    /// Write one JSON line per frame (`frame`, `state`, `reason`, `reference`, `keyframe`,
    /// `aligned_only`, `prepared_region` (`[x, y, width, height]` of the image the frame was
    /// prepared on, null: whole), `pose_from_first`, `bound_from_first` (`rotation_deg`,
    /// `translation_m`: bounds on that pose's error, the estimates' bounds composed along the
    /// chain of references back to the first frame; null where one has none), the errors with
    /// --gt, and `estimate`: the `estimate --json` fields).
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write the trajectory in the TUM format (`timestamp tx ty tz qx qy qz qw`: the object's
    /// motion from the first frame, `P_k = T_0k P_0`), for `evo` and the TUM tools.
    #[arg(long)]
    pub tum: Option<PathBuf>,
    /// Frames per second of the stream: TUM timestamps are frame number / fps (a TUM image
    /// list's own timestamps are kept).
    #[arg(long, default_value_t = 30.0)]
    pub fps: f64,
    /// The true motion, for the errors: a TUM file of `T_0k`, or a `poses.json` of calibrated
    /// camera poses (`camera_to_world_calibrated`: a static scene, the camera moving).
    #[arg(long)]
    pub gt: Option<PathBuf>,
    /// Write a Rerun recording: each frame's estimate against its reference (both frames,
    /// depth, masks, clouds, flow pairs, the judge's candidates, pose, bounds, times) at the
    /// frame's index on the `pair` timeline (docs/rerun.md). Needs `--features rerun`.
    #[arg(long)]
    pub rerun: Option<PathBuf>,
    /// Write an overlay per frame to this folder (`frame-NNNNNN.png`): the frame darkened, the
    /// first frame's object cloud where it was (red) and moved by the frame's pose (green).
    #[arg(long)]
    pub viz: Option<PathBuf>,
}

/// Run `track`.
pub fn run(args: &TrackArgs) -> anyhow::Result<ExitCode> {
    for (path, flag) in [(&args.json, "--json"), (&args.tum, "--tum"), (&args.rerun, "--rerun")] {
        if let Some(p) = path {
            check_writable_file(p).context(flag)?;
        }
    }
    if let Some(dir) = &args.viz {
        check_writable_dir(dir).context("--viz")?;
    }
    if let Some(path) = args.rerun.as_ref().filter(|_| !flowfilter_rerun::CAN_RECORD) {
        return Err(flowfilter_rerun::RecordError::NotBuilt { path: path.clone() }).context("--rerun");
    }
    if !(args.fps.is_finite() && args.fps > 0.0) {
        anyhow::bail!("--fps: expected a positive number of frames per second, found {}", args.fps);
    }
    let Input { mut folder, camera, first_mask, bop_truth } = open_input(args)?;
    if let Some(n) = args.max_frames {
        folder.frames.truncate(n.max(1));
    }
    let numbers: Vec<u64> = folder.frames.iter().map(|f| f.number).collect();
    let truth = match &args.gt {
        Some(p) => Some(tum::read_truth(p, &numbers)?),
        None => bop_truth,
    };
    let pipeline = crate::estimate::pipeline(args.config.as_deref(), None)?;
    let mut first = load(&folder.frames[0], &camera, first_mask).context("the first frame")?;
    if let Some(text) = &args.bbox {
        first.mask = boxed::first_mask(&pipeline, &first, parse_box(text)?).context("--box")?;
    }
    let settings = match &args.tracker {
        Some(path) => TrackerConfig::from_file(path).context("--tracker")?,
        None => TrackerConfig::default(),
    };
    let config = TrackerConfig { trace: args.rerun.is_some(), ..settings };
    let mut tracker = Tracker::new(pipeline, config, &first)?;
    let recording = args.rerun.as_deref().map(|p| Recorder::create(p, "flowfilter track")).transpose()?;
    let mut colours: Vec<Option<RgbImage>> = vec![recording.as_ref().map(|_| first.color.clone())];
    if let Some(dir) = &args.viz {
        let f = tracker.first_frame();
        let image = crate::estimate::overlay_cloud(&first.color, &f.sensor.color, &f.cloud.points, &Pose::identity());
        crate::save_image(&image, &dir.join(format!("{}.png", folder.frames[0].label())))?;
    }
    let started = std::time::Instant::now();
    let bar = crate::progress::bar(folder.frames.len(), "frames");
    bar.set_message("track");
    let mut out: Vec<TrackedFrame> = vec![tracker.first()];
    crate::progress::advance(&bar, 1);
    // What the overlays draw: the first frame's cloud, moved by each pose.
    let (first_camera, first_points) = (tracker.first_frame().sensor.color, tracker.first_frame().cloud.points.clone());
    let keep_colour = args.viz.is_some() || recording.is_some();
    let frames = folder.frames.iter().skip(1).map(|entry| {
        let frame = load(entry, &camera, MaskSource::None).map_err(|e| format!("{e:#}"));
        let colour = frame.as_ref().ok().filter(|_| keep_colour).map(|f| f.color.clone());
        ((entry, colour), frame)
    });
    tracker.update_stream(frames, |(entry, colour), mut tracked| -> anyhow::Result<()> {
        colours.push(recording.as_ref().and(colour.clone()));
        if let (Some(dir), Some(colour)) = (&args.viz, colour) {
            let image = crate::estimate::overlay_cloud(&colour, &first_camera, &first_points, &tracked.pose);
            crate::save_image(&image, &dir.join(format!("{}.png", entry.label())))?;
        }
        if let Some(recorder) = &recording {
            record(recorder, &mut tracked, &colours, &folder.frames, truth.as_ref())?;
        }
        out.push(tracked);
        crate::progress::advance(&bar, out.len());
        Ok(())
    })?;
    bar.finish_and_clear();
    if let Some(recorder) = recording {
        recorder.finish()?;
    }
    let rows: Vec<serde_json::Value> =
        out.iter().zip(&folder.frames).map(|(t, f)| json_row(t, f, truth.as_ref())).collect();
    if let Some(path) = &args.json {
        write_lines(path, rows.iter().map(serde_json::Value::to_string))?;
    }
    if let Some(path) = &args.tum {
        let header = std::iter::once(
            "# timestamp tx ty tz qx qy qz qw (flowfilter track: the object's motion from the first frame)".to_string(),
        );
        let lines = out
            .iter()
            .zip(&folder.frames)
            .map(|(t, f)| tum::line(f.timestamp.unwrap_or(f.number as f64 / args.fps), &t.pose));
        write_lines(path, header.chain(lines))?;
    }
    let rate = Rate { frames: out.len() - 1, seconds: started.elapsed().as_secs_f64() };
    print_summary(&out, &folder.frames, truth.as_ref(), rate);
    Ok(ExitCode::SUCCESS)
}

/// A frame's estimate against its reference, recorded at the frame's index (its trace then
/// dropped: a recording of a long stream does not hold every frame in memory).
fn record(
    recorder: &Recorder,
    tracked: &mut TrackedFrame,
    colours: &[Option<RgbImage>],
    frames: &[FrameEntry],
    truth: Option<&BTreeMap<u64, Pose>>,
) -> anyhow::Result<()> {
    let (Some(pair), Some(e), Some(reference)) = (tracked.traced.take(), tracked.estimate.as_ref(), tracked.reference)
    else {
        return Ok(());
    };
    let (Some(Some(model_colour)), Some(Some(colour))) = (colours.get(reference), colours.get(tracked.index)) else {
        return Ok(());
    };
    let pair_truth = truth.and_then(|t| {
        let (a, b) = (t.get(&frames[reference].number)?, t.get(&frames[tracked.index].number)?);
        Some(b * a.inverse())
    });
    let e = match &pair_truth {
        Some(t) => e.clone().with_ground_truth(t, Some(&pair.model.cloud.points)),
        None => e.clone(),
    };
    let model = FrameInput { color: model_colour, prepared: &pair.model };
    let target = FrameInput { color: colour, prepared: &pair.target };
    let step = i64::try_from(tracked.index).unwrap_or(i64::MAX);
    recorder.log_pair(step, &PairScene::new(model, target, &e, &pair.trace, pair_truth.as_ref()))?;
    Ok(())
}

/// The frames, the camera and the first frame's mask: from --frames and --camera (the mask
/// from --mask, if any), or from a --bop scene (the object's visible mask unless --mask) with
/// its annotations as the truth.
struct Input {
    folder: FrameFolder,
    camera: CameraFile,
    first_mask: MaskSource,
    /// With --bop: the object's annotated motion from the first image, by image number.
    bop_truth: Option<BTreeMap<u64, Pose>>,
}

fn open_input(args: &TrackArgs) -> anyhow::Result<Input> {
    let given_mask = args.mask.clone().map(MaskSource::Binary);
    let (Some(dir), Some(obj)) = (&args.bop, args.object) else {
        let (Some(frames), Some(camera)) = (args.frames.as_deref(), args.camera.as_deref()) else {
            anyhow::bail!("--frames and --camera are needed without --bop");
        };
        let (folder, camera) = (FrameFolder::open_any(frames)?, CameraFile::from_file(camera)?);
        return Ok(Input { folder, camera, first_mask: given_mask.unwrap_or(MaskSource::None), bop_truth: None });
    };
    let scene = BopScene::open(dir)?;
    let ids: Vec<u32> = scene.image_ids().into_iter().filter(|&im| scene.instance(im, obj).is_ok()).collect();
    let Some(&first) = ids.first() else {
        anyhow::bail!("--bop {}: object {obj} is annotated in none of its images", dir.display());
    };
    let camera = match &args.camera {
        Some(path) => CameraFile::from_file(path)?,
        None => scene.camera(first)?,
    };
    let mut first_mask = MaskSource::None;
    let mut frames = vec![];
    let mut truth = BTreeMap::new();
    for &im in &ids {
        let files = scene.files(im, obj)?;
        if im == first {
            first_mask = files.mask;
        }
        frames.push(FrameEntry { number: u64::from(im), color: files.color, depth: files.depth, timestamp: None });
        truth.insert(u64::from(im), scene.relative_motion(first, im, obj)?);
    }
    let folder = FrameFolder { dir: dir.clone(), frames };
    Ok(Input { folder, camera, first_mask: given_mask.unwrap_or(first_mask), bop_truth: Some(truth) })
}

/// `X,Y,W,H` of `--box`.
fn parse_box(text: &str) -> anyhow::Result<PixelBox> {
    let v: Vec<usize> =
        text.split(',').map(|s| s.trim().parse()).collect::<Result<_, _>>().map_err(|_| {
            anyhow::anyhow!("--box: expected X,Y,W,H (pixels: left, top, width, height), found {text:?}")
        })?;
    match v[..] {
        [x, y, width, height] if width > 0 && height > 0 => Ok(PixelBox { x, y, width, height }),
        _ => anyhow::bail!("--box: expected X,Y,W,H with a positive width and height, found {text:?}"),
    }
}

/// One frame from its files (the mask only for the first).
fn load(entry: &FrameEntry, camera: &CameraFile, mask: MaskSource) -> anyhow::Result<RgbdFrame> {
    let files = FrameFiles { color: entry.color.clone(), depth: entry.depth.clone(), mask };
    Ok(files.load(camera, &entry.label())?)
}

fn json_row(t: &TrackedFrame, f: &FrameEntry, truth: Option<&BTreeMap<u64, Pose>>) -> serde_json::Value {
    let mut row = serde_json::json!({
        "frame": f.number,
        "label": t.label,
        "state": t.state,
        "reason": t.reason,
        "reference": t.reference,
        "keyframe": t.keyframe,
        "mask_px": t.mask_px,
        "aligned_only": t.aligned_only,
        "prepared_region": t.prepared_region.map(|r| [r.x, r.y, r.width, r.height]),
        "pose_from_first": matrix_rows(&t.pose),
        "bound_from_first": t.bound_from_first,
        "estimate": t.estimate,
    });
    if let Some(g) = truth.and_then(|m| m.get(&f.number)) {
        row["errors"] = serde_json::json!({
            "rotation_deg": geodesic_error_deg(&t.pose, g),
            "translation_m": translation_error_m(&t.pose, g),
        });
    }
    row
}

fn write_lines(path: &Path, lines: impl Iterator<Item = String>) -> anyhow::Result<()> {
    let lines: Vec<String> = lines.collect();
    write_atomic_with(path, |p| {
        let mut f = std::io::BufWriter::new(std::fs::File::create(p)?);
        for l in &lines {
            writeln!(f, "{l}")?;
        }
        f.flush()
    })
    .with_context(|| format!("writing {}", path.display()))
}

/// How fast the frames after the first went through: reading, preparing and tracking them
/// (the overlays and the recording included when asked for).
struct Rate {
    frames: usize,
    seconds: f64,
}

fn print_summary(out: &[TrackedFrame], frames: &[FrameEntry], truth: Option<&BTreeMap<u64, Pose>>, rate: Rate) {
    for (t, f) in out.iter().zip(frames) {
        let state = serde_json::to_value(t.state).ok().and_then(|v| v.as_str().map(str::to_string)).unwrap_or_default();
        let error = truth.and_then(|m| m.get(&f.number)).map_or(String::new(), |g| {
            format!(", error {:.2} deg {:.1} mm", geodesic_error_deg(&t.pose, g), translation_error_m(&t.pose, g) * 1e3)
        });
        let reference = t.reference.map_or(String::new(), |r| format!(" vs {}", frames[r].label()));
        let reason = t.reason.as_ref().map_or(String::new(), |r| format!(" ({r})"));
        println!(
            "{}: {state}{reference}{}, {:.2} deg {:.1} mm from the first{error}{reason}",
            f.label(),
            if t.keyframe { ", keyframe" } else { "" },
            t.pose.rotation.angle().to_degrees(),
            t.pose.translation.vector.norm() * 1e3
        );
    }
    let count = |s: TrackState| out.iter().filter(|t| t.state == s).count();
    let per_second = if rate.seconds > 0.0 { rate.frames as f64 / rate.seconds } else { 0.0 };
    println!(
        "{} frames: {} tracking, {} uncertain, {} lost, {} recovered; {:.1} frames per second after the first ({} in {:.2} s, reading included)",
        out.len(),
        count(TrackState::Tracking),
        count(TrackState::Uncertain),
        count(TrackState::Lost),
        count(TrackState::Recovered),
        per_second,
        rate.frames,
        rate.seconds
    );
    let Some(truth) = truth else { return };
    let paired: Vec<(Pose, Pose)> =
        out.iter().zip(frames).filter_map(|(t, f)| truth.get(&f.number).map(|g| (t.pose, *g))).collect();
    let (est, gt): (Vec<Pose>, Vec<Pose>) = paired.into_iter().unzip();
    if let Some(e) = trajectory_errors(&est, &gt) {
        println!(
            "vs ground truth ({} frames): ATE {:.1} mm, RPE {:.1} mm / {:.2} deg per frame, last frame {:.2} deg {:.1} mm",
            e.frames,
            e.ate_rmse_m * 1e3,
            e.rpe_rmse_m * 1e3,
            e.rpe_mean_deg,
            e.final_rotation_deg,
            e.final_translation_m * 1e3
        );
    }
}
