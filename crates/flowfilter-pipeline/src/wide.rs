//! The wide-baseline guide: where the model's region went in the target image
//! ([`flowfilter_flow::coarse_search`]) as a predicted motion that guided tracking starts from.

use crate::config::WideBaselineConfig;
use crate::stages::PreparedFrame;
use flowfilter_camera::{CameraModel, Pixel};
use flowfilter_flow::coarse_search::{CoarseMatch, coarse_search};
use flowfilter_geometry::Pose;
use nalgebra::{Rotation3, Translation3, Unit, UnitQuaternion, Vector3};

/// The motion the coarse search predicts for the model's region, when the search finds the
/// region and it moved at least `min_motion_px` on average.
pub(crate) fn wide_guide(model: &PreparedFrame, target: &PreparedFrame, cfg: &WideBaselineConfig) -> Option<Pose> {
    if !cfg.enabled {
        return None;
    }
    let found = coarse_search(&model.gray, &model.mask, &target.gray, &cfg.search)?;
    (mean_motion_px(&found, model) >= cfg.min_motion_px).then_some(())?;
    camera_turn(&model.sensor.color, &found)
}

/// The mean displacement of the model's mask pixels (every 8th row and column) under the match.
fn mean_motion_px(found: &CoarseMatch, model: &PreparedFrame) -> f64 {
    let (w, h) = model.mask.dims();
    let moved: Vec<f64> = (0..h)
        .step_by(8)
        .flat_map(|y| (0..w).step_by(8).map(move |x| (x, y)))
        .filter(|&(x, y)| *model.mask.at(x, y))
        .map(|(x, y)| {
            let to = found.apply(x as f64, y as f64);
            (to[0] - x as f64).hypot(to[1] - y as f64)
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
}
