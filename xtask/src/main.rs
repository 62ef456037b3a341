//! `cargo xtask <command>`: project automation.
//!
//! - `bench-bigbird`: the paper's BigBIRD experiment (relative rotation between turntable
//!   angles seen by one camera) on the embedded synthetic dataset, generated once and cached
//!   under `target/`, or on a real BigBIRD download (`--data DIR`).
//! - `bench-bop`: the same measurement on BOP scenes (image `i` to image `i + gap`, every
//!   object visible in both), on a BOP dataset (`--data DIR`) or the embedded synthetic scenes.
//! - `bench-merge`: the shards of a sharded benchmark run (`--shard K/N`, one process each,
//!   launched by any scheduler: `deploy/`) merged into one run's outputs.
//! - `bench-speed`: ours against the peers on the same inputs with 1 and 2 threads, and the
//!   pipeline's pairs per second.
//! - `twin`: the synthetic twin of real YCB-Video frames (the real views and motions under the
//!   synthetic sensor model), for `bench-bop --data`.
//! - `publish-check`: every library crate packages and builds from its package; a scratch
//!   crate outside the workspace depends on `flowfilter-registration` and runs its README
//!   example.

/// mimalloc keeps freed pages for the next frame's images (the workspace manifest says more).
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

mod bench;
mod bench_bop;
mod bench_real;
mod bench_track;
mod dataset;
mod deps;
mod failures;
mod merge;
mod mutate;
mod pairs;
mod plots;
mod publish_check;
mod real_twin;
mod realsense;
mod report;
mod sequence;
mod shard;
mod speed;
mod twin;

use clap::{Parser, Subcommand};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Parser)]
#[command(name = "xtask")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the BigBIRD benchmark and write results/<timestamp>/.
    BenchBigbird(bench::BenchArgs),
    /// Run the relative-pose benchmark on BOP scenes (a BOP dataset, or the embedded synthetic
    /// scenes) and write results/<timestamp>/.
    BenchBop(bench_bop::BopBenchArgs),
    /// Run the relative-pose benchmark on real RGB-D sequences with calibrated camera poses
    /// (default: ../shared/data/realsense-shelf): whole frames and region objects with a
    /// segmentation network's masks, and write results/<timestamp>/.
    BenchReal(bench_real::RealBenchArgs),
    /// Track objects through streams (synthetic turntable loops, the real sequences as whole
    /// frames and regions) with `flowfilter track`'s tracker and with chained pairwise
    /// estimates; ATE, RPE, the last frame's error, frames per second.
    BenchTrack(bench_track::TrackBenchArgs),
    /// Merge the shards of a sharded benchmark run (`--shard K/N`) into the outputs one
    /// process would have written.
    BenchMerge(merge::MergeArgs),
    /// Time ours against the peers (probreg, Open3D, OpenCV) on the same inputs with 1 and 2
    /// threads, and the pipeline's pairs per second for each method.
    BenchSpeed(speed::SpeedArgs),
    /// Check that every library crate packages and builds on its own, and that a crate outside
    /// the workspace can depend on one and run its README example.
    PublishCheck(publish_check::PublishCheckArgs),
    /// Write the synthetic twin of real YCB-Video frames: each annotated object's scan rendered
    /// where the annotation puts it, through the frames' camera, under the synthetic sensor
    /// model (measure it with `bench-bop --data OUT`).
    Twin(twin::TwinArgs),
    /// Feed randomly mutated files of every input format to the parsers (seeded); fail on any
    /// panic.
    Mutate(mutate::MutateArgs),
}

/// The repository root (relative paths in protocols and options are resolved against it).
pub(crate) fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// `../shared/<path>` beside the repository, or `None` with a message when it is absent: the
/// tests that need the shared data skip without it.
#[cfg(test)]
pub(crate) fn shared_or_skip(path: &str) -> Option<PathBuf> {
    let dir = repo_root().join("../shared").join(path);
    if dir.exists() {
        Some(dir)
    } else {
        eprintln!("skipping: {} is absent (the shared data sits beside the repository)", dir.display());
        None
    }
}

/// `path` as given when absolute, else under the repository root: what a protocol or a
/// `--pipeline` option names, and where the embedded datasets are cached, whatever the working
/// directory (`cargo test -p xtask` runs in `xtask/`).
pub(crate) fn in_repo(path: &Path) -> PathBuf {
    if path.is_absolute() { path.to_path_buf() } else { repo_root().join(path) }
}

/// A directory's last component (an object's or a scene's name in the results).
pub(crate) fn dir_name(dir: &Path) -> String {
    dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
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
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .with_writer(std::io::stderr)
        .init();
    let result = match Cli::parse().command {
        Command::BenchBigbird(args) => bench::run(&args),
        Command::BenchBop(args) => bench_bop::run(&args),
        Command::BenchReal(args) => bench_real::run(&args),
        Command::BenchTrack(args) => bench_track::run(&args),
        Command::BenchMerge(args) => merge::run(&args),
        Command::BenchSpeed(args) => speed::run(&args),
        Command::PublishCheck(args) => publish_check::run(&args),
        Command::Mutate(args) => mutate::run(&args),
        Command::Twin(args) => twin::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
