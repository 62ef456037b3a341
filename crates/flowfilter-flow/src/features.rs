//! Wide-baseline feature matches: corners of the model's object matched to corners of the
//! target's by their binary descriptors, wherever they moved in the image.
//!
//! Lucas-Kanade's pyramid reaches about 70 px; a camera turned 12-30 deg moves an object 100-250
//! px, and a guided search needs a guess within its reach. Descriptor matches need none: FAST-9
//! corners (imageproc) in the model's mask and in the target's, each described by a 256-bit
//! BRIEF descriptor (imageproc; test pairs drawn once from a fixed seed, so runs repeat),
//! matched by Hamming distance both ways with Lowe's ratio test. Their pixels become 3-D pairs
//! as the flow's do ([`crate::correspondences`]). The matches are sparse and some are wrong; the
//! registration's RANSAC weighs them beside the flow's sets.

use crate::correspondences::{FlowPairs, FlowView, lift_matches};
use flowfilter_camera::RayTable;
use image::GrayImage;
use imageproc::binary_descriptors::BinaryDescriptor;
use imageproc::binary_descriptors::brief::{BriefDescriptor, TestPair, brief};
use imageproc::point::Point;
use serde::{Deserialize, Serialize};
use std::sync::OnceLock;
use std::time::Instant;

/// Parameters of the feature matches (`[flow.wide.features]` in the pipeline configuration).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FeatureParams {
    /// Match features where the pyramid's flow is split (with the coarse search). Off by
    /// default: on the real shelf sequences the matches are right but few (10-50 on a region),
    /// and the region tracked from their consensus did not beat the coarse search's (see the
    /// project's `docs/real.md`).
    pub enabled: bool,
    /// FAST-9 threshold: grey-level step (of 255) around a corner.
    pub fast_threshold: u8,
    /// Corners kept in the model's mask, strongest first, one per cell of `cell_px`.
    pub max_model_corners: usize,
    /// Corners kept in the target's mask.
    pub max_target_corners: usize,
    /// Side of the cells that keep one corner each (pixels).
    pub cell_px: usize,
    /// Largest Hamming distance of a match (of 256 bits).
    pub max_hamming: u32,
    /// A match's distance must be below this fraction of the second-best's (Lowe's ratio).
    pub ratio: f64,
}

impl Default for FeatureParams {
    fn default() -> Self {
        Self {
            enabled: false,
            fast_threshold: 8,
            max_model_corners: 500,
            max_target_corners: 2000,
            cell_px: 4,
            max_hamming: 64,
            ratio: 0.8,
        }
    }
}

impl FeatureParams {
    /// Check ranges.
    ///
    /// # Errors
    /// A message naming the field.
    pub fn validate(&self) -> Result<(), String> {
        if self.cell_px == 0 || self.max_model_corners == 0 || self.max_target_corners == 0 {
            return Err("features: cell_px, max_model_corners and max_target_corners must be at least 1".into());
        }
        if !(self.ratio > 0.0 && self.ratio <= 1.0) || self.max_hamming == 0 || self.max_hamming > DESCRIPTOR_BITS {
            return Err(format!(
                "features: ratio in (0, 1] and max_hamming in 1..={DESCRIPTOR_BITS} required, found {} and {}",
                self.ratio, self.max_hamming
            ));
        }
        Ok(())
    }
}

/// Bits of a descriptor.
const DESCRIPTOR_BITS: u32 = 256;
/// Distance of a corner from the image's border that BRIEF's 31-px patch needs (pixels).
const PATCH_MARGIN: u32 = 20;
/// Standard deviation of BRIEF's test points about the patch centre (Calonder et al.: S^2/25).
const TEST_SIGMA_PX: f64 = 6.6;

