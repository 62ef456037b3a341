//! Flow correspondences (stage 4 of the method): model pixels with depth, moved by the flow,
//! target depth interpolated at the flowed position, both back-projected: 3-D/3-D pairs.

use crate::estimator::{FlowError, FlowEstimator, WindowMatcher, forward_backward_sparse};
use crate::lk::{Gray, IDENTITY_WARP, WindowWarp};
use crate::pyramid::{ImagePyramid, PyramidCache, PyramidKey};
use flowfilter_camera::{CameraModel, RayTable};
use flowfilter_geometry::{Correspondences, DepthMap, Mask, Point3, Pose, mask_bbox};
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use std::time::Instant;

/// One view as the correspondence search sees it: grey image, depth and object mask, all on
/// the colour camera's grid.
#[derive(Debug, Clone, Copy)]
pub struct FlowView<'a> {
    /// Grey image in [0, 1].
    pub gray: &'a Gray,
    /// Depth on the colour grid (metres, 0 = none).
    pub depth: &'a DepthMap,
    /// Object mask.
    pub mask: &'a Mask,
    /// Where the view's image pyramids are kept between passes (a prepared frame's); `None`:
    /// built for each call.
    pub pyramids: Option<&'a PyramidCache>,
}

/// Flow correspondences with what it took to find them.
#[derive(Debug, Clone, Default)]
pub struct FlowPairs {
    /// Weighted 3-D pairs (`source`: model-frame points, `target`: target-frame points, both in
    /// the colour camera's frame; weights in [0, 1]).
    pub pairs: Correspondences,
    /// Pixels tracked, before any rejection.
    pub tracked: usize,
    /// Seconds spent estimating flow (forward and backward), the rest being geometry.
    pub flow_seconds: f64,
}

/// Parameters of the correspondence search.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CorrespondenceParams {
    /// Grid step of the model pixels tracked (pixels).
    pub grid_step: usize,
    /// At most this many model pixels are tracked: on a larger region (a whole frame, an
    /// object close to the camera) the grid step grows until the grid holds no more, so the
    /// flow's cost is bounded by this budget, not by the region's area. 0 = no limit.
    pub max_pixels: usize,
    /// Forward-backward consistency threshold (pixels).
    pub fb_threshold: f32,
    /// Reject pairs whose depth change is more than this many standard deviations from the
    /// mean depth change (the paper's Gaussian fit applied to the flowed depths).
    pub depth_k_sigma: f64,
    /// Flow is estimated on the crop of both images around the union of the two masks, widened
    /// by this margin (pixels): the result is the same as on the full frames when the margin
    /// covers the estimator's reach, at a fraction of the cost. 0 = no cropping.
    pub crop_margin_px: usize,
    /// Guided tracking warps each matching window by the predicted motion's local linear map
    /// (in-image rotation, scale, foreshortening of the surface under the pixel), for
    /// estimators that match windows (Lucas-Kanade). Without it a window that turns with the
    /// object matches best short of the true displacement.
    pub warp_windows: bool,
}

impl Default for CorrespondenceParams {
    fn default() -> Self {
        Self {
            grid_step: 6,
            max_pixels: 2000,
            fb_threshold: 1.0,
            depth_k_sigma: 2.5,
            crop_margin_px: 96,
            warp_windows: true,
        }
    }
}

impl CorrespondenceParams {
    /// Check ranges.
    pub fn validate(&self) -> Result<(), FlowError> {
        let ok = self.grid_step > 0 && self.fb_threshold > 0.0 && self.depth_k_sigma > 0.0;
        if ok {
            Ok(())
        } else {
            Err(FlowError::Config(format!(
                "correspondences: grid_step >= 1, fb_threshold > 0 and depth_k_sigma > 0 required, found {}, {}, {}",
                self.grid_step, self.fb_threshold, self.depth_k_sigma
            )))
        }
    }
}

