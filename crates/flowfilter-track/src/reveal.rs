//! The carried mask grown onto the object's surface that turns into view.
//!
//! A mask carried from a reference frame holds only what the reference saw of the object: a
//! face turning into view is never taken in (a box seen level with its turntable keeps two
//! thirds of its pixels at 90 deg, then less). A pixel next to the mask joins it when its depth
//! continues the mask's and the reference frame saw its surface at that depth, off the mask,
//! edge-on (more than [`RevealParams::grazing_deg`] from its ray), and the surface has turned
//! towards the camera since: a convex object's side turning into view. A surface the reference
//! saw face-on off the mask (the background beside the object, a static scene around a
//! region), or one that keeps its angle to the camera (a turntable's top, turning in its own
//! plane), stays out; so does one the reference did not see at all (hidden, out of view, or
//! without depth there), which may as well be the background the object uncovers.

use flowfilter_geometry::{Mask, Pose, mask_bbox};
use flowfilter_pipeline::PreparedFrame;
use nalgebra::{Point2, Point3, Vector3};
use std::collections::VecDeque;

/// How the growth reads depth.
#[derive(Debug, Clone, Copy)]
pub struct RevealParams {
    /// Neighbouring pixels whose depths differ by more than this (metres) are not joined.
    pub step_m: f64,
    /// A point within this of the reference's depth along its ray (metres) was seen there.
    pub seen_m: f64,
    /// A surface seen at more than this angle from the reference camera's ray (degrees) was
    /// seen edge-on...
    pub grazing_deg: f64,
    /// ... and has turned into view when it faces the target camera by at least this much more
    /// (degrees of the angle's cosine, about the turn at grazing angles).
    pub min_turn_deg: f64,
    /// Half the span of the depth differences a pixel's surface normal is taken from (pixels).
    pub normal_span_px: usize,
}

impl Default for RevealParams {
    fn default() -> Self {
        Self { step_m: 0.01, seen_m: 0.006, grazing_deg: 75.0, min_turn_deg: 1.5, normal_span_px: 4 }
    }
}

/// `mask` (the object's mask carried into `target` from `reference` by `motion`,
/// `target ~ motion * reference`) grown over the target's depth onto the object's surface that
/// turned into view (see the module's documentation); at most `mask`'s own area of pixels is
/// added. Returns the pixels added.
pub fn grow_revealed(
    reference: &PreparedFrame,
    motion: &Pose,
    target: &PreparedFrame,
    mask: &mut Mask,
    params: &RevealParams,
) -> usize {
    let (w, h) = mask.dims();
    let budget = mask.count();
    let Some((x0, y0, x1, y1)) = mask_bbox(mask) else { return 0 };
    let back = motion.inverse();
    let point = |x: usize, y: usize| {
        let z = target.depth.get(x, y).copied().filter(|z| z.is_finite() && *z > 0.0)?;
        target.sensor.color.backproject(&Point2::new(x as f64, y as f64), f64::from(z))
    };
    // The target's surface normal at (x, y), from its depth's differences, facing the camera.
    let normal = |x: usize, y: usize, q: &Point3<f64>| {
        let r = params.normal_span_px;
        let (left, right) = (point(x.checked_sub(r)?, y)?, point((x + r).min(w - 1), y)?);
        let (up, down) = (point(x, y.checked_sub(r)?)?, point(x, (y + r).min(h - 1))?);
        let n = (right - left).cross(&(down - up)).try_normalize(1e-12)?;
        Some(if n.dot(&q.coords) > 0.0 { -n } else { n })
    };
    let grazing_cos = params.grazing_deg.to_radians().cos();
    let turned = params.min_turn_deg.to_radians();
    let joins = |x: usize, y: usize, q: &Point3<f64>| {
        let p = back * q;
        // Seen off the object's mask, at its depth: joins only if seen edge-on, turned since.
        seen_off_mask(reference, &p, params.seen_m)
            && normal(x, y, q).is_some_and(|n| {
                let facing_target = -n.dot(&q.coords.normalize());
                let n: Vector3<f64> = back.rotation * n;
                let facing_reference = -n.dot(&p.coords.normalize());
                facing_reference < grazing_cos && facing_target > facing_reference + turned
            })
    };
    let mut queue: VecDeque<(usize, usize)> = VecDeque::new();
    for y in y0..=y1 {
        for x in x0..=x1 {
            if *mask.at(x, y) && neighbours(x, y, w, h).any(|(u, v)| !*mask.at(u, v)) {
                queue.push_back((x, y));
            }
        }
    }
    let mut added = 0;
    let mut tried = Mask::filled(w, h, false);
    while let Some((x, y)) = queue.pop_front() {
        let Some(a) = point(x, y) else { continue };
        for (u, v) in neighbours(x, y, w, h) {
            if added >= budget || *mask.at(u, v) || *tried.at(u, v) {
                continue;
            }
            *tried.at_mut(u, v) = true;
            let Some(b) = point(u, v) else { continue };
            if (b.z - a.z).abs() > params.step_m || !joins(u, v, &b) {
                continue;
            }
            *mask.at_mut(u, v) = true;
            added += 1;
            queue.push_back((u, v));
        }
    }
    added
}

/// Whether `reference` saw point `p` (its camera frame) off its mask, at its depth (to `seen_m`
/// metres along the ray); not when it was hidden, in front of what the reference saw, out of
/// view, without depth there, or on the mask (the carried mask's own).
fn seen_off_mask(reference: &PreparedFrame, p: &Point3<f64>, seen_m: f64) -> bool {
    let Some(px) = reference.sensor.color.project(p) else { return false };
    let (rx, ry) = (px.x.round(), px.y.round());
    if rx < 0.0 || ry < 0.0 {
        return false;
    }
    let (rx, ry) = (rx as usize, ry as usize);
    match reference.depth.get(rx, ry) {
        Some(&z) if z.is_finite() && z > 0.0 => (p.z - f64::from(z)).abs() <= seen_m && !*reference.mask.at(rx, ry),
        _ => false,
    }
}

/// The 4-neighbours of `(x, y)` inside a `w` x `h` image.
fn neighbours(x: usize, y: usize, w: usize, h: usize) -> impl Iterator<Item = (usize, usize)> {
    let (x, y) = (x as i64, y as i64);
    [(x - 1, y), (x + 1, y), (x, y - 1), (x, y + 1)]
        .into_iter()
        .filter(move |&(u, v)| u >= 0 && v >= 0 && u < w as i64 && v < h as i64)
        .map(|(u, v)| (u as usize, v as usize))
}
