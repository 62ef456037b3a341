//! Anderson acceleration (type II) of a fixed-point iteration `z <- G(z)`.
//!
//! EM registration converges linearly, and slowly where the cloud lets points slide along the
//! surface (FilterReg on a smooth shape needs 100+ iterations for the last tenths of a degree).
//! Anderson mixing extrapolates from the last `depth` iterates and their residuals
//! `f = G(z) - z`: `z' = G(z_k) - sum_j gamma_j (G(z_{j+1}) - G(z_j))` with `gamma` the
//! least-squares fit of `f_k` by the residual differences. For a linear contraction it reaches the
//! fixed point after `dim + 1` steps. The caller safeguards it (falls back to the plain step and
//! calls [`Anderson::reset`] when the residual grows), as in Zhang et al., "Fast and Robust
//! Iterative Closest Point" (TPAMI 2021).

use flowfilter_geometry::{Point3, Pose, Vector3};
use nalgebra::{DMatrix, DVector, Translation3, UnitQuaternion};
use std::collections::VecDeque;

/// Relative Tikhonov term of the small least-squares problem (keeps nearly collinear residual
/// histories from producing huge coefficients).
const RIDGE: f64 = 1e-10;

/// The iterate history of one Anderson-accelerated iteration.
#[derive(Debug, Clone)]
pub(crate) struct Anderson {
    depth: usize,
    /// `G(z_j)` for the last `depth + 1` iterates.
    g: VecDeque<DVector<f64>>,
    /// `f_j = G(z_j) - z_j` for the same iterates.
    f: VecDeque<DVector<f64>>,
}

impl Anderson {
    /// Mixing over the last `depth` differences (`depth >= 1`).
    pub(crate) fn new(depth: usize) -> Self {
        Self { depth: depth.max(1), g: VecDeque::new(), f: VecDeque::new() }
    }

    /// Forget the history (after a rejected step or a change of parametrisation).
    pub(crate) fn reset(&mut self) {
        self.g.clear();
        self.f.clear();
    }

    /// Record the plain step `z -> g = G(z)` and return the next iterate: `g` itself while the
    /// history is empty, the Anderson mixture otherwise.
    pub(crate) fn step(&mut self, z: &DVector<f64>, g: DVector<f64>) -> DVector<f64> {
        self.f.push_back(&g - z);
        self.g.push_back(g);
        if self.f.len() > self.depth + 1 {
            self.f.pop_front();
            self.g.pop_front();
        }
        let (n, m) = (z.len(), self.f.len() - 1);
        let last_g = self.g[m].clone();
        if m == 0 {
            return last_g;
        }
        let df = DMatrix::from_fn(n, m, |r, c| self.f[c + 1][r] - self.f[c][r]);
        let dg = DMatrix::from_fn(n, m, |r, c| self.g[c + 1][r] - self.g[c][r]);
        // Normal equations with a small ridge: m <= depth is tiny.
        let mut a = df.transpose() * &df;
        let ridge = RIDGE * a.trace().max(f64::MIN_POSITIVE);
        for i in 0..m {
            a[(i, i)] += ridge;
        }
        let b = df.transpose() * &self.f[m];
        match a.cholesky() {
            Some(ch) => {
                let gamma = ch.solve(&b);
                let next = last_g - dg * gamma;
                if next.iter().all(|v| v.is_finite()) { next } else { self.g[m].clone() }
            }
            None => last_g,
        }
    }
}

/// Coordinates of an EM registration's state for Anderson mixing: the rotation vector of
/// `pose` relative to `reference`, the displacement of the source centroid relative to where
/// `reference` puts it (in units of the cloud's radius, so both parts weigh alike) and, when
/// sigma is an EM variable, `ln sigma^2`.
#[derive(Debug, Clone)]
struct EmCoordinates {
    reference: Pose,
    centre: Point3,
    radius: f64,
    with_sigma: bool,
}

impl EmCoordinates {
    fn encode(&self, pose: &Pose, sigma2: f64) -> DVector<f64> {
        let w = (pose.rotation * self.reference.rotation.inverse()).scaled_axis();
        let p = (pose * self.centre - self.reference * self.centre) / self.radius;
        let mut z = vec![w.x, w.y, w.z, p.x, p.y, p.z];
        if self.with_sigma {
            z.push(sigma2.ln());
        }
        DVector::from_vec(z)
    }

    /// The pose and (when mixed) sigma^2 of `z`.
    fn decode(&self, z: &DVector<f64>) -> (Pose, Option<f64>) {
        let r = UnitQuaternion::from_scaled_axis(Vector3::new(z[0], z[1], z[2])) * self.reference.rotation;
        let c = self.reference * self.centre + Vector3::new(z[3], z[4], z[5]) * self.radius;
        let pose = Pose::from_parts(Translation3::from(c - r * self.centre), r);
        (pose, self.with_sigma.then(|| z[6].exp()))
    }
}

