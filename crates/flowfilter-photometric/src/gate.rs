//! When the judge is needed: only when the evidence is split.
//!
//! The judge ([`crate::judge`]) looks for a turn the flow did not follow. Its candidates are
//! turns of the answer that the clouds allow; each one moves the model's flow pairs away from
//! where the flow put them. So when the pyramid's own flow pairs agree with one another *and*
//! with the answer (most of them land within a few millimetres of where the answer moves their
//! model point), every candidate contradicts that flow, and the judge can only confirm the
//! answer. The judge is then skipped, unless the answer itself is a large motion, where the flow
//! is most often wrong as a whole (an object turned 20-30 degrees between frames).
//!
//! The test, [`evidence_settled`], is a single pass over the pairs: no RANSAC, no image.

use flowfilter_geometry::{Correspondences, ParamError, Pose, params};
use serde::{Deserialize, Serialize};

/// When the judge is skipped (`[judge.gate]` in the pipeline configuration).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct JudgeGate {
    /// Skip the judge when the evidence is settled; `false` runs it on every pair (the
    /// ablation).
    pub enabled: bool,
    /// Settled: at least this many of the plain flow's usable pairs (a texture-poor can's
    /// flow can agree, on a hundred pairs, with a turn 2-10 degrees short: 200 leaves it to the
    /// judge)...
    pub min_pairs: usize,
    /// ... and at least this fraction of them ...
    pub fraction: f64,
    /// ... land within this of the answer's prediction (metres) ...
    pub distance_m: f64,
    /// ... and the answer turns less than this (degrees).
    pub max_turn_deg: f64,
}

impl Default for JudgeGate {
    fn default() -> Self {
        Self { enabled: true, min_pairs: 200, fraction: 0.7, distance_m: 0.005, max_turn_deg: 10.0 }
    }
}

impl JudgeGate {
    /// Ranges serde cannot check.
    ///
    /// # Errors
    /// [`ParamError`] naming the key.
    pub fn validate(&self) -> Result<(), ParamError> {
        params::count_positive("min_pairs", self.min_pairs)?;
        params::require(self.fraction > 0.0 && self.fraction <= 1.0, "fraction", "in (0, 1]", self.fraction)?;
        params::positive("distance_m", self.distance_m)?;
        params::non_negative("max_turn_deg", self.max_turn_deg)
    }
}

/// Whether the flow pairs and the answer leave the judge nothing to decide: the gate is
/// enabled, the answer turns less than [`JudgeGate::max_turn_deg`], and at least
/// [`JudgeGate::min_pairs`] and [`JudgeGate::fraction`] of the usable pairs land within
/// [`JudgeGate::distance_m`] of `answer * source`.
///
/// ```
/// use flowfilter_geometry::{Correspondences, Point3, Pose};
/// use flowfilter_photometric::gate::{JudgeGate, evidence_settled};
/// let answer = Pose::translation(0.01, 0.0, 0.0);
/// let source: Vec<Point3> = (0..300).map(|i| Point3::new(f64::from(i) * 0.001, 0.0, 0.5)).collect();
/// let target = source.iter().map(|p| answer * p).collect();
/// let pairs = Correspondences { source, target, weights: vec![1.0; 300] };
/// assert!(evidence_settled(&pairs, &answer, &JudgeGate::default()));
/// // The same flow against an answer 2 cm away: split, the judge runs.
/// assert!(!evidence_settled(&pairs, &Pose::translation(0.03, 0.0, 0.0), &JudgeGate::default()));
/// ```
pub fn evidence_settled(pairs: &Correspondences, answer: &Pose, gate: &JudgeGate) -> bool {
    if !gate.enabled || answer.rotation.angle().to_degrees() >= gate.max_turn_deg {
        return false;
    }
    let agreeing = pairs.agreeing(answer, gate.distance_m);
    agreeing >= gate.min_pairs && agreeing as f64 >= gate.fraction * pairs.usable() as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowfilter_geometry::Point3;

    /// `agree` pairs moved by `motion`, `scattered` pairs moved 3 cm further.
    fn pairs(motion: &Pose, agree: usize, scattered: usize) -> Correspondences {
        let source: Vec<Point3> =
            (0..agree + scattered).map(|i| Point3::new((i % 10) as f64 * 0.01, (i / 10) as f64 * 0.01, 0.6)).collect();
        let target = source
            .iter()
            .enumerate()
            .map(|(i, p)| {
                motion * p + if i < agree { nalgebra::Vector3::zeros() } else { nalgebra::Vector3::new(0.03, 0.0, 0.0) }
            })
            .collect();
        Correspondences { source, target, weights: vec![1.0; agree + scattered] }
    }

    #[test]
    fn the_judge_is_skipped_only_when_the_flow_agrees_with_a_small_answer() {
        let gate = JudgeGate { min_pairs: 30, ..JudgeGate::default() };
        let small = Pose::from_parts(
            nalgebra::Translation3::new(0.01, 0.0, 0.0),
            nalgebra::UnitQuaternion::from_euler_angles(0.0, 3f64.to_radians(), 0.0),
        );
        // 60 of 80 pairs agree with the answer: settled.
        assert!(evidence_settled(&pairs(&small, 60, 20), &small, &gate));
        // Too few (20 < 30) or too small a share (40 of 80): split.
        assert!(!evidence_settled(&pairs(&small, 20, 0), &small, &gate));
        assert!(!evidence_settled(&pairs(&small, 40, 40), &small, &gate));
        // The flow agrees with itself but not with the answer (the answer turned 5 degrees more).
        let turned = Pose::from_parts(
            small.translation,
            nalgebra::UnitQuaternion::from_euler_angles(0.0, 8f64.to_radians(), 0.0),
        );
        assert!(!evidence_settled(&pairs(&small, 80, 0), &turned, &gate));
        // A large motion: the judge runs whatever the flow says.
        let large = Pose::from_parts(
            small.translation,
            nalgebra::UnitQuaternion::from_euler_angles(0.0, 12f64.to_radians(), 0.0),
        );
        assert!(!evidence_settled(&pairs(&large, 80, 0), &large, &gate));
        // Disabled: the judge runs on every pair.
        assert!(!evidence_settled(&pairs(&small, 80, 0), &small, &JudgeGate { enabled: false, ..gate }));
        // Rejected pairs (weight 0) neither count nor dilute.
        let mut p = pairs(&small, 40, 40);
        p.weights[40..].fill(0.0);
        assert!(evidence_settled(&p, &small, &gate));
    }
}
