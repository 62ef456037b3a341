//! `flowfilter estimate`: the relative pose of an object between two frames of one camera, from
//! a BigBIRD-layout object or from RGB-D files.

use anyhow::Context;
use clap::Args;
use flowfilter_bigbird::{BigBirdObject, FrameId, SensorId};
use flowfilter_depth::ply::{PlyFormat, write_ply};
use flowfilter_geometry::atomic::{check_writable_dir, check_writable_file, write_atomic_with};
use flowfilter_geometry::{PointCloud, Pose};
use flowfilter_pipeline::{
    CameraFile, Estimate, FrameFiles, GeometryFirstReport, MaskSource, Pipeline, PipelineConfig, PipelineWarning,
    PreparedFrame, RgbdFrame, load_bigbird_frame,
};
use flowfilter_rerun::{FrameInput, PairScene, Recorder};
use image::{Rgb, RgbImage};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Arguments of `estimate`: two frames of a BigBIRD-layout object (`--object`, `--camera NP3`,
/// `--from`, `--to`), or two RGB-D frames given as files (`--model-color`, `--model-depth`,
/// `--target-color`, `--target-depth`, `--camera camera.json`) for any camera whose depth is
/// registered to colour.
#[derive(Args)]
#[command(group(clap::ArgGroup::new("frames").required(true).args(["object", "model_color"])))]
pub struct EstimateArgs {
    /// A BigBIRD-layout object directory (real or synthesised).
    #[arg(long, requires_all = ["from", "to"], conflicts_with_all = ["model_color", "model_depth", "target_color", "target_depth", "model_mask", "target_mask", "label", "gt"])]
    pub object: Option<PathBuf>,
    /// With --object: the camera (NP1..NP5). With frame files: the camera file (JSON: ours,
    /// a BOP scene_camera.json entry or camera.json, or Open3D's PinholeCameraIntrinsic).
    #[arg(long)]
    pub camera: String,
    /// Turntable angle of the model frame (degrees; with --object).
    #[arg(long, allow_negative_numbers = true, value_parser = crate::args::turntable_angle)]
    pub from: Option<u32>,
    /// Turntable angle of the target frame (degrees; with --object).
    #[arg(long, allow_negative_numbers = true, value_parser = crate::args::turntable_angle)]
    pub to: Option<u32>,
    /// Colour image of the model frame (PNG or JPEG).
    #[arg(long, requires_all = ["model_depth", "target_color", "target_depth"])]
    pub model_color: Option<PathBuf>,
    /// Depth of the model frame: a 16-bit PNG registered to the colour image (metres = value x
    /// the camera file's depth unit).
    #[arg(long)]
    pub model_depth: Option<PathBuf>,
    /// Object mask of the model frame: a binary PNG, or a label image with --label. Without a
    /// mask the object is the whole image (the registration then aligns the whole scene).
    #[arg(long)]
    pub model_mask: Option<PathBuf>,
    /// Colour image of the target frame.
    #[arg(long)]
    pub target_color: Option<PathBuf>,
    /// Depth of the target frame (as --model-depth).
    #[arg(long)]
    pub target_depth: Option<PathBuf>,
    /// Object mask of the target frame (as --model-mask).
    #[arg(long)]
    pub target_mask: Option<PathBuf>,
    /// The masks are label images and this is the object's label.
    #[arg(long)]
    pub label: Option<u16>,
    /// The true motion, for the errors: a JSON file with `transform` (4x4, row-major,
    /// `P_target = T * P_model`) or a text file of 16 numbers.
    #[arg(long)]
    pub gt: Option<PathBuf>,
    /// Registration method (overrides the configuration's `method`).
    #[arg(long, value_parser = crate::method_parser())]
    pub method: Option<String>,
    /// Pipeline configuration (TOML; see configs/). Default: configs/flowfilter.toml's values.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Print the estimate as JSON (schema "flowfilter estimate v3").
    #[arg(long)]
    pub json: bool,
    /// Write model.ply, target.ply and aligned.ply (the registration clouds) to this directory.
    #[arg(long)]
    pub save_ply: Option<PathBuf>,
    /// Write the target image with the aligned model cloud projected over it (green; the
    /// unaligned model in red).
    #[arg(long)]
    pub viz: Option<PathBuf>,
    /// Write a Rerun recording of the pair to this .rrd file: both frames, depth and masks, the
    /// clouds before and after, the flow pairs by inlier, the judge's candidates, the pose with
    /// its bounds and the stage times (entities in docs/rerun.md; open with `rerun FILE.rrd`).
    /// Needs a build with `--features rerun`.
    #[arg(long)]
    pub rerun: Option<PathBuf>,
}

/// The two frames and, when known, the true motion.
type Frames = (RgbdFrame, RgbdFrame, Option<Pose>);

/// The pipeline of `--config` (default: configs/flowfilter.toml's values) with `--method`
/// replacing its method.
pub fn pipeline(config: Option<&Path>, method: Option<&str>) -> anyhow::Result<Pipeline> {
    let mut config = match config {
        Some(p) => PipelineConfig::from_file(p)?,
        None => PipelineConfig::default(),
    };
    if let Some(m) = method {
        config.method = m.to_string();
    }
    Pipeline::from_config(config).context("--method / --config")
}

/// Run `estimate`.
pub fn run(args: &EstimateArgs) -> anyhow::Result<ExitCode> {
    let pipeline = pipeline(args.config.as_deref(), args.method.as_deref())?;
    check_outputs(args)?;
    let (fa, fb, truth) = match &args.object {
        Some(object) => bigbird_frames(args, object)?,
        None => file_frames(args)?,
    };
    let (e, a, b, trace) = match &args.rerun {
        Some(_) => pipeline.estimate_against_traced(&fa, &fb, truth.as_ref()).map(|(e, a, b, t)| (e, a, b, Some(t)))?,
        None => pipeline.estimate_against(&fa, &fb, truth.as_ref()).map(|(e, a, b)| (e, a, b, None))?,
    };
    // The estimate first: a file that then cannot be written does not lose it.
    if args.json {
        println!("{}", serde_json::to_string_pretty(&e)?);
    } else {
        print_human(&e);
    }
    for w in &e.warnings {
        eprintln!("warning: {w}");
    }
    if let Some(dir) = &args.save_ply {
        save_clouds(dir, &a, &b, &e)?;
    }
    if let Some(path) = &args.viz {
        let image = overlay(&fb.color, &a, &b, &e);
        write_atomic_with(path, |p| image.save(p).map_err(std::io::Error::other))
            .with_context(|| format!("writing {}", path.display()))?;
    }
    if let (Some(path), Some(trace)) = (&args.rerun, trace) {
        let recorder = Recorder::create(path, "flowfilter estimate")?;
        let model = FrameInput { color: &fa.color, prepared: &a };
        let target = FrameInput { color: &fb.color, prepared: &b };
        recorder.log_pair(0, &PairScene::new(model, target, &e, &trace, truth.as_ref()))?;
        recorder.finish()?;
    }
    Ok(crate::exit_code(e.warnings.iter().any(PipelineWarning::is_implausible)))
}

/// The output paths can be written: checked before any work (the file first, so that a bad
/// `--viz` leaves no `--save-ply` directory behind).
fn check_outputs(args: &EstimateArgs) -> anyhow::Result<()> {
    if let Some(path) = &args.viz {
        check_writable_file(path).context("--viz")?;
    }
    if let Some(dir) = &args.save_ply {
        check_writable_dir(dir).context("--save-ply")?;
    }
    if let Some(path) = &args.rerun {
        check_writable_file(path).context("--rerun")?;
        if !flowfilter_rerun::CAN_RECORD {
            return Err(flowfilter_rerun::RecordError::NotBuilt { path: path.clone() }).context("--rerun");
        }
    }
    Ok(())
}

/// Two frames of one camera of a BigBIRD-layout object, with the turntable's ground truth.
fn bigbird_frames(args: &EstimateArgs, dir: &Path) -> anyhow::Result<Frames> {
    let camera: SensorId = args
        .camera
        .parse()
        .map_err(|e| anyhow::anyhow!("--camera '{}': {e} (with --object: NP1..NP5)", args.camera))?;
    let (from, to) =
        (args.from.context("--from is required with --object")?, args.to.context("--to is required with --object")?);
    let object = BigBirdObject::open(dir)?;
    if let Some(note) = object.calibration.sensors.get(&camera).and_then(|c| c.depth_bias_note(camera)) {
        eprintln!("warning: {note}");
    }
    let load = |angle: u32| -> anyhow::Result<RgbdFrame> {
        let id = FrameId { sensor: camera, angle };
        if !object.has_frame(id) {
            anyhow::bail!("{}: no frame {id} (camera {camera}, angle {angle})", dir.display());
        }
        Ok(load_bigbird_frame(&object, id)?)
    };
    let (fa, fb) = (load(from)?, load(to)?);
    Ok((fa, fb, object.relative_motion(camera, from, to).ok()))
}

/// Two frames given as files, with the camera file and the optional --gt.
fn file_frames(args: &EstimateArgs) -> anyhow::Result<Frames> {
    let camera = CameraFile::from_file(Path::new(&args.camera))?;
    let mask = |m: &Option<PathBuf>| match (m, args.label) {
        (None, _) => MaskSource::None,
        (Some(path), None) => MaskSource::Binary(path.clone()),
        (Some(path), Some(id)) => MaskSource::Label { path: path.clone(), id },
    };
    let required = |p: &Option<PathBuf>, flag: &str| p.clone().with_context(|| format!("{flag} is required"));
    let model = FrameFiles {
        color: required(&args.model_color, "--model-color")?,
        depth: required(&args.model_depth, "--model-depth")?,
        mask: mask(&args.model_mask),
    };
    let target = FrameFiles {
        color: required(&args.target_color, "--target-color")?,
        depth: required(&args.target_depth, "--target-depth")?,
        mask: mask(&args.target_mask),
    };
    let stem = |p: &Path| p.file_stem().map_or_else(|| p.display().to_string(), |s| s.to_string_lossy().into_owned());
    let fa = model.load(&camera, &stem(&model.color))?;
    let fb = target.load(&camera, &stem(&target.color))?;
    let truth = args.gt.as_deref().map(crate::matrix_file::read_pose).transpose()?;
    Ok((fa, fb, truth))
}

fn print_human(e: &Estimate) {
    println!(
        "{} -> {} with {}{}",
        e.model,
        e.target,
        e.method,
        e.flow_estimator.as_ref().map_or(String::new(), |f| format!(" (flow: {f})"))
    );
    for row in &e.transform {
        println!("  {:>12.8} {:>12.8} {:>12.8} {:>12.8}", row[0], row[1], row[2], row[3]);
    }
    println!(
        "rotation {:.3} deg about [{:.3}, {:.3}, {:.3}], translation {:.2} mm",
        e.rotation_angle_deg,
        e.rotation_axis[0],
        e.rotation_axis[1],
        e.rotation_axis[2],
        e.translation_m.iter().map(|v| v * v).sum::<f64>().sqrt() * 1e3
    );
    let r = &e.registration;
    println!(
        "registration: {} iterations, converged {}, fitness {:.3}, inlier RMSE {:.2} mm ({} -> {} points)",
        r.iterations,
        r.converged,
        r.fitness,
        r.inlier_rmse_m * 1e3,
        r.model_points,
        r.target_points
    );
    if let Some(u) = r.uncertainty {
        println!(
            "error bounds (2.5 sigma, independent flow errors): {:.3} deg, {:.2} mm",
            u.rotation_deg,
            u.translation_m * 1e3
        );
    }
    if let Some(c) = e.correspondences {
        println!("flow pairs: {} tracked, {} consistent, {} inliers", c.tracked, c.consistent, c.inliers);
    }
    if let Some(g) = &e.geometry_first {
        println!("{}", geometry_first_line(g));
    }
    let s = e.stage_ms;
    println!(
        "time (ms): depth {:.1} + {:.1}, flow {:.1}, correspondences {:.1}, registration {:.1}, total {:.1}",
        s.depth_model, s.depth_target, s.flow, s.correspondences, s.registration, s.total
    );
    if let Some(gt) = &e.ground_truth {
        let x = &gt.errors;
        println!(
            "vs ground truth: rotation-angle error {:.3} deg, geodesic {:.3} deg, translation {:.2} mm, ADD-S {}, success {}",
            x.angle_error_deg,
            x.geodesic_error_deg,
            x.translation_error_m * 1e3,
            x.add_s_m.map_or("-".into(), |v| format!("{:.2} mm", v * 1e3)),
            x.success
        );
    }
}

/// What a scene's geometry-first try found, as one line.
fn geometry_first_line(g: &GeometryFirstReport) -> String {
    let seen = match (g.score, g.visible_fraction) {
        (Some(score), Some(visible)) => {
            format!("texture score {score:.3}, {:.0}% of the pixels visible", 100.0 * visible)
        }
        (None, Some(visible)) => format!("flat texture, {:.0}% of the pixels visible", 100.0 * visible),
        _ => "FilterReg did not converge".to_string(),
    };
    match g.confirmed {
        true => format!("geometry first: kept ({seen}): no flow ran"),
        false => format!("geometry first: not kept ({seen}): the full pipeline ran"),
    }
}

fn save_clouds(dir: &Path, a: &PreparedFrame, b: &PreparedFrame, e: &Estimate) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let aligned: PointCloud = a.cloud.transformed(&e.pose);
    for (name, cloud) in [("model.ply", &a.cloud), ("target.ply", &b.cloud), ("aligned.ply", &aligned)] {
        write_ply(cloud, &dir.join(name), PlyFormat::BinaryLittleEndian)?;
    }
    Ok(())
}