/// Mixed poses rotating more than this (rad) from the reference start a new history.
const MAX_MIXING_ANGLE: f64 = 1.0;

/// Anderson mixing of an EM registration's map `(pose, sigma^2) -> (pose', sigma'^2)`, with
/// the safeguard: when a mixed iterate's fixed-point residual grew, its plain step is taken
/// instead and the history restarts there.
#[derive(Debug, Clone)]
pub(crate) struct PoseMixing {
    anderson: Anderson,
    coords: EmCoordinates,
    /// The fixed-point residual of the last recorded step (None: the history is empty).
    previous_residual: Option<f64>,
    /// Whether the current iterate is a mixed one.
    mixed: bool,
}

impl PoseMixing {
    /// Mixing over the last `depth` steps, starting from `reference`; `centre` and `radius`:
    /// the source's centroid and RMS radius; `with_sigma`: whether sigma^2 is mixed too.
    pub(crate) fn new(depth: usize, reference: Pose, centre: Point3, radius: f64, with_sigma: bool) -> Self {
        Self {
            anderson: Anderson::new(depth),
            coords: EmCoordinates { reference, centre, radius, with_sigma },
            previous_residual: None,
            mixed: false,
        }
    }

    /// Start a fresh history at the next step (the map changed: another subset, a new phase).
    pub(crate) fn restart(&mut self) {
        self.previous_residual = None;
        self.mixed = false;
    }

    /// The next iterate from the current one `(t, sigma2)` and its plain EM step
    /// `(g, new_sigma2)`; a mixed sigma^2 keeps the plain step's bounds (at most halved, at
    /// least `min_sigma2`, at most doubled).
    pub(crate) fn step(&mut self, t: Pose, sigma2: f64, g: Pose, new_sigma2: f64, min_sigma2: f64) -> (Pose, f64) {
        // A fresh history wherever the last residual is unknown: at the start, after the
        // safeguard below, and after a restart.
        if self.previous_residual.is_none() {
            self.anderson.reset();
            self.coords.reference = t;
        }
        let z = self.coords.encode(&t, sigma2);
        let gz = self.coords.encode(&g, new_sigma2);
        let residual = (&gz - &z).norm();
        if let Some(previous) = self.previous_residual
            && self.mixed
            && residual > previous
        {
            self.restart();
            return (g, new_sigma2);
        }
        self.previous_residual = Some(residual);
        let next = self.anderson.step(&z, gz);
        let (pose, s2) = self.coords.decode(&next);
        let s2 = s2.map_or(new_sigma2, |v| v.clamp((0.5 * sigma2).max(min_sigma2), 2.0 * sigma2));
        self.mixed = pose != g || s2 != new_sigma2;
        if (pose.rotation * self.coords.reference.rotation.inverse()).angle() > MAX_MIXING_ANGLE {
            self.anderson.reset();
            self.coords.reference = pose;
        }
        (pose, s2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A slow linear contraction (spectral radius 0.97) in 4-D.
    fn map(z: &DVector<f64>) -> DVector<f64> {
        let a = DMatrix::from_row_slice(
            4,
            4,
            &[0.97, 0.01, 0.0, 0.0, 0.0, 0.9, 0.02, 0.0, 0.0, 0.0, 0.5, 0.1, 0.01, 0.0, 0.0, 0.8],
        );
        let c = DVector::from_vec(vec![1.0, -2.0, 0.5, 3.0]);
        a * z + c
    }

    fn fixed_point() -> DVector<f64> {
        let mut z = DVector::zeros(4);
        for _ in 0..5000 {
            z = map(&z);
        }
        z
    }

    #[test]
    fn linear_contraction_is_solved_in_dimension_plus_one_steps() {
        let want = fixed_point();
        let mut aa = Anderson::new(4);
        let mut z = DVector::zeros(4);
        for _ in 0..6 {
            let g = map(&z);
            z = aa.step(&z, g);
        }
        assert!((&z - &want).norm() < 1e-6 * want.norm(), "{z} vs {want}");
        // The plain iteration is still far off after as many steps.
        let mut p = DVector::zeros(4);
        for _ in 0..6 {
            p = map(&p);
        }
        assert!((&p - &want).norm() > 0.1 * want.norm());
    }

    #[test]
    fn first_step_and_reset_return_the_plain_iterate() {
        let mut aa = Anderson::new(3);
        let z = DVector::from_vec(vec![0.5, 0.5, 0.5, 0.5]);
        assert_eq!(aa.step(&z, map(&z)), map(&z));
        let z2 = map(&z);
        assert_ne!(aa.step(&z2, map(&z2)), map(&z2));
        aa.reset();
        assert_eq!(aa.step(&z2, map(&z2)), map(&z2));
    }
}
