//! The registration problem, its result, and the trait every backend implements.

use crate::error::RegistrationError;
use crate::warning::RegistrationWarning;
pub use flowfilter_geometry::Correspondences;
use flowfilter_geometry::{PointCloud, Pose};
use serde::Serialize;

/// What to register: `target ~ T * source`.
#[derive(Debug, Clone)]
pub struct RegistrationProblem {
    /// The cloud to move (model frame).
    pub source: PointCloud,
    /// The cloud to align to (target frame).
    pub target: PointCloud,
    /// Initial estimate of `T`.
    pub init: Pose,
    /// Optional weighted correspondences, read by backends whose
    /// [`Registrar::uses_correspondences`] is true (Flow Filter) and ignored by the others.
    pub correspondences: Option<Correspondences>,
    /// Further candidate sets of correspondences (e.g. flow tracked from a predicted motion as
    /// well as without one). A backend that uses correspondences picks one set among
    /// `correspondences` (set 0) and these (sets 1, 2, ...) and reports its pick in
    /// [`Registration::correspondence_set`].
    pub alternative_correspondences: Vec<Correspondences>,
    /// The backend's own [`Registrar::prior`] of this problem (same clouds, same initial pose),
    /// handed back so that the backend does not compute it a second time. Only the backend
    /// that computed it may be given it.
    pub prior: Option<Registration>,
    /// How many points the source cloud stands for: the pipeline gives its count at the
    /// configured voxel, before a point budget (`cloud.max_points`) thinned it, as the points its
    /// surface holds at a 4 mm voxel. `None`: the points it holds. Rules that tell a scene from
    /// an object by its size ([`crate::FlowFilterConfig::scene_points`]) read this, so that a
    /// whole frame thinned to a budget, or to a coarser voxel, is still a scene.
    pub source_points: Option<usize>,
}

impl RegistrationProblem {
    /// A problem from identity, without correspondences.
    pub fn new(source: PointCloud, target: PointCloud) -> Self {
        Self {
            source,
            target,
            init: Pose::identity(),
            correspondences: None,
            alternative_correspondences: vec![],
            prior: None,
            source_points: None,
        }
    }

    /// The source's size as rules about it read it: [`RegistrationProblem::source_points`], or
    /// the points it holds.
    pub fn source_size(&self) -> usize {
        self.source_points.unwrap_or(self.source.len())
    }

    /// Set the initial pose.
    pub fn with_init(mut self, init: Pose) -> Self {
        self.init = init;
        self
    }

    /// Set the correspondences.
    pub fn with_correspondences(mut self, correspondences: Correspondences) -> Self {
        self.correspondences = Some(correspondences);
        self
    }

    /// The same clouds and initial pose, without correspondences or prior: what a geometric
    /// backend run inside another one sees.
    pub fn geometry_only(&self) -> Self {
        Self { source_points: self.source_points, ..Self::new(self.source.clone(), self.target.clone()) }
            .with_init(self.init)
    }

    /// The candidate sets of correspondences in order (set 0 first); empty without any.
    pub fn correspondence_sets(&self) -> Vec<&Correspondences> {
        self.correspondences.iter().chain(self.alternative_correspondences.iter()).collect()
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
    pub warnings: Vec<RegistrationWarning>,
    /// Which candidate set of correspondences the backend used (see
    /// [`RegistrationProblem::alternative_correspondences`]); `None` when it used none.
    pub correspondence_set: Option<usize>,
    /// How far the pose may be off, when the backend can tell.
    pub uncertainty: Option<Uncertainty>,
    /// Flow Filter: the flow's own result (polished and refined alike) when a geometric check
    /// overruled it ([`RegistrationWarning::MotionCheck`], [`RegistrationWarning::GeometricCheck`]):
    /// the other answer the frames support, for a caller that can weigh the two on the images.
    pub overruled_flow: Option<Box<Registration>>,
}

impl Registration {
    /// A bare result holding `transform`: no iterations, not converged, fitness 0, nothing else
    /// (for custom backends to fill in).
    pub fn with_transform(transform: Pose) -> Self {
        Self {
            transform,
            iterations: 0,
            converged: false,
            fitness: 0.0,
            inlier_rmse: 0.0,
            sigma2: None,
            scale: None,
            history: vec![],
            warnings: vec![],
            correspondence_set: None,
            uncertainty: None,
            overruled_flow: None,
        }
    }
}

/// Bounds on a pose's error, meant to hold together on 90% of estimates (Flow Filter: the 95%
/// radius, along the worst axis, of its reprojection refinement's cluster-robust covariance,
/// widened by how far the refinement moved the pose and reaching any pose a geometric check
/// overruled). How often they hold on real and synthetic frames is measured by the benchmarks
/// (`docs/bop.md`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Uncertainty {
    /// Rotation error bound, degrees.
    pub rotation_deg: f64,
    /// Translation error bound, metres.
    pub translation_m: f64,
}

