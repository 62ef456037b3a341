//! [`RegistrationWarning`]: conditions a backend reports beside its result (a fallback taken, an
//! early stop), as values a caller can match on, each with a message for people.

use serde::ser::{Serialize, SerializeMap, Serializer};
use std::fmt;

/// Something the caller should know about a registration result.
///
/// `Display` gives the message; [`RegistrationWarning::code`] a stable snake-case name. Serialized
/// (JSON outputs) as `{"code": ..., "message": ...}`.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum RegistrationWarning {
    /// ICP found fewer than three pairs within its gate and stopped.
    TooFewPairs {
        /// Pairs found.
        found: usize,
        /// The gate, metres.
        max_distance_m: f64,
    },
    /// ICP's update was not determined (degenerate pairs) and it stopped.
    DegenerateUpdate,
    /// CPD's mixture explained no target point (it diverged) and it stopped.
    NothingExplained,
    /// FilterReg found no source point near the target at this kernel width and stopped.
    NothingNear {
        /// The kernel width, metres.
        sigma_m: f64,
    },
    /// The iterations reached a non-finite pose; the initial pose is returned.
    Diverged {
        /// The backend.
        method: &'static str,
    },
    /// Too few flow correspondences agreed on a rigid motion: Flow Filter fell back to FilterReg.
    FlowFallback {
        /// Pairs that agreed with the best rigid hypothesis.
        agreeing: usize,
        /// Pairs with a positive weight.
        usable: usize,
        /// Minimum agreeing pairs.
        min_inliers: usize,
        /// Minimum agreeing fraction of the usable pairs.
        min_fraction: f64,
    },
    /// Flow Filter's motion check kept a geometric registration from the initial pose that
    /// moved further than the flow result and fits as well.
    MotionCheck {
        /// The registration kept.
        kept: &'static str,
        /// How far it moved, degrees.
        moved_deg: f64,
        /// Its mean visible residual, metres.
        residual_m: f64,
        /// How far the flow result moved, degrees.
        flow_moved_deg: f64,
        /// The flow result's mean visible residual, metres.
        flow_residual_m: f64,
    },
    /// The estimated motion is within the estimate's own error bounds: it cannot be told from
    /// no motion.
    BelowResolution {
        /// The estimated rotation, degrees.
        moved_deg: f64,
        /// The rotation bound, degrees.
        rotation_deg: f64,
        /// The estimated translation, metres.
        moved_m: f64,
        /// The translation bound, metres.
        translation_m: f64,
    },
    /// A cloud was larger than the backend's work limit and was registered on an even subset.
    Subsampled {
        /// `source` or `target`.
        which: &'static str,
        /// Its points.
        points: usize,
        /// Points kept.
        kept: usize,
        /// The limit (`max_points`).
        limit: usize,
    },
    /// After the initial pose the clouds are far apart for their size: the result is a guess.
    FarApart {
        /// Centroid distance after the initial pose, metres.
        distance_m: f64,
        /// The larger cloud's bounding-box diagonal, metres.
        size_m: f64,
    },
    /// Few moved source points have a target point near them: the clouds do not support the pose.
    PoorFit {
        /// Fraction of source points within the gate.
        fitness: f64,
        /// The gate, metres.
        gate_m: f64,
    },
    /// The source fits, but most target points in its region have no source point near them.
    OneSidedOverlap {
        /// Fraction of source points within the gate.
        fitness: f64,
        /// Fraction of the target points in the source's box within the gate.
        support: f64,
        /// The gate, metres.
        gate_m: f64,
    },
    /// The registration stopped without converging and without another reason: its iteration
    /// limit, or a result that was never iterated (set by [`crate::assess`], so that every
    /// result reported as not converged says why).
    IterationLimit {
        /// Iterations run.
        iterations: usize,
    },
    /// FilterReg stopped because its E-step kept switching between the lattice's and the exact
    /// sums (`max_e_step_switches`): its kernel cycled instead of settling.
    KernelCycling {
        /// Iterations run.
        iterations: usize,
        /// Switches between the two E-steps.
        switches: usize,
    },
    /// Flow Filter's geometric check kept a flow-free registration that fits the clouds clearly
    /// better than the flow result.
    GeometricCheck {
        /// The registration kept.
        kept: &'static str,
        /// Its mean visible residual, metres.
        residual_m: f64,
        /// The flow result's mean visible residual, metres.
        flow_residual_m: f64,
    },
}