/// The target image, dimmed, with the model cloud projected before (red) and after (green)
/// alignment.
fn overlay(target_color: &RgbImage, a: &PreparedFrame, b: &PreparedFrame, e: &Estimate) -> RgbImage {
    overlay_cloud(target_color, &b.sensor.color, &a.cloud.points, &e.pose)
}

/// The target image darkened, `model` projected over it where it was (red) and moved by `pose`
/// (green): what `estimate --viz` and `track --viz` draw.
pub fn overlay_cloud(
    target_color: &RgbImage,
    camera: &flowfilter_pipeline::camera::CameraModel,
    model: &[flowfilter_geometry::Point3],
    pose: &flowfilter_geometry::Pose,
) -> RgbImage {
    let mut img = RgbImage::from_fn(target_color.width(), target_color.height(), |x, y| {
        let p = target_color.get_pixel(x, y).0;
        Rgb(p.map(|c| c / 2))
    });
    let mut dot = |p: &flowfilter_geometry::Point3, colour: [u8; 3]| {
        if let Some(px) = camera.project(p) {
            let (cx, cy) = (px.x.round() as i64, px.y.round() as i64);
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let (x, y) = (cx + dx, cy + dy);
                    if x >= 0 && y >= 0 && (x as u32) < img.width() && (y as u32) < img.height() {
                        img.put_pixel(x as u32, y as u32, Rgb(colour));
                    }
                }
            }
        }
    };
    for p in model {
        dot(p, [220, 40, 40]);
    }
    for p in model {
        dot(&(pose * p), [40, 230, 60]);
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_geometry_first_line_says_which_path_ran_and_why() {
        let report = |confirmed: bool, score: Option<f64>, visible_fraction: Option<f64>| GeometryFirstReport {
            confirmed,
            registration_converged: visible_fraction.is_some(),
            score,
            visible_fraction,
        };
        let kept = geometry_first_line(&report(true, Some(0.142), Some(0.61)));
        assert_eq!(kept, "geometry first: kept (texture score 0.142, 61% of the pixels visible): no flow ran");
        let refused = geometry_first_line(&report(false, Some(0.93), Some(0.3)));
        assert!(refused.starts_with("geometry first: not kept (texture score 0.930, 30%"), "{refused}");
        assert!(geometry_first_line(&report(false, None, None)).contains("FilterReg did not converge"));
        assert!(geometry_first_line(&report(false, None, Some(0.7))).contains("flat texture"));
    }
}