impl Uncertainty {
    /// No error at all: the bounds of a pose known exactly (a stream's first frame against
    /// itself), from which bounds along a chain of estimates grow.
    pub const EXACT: Self = Self { rotation_deg: 0.0, translation_m: 0.0 };
}

/// A rigid registration backend.
///
/// Implementing it plugs a backend into everything that takes one (the pipeline, the CLI):
///
/// ```
/// use flowfilter_registration::{
///     Point3, PointCloud, Pose, Registrar, Registration, RegistrationError, RegistrationProblem, Vector3,
///     validate_problem,
/// };
///
/// /// Aligns the clouds' centroids: a translation-only backend.
/// struct Centroids;
///
/// impl Registrar for Centroids {
///     fn name(&self) -> &str {
///         "centroids"
///     }
///
///     fn register(&self, p: &RegistrationProblem) -> Result<Registration, RegistrationError> {
///         validate_problem(p, None)?;
///         let shift = p.target.centroid().unwrap() - p.source.centroid().unwrap();
///         Ok(Registration {
///             iterations: 1,
///             converged: true,
///             fitness: 1.0,
///             ..Registration::with_transform(Pose::new(shift, Vector3::zeros()))
///         })
///     }
/// }
///
/// let source: Vec<Point3> = (0..50).map(|i| Point3::new((i % 7) as f64 * 0.01, (i / 7) as f64 * 0.01, 0.5 + (i % 3) as f64 * 0.01)).collect();
/// let target: Vec<Point3> = source.iter().map(|p| p + Vector3::new(0.02, 0.0, -0.01)).collect();
/// let problem = RegistrationProblem::new(PointCloud::from_points(source), PointCloud::from_points(target));
/// let r = Centroids.register(&problem)?;
/// assert!((r.transform.translation.vector - Vector3::new(0.02, 0.0, -0.01)).norm() < 1e-12);
/// # Ok::<(), RegistrationError>(())
/// ```
pub trait Registrar: Send + Sync {
    /// The backend's name (as accepted by [`crate::registrar_by_name`]).
    fn name(&self) -> &str;

    /// Estimate `T` with `target ~ T * source`.
    ///
    /// # Errors
    /// [`RegistrationError`] when the problem cannot be registered: an empty, too small,
    /// non-finite or degenerate cloud, missing normals where the method needs them, malformed
    /// correspondences or a non-finite initial pose. Conditions that still give a pose (a
    /// fallback, an early stop) are [`Registration::warnings`] instead.
    fn register(&self, problem: &RegistrationProblem) -> Result<Registration, RegistrationError>;

    /// [`Registrar::register`], then [`crate::assess`]: a result the clouds do not support
    /// carries a warning and is not converged. What the CLI, the pipeline and the Python package
    /// call; backends call each other through `register` (their intermediate results are not
    /// final answers).
    ///
    /// # Errors
    /// As [`Registrar::register`].
    fn register_checked(&self, problem: &RegistrationProblem) -> Result<Registration, RegistrationError> {
        let mut r = self.register(problem)?;
        crate::assess(problem, &mut r);
        Ok(r)
    }

    /// Whether the backend reads [`RegistrationProblem::correspondences`]: callers skip the
    /// (costly) correspondence search for backends that do not.
    fn uses_correspondences(&self) -> bool {
        false
    }

    /// A registration of the clouds alone from the initial pose, computed before any
    /// correspondence exists, that a caller may use to predict the motion for its
    /// correspondence search and then hand back in [`RegistrationProblem::prior`]. Backends
    /// without such a step (the default) return `None`.
    ///
    /// # Errors
    /// As [`Registrar::register`].
    fn prior(&self, problem: &RegistrationProblem) -> Result<Option<Registration>, RegistrationError> {
        let _ = problem;
        Ok(None)
    }
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
    let limit = flowfilter_geometry::MAX_COORDINATE_M;
    if let Some((index, p)) = cloud.points.iter().enumerate().find(|(_, p)| p.coords.amax() > limit) {
        return Err(RegistrationError::OutOfRange { which, index, value: p.coords.amax(), limit });
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
            return Err(RegistrationError::NonFiniteNormal { which, index });
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
    for c in p.correspondence_sets() {
        c.validate()?;
    }
    if !p.init.to_homogeneous().iter().all(|v| v.is_finite()) {
        return Err(RegistrationError::Config("the initial pose is not finite".into()));
    }
    let norm = p.init.translation.vector.norm();
    if norm > flowfilter_geometry::MAX_COORDINATE_M {
        return Err(RegistrationError::Config(format!(
            "the initial pose's translation is {norm:e} m long, beyond {:e} m",
            flowfilter_geometry::MAX_COORDINATE_M
        )));
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
