//! [`Pipeline`]: the stages composed, timed, and every degradation reported.

use crate::config::PipelineConfig;
use crate::error::PipelineError;
use crate::estimate::{CorrespondenceSummary, ESTIMATE_SCHEMA, Estimate, RegistrationSummary, StageTimes, matrix_rows};
use crate::frame::RgbdFrame;
use crate::stages::{
    CorrespondenceFinder, DepthPreparer, FlowCorrespondenceFinder, FramePreparer, PreparedFrame, flow_estimator_by_name,
};
use flowfilter_flow::correspondences::FlowPairs;
use flowfilter_registration::{
    Correspondences, FilterReg, Registrar, RegistrationProblem, ransac_kabsch, registrar_by_name,
};
use std::time::Instant;

/// Two RGB-D frames in, a relative pose out.
pub struct Pipeline {
    config: PipelineConfig,
    preparer: Box<dyn FramePreparer>,
    finder: Option<Box<dyn CorrespondenceFinder>>,
    registrar: Box<dyn Registrar>,
}

impl Pipeline {
    /// The default stages, configured (the correspondence stage only for methods that use flow).
    pub fn from_config(config: PipelineConfig) -> Result<Self, PipelineError> {
        config.validate().map_err(|message| PipelineError::Config { path: "<configuration>".into(), message })?;
        let preparer = Box::new(DepthPreparer::new(config.depth.clone(), config.cloud.clone())?);
        let finder: Option<Box<dyn CorrespondenceFinder>> = if config.uses_flow() {
            Some(Box::new(FlowCorrespondenceFinder::new(
                flow_estimator_by_name(&config.flow)?,
                config.flow.correspondences.clone(),
            )))
        } else {
            None
        };
        let registrar = registrar_by_name(&config.method, &config.registration)?;
        Ok(Self { config, preparer, finder, registrar })
    }

    /// A pipeline from custom stages (the configuration is kept for reference).
    pub fn with_stages(
        config: PipelineConfig,
        preparer: Box<dyn FramePreparer>,
        finder: Option<Box<dyn CorrespondenceFinder>>,
        registrar: Box<dyn Registrar>,
    ) -> Self {
        Self { config, preparer, finder, registrar }
    }

    /// The configuration.
    pub fn config(&self) -> &PipelineConfig {
        &self.config
    }

    /// The registration backend's name.
    pub fn method(&self) -> &str {
        self.registrar.name()
    }

    /// Run the frame stage on one frame (reusable across many pairs).
    pub fn prepare(&self, frame: &RgbdFrame) -> Result<PreparedFrame, PipelineError> {
        self.preparer.prepare(frame)
    }

    /// Estimate `T` with `target ~ T * model` from two frames.
    pub fn estimate(&self, model: &RgbdFrame, target: &RgbdFrame) -> Result<Estimate, PipelineError> {
        let t0 = Instant::now();
        let a = self.prepare(model)?;
        let b = self.prepare(target)?;
        let mut e = self.estimate_prepared(&a, &b)?;
        e.stage_ms.total = t0.elapsed().as_secs_f64() * 1e3;
        Ok(e)
    }

