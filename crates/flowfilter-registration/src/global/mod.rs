//! Global registration by feature matching, as Open3D's
//! `registration_ransac_based_on_correspondence` with FPFH features: no initial pose is needed,
//! so it reaches motions of any size, to the precision of the clouds' spacing. Its answer is a
//! start for a local registration, not an answer of its own.
//!
//! 1. [`fpfh_features`] of both clouds (which must hold normals);
//! 2. matches: each source point's nearest target point in descriptor space, kept when that
//!    target point's nearest source point is the same (mutual);
//! 3. a seeded RANSAC over three matches: a sample is tried when the three points' distances
//!    agree in both clouds (within `edge_ratio`), its Kabsch motion kept when it brings the three
//!    within `max_distance_m`; the motion that most matches agree with wins, and is refined on
//!    them. The RANSAC stops once `confidence` says a better sample is unlikely (as Open3D's).

mod fpfh;
mod matching;

pub use fpfh::{FPFH_LEN, Fpfh, fpfh_features};
pub use matching::mutual_matches;

use flowfilter_geometry::{ParamError, Point3, PointCloud, Pose, params, weighted_kabsch};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Parameters of [`register_by_features`] (Open3D's global registration tutorial's, for clouds
/// thinned to a voxel `v`: features over `5 v`, matches within `1.5 v`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GlobalConfig {
    /// Radius of a point's neighbourhood for its descriptor (metres).
    pub feature_radius_m: f64,
    /// At most this many of the nearest neighbours within the radius.
    pub max_neighbours: usize,
    /// A match agrees with a motion when it brings the two points within this (metres).
    pub max_distance_m: f64,
    /// A sample of three matches is tried only when each distance between its points in one
    /// cloud is at least this fraction of the same distance in the other (Open3D's edge-length
    /// check).
    pub edge_ratio: f64,
    /// RANSAC samples at most.
    pub max_iterations: usize,
    /// Stop once a sample of three agreeing matches would have been drawn with this probability.
    pub confidence: f64,
    /// Fewer agreeing matches give no answer.
    pub min_inliers: usize,
    /// Seed of the samples.
    pub seed: u64,
}

impl Default for GlobalConfig {
    fn default() -> Self {
        Self {
            feature_radius_m: 0.05,
            max_neighbours: 100,
            max_distance_m: 0.015,
            edge_ratio: 0.9,
            max_iterations: 20_000,
            confidence: 0.999,
            min_inliers: 12,
            seed: 0,
        }
    }
}

impl GlobalConfig {
    /// Ranges serde cannot check.
    ///
    /// # Errors
    /// [`ParamError`] naming the key.
    pub fn validate(&self) -> Result<(), ParamError> {
        params::positive("feature_radius_m", self.feature_radius_m)?;
        params::count_positive("max_neighbours", self.max_neighbours)?;
        params::positive("max_distance_m", self.max_distance_m)?;
        params::require(self.edge_ratio > 0.0 && self.edge_ratio < 1.0, "edge_ratio", "in (0, 1)", self.edge_ratio)?;
        params::count_positive("max_iterations", self.max_iterations)?;
        params::require(self.confidence > 0.0 && self.confidence < 1.0, "confidence", "in (0, 1)", self.confidence)?;
        params::require(self.min_inliers >= 3, "min_inliers", "at least 3", self.min_inliers)?;
        Ok(())
    }
}

/// What [`register_by_features`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct GlobalMatch {
    /// The motion `T` with `target ~ T * source`.
    pub pose: Pose,
    /// Matches that agree with it.
    pub inliers: usize,
    /// Matches the RANSAC drew from.
    pub matches: usize,
    /// Samples drawn.
    pub iterations: usize,
}

