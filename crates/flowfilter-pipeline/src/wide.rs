//! The wide-baseline guide: where the model's region went in the target image
//! ([`flowfilter_flow::coarse_search`]) as a predicted motion that guided tracking starts from.

use crate::config::WideBaselineConfig;
use crate::global_start::global_start;
use crate::stages::PreparedFrame;
use flowfilter_camera::{CameraModel, Pixel};
use flowfilter_flow::coarse_search::{CoarseMatch, SearchImages, coarse_search, search_hypotheses};
use flowfilter_flow::correspondences::FlowPairs;
use flowfilter_flow::features::feature_pairs;
use flowfilter_geometry::{Correspondences, Pose};
use flowfilter_registration::ransac_kabsch;
use nalgebra::{Rotation3, Translation3, Unit, UnitQuaternion, Vector3};

/// The coarse search of one pair, run once: its pyramid levels and where it placed the model's
/// region (shared by the wide-baseline guide and the mask propagation).
pub(crate) struct CoarseView {
    images: SearchImages,
    /// Where the model's region went, when the search found it.
    pub(crate) found: Option<CoarseMatch>,
}

impl CoarseView {
    /// The search of `model`'s region in `target`.
    pub(crate) fn new(model: &PreparedFrame, target: &PreparedFrame, cfg: &WideBaselineConfig) -> Self {
        let images = SearchImages::new(&model.gray, &target.gray, search_level(model.gray.dims(), cfg));
        let found = coarse_search(&images, &model.mask, &cfg.search);
        Self { images, found }
    }
}

/// The motion the coarse search predicts for the model's region, when the search finds the
/// region and the motion moves its pixels at least `min_motion_px` on average.
///
/// Two kinds of motion are weighed: a shift and turn of the region in the image (a camera
/// that pans or rolls), and turns of the region about its own centre by up to
/// [`ORBIT_MAX_DEG`] about the camera's x or y axis, each placed by its own shift search (a
/// camera circling the object: its sides turn away while it shifts less than a pan would move
/// it). The second is taken when it correlates clearly better.
pub(crate) fn wide_guide(model: &PreparedFrame, view: &CoarseView, cfg: &WideBaselineConfig) -> Option<Pose> {
    if !cfg.enabled {
        return None;
    }
    let found = view.found?;
    let camera = &model.sensor.color;
    let flat = camera_turn(camera, &found)?;
    let orbit = cfg.orbit.then(|| orbit_guide(model, view, cfg, &found)).flatten();
    let guide = orbit.unwrap_or(flat);
    (mean_motion_px(&guide, model) >= cfg.min_motion_px).then_some(guide)
}

/// The coarse search's pyramid level for images of `(w, h)`: `cfg.search.level`, raised (up to
/// 6) while the searched image's longer side exceeds `cfg.max_search_side_px`.
pub(crate) fn search_level((w, h): (usize, usize), cfg: &WideBaselineConfig) -> usize {
    let mut level = cfg.search.level.max(1);
    while cfg.max_search_side_px > 0 && (w.max(h) >> level) > cfg.max_search_side_px && level < 6 {
        level += 1;
    }
    level
}

/// The largest rigid consensus among `pairs`: a motion that at least `settled_min_pairs` of them
/// (and at least 3) agree on within `settled_distance_m`, and how many agree. The RANSAC is
/// seeded, so the answer is the same on every run.
pub(crate) fn consensus(pairs: &Correspondences, cfg: &WideBaselineConfig) -> Option<(Pose, usize)> {
    let min = cfg.settled_min_pairs.max(3);
    let (pose, inliers) = ransac_kabsch(pairs, SETTLED_RANSAC_ITERATIONS, cfg.settled_distance_m, min, 0)?;
    let agreeing = inliers.iter().filter(|b| **b).count();
    (agreeing >= min).then_some((pose, agreeing))
}

/// The rigid motion the pyramid's flow pairs already agree on, if they do (see
/// [`WideBaselineConfig::settled_min_pairs`]), from their [`consensus`]: enough of them, and a
/// share of at least `settled_fraction` of the usable ones. The coarse search is then not needed.
pub(crate) fn settled_by(
    consensus: Option<(Pose, usize)>,
    pairs: &Correspondences,
    cfg: &WideBaselineConfig,
) -> Option<Pose> {
    let (pose, agreeing) = consensus.filter(|_| cfg.settled_min_pairs > 0)?;
    (agreeing as f64 >= cfg.settled_fraction * pairs.usable() as f64).then_some(pose)
}

