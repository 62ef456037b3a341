//! Flow Filter on a rotationally symmetric object: geometry alone cannot see a rotation about
//! the axis, correspondences can.

mod common;

use flowfilter_geometry::{Point3, PointCloud, Pose, Vector3};
use flowfilter_registration::{
    Correspondences, FlowFilter, FlowFilterConfig, FlowFilterMode, Registrar, RegistrationConfig, RegistrationProblem,
    RegistrationWarning, registrar_by_name,
};

/// A partial cylinder (the visible half of a can), radius 3.4 cm, height 10 cm.
fn half_cylinder() -> PointCloud {
    let mut pts = vec![];
    for i in 0..60 {
        for j in 0..40 {
            let a = -1.4 + 2.8 * i as f64 / 59.0;
            pts.push(Point3::new(0.034 * a.sin(), 0.1 * j as f64 / 39.0 - 0.05, 0.7 - 0.034 * a.cos()));
        }
    }
    PointCloud::from_points(pts)
}

#[test]
fn correspondences_resolve_rotation_about_the_symmetry_axis() {
    let source = half_cylinder();
    // Rotation of 15 deg about the cylinder's own axis (vertical through (0, 0, 0.7)).
    let axis_point = Vector3::new(0.0, 0.0, 0.7);
    let spin = Pose::rotation(Vector3::y() * 15f64.to_radians());
    let truth = Pose::translation(axis_point.x, axis_point.y, axis_point.z)
        * spin
        * Pose::translation(-axis_point.x, -axis_point.y, -axis_point.z);
    let target = source.transformed(&truth);
    // Correspondences on a third of the points, 30% of them wrong.
    let mut c = Correspondences::default();
    for (k, p) in source.points.iter().enumerate().step_by(3) {
        c.source.push(*p);
        c.target.push(if k % 10 < 3 { truth * p + Vector3::new(0.02, -0.01, 0.015) } else { truth * p });
        c.weights.push(1.0);
    }
    let mut problem = RegistrationProblem::new(source.clone(), target.clone());
    let err = |t: &Pose| (t * truth.inverse()).rotation.angle().to_degrees();
    let fr = registrar_by_name("filterreg-pt2pt", &RegistrationConfig::default()).unwrap().register(&problem).unwrap();
    println!("filterreg: {:.3} deg", err(&fr.transform));
    assert!(err(&fr.transform) > 1.0, "geometry alone should not see the spin");
    problem.correspondences = Some(c);
    for mode in [FlowFilterMode::FlowOnly, FlowFilterMode::InitOnly, FlowFilterMode::Joint] {
        let ff = FlowFilter::new(FlowFilterConfig { mode, ..Default::default() }).unwrap();
        let r = ff.register(&problem).unwrap();
        println!("{}: {:.4} deg", ff.name(), err(&r.transform));
        if mode != FlowFilterMode::InitOnly {
            assert!(err(&r.transform) < 0.1, "{mode:?}: {} deg", err(&r.transform));
        }
        assert!(r.warnings.is_empty());
    }
}

#[test]
fn without_flow_it_falls_back_to_filterreg_and_says_so() {
    let source = half_cylinder();
    let target = source.transformed(&Pose::translation(0.005, 0.0, 0.0));
    let r = registrar_by_name("flowfilter", &RegistrationConfig::default())
        .unwrap()
        .register(&RegistrationProblem::new(source, target))
        .unwrap();
    assert!(r.warnings.iter().any(|w| matches!(w, RegistrationWarning::FlowFallback { .. })), "{:?}", r.warnings);
}

/// A rotation of `deg` about `axis` through `centre`.
fn rotation_about(centre: &Point3, axis: Vector3, deg: f64) -> Pose {
    Pose::translation(centre.x, centre.y, centre.z)
        * Pose::rotation(axis.normalize() * deg.to_radians())
        * Pose::translation(-centre.x, -centre.y, -centre.z)
}