    /// Flow pairs: unguided, and (when configured) guided by a geometric registration; the set
    /// whose largest rigid consensus is bigger wins. Returns the pairs, whether they are the
    /// guided ones, and the seconds spent in flow estimation.
    fn find_pairs(
        &self,
        finder: &dyn CorrespondenceFinder,
        model: &PreparedFrame,
        target: &PreparedFrame,
    ) -> Result<(FlowPairs, bool, f64), PipelineError> {
        let plain = finder.find(model, target)?;
        if !self.config.flow.guided {
            let s = plain.flow_seconds;
            return Ok((plain, false, s));
        }
        let ff = &self.config.registration.flowfilter;
        let mut geo_cfg = ff.filterreg.clone();
        geo_cfg.correspondence_weight = 0.0;
        let geometric =
            FilterReg::new(geo_cfg)?.register(&RegistrationProblem::new(model.cloud.clone(), target.cloud.clone()))?;
        let guided = finder.find_guided(model, target, &geometric.transform)?;
        let seconds = plain.flow_seconds + guided.flow_seconds;
        let consensus = |p: &FlowPairs| {
            let c = Correspondences { source: p.model.clone(), target: p.target.clone(), weights: p.weights.clone() };
            ransac_kabsch(&c, ff.ransac_iterations, ff.inlier_threshold_m, ff.min_inliers, ff.seed)
                .map_or(0, |(_, inl)| inl.iter().filter(|b| **b).count())
        };
        Ok(if consensus(&guided) > consensus(&plain) { (guided, true, seconds) } else { (plain, false, seconds) })
    }

    /// Estimate from frames already prepared (their preparation times are reported).
    pub fn estimate_prepared(&self, model: &PreparedFrame, target: &PreparedFrame) -> Result<Estimate, PipelineError> {
        let t0 = Instant::now();
        let mut times =
            StageTimes { depth_model: model.seconds * 1e3, depth_target: target.seconds * 1e3, ..Default::default() };
        let mut warnings = vec![];
        let mut problem = RegistrationProblem::new(model.cloud.clone(), target.cloud.clone());
        let mut summary = None;
        if let Some(finder) = &self.finder {
            if model.sensor.color != target.sensor.color || model.gray.dims() != target.gray.dims() {
                warnings.push(format!(
                    "flow skipped: frames {} and {} come from different colour cameras or image sizes",
                    model.label, target.label
                ));
            } else {
                let tf = Instant::now();
                match self.find_pairs(finder.as_ref(), model, target) {
                    Ok((pairs, guided, flow_seconds)) => {
                        let all = tf.elapsed().as_secs_f64();
                        times.flow = flow_seconds * 1e3;
                        times.correspondences = (all - flow_seconds).max(0.0) * 1e3;
                        let inliers = pairs.weights.iter().filter(|w| **w > 0.0).count();
                        summary = Some(CorrespondenceSummary {
                            tracked: pairs.tracked,
                            consistent: pairs.model.len(),
                            inliers,
                            guided,
                        });
                        problem.correspondences =
                            Some(Correspondences { source: pairs.model, target: pairs.target, weights: pairs.weights });
                    }
                    Err(e) => warnings.push(format!("flow failed: {e}")),
                }
            }
        }
        let tr = Instant::now();
        let reg = self.registrar.register(&problem)?;
        times.registration = tr.elapsed().as_secs_f64() * 1e3;
        times.total = times.depth_model + times.depth_target + t0.elapsed().as_secs_f64() * 1e3;
        warnings.extend(reg.warnings.iter().cloned());
        let (axis, angle) = reg.transform.rotation.axis_angle().map_or(([0.0; 3], 0.0), |(a, t)| ([a.x, a.y, a.z], t));
        let t = reg.transform.translation.vector;
        Ok(Estimate {
            schema: ESTIMATE_SCHEMA,
            method: self.registrar.name().to_string(),
            flow_estimator: self.finder.as_ref().map(|f| f.name().to_string()),
            model: model.label.clone(),
            target: target.label.clone(),
            transform: matrix_rows(&reg.transform),
            rotation_angle_deg: angle.to_degrees(),
            rotation_axis: axis,
            translation_m: [t.x, t.y, t.z],
            registration: RegistrationSummary {
                iterations: reg.iterations,
                converged: reg.converged,
                fitness: reg.fitness,
                inlier_rmse_m: reg.inlier_rmse,
                sigma2: reg.sigma2,
                model_points: model.cloud.len(),
                target_points: target.cloud.len(),
            },
            correspondences: summary,
            stage_ms: times,
            warnings,
            ground_truth: None,
            pose: reg.transform,
        })
    }
}
