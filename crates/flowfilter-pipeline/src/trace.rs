//! [`PairTrace`]: what the pipeline weighed on one pair, kept for inspection
//! ([`crate::Pipeline::estimate_traced`]; the `flowfilter-rerun` crate records it).

use flowfilter_geometry::{Correspondences, Mask, Pose};

/// One candidate set of flow correspondences.
#[derive(Debug, Clone)]
pub struct TracedSet {
    /// Where the set came from: `plain` (the flow from the frames as they are), `wide` (tracked
    /// again from the wide-baseline guide's placement) or `guided` (tracked again from the
    /// geometric registration's prior).
    pub source: &'static str,
    /// The 3-D pairs (model point, target point, weight; colour camera frames).
    pub pairs: Correspondences,
}

/// One pose the photometric judge weighed.
#[derive(Debug, Clone, Copy)]
pub struct TracedCandidate {
    /// The turn's axis (unit, target camera frame).
    pub axis: [f64; 3],
    /// The turn, degrees.
    pub turn_deg: f64,
    /// The candidate pose (`target ~ pose * model`).
    pub pose: Pose,
    /// Its photometric score (lower agrees better; `None`: too little texture to score).
    pub score: Option<f64>,
}

/// What the pipeline saw and weighed on one pair.
#[derive(Debug, Clone, Default)]
pub struct PairTrace {
    /// The candidate sets of flow correspondences, in the order the registration weighed them.
    pub sets: Vec<TracedSet>,
    /// The set the registration kept (index into `sets`), when it says.
    pub kept_set: Option<usize>,
    /// The distance (metres) within which a pair agrees with a pose (`[flowfilter]
    /// inlier_threshold_m`): the pairs drawn as inliers of the answer.
    pub inlier_distance_m: f64,
    /// The judge's candidates and their scores (empty when the judge did not run).
    pub candidates: Vec<TracedCandidate>,
    /// The judge's score of the registration's answer.
    pub answer_score: Option<f64>,
    /// The target mask the pipeline used when it propagated the model's (the target came
    /// without one).
    pub propagated_mask: Option<Mask>,
}

impl PairTrace {
    /// Whether pair `i` of `pairs` agrees with `pose` (within [`PairTrace::inlier_distance_m`];
    /// pairs of weight 0 never do).
    pub fn is_inlier(&self, pairs: &Correspondences, i: usize, pose: &Pose) -> bool {
        pairs.agrees(i, pose, self.inlier_distance_m)
    }
}
