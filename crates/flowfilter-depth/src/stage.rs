//! The whole depth stage: raw depth + colour + mask -> filtered depth on the colour grid and an
//! organised object cloud.

use crate::cloud::{knn_normals, organized_cloud_in, organized_normals};
use crate::config::{DepthConfig, NormalMethod, RegistrationMethod};
use crate::error::DepthError;
use crate::filter::{bigbird_discontinuity, gaussian_window};
use crate::interpolate::fill_holes_in;
use crate::register::{depth_roi, mask_bbox, mesh_in, project_depth_grid, splat};
use flowfilter_camera::{CameraModel, RayTable, RgbdSensor};
use flowfilter_geometry::{DepthMap, Mask, Point3, PointCloud, RawDepth};
use image::RgbImage;
use std::sync::{Arc, Mutex};

/// Nearest and farthest depth considered when bounding the depth pixels that can reach the
/// mask (metres): the working range of Carmine-class sensors.
const ROI_NEAR_M: f64 = 0.25;
const ROI_FAR_M: f64 = 5.0;
/// Relative and absolute slack on the measured depth range when narrowing the crop.
const ROI_Z_SLACK: f64 = 0.05;
const ROI_Z_SLACK_M: f64 = 0.02;

/// Counts of what each step did, for diagnostics.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct DepthStats {
    /// Raw pixels with a reading.
    pub raw_valid: usize,
    /// Readings outside the sensor's working range ([`crate::RangeConfig`]) in the region
    /// processed.
    pub out_of_range: usize,
    /// Rejected by the BigBIRD discontinuity filter.
    pub rejected_discontinuity: usize,
    /// Rejected by the Gaussian window filter.
    pub rejected_gaussian: usize,
    /// Rejected by the step filter.
    pub rejected_step: usize,
    /// Mask pixels with registered depth before interpolation.
    pub registered: usize,
    /// Mask pixels filled by interpolation.
    pub interpolated: usize,
    /// Mask pixels.
    pub mask_pixels: usize,
    /// The cloud's pixel step (every `cloud_step`-th pixel in each direction;
    /// [`crate::CloudConfig::pixel_budget`]).
    pub cloud_step: usize,
    /// Wall time of each step, milliseconds, in order.
    pub timings_ms: Vec<(&'static str, f64)>,
}

/// The output of the depth stage.
#[derive(Debug, Clone)]
pub struct ProcessedDepth {
    /// Filtered depth on the depth camera's grid, metres (0 = none).
    pub filtered_raw: DepthMap,
    /// Dense depth on the colour grid, inside the mask, metres (0 = none).
    pub depth: DepthMap,
    /// Organised object cloud in the colour camera frame (pixels, colours, normals).
    pub cloud: PointCloud,
    /// Per colour pixel, the index of its point in `cloud` (`u32::MAX` for none).
    pub point_index: Vec<u32>,
    /// What each step did.
    pub stats: DepthStats,
}

/// The depth stage with its configuration and a cache of per-camera ray tables.
pub struct DepthStage {
    config: DepthConfig,
    rays: Mutex<Vec<Arc<RayTable>>>,
}

fn size_text(w: usize, h: usize) -> String {
    format!("{w}x{h}")
}

fn check_sensor(s: &RgbdSensor) -> Result<(), DepthError> {
    let t = s.color_from_depth.to_homogeneous();
    let values = [
        ("depth fx", s.depth.intrinsics.fx),
        ("depth fy", s.depth.intrinsics.fy),
        ("depth cx", s.depth.intrinsics.cx),
        ("depth cy", s.depth.intrinsics.cy),
        ("colour fx", s.color.intrinsics.fx),
        ("colour fy", s.color.intrinsics.fy),
        ("colour cx", s.color.intrinsics.cx),
        ("colour cy", s.color.intrinsics.cy),
        ("depth scale", s.metres_per_unit),
    ];
    for (name, value) in values.into_iter().chain(s.color.distortion.to_array().map(|v| ("colour distortion", v))) {
        if !value.is_finite() {
            return Err(DepthError::NonFiniteCalibration { name, value });
        }
    }
    if let Some(value) = t.iter().copied().find(|v| !v.is_finite()) {
        return Err(DepthError::NonFiniteCalibration { name: "colour-from-depth transform", value });
    }
    Ok(())
}