/// The box `(x0, y0, x1, y1)` (exclusive ends) around both masks, widened by `margin`; the
/// whole image when `margin` is 0 or the masks are empty.
fn crop_box(a: &Mask, b: &Mask, margin: usize) -> (usize, usize, usize, usize) {
    let (w, h) = a.dims();
    if margin == 0 {
        return (0, 0, w, h);
    }
    let boxes: Vec<_> = [a, b].into_iter().filter_map(mask_bbox).collect();
    let Some(x0) = boxes.iter().map(|bb| bb.0).min() else { return (0, 0, w, h) };
    let y0 = boxes.iter().map(|bb| bb.1).min().expect("non-empty");
    let x1 = boxes.iter().map(|bb| bb.2).max().expect("non-empty") + 1;
    let y1 = boxes.iter().map(|bb| bb.3).max().expect("non-empty") + 1;
    (x0.saturating_sub(margin), y0.saturating_sub(margin), (x1 + margin).min(w), (y1 + margin).min(h))
}

/// Depth at a sub-pixel position by bilinear interpolation of four valid neighbours that agree
/// within 1 cm (never across a discontinuity).
fn depth_at(d: &DepthMap, x: f32, y: f32) -> Option<f64> {
    let (x0, y0) = (x.floor(), y.floor());
    if x0 < 0.0 || y0 < 0.0 {
        return None;
    }
    let (ix, iy) = (x0 as usize, y0 as usize);
    let z = [d.get(ix, iy)?, d.get(ix + 1, iy)?, d.get(ix, iy + 1)?, d.get(ix + 1, iy + 1)?].map(|v| *v);
    if z.iter().any(|&v| v <= 0.0)
        || z.iter().fold(f32::MIN, |a, &b| a.max(b)) - z.iter().fold(f32::MAX, |a, &b| a.min(b)) > 0.01
    {
        return None;
    }
    let (fx, fy) = (x - x0, y - y0);
    Some(f64::from((z[0] * (1.0 - fx) + z[1] * fx) * (1.0 - fy) + (z[2] * (1.0 - fx) + z[3] * fx) * fy))
}

/// The model pixels tracked: the mask's pixels with depth on a grid of `step`, the step grown
/// until at most `max_pixels` remain (0 = no limit). Rows and columns of the grid start at 0,
/// so the same frame gives the same pixels on every pair.
pub fn tracked_pixels(mask: &Mask, depth: &DepthMap, step: usize, max_pixels: usize) -> Vec<[f32; 2]> {
    let (w, h) = depth.dims();
    let on_grid = |step: usize| {
        (0..h)
            .step_by(step)
            .flat_map(move |y| (0..w).step_by(step).map(move |x| (x, y)))
            .filter(|&(x, y)| *mask.at(x, y) && *depth.at(x, y) > 0.0)
    };
    let mut step = step.max(1);
    if max_pixels > 0 {
        // The count falls with the square of the step: start near the step that fits.
        let n = on_grid(step).count();
        if n > max_pixels {
            step = ((step as f64) * (n as f64 / max_pixels as f64).sqrt()).floor().max(step as f64) as usize;
            while on_grid(step).count() > max_pixels {
                step += 1;
            }
        }
    }
    on_grid(step).map(|(x, y)| [x as f32, y as f32]).collect()
}

/// Build flow correspondences between a model view and a target view of the same colour camera:
/// track a grid of model-mask pixels with depth into the target image with `estimator`, check
/// forward-backward consistency, require the flowed pixel inside the target mask with valid
/// interpolated depth, back-project both, and reject depth-change outliers.
pub fn flow_correspondences(
    estimator: &dyn FlowEstimator,
    model: &FlowView<'_>,
    target: &FlowView<'_>,
    rays: &RayTable,
    p: &CorrespondenceParams,
) -> Result<FlowPairs, FlowError> {
    flow_correspondences_guided(estimator, model, target, rays, p, None)
}

