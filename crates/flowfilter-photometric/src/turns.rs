//! Candidate poses for motions the flow could not follow.
//!
//! Flow and geometry both fail towards "no motion" on a turned object whose silhouette and
//! shading stay put (a can, a bottle, a mug seen from its plain side): the geometry maps onto
//! itself, and the flow tracks the shading. [`TurnHypotheses`] offers the poses such an object
//! may really have: the answer preceded by a turn about one of the model cloud's normal-scatter axes
//! (through the point the surface revolves about, when it is one of revolution), kept only
//! when the turned model still fits the target cloud about as well as the answer. Which of them
//! is right is for the colour images to say ([`crate::judge`]).

use flowfilter_geometry::{KnnIndex, ParamError, Point3, Pose, Vector3, params};
use flowfilter_registration::{RegistrationProblem, visible_residual};
use nalgebra::{Matrix2, Matrix3, Translation3, UnitQuaternion, Vector2};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The sweep's parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TurnSweepConfig {
    /// The coarse sweep's turns about each axis (degrees; each taken both ways).
    pub sweep_deg: Vec<f64>,
    /// A turned model fits well enough when its visible-point residual is at most the answer's
    /// times `1 + fit_tolerance` plus `fit_slack_m`. A correct turn of a partial view fits worse
    /// than the answer it replaces (its points that turned towards the silhouette find no
    /// partner in the target, whose depth there is filtered away): measured up to 1.95x for a
    /// can turned 30 degrees, against 2.8x and more for a box turned 6 degrees.
    pub fit_tolerance: f64,
    /// See `fit_tolerance` (metres).
    pub fit_slack_m: f64,
    /// Truncation of the residual (metres).
    pub tau_m: f64,
}

impl Default for TurnSweepConfig {
    fn default() -> Self {
        Self {
            sweep_deg: vec![6.0, 12.0, 18.0, 24.0, 30.0, 36.0],
            fit_tolerance: 1.0,
            fit_slack_m: 0.0005,
            tau_m: 0.01,
        }
    }
}

impl TurnSweepConfig {
    /// Ranges serde cannot check.
    ///
    /// # Errors
    /// [`ParamError`] naming the key.
    pub fn validate(&self) -> Result<(), ParamError> {
        for d in &self.sweep_deg {
            params::positive("sweep_deg", *d)?;
        }
        params::non_negative("fit_tolerance", self.fit_tolerance)?;
        params::non_negative("fit_slack_m", self.fit_slack_m)?;
        params::positive("tau_m", self.tau_m)
    }
}

/// At most this many model points measure a candidate's fit (every k-th of the cloud): the
/// fit is a mean, which a few thousand evenly spread points give to a few per cent.
const FIT_POINTS: usize = 1500;

/// The turn that tests an axis (degrees): large enough that a wrong axis shows in the fit.
const AXIS_TEST_DEG: f64 = 20.0;

/// One axis the candidates turn about (model coordinates).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TurnAxis {
    /// A point on the axis.
    pub pivot: Point3,
    /// Its unit direction.
    pub direction: Vector3,
}

/// A candidate pose: the answer preceded by `deg` degrees about axis `axis`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TurnCandidate {
    /// Index into [`TurnHypotheses::axes`].
    pub axis: usize,
    /// The turn, degrees.
    pub deg: f64,
    /// The pose.
    pub pose: Pose,
}

/// The turned candidates of one answer (see the module documentation).
pub struct TurnHypotheses {
    /// The model points the fit is measured on (evenly thinned to at most [`FIT_POINTS`]) and
    /// their normals.
    fit_points: Vec<Point3>,
    fit_normals: Vec<Vector3>,
    index: KnnIndex,
    answer: Pose,
    fit_limit: f64,
    tau: f64,
    /// The model's normal-scatter axes, each through its pivot.
    pub axes: [TurnAxis; 3],
}