/// The box of `mask`'s pixels (within `mask_box`) that hold a reading of `raw` (registered to
/// the mask's grid), grown by `reach` pixels and kept within `mask_box`; `None` when there is
/// none. Outside it no mask pixel has a reading or a hole the fill reaches.
fn reading_box(
    raw: &RawDepth,
    mask: &Mask,
    (x0, y0, x1, y1): (usize, usize, usize, usize),
    reach: usize,
) -> Option<(usize, usize, usize, usize)> {
    let mut found: Option<(usize, usize, usize, usize)> = None;
    for y in y0..=y1 {
        let (m, d) = (&mask.row(y)[x0..=x1], &raw.row(y)[x0..=x1]);
        let mut hits = m.iter().zip(d).enumerate().filter(|(_, (m, d))| **m && **d > 0).map(|(i, _)| x0 + i);
        let Some(first) = hits.next() else { continue };
        let last = hits.next_back().unwrap_or(first);
        found = Some(match found {
            None => (first, y, last, y),
            Some((a, b, c, _)) => (a.min(first), b, c.max(last), y),
        });
    }
    found.map(|(a, b, c, d)| {
        (a.saturating_sub(reach).max(x0), b.saturating_sub(reach).max(y0), (c + reach).min(x1), (d + reach).min(y1))
    })
}

impl DepthStage {
    /// A stage with a validated configuration.
    pub fn new(config: DepthConfig) -> Result<Self, DepthError> {
        config.validate()?;
        Ok(Self { config, rays: Mutex::new(Vec::new()) })
    }

    /// The configuration.
    pub fn config(&self) -> &DepthConfig {
        &self.config
    }

    /// The ray table of a camera (computed once per distinct camera model).
    pub fn rays(&self, camera: &CameraModel) -> Arc<RayTable> {
        let mut cache = self.rays.lock().expect("ray cache lock");
        if let Some(t) = cache.iter().find(|t| t.camera() == camera) {
            return t.clone();
        }
        let t = Arc::new(RayTable::new(camera));
        if cache.len() >= 16 {
            cache.remove(0);
        }
        cache.push(t.clone());
        t
    }

    /// Run the stage on one frame: check the inputs, crop the depth to the region that can
    /// land in the mask, filter it, register it to the colour grid (depth already registered to
    /// colour, [`RgbdSensor::is_registered`], is placed as it is), fill holes, and build the
    /// organised cloud with normals.
    ///
    /// # Errors
    /// [`DepthError::SizeMismatch`] when the depth image, colour image or mask does not have
    /// the sensor's size, [`DepthError::EmptyMask`], [`DepthError::NoDepth`], and the sensor
    /// checks' errors.
    pub fn process(
        &self,
        raw: &RawDepth,
        color: &RgbImage,
        mask: &Mask,
        sensor: &RgbdSensor,
    ) -> Result<ProcessedDepth, DepthError> {
        check_inputs(raw, color, mask, sensor)?;
        let (dw, dh) = (sensor.depth.size.width as usize, sensor.depth.size.height as usize);
        let (cw, ch) = (sensor.color.size.width as usize, sensor.color.size.height as usize);
        // One scan of the mask: its box (None when empty); the pixel count only inside the box.
        let mask_box = mask_bbox(mask).ok_or(DepthError::EmptyMask)?;
        let (bx0, by0, bx1, by1) = mask_box;
        let mask_pixels = (by0..=by1).map(|y| mask.row(y)[bx0..=bx1].iter().filter(|&&m| m).count()).sum();
        let raw_valid = raw.as_slice().iter().filter(|&&d| d > 0).count();
        if raw_valid == 0 {
            return Err(DepthError::NoDepth);
        }
        let cfg = &self.config;
        // Depth on the colour grid: only the mask's pixels with readings, and the holes the
        // fill can reach from them, get depth; the work is cut to their box (a whole-image mask
        // on a frame whose readings cover a quarter of it: 90 -> 25 ms at 1280 x 1024, the same
        // output).
        let mask_box = match sensor.is_registered() {
            true => reading_box(raw, mask, mask_box, cfg.interpolation.max_radius_px).unwrap_or(mask_box),
            false => mask_box,
        };
        let (bx0, by0, bx1, by1) = mask_box;
        let mut stats = DepthStats { raw_valid, mask_pixels, ..Default::default() };
        let mut laps = Laps::start();
        let region = if cfg.registration.restrict_to_mask {
            self.depth_region(raw, sensor, mask_box)
        } else {
            (0, 0, dw - 1, dh - 1)
        };
        let depth = self.filtered_crop(raw, sensor.metres_per_unit, region, &mut stats, &mut laps);
        let origin = (region.0, region.1);
        let restrict = cfg.registration.restrict_to_mask.then_some(mask);
        let registered = if sensor.is_registered() {
            // Depth already on the colour grid: placed, not re-projected.
            in_place(&depth, origin, cw, ch, restrict)
        } else {
            let projected = project_depth_grid(&depth, origin, sensor, &self.rays(&sensor.depth));
            match cfg.registration.method {
                RegistrationMethod::Splat => splat(&projected, cw, ch, restrict),
                RegistrationMethod::Mesh => {
                    let region = if restrict.is_some() { mask_box } else { (0, 0, cw - 1, ch - 1) };
                    mesh_in(&depth, &projected, cw, ch, cfg.registration.max_step_m, restrict, Some(region))
                }
            }
        };
        laps.lap(&mut stats, "project+register");
        // Registration only writes inside the mask (or anywhere when unrestricted).
        stats.registered = (by0..=by1)
            .flat_map(|y| (bx0..=bx1).map(move |x| y * cw + x))
            .filter(|&k| registered.as_slice()[k] > 0.0 && mask.as_slice()[k])
            .count();
        let mut dense = registered;
        stats.interpolated = fill_holes_in(&mut dense, mask, Some(mask_box), &cfg.interpolation);
        laps.lap(&mut stats, "interpolate");
        stats.cloud_step = cfg.cloud.pixel_step(stats.registered + stats.interpolated);
        let (cloud, point_index) = self.cloud(&dense, color, mask, mask_box, sensor, stats.cloud_step);
        laps.lap(&mut stats, "cloud+normals");
        let filtered_raw = paste(&depth, origin, dw, dh);
        Ok(ProcessedDepth { filtered_raw, depth: dense, cloud, point_index, stats })
    }

