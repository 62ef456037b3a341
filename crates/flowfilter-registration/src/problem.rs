//! The registration problem, its result, and the trait every backend implements.

use crate::error::RegistrationError;
use flowfilter_geometry::{Point3, PointCloud, Pose};
use serde::Serialize;

/// Weighted 3-D/3-D correspondences `source_i <-> target_i` (e.g. from optical flow).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Correspondences {
    /// Points in the source frame.
    pub source: Vec<Point3>,
    /// Corresponding points in the target frame.
    pub target: Vec<Point3>,
    /// Non-negative weights.
    pub weights: Vec<f64>,
}

impl Correspondences {
    /// Number of pairs.
    pub fn len(&self) -> usize {
        self.source.len()
    }

    /// Whether there is no pair.
    pub fn is_empty(&self) -> bool {
        self.source.is_empty()
    }

    /// Check lengths, finiteness and weights.
    pub fn validate(&self) -> Result<(), RegistrationError> {
        if self.target.len() != self.source.len() || self.weights.len() != self.source.len() {
            return Err(RegistrationError::BadCorrespondences(format!(
                "{} sources, {} targets, {} weights",
                self.source.len(),
                self.target.len(),
                self.weights.len()
            )));
        }
        for i in 0..self.len() {
            let finite = self.source[i].coords.iter().chain(self.target[i].coords.iter()).all(|v| v.is_finite());
            if !finite || !self.weights[i].is_finite() || self.weights[i] < 0.0 {
                return Err(RegistrationError::BadCorrespondences(format!(
                    "pair {i} is not finite or has a negative weight"
                )));
            }
        }
        Ok(())
    }
}

/// What to register: `target ~ T * source`.
#[derive(Debug, Clone)]
pub struct RegistrationProblem {
    /// The cloud to move (model frame).
    pub source: PointCloud,
    /// The cloud to align to (target frame).
    pub target: PointCloud,
    /// Initial estimate of `T`.
    pub init: Pose,
    /// Optional weighted correspondences (used by Flow Filter).
    pub correspondences: Option<Correspondences>,
}

impl RegistrationProblem {
    /// A problem from identity, without correspondences.
    pub fn new(source: PointCloud, target: PointCloud) -> Self {
        Self { source, target, init: Pose::identity(), correspondences: None }
    }

    /// Set the initial pose.
    pub fn with_init(mut self, init: Pose) -> Self {
        self.init = init;
        self
    }
}

/// One iteration of a backend, for convergence plots.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct IterationRecord {
    /// Iteration number (0-based).
    pub iteration: usize,
    /// Estimate after the iteration.
    #[serde(skip)]
    pub transform: Pose,
    /// Backend-specific objective value (RMSE for ICP, sigma^2 for GMM methods).
    pub objective: f64,
}

/// The result of a registration.
#[derive(Debug, Clone, PartialEq)]
pub struct Registration {
    /// The estimated `T` with `target ~ T * source`.
    pub transform: Pose,
    /// Iterations run.
    pub iterations: usize,
    /// Whether the convergence criterion was met (false: iteration limit or divergence).
    pub converged: bool,
    /// Fraction of source points with a target neighbour within the inlier distance.
    pub fitness: f64,
    /// RMSE of those inlier pairs, metres.
    pub inlier_rmse: f64,
    /// Final sigma^2 of GMM methods.
    pub sigma2: Option<f64>,
    /// Estimated scale (CPD with scale estimation), not part of `transform`.
    pub scale: Option<f64>,
    /// Per-iteration history.
    pub history: Vec<IterationRecord>,
    /// Conditions the caller should know about (e.g. a fallback taken).
    pub warnings: Vec<String>,
}

/// A rigid registration backend.
pub trait Registrar: Send + Sync {
    /// The backend's name (as accepted by [`crate::registrar_by_name`]).
    fn name(&self) -> &str;
    /// Estimate `T` with `target ~ T * source`.
    fn register(&self, problem: &RegistrationProblem) -> Result<Registration, RegistrationError>;
}

/// Validate one cloud: non-empty, at least 3 points, finite, not collinear; normals finite and
/// present when `needs_normals`.
pub fn validate_cloud(
    cloud: &PointCloud,
    which: &'static str,
    needs_normals: Option<&'static str>,
) -> Result<(), RegistrationError> {
    let n = cloud.len();
    if n == 0 {
        return Err(RegistrationError::EmptyCloud { which });
    }
    if n < 3 {
        return Err(RegistrationError::TooFewPoints { which, found: n });
    }
    if let Some(index) = cloud.points.iter().position(|p| !p.coords.iter().all(|c| c.is_finite())) {
        return Err(RegistrationError::NonFinite { which, index });
    }
    // Degenerate: the spread's second principal axis vanishes.
    let c = cloud.centroid().expect("non-empty");
    let cov = cloud.points.iter().fold(nalgebra::Matrix3::zeros(), |a, p| {
        let d = p - c;
        a + d * d.transpose()
    }) / n as f64;
    let mut ev: Vec<f64> = cov.symmetric_eigenvalues().iter().copied().collect();
    ev.sort_by(|a, b| b.total_cmp(a));
    if ev[0] <= 1e-18 || ev[1] <= 1e-10 * ev[0] {
        return Err(RegistrationError::Degenerate { which });
    }
    if let Some(method) = needs_normals {
        let normals = cloud.normals.as_ref().ok_or(RegistrationError::MissingNormals { method, which })?;
        if normals.len() != n {
            return Err(RegistrationError::MissingNormals { method, which });
        }
        if let Some(index) = normals.iter().position(|v| !v.iter().all(|c| c.is_finite())) {
            return Err(RegistrationError::NonFinite { which, index });
        }
    }
    Ok(())
}

/// Validate a whole problem.
pub fn validate_problem(
    p: &RegistrationProblem,
    target_normals: Option<&'static str>,
) -> Result<(), RegistrationError> {
    validate_cloud(&p.source, "source", None)?;
    validate_cloud(&p.target, "target", target_normals)?;
    if let Some(c) = &p.correspondences {
        c.validate()?;
    }
    if !p.init.to_homogeneous().iter().all(|v| v.is_finite()) {
        return Err(RegistrationError::Config("the initial pose is not finite".into()));
    }
    Ok(())
}

/// Runs `f` on a thread of the rayon pool (inline when already on one). The backends' many short
/// parallel loops are then forked from inside the pool; started from outside it, each loop would
/// be injected into the pool with the caller put to sleep until it finishes, which costs more
/// than the loop itself on small clouds.
pub(crate) fn in_pool<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    rayon::scope(|_| f())
}
