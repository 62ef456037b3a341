//! [`Recorder`]: a `.rrd` file of Rerun's, written through its SDK (feature `rerun`).

use crate::error::RecordError;
use crate::paths;
use crate::scene::{FrameLayer, PairScene};
use flowfilter_geometry::Pose;
use std::path::{Path, PathBuf};

/// A Rerun recording being written to a `.rrd` file: one or more pairs, each at its own step of
/// the [`paths::TIMELINE_PAIR`] timeline.
pub struct Recorder {
    stream: rerun::RecordingStream,
    path: PathBuf,
}

impl Recorder {
    /// Start a recording in `path` (created or replaced), named `application` in the viewer.
    ///
    /// # Errors
    /// [`RecordError::Create`] when the file cannot be created.
    ///
    /// ```
    /// let dir = tempfile::tempdir()?;
    /// let recorder = flowfilter_rerun::Recorder::create(&dir.path().join("pair.rrd"), "flowfilter")?;
    /// recorder.finish()?;
    /// assert!(dir.path().join("pair.rrd").metadata()?.len() > 0);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn create(path: &Path, application: &'static str) -> Result<Self, RecordError> {
        let stream = rerun::RecordingStreamBuilder::new(application)
            .save(path)
            .map_err(|e| RecordError::Create { path: path.to_path_buf(), message: e.to_string() })?;
        Ok(Self { stream, path: path.to_path_buf() })
    }

    /// Log one pair at step `step` of the pair timeline.
    ///
    /// # Errors
    /// [`RecordError::Log`] naming the entity that failed.
    pub fn log_pair(&self, step: i64, scene: &PairScene) -> Result<(), RecordError> {
        self.stream.set_time_sequence(paths::TIMELINE_PAIR, step);
        self.log_frame(scene, &scene.model, [paths::MODEL_COLOR, paths::MODEL_DEPTH, paths::MODEL_MASK])?;
        self.log_frame(scene, &scene.target, [paths::TARGET_COLOR, paths::TARGET_DEPTH, paths::TARGET_MASK])?;
        self.log_flow(scene)?;
        self.log_clouds(scene)?;
        self.log_pose(scene)?;
        self.log_judge(scene)?;
        self.log_report(scene)
    }

    /// Flush and close the file.
    ///
    /// # Errors
    /// [`RecordError::Log`] when the last entities could not be written.
    pub fn finish(self) -> Result<(), RecordError> {
        self.stream.flush_blocking().map_err(|e| self.error("(flush)", e))
    }

    fn error(&self, entity: &str, e: impl std::fmt::Display) -> RecordError {
        RecordError::Log { path: self.path.clone(), entity: entity.into(), message: e.to_string() }
    }

    fn log(&self, entity: &str, what: &impl rerun::AsComponents) -> Result<(), RecordError> {
        self.stream.log(entity, what).map_err(|e| self.error(entity, e))
    }

    fn log_frame(
        &self,
        _scene: &PairScene,
        f: &FrameLayer,
        [color, depth, mask]: [&str; 3],
    ) -> Result<(), RecordError> {
        let (w, h) = f.color.dimensions();
        self.log(color, &rerun::Image::from_rgb24(f.color.as_raw().clone(), [w, h]))?;
        let (dw, dh) = (f.depth_m.width() as u32, f.depth_m.height() as u32);
        let bytes: Vec<u8> = f.depth_m.as_slice().iter().flat_map(|v| v.to_le_bytes()).collect();
        let image = rerun::DepthImage::from_data_type_and_bytes(bytes, [dw, dh], rerun::ChannelDatatype::F32);
        self.log(depth, &image.with_meter(1.0))?;
        let (mw, mh) = (f.mask.width() as u32, f.mask.height() as u32);
        let labels: Vec<u8> = f.mask.as_slice().iter().map(|&m| u8::from(m)).collect();
        let format = rerun::datatypes::ImageFormat::segmentation([mw, mh], rerun::ChannelDatatype::U8);
        self.log(mask, &rerun::SegmentationImage::new(labels, format).with_opacity(0.4))
    }

    fn log_flow(&self, scene: &PairScene) -> Result<(), RecordError> {
        let origins = scene.flow.iter().map(|p| p.model_px);
        let vectors = scene.flow.iter().map(|p| [p.target_px[0] - p.model_px[0], p.target_px[1] - p.model_px[1]]);
        let colors = scene.flow.iter().map(|p| rerun::Color::from_rgb(p.color()[0], p.color()[1], p.color()[2]));
        let arrows = rerun::Arrows2D::from_vectors(vectors).with_origins(origins).with_colors(colors).with_radii([0.5]);
        self.log(paths::TARGET_FLOW, &arrows)?;
        let kept: Vec<_> = scene.flow.iter().filter(|p| p.kept).collect();
        let strips = kept.iter().map(|p| vec![p.aligned, p.target]);
        let colors = kept.iter().map(|p| rerun::Color::from_rgb(p.color()[0], p.color()[1], p.color()[2]));
        self.log(paths::WORLD_PAIRS, &rerun::LineStrips3D::new(strips).with_colors(colors))
    }

    fn log_clouds(&self, scene: &PairScene) -> Result<(), RecordError> {
        let cloud = |points: &[[f32; 3]], rgb: [u8; 3]| {
            rerun::Points3D::new(points.iter().copied())
                .with_colors([rerun::Color::from_rgb(rgb[0], rgb[1], rgb[2])])
                .with_radii([0.0015])
        };
        self.log(paths::CLOUD_MODEL, &cloud(&scene.model_cloud, [230, 120, 40]))?;
        self.log(paths::CLOUD_TARGET, &cloud(&scene.target_cloud, [60, 120, 230]))?;
        self.log(paths::CLOUD_ALIGNED, &cloud(&scene.aligned_cloud, [40, 200, 60]))?;
        if let Some(truth) = &scene.truth_cloud {
            self.log(paths::CLOUD_TRUTH, &cloud(truth, [240, 240, 240]))?;
        }
        if let Some(best) = &scene.best_candidate_cloud {
            self.log(paths::CLOUD_BEST_CANDIDATE, &cloud(best, [200, 60, 200]))?;
        }
        Ok(())
    }

    fn log_pose(&self, scene: &PairScene) -> Result<(), RecordError> {
        self.log(paths::POSE_ESTIMATE, &transform(&scene.pose))?;
        if let Some(truth) = &scene.truth {
            self.log(paths::POSE_TRUTH, &transform(truth))?;
        }
        if let Some((rotation, translation)) = scene.bounds {
            self.log(paths::BOUND_ROTATION, &rerun::Scalars::single(rotation))?;
            self.log(paths::BOUND_TRANSLATION, &rerun::Scalars::single(translation))?;
        }
        if let Some((rotation, translation)) = scene.errors {
            self.log(paths::ERROR_ROTATION, &rerun::Scalars::single(rotation))?;
            self.log(paths::ERROR_TRANSLATION, &rerun::Scalars::single(translation))?;
        }
        Ok(())
    }

    fn log_judge(&self, scene: &PairScene) -> Result<(), RecordError> {
        if scene.candidates.is_empty() {
            return Ok(());
        }
        let table = rerun::TextDocument::new(scene.candidates_table()).with_media_type(rerun::MediaType::markdown());
        self.log(paths::JUDGE_CANDIDATES, &table)?;
        if let Some(s) = scene.answer_score {
            self.log(paths::JUDGE_ANSWER_SCORE, &rerun::Scalars::single(s))?;
        }
        if let Some(best) = scene.candidates.iter().filter_map(|c| c.score).min_by(f64::total_cmp) {
            self.log(paths::JUDGE_BEST_SCORE, &rerun::Scalars::single(best))?;
        }
        Ok(())
    }

    fn log_report(&self, scene: &PairScene) -> Result<(), RecordError> {
        for (stage, ms) in &scene.timings_ms {
            self.log(&paths::timing(stage), &rerun::Scalars::single(*ms))?;
        }
        for w in &scene.warnings {
            self.log(paths::WARNINGS, &rerun::TextLog::new(w.as_str()).with_level(rerun::TextLogLevel::WARN))?;
        }
        let converged = if scene.converged { "converged" } else { "not converged" };
        let text = format!("# {}\n\n{converged}\n\n```json\n{}\n```\n", scene.label, scene.summary_json);
        self.log(paths::SUMMARY, &rerun::TextDocument::new(text).with_media_type(rerun::MediaType::markdown()))
    }
}

/// A pose as Rerun's transform (`target ~ T * model`; columns of the rotation).
fn transform(pose: &Pose) -> rerun::Transform3D {
    let r = pose.rotation.to_rotation_matrix();
    let m = r.matrix();
    let columns: [[f32; 3]; 3] = std::array::from_fn(|c| std::array::from_fn(|row| m[(row, c)] as f32));
    let t = pose.translation.vector;
    rerun::Transform3D::from_translation_mat3x3([t.x as f32, t.y as f32, t.z as f32], columns)
}
