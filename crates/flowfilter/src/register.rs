//! `flowfilter register`: align two PLY point clouds with one backend.

use anyhow::Context;
use clap::Args;
use flowfilter_depth::cloud::knn_normals;
use flowfilter_depth::ply::read_ply;
use flowfilter_geometry::{Point3, PointCloud, Pose};
use flowfilter_pipeline::{GeometryGuideConfig, PipelineConfig, RegisterReport, global_start};
use flowfilter_registration::{RegistrationConfig, RegistrationError, RegistrationProblem, registrar_by_name};
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
    /// The backend (default: the configuration file's `method` when it has one, else
    /// filterreg-pt2pt). The Flow Filter methods need flow correspondences, which PLY clouds do
    /// not carry: they fall back to FilterReg with a warning.
    #[arg(long, value_parser = crate::method_parser())]
    pub method: Option<String>,
    /// Initial 4x4 transform: a text file of 16 numbers (row-major) or a JSON 4x4 array of rows
    /// (bare or under `transform`).
    #[arg(long, conflicts_with = "global")]
    pub init: Option<PathBuf>,
    /// Start from a global registration instead of identity (motions of any size, as Open3D's
    /// global registration before its ICP): both clouds thinned to at most 2500 points from
    /// `--global-voxel` up, FPFH descriptors matched both ways, a RANSAC over three matches,
    /// point-to-plane ICP; the method then refines from there. Fails when no motion gathers
    /// 12 matches.
    #[arg(long)]
    pub global: bool,
    /// The finest voxel of `--global` (metres).
    #[arg(long, default_value_t = 0.005, requires = "global")]
    pub global_voxel: f64,
    /// Backend parameters (TOML): a pipeline configuration such as configs/icp.toml (its
    /// [registration.*] tables and `method`), or a file of bare [icp], [cpd], [filterreg] and
    /// [flowfilter] tables.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Print the result as JSON (schema "flowfilter register v1").
    #[arg(long)]
    pub json: bool,
    /// Estimate both clouds' normals (PCA over the `--normals-k` nearest neighbours, facing the
    /// origin, as Open3D's `estimate_normals` + `orient_normals_towards_camera_location`),
    /// replacing any the files hold. Without it, normals a method needs and a file lacks are
    /// estimated the same way, with a warning.
    #[arg(long)]
    pub estimate_normals: bool,
    /// Neighbours of the normal estimation.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u32).range(3..))]
    pub normals_k: u32,
}

/// Source x target pairs above which a CPD run shows a spinner (about 0.1 s per iteration).
const LONG_RUN_PAIRS: f64 = 2e7;

/// Give `cloud` PCA normals from its `k` nearest neighbours, facing the origin.
fn estimate_normals(cloud: &mut PointCloud, k: u32) {
    cloud.normals = Some(knn_normals(&cloud.points, k as usize, &Point3::origin()));
}

/// The start `--global` finds (a line on stderr says how well the matches agreed).
fn global_init(source: &PointCloud, target: &PointCloud, voxel: f64) -> anyhow::Result<Pose> {
    anyhow::ensure!(
        voxel.is_finite() && voxel > 0.0,
        "--global-voxel: expected a positive length in metres, found {voxel}"
    );
    let cfg = GeometryGuideConfig { min_voxel_m: voxel, ..GeometryGuideConfig::default() };
    let found = global_start(source, target, &cfg).ok_or_else(|| {
        anyhow::anyhow!(
            "--global: no motion gathers {} matching FPFH descriptors (the clouds share too little shape at a {voxel} m voxel)",
            cfg.min_inliers
        )
    })?;
    eprintln!(
        "global start: {} of {} descriptor matches agree (voxel {:.4} m)",
        found.inliers, found.matches, found.voxel_m
    );
    Ok(found.pose)
}

/// The backend parameters and, for a pipeline configuration, its method.
fn read_config(path: &Path) -> anyhow::Result<(RegistrationConfig, Option<String>)> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let table: toml::Table = toml::from_str(&text).with_context(|| format!("{}: not a TOML file", path.display()))?;
    if table.contains_key("registration") || table.contains_key("method") {
        let config = PipelineConfig::from_toml_str(&text, path)?;
        return Ok((config.registration, Some(config.method)));
    }
    flowfilter_pipeline::geometry::params::reject_non_finite(&table)
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let config: RegistrationConfig = toml::from_str(&text).with_context(|| {
        format!("{}: invalid registration config (tables [icp], [cpd], [filterreg], [flowfilter])", path.display())
    })?;
    config.validate().map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    Ok((config, None))
}

/// Run `register`.
pub fn run(args: &RegisterArgs) -> anyhow::Result<ExitCode> {
    let (config, config_method) = match &args.config {
        Some(p) => read_config(p)?,
        None => (RegistrationConfig::default(), None),
    };
    let method = args.method.clone().or(config_method).unwrap_or_else(|| "filterreg-pt2pt".into());
    let registrar = registrar_by_name(&method, &config).context("--method / --config")?;
    let mut source = read_ply(&args.source)?;
    let mut target = read_ply(&args.target)?;
    if args.estimate_normals {
        estimate_normals(&mut source, args.normals_k);
        estimate_normals(&mut target, args.normals_k);
    }
    let init = match &args.init {
        Some(path) => crate::matrix_file::read_pose(path)?,
        None if args.global => global_init(&source, &target, args.global_voxel)?,
        None => Pose::identity(),
    };
    let (model_points, target_points) = (source.len(), target.len());
    let start = Instant::now();
    let mut problem = RegistrationProblem::new(source, target).with_init(init);
    let mut notes = Vec::new();
    // A spinner for runs long enough to wonder about (CPD's iterations visit every pair).
    let long = registrar.name() == "cpd" && (model_points as f64) * (target_points as f64) > LONG_RUN_PAIRS;
    let spinner = long.then(|| {
        crate::progress::spinner(format!("register: {} on {model_points} x {target_points} points", registrar.name()))
    });
    let r = match registrar.register_checked(&problem) {
        Err(RegistrationError::MissingNormals { .. }) => {
            for (cloud, which, path) in
                [(&mut problem.source, "source", &args.source), (&mut problem.target, "target", &args.target)]
            {
                if cloud.normals.is_none() {
                    estimate_normals(cloud, args.normals_k);
                    notes.push(format!(
                        "{} ({which}) has no normals, which {} needs: estimated from each point's {} nearest neighbours (--estimate-normals to do so always)",
                        path.display(),
                        registrar.name(),
                        args.normals_k
                    ));
                }
            }
            registrar.register_checked(&problem)?
        }
        other => other?,
    };
    if let Some(s) = spinner {
        s.finish_and_clear();
    }
    for note in &notes {
        eprintln!("warning: {note}");
    }
    let ms = start.elapsed().as_secs_f64() * 1e3;
    let report = RegisterReport::new(registrar.name(), &r, model_points, target_points, ms);
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!("method: {}", registrar.name());
        for row in &report.transform {
            println!("  {:>12.8} {:>12.8} {:>12.8} {:>12.8}", row[0], row[1], row[2], row[3]);
        }
        println!(
            "rotation {:.4} deg, {} iterations, converged: {}, fitness {:.4}, inlier RMSE {:.3} mm, {:.1} ms",
            report.rotation_angle_deg,
            r.iterations,
            r.converged,
            r.fitness,
            r.inlier_rmse * 1e3,
            ms
        );
        for w in &r.warnings {
            eprintln!("warning: {w}");
        }
    }
    Ok(crate::exit_code(r.warnings.iter().any(|w| w.is_implausible())))
}
