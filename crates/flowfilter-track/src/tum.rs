//! Trajectories in the TUM RGB-D format (`timestamp tx ty tz qx qy qz qw`, one pose per line,
//! `#` comments), which `evo` and the TUM tools read; and the true motion of a tracked object
//! from a TUM file or from a sequence's calibrated camera poses (`poses.json`).

use flowfilter_geometry::Pose;
use nalgebra::{Matrix4, Quaternion, Translation3, UnitQuaternion};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// A TUM line of `pose` at `timestamp` (seconds).
///
/// ```
/// use flowfilter_geometry::Pose;
/// assert_eq!(flowfilter_track::tum::line(1.5, &Pose::translation(0.1, 0.0, 0.0)), "1.500000 0.100000000 0.000000000 0.000000000 0.000000000 0.000000000 0.000000000 1.000000000");
/// ```
pub fn line(timestamp: f64, pose: &Pose) -> String {
    let t = pose.translation.vector;
    let q = pose.rotation.quaternion();
    format!("{timestamp:.6} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9}", t.x, t.y, t.z, q.i, q.j, q.k, q.w)
}

/// Why a ground-truth file cannot be used.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {message}")]
pub struct TruthError {
    /// The file.
    pub path: PathBuf,
    /// What is wrong, naming the line or key.
    pub message: String,
}

/// The camera-to-world poses of a `poses.json` (`camera_to_world_calibrated`: frame number ->
/// 4x4 row-major, metres), as the shared RealSense sequences ship them.
///
/// # Errors
/// [`TruthError`] naming the key that cannot be read.
pub fn read_calibrated_poses(path: &Path) -> Result<BTreeMap<u64, Pose>, TruthError> {
    read_camera_poses(path, CALIBRATED)
}

/// The key of a `poses.json`'s calibrated camera poses.
pub const CALIBRATED: &str = "camera_to_world_calibrated";
/// The key of a `poses.json`'s camera poses by the arm's kinematics alone.
pub const ARM: &str = "camera_to_world_robot";

/// The camera-to-world poses under `key` of a `poses.json` (frame number -> 4x4 row-major,
/// metres): [`CALIBRATED`] or [`ARM`] in the shared RealSense sequences.
///
/// # Errors
/// [`TruthError`] naming the key that cannot be read.
pub fn read_camera_poses(path: &Path, key: &str) -> Result<BTreeMap<u64, Pose>, TruthError> {
    let err = |message: String| TruthError { path: path.to_path_buf(), message };
    let text = std::fs::read_to_string(path).map_err(|e| err(format!("cannot read: {e}")))?;
    let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| err(format!("not JSON: {e}")))?;
    let table = v[key].as_object().ok_or_else(|| err(format!("expected a `{key}` object (frame number -> 4x4)")))?;
    let mut cameras = BTreeMap::new();
    for (frame, m) in table {
        let bad = |what: String| err(format!("{key}.{frame}: {what}"));
        let n: u64 = frame.parse().map_err(|_| bad("the key must be a frame number".into()))?;
        let values: Option<Vec<f64>> = (0..16).map(|k| m[k / 4][k % 4].as_f64()).collect();
        let values = values.ok_or_else(|| bad("expected 4 rows of 4 numbers".into()))?;
        let pose = flowfilter_geometry::rigid_from_matrix(&Matrix4::from_row_slice(&values))
            .map_err(|e| bad(e.to_string()))?;
        cameras.insert(n, pose);
    }
    Ok(cameras)
}

/// The true motion of the tracked object from the first frame, by frame number.
///
/// - A TUM file: each line's timestamp is the frame number (or the frames' times: the lines are
///   matched to frames in order when their count equals the frames'), its pose the motion
///   `T_0k`.
/// - A `poses.json` with `camera_to_world_calibrated` (frame number -> 4x4): a static scene seen
///   by a moving camera; the motion of the scene in the camera is `inv(C_k) * C_0`.
///
/// # Errors
/// [`TruthError`] naming the line or key that cannot be read.
pub fn read_truth(path: &Path, numbers: &[u64]) -> Result<BTreeMap<u64, Pose>, TruthError> {
    let err = |message: String| TruthError { path: path.to_path_buf(), message };
    let text = std::fs::read_to_string(path).map_err(|e| err(format!("cannot read: {e}")))?;
    let first = *numbers.first().ok_or_else(|| err("no frames to match".into()))?;
    if path.extension().is_some_and(|e| e == "json") {
        let cameras = read_calibrated_poses(path)?;
        let c0 = *cameras.get(&first).ok_or_else(|| err(format!("no pose of the first frame ({first})")))?;
        return Ok(cameras.into_iter().map(|(n, c)| (n, c.inverse() * c0)).collect());
    }
    let mut rows: Vec<(f64, Pose)> = vec![];
    for (i, l) in text.lines().enumerate() {
        let l = l.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let v: Result<Vec<f64>, _> = l.split_whitespace().map(str::parse).collect();
        let v = v
            .ok()
            .filter(|v| v.len() == 8)
            .ok_or_else(|| err(format!("line {}: expected `timestamp tx ty tz qx qy qz qw`, found `{l}`", i + 1)))?;
        let q = Quaternion::new(v[7], v[4], v[5], v[6]);
        if (q.norm() - 1.0).abs() >= 1e-3 {
            return Err(err(format!("line {}: the quaternion's norm is {}, expected 1", i + 1, q.norm())));
        }
        rows.push((v[0], Pose::from_parts(Translation3::new(v[1], v[2], v[3]), UnitQuaternion::from_quaternion(q))));
    }
    if rows.len() == numbers.len() {
        return Ok(numbers.iter().copied().zip(rows.into_iter().map(|(_, p)| p)).collect());
    }
    let by_number: BTreeMap<u64, Pose> =
        rows.into_iter().filter(|(t, _)| t.fract() == 0.0 && *t >= 0.0).map(|(t, p)| (t as u64, p)).collect();
    if numbers.iter().all(|n| !by_number.contains_key(n)) {
        return Err(err(format!(
            "{} poses for {} frames, and no timestamp is a frame number",
            by_number.len(),
            numbers.len()
        )));
    }
    Ok(by_number)
}
