//! Every registration backend on the test suite's bumpy closed shape (5k and 20k points), moved
//! by 25 degrees and 2.7 cm, with 1 mm noise and 10% outliers: time per `register` call.
//! Run: `cargo bench -p flowfilter-registration --bench registration` (`RAYON_NUM_THREADS=1`
//! for one thread). The comparison with probreg and Open3D on the peers' own clouds is the
//! `bench_peers` example (docs/benchmarks.md).

#[path = "../tests/common/mod.rs"]
mod common;

use common::{bumpy_shape, corrupted};
use flowfilter_geometry::Pose;
use flowfilter_registration::{RegistrationConfig, RegistrationProblem, registrar_by_name};
use nalgebra::{Translation3, UnitQuaternion, Vector3};

fn main() {
    divan::main();
}

/// The pair of `n` points and a configuration as the peers harness uses (25 cm ICP gate).
fn problem(n: usize) -> (RegistrationProblem, RegistrationConfig) {
    let source = bumpy_shape(n, 1);
    let truth = Pose::from_parts(
        Translation3::new(0.02, -0.015, 0.01),
        UnitQuaternion::from_axis_angle(
            &nalgebra::Unit::new_normalize(Vector3::new(0.3, 1.0, 0.2)),
            25f64.to_radians(),
        ),
    );
    let target = corrupted(&source, &truth, 0.001, 0.1, 2);
    let mut config = RegistrationConfig::default();
    config.cpd.w = 0.2;
    config.filterreg.w = 0.2;
    config.icp.max_correspondence_distance = 0.25;
    config.icp.max_iterations = 200;
    (RegistrationProblem::new(source, target), config)
}

#[divan::bench(args = ["icp-pt2pt", "icp-pt2pl", "filterreg-pt2pt", "filterreg-pt2pl", "cpd"], sample_count = 10)]
fn points_5000(bencher: divan::Bencher, method: &str) {
    let (problem, config) = problem(5000);
    let registrar = registrar_by_name(method, &config).unwrap();
    bencher.bench(|| registrar.register(&problem).unwrap());
}

#[divan::bench(args = ["icp-pt2pt", "icp-pt2pl", "filterreg-pt2pt", "filterreg-pt2pl"], sample_count = 10)]
fn points_20000(bencher: divan::Bencher, method: &str) {
    let (problem, config) = problem(20000);
    let registrar = registrar_by_name(method, &config).unwrap();
    bencher.bench(|| registrar.register(&problem).unwrap());
}