#[test]
fn geometry_overrules_flow_that_contradicts_it() {
    // An asymmetric shape 70 cm in front of the camera; the true motion is 8 degrees, but the
    // "flow" pairs agree on a motion 20 degrees away from it (a tracker locked on the wrong
    // thing). The geometric check must notice that the flow result does not fit the clouds.
    let mut source = common::bumpy_shape(2500, 3);
    source.transform(&Pose::translation(0.0, 0.0, 0.7));
    let c0 = source.centroid().unwrap();
    let truth = rotation_about(&c0, Vector3::new(0.2, 1.0, 0.1), 8.0);
    let wrong = rotation_about(&c0, Vector3::new(1.0, -0.3, 0.4), 20.0) * truth;
    let target = source.transformed(&truth);
    let mut c = Correspondences::default();
    for p in source.points.iter().step_by(5) {
        c.source.push(*p);
        c.target.push(wrong * p);
        c.weights.push(1.0);
    }
    let mut problem = RegistrationProblem::new(source.clone(), target);
    problem.correspondences = Some(c.clone());
    let err = |t: &Pose| (t * truth.inverse()).rotation.angle().to_degrees();
    let checked = FlowFilter::new(FlowFilterConfig::default()).unwrap().register(&problem).unwrap();
    let unchecked = FlowFilter::new(FlowFilterConfig { geometric_check: false, ..Default::default() })
        .unwrap()
        .register(&problem)
        .unwrap();
    println!(
        "with the check {:.3} deg {:?}; without {:.3} deg",
        err(&checked.transform),
        checked.warnings,
        err(&unchecked.transform)
    );
    assert!(err(&unchecked.transform) > 5.0, "the wrong flow should mislead the unchecked method");
    assert!(err(&checked.transform) < 0.5, "{} deg", err(&checked.transform));
    assert!(
        checked.warnings.iter().any(|w| matches!(w, RegistrationWarning::GeometricCheck { .. })),
        "{:?}",
        checked.warnings
    );
    // Flow that agrees with the geometry passes the check untouched.
    let good: Correspondences = Correspondences {
        source: c.source.clone(),
        target: c.source.iter().map(|p| truth * p).collect(),
        weights: c.weights.clone(),
    };
    problem.correspondences = Some(good);
    let r = FlowFilter::new(FlowFilterConfig::default()).unwrap().register(&problem).unwrap();
    assert!(r.warnings.is_empty() && err(&r.transform) < 0.1, "{:?} {}", r.warnings, err(&r.transform));
}

/// The asymmetric shape 70 cm from the camera turned `deg` degrees (1 mm of sensor noise: no
/// pose fits exactly), with "flow" pairs on every fifth point that all say it stood still (a
/// tracker locked on shading that does not move with a turning surface); and the true motion.
fn turned_with_static_flow(deg: f64) -> (RegistrationProblem, Pose) {
    let mut source = common::bumpy_shape(2500, 3);
    source.transform(&Pose::translation(0.0, 0.0, 0.7));
    let c0 = source.centroid().unwrap();
    let truth = rotation_about(&c0, Vector3::new(0.1, 1.0, 0.2), deg);
    let target = common::corrupted(&source, &truth, 0.001, 0.0, 7);
    let pairs: Vec<Point3> = source.points.iter().step_by(5).copied().collect();
    let mut problem = RegistrationProblem::new(source, target);
    problem.correspondences =
        Some(Correspondences { source: pairs.clone(), target: pairs.clone(), weights: vec![1.0; pairs.len()] });
    (problem, truth)
}

