//! Validation of a whole object directory, collecting every problem.

use crate::calibration::Calibration;
use crate::capture_status::{CaptureStatus, capture_status_path};
use crate::error::BigBirdError;
use crate::layout::{FrameId, SensorId, calibration_path, table_pose_path, turntable_path};
use crate::object::{TablePose, Turntable, discover_frames, load_frame_files};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// What an inspected directory holds (whatever could be read).
#[derive(Debug, Clone, Default)]
pub struct ObjectSummary {
    /// The directory.
    pub dir: PathBuf,
    /// Frames found by name.
    pub frames: BTreeSet<FrameId>,
    /// Frames whose three files loaded and agree.
    pub valid_frames: usize,
    /// Calibration, if it could be read.
    pub calibration: Option<Calibration>,
    /// Turntable, if it could be read.
    pub turntable: Option<Turntable>,
    /// Table poses that could be read.
    pub table_poses: BTreeMap<u32, TablePose>,
    /// Colour image sizes seen per sensor `(width, height)`.
    pub color_sizes: BTreeMap<SensorId, BTreeSet<(u32, u32)>>,
    /// Depth image sizes seen per sensor `(width, height)`.
    pub depth_sizes: BTreeMap<SensorId, BTreeSet<(u32, u32)>>,
}

impl ObjectSummary {
    /// Sensors with frames.
    pub fn sensors(&self) -> BTreeSet<SensorId> {
        self.frames.iter().map(|f| f.sensor).collect()
    }

    /// Angles with frames.
    pub fn angles(&self) -> BTreeSet<u32> {
        self.frames.iter().map(|f| f.angle).collect()
    }
}

/// The outcome of [`inspect`]: a summary and every problem found.
#[derive(Debug, Default)]
pub struct InspectReport {
    /// What was found.
    pub summary: ObjectSummary,
    /// Every problem, in the order found.
    pub problems: Vec<BigBirdError>,
}

impl InspectReport {
    /// Whether no problem was found.
    pub fn is_ok(&self) -> bool {
        self.problems.is_empty()
    }
}

/// Read and validate every file of an object directory, collecting all problems instead of
/// stopping at the first: calibration, turntable, the pose of each angle, and each frame's
/// colour image, depth and mask (sizes must agree within a sensor).
pub fn inspect(dir: impl AsRef<Path>) -> InspectReport {
    let dir = dir.as_ref();
    let mut report =
        InspectReport { summary: ObjectSummary { dir: dir.into(), ..Default::default() }, problems: vec![] };
    if dir.is_file() {
        report.problems.push(BigBirdError::NotADirectory { path: dir.into() });
        return report;
    }
    if !dir.is_dir() {
        report.problems.push(BigBirdError::NotFound { path: dir.into() });
        return report;
    }
    let s = &mut report.summary;
    let p = &mut report.problems;
    let status = CaptureStatus::read(dir).unwrap_or_else(|e| {
        p.push(e);
        None
    });
    match discover_frames(dir) {
        Ok(frames) if frames.is_empty() => p.push(BigBirdError::NoFrames { dir: dir.into() }),
        Ok(frames) => s.frames = frames,
        Err(e) => p.push(e),
    }
    match Calibration::read(&calibration_path(dir)) {
        Ok(c) => s.calibration = Some(c),
        Err(e) => p.push(e),
    }
    match Turntable::read(&turntable_path(dir)) {
        Ok(t) => s.turntable = Some(t),
        Err(e) => p.push(e),
    }
    for angle in s.angles() {
        match TablePose::read(&table_pose_path(dir, angle)) {
            Ok(pose) => {
                s.table_poses.insert(angle, pose);
            }
            Err(e) => p.push(e),
        }
    }
    if let Some(cal) = &s.calibration {
        for sensor in s.sensors() {
            if !cal.sensors.contains_key(&sensor) {
                p.push(BigBirdError::MissingDataset {
                    path: calibration_path(dir),
                    key: format!("{sensor}_rgb_K (the directory has {sensor} frames)"),
                });
            }
        }
    }
    for id in s.frames.clone() {
        match load_frame_files(dir, id) {
            Ok(frame) if !frame.mask.as_slice().iter().any(|&m| m) => p.push(BigBirdError::Invalid {
                path: id.mask_path(dir),
                message: "the mask is empty: no object pixel".into(),
            }),
            Ok(frame) => {
                s.valid_frames += 1;
                s.color_sizes.entry(id.sensor).or_default().insert((frame.color.width(), frame.color.height()));
                s.depth_sizes
                    .entry(id.sensor)
                    .or_default()
                    .insert((frame.depth.width() as u32, frame.depth.height() as u32));
            }
            Err(e) => p.push(e),
        }
    }
    match status {
        Some(CaptureStatus { complete: false, frames }) => p.push(BigBirdError::Invalid {
            path: capture_status_path(dir),
            message: format!(
                "the capture is incomplete: its writer stopped before the end ({} of {frames} frames present); \
                 write it again",
                s.frames.len()
            ),
        }),
        Some(CaptureStatus { complete: true, frames }) if frames != s.frames.len() => p.push(BigBirdError::Invalid {
            path: capture_status_path(dir),
            message: format!("the capture was written with {frames} frames, {} are present", s.frames.len()),
        }),
        _ => {}
    }
    for (what, sizes) in [("colour", &s.color_sizes), ("depth", &s.depth_sizes)] {
        for (sensor, set) in sizes {
            if set.len() > 1 {
                p.push(BigBirdError::Invalid {
                    path: dir.into(),
                    message: format!("{sensor} {what} images differ in size across angles: {set:?}"),
                });
            }
        }
    }
    report
}
