//! Plug custom stages into the pipeline: a correspondence finder that thins the flow pairs of
//! the default finder, and a registrar that runs two backends and keeps the better fit.
//! Run: `cargo run --release -p flowfilter-pipeline --example custom_stages`.

use flowfilter_bigbird::SensorId;
use flowfilter_pipeline::registration::{RegistrationConfig, registrar_by_name};
use flowfilter_pipeline::{
    CorrespondenceFinder, DepthPreparer, FlowCorrespondenceFinder, FlowPairs, Pipeline, PipelineConfig, PipelineError,
    Pose, PreparedFrame, Registrar, Registration, RegistrationError, RegistrationProblem, RgbdFrame,
};
use flowfilter_synth::{NoiseProfile, Rig, Scene, procedural, render_frame};

/// Keeps every `keep`-th pair of another finder (fewer pairs, faster registration).
struct Thinned {
    inner: FlowCorrespondenceFinder,
    keep: usize,
}

impl Thinned {
    fn thin(&self, mut found: FlowPairs) -> FlowPairs {
        let c = &mut found.pairs;
        let keep = |i: &usize| i.is_multiple_of(self.keep);
        c.source = c.source.iter().enumerate().filter(|(i, _)| keep(i)).map(|(_, p)| *p).collect();
        c.target = c.target.iter().enumerate().filter(|(i, _)| keep(i)).map(|(_, p)| *p).collect();
        c.weights = c.weights.iter().enumerate().filter(|(i, _)| keep(i)).map(|(_, w)| *w).collect();
        found
    }
}

impl CorrespondenceFinder for Thinned {
    fn name(&self) -> &str {
        "thinned-lk"
    }

    fn find(&self, model: &PreparedFrame, target: &PreparedFrame) -> Result<FlowPairs, PipelineError> {
        Ok(self.thin(self.inner.find(model, target)?))
    }

    fn find_guided(
        &self,
        model: &PreparedFrame,
        target: &PreparedFrame,
        guide: &Pose,
    ) -> Result<FlowPairs, PipelineError> {
        Ok(self.thin(self.inner.find_guided(model, target, guide)?))
    }
}

/// Runs two backends and keeps the result with the higher fitness.
struct BestOf(Box<dyn Registrar>, Box<dyn Registrar>);

impl Registrar for BestOf {
    fn name(&self) -> &str {
        "best-of"
    }

    fn register(&self, p: &RegistrationProblem) -> Result<Registration, RegistrationError> {
        let (a, b) = (self.0.register(p)?, self.1.register(p)?);
        Ok(if b.fitness > a.fitness { b } else { a })
    }

    fn uses_correspondences(&self) -> bool {
        self.0.uses_correspondences() || self.1.uses_correspondences()
    }

    fn prior(&self, p: &RegistrationProblem) -> Result<Option<Registration>, RegistrationError> {
        // Neither inner backend may be handed the other's prior: offer none.
        let _ = p;
        Ok(None)
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (rig, sensor) = (Rig::bigbird_like(), SensorId::new(3).expect("NP1..NP5"));
    let scene = Scene::new(procedural("box", 1)?.placed_on_table(0.01, -0.005), 1);
    let frame = |angle| {
        let f = render_frame(&scene, &rig, sensor, angle, Some(&NoiseProfile::carmine()), 7);
        RgbdFrame {
            label: format!("{sensor}_{angle}"),
            color: f.color,
            depth: f.raw_depth,
            mask: f.mask,
            sensor: rig.sensors[&sensor].rgbd,
        }
    };
    let config = PipelineConfig::default();
    let finder = Thinned {
        inner: FlowCorrespondenceFinder::new(config.flow.estimator()?, config.flow.correspondences.clone()),
        keep: 2,
    };
    let registration = RegistrationConfig::default();
    let registrar =
        BestOf(registrar_by_name("flowfilter", &registration)?, registrar_by_name("icp-pt2pl", &registration)?);
    let preparer = DepthPreparer::new(config.depth.clone(), config.cloud.clone())?;
    let pipeline = Pipeline::with_stages(config, Box::new(preparer), Some(Box::new(finder)), Box::new(registrar));
    let e = pipeline.estimate(&frame(0), &frame(15))?;
    println!(
        "{} with {}: turned {:.2} deg (true 15), {:?} pairs, {:.0} ms",
        e.method,
        e.flow_estimator.as_deref().unwrap_or("-"),
        e.rotation_angle_deg,
        e.correspondences.map(|c| c.consistent),
        e.stage_ms.total
    );
    for w in &e.warnings {
        println!("warning [{}]: {w}", w.code());
    }
    Ok(())
}