impl TurnHypotheses {
    /// The hypotheses around `answer`; `None` without normals on the model cloud (the
    /// visibility test and the pivot need them) or with fewer than 10 model points.
    pub fn new(problem: &RegistrationProblem, answer: Pose, cfg: &TurnSweepConfig) -> Option<Self> {
        let normals = problem.source.normals.as_deref()?;
        if problem.source.points.len() < 10 || problem.target.points.is_empty() {
            return None;
        }
        let (centroid, directions) = normal_scatter_axes(&problem.source.points, normals);
        let axes = directions.map(|direction| revolution_axis(&problem.source.points, normals, direction, centroid));
        let every = problem.source.points.len().div_ceil(FIT_POINTS);
        let mut h = Self {
            fit_points: problem.source.points.iter().step_by(every).copied().collect(),
            fit_normals: normals.iter().step_by(every).copied().collect(),
            index: KnnIndex::new(&problem.target.points),
            answer,
            fit_limit: 0.0,
            tau: cfg.tau_m,
            axes,
        };
        h.fit_limit = h.fit(&answer) * (1.0 + cfg.fit_tolerance) + cfg.fit_slack_m;
        // The refinement can wander where little of the side is seen (a flat can): of the seed
        // and its refinement, keep the axis the model turns about with the better fit.
        let mut fits = [0.0; 3];
        let seeds: Vec<(TurnAxis, f64, f64)> = (0..3)
            .into_par_iter()
            .map(|k| {
                let direction = directions[k];
                let pivot = revolution_pivot(&problem.source.points, normals, &direction).unwrap_or(centroid);
                let seed = TurnAxis { pivot, direction };
                (seed, h.turn_fit(&seed), h.turn_fit(&h.axes[k]))
            })
            .collect();
        for (k, (seed, a, b)) in seeds.into_iter().enumerate() {
            fits[k] = a.min(b);
            if a < b {
                h.axes[k] = seed;
            }
        }
        // The axis the model turns about best is the candidate axis of revolution: tilt it
        // where that fits better still (a pattern search, steps of 2, 1 and 0.5 degrees). Not
        // where no turn about any axis fits (a box): no tilt of a few degrees changes that.
        let k = (0..3).min_by(|&a, &b| fits[a].total_cmp(&fits[b])).unwrap_or(0);
        if fits[k] <= h.fit_limit {
            h.axes[k] = h.tilted_to_fit(h.axes[k], fits[k], &problem.source.points, normals, centroid);
        }
        Some(h)
    }

    /// The visible-point residual of the model (thinned) moved by `pose` against the target
    /// (metres).
    pub fn fit(&self, pose: &Pose) -> f64 {
        visible_residual(&self.fit_points, Some(&self.fit_normals), &self.index, pose, self.tau, 0.3)
    }

    /// How well the model fits when turned both ways about `axis` by [`AXIS_TEST_DEG`]: the
    /// mean visible-point residual (metres).
    fn turn_fit(&self, axis: &TurnAxis) -> f64 {
        let turn = |deg| self.fit(&turned(&self.answer, &axis.pivot, &axis.direction, deg));
        0.5 * (turn(AXIS_TEST_DEG) + turn(-AXIS_TEST_DEG))
    }

    /// `axis` tilted, step by step, while turning about it fits better (pivots re-found).
    fn tilted_to_fit(
        &self,
        mut axis: TurnAxis,
        mut fit: f64,
        points: &[Point3],
        normals: &[Vector3],
        centroid: Point3,
    ) -> TurnAxis {
        for step_deg in [2.0f64, 1.0, 0.5] {
            let (u, v) = across(&axis.direction);
            loop {
                let tries: Vec<(f64, TurnAxis)> = [u, -u, v, -v]
                    .into_par_iter()
                    .map(|w| {
                        let direction = UnitQuaternion::from_scaled_axis(w * step_deg.to_radians()) * axis.direction;
                        let pivot = revolution_pivot(points, normals, &direction).unwrap_or(centroid);
                        let tried = TurnAxis { pivot, direction };
                        (self.turn_fit(&tried), tried)
                    })
                    .collect();
                let Some((f, best)) = tries.into_iter().min_by(|a, b| a.0.total_cmp(&b.0)).filter(|(f, _)| *f < fit)
                else {
                    break;
                };
                (fit, axis) = (f, best);
            }
        }
        axis
    }

    /// The answer turned by `deg` about axis `axis`, if it fits well enough.
    pub fn candidate(&self, axis: usize, deg: f64) -> Option<TurnCandidate> {
        let a = self.axes.get(axis)?;
        let pose = turned(&self.answer, &a.pivot, &a.direction, deg);
        (self.fit(&pose) <= self.fit_limit).then_some(TurnCandidate { axis, deg, pose })
    }

    /// The coarse candidates that fit well enough: about each axis and each way, the turns in
    /// increasing size up to the first that does not fit (the fit worsens as the turn grows;
    /// a box stops at its first turn).
    pub fn coarse(&self, cfg: &TurnSweepConfig) -> Vec<TurnCandidate> {
        let mut turns = cfg.sweep_deg.clone();
        turns.sort_by(f64::total_cmp);
        // The six ways side by side, concatenated in order.
        let ways: Vec<(usize, f64)> = (0..3).flat_map(|axis| [(axis, 1.0), (axis, -1.0)]).collect();
        let runs: Vec<Vec<TurnCandidate>> = ways
            .into_par_iter()
            .map(|(axis, sign)| turns.iter().map_while(|&d| self.candidate(axis, sign * d)).collect())
            .collect();
        runs.concat()
    }
}