/// The feature matches of `model`'s region in `target` ([`flowfilter_flow::features`]) as 3-D
/// pairs, and the motion their largest rigid consensus gives when it has at least
/// [`FEATURE_MIN_AGREEING`] pairs and moves the region's pixels at least `min_motion_px` on
/// average (the guide tracking starts from, as the coarse search's).
pub(crate) fn feature_guide(
    model: &PreparedFrame,
    target: &PreparedFrame,
    cfg: &WideBaselineConfig,
    k_sigma: f64,
) -> (FlowPairs, Option<Pose>) {
    let matched = feature_pairs(&model.view(), &target.view(), &model.rays, &cfg.features, k_sigma);
    let guide = ransac_kabsch(&matched.pairs, FEATURE_RANSAC_ITERATIONS, FEATURE_AGREEMENT_M, FEATURE_MIN_AGREEING, 0)
        .map(|(pose, _)| pose)
        .filter(|pose| mean_motion_px(pose, model) >= cfg.min_motion_px);
    (matched, guide)
}

/// The motion a global registration of the two frames' clouds finds
/// ([`crate::config::GeometryGuideConfig`]), refined by point-to-plane ICP, when it moves the
/// region's pixels at least `min_motion_px` on average.
pub(crate) fn geometric_guide(model: &PreparedFrame, target: &PreparedFrame, cfg: &WideBaselineConfig) -> Option<Pose> {
    let pose = global_start(&model.cloud, &target.cloud, &cfg.geometry)?.pose;
    (mean_motion_px(&pose, model) >= cfg.min_motion_px).then_some(pose)
}

/// Least feature pairs agreeing on a motion for it to guide tracking.
pub const FEATURE_MIN_AGREEING: usize = 8;
/// Distance within which a feature pair agrees with a motion (metres): a corner is placed to a
/// pixel or two, and real depth at a corner is noisy.
const FEATURE_AGREEMENT_M: f64 = 0.01;
/// RANSAC hypotheses of [`feature_guide`].
const FEATURE_RANSAC_ITERATIONS: usize = 500;

/// RANSAC hypotheses of [`settled`].
const SETTLED_RANSAC_ITERATIONS: usize = 200;

/// Largest turn of the orbit hypotheses about either axis, degrees.
pub const ORBIT_MAX_DEG: f64 = 30.0;
/// Step of the orbit hypotheses, degrees.
const ORBIT_STEP_DEG: f64 = 10.0;
/// An orbit hypothesis replaces the image-plane match when it correlates better by this much.
const ORBIT_MARGIN: f64 = 0.05;

/// The best orbit hypothesis (see [`wide_guide`]) as a motion, when it beats the image-plane
/// match `found` by [`ORBIT_MARGIN`] (the hypotheses' shifts are searched from no shift).
fn orbit_guide(
    model: &PreparedFrame,
    view: &CoarseView,
    cfg: &WideBaselineConfig,
    found: &CoarseMatch,
) -> Option<Pose> {
    let centre = model.cloud.centroid()?;
    let steps = (ORBIT_MAX_DEG / ORBIT_STEP_DEG).round() as i32;
    // Turns about one axis at a time: a circling camera turns the region about the vertical or
    // the horizontal, and the shift search places each.
    let turns: Vec<Pose> = (-steps..=steps)
        .filter(|&k| k != 0)
        .flat_map(|k| [(k, 0), (0, k)])
        .map(|(i, j)| {
            let step = ORBIT_STEP_DEG.to_radians();
            let r = UnitQuaternion::from_euler_angles(f64::from(i) * step, f64::from(j) * step, 0.0);
            // About the region's centre: P -> R (P - c) + c.
            Pose::from_parts(Translation3::from(centre.coords - r * centre.coords), r)
        })
        .collect();
    let camera = &model.sensor.color;
    let predict = |h: usize, x: f64, y: f64| {
        let (xi, yi) = (x as usize, y as usize);
        let z = f64::from(*model.depth.get(xi, yi)?);
        let p = model.rays.backproject(xi, yi, z).filter(|_| z > 0.0)?;
        let q = camera.project(&(turns[h] * p))?;
        Some([q.x, q.y])
    };
    let from_still = CoarseMatch { shift: [0.0; 2], turn_rad: 0.0, ..*found };
    let best = search_hypotheses(&view.images, &model.mask, &cfg.search, &from_still, turns.len(), &predict)?;
    if best.score < found.score + ORBIT_MARGIN {
        return None;
    }
    // The hypothesis, then a turn of the camera that shifts its image of the centre as found.
    let seen = camera.project(&(turns[best.index] * centre))?;
    let shift = CoarseMatch { centre: [seen.x, seen.y], shift: best.shift, turn_rad: 0.0, score: best.score };
    Some(camera_turn(camera, &shift)? * turns[best.index])
}

/// The mean displacement of the model's mask pixels with depth (every 8th row and column)
/// under `guide`.
fn mean_motion_px(guide: &Pose, model: &PreparedFrame) -> f64 {
    let (w, h) = model.mask.dims();
    let camera = &model.sensor.color;
    let moved: Vec<f64> = (0..h)
        .step_by(8)
        .flat_map(|y| (0..w).step_by(8).map(move |x| (x, y)))
        .filter(|&(x, y)| *model.mask.at(x, y) && *model.depth.at(x, y) > 0.0)
        .filter_map(|(x, y)| {
            let p = model.rays.backproject(x, y, f64::from(*model.depth.at(x, y)))?;
            let q = camera.project(&(guide * p))?;
            Some((q.x - x as f64).hypot(q.y - y as f64))
        })
        .collect();
    if moved.is_empty() { 0.0 } else { moved.iter().sum::<f64>() / moved.len() as f64 }
}