/// A motion prediction for guided tracking: the colour camera and a pose `T` with
/// `P_target ~ T * P_model` (e.g. from a geometric registration).
#[derive(Debug, Clone, Copy)]
pub struct FlowGuide<'a> {
    /// The colour camera (projection with distortion).
    pub camera: &'a CameraModel,
    /// The predicted motion.
    pub pose: &'a Pose,
}

/// Pixels from a model pixel to the samples of its predicted warp's finite differences.
const WARP_REACH_PX: isize = 6;

/// Neighbours whose depth differs from the pixel's by more than this lie on another surface:
/// they are taken at the pixel's depth instead (metres).
const WARP_SAME_SURFACE_M: f64 = 0.01;

/// The predicted motion's local linear map at model pixel `(x, y)` (which has depth): central
/// differences of the projected, moved back-projections of the neighbours [`WARP_REACH_PX`] away
/// along x and along y (one-sided at the image border), each at its own depth when it is on the
/// same surface (so the surface's slant foreshortens the window), else at the pixel's depth.
/// The identity when the prediction leaves the image or is degenerate.
fn predicted_warp(
    guide: &FlowGuide<'_>,
    rays: &RayTable,
    depth: &DepthMap,
    mask: &Mask,
    x: usize,
    y: usize,
) -> WindowWarp {
    let z = f64::from(*depth.at(x, y));
    let (w, h) = (depth.width() as isize, depth.height() as isize);
    let moved = |px: isize, py: isize| {
        let (ux, uy) = (px as usize, py as usize);
        let d = f64::from(*depth.at(ux, uy));
        let d = if *mask.at(ux, uy) && d > 0.0 && (d - z).abs() <= WARP_SAME_SURFACE_M { d } else { z };
        rays.backproject(ux, uy, d).and_then(|p| guide.camera.project(&(guide.pose * p)))
    };
    let column = |dx: isize, dy: isize| -> Option<[f64; 2]> {
        let inside = |k: isize| {
            let (px, py) = (x as isize + k * dx, y as isize + k * dy);
            (px >= 0 && py >= 0 && px < w && py < h).then_some((px, py, k))
        };
        let (lo, hi) = (inside(-WARP_REACH_PX).or(inside(0))?, inside(WARP_REACH_PX).or(inside(0))?);
        let (a, b) = (moved(lo.0, lo.1)?, moved(hi.0, hi.1)?);
        let span = (hi.2 - lo.2) as f64;
        (span > 0.0).then(|| [(b.x - a.x) / span, (b.y - a.y) / span])
    };
    match (column(1, 0), column(0, 1)) {
        (Some(cx), Some(cy)) => {
            let m = [cx[0] as f32, cy[0] as f32, cx[1] as f32, cy[1] as f32];
            let det = m[0] * m[3] - m[1] * m[2];
            // A prediction that folds or squeezes the window by more than 4x is not trusted.
            if (0.25..=4.0).contains(&det) { m } else { IDENTITY_WARP }
        }
        _ => IDENTITY_WARP,
    }
}

/// The inverse of a (non-degenerate) window warp.
fn inverse_warp(m: &WindowWarp) -> WindowWarp {
    let det = m[0] * m[3] - m[1] * m[2];
    [m[3] / det, -m[1] / det, -m[2] / det, m[0] / det]
}

