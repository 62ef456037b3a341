//! `flowfilter register`: align two PLY point clouds with one backend.

use anyhow::{Context, bail};
use clap::Args;
use flowfilter_depth::ply::read_ply;
use flowfilter_geometry::{Pose, rigid_from_matrix, rotation_angle_deg};
use flowfilter_registration::{METHOD_NAMES, RegistrationConfig, RegistrationProblem, registrar_by_name};
use nalgebra::Matrix4;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

/// Arguments of `register`.
#[derive(Args)]
pub struct RegisterArgs {
    /// The cloud to move (PLY).
    #[arg(long)]
    pub source: PathBuf,
    /// The cloud to align to (PLY; normals needed for the point-to-plane methods).
    #[arg(long)]
    pub target: PathBuf,
    /// icp-pt2pt, icp-pt2pl, cpd, filterreg-pt2pt or filterreg-pt2pl.
    #[arg(long, default_value = "filterreg-pt2pt")]
    pub method: String,
    /// Initial 4x4 transform: a text file with 16 numbers, row-major.
    #[arg(long)]
    pub init: Option<PathBuf>,
    /// Backend parameters: a TOML file with [icp], [cpd] and [filterreg] tables.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Print the result as JSON.
    #[arg(long)]
    pub json: bool,
}

fn read_matrix(path: &Path) -> anyhow::Result<Pose> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let values: Vec<f64> = text
        .split(|c: char| c.is_whitespace() || c == ',')
        .filter(|s| !s.is_empty())
        .map(|s| s.parse::<f64>().with_context(|| format!("{}: '{s}' is not a number", path.display())))
        .collect::<Result<_, _>>()?;
    if values.len() != 16 {
        bail!("{}: expected 16 numbers (a 4x4 matrix, row-major), found {}", path.display(), values.len());
    }
    rigid_from_matrix(&Matrix4::from_row_slice(&values))
        .with_context(|| format!("{}: not a rigid transform", path.display()))
}

/// Run `register`.
pub fn run(args: &RegisterArgs) -> anyhow::Result<ExitCode> {
    let config: RegistrationConfig = match &args.config {
        Some(p) => {
            let text = std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            toml::from_str(&text).with_context(|| format!("{}: invalid registration config", p.display()))?
        }
        None => RegistrationConfig::default(),
    };
    let registrar = registrar_by_name(&args.method, &config)
        .with_context(|| format!("--method must be one of {}", METHOD_NAMES.join(", ")))?;
    let source = read_ply(&args.source)?;
    let target = read_ply(&args.target)?;
    let init = args.init.as_deref().map(read_matrix).transpose()?.unwrap_or_else(Pose::identity);
    let start = Instant::now();
    let r = registrar.register(&RegistrationProblem::new(source, target).with_init(init))?;
    let secs = start.elapsed().as_secs_f64();
    let m = r.transform.to_homogeneous();
    let rows: Vec<[f64; 4]> = (0..4).map(|i| [m[(i, 0)], m[(i, 1)], m[(i, 2)], m[(i, 3)]]).collect();
    if args.json {
        let out = serde_json::json!({
            "method": registrar.name(),
            "transform": rows,
            "rotation_deg": rotation_angle_deg(&r.transform),
            "iterations": r.iterations,
            "converged": r.converged,
            "fitness": r.fitness,
            "inlier_rmse": r.inlier_rmse,
            "sigma2": r.sigma2,
            "seconds": secs,
            "warnings": r.warnings,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        println!("method: {}", registrar.name());
        for row in &rows {
            println!("  {:>12.8} {:>12.8} {:>12.8} {:>12.8}", row[0], row[1], row[2], row[3]);
        }
        println!(
            "rotation {:.4} deg, {} iterations, converged: {}, fitness {:.4}, inlier RMSE {:.3} mm, {:.1} ms",
            rotation_angle_deg(&r.transform),
            r.iterations,
            r.converged,
            r.fitness,
            r.inlier_rmse * 1e3,
            secs * 1e3
        );
        for w in &r.warnings {
            eprintln!("warning: {w}");
        }
    }
    Ok(ExitCode::SUCCESS)
}