/// The motion of `source` onto `target` from their FPFH matches (module documentation); `None`
/// when a cloud has no normals, or no motion gathers `cfg.min_inliers` matches.
///
/// # Examples
///
/// ```
/// use flowfilter_registration::global::{GlobalConfig, register_by_features};
/// use flowfilter_registration::{Point3, PointCloud, Pose, Vector3};
///
/// // A bumpy sheet and the same sheet turned by 40 degrees: far beyond a local method's reach.
/// let sheet = |i: usize| {
///     let (x, y) = ((i % 40) as f64 * 0.005, (i / 40) as f64 * 0.005);
///     let z = 0.6 + 0.01 * (x * 40.0).sin() * (y * 30.0).cos();
///     let n = Vector3::new(-0.4 * (x * 40.0).cos() * (y * 30.0).cos(), 0.3 * (x * 40.0).sin() * (y * 30.0).sin(), 1.0);
///     (Point3::new(x, y, z), n.normalize())
/// };
/// let (points, normals): (Vec<Point3>, Vec<Vector3>) = (0..1600).map(sheet).unzip();
/// let source = PointCloud { points, normals: Some(normals), ..Default::default() };
/// let truth = Pose::new(Vector3::new(0.05, 0.02, -0.03), Vector3::new(0.0, 40f64.to_radians(), 0.0));
/// let target = PointCloud {
///     points: source.points.iter().map(|p| truth * p).collect(),
///     normals: source.normals.as_ref().map(|ns| ns.iter().map(|n| truth.rotation * n).collect()),
///     ..Default::default()
/// };
/// let cfg = GlobalConfig { feature_radius_m: 0.025, max_distance_m: 0.0075, ..GlobalConfig::default() };
/// let found = register_by_features(&source, &target, &cfg).expect("matched");
/// assert!((found.pose.inverse() * truth).rotation.angle().to_degrees() < 1.0);
/// ```
pub fn register_by_features(source: &PointCloud, target: &PointCloud, cfg: &GlobalConfig) -> Option<GlobalMatch> {
    let (fs, ft) = rayon::join(
        || fpfh_features(source, cfg.feature_radius_m, cfg.max_neighbours),
        || fpfh_features(target, cfg.feature_radius_m, cfg.max_neighbours),
    );
    let matches = mutual_matches(&fs?, &ft?);
    let pairs: Vec<(Point3, Point3)> = matches.iter().map(|&(i, j)| (source.points[i], target.points[j])).collect();
    ransac(&pairs, cfg)
}

