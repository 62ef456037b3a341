//! The object's mask carried into a new frame by a pose and refined on that frame's depth.

use flowfilter_geometry::{Mask, Pose};
use flowfilter_pipeline::PreparedFrame;
use nalgebra::Point2;

/// The object's mask in `target`: `keyframe`'s object pixels that have depth, moved by `pose`
/// (`target ~ pose * keyframe`) and projected, each covering `splat_px` pixels around it (the
/// depth's holes and the pixel grid leave gaps otherwise); then refined on the target's depth:
/// a covered pixel whose depth is more than `tolerance_m` nearer or farther than the moved
/// point is dropped (an occluder in front, background behind). Covered pixels without depth
/// stay (sparse sensors).
pub fn carry_mask(
    keyframe: &PreparedFrame,
    pose: &Pose,
    target: &PreparedFrame,
    splat_px: usize,
    tolerance_m: f64,
) -> Mask {
    let (w, h) = target.depth.dims();
    let mut depth_at: Vec<f32> = vec![f32::INFINITY; w * h];
    let (kw, kh) = keyframe.mask.dims();
    for y in 0..kh {
        for x in 0..kw {
            if !keyframe.mask.get(x, y).copied().unwrap_or(false) {
                continue;
            }
            let z = keyframe.depth.get(x, y).copied().unwrap_or(0.0);
            if !(z.is_finite() && z > 0.0) {
                continue;
            }
            let Some(p) = keyframe.sensor.color.backproject(&Point2::new(x as f64, y as f64), f64::from(z)) else {
                continue;
            };
            let q = pose * p;
            let Some(px) = target.sensor.color.project(&q) else { continue };
            let (cx, cy) = (px.x.round() as i64, px.y.round() as i64);
            let r = splat_px as i64;
            for v in (cy - r).max(0)..=(cy + r).min(h as i64 - 1) {
                for u in (cx - r).max(0)..=(cx + r).min(w as i64 - 1) {
                    let i = v as usize * w + u as usize;
                    depth_at[i] = depth_at[i].min(q.z as f32);
                }
            }
        }
    }
    Mask::from_fn(w, h, |x, y| {
        let expected = depth_at[y * w + x];
        if !expected.is_finite() {
            return false;
        }
        let seen = target.depth.get(x, y).copied().unwrap_or(0.0);
        !(seen.is_finite() && seen > 0.0) || f64::from((seen - expected).abs()) <= tolerance_m
    })
}

/// Pixels of a mask.
pub fn area(mask: &Mask) -> usize {
    mask.as_slice().iter().filter(|m| **m).count()
}