/// [`flow_correspondences`], each model pixel's track starting from the flow that `guide`
/// predicts (its back-projected point moved by the pose and projected), the backward track from
/// the forward result reversed.
pub fn flow_correspondences_guided(
    estimator: &dyn FlowEstimator,
    model: &FlowView<'_>,
    target: &FlowView<'_>,
    rays: &RayTable,
    p: &CorrespondenceParams,
    guide: Option<FlowGuide<'_>>,
) -> Result<FlowPairs, FlowError> {
    p.validate()?;
    for (which, v) in [("model", model), ("target", target)] {
        if v.depth.dims() != v.gray.dims() || v.mask.dims() != v.gray.dims() {
            return Err(FlowError::Config(format!(
                "{which} view: depth {:?} and mask {:?} must have the image's size {:?}",
                v.depth.dims(),
                v.mask.dims(),
                v.gray.dims()
            )));
        }
    }
    let (model_depth, model_mask, target_mask) = (model.depth, model.mask, target.mask);
    let pixels = tracked_pixels(model_mask, model_depth, p.grid_step, p.max_pixels);
    let t0 = Instant::now();
    // Crop both views to the masks' region (flow vectors do not depend on the origin).
    let (x0, y0, x1, y1) = crop_box(model_mask, target_mask, p.crop_margin_px);
    let (cw, ch) = (x1 - x0, y1 - y0);
    let crop = PyramidKey { x0, y0, width: cw, height: ch, levels: 0 };
    let (ma, mb) = (model_mask.crop(x0, y0, cw, ch), target_mask.crop(x0, y0, cw, ch));
    let shift = [x0 as f32, y0 as f32];
    let local: Vec<[f32; 2]> = pixels.iter().map(|q| [q[0] - shift[0], q[1] - shift[1]]).collect();
    // The guide's start for each pixel and, when windows are warped, its window's linear map.
    let guided: Option<GuidedStarts> = guide.map(|g| {
        let guesses: Vec<[f32; 2]> = pixels
            .iter()
            .map(|q| {
                let (x, y) = (q[0] as usize, q[1] as usize);
                rays.backproject(x, y, f64::from(*model_depth.at(x, y)))
                    .and_then(|a| g.camera.project(&(g.pose * a)))
                    .map_or([0.0; 2], |t| [(t.x - f64::from(q[0])) as f32, (t.y - f64::from(q[1])) as f32])
            })
            .collect();
        let warps: Option<Vec<WindowWarp>> = p.warp_windows.then(|| {
            pixels
                .iter()
                .map(|q| predicted_warp(&g, rays, model_depth, model_mask, q[0] as usize, q[1] as usize))
                .collect()
        });
        GuidedStarts { guesses, warps }
    });
    let tracker = CropTracker::new(estimator, (model, target), crop, (&ma, &mb));
    let (guesses, warps) = guided.as_ref().map_or((None, None), |g| (Some(g.guesses.as_slice()), g.warps.as_deref()));
    let forward = tracker.track(Direction::Forward, &local, guesses, warps)?;
    // The backward track starts from the forward result reversed, through the inverse warps.
    let back: Option<Vec<[f32; 2]>> =
        guesses.map(|gs| forward.iter().zip(gs).map(|(f, g)| f.map_or([-g[0], -g[1]], |f| [-f[0], -f[1]])).collect());
    let back_warps: Option<Vec<WindowWarp>> = warps.map(|w| w.iter().map(inverse_warp).collect());
    let moved_local: Vec<[f32; 2]> =
        local.iter().zip(&forward).map(|(q, f)| f.map_or(*q, |f| [q[0] + f[0], q[1] + f[1]])).collect();
    let backward = tracker.track(Direction::Backward, &moved_local, back.as_deref(), back_warps.as_deref())?;
    let moved: Vec<[f32; 2]> = moved_local.iter().map(|q| [q[0] + shift[0], q[1] + shift[1]]).collect();
    let flow_seconds = t0.elapsed().as_secs_f64();
    let consistent = forward_backward_sparse(&forward, &backward, p.fb_threshold);
    let mut pairs = lift_matches(model, target, rays, &pixels, &moved, &consistent, p.depth_k_sigma);
    pairs.tracked = pixels.len();
    pairs.flow_seconds = flow_seconds;
    Ok(pairs)
}

