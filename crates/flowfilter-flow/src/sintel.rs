//! Loading MPI-Sintel pairs (Butler et al., ECCV 2012) in the layout of the project's shared data:
//! `{pass}/{scene}/frame_0002.png`, `frame_0003.png`, `gt/frame_0002.flo`,
//! `gt/occlusions_0002.png` and `gt/invalid_0002.png` (white = excluded).

use crate::{FlowField, flo};
use flowfilter_geometry::Mask;
use image::RgbImage;
use std::path::Path;

/// One Sintel pair with its ground truth.
pub struct SintelPair {
    /// First frame.
    pub from: RgbImage,
    /// Second frame.
    pub to: RgbImage,
    /// Ground-truth forward flow.
    pub flow: FlowField,
    /// Pixels counted by the non-occluded EPE (neither occluded nor invalid).
    pub non_occluded: Mask,
}

fn mask_of(path: &Path) -> Result<Mask, String> {
    let img = image::open(path).map_err(|e| format!("{}: {e}", path.display()))?.to_luma8();
    Ok(Mask::from_fn(img.width() as usize, img.height() as usize, |x, y| img.get_pixel(x as u32, y as u32).0[0] < 128))
}

/// Load the pair of `dir` (e.g. `.../sintel/clean/easy`).
pub fn load(dir: &Path) -> Result<SintelPair, String> {
    let open = |p: &Path| image::open(p).map(|i| i.to_rgb8()).map_err(|e| format!("{}: {e}", p.display()));
    let from = open(&dir.join("frame_0002.png"))?;
    let to = open(&dir.join("frame_0003.png"))?;
    let flow = flo::read(&dir.join("gt/frame_0002.flo")).map_err(|e| e.to_string())?;
    let occ = mask_of(&dir.join("gt/occlusions_0002.png"))?;
    let inv = mask_of(&dir.join("gt/invalid_0002.png"))?;
    let non_occluded = Mask::from_vec(
        occ.width(),
        occ.height(),
        occ.as_slice().iter().zip(inv.as_slice()).map(|(a, b)| *a && *b).collect(),
    )
    .expect("same size");
    Ok(SintelPair { from, to, flow, non_occluded })
}