/// The RANSAC of [`register_by_features`] over point pairs.
fn ransac(pairs: &[(Point3, Point3)], cfg: &GlobalConfig) -> Option<GlobalMatch> {
    if pairs.len() < cfg.min_inliers.max(3) {
        return None;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let agreeing = |pose: &Pose| pairs.iter().filter(|(p, q)| (pose * p - q).norm() < cfg.max_distance_m).count();
    let (mut best, mut best_count, mut needed, mut iterations) = (None, 0usize, cfg.max_iterations, 0);
    while iterations < needed.min(cfg.max_iterations) {
        iterations += 1;
        let sample = [0; 3].map(|_| pairs[rng.random_range(0..pairs.len())]);
        let Some(pose) = sample_motion(&sample, cfg) else { continue };
        let count = agreeing(&pose);
        if count > best_count {
            (best, best_count) = (Some(pose), count);
            needed = iterations_needed(count as f64 / pairs.len() as f64, cfg.confidence);
        }
    }
    let mut pose = best.filter(|_| best_count >= cfg.min_inliers)?;
    // Refined on the agreeing pairs, which are gathered again, twice.
    for _ in 0..2 {
        let (s, t): (Vec<Point3>, Vec<Point3>) =
            pairs.iter().filter(|(p, q)| (pose * p - q).norm() < cfg.max_distance_m).copied().unzip();
        pose = weighted_kabsch(&s, &t, None).ok()?;
    }
    Some(GlobalMatch { pose, inliers: agreeing(&pose), matches: pairs.len(), iterations })
}

/// The Kabsch motion of a sample of three pairs, when their edges agree and it brings each
/// within the distance.
fn sample_motion(sample: &[(Point3, Point3); 3], cfg: &GlobalConfig) -> Option<Pose> {
    for (a, b) in [(0, 1), (1, 2), (0, 2)] {
        let (ls, lt) = ((sample[a].0 - sample[b].0).norm(), (sample[a].1 - sample[b].1).norm());
        if ls < cfg.edge_ratio * lt || lt < cfg.edge_ratio * ls {
            return None;
        }
    }
    let (s, t): (Vec<Point3>, Vec<Point3>) = sample.iter().copied().unzip();
    let pose = weighted_kabsch(&s, &t, None).ok()?;
    sample.iter().all(|(p, q)| (pose * p - q).norm() < cfg.max_distance_m).then_some(pose)
}

/// Samples after which one of three agreeing pairs has been drawn with probability
/// `confidence`, when a share `fraction` of the pairs agree.
fn iterations_needed(fraction: f64, confidence: f64) -> usize {
    let all_three = fraction.powi(3);
    if all_three >= 1.0 {
        return 1;
    }
    if all_three <= 0.0 {
        return usize::MAX;
    }
    let n = (1.0 - confidence).ln() / (1.0 - all_three).ln();
    if n.is_finite() { n.ceil() as usize } else { usize::MAX }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    /// Pairs on one motion, and wrong pairs between random points of the same region.
    fn pairs(right: usize, wrong: usize, truth: &Pose) -> Vec<(Point3, Point3)> {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut point =
            || Point3::new(rng.random_range(-0.2..0.2), rng.random_range(-0.15..0.15), rng.random_range(0.5..0.7));
        let mut v: Vec<(Point3, Point3)> = (0..right).map(|_| point()).map(|p| (p, truth * p)).collect();
        v.extend((0..wrong).map(|_| (point(), point())));
        // Interleaved, so that the order says nothing.
        v.sort_by(|a, b| a.0.x.total_cmp(&b.0.x));
        v
    }

    #[test]
    fn the_ransac_finds_a_motion_that_one_match_in_ten_supports() {
        let truth = Pose::new(Vector3::new(0.1, -0.05, 0.02), Vector3::new(0.2, 0.5, -0.1));
        let found = ransac(&pairs(60, 540, &truth), &GlobalConfig::default()).expect("found");
        assert!((found.pose.inverse() * truth).rotation.angle().to_degrees() < 0.01);
        assert_eq!(found.inliers, 60);
        assert!(found.iterations < 20_000, "stopped early: {}", found.iterations);
    }

    #[test]
    fn the_ransac_gives_nothing_without_agreement() {
        let truth = Pose::identity();
        assert!(ransac(&pairs(5, 300, &truth), &GlobalConfig::default()).is_none());
        assert!(ransac(&pairs(2, 0, &truth), &GlobalConfig::default()).is_none());
    }

    #[test]
    fn the_same_seed_gives_the_same_answer() {
        let truth = Pose::new(Vector3::new(0.0, 0.03, 0.0), Vector3::new(0.0, 0.3, 0.0));
        let p = pairs(40, 400, &truth);
        let cfg = GlobalConfig { seed: 3, ..GlobalConfig::default() };
        assert_eq!(ransac(&p, &cfg), ransac(&p, &cfg));
    }

    #[test]
    fn the_samples_needed_fall_as_more_pairs_agree() {
        assert!(iterations_needed(0.1, 0.999) > iterations_needed(0.3, 0.999));
        assert_eq!(iterations_needed(1.0, 0.999), 1);
        assert_eq!(iterations_needed(0.0, 0.999), usize::MAX);
        // Open3D's rule: log(1 - p) / log(1 - w^3).
        assert_eq!(iterations_needed(0.1, 0.999), 6905);
    }

    #[test]
    fn bad_parameters_are_named() {
        let e = GlobalConfig { edge_ratio: 1.5, ..GlobalConfig::default() }.validate().unwrap_err();
        assert!(e.to_string().contains("edge_ratio"), "{e}");
        let e = GlobalConfig { min_inliers: 2, ..GlobalConfig::default() }.validate().unwrap_err();
        assert!(e.to_string().contains("min_inliers"), "{e}");
    }
}