/// Where a guide starts each tracked pixel, and its window's linear map when windows are warped.
struct GuidedStarts {
    guesses: Vec<[f32; 2]>,
    warps: Option<Vec<WindowWarp>>,
}

/// Which way a track runs: the model's pixels into the target, or back.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Direction {
    Forward,
    Backward,
}

/// The two views cut to one crop, tracked either way: on pyramids built once for both
/// directions (and kept in the views' caches, for the pair's other passes) when the estimator
/// matches windows, else on the cropped images.
struct CropTracker<'a> {
    estimator: &'a dyn FlowEstimator,
    images: CropImages<'a>,
    masks: (&'a Mask, &'a Mask),
}

/// The crops' pyramids with the window matcher that reads them, or the crops themselves.
enum CropImages<'a> {
    Pyramids(&'a dyn WindowMatcher, Arc<ImagePyramid>, Arc<ImagePyramid>),
    Crops(Gray, Gray),
}

impl<'a> CropTracker<'a> {
    fn new(
        estimator: &'a dyn FlowEstimator,
        (model, target): (&FlowView<'_>, &FlowView<'_>),
        crop: PyramidKey,
        masks: (&'a Mask, &'a Mask),
    ) -> Self {
        let cut = |view: &FlowView<'_>| view.gray.crop(crop.x0, crop.y0, crop.width, crop.height);
        let images = match estimator.window_matcher() {
            Some(m) => {
                let key = PyramidKey { levels: m.pyramid_levels(), ..crop };
                let pyramid = |view: &FlowView<'_>| {
                    let build = || ImagePyramid::new(cut(view), key.levels);
                    match view.pyramids {
                        Some(cache) => cache.pyramid(key, build),
                        None => Arc::new(build()),
                    }
                };
                let (a, b) = rayon::join(|| pyramid(model), || pyramid(target));
                CropImages::Pyramids(m, a, b)
            }
            None => CropImages::Crops(cut(model), cut(target)),
        };
        Self { estimator, images, masks }
    }

    /// The tracks of `points` (crop coordinates) in `direction`, each from its guess when given
    /// and with its window's warp when given (a window matcher; others take the guesses alone).
    fn track(
        &self,
        direction: Direction,
        points: &[[f32; 2]],
        guesses: Option<&[[f32; 2]]>,
        warps: Option<&[WindowWarp]>,
    ) -> Result<Vec<Option<[f32; 2]>>, FlowError> {
        let mask = match direction {
            Direction::Forward => self.masks.0,
            Direction::Backward => self.masks.1,
        };
        match &self.images {
            CropImages::Pyramids(m, a, b) => {
                let (from, to) = if direction == Direction::Forward { (a, b) } else { (b, a) };
                m.sparse_in(from, to, points, guesses, warps, Some(mask))
            }
            CropImages::Crops(a, b) => {
                let (from, to) = if direction == Direction::Forward { (a, b) } else { (b, a) };
                match guesses {
                    Some(g) => self.estimator.sparse_guided(from, to, points, g, Some(mask)),
                    None => self.estimator.sparse(from, to, points, Some(mask)),
                }
            }
        }
    }
}

