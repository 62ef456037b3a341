//! Our side of `bench-speed`: the registration backends on the cloud pairs and DIS on the
//! Sintel pairs, each in a thread pool of the asked size, fastest of the runs [`Repeats`] asks for.

use super::clouds::CloudPair;
use anyhow::Context;
use flowfilter_pipeline::Pose;
use flowfilter_pipeline::depth::ply::read_ply;
use flowfilter_pipeline::eval::{geodesic_error_deg, translation_error_m};
use flowfilter_pipeline::flow::dis::{Dis, DisParams};
use flowfilter_pipeline::flow::lk::to_gray;
use flowfilter_pipeline::flow::{FlowEstimator, sintel};
use flowfilter_pipeline::registration::{RegistrationConfig, RegistrationProblem, registrar_by_name};
use std::path::Path;
use std::time::Instant;

/// The methods timed on the cloud pairs.
pub const REGISTRATION_METHODS: [&str; 5] = ["filterreg-pt2pt", "filterreg-pt2pl", "icp-pt2pt", "icp-pt2pl", "cpd"];

/// One method's fastest run.
#[derive(Debug, Clone)]
pub struct Timed {
    /// Seconds of the fastest run.
    pub seconds: f64,
    /// Its error: rotation (deg) for registration, EPE (px) for flow.
    pub error: f64,
    /// Translation error (m), for registration.
    pub translation_m: Option<f64>,
    /// Iterations, for registration.
    pub iterations: Option<usize>,
    /// The registration's pose.
    pub pose: Option<Pose>,
}

/// The parameters both sides run with: probreg's FilterReg (`w = 0.2`, 100 iterations, tolerance
/// 1e-6), Open3D's ICP with a 5 cm gate and 30 iterations (Open3D's stopping rule alone), and
/// `configs/cpd-full-cloud.toml` for our CPD on every point.
pub fn registration_config() -> anyhow::Result<RegistrationConfig> {
    let path = crate::repo_root().join("configs/cpd-full-cloud.toml");
    let mut config = flowfilter_pipeline::PipelineConfig::from_file(&path)?.registration;
    config.filterreg.w = 0.2;
    config.filterreg.max_iterations = 100;
    config.filterreg.tolerance = 1e-6;
    config.icp.max_correspondence_distance = 0.05;
    config.icp.max_iterations = 30;
    config.icp.relative_fitness = 1e-6;
    config.icp.relative_rmse = 1e-6;
    config.icp.min_update = 0.0;
    Ok(config)
}

/// The geodesic rotation (deg) and translation (m) errors of `estimate` against `truth`.
pub fn pose_errors(estimate: &Pose, truth: &Pose) -> (f64, f64) {
    (geodesic_error_deg(estimate, truth), translation_error_m(estimate, truth))
}

/// How many times each timing runs (both sides, the same rule): at least `min` times, then
/// again while the runs so far took less than `budget_s` in all, up to [`Repeats::MAX_RUNS`].
/// A 20 ms ICP run is over before the host's stalls average out; three runs of it left the
/// speed-up swinging between 1.3x and 2.2x from one bench run to the next.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Repeats {
    /// Runs always made.
    pub min: usize,
    /// Seconds of runs after which no further run starts (0: exactly `min` runs).
    pub budget_s: f64,
}

impl Repeats {
    /// The most runs of one timing.
    pub const MAX_RUNS: usize = 50;

    /// Whether another run follows `runs` runs that took `spent_s` seconds in all.
    pub fn again(&self, runs: usize, spent_s: f64) -> bool {
        runs < self.min.max(1) || (runs < Self::MAX_RUNS && spent_s < self.budget_s)
    }
}

/// The rule in words, for the report's heading.
impl std::fmt::Display for Repeats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let runs = if self.min == 1 { "run" } else { "runs" };
        if self.budget_s > 0.0 {
            write!(
                f,
                "fastest of at least {} {runs} per timing, repeated while under {} s in all, at most {}",
                self.min,
                self.budget_s,
                Self::MAX_RUNS
            )
        } else {
            write!(f, "fastest of {} {runs} per timing", self.min)
        }
    }
}

/// Run `f` in `pool` as `repeats` says and keep the fastest run's seconds and result.
pub fn fastest<T: Send>(
    pool: &rayon::ThreadPool,
    repeats: Repeats,
    mut f: impl FnMut() -> anyhow::Result<T> + Send,
) -> anyhow::Result<(f64, T)> {
    let mut best: Option<(f64, T)> = None;
    let (mut runs, mut spent) = (0, 0.0);
    while repeats.again(runs, spent) {
        let (secs, out) = pool.install(|| {
            let t0 = Instant::now();
            let out = f();
            (t0.elapsed().as_secs_f64(), out)
        });
        let out = out?;
        (runs, spent) = (runs + 1, spent + secs);
        if best.as_ref().is_none_or(|(b, _)| secs < *b) {
            best = Some((secs, out));
        }
    }
    Ok(best.expect("at least one run"))
}

/// Every registration method on one pair.
///
/// # Errors
/// A cloud that cannot be read, a method that fails.
pub fn registration(
    pair: &CloudPair,
    config: &RegistrationConfig,
    pool: &rayon::ThreadPool,
    repeats: Repeats,
) -> anyhow::Result<Vec<(String, Timed)>> {
    let source = read_ply(&pair.source).with_context(|| format!("reading {}", pair.source.display()))?;
    let target = read_ply(&pair.target).with_context(|| format!("reading {}", pair.target.display()))?;
    let problem = RegistrationProblem::new(source, target);
    REGISTRATION_METHODS
        .iter()
        .map(|&method| {
            let registrar = registrar_by_name(method, config)?;
            let (seconds, r) = fastest(pool, repeats, || Ok(registrar.register(&problem)?))?;
            let (deg, metres) = pose_errors(&r.transform, &pair.truth);
            Ok((
                method.to_string(),
                Timed {
                    seconds,
                    error: deg,
                    translation_m: Some(metres),
                    iterations: Some(r.iterations),
                    pose: Some(r.transform),
                },
            ))
        })
        .collect()
}

/// The Sintel cases timed (pass/scene).
pub const SINTEL_CASES: [&str; 4] = ["clean/easy", "clean/medium", "final/easy", "final/medium"];

/// DIS-medium (OpenCV's preset) on one Sintel pair; the error is the EPE over all pixels.
///
/// # Errors
/// A pair that cannot be read.
pub fn flow(sintel_root: &Path, case: &str, pool: &rayon::ThreadPool, repeats: Repeats) -> anyhow::Result<Timed> {
    let pair = sintel::load(&sintel_root.join(case)).map_err(anyhow::Error::msg)?;
    let (a, b) = (to_gray(&pair.from), to_gray(&pair.to));
    let dis = Dis::new(DisParams::medium())?;
    pool.install(|| dis.dense(&a, &b, None))?; // warm-up, as the peer's
    let (seconds, field) = fastest(pool, repeats, || Ok(dis.dense(&a, &b, None)?))?;
    let (epe, _) = flowfilter_pipeline::flow::metrics::epe(&field, &pair.flow, None)
        .context("the flow and its ground truth differ in size")?;
    Ok(Timed { seconds, error: epe, translation_m: None, iterations: None, pose: None })
}
