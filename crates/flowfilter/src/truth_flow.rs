//! `flowfilter truth-flow`: render two colour views of a synthetic turntable object and write
//! their exact optical flow (`.flo`) with the occlusion mask.

use crate::synth::ObjectArgs;
use anyhow::Context;
use clap::Args;
use flowfilter_bigbird::{FrameId, SensorId};
use flowfilter_flow::{FlowField, flo, viz};
use flowfilter_geometry::Mask;
use flowfilter_synth::{NoiseProfile, Rig, render_frame, true_flow};
use image::{GrayImage, Luma};
use std::path::PathBuf;
use std::process::ExitCode;

/// Arguments of `truth-flow`.
#[derive(Args)]
pub struct TruthFlowArgs {
    /// The object.
    #[command(flatten)]
    pub object: ObjectArgs,
    /// Camera of the first view.
    #[arg(long, default_value = "NP3")]
    pub camera: String,
    /// Camera of the second view (default: the first view's).
    #[arg(long)]
    pub to_camera: Option<String>,
    /// Turntable angle of the first view (degrees).
    #[arg(long, allow_negative_numbers = true, value_parser = crate::args::turntable_angle)]
    pub from: u32,
    /// Turntable angle of the second view (degrees).
    #[arg(long, allow_negative_numbers = true, value_parser = crate::args::turntable_angle)]
    pub to: u32,
    /// Noise of the written colour images: `none` (default), `carmine`, or a TOML profile.
    #[arg(long, default_value = "none")]
    pub noise: String,
    /// Depth tolerance of the visibility test, metres.
    #[arg(long, default_value_t = 0.003, value_parser = crate::args::positive_f64)]
    pub tolerance: f64,
    /// Output directory: from.png, to.png, flow.flo (object pixels; unknown elsewhere),
    /// occlusion.png (255 = occluded in the second view), object.png, flow.png (colour wheel).
    #[arg(long)]
    pub out: PathBuf,
}

fn sensor(name: &str) -> anyhow::Result<SensorId> {
    name.trim().parse::<SensorId>().map_err(anyhow::Error::msg)
}

fn mask_png(mask: &Mask) -> GrayImage {
    GrayImage::from_fn(mask.width() as u32, mask.height() as u32, |x, y| {
        Luma([if *mask.at(x as usize, y as usize) { 255 } else { 0 }])
    })
}

/// Run `truth-flow`.
pub fn run(args: &TruthFlowArgs) -> anyhow::Result<ExitCode> {
    let (s_from, s_to) = (sensor(&args.camera)?, sensor(args.to_camera.as_deref().unwrap_or(&args.camera))?);
    for a in [args.from, args.to] {
        anyhow::ensure!(a < 360, "--from/--to: angle {a} is outside 0..360");
    }
    let noise = NoiseProfile::resolve(&args.noise)?;
    let scene = args.object.scene()?;
    let rig = Rig::bigbird_like();
    let (from, to) = (FrameId { sensor: s_from, angle: args.from }, FrameId { sensor: s_to, angle: args.to });
    let truth = true_flow(&scene, &rig, from, to, args.tolerance);
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let path = |name: &str| args.out.join(name);
    for (id, name) in [(from, "from.png"), (to, "to.png")] {
        let frame = render_frame(&scene, &rig, id.sensor, id.angle, noise.as_ref(), args.object.seed);
        crate::save_image(&frame.color, &path(name))?;
    }
    let object = truth.object();
    let field = FlowField { flow: truth.flow.clone(), valid: object.clone() };
    flo::write(&field, &path("flow.flo"))?;
    for (mask, name) in [(&truth.occluded, "occlusion.png"), (&object, "object.png")] {
        crate::save_image(&mask_png(mask), &path(name))?;
    }
    crate::save_image(&viz::colorize(&field, None), &path("flow.png"))?;
    println!(
        "{} -> {}: {} object pixels, {:.1}% occluded; wrote {}",
        from,
        to,
        truth.object_pixels(),
        100.0 * truth.occluded_fraction(),
        args.out.display()
    );
    Ok(ExitCode::SUCCESS)
}