/// 3-D pairs from pixel matches: each kept model pixel (with depth) back-projected, its match
/// in the target (inside the target's mask, with interpolated depth) back-projected along the
/// interpolated ray, and depth-change outliers weighted 0 under a Gaussian fit of the depth
/// changes (the paper's eqs. 9-11 on `Z_f`, `k_sigma` standard deviations).
pub(crate) fn lift_matches(
    model: &FlowView<'_>,
    target: &FlowView<'_>,
    rays: &RayTable,
    pixels: &[[f32; 2]],
    moved: &[[f32; 2]],
    keep: &[bool],
    k_sigma: f64,
) -> FlowPairs {
    let (model_depth, target_depth, target_mask) = (model.depth, target.depth, target.mask);
    let mut pairs = FlowPairs::default();
    let mut dz = vec![];
    for i in 0..pixels.len() {
        if !keep[i] {
            continue;
        }
        let q = moved[i];
        let (qx, qy) = (q[0].round(), q[1].round());
        if qx < 0.0 || qy < 0.0 || !target_mask.get(qx as usize, qy as usize).copied().unwrap_or(false) {
            continue;
        }
        let Some(zt) = depth_at(target_depth, q[0], q[1]) else { continue };
        let (x, y) = (pixels[i][0] as usize, pixels[i][1] as usize);
        let Some(a) = rays.backproject(x, y, f64::from(*model_depth.at(x, y))) else { continue };
        // Target ray at the sub-pixel position: interpolate the rays of the neighbours.
        let (ix, iy) = (q[0].floor() as usize, q[1].floor() as usize);
        let (Some(r0), Some(r1), Some(r2)) = (rays.ray(ix, iy), rays.ray(ix + 1, iy), rays.ray(ix, iy + 1)) else {
            continue;
        };
        let (fx, fy) = (q[0] - ix as f32, q[1] - iy as f32);
        let rx = r0[0] + (r1[0] - r0[0]) * fx;
        let ry = r0[1] + (r2[1] - r0[1]) * fy;
        let t = Point3::new(f64::from(rx) * zt, f64::from(ry) * zt, zt);
        dz.push(t.z - a.z);
        pairs.pairs.source.push(a);
        pairs.pairs.target.push(t);
    }
    // Depth-change outliers under a Gaussian fit of the flowed depth changes (eqs. 9-11 on Z_f).
    if dz.len() >= 3 {
        let n = dz.len() as f64;
        let mean = dz.iter().sum::<f64>() / n;
        let sd = (dz.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / n).sqrt().max(1e-4);
        pairs.pairs.weights = dz.iter().map(|d| if (d - mean).abs() <= k_sigma * sd { 1.0 } else { 0.0 }).collect();
    } else {
        pairs.pairs.weights = vec![1.0; dz.len()];
    }
    pairs
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `w x h` frame whose mask is a disc of radius `r` px with depth everywhere but every
    /// seventh column (a sensor's holes).
    fn disc(w: usize, h: usize, r: f64) -> (Mask, DepthMap) {
        let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
        let mask = Mask::from_fn(w, h, |x, y| (x as f64 - cx).hypot(y as f64 - cy) < r);
        let depth = DepthMap::from_fn(w, h, |x, _| if x % 7 == 3 { 0.0 } else { 0.6 });
        (mask, depth)
    }

    #[test]
    fn the_tracked_pixels_are_bounded_by_the_budget_and_spread_over_the_region() {
        let (mask, depth) = disc(640, 480, 230.0);
        let all = tracked_pixels(&mask, &depth, 6, 0);
        assert!(all.len() > 3500, "{}", all.len());
        for budget in [2000, 500, 50] {
            let kept = tracked_pixels(&mask, &depth, 6, budget);
            assert!(kept.len() <= budget && kept.len() * 2 > budget, "{budget}: {}", kept.len());
            // Spread: the kept pixels span most of the disc's 460-px diameter both ways.
            let span = |k: usize| {
                let (lo, hi) = kept.iter().fold((f32::MAX, f32::MIN), |(lo, hi), q| (lo.min(q[k]), hi.max(q[k])));
                hi - lo
            };
            assert!(span(0) > 320.0 && span(1) > 320.0, "{budget}: spans {} x {}", span(0), span(1));
            assert!(
                kept.iter()
                    .all(|q| *mask.at(q[0] as usize, q[1] as usize) && *depth.at(q[0] as usize, q[1] as usize) > 0.0)
            );
        }
        // A region within the budget is tracked on the configured grid.
        let (small, depth) = disc(640, 480, 60.0);
        assert_eq!(tracked_pixels(&small, &depth, 6, 2000), tracked_pixels(&small, &depth, 6, 0));
    }
}
