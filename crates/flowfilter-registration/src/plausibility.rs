//! Whether the clouds support a registration's result: a check run after any backend, so that
//! a pose the geometry does not carry is never reported as converged.
//!
//! Three conditions, each a [`RegistrationWarning`] that also sets `converged` to false:
//! - **far apart**: after the initial pose the clouds' centroids are further apart than
//!   [`Plausibility::far_apart_ratio`] times the clouds' size (a registration from there is a
//!   guess at the rotation);
//! - **poor fit**: fewer than [`Plausibility::min_fitness`] of the moved source points have a
//!   target point within the gate;
//! - **one-sided overlap**: of the target points inside the moved source's bounding box, fewer
//!   than [`Plausibility::min_support`] have a source point within the gate (the source lies on
//!   a small part of a surface that the rest of it contradicts).
//!
//! A result that is not converged for none of these reasons, nor for a stop its backend
//! named, gets [`RegistrationWarning::IterationLimit`]: every result reported as not converged
//! says why.
//!
//! The gate is [`Plausibility::gate_spacings`] times the clouds' median point spacing, so the
//! checks hold at any density.

use crate::problem::{Registration, RegistrationProblem};
use crate::warning::RegistrationWarning;
#[cfg(test)]
use flowfilter_geometry::PointCloud;
use flowfilter_geometry::{KnnIndex, Point3};
use rayon::prelude::*;

/// Thresholds of [`assess`]. The defaults pass every pair of the benchmarks whose estimate is
/// within their success thresholds, and flag the failures listed in the module's doc.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plausibility {
    /// Centroid distance after the initial pose, in units of the larger cloud's bounding-box
    /// diagonal, beyond which the clouds are far apart.
    pub far_apart_ratio: f64,
    /// Least fraction of moved source points with a target point within the gate.
    pub min_fitness: f64,
    /// Least fraction of the target points in the moved source's box with a source point within
    /// the gate.
    pub min_support: f64,
    /// The gate, in median point spacings (the larger of the two clouds').
    pub gate_spacings: f64,
}

impl Default for Plausibility {
    fn default() -> Self {
        Self { far_apart_ratio: 10.0, min_fitness: 0.1, min_support: 0.1, gate_spacings: 3.0 }
    }
}

/// Points sampled for the median spacing.
const SPACING_SAMPLES: usize = 512;

/// Check `r` against the clouds of `problem` with the default thresholds: append a warning and
/// set `converged` to false for each condition the result fails.
///
/// ```
/// use flowfilter_registration::{Point3, PointCloud, Pose, Registration, RegistrationProblem, assess};
/// let grid: Vec<Point3> = (0..400).map(|i| Point3::new((i % 20) as f64 * 0.005, (i / 20) as f64 * 0.005, 1.0)).collect();
/// let far: Vec<Point3> = grid.iter().map(|p| p + nalgebra::Vector3::new(1000.0, 0.0, 0.0)).collect();
/// let problem = RegistrationProblem::new(PointCloud::from_points(grid), PointCloud::from_points(far));
/// let mut r = Registration::with_transform(Pose::identity());
/// r.converged = true;
/// assess(&problem, &mut r);
/// assert!(!r.converged);
/// assert!(r.warnings.iter().any(|w| w.code() == "far_apart"));
/// ```
pub fn assess(problem: &RegistrationProblem, r: &mut Registration) {
    assess_with(problem, r, &Plausibility::default());
}

/// [`assess`] with given thresholds.
pub fn assess_with(problem: &RegistrationProblem, r: &mut Registration, limits: &Plausibility) {
    check_support(problem, r, limits);
    if !r.converged && !r.warnings.iter().any(RegistrationWarning::explains_no_convergence) {
        r.warnings.push(RegistrationWarning::IterationLimit { iterations: r.iterations });
    }
}

/// The three conditions of the module's doc.
fn check_support(problem: &RegistrationProblem, r: &mut Registration, limits: &Plausibility) {
    let (source, target) = (&problem.source, &problem.target);
    if source.len() < 3 || target.len() < 3 {
        return;
    }
    let before = r.warnings.len();
    let size = diagonal(&source.points).max(diagonal(&target.points)).max(f64::MIN_POSITIVE);
    let (cs, ct) = (source.centroid().expect("non-empty"), target.centroid().expect("non-empty"));
    let gap = (problem.init * cs - ct).norm();
    if gap > limits.far_apart_ratio * size {
        r.warnings.push(RegistrationWarning::FarApart { distance_m: gap, size_m: size });
    }
    // A rigid motion keeps the spacing: the moved source's index serves for both.
    let target_index = KnnIndex::new(&target.points);
    let moved: Vec<Point3> = source.points.iter().map(|p| r.transform * p).collect();
    let moved_index = KnnIndex::new(&moved);
    let gate =
        limits.gate_spacings * median_spacing(&moved, &moved_index).max(median_spacing(&target.points, &target_index));
    let fitness = fraction_within(&moved, &target_index, gate);
    if fitness < limits.min_fitness {
        r.warnings.push(RegistrationWarning::PoorFit { fitness, gate_m: gate });
    } else {
        let (lo, hi) = bounds(&moved);
        let inside: Vec<Point3> = target
            .points
            .iter()
            .filter(|p| (0..3).all(|k| p[k] >= lo[k] - gate && p[k] <= hi[k] + gate))
            .copied()
            .collect();
        let support = if inside.is_empty() { 0.0 } else { fraction_within(&inside, &moved_index, gate) };
        if support < limits.min_support {
            r.warnings.push(RegistrationWarning::OneSidedOverlap { fitness, support, gate_m: gate });
        }
    }
    if r.warnings.len() > before {
        r.converged = false;
    }
}

