//! The registration inputs of `bench-speed`: Kinect-sized pairs of a wavy surface seen from
//! the front (a sensor's single view), the target moved by a known motion, resampled and noisy,
//! and real pairs (two frames of a posed RGB-D sequence as the depth stage turns them into
//! clouds), written as PLY (the target with normals) for ours and the peers alike.

use anyhow::Context;
use flowfilter_pipeline::depth::cloud::knn_normals;
use flowfilter_pipeline::depth::ply::{PlyFormat, write_ply};
use flowfilter_pipeline::{Point3, PointCloud, Pose};
use nalgebra::{Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::path::{Path, PathBuf};

/// Neighbours of the target's normals (Open3D's `KDTreeSearchParamKNN(12)` in the peers'
/// fixtures).
const NORMAL_NEIGHBOURS: usize = 12;

/// One registration pair on disk with its true motion.
#[derive(Debug, Clone)]
pub struct CloudPair {
    /// `wavy-<source points>`.
    pub name: String,
    /// Source cloud (PLY, points).
    pub source: PathBuf,
    /// Target cloud (PLY, points and normals).
    pub target: PathBuf,
    /// The source-to-target motion.
    pub truth: Pose,
    /// Whether `truth` is exact (a synthetic pair) or a calibration's (a real pair: ours and the
    /// peer are then compared with each other, not held to it).
    pub exact_truth: bool,
}

/// A point of the wavy surface at `(u, v)` (metres; the surface spans 1.2 x 0.9 m, 1.5 m from
/// the camera, with 3-5 cm undulations).
fn surface(u: f64, v: f64) -> Point3 {
    let z = 1.5 + 0.05 * (6.0 * u).sin() * (5.0 * v).cos() + 0.03 * (11.0 * v).sin();
    Point3::new(u, v, z)
}

/// The motion of every pair: 4 deg about x, 2 deg about y about the surface's centre, and a
/// shift of a few centimetres (4.5 deg and 3.8 cm in all).
fn motion(centre: &Point3) -> Pose {
    let rotation = UnitQuaternion::from_euler_angles(4f64.to_radians(), 2f64.to_radians(), 0.0);
    let shift = Vector3::new(0.02, -0.01, 0.015);
    let t = centre.coords + shift - rotation * centre.coords;
    Pose::from_parts(Translation3::from(t), rotation)
}

/// `n` source points and `n * 11 / 12` target points (independent samples of the surface,
/// 2 mm noise), seeded.
fn make_pair(n: usize, seed: u64) -> (PointCloud, PointCloud, Pose) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, 0.002).expect("positive sd");
    let mut sample = |count: usize| -> Vec<Point3> {
        (0..count).map(|_| surface(rng.random_range(-0.6..0.6), rng.random_range(-0.45..0.45))).collect()
    };
    let (source, target) = (sample(n), sample(n * 11 / 12));
    let centre = Point3::from(source.iter().map(|p| p.coords).sum::<Vector3<f64>>() / source.len() as f64);
    let truth = motion(&centre);
    let mut jitter = |p: Point3| p + Vector3::from_fn(|_, _| noise.sample(&mut rng));
    let source: Vec<Point3> = source.into_iter().map(&mut jitter).collect();
    let target: Vec<Point3> = target.into_iter().map(|p| jitter(truth * p)).collect();
    let normals = knn_normals(&target, NORMAL_NEIGHBOURS, &Point3::origin());
    let target = PointCloud { normals: Some(normals), ..PointCloud::from_points(target) };
    (PointCloud::from_points(source), target, truth)
}

/// Write one pair of `n` source points into `dir` (binary PLY; the same files for the same `n`
/// and seed).
///
/// # Errors
/// A file that cannot be written.
pub fn write_pair(dir: &Path, n: usize, seed: u64) -> anyhow::Result<CloudPair> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let name = format!("wavy-{n}");
    let (source_path, target_path) = (dir.join(format!("{name}_source.ply")), dir.join(format!("{name}_target.ply")));
    let (source, target, truth) = make_pair(n, seed);
    for (cloud, path) in [(&source, &source_path), (&target, &target_path)] {
        write_ply(cloud, path, PlyFormat::BinaryLittleEndian).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(CloudPair { name, source: source_path, target: target_path, truth, exact_truth: true })
}