/// Feature matches of the model's object in the target as 3-D pairs: `tracked` is the model's
/// corners, `flow_seconds` the time spent detecting, describing and matching.
///
/// ```
/// use flowfilter_flow::features::{FeatureParams, feature_pairs};
/// use flowfilter_flow::{correspondences::FlowView, lk::Gray};
/// use flowfilter_camera::{CameraModel, Distortion, ImageSize, Intrinsics, RayTable};
/// use flowfilter_geometry::{DepthMap, Mask};
///
/// // A textured plane 0.5 m away, seen again 60 px further right.
/// let (w, h) = (320, 240);
/// let texture = |x: i64, y: i64| ((x / 7 * 31 + y / 5 * 17 + (x / 7) * (y / 5)) % 97) as f32 / 97.0;
/// let model = Gray::from_fn(w, h, |x, y| texture(x as i64, y as i64));
/// let target = Gray::from_fn(w, h, |x, y| texture(x as i64 - 60, y as i64));
/// let depth = DepthMap::filled(w, h, 0.5);
/// let mask = Mask::from_fn(w, h, |x, _| x < 200);
/// let everywhere = Mask::filled(w, h, true);
/// let camera = CameraModel::new(Intrinsics::new(300.0, 300.0, 160.0, 120.0)?, Distortion::NONE, ImageSize::new(320, 240)?);
/// let rays = RayTable::new(&camera);
/// let pairs = feature_pairs(
///     &FlowView { gray: &model, depth: &depth, mask: &mask, pyramids: None },
///     &FlowView { gray: &target, depth: &depth, mask: &everywhere, pyramids: None },
///     &rays,
///     &FeatureParams::default(),
///     2.5,
/// );
/// let shifted = (0..pairs.pairs.len()).filter(|&i| (pairs.pairs.target[i].x - pairs.pairs.source[i].x - 0.1).abs() < 0.005).count();
/// assert!(shifted >= 20 && shifted * 10 >= pairs.pairs.len() * 9, "{shifted} of {}", pairs.pairs.len());
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn feature_pairs(
    model: &FlowView<'_>,
    target: &FlowView<'_>,
    rays: &RayTable,
    p: &FeatureParams,
    k_sigma: f64,
) -> FlowPairs {
    let t0 = Instant::now();
    let model_corners = corners(model, p, p.max_model_corners, true);
    let target_corners = corners(target, p, p.max_target_corners, false);
    let matches = match_corners(&model_corners, &target_corners, p);
    let seconds = t0.elapsed().as_secs_f64();
    let pixels: Vec<[f32; 2]> = matches.iter().map(|(a, _)| *a).collect();
    let moved: Vec<[f32; 2]> = matches.iter().map(|(_, b)| *b).collect();
    let mut pairs = lift_matches(model, target, rays, &pixels, &moved, &vec![true; pixels.len()], k_sigma);
    pairs.tracked = model_corners.len();
    pairs.flow_seconds = seconds;
    pairs
}

/// A corner and its descriptor.
struct Described {
    at: [f32; 2],
    descriptor: BriefDescriptor,
}

/// The view's FAST-9 corners in its mask (with depth where `need_depth`), strongest first, one
/// per cell, at most `limit`, with their BRIEF descriptors.
fn corners(view: &FlowView<'_>, p: &FeatureParams, limit: usize, need_depth: bool) -> Vec<Described> {
    let image = to_u8(view.gray);
    let (w, h) = image.dimensions();
    if w <= 2 * PATCH_MARGIN || h <= 2 * PATCH_MARGIN {
        return vec![];
    }
    let inside = |x: u32, y: u32| {
        (PATCH_MARGIN..w - PATCH_MARGIN).contains(&x)
            && (PATCH_MARGIN..h - PATCH_MARGIN).contains(&y)
            && *view.mask.at(x as usize, y as usize)
            && (!need_depth || *view.depth.at(x as usize, y as usize) > 0.0)
    };
    let mut found: Vec<_> =
        imageproc::corners::corners_fast9(&image, p.fast_threshold).into_iter().filter(|c| inside(c.x, c.y)).collect();
    // Strongest first; ties by position, so the order never depends on the detector's.
    found.sort_by(|a, b| b.score.total_cmp(&a.score).then((a.y, a.x).cmp(&(b.y, b.x))));
    let cell = p.cell_px as u32;
    let cols = w.div_ceil(cell) as usize;
    let mut taken = vec![false; cols * h.div_ceil(cell) as usize];
    let mut kept: Vec<Point<u32>> = vec![];
    for c in found {
        let k = (c.y / cell) as usize * cols + (c.x / cell) as usize;
        if !taken[k] {
            taken[k] = true;
            kept.push(Point::new(c.x, c.y));
            if kept.len() == limit {
                break;
            }
        }
    }
    let Ok((descriptors, _)) = brief(&image, &kept, DESCRIPTOR_BITS as usize, Some(test_pairs())) else {
        return vec![];
    };
    descriptors.into_iter().map(|d| Described { at: [d.corner.x as f32, d.corner.y as f32], descriptor: d }).collect()
}

