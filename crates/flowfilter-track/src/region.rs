//! The part of the image a stream's frame is prepared on: where the object is predicted to be,
//! with a margin, so that a small object's frame costs its region's depth stage, not the whole
//! image's.

use crate::boxed::PixelBox;
use flowfilter_geometry::{Mask, Pose, mask_bbox};
use flowfilter_pipeline::PreparedFrame;

/// A predicted region larger than this fraction of the image is not worth preparing apart: the
/// frame is prepared whole.
const MAX_IMAGE_FRACTION: f64 = 0.4;

/// The carried mask must keep this many pixels from the region's edges for the region's
/// preparation to stand (the depth stage's filters and hole filling read a few pixels around each
/// one; nearer the edge the frame is prepared whole).
pub(crate) const EDGE_PX: usize = 8;

/// Where `frame`'s object (its registration cloud) is `steps` frames after `frame`, moved by
/// `velocity` each frame: the box of its pixels at every step from 0 to `steps` (the path it
/// sweeps, so that a motion that slows down stays inside), widened on each side by `margin`
/// times the object's larger side in pixels plus the pixels one step moves it (the
/// prediction's error grows with the speed). `None` when the object has no projected point
/// or the region would cover most of the image (prepared whole).
pub(crate) fn predicted(frame: &PreparedFrame, velocity: &Pose, steps: u32, margin: f64) -> Option<PixelBox> {
    let camera = &frame.sensor.color;
    let (w, h) = frame.gray.dims();
    let mut motion = Pose::identity();
    let mut boxes = vec![];
    for _ in 0..=steps {
        boxes.push(pixel_box(frame.cloud.points.iter().filter_map(|p| camera.project(&(motion * p))))?);
        motion = velocity * motion;
    }
    let (first, one_step) = (boxes[0], boxes.get(1).copied().unwrap_or(boxes[0]));
    let side = (first[2] - first[0]).max(first[3] - first[1]);
    let speed = (0..4).map(|i| (one_step[i] - first[i]).abs()).fold(0.0, f64::max);
    let pad = margin * side + speed;
    let swept = boxes.iter().fold(first, |a, b| [a[0].min(b[0]), a[1].min(b[1]), a[2].max(b[2]), a[3].max(b[3])]);
    let clamp = |v: f64, hi: usize| v.clamp(0.0, hi as f64) as usize;
    let (x0, y0) = (clamp((swept[0] - pad).floor(), w), clamp((swept[1] - pad).floor(), h));
    let (x1, y1) = (clamp((swept[2] + pad).ceil() + 1.0, w), clamp((swept[3] + pad).ceil() + 1.0, h));
    let region = PixelBox { x: x0, y: y0, width: x1 - x0, height: y1 - y0 };
    let area = region.width * region.height;
    (area > 0 && (area as f64) <= MAX_IMAGE_FRACTION * (w * h) as f64).then_some(region)
}

/// Whether every pixel of `mask` lies inside `region`, [`EDGE_PX`] from its edges (or the
/// image's edges, where the region reaches them).
pub(crate) fn holds(region: &PixelBox, mask: &Mask) -> bool {
    let (w, h) = mask.dims();
    let Some((bx0, by0, bx1, by1)) = mask_bbox(mask) else { return true };
    let inner = |lo: usize, len: usize, size: usize, a: usize, b: usize| {
        let hi = lo + len;
        (lo == 0 || a >= lo + EDGE_PX) && (hi == size || b + EDGE_PX < hi)
    };
    inner(region.x, region.width, w, bx0, bx1) && inner(region.y, region.height, h, by0, by1)
}

/// The bounding box `[x0, y0, x1, y1]` of pixel positions, `None` without any.
fn pixel_box(points: impl Iterator<Item = nalgebra::Point2<f64>>) -> Option<[f64; 4]> {
    points.fold(None, |b, p| {
        Some(match b {
            None => [p.x, p.y, p.x, p.y],
            Some([x0, y0, x1, y1]) => [p.x.min(x0), p.y.min(y0), p.x.max(x1), p.y.max(y1)],
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mask_with(w: usize, h: usize, on: impl Fn(usize, usize) -> bool) -> Mask {
        Mask::from_fn(w, h, on)
    }

    #[test]
    fn a_mask_near_the_regions_edge_is_not_held_unless_the_edge_is_the_images() {
        let r = PixelBox { x: 10, y: 0, width: 40, height: 40 };
        let (w, h) = (100, 40);
        assert!(holds(&r, &mask_with(w, h, |x, y| (20..40).contains(&x) && (0..30).contains(&y))));
        // 5 pixels from the left edge: too near.
        assert!(!holds(&r, &mask_with(w, h, |x, y| (15..40).contains(&x) && (5..30).contains(&y))));
        // Beyond the right edge.
        assert!(!holds(&r, &mask_with(w, h, |x, y| (20..60).contains(&x) && (5..30).contains(&y))));
        // Touching the image's bottom edge, which is the region's: held.
        assert!(holds(&r, &mask_with(w, h, |x, y| (20..40).contains(&x) && (30..40).contains(&y))));
        assert!(holds(&r, &mask_with(w, h, |_, _| false)));
    }

    #[test]
    fn the_region_mask_is_its_rectangle() {
        let r = PixelBox { x: 2, y: 1, width: 2, height: 2 };
        let m = r.mask((6, 4));
        let on: Vec<(usize, usize)> =
            (0..4).flat_map(|y| (0..6).map(move |x| (x, y))).filter(|&(x, y)| m.get(x, y) == Some(&true)).collect();
        assert_eq!(on, vec![(2, 1), (3, 1), (2, 2), (3, 2)]);
    }
}
