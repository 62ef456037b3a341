//! `flowfilter estimate`: the relative pose of an object between two frames of one camera.

use anyhow::Context;
use clap::Args;
use flowfilter_bigbird::{BigBirdObject, FrameId, SensorId};
use flowfilter_depth::ply::{PlyFormat, write_ply};
use flowfilter_geometry::PointCloud;
use flowfilter_pipeline::{Estimate, Pipeline, PipelineConfig, PreparedFrame, RgbdFrame, load_bigbird_frame};
use image::{Rgb, RgbImage};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Arguments of `estimate`.
#[derive(Args)]
pub struct EstimateArgs {
    /// A BigBIRD-layout object directory (real or synthesised).
    #[arg(long)]
    pub object: PathBuf,
    /// The camera, e.g. NP3.
    #[arg(long)]
    pub camera: SensorId,
    /// Turntable angle of the model frame (degrees).
    #[arg(long)]
    pub from: u32,
    /// Turntable angle of the target frame (degrees).
    #[arg(long)]
    pub to: u32,
    /// Registration method (overrides the configuration's `method`).
    #[arg(long, value_parser = crate::method_parser())]
    pub method: Option<String>,
    /// Pipeline configuration (TOML; see configs/). Default: configs/flowfilter.toml's values.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Print the estimate as JSON (schema "flowfilter estimate v2").
    #[arg(long)]
    pub json: bool,
    /// Write model.ply, target.ply and aligned.ply (the registration clouds) to this directory.
    #[arg(long)]
    pub save_ply: Option<PathBuf>,
    /// Write the target image with the aligned model cloud projected over it (green; the
    /// unaligned model in red).
    #[arg(long)]
    pub viz: Option<PathBuf>,
}

/// Run `estimate`.
pub fn run(args: &EstimateArgs) -> anyhow::Result<ExitCode> {
    let mut config = match &args.config {
        Some(p) => PipelineConfig::from_file(p)?,
        None => PipelineConfig::default(),
    };
    if let Some(m) = &args.method {
        config.method = m.clone();
    }
    let pipeline = Pipeline::from_config(config).context("--method / --config")?;
    let object = BigBirdObject::open(&args.object)?;
    let load = |angle: u32| -> anyhow::Result<RgbdFrame> {
        let id = FrameId { sensor: args.camera, angle };
        if !object.has_frame(id) {
            anyhow::bail!("{}: no frame {id} (camera {}, angle {angle})", args.object.display(), args.camera);
        }
        Ok(load_bigbird_frame(&object, id)?)
    };
    let (fa, fb) = (load(args.from)?, load(args.to)?);
    let started = std::time::Instant::now();
    let (a, b) = (pipeline.prepare(&fa)?, pipeline.prepare(&fb)?);
    let mut e = pipeline.estimate_prepared(&a, &b)?;
    e.stage_ms.total = started.elapsed().as_secs_f64() * 1e3;
    if let Ok(truth) = object.relative_motion(args.camera, args.from, args.to) {
        e = e.with_ground_truth(&truth, Some(&a.cloud.points));
    }
    if let Some(dir) = &args.save_ply {
        save_clouds(dir, &a, &b, &e)?;
    }
    if let Some(path) = &args.viz {
        overlay(&fb.color, &a, &b, &e).save(path).with_context(|| format!("writing {}", path.display()))?;
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&e)?);
    } else {
        print_human(&e);
    }
    for w in &e.warnings {
        eprintln!("warning: {w}");
    }
    Ok(ExitCode::SUCCESS)
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
    if let Some(c) = e.correspondences {
        println!("flow pairs: {} tracked, {} consistent, {} inliers", c.tracked, c.consistent, c.inliers);
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
    let mut img = RgbImage::from_fn(target_color.width(), target_color.height(), |x, y| {
        let p = target_color.get_pixel(x, y).0;
        Rgb(p.map(|c| c / 2))
    });
    let camera = &b.sensor.color;
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
    for p in &a.cloud.points {
        dot(p, [220, 40, 40]);
    }
    for p in &a.cloud.points {
        dot(&(e.pose * p), [40, 230, 60]);
    }
    img
}