/// Matches both ways: each model corner's nearest target corner by Hamming distance, kept
/// when within `max_hamming`, below `ratio` times the second nearest, and the target corner's
/// own nearest model corner is it.
fn match_corners(model: &[Described], target: &[Described], p: &FeatureParams) -> Vec<([f32; 2], [f32; 2])> {
    let nearest_two = |d: &BriefDescriptor, among: &[Described]| {
        let mut best = (u32::MAX, usize::MAX, u32::MAX);
        for (j, o) in among.iter().enumerate() {
            let h = d.hamming_distance(&o.descriptor);
            if h < best.0 {
                best = (h, j, best.0);
            } else if h < best.2 {
                best.2 = h;
            }
        }
        best
    };
    let mut out = vec![];
    for a in model {
        let (h, j, second) = nearest_two(&a.descriptor, target);
        if j == usize::MAX || h > p.max_hamming || f64::from(h) >= p.ratio * f64::from(second) {
            continue;
        }
        let (_, back, _) = nearest_two(&target[j].descriptor, model);
        if back < model.len() && model[back].at == a.at {
            out.push((a.at, target[j].at));
        }
    }
    out
}

/// Grey values in [0, 1] as 8-bit.
fn to_u8(gray: &crate::lk::Gray) -> GrayImage {
    let (w, h) = gray.dims();
    GrayImage::from_fn(w as u32, h as u32, |x, y| {
        image::Luma([(gray.at(x as usize, y as usize).clamp(0.0, 1.0) * 255.0).round() as u8])
    })
}

/// BRIEF's test pairs, drawn once from a fixed seed (isotropic Gaussian about the patch centre,
/// inside the 31-px patch), so that descriptors repeat across runs and processes.
fn test_pairs() -> &'static Vec<TestPair> {
    static PAIRS: OnceLock<Vec<TestPair>> = OnceLock::new();
    PAIRS.get_or_init(|| {
        // A SplitMix64 stream and Box-Muller: four coordinates per pair.
        let mut state: u64 = 0x5EED_B21E_F000_0001;
        let mut uniform = move || {
            state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut coordinate = || loop {
            let (u, v) = (uniform().max(f64::MIN_POSITIVE), uniform());
            let c = 14.0 + TEST_SIGMA_PX * (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos();
            if (0.0..31.0).contains(&c) {
                return c as u32;
            }
        };
        (0..DESCRIPTOR_BITS)
            .map(|_| TestPair {
                p0: Point::new(coordinate(), coordinate()),
                p1: Point::new(coordinate(), coordinate()),
            })
            .collect()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Out-of-range parameters are named; the test pairs repeat and lie inside the patch.
    #[test]
    fn parameters_are_checked_and_the_tests_repeat() {
        assert!(FeatureParams::default().validate().is_ok());
        let bad = FeatureParams { ratio: 0.0, ..FeatureParams::default() };
        assert!(bad.validate().unwrap_err().contains("ratio"));
        let bad = FeatureParams { max_hamming: 300, ..FeatureParams::default() };
        assert!(bad.validate().unwrap_err().contains("max_hamming"));
        let bad = FeatureParams { cell_px: 0, ..FeatureParams::default() };
        assert!(bad.validate().unwrap_err().contains("cell_px"));
        let pairs = test_pairs();
        assert_eq!(pairs.len(), DESCRIPTOR_BITS as usize);
        assert!(pairs.iter().all(|t| [t.p0.x, t.p0.y, t.p1.x, t.p1.y].iter().all(|&c| c < 31)));
        assert!(pairs.iter().any(|t| t.p0 != t.p1));
    }
}