#[test]
fn geometry_that_moves_overrules_flow_that_stands_still() {
    // The asymmetric shape turns 20 degrees, but every "flow" pair says it stood still (a
    // tracker locked on shading that does not move with a turning surface). FilterReg from the
    // initial pose leaves it for 20 degrees of motion and fits better: the motion check keeps it.
    let (problem, truth) = turned_with_static_flow(20.0);
    let err = |t: &Pose| (t * truth.inverse()).rotation.angle().to_degrees();
    // On these whole, noise-free clouds the residual ratio alone would expose the flow result;
    // on real partial views it is 1.04-1.7 (measured on the turntable pairs: no threshold
    // separates it from correct flow results). A ratio rule that never fires isolates the
    // motion check.
    let config = FlowFilterConfig { geometric_ratio: 1e3, ..Default::default() };
    let checked = FlowFilter::new(config.clone()).unwrap().register(&problem).unwrap();
    let unchecked =
        FlowFilter::new(FlowFilterConfig { motion_margin_deg: -1.0, ..config }).unwrap().register(&problem).unwrap();
    println!(
        "with the motion check {:.3} deg {:?}; without {:.3} deg {:?}",
        err(&checked.transform),
        checked.warnings,
        err(&unchecked.transform),
        unchecked.warnings
    );
    assert!(err(&unchecked.transform) > 5.0, "the static flow should hold the method back without the check");
    assert!(err(&checked.transform) < 0.5, "{} deg", err(&checked.transform));
    // The bounds reach the pose the check overruled (the flow's, standing still): the frames
    // support it too.
    let bounds = checked.uncertainty.expect("bounds after the refinement");
    assert!(bounds.rotation_deg >= 19.0, "{bounds:?}");
    assert!(
        checked.warnings.iter().any(|w| matches!(w, RegistrationWarning::MotionCheck { .. })),
        "{:?}",
        checked.warnings
    );
    // The overruled flow result comes back beside the answer (for a caller that can weigh the
    // two on the images): standing still, its bounds reaching the answer.
    let flow = checked.overruled_flow.as_deref().expect("the overruled flow result");
    assert!(err(&flow.transform) > 15.0, "{} deg", err(&flow.transform));
    assert!(flow.uncertainty.is_some_and(|b| b.rotation_deg >= 19.0), "{:?}", flow.uncertainty);
    assert!(unchecked.overruled_flow.is_none());
}

#[test]
fn the_motion_check_also_asks_point_to_plane_icp() {
    // The asymmetric shape turns 12 degrees; every flow pair says it stood still. FilterReg is
    // held to two iterations here (standing in for the GMM's wide kernels averaging a small
    // feature, such as a mug's handle, away: measured on the turntable mugs), so only the
    // motion check's point-to-plane ICP candidate, started from the same initial pose, can
    // find the turn.
    let (problem, truth) = turned_with_static_flow(12.0);
    let err = |t: &Pose| (t * truth.inverse()).rotation.angle().to_degrees();
    let mut config = FlowFilterConfig { geometric_ratio: 1e3, ..Default::default() };
    config.filterreg.max_iterations = 2;
    let with_icp = FlowFilter::new(config.clone()).unwrap().register(&problem).unwrap();
    let without_icp =
        FlowFilter::new(FlowFilterConfig { motion_icp_distance_m: 0.0, ..config }).unwrap().register(&problem).unwrap();
    println!(
        "with the ICP candidate {:.3} deg {:?}; FilterReg only {:.3} deg {:?}",
        err(&with_icp.transform),
        with_icp.warnings,
        err(&without_icp.transform),
        without_icp.warnings
    );
    assert!(err(&without_icp.transform) > 5.0, "{} deg", err(&without_icp.transform));
    assert!(err(&with_icp.transform) < 0.5, "{} deg", err(&with_icp.transform));
    assert!(with_icp.warnings.iter().any(|w| matches!(
        w,
        RegistrationWarning::MotionCheck { kept: "point-to-plane ICP from the initial pose", .. }
    )));
}

#[test]
fn the_motion_rule_on_measured_turntable_pairs() {
    // (mean visible residual mm, degrees moved from the initial pose) of a geometric candidate
    // and of the flow result, measured on the default dataset (`flowfilter estimate`, LK flow).
    let c = FlowFilterConfig::default();
    let wins = |cand: (f64, f64), flow: (f64, f64)| c.motion_wins((cand.0 * 1e-3, cand.1), (flow.0 * 1e-3, flow.1));
    // Flow stuck on shading, the candidate right: mustard bottle NP5 0 -> 30, bleach cleanser
    // NP5 0 -> 9 (fits better, moved further); mug NP4 0 -> 30 (ICP: 10% worse, 27x further).
    assert!(wins((1.851, 30.00), (3.016, 1.96)));
    assert!(wins((2.039, 8.89), (2.125, 3.62)));
    assert!(wins((2.411, 26.26), (2.182, 0.96)));
    // Flow right, the candidate not: sugar box NP1 0 -> 30 (a flip that moved 58 degrees, 4%
    // worse: not twice as far), pudding box NP5 0 -> 9 (better by 1%, but only 1.2 deg further),
    // master chef can NP3 0 -> 15 (geometry stuck on the symmetric can: moved less).
    assert!(!wins((1.776, 57.67), (1.709, 29.61)));
    assert!(!wins((1.857, 9.78), (1.882, 8.59)));
    assert!(!wins((1.344, 0.79), (1.542, 13.47)));
    // Switched off.
    let off = FlowFilterConfig { motion_margin_deg: -1.0, ..Default::default() };
    assert!(!off.motion_wins((1.851e-3, 30.0), (3.016e-3, 1.96)));
}

