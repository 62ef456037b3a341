//! Geometry first: a scene (a whole frame, an object larger than `scene_points`) is registered
//! by its clouds' shapes alone (the registrar's prior: Flow Filter's point-to-plane FilterReg
//! from the initial pose), aligned on the two images, and kept when the images confirm it;
//! flow, the judge and the rest of the pipeline run only where they do not, and reuse that
//! registration.
//!
//! On the shared RealSense sequences' whole frames, where the images confirm them, FilterReg
//! and the direct alignment land within 0.08 deg of the full pipeline's answer (median; at most
//! 1.3) in a third of its time; where FilterReg lost the scene (15-100 deg off), fewer than two
//! in five of the model's pixels land where the target's depth agrees and their texture does
//! not correlate ([`GeometryFirstConfig`]).

use flowfilter_geometry::params::{self, ParamError};
use flowfilter_photometric::Agreement;
use serde::{Deserialize, Serialize};

/// When a scene's geometric registration is taken without the flow (`[geometry_first]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GeometryFirstConfig {
    /// Try the geometric registration first on scenes (model clouds over
    /// `registration.flowfilter.scene_points`); Flow Filter methods only.
    pub enabled: bool,
    /// Kept only when the aligned answer's texture score (one minus the normalised
    /// cross-correlation of the model's texture, moved, with the target's) is at most this...
    pub max_score: f64,
    /// ...and at least this fraction of the model's compared pixels land where the target's
    /// depth agrees.
    pub min_visible: f64,
}

impl Default for GeometryFirstConfig {
    /// Thresholds chosen on the whole frames of shelf-A and shelf-D (`cargo xtask bench-real`):
    /// every answer kept there and on the held-out sequences lies within 3.3 deg of the
    /// calibrated motion; every answer over 15 deg off scores above 0.85 with at most 37% of
    /// its pixels visible.
    fn default() -> Self {
        Self { enabled: true, max_score: 0.5, min_visible: 0.5 }
    }
}

impl GeometryFirstConfig {
    /// Check the ranges.
    ///
    /// # Errors
    /// The key at fault, with the value found.
    pub fn validate(&self) -> Result<(), ParamError> {
        params::in_closed("max_score", self.max_score, 0.0, 2.0)?;
        params::in_closed("min_visible", self.min_visible, 0.0, 1.0)
    }

    /// Whether `agreement` (at the aligned geometric answer) confirms it.
    pub fn confirms(&self, agreement: &Agreement) -> bool {
        agreement.score.is_some_and(|s| s <= self.max_score) && agreement.visible_fraction() >= self.min_visible
    }
}

/// What the geometry-first try found (an estimate's `geometry_first`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GeometryFirstReport {
    /// Whether the geometric answer was kept (no flow ran).
    pub confirmed: bool,
    /// Whether FilterReg converged (an answer that did not is not aligned or scored).
    pub registration_converged: bool,
    /// The aligned answer's texture score (see [`GeometryFirstConfig::max_score`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub score: Option<f64>,
    /// The fraction of the model's compared pixels visible in the target at that answer.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub visible_fraction: Option<f64>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_answer_is_confirmed_only_by_both_tests() {
        let cfg = GeometryFirstConfig::default();
        let agreement = |visible, score| Agreement { samples: 100, visible, score };
        assert!(cfg.confirms(&agreement(60, Some(0.3))));
        assert!(!cfg.confirms(&agreement(30, Some(0.3))), "too few pixels visible");
        assert!(!cfg.confirms(&agreement(60, Some(0.9))), "texture does not correlate");
        assert!(!cfg.confirms(&agreement(60, None)), "flat texture: no score");
        assert!(GeometryFirstConfig { min_visible: 1.5, ..cfg.clone() }.validate().is_err());
        assert!(GeometryFirstConfig { max_score: -0.1, ..cfg }.validate().is_err());
    }
}