/// The centroid of `points` and the eigenvectors of the normals' scatter matrix: on a surface
/// of revolution seen with its lid, the normals of the side are across the axis and those of
/// the lid along it, so the axis is one of them (the points' own principal axes are not, on a
/// partial view); on a box, they are the faces' normals.
fn normal_scatter_axes(points: &[Point3], normals: &[Vector3]) -> (Point3, [Vector3; 3]) {
    let n = points.len().max(1) as f64;
    let c = points.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let scatter = normals.iter().fold(Matrix3::zeros(), |a, m| a + m * m.transpose());
    let eig = scatter.symmetric_eigen();
    let axis = |k: usize| eig.eigenvectors.column(k).into_owned().try_normalize(1e-12).unwrap_or_else(Vector3::z);
    (Point3::from(c), [axis(0), axis(1), axis(2)])
}

/// Two unit vectors across the unit vector `axis` and across each other.
fn across(axis: &Vector3) -> (Vector3, Vector3) {
    let u = axis.cross(&if axis.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() }).normalize();
    (u, axis.cross(&u))
}

/// A point on the axis of direction `axis` about which the surface is one of revolution: every
/// normal line of such a surface meets its axis, so in the plane across the axis the normals'
/// lines meet in one point (least squares over the points whose normals are not along the
/// axis). `None` when they do not pin that point down (parallel normals: a plane).
fn revolution_pivot(points: &[Point3], normals: &[Vector3], axis: &Vector3) -> Option<Point3> {
    let (u, v) = across(axis);
    let (mut a, mut b) = (Matrix2::<f64>::zeros(), Vector2::<f64>::zeros());
    let mut along = 0.0;
    for (p, n) in points.iter().zip(normals) {
        along += p.coords.dot(axis);
        let across = Vector2::new(n.dot(&u), n.dot(&v));
        if across.norm() < 0.5 {
            continue;
        }
        // The line through p' along n' is m . x = m . p', with m across it.
        let m = Vector2::new(-across.y, across.x).normalize();
        let q = Vector2::new(p.coords.dot(&u), p.coords.dot(&v));
        a += m * m.transpose();
        b += m * m.dot(&q);
    }
    let eig = a.symmetric_eigenvalues();
    if eig.min() < 0.05 * eig.max().max(1e-12) {
        return None;
    }
    let c = a.try_inverse()? * b;
    Some(Point3::from(u * c.x + v * c.y + axis * (along / points.len().max(1) as f64)))
}

/// The axis about which the surface is one of revolution, refined from `direction`: its pivot
/// ([`revolution_pivot`]) and its direction alternately. Every normal line of such a surface
/// meets the axis, so `n x (p - pivot)` is across it, and the direction is the least
/// eigenvector of those vectors' scatter (points with normals along the axis, a lid, left out).
/// Stays at `direction` through the centroid where the points do not pin an axis down.
fn revolution_axis(points: &[Point3], normals: &[Vector3], direction: Vector3, centroid: Point3) -> TurnAxis {
    let mut axis = TurnAxis { pivot: centroid, direction };
    for _ in 0..5 {
        let Some(pivot) = revolution_pivot(points, normals, &axis.direction) else { break };
        let scatter = points.iter().zip(normals).filter(|(_, n)| n.dot(&axis.direction).abs() < 0.7).fold(
            Matrix3::zeros(),
            |acc, (p, n)| {
                let m = n.cross(&(p - pivot));
                acc + m * m.transpose()
            },
        );
        let eig = scatter.symmetric_eigen();
        let k = eig.eigenvalues.imin();
        let mut d = eig.eigenvectors.column(k).into_owned();
        if d.dot(&axis.direction) < 0.0 {
            d = -d;
        }
        let turn = d.dot(&axis.direction).clamp(-1.0, 1.0).acos();
        axis = TurnAxis { pivot, direction: d };
        if turn < 1e-4 {
            break;
        }
    }
    axis.pivot = revolution_pivot(points, normals, &axis.direction).unwrap_or(axis.pivot);
    axis
}