#[test]
fn the_point_to_plane_polish_stays_at_the_noise_floor() {
    // A noisy partial view of the asymmetric shape, flow pairs with 2 mm of noise (real pairs
    // have about 1 mm): the polish keeps the estimate at the noise floor, and it must move it
    // (it ran). On the symmetric cylinder above it must not slide: that test runs with the
    // polish on, the default. (Its benefit is measured on the benchmark, docs/results.md.)
    let mut shape = common::bumpy_shape(3000, 5);
    shape.transform(&Pose::translation(0.0, 0.0, 0.7));
    let source = shape.select(&(0..shape.len()).filter(|&i| shape.points[i].x < 0.02).collect::<Vec<_>>());
    let c0 = source.centroid().unwrap();
    let truth = rotation_about(&c0, Vector3::new(0.1, 1.0, 0.2), 12.0);
    let target = common::corrupted(&source, &truth, 0.001, 0.0, 9);
    let mut problem = RegistrationProblem::new(source.clone(), target);
    problem.correspondences = Some(Correspondences {
        source: source.points.iter().step_by(7).copied().collect(),
        target: source
            .points
            .iter()
            .step_by(7)
            .enumerate()
            .map(|(i, p)| truth * p + Vector3::new(0.002 * (i as f64 * 0.7).sin(), 0.002 * (i as f64 * 1.3).cos(), 0.0))
            .collect(),
        weights: vec![1.0; source.points.iter().step_by(7).count()],
    });
    let err = |t: &Pose| (t * truth.inverse()).rotation.angle().to_degrees();
    let polished = FlowFilter::new(FlowFilterConfig::default()).unwrap().register(&problem).unwrap();
    let raw = FlowFilter::new(FlowFilterConfig { polish_distance_m: 0.0, ..Default::default() })
        .unwrap()
        .register(&problem)
        .unwrap();
    println!("polished {:.4} deg, unpolished {:.4} deg", err(&polished.transform), err(&raw.transform));
    assert!(err(&polished.transform) < 0.2 && err(&raw.transform) < 0.3);
    assert!(polished.transform != raw.transform, "the polish did not run");
}

#[test]
fn the_polish_guard_on_a_measured_pair() {
    // Gelatin box, top camera, turned 15 degrees (bench pair NP5 0 -> 15): the flow pose is
    // 0.07 deg from the truth, its joint result's flow pairs have a median residual of 0.99 mm;
    // the 5 mm point-to-plane polish follows the partial view's geometry to 1.47 deg off and
    // raises that median to 1.64 mm. The default slack undoes it; a 1 mm slack (the former
    // rule) kept it.
    let cfg = FlowFilterConfig::default();
    assert!(!cfg.polish_agrees_with_flow(0.99e-3, 1.64e-3));
    assert!(FlowFilterConfig { polish_flow_slack_m: 1e-3, ..cfg.clone() }.polish_agrees_with_flow(0.99e-3, 1.64e-3));
    // A polish that barely moves the flow pairs is kept; so is one within half the residual.
    assert!(cfg.polish_agrees_with_flow(1.6e-3, 1.9e-3));
    assert!(cfg.polish_agrees_with_flow(0.4e-3, 0.85e-3));
    assert!(!cfg.polish_agrees_with_flow(0.4e-3, 0.95e-3));
    // A negative slack is a configuration error.
    assert!(FlowFilter::new(FlowFilterConfig { polish_flow_slack_m: -1e-3, ..cfg }).is_err());
}
