//! `flowfilter`: the command-line front end of the Flow Filter workspace.

/// mimalloc keeps freed pages for the next frame's images, where glibc's malloc handed them
/// back to the kernel and faulted them in again, zeroed (the workspace manifest says more).
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

mod args;
mod calibrate_depth;
mod estimate;
mod estimate_batch;
mod flow;
mod inspect;
mod matrix_file;
mod progress;
mod register;
mod synth;
mod track;
mod truth_flow;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// Relative 6-DoF pose estimation of partially seen rigid objects from RGB-D.
#[derive(Parser)]
#[command(name = "flowfilter", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Validate every file of a BigBIRD-layout object directory and print a summary.
    Inspect(inspect::InspectArgs),
    /// Render a synthetic turntable capture of one object in the BigBIRD layout.
    Synth(synth::SynthArgs),
    /// Align two PLY point clouds with ICP, CPD or FilterReg.
    Register(register::RegisterArgs),
    /// Estimate an object's relative pose between two frames of one camera (the pipeline).
    Estimate(estimate::EstimateArgs),
    /// Estimate every pair of a CSV pair list: one JSON line per pair, resumable, shardable.
    EstimateBatch(estimate_batch::EstimateBatchArgs),
    /// Optical flow between two images (EPE against a ground-truth .flo).
    Flow(flow::FlowArgs),
    /// Render two views of a synthetic object and write their exact optical flow and occlusion.
    TruthFlow(truth_flow::TruthFlowArgs),
    /// Track an object (or the whole scene) through a folder of RGB-D frames from one mask.
    Track(track::TrackArgs),
    /// Fit the depth sensor's own error over its image (`depth_bias` in the camera file) from a
    /// folder of frames of a static scene, without any truth.
    CalibrateDepth(calibrate_depth::CalibrateDepthArgs),
}

/// `--method` of `register` and `estimate`: the registration backends' names (checked and
/// listed by clap), with the aliases `icp` and `filterreg`.
fn method_parser() -> clap::builder::PossibleValuesParser {
    clap::builder::PossibleValuesParser::new(
        flowfilter_registration::METHOD_NAMES.iter().copied().chain(["icp", "filterreg"]),
    )
}

/// Exit code of a command whose estimate the data do not support (documented in docs/limits.md).
pub const EXIT_NOT_TRUSTWORTHY: u8 = 3;

/// Success, or [`EXIT_NOT_TRUSTWORTHY`] (with a line saying so) when `implausible`.
fn exit_code(implausible: bool) -> ExitCode {
    if implausible {
        eprintln!("the estimate is not trustworthy: the data do not support it (see the warnings); exit code 3");
        ExitCode::from(EXIT_NOT_TRUSTWORTHY)
    } else {
        ExitCode::SUCCESS
    }
}

/// Save an image (format by extension) whole or not at all.
fn save_image<P, C>(img: &image::ImageBuffer<P, C>, path: &std::path::Path) -> anyhow::Result<()>
where
    P: image::PixelWithColorType,
    [P::Subpixel]: image::EncodableLayout,
    C: std::ops::Deref<Target = [P::Subpixel]>,
{
    use anyhow::Context;
    flowfilter_geometry::atomic::write_atomic_with(path, |p| img.save(p).map_err(std::io::Error::other))
        .with_context(|| format!("writing {}", path.display()))
}

/// The error and its causes joined by ": ", leaving out a cause whose message the text already
/// holds (typed errors often print their source in their own message).
fn error_chain(e: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in e.chain() {
        let message = cause.to_string();
        if !text.contains(&message) {
            if !text.is_empty() {
                text.push_str(": ");
            }
            text.push_str(&message);
        }
    }
    text
}

/// Freed pages go back to the kernel after a second, not 10 ms (the workspace manifest says
/// why), unless `MIMALLOC_PURGE_DELAY` says otherwise.
fn keep_freed_pages() {
    /// `mi_option_purge_delay` (the same slot in mimalloc v2 and v3; libmimalloc-sys does not
    /// name it).
    const PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;
    if std::env::var_os("MIMALLOC_PURGE_DELAY").is_none() {
        // SAFETY: sets one of mimalloc's integer options; it is read on the allocator's next purge.
        unsafe { libmimalloc_sys::mi_option_set(PURGE_DELAY, 1000) };
    }
}

fn main() -> ExitCode {
    keep_freed_pages();
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "warn".into()))
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Inspect(args) => inspect::run(&args),
        Command::Synth(args) => synth::run(&args),
        Command::Register(args) => register::run(&args),
        Command::Estimate(args) => estimate::run(&args),
        Command::EstimateBatch(args) => estimate_batch::run(&args),
        Command::Flow(args) => flow::run(&args),
        Command::TruthFlow(args) => truth_flow::run(&args),
        Command::Track(args) => track::run(&args),
        Command::CalibrateDepth(args) => calibrate_depth::run(&args),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {}", error_chain(&e));
            ExitCode::FAILURE
        }
    }
}