/// `answer` preceded by a turn of `deg` about `axis` through `pivot` (model coordinates).
fn turned(answer: &Pose, pivot: &Point3, axis: &Vector3, deg: f64) -> Pose {
    let r = UnitQuaternion::from_scaled_axis(axis * deg.to_radians());
    let about = Translation3::from(pivot.coords)
        * Pose::from_parts(Translation3::identity(), r)
        * Translation3::from(-pivot.coords);
    answer * about
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowfilter_geometry::PointCloud;

    /// The camera-facing half of a can (radius 3.4 cm, 10 cm tall; all of it when `whole`) with
    /// its lid, its axis `axis` through `base`, points with outward normals.
    fn can(axis: Vector3, base: Point3, whole: bool) -> PointCloud {
        let a = axis.normalize();
        let (u, v) = across(&a);
        let (mut points, mut normals) = (vec![], vec![]);
        let arc = if whole { std::f64::consts::TAU } else { std::f64::consts::PI };
        for i in 0..40 {
            let h = 0.1 * f64::from(i) / 39.0;
            for j in 0..80 {
                let phi = arc * (f64::from(j) / 80.0 - 0.5);
                // Facing the camera at the origin: the half towards -base.
                let radial = u * phi.cos() + v * phi.sin();
                let radial = if !whole && radial.dot(&(-base.coords)) < 0.0 { -radial } else { radial };
                points.push(base + a * h + radial * 0.034);
                normals.push(radial);
            }
        }
        for i in 0..12 {
            for j in 0..24 {
                let (r, phi) = (0.034 * f64::from(i) / 12.0, std::f64::consts::TAU * f64::from(j) / 24.0);
                points.push(base + a * 0.1 + (u * phi.cos() + v * phi.sin()) * r);
                normals.push(a);
            }
        }
        PointCloud { points, normals: Some(normals), colors: None, pixels: None }
    }

    #[test]
    fn the_axis_of_a_partly_seen_can_is_found_from_its_normals() {
        let axis = Vector3::new(0.05, 0.7, 0.7).normalize();
        let base = Point3::new(0.01, 0.02, 0.75);
        let can = can(axis, base, false);
        let normals = can.normals.as_deref().unwrap();
        let (centroid, directions) = normal_scatter_axes(&can.points, normals);
        let found: Vec<TurnAxis> =
            directions.iter().map(|d| revolution_axis(&can.points, normals, *d, centroid)).collect();
        let best =
            found.iter().max_by(|a, b| a.direction.dot(&axis).abs().total_cmp(&b.direction.dot(&axis).abs())).unwrap();
        let off_deg = best.direction.dot(&axis).abs().clamp(0.0, 1.0).acos().to_degrees();
        assert!(off_deg < 0.5, "axis off by {off_deg} deg");
        // The pivot lies on the true axis.
        let d = best.pivot - base;
        let across = (d - axis * d.dot(&axis)).norm();
        assert!(across < 0.001, "pivot {across} m from the axis");
    }

    #[test]
    fn turns_about_a_cans_axis_fit_and_turns_of_a_box_do_not() {
        // The model sees half of the can; the target all of it (a turned half still fits).
        let (axis, base) = (Vector3::new(0.0, 0.7, 0.7), Point3::new(0.0, 0.0, 0.75));
        let p = RegistrationProblem::new(can(axis, base, false), can(axis, base, true));
        let cfg = TurnSweepConfig::default();
        let h = TurnHypotheses::new(&p, Pose::identity(), &cfg).unwrap();
        let about_axis = (0..3).filter(|&k| h.candidate(k, 30.0).is_some()).count();
        assert!(about_axis >= 1, "no axis of the can admits a 30-degree turn");
        assert!(h.coarse(&cfg).iter().all(|c| h.fit(&c.pose) <= h.fit_limit));
        // A box (three faces seen) admits no turn of 12 degrees or more.
        let mut points = vec![];
        let mut normals = vec![];
        for i in 0..30 {
            for j in 0..30 {
                let (s, t) = (f64::from(i) / 29.0, f64::from(j) / 29.0);
                for (o, e1, e2, n) in [
                    (
                        Vector3::new(-0.05, -0.03, 0.7),
                        Vector3::new(0.1, 0.0, 0.0),
                        Vector3::new(0.0, 0.06, 0.0),
                        -Vector3::z(),
                    ),
                    (
                        Vector3::new(-0.05, -0.03, 0.7),
                        Vector3::new(0.0, 0.0, 0.08),
                        Vector3::new(0.0, 0.06, 0.0),
                        -Vector3::x(),
                    ),
                    (
                        Vector3::new(-0.05, -0.03, 0.7),
                        Vector3::new(0.1, 0.0, 0.0),
                        Vector3::new(0.0, 0.0, 0.08),
                        -Vector3::y(),
                    ),
                ] {
                    points.push(Point3::from(o + e1 * s + e2 * t));
                    normals.push(n);
                }
            }
        }
        let cube = PointCloud { points, normals: Some(normals), colors: None, pixels: None };
        let p = RegistrationProblem::new(cube.clone(), cube);
        let h = TurnHypotheses::new(&p, Pose::identity(), &cfg).unwrap();
        let turns: Vec<f64> = h.coarse(&cfg).iter().map(|c| c.deg.abs()).collect();
        assert!(turns.iter().all(|d| *d < 12.0), "{turns:?}");
    }
}
