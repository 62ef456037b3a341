//! Bad clouds give typed errors; a run that cannot converge says so.

mod common;

use flowfilter_geometry::{Point3, PointCloud, Pose};
use flowfilter_registration::{
    METHOD_NAMES, RegistrationConfig, RegistrationError, RegistrationProblem, registrar_by_name,
};

fn run(
    name: &str,
    source: PointCloud,
    target: PointCloud,
) -> Result<flowfilter_registration::Registration, RegistrationError> {
    registrar_by_name(name, &RegistrationConfig::default()).unwrap().register(&RegistrationProblem::new(source, target))
}

#[test]
fn degenerate_clouds_are_rejected_by_every_backend() {
    let good = common::bumpy_shape(300, 1);
    let line = PointCloud::from_points((0..50).map(|i| Point3::new(i as f64 * 0.01, 0.0, 0.5)).collect());
    let same = PointCloud::from_points(vec![Point3::new(0.1, 0.2, 0.3); 20]);
    let mut nan = good.clone();
    nan.points[17].y = f64::NAN;
    let two = PointCloud::from_points(vec![Point3::origin(), Point3::new(1.0, 0.0, 0.0)]);
    for name in METHOD_NAMES {
        assert_eq!(
            run(name, PointCloud::default(), good.clone()).unwrap_err(),
            RegistrationError::EmptyCloud { which: "source" },
            "{name}"
        );
        assert_eq!(
            run(name, good.clone(), two.clone()).unwrap_err(),
            RegistrationError::TooFewPoints { which: "target", found: 2 },
            "{name}"
        );
        assert_eq!(
            run(name, line.clone(), good.clone()).unwrap_err(),
            RegistrationError::Degenerate { which: "source" },
            "{name}"
        );
        assert_eq!(
            run(name, good.clone(), same.clone()).unwrap_err(),
            RegistrationError::Degenerate { which: "target" },
            "{name}"
        );
        assert_eq!(
            run(name, nan.clone(), good.clone()).unwrap_err(),
            RegistrationError::NonFinite { which: "source", index: 17 },
            "{name}"
        );
    }
    let mut no_normals = good.clone();
    no_normals.normals = None;
    for name in ["icp-pt2pl", "filterreg-pt2pl"] {
        let e = run(name, good.clone(), no_normals.clone()).unwrap_err();
        assert!(matches!(e, RegistrationError::MissingNormals { which: "target", .. }), "{name}: {e}");
        assert!(e.to_string().contains("needs normals"), "{e}");
    }
    assert!(registrar_by_name("teaser", &RegistrationConfig::default()).is_err());
}

#[test]
fn runs_that_cannot_converge_report_it() {
    let source = common::bumpy_shape(500, 2);
    // The target is 5 m away: no correspondence within ICP's gate.
    let far = source.transformed(&Pose::translation(5.0, 0.0, 0.0));
    for name in ["icp-pt2pt", "icp-pt2pl"] {
        let r = run(name, source.clone(), far.clone()).unwrap();
        assert!(!r.converged, "{name}");
        assert!(!r.warnings.is_empty(), "{name}");
        assert_eq!(r.fitness, 0.0);
    }
    // A GMM method stopped after one iteration has not converged.
    let mut cfg = RegistrationConfig::default();
    cfg.filterreg.max_iterations = 1;
    cfg.cpd.max_iterations = 1;
    let target =
        source.transformed(&Pose::new(nalgebra::Vector3::new(0.02, 0.0, 0.0), nalgebra::Vector3::new(0.0, 0.3, 0.0)));
    for name in ["cpd", "filterreg-pt2pt"] {
        let r = registrar_by_name(name, &cfg)
            .unwrap()
            .register(&RegistrationProblem::new(source.clone(), target.clone()))
            .unwrap();
        assert!(!r.converged, "{name}");
    }
}

/// A fast CPD E-step that would run the lattice near the point spacing is refused with the key
/// and the rule.
#[test]
fn a_fast_cpd_e_step_below_its_neighbour_floor_is_refused() {
    use flowfilter_registration::{Cpd, CpdConfig, CpdEStep, MIN_LATTICE_NEIGHBOURS};
    let e_step = CpdEStep::Fast { max_pairs: 1, max_neighbours: MIN_LATTICE_NEIGHBOURS - 1 };
    let e = Cpd::new(CpdConfig { e_step, ..Default::default() }).unwrap_err().to_string();
    assert!(e.contains("e_step.max_neighbours") && e.contains("at least 100") && e.contains("99"), "{e}");
    let e_step = CpdEStep::Fast { max_pairs: 1, max_neighbours: MIN_LATTICE_NEIGHBOURS };
    assert!(Cpd::new(CpdConfig { e_step, ..Default::default() }).is_ok());
}
