//! The object's mask carried into a new frame by a pose and refined on that frame's depth.

use flowfilter_geometry::{Mask, Pose, mask_bbox};
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
    let splats = moved_pixels(keyframe, pose, target);
    let r = splat_px as i64;
    // The pixels the splats cover, clamped to the image: the expected depth is kept on that box
    // only.
    let covered = splats.iter().fold(None, |b: Option<(i64, i64, i64, i64)>, &(cx, cy, _)| {
        let (x0, y0, x1, y1) =
            ((cx - r).max(0), (cy - r).max(0), (cx + r).min(w as i64 - 1), (cy + r).min(h as i64 - 1));
        if x0 > x1 || y0 > y1 {
            return b;
        }
        Some(b.map_or((x0, y0, x1, y1), |b| (b.0.min(x0), b.1.min(y0), b.2.max(x1), b.3.max(y1))))
    });
    let Some((bx0, by0, bx1, by1)) = covered else { return Mask::filled(w, h, false) };
    let bw = (bx1 - bx0 + 1) as usize;
    let mut depth_at: Vec<f32> = vec![f32::INFINITY; bw * (by1 - by0 + 1) as usize];
    for &(cx, cy, z) in &splats {
        for v in (cy - r).max(by0)..=(cy + r).min(by1) {
            for u in (cx - r).max(bx0)..=(cx + r).min(bx1) {
                let i = (v - by0) as usize * bw + (u - bx0) as usize;
                depth_at[i] = depth_at[i].min(z);
            }
        }
    }
    Mask::from_fn(w, h, |x, y| {
        let (x, y) = (x as i64, y as i64);
        if x < bx0 || x > bx1 || y < by0 || y > by1 {
            return false;
        }
        let expected = depth_at[(y - by0) as usize * bw + (x - bx0) as usize];
        if !expected.is_finite() {
            return false;
        }
        let seen = target.depth.get(x as usize, y as usize).copied().unwrap_or(0.0);
        !(seen.is_finite() && seen > 0.0) || f64::from((seen - expected).abs()) <= tolerance_m
    })
}

/// `keyframe`'s object pixels that have depth, moved by `pose` and projected into `target`:
/// each one's rounded pixel and depth.
fn moved_pixels(keyframe: &PreparedFrame, pose: &Pose, target: &PreparedFrame) -> Vec<(i64, i64, f32)> {
    let Some((x0, y0, x1, y1)) = mask_bbox(&keyframe.mask) else { return vec![] };
    let mut out = vec![];
    for y in y0..=y1 {
        for x in x0..=x1 {
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
            if let Some(px) = target.sensor.color.project(&q) {
                out.push((px.x.round() as i64, px.y.round() as i64, q.z as f32));
            }
        }
    }
    out
}