    /// The depth pixels that can land in the mask's box (filters and projection then touch a
    /// fraction of the frame): the box seen over the plausible depth range, narrowed to the
    /// depths measured there.
    fn depth_region(
        &self,
        raw: &RawDepth,
        sensor: &RgbdSensor,
        mask_box: (usize, usize, usize, usize),
    ) -> (usize, usize, usize, usize) {
        let cfg = &self.config;
        let margin = cfg.gaussian_filter.window.max(cfg.bigbird_filter.window).max(cfg.step_filter.window) + 2;
        let coarse = depth_roi(sensor, mask_box, ROI_NEAR_M, ROI_FAR_M, margin);
        // Narrow the depth range to the depths measured in that region (the parallax
        // between the cameras makes the region grow with the range), with slack for the
        // difference between depth- and colour-camera z.
        let (lo, hi) = (coarse.1..=coarse.3)
            .flat_map(|y| raw.row(y)[coarse.0..=coarse.2].iter().copied())
            .filter(|&d| d > 0)
            .fold((u16::MAX, 0u16), |(lo, hi), d| (lo.min(d), hi.max(d)));
        if lo > hi {
            return coarse;
        }
        let (near, far) = (f64::from(lo) * sensor.metres_per_unit, f64::from(hi) * sensor.metres_per_unit);
        let near = (near * (1.0 - ROI_Z_SLACK) - ROI_Z_SLACK_M).max(ROI_NEAR_M);
        let far = (far * (1.0 + ROI_Z_SLACK) + ROI_Z_SLACK_M).clamp(near, ROI_FAR_M.max(near));
        depth_roi(sensor, mask_box, near, far, margin)
    }

    /// The raw depth of `region` in metres, through the Gaussian-window and step filters.
    fn filtered_crop(
        &self,
        raw: &RawDepth,
        unit: f64,
        (rx0, ry0, rx1, ry1): (usize, usize, usize, usize),
        stats: &mut DepthStats,
        laps: &mut Laps,
    ) -> DepthMap {
        let cfg = &self.config;
        let (rw, rh) = (rx1 - rx0 + 1, ry1 - ry0 + 1);
        let range = &cfg.range;
        let mut depth = DepthMap::from_fn(rw, rh, |x, y| {
            let d = *raw.at(rx0 + x, ry0 + y);
            let z = f64::from(d) * unit;
            if d == 0 || !range.contains(z) { 0.0 } else { z as f32 }
        });
        // Counted only where a bound is set: by default every reading is in range.
        stats.out_of_range = match range.is_unbounded() {
            true => 0,
            false => (0..rh)
                .map(|y| {
                    let row = &raw.row(ry0 + y)[rx0..rx0 + rw];
                    row.iter().filter(|&&d| d > 0 && !range.contains(f64::from(d) * unit)).count()
                })
                .sum(),
        };
        laps.lap(stats, "crop");
        if cfg.gaussian_filter.enabled {
            let (d, n) = gaussian_window(&depth, &cfg.gaussian_filter);
            depth = d;
            stats.rejected_gaussian = n;
        }
        laps.lap(stats, "gaussian");
        if cfg.step_filter.enabled {
            let (d, n) = bigbird_discontinuity(&depth, cfg.step_filter.window, cfg.step_filter.threshold_m);
            depth = d;
            stats.rejected_step = n;
        }
        laps.lap(stats, "step");
        depth
    }