/// The voxel real clouds are thinned to (metres): a whole 640x480 RealSense frame of the shared
/// sequences becomes 13-17k points.
pub const REAL_VOXEL_M: f64 = 0.004;

/// Write the real pair of the first two frames of the posed sequence in `sequence` (as
/// `bench-real` reads it) into `dir`: each frame's whole-frame cloud from the depth stage
/// (default configuration; normals from the organised grid), thinned to [`REAL_VOXEL_M`], the
/// source moved by the calibrated motion so that the registration starts where a tracker's
/// prediction would (the calibration's own error, 0.5-1 deg, is what is left to find). The
/// pair's truth is then the identity, up to that error.
///
/// # Errors
/// A folder that is not a posed sequence of two frames or more; frames that cannot be read or
/// prepared; a file that cannot be written.
pub fn write_real_pair(dir: &Path, sequence: &Path) -> anyhow::Result<CloudPair> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let posed = crate::realsense::PosedFrames::open_with_truth(sequence, &crate::realsense::Truth::Calibrated)
        .map_err(anyhow::Error::msg)?;
    let frames = match posed.ids()[..] {
        [a, b, ..] => (a, b),
        _ => anyhow::bail!("{}: two posed frames expected, found one", sequence.display()),
    };
    let stage = flowfilter_pipeline::depth::DepthStage::new(flowfilter_pipeline::DepthConfig::default())?;
    let cloud = |im: u32| -> anyhow::Result<PointCloud> {
        let frame = posed.frame(im).map_err(anyhow::Error::msg)?;
        let p = stage
            .process(&frame.depth, &frame.color, &frame.mask, &frame.sensor)
            .with_context(|| format!("{}: frame {im}", sequence.display()))?;
        let mut thinned = flowfilter_pipeline::depth::cloud::voxel_downsample(&p.cloud, REAL_VOXEL_M);
        thinned.colors = None;
        Ok(thinned)
    };
    let motion = posed.calibrated_motion(frames.0, frames.1).map_err(anyhow::Error::msg)?;
    let mut source = cloud(frames.0)?;
    source.points.iter_mut().for_each(|p| *p = motion * *p);
    if let Some(normals) = source.normals.as_mut() {
        normals.iter_mut().for_each(|n| *n = motion.rotation * *n);
    }
    let target = cloud(frames.1)?;
    let sequence_name = sequence.file_name().map_or_else(|| "real".into(), |n| n.to_string_lossy().into_owned());
    let name = format!("real-{sequence_name}-{}-{}", frames.0, frames.1);
    let (source_path, target_path) = (dir.join(format!("{name}_source.ply")), dir.join(format!("{name}_target.ply")));
    for (cloud, path) in [(&source, &source_path), (&target, &target_path)] {
        write_ply(cloud, path, PlyFormat::BinaryLittleEndian).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(CloudPair { name, source: source_path, target: target_path, truth: Pose::identity(), exact_truth: false })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pairs_are_seeded_and_carry_the_stated_motion() {
        let (s1, t1, truth) = make_pair(2000, 3);
        let (s2, t2, _) = make_pair(2000, 3);
        assert_eq!(s1.points, s2.points);
        assert_eq!(t1.points, t2.points);
        assert_eq!((s1.len(), t1.len()), (2000, 1833));
        let deg = truth.rotation.angle().to_degrees();
        assert!((deg - 4.47).abs() < 0.01, "{deg}");
        // Every target point lies within noise of the moved surface: its pre-image is on it.
        for p in t1.points.iter().take(200) {
            let q = truth.inverse() * p;
            assert!((surface(q.x, q.y).z - q.z).abs() < 0.015, "{q:?}");
        }
        // Normals face the camera at the origin.
        let n = t1.normals.as_ref().unwrap();
        assert!(n.iter().zip(&t1.points).all(|(n, p)| n.dot(&p.coords) < 0.0));
    }
}
