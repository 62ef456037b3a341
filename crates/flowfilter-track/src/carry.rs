//! The object's mask carried into a new frame by a pose and refined on that frame's depth.

use flowfilter_geometry::{Mask, Pose, mask_bbox};
use flowfilter_pipeline::PreparedFrame;
use nalgebra::Point2;
use rayon::prelude::*;

/// Rows of the carried mask's depth buffer filled per parallel task.
const SPLAT_BAND_ROWS: usize = 32;

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
    // The nearest splat's depth per covered pixel, by bands of rows side by side (each band
    // takes the splats that reach it; a minimum, so the same in any order).
    let mut depth_at: Vec<f32> = vec![f32::INFINITY; bw * (by1 - by0 + 1) as usize];
    depth_at.par_chunks_mut(bw * SPLAT_BAND_ROWS).enumerate().for_each(|(band, rows)| {
        let top = by0 + (band * SPLAT_BAND_ROWS) as i64;
        let bottom = top + (rows.len() / bw) as i64 - 1;
        for &(cx, cy, z) in splats.iter().filter(|s| s.1 + r >= top && s.1 - r <= bottom) {
            for v in (cy - r).max(top)..=(cy + r).min(bottom) {
                for u in (cx - r).max(bx0)..=(cx + r).min(bx1) {
                    let i = (v - top) as usize * bw + (u - bx0) as usize;
                    rows[i] = rows[i].min(z);
                }
            }
        }
    });
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
/// each one's rounded pixel and depth, in row order (rows side by side: the back-projection
/// through the lens model is most of a frame's carrying).
fn moved_pixels(keyframe: &PreparedFrame, pose: &Pose, target: &PreparedFrame) -> Vec<(i64, i64, f32)> {
    let Some((x0, y0, x1, y1)) = mask_bbox(&keyframe.mask) else { return vec![] };
    let moved = |x: usize, y: usize| -> Option<(i64, i64, f32)> {
        if !keyframe.mask.get(x, y).copied().unwrap_or(false) {
            return None;
        }
        let z = keyframe.depth.get(x, y).copied().unwrap_or(0.0);
        if !(z.is_finite() && z > 0.0) {
            return None;
        }
        let p = keyframe.sensor.color.backproject(&Point2::new(x as f64, y as f64), f64::from(z))?;
        let q = pose * p;
        let px = target.sensor.color.project(&q)?;
        Some((px.x.round() as i64, px.y.round() as i64, q.z as f32))
    };
    (y0..=y1).into_par_iter().flat_map_iter(|y| (x0..=x1).filter_map(move |x| moved(x, y))).collect()
}