/// A turn of the camera about its centre that moves the image as the match says: the region's
/// centre ray turned onto the ray of where it went, after a turn about that ray by the match's
/// image turn. Depth-free, so every pixel's prediction holds whatever its depth.
fn camera_turn(camera: &CameraModel, found: &CoarseMatch) -> Option<Pose> {
    let from = Pixel::new(found.centre[0], found.centre[1]);
    let to = Pixel::new(found.centre[0] + found.shift[0], found.centre[1] + found.shift[1]);
    let (a, b) = (camera.normalized_ray(&from)?, camera.normalized_ray(&to)?);
    let (a, b) = (Unit::new_normalize(a), Unit::new_normalize(b));
    let twist = UnitQuaternion::from_axis_angle(&a, found.turn_rad);
    let align = UnitQuaternion::from_rotation_matrix(&Rotation3::rotation_between(&a, &b)?);
    let rotation = align * twist;
    rotation
        .coords
        .iter()
        .all(|v| v.is_finite())
        .then(|| Pose::from_parts(Translation3::from(Vector3::zeros()), rotation))
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowfilter_camera::{Distortion, ImageSize, Intrinsics};

    #[test]
    fn the_camera_turn_moves_pixels_as_the_match_does() {
        let camera = CameraModel::new(
            Intrinsics::new(600.0, 600.0, 320.0, 240.0).unwrap(),
            Distortion::NONE,
            ImageSize::new(640, 480).unwrap(),
        );
        let found = CoarseMatch { centre: [300.0, 200.0], shift: [150.0, 40.0], turn_rad: 0.15, score: 0.9 };
        let pose = camera_turn(&camera, &found).unwrap();
        for (x, y, z) in [(300.0, 200.0, 0.5), (330.0, 230.0, 0.7), (270.0, 190.0, 0.4)] {
            let p = camera.backproject(&Pixel::new(x, y), z).unwrap();
            let q = camera.project(&(pose * p)).unwrap();
            let want = found.apply(x, y);
            let e = (q.x - want[0]).hypot(q.y - want[1]);
            assert!(e < 3.0, "({x}, {y}) -> ({}, {}), want {want:?}", q.x, q.y);
        }
    }

    /// `agreeing` pairs moved by one rigid motion and `scattered` pairs each moved its own way
    /// (by 3-12 cm).
    fn pairs(agreeing: usize, scattered: usize) -> Correspondences {
        let motion = Pose::new(Vector3::new(0.05, 0.01, -0.02), Vector3::new(0.0, 0.2, 0.05));
        let point = |i: usize| flowfilter_geometry::Point3::new((i % 10) as f64 * 0.01, (i / 10) as f64 * 0.01, 0.6);
        let mut c = Correspondences { source: vec![], target: vec![], weights: vec![] };
        for i in 0..agreeing + scattered {
            let p = point(i);
            let q = if i < agreeing {
                motion * p
            } else {
                let k = i as f64;
                p + Vector3::new(0.03 + 0.09 * (k * 0.7).sin().abs(), 0.05 * (k * 1.3).cos(), 0.04 * (k * 0.9).sin())
            };
            c.source.push(p);
            c.target.push(q);
            c.weights.push(1.0);
        }
        c
    }

    #[test]
    fn the_search_level_keeps_the_searched_image_small() {
        let cfg = WideBaselineConfig::default();
        assert_eq!(search_level((640, 480), &cfg), 3);
        assert_eq!(search_level((1280, 1024), &cfg), 4);
        assert_eq!(search_level((1920, 1080), &cfg), 5);
        assert_eq!(search_level((320, 240), &cfg), 3, "never below the configured level");
        assert_eq!(search_level((1280, 1024), &WideBaselineConfig { max_search_side_px: 0, ..cfg }), 3);
    }

    #[test]
    fn the_search_is_skipped_only_when_the_pyramids_flow_agrees() {
        let cfg = WideBaselineConfig::default();
        let settled = |pairs: &Correspondences, cfg: &WideBaselineConfig| settled_by(consensus(pairs, cfg), pairs, cfg);
        // 60 pairs on one motion, 20 scattered: settled.
        assert!(settled(&pairs(60, 20), &cfg).is_some());
        // Too few agree (20 < 30), or too small a share (50 of 100): split, the search runs.
        assert!(settled(&pairs(20, 0), &cfg).is_none());
        assert!(settled(&pairs(50, 50), &cfg).is_none());
        // 0 pairs asks for the search on every pair.
        assert!(settled(&pairs(60, 0), &WideBaselineConfig { settled_min_pairs: 0, ..cfg }).is_none());
    }
}