/// Bounding-box diagonal.
fn diagonal(points: &[Point3]) -> f64 {
    let (lo, hi) = bounds(points);
    (hi - lo).norm()
}

fn bounds(points: &[Point3]) -> (Point3, Point3) {
    points.iter().fold((Point3::from([f64::INFINITY; 3]), Point3::from([f64::NEG_INFINITY; 3])), |(lo, hi), p| {
        (lo.inf(p), hi.sup(p))
    })
}

/// Median distance to the nearest other point, over an even sample of `points` (`index`: their
/// k-d tree).
fn median_spacing(points: &[Point3], index: &KnnIndex) -> f64 {
    let step = points.len().div_ceil(SPACING_SAMPLES).max(1);
    let mut d: Vec<f64> =
        points.iter().step_by(step).filter_map(|p| index.k_nearest(p, 2).get(1).map(|n| n.dist2.sqrt())).collect();
    if d.is_empty() {
        return 0.0;
    }
    let mid = d.len() / 2;
    *d.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// Fraction of `points` with a point of `index` within `gate`.
fn fraction_within(points: &[Point3], index: &KnnIndex, gate: f64) -> f64 {
    let near = points.par_iter().filter(|p| index.nearest(p).is_some_and(|n| n.dist2 <= gate * gate)).count();
    near as f64 / points.len().max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowfilter_geometry::{Pose, Vector3};

    fn cloud(points: Vec<Point3>) -> PointCloud {
        PointCloud::from_points(points)
    }

    fn plane(n: usize, spacing: f64) -> Vec<Point3> {
        (0..n * n).map(|i| Point3::new((i % n) as f64 * spacing, (i / n) as f64 * spacing, 1.0)).collect()
    }

    fn result(transform: Pose) -> Registration {
        Registration { converged: true, ..Registration::with_transform(transform) }
    }

    #[test]
    fn a_supported_result_is_left_alone() {
        let p = RegistrationProblem::new(cloud(plane(30, 0.004)), cloud(plane(30, 0.004)));
        let mut r = result(Pose::identity());
        assess(&p, &mut r);
        assert!(r.converged && r.warnings.is_empty(), "{:?}", r.warnings);
    }

    /// A supported result its backend did not converge on says so; one whose backend named its
    /// stop keeps that reason alone.
    #[test]
    fn a_result_not_converged_says_why() {
        let p = RegistrationProblem::new(cloud(plane(30, 0.004)), cloud(plane(30, 0.004)));
        let mut r = Registration { iterations: 50, ..Registration::with_transform(Pose::identity()) };
        assess(&p, &mut r);
        assert!(!r.converged);
        assert_eq!(r.warnings, [RegistrationWarning::IterationLimit { iterations: 50 }]);
        let mut r = Registration { warnings: vec![RegistrationWarning::DegenerateUpdate], ..r };
        assess(&p, &mut r);
        assert_eq!(r.warnings, [RegistrationWarning::DegenerateUpdate]);
    }

    #[test]
    fn a_result_off_the_target_is_a_poor_fit() {
        let p = RegistrationProblem::new(cloud(plane(30, 0.004)), cloud(plane(30, 0.004)));
        let mut r = result(Pose::translation(0.0, 0.0, 0.5));
        assess(&p, &mut r);
        assert!(!r.converged);
        assert_eq!(r.warnings[0].code(), "poor_fit");
    }

    #[test]
    fn patches_spanning_a_surface_they_do_not_explain_are_one_sided() {
        // The source: two small patches at opposite corners of the target's wall. Both fit it,
        // but the wall between them, inside the source's box, has no source point near it.
        let target = plane(50, 0.004);
        let source: Vec<Point3> = target
            .iter()
            .enumerate()
            .filter(|(i, _)| {
                let (x, y) = (i % 50, i / 50);
                (x < 4 && y < 4) || (x >= 46 && y >= 46)
            })
            .map(|(_, p)| *p)
            .collect();
        let p = RegistrationProblem::new(cloud(source), cloud(target));
        let mut r = result(Pose::identity());
        assess(&p, &mut r);
        assert!(!r.converged);
        assert_eq!(r.warnings[0].code(), "one_sided_overlap", "{:?}", r.warnings);
    }

    #[test]
    fn clouds_far_apart_are_flagged_whatever_the_result() {
        let far: Vec<Point3> = plane(30, 0.004).iter().map(|p| p + Vector3::new(1000.0, 0.0, 0.0)).collect();
        let p = RegistrationProblem::new(cloud(plane(30, 0.004)), cloud(far));
        let mut r = result(Pose::translation(1000.0, 0.0, 0.0));
        assess(&p, &mut r);
        assert!(!r.converged);
        assert_eq!(r.warnings.iter().map(|w| w.code()).collect::<Vec<_>>(), ["far_apart"]);
        // The same clouds with an initial pose that brings them together: no warning.
        let p = p.with_init(Pose::translation(1000.0, 0.0, 0.0));
        let mut r = result(Pose::translation(1000.0, 0.0, 0.0));
        assess(&p, &mut r);
        assert!(r.converged && r.warnings.is_empty());
    }
}
