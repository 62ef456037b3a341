//! `flowfilter flow`: optical flow between two images, with EPE against ground truth.

use anyhow::{Context, bail};
use clap::Args;
use flowfilter_flow::lk::to_gray;
use flowfilter_flow::metrics::epe;
use flowfilter_flow::{FlowEstimator, flo, flow_estimator_with_presets, viz};
use flowfilter_geometry::Mask;
use flowfilter_geometry::atomic::check_writable_file;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

/// Arguments of `flow`.
#[derive(Args)]
pub struct FlowArgs {
    /// First image.
    #[arg(long)]
    pub from: PathBuf,
    /// Second image.
    #[arg(long)]
    pub to: PathBuf,
    /// lk (dense by grid + interpolation), dis (OpenCV "medium" preset), dis-fast, dis-ultrafast,
    /// net (our trained network, feature `onnx`) or onnx:MODEL.onnx (feature `onnx`; the
    /// contract MODEL.toml beside it).
    #[arg(long, default_value = "dis")]
    pub method: String,
    /// Ground-truth flow (.flo): print the end-point error.
    #[arg(long)]
    pub gt: Option<PathBuf>,
    /// Occlusion mask of the ground truth (PNG, non-zero = occluded): also print the EPE over
    /// the non-occluded pixels.
    #[arg(long, requires = "gt")]
    pub occlusion: Option<PathBuf>,
    /// Write the estimate as .flo.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write the colour-wheel visualisation (PNG).
    #[arg(long)]
    pub viz: Option<PathBuf>,
}

/// The estimator named on the command line: the registry's names (lk, dis, net, onnx:MODEL)
/// plus the DIS presets; LK with the pipeline's 9-pixel window.
fn estimator(name: &str) -> anyhow::Result<Box<dyn FlowEstimator>> {
    #[cfg(not(feature = "onnx"))]
    if name.starts_with("onnx:") || name == "net" {
        bail!("--method {name}: ONNX networks need a build with the `onnx` feature (cargo build --features onnx)")
    }
    flow_estimator_with_presets(name).with_context(|| format!("--method {name}"))
}

/// Run `flow`.
pub fn run(args: &FlowArgs) -> anyhow::Result<ExitCode> {
    let est = estimator(&args.method)?;
    if let Some(out) = &args.out {
        check_writable_file(out).context("--out")?;
    }
    if let Some(viz) = &args.viz {
        check_writable_file(viz).context("--viz")?;
    }
    let open = |p: &PathBuf| -> anyhow::Result<image::RgbImage> {
        Ok(image::open(p).with_context(|| format!("reading {}", p.display()))?.to_rgb8())
    };
    let (a, b) = (to_gray(&open(&args.from)?), to_gray(&open(&args.to)?));
    let start = Instant::now();
    let field = est.dense(&a, &b, None).with_context(|| format!("{} -> {}", args.from.display(), args.to.display()))?;
    let ms = start.elapsed().as_secs_f64() * 1e3;
    println!("{}: {}x{} in {ms:.1} ms", est.name(), field.width(), field.height());
    if let Some(gt) = &args.gt {
        let truth = flo::read(gt)?;
        anyhow::ensure!(
            (truth.width(), truth.height()) == (field.width(), field.height()),
            "{}: ground truth is {}x{}, the images {}x{}",
            gt.display(),
            truth.width(),
            truth.height(),
            field.width(),
            field.height()
        );
        match epe(&field, &truth, None) {
            Some((e, n)) => println!("EPE {e:.4} px over {n} pixels"),
            None => bail!(
                "no pixel has both an estimate and a ground truth ({} of {} pixels estimated, {} with ground truth): \
                 {} found nothing to track (textureless images?)",
                field.valid.as_slice().iter().filter(|&&v| v).count(),
                field.valid.as_slice().len(),
                truth.valid.as_slice().iter().filter(|&&v| v).count(),
                est.name()
            ),
        }
        if let Some(occ_path) = &args.occlusion {
            let occ = image::open(occ_path).with_context(|| format!("reading {}", occ_path.display()))?.to_luma8();
            anyhow::ensure!(
                (occ.width() as usize, occ.height() as usize) == (truth.width(), truth.height()),
                "{}: occlusion mask is {}x{}, the ground truth {}x{}",
                occ_path.display(),
                occ.width(),
                occ.height(),
                truth.width(),
                truth.height()
            );
            let visible =
                Mask::from_fn(truth.width(), truth.height(), |x, y| occ.get_pixel(x as u32, y as u32).0[0] == 0);
            match epe(&field, &truth, Some(&visible)) {
                Some((e, n)) => println!("EPE (non-occluded) {e:.4} px over {n} pixels"),
                None => println!("EPE (non-occluded): no non-occluded pixel with ground truth"),
            }
        }
    }
    if let Some(out) = &args.out {
        flo::write(&field, out)?;
    }
    if let Some(path) = &args.viz {
        crate::save_image(&viz::colorize(&field, None), path)?;
    }
    Ok(ExitCode::SUCCESS)
}
