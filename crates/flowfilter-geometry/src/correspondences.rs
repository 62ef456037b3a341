//! [`Correspondences`]: weighted 3-D/3-D point pairs, the one pair type every stage speaks
//! (optical flow produces them, registration consumes them).

use crate::{Point3, Pose};
use thiserror::Error;

/// Why a set of correspondences cannot be used.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum CorrespondenceError {
    /// The three arrays differ in length.
    #[error("correspondences: {sources} sources, {targets} targets and {weights} weights (one each per pair expected)")]
    LengthMismatch {
        /// Source points.
        sources: usize,
        /// Target points.
        targets: usize,
        /// Weights.
        weights: usize,
    },
    /// A pair has a non-finite coordinate, or a negative or non-finite weight.
    #[error("correspondence pair {index} is not finite or has a negative weight")]
    BadPair {
        /// The pair's index.
        index: usize,
    },
}

/// Weighted 3-D/3-D correspondences `source[i] <-> target[i]`, with `target[i] ~ T * source[i]`
/// for the motion `T` they describe.
///
/// ```
/// use flowfilter_geometry::{Correspondences, Point3};
/// let c = Correspondences {
///     source: vec![Point3::new(0.0, 0.0, 1.0)],
///     target: vec![Point3::new(0.01, 0.0, 1.0)],
///     weights: vec![1.0],
/// };
/// assert_eq!(c.len(), 1);
/// assert_eq!(c.usable(), 1);
/// // The pair agrees with a 1 cm shift along x, not with no motion (within 1 mm).
/// assert_eq!(c.agreeing(&flowfilter_geometry::Pose::translation(0.01, 0.0, 0.0), 0.001), 1);
/// assert_eq!(c.agreeing(&flowfilter_geometry::Pose::identity(), 0.001), 0);
/// c.validate().unwrap();
/// ```
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Correspondences {
    /// Points in the source (model) frame.
    pub source: Vec<Point3>,
    /// Corresponding points in the target frame.
    pub target: Vec<Point3>,
    /// Non-negative weights (0: a rejected pair kept for bookkeeping).
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

    /// Number of pairs with a positive weight.
    pub fn usable(&self) -> usize {
        self.weights.iter().filter(|w| **w > 0.0).count()
    }

    /// Whether pair `i` is usable and `pose` moves its source point to within `within_m` of
    /// its target point.
    pub fn agrees(&self, i: usize, pose: &Pose, within_m: f64) -> bool {
        self.weights[i] > 0.0 && (pose * self.source[i] - self.target[i]).norm() <= within_m
    }

    /// Number of pairs that [agree](Correspondences::agrees) with `pose` within `within_m`.
    pub fn agreeing(&self, pose: &Pose, within_m: f64) -> usize {
        (0..self.len()).filter(|&i| self.agrees(i, pose, within_m)).count()
    }

    /// Check lengths, finiteness and weights.
    ///
    /// # Errors
    /// [`CorrespondenceError::LengthMismatch`] when the arrays differ in length,
    /// [`CorrespondenceError::BadPair`] for the first pair with a non-finite coordinate or a
    /// negative or non-finite weight.
    pub fn validate(&self) -> Result<(), CorrespondenceError> {
        if self.target.len() != self.source.len() || self.weights.len() != self.source.len() {
            return Err(CorrespondenceError::LengthMismatch {
                sources: self.source.len(),
                targets: self.target.len(),
                weights: self.weights.len(),
            });
        }
        for i in 0..self.len() {
            let finite = self.source[i].coords.iter().chain(self.target[i].coords.iter()).all(|v| v.is_finite());
            if !finite || !self.weights[i].is_finite() || self.weights[i] < 0.0 {
                return Err(CorrespondenceError::BadPair { index: i });
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn validation_names_the_fault() {
        let p = Point3::new(0.0, 0.0, 1.0);
        let short = Correspondences { source: vec![p, p], target: vec![p], weights: vec![1.0, 1.0] };
        assert_eq!(short.validate(), Err(CorrespondenceError::LengthMismatch { sources: 2, targets: 1, weights: 2 }));
        let negative = Correspondences { source: vec![p, p], target: vec![p, p], weights: vec![1.0, -1.0] };
        assert_eq!(negative.validate(), Err(CorrespondenceError::BadPair { index: 1 }));
        let nan =
            Correspondences { source: vec![Point3::new(f64::NAN, 0.0, 0.0)], target: vec![p], weights: vec![1.0] };
        assert_eq!(nan.validate(), Err(CorrespondenceError::BadPair { index: 0 }));
        let fine = Correspondences { source: vec![p, p], target: vec![p, p], weights: vec![0.0, 2.0] };
        assert_eq!(fine.validate(), Ok(()));
        assert_eq!(fine.usable(), 1);
    }
}