    /// The organised cloud of the dense colour-grid depth inside the mask (every `step`-th
    /// pixel in each direction), with the configured normals, and each point's pixel index.
    fn cloud(
        &self,
        dense: &DepthMap,
        color: &RgbImage,
        mask: &Mask,
        mask_box: (usize, usize, usize, usize),
        sensor: &RgbdSensor,
        step: usize,
    ) -> (PointCloud, Vec<u32>) {
        let cfg = &self.config;
        let color_rays = self.rays(&sensor.color);
        let (mut cloud, point_index) =
            organized_cloud_in(dense, &color_rays, Some(color), Some(mask), Some(mask_box), step);
        cloud.normals = match cfg.cloud.normals {
            NormalMethod::None => None,
            NormalMethod::Organized => Some(organized_normals(
                &cloud,
                &point_index,
                sensor.color.size.width as usize,
                cfg.cloud.organized_step_px.next_multiple_of(step),
                cfg.registration.max_step_m,
            )),
            NormalMethod::Knn => Some(knn_normals(&cloud.points, cfg.cloud.knn, &Point3::origin())),
        };
        (cloud, point_index)
    }
}

/// Sizes of the depth image, colour image and mask against the sensor's.
fn check_inputs(raw: &RawDepth, color: &RgbImage, mask: &Mask, sensor: &RgbdSensor) -> Result<(), DepthError> {
    check_sensor(sensor)?;
    let (dw, dh) = (sensor.depth.size.width as usize, sensor.depth.size.height as usize);
    let (cw, ch) = (sensor.color.size.width as usize, sensor.color.size.height as usize);
    let found = [
        ("depth image", (dw, dh), raw.dims()),
        ("colour image", (cw, ch), (color.width() as usize, color.height() as usize)),
        ("mask", (cw, ch), mask.dims()),
    ];
    for (what, expected, found) in found {
        if found != expected {
            return Err(DepthError::SizeMismatch {
                what,
                expected: size_text(expected.0, expected.1),
                found: size_text(found.0, found.1),
            });
        }
    }
    Ok(())
}

/// Depth registered to colour, filtered on its crop, placed on the full `cw` x `ch` colour grid
/// (inside `mask` only, when given).
fn in_place(crop: &DepthMap, (x0, y0): (usize, usize), cw: usize, ch: usize, mask: Option<&Mask>) -> DepthMap {
    let mut full = paste(crop, (x0, y0), cw, ch);
    if let Some(m) = mask {
        for (d, inside) in full.as_mut_slice().iter_mut().zip(m.as_slice()) {
            if !inside {
                *d = 0.0;
            }
        }
    }
    full
}

/// The filtered crop pasted back into a full-size (`dw` x `dh`) depth-grid map.
fn paste(crop: &DepthMap, (x0, y0): (usize, usize), dw: usize, dh: usize) -> DepthMap {
    let mut full = DepthMap::filled(dw, dh, 0.0);
    let rw = crop.width();
    for y in 0..crop.height() {
        full.as_mut_slice()[(y0 + y) * dw + x0..(y0 + y) * dw + x0 + rw].copy_from_slice(crop.row(y));
    }
    full
}

/// Wall time per step, recorded in the stage's statistics.
struct Laps(std::time::Instant);

impl Laps {
    fn start() -> Self {
        Self(std::time::Instant::now())
    }

    /// Record the time since the last lap as step `name`.
    fn lap(&mut self, stats: &mut DepthStats, name: &'static str) {
        stats.timings_ms.push((name, self.0.elapsed().as_secs_f64() * 1e3));
        self.0 = std::time::Instant::now();
    }
}
