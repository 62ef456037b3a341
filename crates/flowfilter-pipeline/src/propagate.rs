//! A target frame without an object mask gets the model's: the model's mask moved to where the
//! coarse search ([`flowfilter_flow::coarse_search`]) finds the region in the target image (or
//! left where it is when the search finds nothing), and the target's cloud cut to it.

use crate::stages::PreparedFrame;
use flowfilter_flow::coarse_search::CoarseMatch;
use flowfilter_geometry::Mask;

/// `target` with the model's mask propagated into it: moved by where the coarse search
/// `found` the model's region, else left in place (see the module documentation).
pub(crate) fn with_propagated_mask(
    model: &PreparedFrame,
    target: &PreparedFrame,
    found: Option<&CoarseMatch>,
) -> PreparedFrame {
    let mask = found.map_or_else(|| model.mask.clone(), |m| moved_mask(&model.mask, m));
    target.with_mask(mask)
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
