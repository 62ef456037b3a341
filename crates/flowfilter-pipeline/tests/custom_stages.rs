//! The pipeline's seams used from outside: a custom `CorrespondenceFinder` and a custom
//! `Registrar` plugged in through `Pipeline::with_stages`, speaking only the types this crate
//! re-exports.

mod common;

use common::{box_scene, frame, truth};
use flowfilter_pipeline::geometry::weighted_kabsch;
use flowfilter_pipeline::registration::{RegistrationConfig, registrar_by_name};
use flowfilter_pipeline::{
    CorrespondenceFinder, Correspondences, DepthPreparer, FlowPairs, Pipeline, PipelineConfig, PipelineError, Pose,
    PreparedFrame, Registrar, Registration, RegistrationError, RegistrationProblem,
};
use flowfilter_synth::Rig;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

/// An oracle finder: every model point paired with where the known motion puts it, every
/// third pair weighted 0 (as rejected pairs are).
struct KnownMotion {
    motion: Pose,
    calls: Arc<AtomicUsize>,
}

impl KnownMotion {
    /// The finder, and the counter of its searches.
    fn new(motion: Pose) -> (Self, Arc<AtomicUsize>) {
        let calls = Arc::new(AtomicUsize::new(0));
        (Self { motion, calls: calls.clone() }, calls)
    }
}

impl CorrespondenceFinder for KnownMotion {
    fn name(&self) -> &str {
        "known-motion"
    }

    fn find(&self, model: &PreparedFrame, _target: &PreparedFrame) -> Result<FlowPairs, PipelineError> {
        self.calls.fetch_add(1, Ordering::Relaxed);
        let source = model.cloud.points.clone();
        let target = source.iter().map(|p| self.motion * p).collect();
        let weights = (0..source.len()).map(|i| if i % 3 == 0 { 0.0 } else { 1.0 }).collect();
        Ok(FlowPairs {
            pairs: Correspondences { source, target, weights },
            tracked: model.cloud.len(),
            flow_seconds: 0.0,
        })
    }
}

/// A registrar that trusts the correspondences alone: weighted Kabsch on them.
struct PairsOnly;

impl Registrar for PairsOnly {
    fn name(&self) -> &str {
        "pairs-only"
    }

    fn register(&self, p: &RegistrationProblem) -> Result<Registration, RegistrationError> {
        let c =
            p.correspondences.as_ref().ok_or(RegistrationError::Config("pairs-only needs correspondences".into()))?;
        let transform = weighted_kabsch(&c.source, &c.target, Some(&c.weights))
            .map_err(|e| RegistrationError::Config(e.to_string()))?;
        Ok(Registration {
            transform,
            iterations: 1,
            converged: true,
            fitness: 1.0,
            inlier_rmse: 0.0,
            sigma2: None,
            scale: None,
            history: vec![],
            warnings: vec![],
            correspondence_set: Some(0),
            uncertainty: None,
            overruled_flow: None,
        })
    }

    fn uses_correspondences(&self) -> bool {
        true
    }
}

fn preparer(config: &PipelineConfig) -> Box<DepthPreparer> {
    Box::new(DepthPreparer::new(config.depth.clone(), config.cloud.clone()).unwrap())
}

#[test]
fn a_custom_finder_and_registrar_run_through_with_stages() {
    let (rig, scene) = (Rig::bigbird_like(), box_scene());
    let (a, b) = (frame(&scene, &rig, 3, 0), frame(&scene, &rig, 3, 12));
    let motion = truth(&rig, 3, 0, 12);
    // The pipeline's own last stage (the direct image alignment) would move the exact answer by
    // its own precision (hundredths of a degree): off, so that the registrar's answer is seen.
    let mut config = PipelineConfig::default();
    config.align.enabled = false;
    let (finder, calls) = KnownMotion::new(motion);
    let pipeline =
        Pipeline::with_stages(config.clone(), preparer(&config), Some(Box::new(finder)), Box::new(PairsOnly));
    let e = pipeline.estimate(&a, &b).unwrap();
    assert_eq!(e.method, "pairs-only");
    assert_eq!(e.flow_estimator.as_deref(), Some("known-motion"));
    let error = (e.pose.inverse() * motion).rotation.angle().to_degrees();
    assert!(error < 1e-6, "rotation error {error} deg");
    assert!((e.pose.translation.vector - motion.translation.vector).norm() < 1e-9);
    // PairsOnly offers no prior, so the finder ran once (no guided pass) and set 0 was used.
    assert_eq!(calls.load(Ordering::Relaxed), 1);
    let c = e.correspondences.expect("the finder ran");
    assert!(!c.guided);
    assert_eq!(c.tracked, e.registration.model_points);
    assert_eq!(c.consistent, e.registration.model_points);
    assert_eq!(c.inliers, c.consistent - c.consistent.div_ceil(3));
    assert!(e.warnings.is_empty(), "{:?}", e.warnings);
}

#[test]
fn a_custom_finder_feeds_the_shipped_flowfilter_and_is_skipped_for_geometric_registrars() {
    let (rig, scene) = (Rig::bigbird_like(), box_scene());
    let (a, b) = (frame(&scene, &rig, 3, 0), frame(&scene, &rig, 3, 24));
    let motion = truth(&rig, 3, 0, 24);
    let config = PipelineConfig::default();
    let registration = RegistrationConfig::default();
    // Flow Filter offers a prior, so the finder is asked twice (plain and guided).
    let (finder, calls) = KnownMotion::new(motion);
    let flowfilter = registrar_by_name("flowfilter", &registration).unwrap();
    let pipeline = Pipeline::with_stages(config.clone(), preparer(&config), Some(Box::new(finder)), flowfilter);
    let e = pipeline.estimate(&a, &b).unwrap();
    let error = (e.pose.inverse() * motion).rotation.angle().to_degrees();
    assert!(error < 0.5, "flowfilter with exact pairs: {error} deg");
    assert!(e.correspondences.is_some());
    assert_eq!(calls.load(Ordering::Relaxed), 2);
    // A registrar that reads no correspondences: the finder is not asked at all.
    let (finder, calls) = KnownMotion::new(motion);
    let icp = registrar_by_name("icp-pt2pl", &registration).unwrap();
    let pipeline = Pipeline::with_stages(config.clone(), preparer(&config), Some(Box::new(finder)), icp);
    let e = pipeline.estimate(&a, &b).unwrap();
    assert!(e.correspondences.is_none() && e.flow_estimator.is_none(), "{:?}", e.correspondences);
    assert_eq!(calls.load(Ordering::Relaxed), 0);
}
