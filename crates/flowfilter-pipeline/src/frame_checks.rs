//! Plausibility checks on a frame before and after the depth stage: depth in a range an RGB-D
//! sensor measures, a cloud that is not empty, a mask that is an object's rather than the whole
//! image. Each failure names the frame and what to check.

use crate::error::PipelineError;
use crate::frame::RgbdFrame;
use crate::stages::PreparedFrame;
use crate::warning::PipelineWarning;
use flowfilter_geometry::Mask;

/// The nearest median depth accepted, metres: no RGB-D sensor measures closer.
pub const MIN_MEDIAN_DEPTH_M: f64 = 0.05;

/// The farthest median depth accepted, metres: beyond every RGB-D sensor's range.
pub const MAX_MEDIAN_DEPTH_M: f64 = 20.0;

/// A depth image with at least this fraction of its readings at 65535 is saturated.
pub const MAX_SATURATED_FRACTION: f64 = 0.5;

/// A mask covering at least this fraction of the image is the scene's, not an object's.
pub const FULL_MASK_FRACTION: f64 = 0.99;

fn frame_error(frame: &str, message: String) -> PipelineError {
    PipelineError::Frame { frame: frame.into(), message }
}

/// The frame's depth readings are in range: some pixel has a reading, and their median depth
/// lies within [`MIN_MEDIAN_DEPTH_M`, `MAX_MEDIAN_DEPTH_M`].
///
/// # Errors
/// [`PipelineError::Frame`] naming the frame, the median found and the depth unit.
pub fn check_depth(frame: &RgbdFrame) -> Result<(), PipelineError> {
    check_principal_points(frame)?;
    let mut raw: Vec<u16> = frame.depth.as_slice().iter().copied().filter(|&d| d > 0).collect();
    if raw.is_empty() {
        return Err(frame_error(&frame.label, "the depth image has no reading (every pixel is 0)".into()));
    }
    let saturated = raw.iter().filter(|&&d| d == u16::MAX).count() as f64 / raw.len() as f64;
    if saturated >= MAX_SATURATED_FRACTION {
        return Err(frame_error(
            &frame.label,
            format!(
                "the depth image is saturated: {:.0}% of its readings are 65535, the 16-bit maximum (an overflow or \
                 a 'no reading' marker, not a depth): check the depth file and its unit",
                saturated * 100.0
            ),
        ));
    }
    let mid = raw.len() / 2;
    let median = f64::from(*raw.select_nth_unstable(mid).1);
    let unit = frame.sensor.metres_per_unit;
    let metres = median * unit;
    if !(MIN_MEDIAN_DEPTH_M..=MAX_MEDIAN_DEPTH_M).contains(&metres) {
        return Err(frame_error(
            &frame.label,
            format!(
                "the median depth is {metres:.4} m (raw {median} x {unit:e} m per unit), outside the \
                 {MIN_MEDIAN_DEPTH_M}-{MAX_MEDIAN_DEPTH_M} m an RGB-D sensor measures: check the depth unit \
                 (the camera's depth scale) or the depth file"
            ),
        ));
    }
    Ok(())
}

/// Each image fits its camera: the principal point lies inside the image (an image of another
/// shape than the calibration's camera, e.g. a depth dataset of the wrong size, does not).
fn check_principal_points(frame: &RgbdFrame) -> Result<(), PipelineError> {
    let sensor = &frame.sensor;
    for (which, camera, (w, h)) in [
        ("colour", &sensor.color, (frame.color.width() as usize, frame.color.height() as usize)),
        ("depth", &sensor.depth, frame.depth.dims()),
    ] {
        let k = camera.intrinsics;
        if !(0.0..=w as f64).contains(&k.cx) || !(0.0..=h as f64).contains(&k.cy) {
            return Err(frame_error(
                &frame.label,
                format!(
                    "the {which} image is {w}x{h}, but its camera's principal point ({}, {}) lies outside it: \
                     the image does not belong to this camera (wrong shape?)",
                    k.cx, k.cy
                ),
            ));
        }
    }
    Ok(())
}

/// The prepared frame has points.
///
/// # Errors
/// [`PipelineError::Frame`] naming the frame, its mask and its depth image.
pub fn check_cloud(frame: &RgbdFrame, prepared: &PreparedFrame) -> Result<(), PipelineError> {
    if !prepared.cloud.is_empty() {
        return Ok(());
    }
    let masked = frame.mask.as_slice().iter().filter(|&&m| m).count();
    let readings = frame.depth.as_slice().iter().filter(|&&d| d > 0).count();
    Err(frame_error(
        &frame.label,
        format!(
            "no pixel of the mask ({masked} px on the {}x{} colour image) has a usable depth ({readings} readings \
             on the {}x{} depth image): check that the depth belongs to this image and camera, and the mask",
            frame.color.width(),
            frame.color.height(),
            frame.depth.width(),
            frame.depth.height()
        ),
    ))
}

/// The fraction of the image inside `mask`.
fn covered_fraction(mask: &Mask) -> f64 {
    mask.count() as f64 / mask.as_slice().len().max(1) as f64
}

/// Whether a frame came without an object mask: its mask covers (nearly) the whole image, or
/// is exactly its pixels with depth (what a frame of registered depth got without a mask before
/// masks covered the whole image).
pub fn is_unmasked(frame: &RgbdFrame) -> bool {
    let mask = frame.mask.as_slice();
    covered_fraction(&frame.mask) >= FULL_MASK_FRACTION
        || (frame.sensor.is_registered()
            && frame.depth.dims() == frame.mask.dims()
            && mask.iter().zip(frame.depth.as_slice()).all(|(m, d)| *m == (*d > 0)))
}

/// A warning when the frame's mask covers (nearly) the whole image.
pub fn mask_coverage(frame: &PreparedFrame) -> Option<PipelineWarning> {
    let fraction = covered_fraction(&frame.mask);
    (fraction >= FULL_MASK_FRACTION).then(|| PipelineWarning::MaskCoversFrame { frame: frame.label.clone(), fraction })
}
