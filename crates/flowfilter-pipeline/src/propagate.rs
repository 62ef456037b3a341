//! A target frame without an object mask gets the model's: the model's mask moved to where the
//! coarse search ([`flowfilter_flow::coarse_search`]) finds the region in the target image (or
//! left where it is when the search finds nothing), and the target's cloud cut to it. A moved
//! mask that holds less than a tenth of the model's points (the region placed on a depth hole,
//! or mostly out of the image) gives way to the mask left in place when that holds more.

use crate::stages::PreparedFrame;
use flowfilter_flow::coarse_search::CoarseMatch;
use flowfilter_geometry::Mask;

/// `target` with the model's mask propagated into it: moved by where the coarse search
/// `found` the model's region, else left in place (see the module documentation); and whether
/// the moved mask was kept.
pub(crate) fn with_propagated_mask(
    model: &PreparedFrame,
    target: &PreparedFrame,
    found: Option<&CoarseMatch>,
) -> (PreparedFrame, bool) {
    let in_place = || target.with_mask(model.mask.clone());
    let Some(found) = found else { return (in_place(), false) };
    let moved = target.with_mask(moved_mask(&model.mask, found));
    if moved.cloud.len() * 10 >= model.cloud.len() {
        return (moved, true);
    }
    let kept = in_place();
    if kept.cloud.len() > moved.cloud.len() { (kept, false) } else { (moved, true) }
}

/// `mask` moved by the match: a target pixel is in it when the pixel it came from is.
fn moved_mask(mask: &Mask, found: &CoarseMatch) -> Mask {
    let (w, h) = mask.dims();
    Mask::from_fn(w, h, |x, y| {
        let [u, v] = found.apply_inverse(x as f64, y as f64);
        let (u, v) = (u.round(), v.round());
        u >= 0.0 && v >= 0.0 && mask.get(u as usize, v as usize).copied().unwrap_or(false)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{CameraFile, Pipeline, PipelineConfig, RawDepth, RgbdFrame};

    /// A 160x120 textured wall 0.8 m away whose right quarter has no depth.
    fn frame(mask: Option<Mask>) -> PreparedFrame {
        let camera = CameraFile::from_json_str(
            r#"{"K": [200, 0, 79.5, 0, 200, 59.5, 0, 0, 1], "depth_unit_m": 0.001}"#,
            "camera.json",
        )
        .unwrap();
        let color = image::RgbImage::from_fn(160, 120, |x, y| {
            let v = ((x * 37 + y * 91) % 251) as u8;
            image::Rgb([v, v / 2, 255 - v])
        });
        let depth = RawDepth::from_fn(160, 120, |x, _| if x < 120 { 800 } else { 0 });
        let frame = RgbdFrame::from_images("f", color, depth, mask, &camera).unwrap();
        Pipeline::from_config(PipelineConfig::default()).unwrap().prepare(&frame).unwrap()
    }

    #[test]
    fn a_mask_moved_onto_no_depth_gives_way_to_the_mask_in_place() {
        let model = frame(Some(Mask::from_fn(160, 120, |x, y| (20..60).contains(&x) && (30..70).contains(&y))));
        let target = frame(None);
        let onto_the_hole = CoarseMatch { centre: [40.0, 50.0], shift: [100.0, 0.0], turn_rad: 0.0, score: 0.9 };
        let (kept, placed) = with_propagated_mask(&model, &target, Some(&onto_the_hole));
        assert!(!placed);
        assert_eq!(kept.cloud.len(), model.cloud.len());
        let nearby = CoarseMatch { shift: [10.0, 5.0], ..onto_the_hole };
        let (moved, placed) = with_propagated_mask(&model, &target, Some(&nearby));
        assert!(placed);
        assert!(moved.mask.get(65, 70 - 1).copied().unwrap_or(false));
    }
}