impl RegistrationWarning {
    /// A stable snake-case name of the condition.
    pub fn code(&self) -> &'static str {
        match self {
            Self::TooFewPairs { .. } => "too_few_pairs",
            Self::DegenerateUpdate => "degenerate_update",
            Self::NothingExplained => "nothing_explained",
            Self::NothingNear { .. } => "nothing_near",
            Self::Diverged { .. } => "diverged",
            Self::BelowResolution { .. } => "below_resolution",
            Self::FlowFallback { .. } => "flow_fallback",
            Self::MotionCheck { .. } => "motion_check",
            Self::GeometricCheck { .. } => "geometric_check",
            Self::Subsampled { .. } => "subsampled",
            Self::FarApart { .. } => "far_apart",
            Self::PoorFit { .. } => "poor_fit",
            Self::OneSidedOverlap { .. } => "one_sided_overlap",
            Self::IterationLimit { .. } => "iteration_limit",
            Self::KernelCycling { .. } => "kernel_cycling",
        }
    }

    /// Whether the condition ends a registration short of convergence (a stop, a divergence,
    /// or a result the clouds do not support): a not-converged result without one gets
    /// [`RegistrationWarning::IterationLimit`].
    pub fn explains_no_convergence(&self) -> bool {
        matches!(
            self,
            Self::TooFewPairs { .. }
                | Self::DegenerateUpdate
                | Self::NothingExplained
                | Self::NothingNear { .. }
                | Self::Diverged { .. }
                | Self::IterationLimit { .. }
                | Self::KernelCycling { .. }
        ) || self.is_implausible()
    }

    /// Whether the condition means the clouds do not support the result (the result is then not
    /// converged, and the CLI exits with code 3).
    pub fn is_implausible(&self) -> bool {
        matches!(self, Self::FarApart { .. } | Self::PoorFit { .. } | Self::OneSidedOverlap { .. })
    }
}

impl fmt::Display for RegistrationWarning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::TooFewPairs { found, max_distance_m } => {
                write!(f, "only {found} correspondences within {max_distance_m} m: ICP cannot continue")
            }
            Self::DegenerateUpdate => write!(f, "the update is not determined (degenerate correspondences)"),
            Self::NothingExplained => write!(f, "no target point is explained by the mixture: CPD diverged"),
            Self::NothingNear { sigma_m } => {
                write!(f, "no source point is near the target at sigma = {sigma_m:.4} m: FilterReg stopped")
            }
            Self::Diverged { method } => {
                write!(f, "{method} diverged to a non-finite pose; returning the initial pose")
            }
            Self::FlowFallback { agreeing, usable, min_inliers, min_fraction } => write!(
                f,
                "too few consistent flow correspondences ({agreeing} of {usable} agree on a rigid motion; \
                 needed {min_inliers} and {:.0}%): Flow Filter fell back to FilterReg",
                min_fraction * 100.0
            ),
            Self::MotionCheck { kept, moved_deg, residual_m, flow_moved_deg, flow_residual_m } => write!(
                f,
                "motion check: {kept} moved {moved_deg:.1} deg from the initial pose and fits the clouds as well \
                 (mean residual {:.2} mm) as the flow result, which moved {flow_moved_deg:.1} deg ({:.2} mm): \
                 kept the former (the flow tracked a pattern that does not move with the surface)",
                residual_m * 1e3,
                flow_residual_m * 1e3
            ),
            Self::BelowResolution { moved_deg, rotation_deg, moved_m, translation_m } => write!(
                f,
                "the motion ({moved_deg:.3} deg, {:.2} mm) is within the estimate's error bounds \
                 ({rotation_deg:.3} deg, {:.2} mm): it cannot be told from no motion",
                moved_m * 1e3,
                translation_m * 1e3
            ),
            Self::Subsampled { which, points, kept, limit } => write!(
                f,
                "the {which} cloud has {points} points, above CPD's work limit of {limit} (max_points): registered on \
                 an even subset of {kept} (max_points = 0 lifts the limit, at about M x N work per iteration)"
            ),
            Self::FarApart { distance_m, size_m } => write!(
                f,
                "the clouds start {distance_m:.3} m apart, {:.0} times their size ({size_m:.3} m): the result is a \
                 guess; give an initial pose that brings them together",
                distance_m / size_m
            ),
            Self::PoorFit { fitness, gate_m } => write!(
                f,
                "only {:.1}% of the source points lie within {:.1} mm of the target after alignment: the clouds do \
                 not support this pose",
                fitness * 100.0,
                gate_m * 1e3
            ),
            Self::OneSidedOverlap { fitness, support, gate_m } => write!(
                f,
                "one-sided overlap: {:.1}% of the source points fit the target, but only {:.1}% of the target points \
                 in the source's region lie within {:.1} mm of it: the pose is not supported by the target",
                fitness * 100.0,
                support * 100.0,
                gate_m * 1e3
            ),
            Self::IterationLimit { iterations } => {
                write!(f, "the registration did not converge (stopped after {iterations} iterations)")
            }
            Self::KernelCycling { iterations, switches } => write!(
                f,
                "FilterReg's kernel cycled between the lattice's and the exact sums ({switches} switches in \
                 {iterations} iterations): stopped, not converged"
            ),
            Self::GeometricCheck { kept, residual_m, flow_residual_m } => write!(
                f,
                "geometric check: the flow result fits the clouds worse (mean residual {:.2} mm) than {kept} \
                 ({:.2} mm); kept the latter",
                flow_residual_m * 1e3,
                residual_m * 1e3
            ),
        }
    }
}

impl Serialize for RegistrationWarning {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut map = serializer.serialize_map(Some(2))?;
        map.serialize_entry("code", self.code())?;
        map.serialize_entry("message", &self.to_string())?;
        map.end()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn warnings_serialise_as_code_and_message() {
        let w = RegistrationWarning::NothingNear { sigma_m: 0.25 };
        let v = serde_json::to_value(&w).unwrap();
        assert_eq!(v["code"], "nothing_near");
        assert_eq!(v["message"], "no source point is near the target at sigma = 0.2500 m: FilterReg stopped");
    }
}
