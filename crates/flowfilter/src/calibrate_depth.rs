//! `flowfilter calibrate-depth`: a stream of a static scene in, the camera file out with the
//! depth sensor's own error (`depth_bias`) fitted from it, without any truth.

use anyhow::Context;
use clap::Args;
use flowfilter_geometry::atomic::{check_writable_file, write_atomic_with};
use flowfilter_pipeline::{CameraFile, FrameFiles, MaskSource, RgbdFrame};
use flowfilter_track::FrameFolder;
use flowfilter_track::depth_calibration::{DepthCalibration, DepthCalibrationConfig, calibrate_depth};
use std::path::PathBuf;
use std::process::ExitCode;

/// Arguments of `calibrate-depth`.
#[derive(Args)]
pub struct CalibrateDepthArgs {
    /// A folder of frames of a static scene, the camera moving (the layouts `track` reads).
    #[arg(long)]
    pub frames: PathBuf,
    /// The camera file (JSON). A `depth_bias` it already holds is applied first and refined.
    #[arg(long)]
    pub camera: PathBuf,
    /// Where to write the camera file with the fitted `depth_bias` (the input's other keys kept).
    #[arg(long)]
    pub out: PathBuf,
    /// Frames to use: at most this many, from the first.
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Pipeline configuration for the tracking (TOML; default: configs/flowfilter.toml's values).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Write a report (JSON): the pairs used and left out, the depth differences before and
    /// after the field, the field's largest correction.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

/// Run `calibrate-depth`.
pub fn run(args: &CalibrateDepthArgs) -> anyhow::Result<ExitCode> {
    check_writable_file(&args.out).context("--out")?;
    if let Some(p) = &args.json {
        check_writable_file(p).context("--json")?;
    }
    let text = std::fs::read_to_string(&args.camera).with_context(|| format!("reading {}", args.camera.display()))?;
    let mut json: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{}: not JSON", args.camera.display()))?;
    // The file is read once: its keys are written back beside the field.
    let camera = CameraFile::from_json_value(&json, &args.camera.display().to_string())?;
    let mut folder = FrameFolder::open_any(&args.frames)?;
    if let Some(n) = args.max_frames {
        folder.frames.truncate(n.max(2));
    }
    let bar = crate::progress::bar(folder.frames.len(), "frames");
    bar.set_message("read");
    let frames = folder
        .frames
        .iter()
        .enumerate()
        .map(|(i, entry)| {
            let files = FrameFiles { color: entry.color.clone(), depth: entry.depth.clone(), mask: MaskSource::None };
            let frame = files.load(&camera, &entry.label());
            crate::progress::advance(&bar, i + 1);
            frame
        })
        .collect::<Result<Vec<RgbdFrame>, _>>()?;
    bar.finish_and_clear();
    let spinner = crate::progress::spinner(format!("tracking {} frames and fitting the field", frames.len()));
    let pipeline = crate::estimate::pipeline(args.config.as_deref(), None)?;
    let calibration = calibrate_depth(&frames, pipeline, &DepthCalibrationConfig::default())?;
    spinner.finish_and_clear();
    // Frames read with a camera that had a field were corrected by it: the fit is what is left.
    let bias = match &camera.depth_bias {
        Some(before) => before.plus(&calibration.fit.bias).context("--camera's depth_bias")?,
        None => calibration.fit.bias.clone(),
    };
    json.as_object_mut()
        .context("the camera file is not a JSON object")?
        .insert("depth_bias".into(), serde_json::to_value(&bias)?);
    write_atomic_with(&args.out, |p| std::fs::write(p, serde_json::to_string_pretty(&json)? + "\n"))
        .with_context(|| format!("writing {}", args.out.display()))?;
    if let Some(path) = &args.json {
        let report = serde_json::to_string_pretty(&report(&calibration))? + "\n";
        write_atomic_with(path, |p| std::fs::write(p, &report))
            .with_context(|| format!("writing {}", path.display()))?;
    }
    summarise(&calibration);
    Ok(ExitCode::SUCCESS)
}

fn summarise(c: &DepthCalibration) {
    let kept = c.pairs.iter().filter(|p| p.left_out.is_none()).count();
    eprintln!(
        "{} of {} frames tracked; {kept} of {} consecutive pairs used; depth differences {:.2} -> {:.2} mm RMS \
         over {} readings; largest correction {:.1} mm",
        c.frames_tracked,
        c.frames,
        c.pairs.len(),
        c.fit.rms_before_m * 1e3,
        c.fit.rms_after_m * 1e3,
        c.fit.samples,
        c.fit.bias.max_abs() * 1e3
    );
    for p in c.pairs.iter().filter(|p| p.left_out.is_some()) {
        eprintln!("  frames {} -> {} left out: {}", p.from, p.to, p.left_out.as_deref().unwrap_or_default());
    }
}

fn report(c: &DepthCalibration) -> serde_json::Value {
    let pairs: Vec<serde_json::Value> = c
        .pairs
        .iter()
        .map(|p| {
            serde_json::json!({
                "from": p.from, "to": p.to, "refinement_deg": p.refinement_deg, "overlap": p.overlap,
                "left_out": p.left_out,
            })
        })
        .collect();
    serde_json::json!({
        "frames": c.frames,
        "frames_tracked": c.frames_tracked,
        "readings": c.fit.samples,
        "rms_before_m": c.fit.rms_before_m,
        "rms_after_m": c.fit.rms_after_m,
        "largest_correction_m": c.fit.bias.max_abs(),
        "pairs": pairs,
    })
}
