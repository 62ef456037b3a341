//! Rendering frames of a turntable capture and writing them in the BigBIRD layout.

use crate::error::SynthError;
use crate::noise::{DepthNoiseInput, DepthNoiseTruth, NoiseProfile, add_color_noise, apply_depth_noise, gaussian_blur};
use crate::rig::{Rig, RigSensor, world_from_table};
use crate::scene::Scene;
use flowfilter_bigbird::{CaptureStatus, FrameId, H5Format, ObjectWriter, SensorId};
use flowfilter_camera::CameraModel;
use flowfilter_camera::raster::{GBuffer, NO_TRIANGLE, ScreenVertex, rasterize};
use flowfilter_geometry::{DepthMap, Mask, Pose, RawDepth};
use image::{Rgb, RgbImage};
use nalgebra::{Point3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

/// One rendered frame with its ground truth.
#[derive(Debug, Clone)]
pub struct RenderedFrame {
    /// Sensor and angle.
    pub id: FrameId,
    /// Colour image (noise applied, before JPEG).
    pub color: RgbImage,
    /// Raw depth as the sensor reports it (noise applied), on the depth grid.
    pub raw_depth: RawDepth,
    /// Object mask on the colour grid.
    pub mask: Mask,
    /// Noise-free depth on the depth grid, metres (0 = no surface).
    pub clean_depth: DepthMap,
    /// Noise-free depth on the colour grid (the colour camera's own z), metres (0 = no surface).
    pub color_depth: DepthMap,
    /// Object mask on the depth grid (noise-free).
    pub depth_object: Mask,
    /// Which depth pixels the noise model altered, and how (all false without noise).
    pub noise_truth: DepthNoiseTruth,
}

fn project_all(scene: &Scene, cam: &CameraModel, h_cam_from_table: &Pose) -> Vec<Option<ScreenVertex>> {
    scene
        .positions
        .par_iter()
        .map(|p| {
            let q = h_cam_from_table * Point3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z));
            if q.z < 0.05 {
                return None;
            }
            cam.project(&q).map(|px| ScreenVertex { x: px.x as f32, y: px.y as f32, z: q.z as f32 })
        })
        .collect()
}

pub(crate) fn render_gbuffer(scene: &Scene, cam: &CameraModel, h_cam_from_table: &Pose) -> GBuffer {
    let v = project_all(scene, cam, h_cam_from_table);
    rasterize(cam.size.width as usize, cam.size.height as usize, &v, &scene.triangles)
}

/// Interpolated table-frame normal of a pixel.
fn normal_at(scene: &Scene, g: &GBuffer, k: usize) -> Vector3<f32> {
    let (mesh, t) = scene.locate(g.triangle[k]);
    let [i0, i1, i2] = mesh.triangles[t].map(|i| i as usize);
    let [b1, b2] = g.bary[k];
    let n = mesh.normals[i0] * (1.0 - b1 - b2) + mesh.normals[i1] * b1 + mesh.normals[i2] * b2;
    n.try_normalize(1e-12).unwrap_or_else(Vector3::z)
}

fn uv_at(scene: &Scene, g: &GBuffer, k: usize) -> Option<(u32, [f32; 2])> {
    if g.triangle[k] == NO_TRIANGLE {
        return None;
    }
    let (mesh, t) = scene.locate(g.triangle[k]);
    let [i0, i1, i2] = mesh.triangles[t].map(|i| i as usize);
    let [b1, b2] = g.bary[k];
    let b0 = 1.0 - b1 - b2;
    let mesh_id = u32::from(g.triangle[k] >= scene.object_triangles() as u32);
    Some((mesh_id, [0, 1].map(|c| mesh.uvs[i0][c] * b0 + mesh.uvs[i1][c] * b1 + mesh.uvs[i2][c] * b2)))
}

fn shade(scene: &Scene, g: &GBuffer, world_from_table: &Pose) -> RgbImage {
    let rot = world_from_table.rotation.cast::<f32>();
    let (w, h) = (g.width, g.height);
    let uvs: Vec<Option<(u32, [f32; 2])>> = (0..w * h).into_par_iter().map(|k| uv_at(scene, g, k)).collect();
    let mut out = vec![scene.background; w * h];
    out.par_iter_mut().enumerate().for_each(|(k, px)| {
        let Some((mesh_id, uv)) = uvs[k] else { return };
        let (mesh, _) = scene.locate(g.triangle[k]);
        // The pixel's footprint in texels, from the UV differences to its neighbours on the
        // same mesh (the larger of the horizontal and vertical ones).
        let (tw, th) = (mesh.texture.width() as f32, mesh.texture.height() as f32);
        let (x, y) = (k % w, k / w);
        let span = |other: Option<usize>| -> Option<f32> {
            let (m, o) = uvs[other?]?;
            // Texture seams wrap: take the shorter way around.
            let du = (o[0] - uv[0]).abs();
            let dv = (o[1] - uv[1]).abs();
            (m == mesh_id).then(|| ((du.min(1.0 - du) * tw).powi(2) + (dv.min(1.0 - dv) * th).powi(2)).sqrt())
        };
        let dx = span((x + 1 < w).then_some(k + 1)).or_else(|| span((x > 0).then(|| k - 1)));
        let dy = span((y + 1 < h).then_some(k + w)).or_else(|| span((y > 0).then(|| k - w)));
        let texels = dx.unwrap_or(1.0).max(dy.unwrap_or(1.0));
        let albedo = mesh.sample_texture_footprint(uv, texels);
        let n_world = rot * normal_at(scene, g, k);
        let light = scene.ambient + scene.diffuse * n_world.dot(&scene.light_world).max(0.0);
        *px = albedo.map(|a| (a * light * 255.0).round().clamp(0.0, 255.0) as u8);
    });
    RgbImage::from_fn(w as u32, h as u32, |x, y| Rgb(out[y as usize * w + x as usize]))
}

fn depth_map(g: &GBuffer) -> DepthMap {
    DepthMap::from_vec(g.width, g.height, g.depth.iter().map(|&z| if z.is_finite() { z } else { 0.0 }).collect())
        .expect("sized")
}

/// Seed of one frame, derived from the capture seed, sensor and angle.
fn frame_seed(seed: u64, id: FrameId) -> u64 {
    seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (u64::from(id.sensor.index()) << 40) ^ u64::from(id.angle) ^ 0x5EED
}

/// Render one frame of `sensor` at turntable angle `angle_deg`.
pub fn render_frame(
    scene: &Scene,
    rig: &Rig,
    sensor: SensorId,
    angle_deg: u32,
    noise: Option<&NoiseProfile>,
    seed: u64,
) -> RenderedFrame {
    let s: &RigSensor = &rig.sensors[&sensor];
    let id = FrameId { sensor, angle: angle_deg };
    let mut rng = ChaCha8Rng::seed_from_u64(frame_seed(seed, id));
    let angle = f64::from(angle_deg);
    let timing = ViewTiming::turntable(s, angle, angle);
    let v = render_view(scene, s, timing, noise, s.rgbd.depth.intrinsics.fx, &mut rng);
    RenderedFrame {
        id,
        color: v.color,
        raw_depth: v.raw_depth,
        mask: v.mask,
        clean_depth: v.clean_depth,
        color_depth: v.color_depth,
        depth_object: v.depth_object,
        noise_truth: v.noise_truth,
    }
}

/// Where the scene stood when the colour and the depth image of a view were taken (the two
/// differ when the sensor does not capture them at the same instant).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ViewTiming {
    /// Colour camera from table at the colour exposure.
    pub color_from_table: Pose,
    /// Colour camera from table at the depth exposure.
    pub color_from_table_at_depth: Pose,
    /// World from table at the colour exposure: the light is fixed in the world.
    pub world_from_table: Pose,
}

impl ViewTiming {
    /// Sensor `s` watching the turntable at `color_deg` for the colour image and `depth_deg`
    /// for the depth image.
    pub fn turntable(s: &RigSensor, color_deg: f64, depth_deg: f64) -> Self {
        Self {
            color_from_table: s.h_color_from_world * world_from_table(color_deg),
            color_from_table_at_depth: s.h_color_from_world * world_from_table(depth_deg),
            world_from_table: world_from_table(color_deg),
        }
    }
}

/// A rendered view: [`RenderedFrame`] without its BigBIRD name.
pub(crate) struct RenderedView {
    pub color: RgbImage,
    pub raw_depth: RawDepth,
    pub mask: Mask,
    pub clean_depth: DepthMap,
    pub color_depth: DepthMap,
    pub depth_object: Mask,
    pub noise_truth: DepthNoiseTruth,
}

/// Which depth pixels the projector cannot light (their point is hidden from the projector).
fn projector_shadows(
    scene: &Scene,
    cam: &CameraModel,
    gd: &GBuffer,
    h_depth_from_table: &Pose,
    baseline: f64,
    tolerance_m: f64,
) -> Vec<bool> {
    let (w, h) = (gd.width, gd.height);
    // The projector sits `baseline` along the depth camera's +x axis, looking the same way.
    let h_proj_from_table = Pose::translation(-baseline, 0.0, 0.0) * h_depth_from_table;
    let gp = render_gbuffer(scene, cam, &h_proj_from_table);
    (0..w * h)
        .into_par_iter()
        .map(|k| {
            let z = gd.depth[k];
            if !z.is_finite() {
                return false;
            }
            let px = flowfilter_camera::Pixel::new((k % w) as f64, (k / w) as f64);
            let Some(p) = cam.backproject(&px, f64::from(z)) else { return false };
            let q = Point3::new(p.x - baseline, p.y, p.z);
            let Some(pp) = cam.project(&q) else { return true };
            let (u, v) = (pp.x.round(), pp.y.round());
            if u < 0.0 || v < 0.0 || u >= w as f64 || v >= h as f64 {
                return false; // outside the projector's view: treat as lit
            }
            let zp = f64::from(gp.depth[v as usize * w + u as usize]);
            zp.is_finite() && q.z > zp + tolerance_m
        })
        .collect()
}

/// The structured-light model applied to the depth camera's clean render. `focal_px` is the
/// focal length of the camera that measured the disparity (its quantisation step).
fn noisy_depth(
    scene: &Scene,
    s: &RigSensor,
    gd: &GBuffer,
    h_depth_from_table: &Pose,
    profile: &NoiseProfile,
    focal_px: f64,
    rng: &mut ChaCha8Rng,
) -> (DepthMap, DepthNoiseTruth) {
    let cam = &s.rgbd.depth;
    let (w, h) = (gd.width, gd.height);
    let rot = h_depth_from_table.rotation.cast::<f32>();
    let cos_incidence: Vec<f32> = (0..w * h)
        .into_par_iter()
        .map(|k| {
            if gd.triangle[k] == NO_TRIANGLE {
                return 1.0;
            }
            let n = rot * normal_at(scene, gd, k);
            let px = flowfilter_camera::Pixel::new((k % w) as f64, (k / w) as f64);
            let ray = cam.normalized_ray(&px).map_or(Vector3::z(), |r| r.normalize()).cast::<f32>();
            n.dot(&ray).abs()
        })
        .collect();
    let shadowed =
        projector_shadows(scene, cam, gd, h_depth_from_table, s.projector_baseline, profile.depth.shadow_tolerance_m);
    let clean_depth = depth_map(gd);
    let input = DepthNoiseInput { clean: &clean_depth, cos_incidence: &cos_incidence, shadowed: &shadowed, focal_px };
    apply_depth_noise(&profile.depth, &input, rng)
}

/// Render one view of `s`: colour (shaded, then blurred and noisy under a profile), the object
/// mask on the colour grid, and depth from the depth camera (under the structured-light model of
/// the profile, quantised with `noise_focal_px`).
pub(crate) fn render_view(
    scene: &Scene,
    s: &RigSensor,
    timing: ViewTiming,
    noise: Option<&NoiseProfile>,
    noise_focal_px: f64,
    rng: &mut ChaCha8Rng,
) -> RenderedView {
    let n_obj = scene.object_triangles() as u32;

    // Colour camera.
    let gc = render_gbuffer(scene, &s.rgbd.color, &timing.color_from_table);
    let mut color = shade(scene, &gc, &timing.world_from_table);
    let mask = Mask::from_vec(gc.width, gc.height, gc.triangle.iter().map(|&t| t < n_obj).collect()).expect("sized");
    let color_depth = depth_map(&gc);

    // Depth camera.
    let h_depth_from_table = s.rgbd.color_from_depth.inverse() * timing.color_from_table_at_depth;
    let gd = render_gbuffer(scene, &s.rgbd.depth, &h_depth_from_table);
    let clean_depth = depth_map(&gd);
    let depth_object =
        Mask::from_vec(gd.width, gd.height, gd.triangle.iter().map(|&t| t < n_obj).collect()).expect("sized");
    let noisy = match noise {
        None => {
            let none = Mask::filled(gd.width, gd.height, false);
            (clean_depth.clone(), DepthNoiseTruth { flying: none.clone(), jittered: none.clone(), dropped: none })
        }
        Some(profile) => noisy_depth(scene, s, &gd, &h_depth_from_table, profile, noise_focal_px, rng),
    };
    let unit = s.rgbd.metres_per_unit;
    let raw_depth =
        noisy.0.map(|&z| if z > 0.0 { (f64::from(z) / unit).round().clamp(1.0, 65535.0) as u16 } else { 0 });
    if let Some(profile) = noise {
        color = gaussian_blur(&color, profile.color.blur_sigma_px);
        add_color_noise(&mut color, profile.color.noise_sigma, rng);
    }
    RenderedView { color, raw_depth, mask, clean_depth, color_depth, depth_object, noise_truth: noisy.1 }
}

/// Parse an angle specification: `start:end:step` (inclusive, e.g. `0:357:3`), a comma list
/// (`0,15,30`), or one angle. Angles are whole degrees in `0..360` (BigBIRD names frames by them).
pub fn parse_angles(text: &str) -> Result<Vec<u32>, SynthError> {
    let angles = parse_fractional_angles(text)?;
    if let Some(a) = angles.iter().find(|a| a.fract() != 0.0) {
        return Err(SynthError::BadAngles {
            text: text.into(),
            message: format!("{a} is not a whole number of degrees"),
        });
    }
    Ok(angles.into_iter().map(|a| a as u32).collect())
}

/// Parse an angle specification with fractional degrees allowed (`0:2.5:0.25`, `0,0.5,3`), sorted
/// and without repeats; every angle in `[0, 360)`.
pub fn parse_fractional_angles(text: &str) -> Result<Vec<f64>, SynthError> {
    let err = |message: &str| SynthError::BadAngles { text: text.into(), message: message.into() };
    let num = |s: &str| {
        s.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite() && *v >= 0.0)
            .ok_or_else(|| err(&format!("'{}' is not a non-negative number of degrees", s.trim())))
    };
    let angles: Vec<f64> = if text.contains(':') {
        let parts: Vec<&str> = text.split(':').collect();
        let [start, end, step] = parts[..] else { return Err(err("expected start:end:step")) };
        let (start, end, step) = (num(start)?, num(end)?, num(step)?);
        if step <= 0.0 {
            return Err(err("step must be > 0"));
        }
        if start > end {
            return Err(err("start must be <= end"));
        }
        let n = ((end - start) / step + 1e-9).floor() as usize + 1;
        (0..n).map(|i| start + i as f64 * step).collect()
    } else {
        text.split(',').map(num).collect::<Result<_, _>>()?
    };
    if angles.is_empty() {
        return Err(err("no angles"));
    }
    if let Some(a) = angles.iter().find(|&&a| a >= 360.0) {
        return Err(err(&format!("angle {a} is not in 0..360")));
    }
    let mut sorted = angles;
    sorted.sort_by(f64::total_cmp);
    sorted.dedup();
    Ok(sorted)
}

/// What to synthesise.
#[derive(Debug, Clone)]
pub struct CaptureOptions {
    /// Sensors to render.
    pub sensors: Vec<SensorId>,
    /// Turntable angles (degrees).
    pub angles: Vec<u32>,
    /// Noise profile (`None` = exact data).
    pub noise: Option<NoiseProfile>,
    /// Seed of all randomness.
    pub seed: u64,
}

/// Render every requested frame and write the object directory in the BigBIRD layout.
/// `progress(done, total)` is called after each frame (from worker threads).
pub fn write_capture(
    dir: &Path,
    scene: &Scene,
    rig: &Rig,
    opts: &CaptureOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<(), SynthError> {
    let quality = opts.noise.as_ref().map_or(100, |p| p.color.jpeg_quality);
    let writer = ObjectWriter::create(dir, H5Format::V110)?.with_jpeg_quality(quality);
    let frames = opts.sensors.len() * opts.angles.len();
    writer.write_status(CaptureStatus { complete: false, frames })?;
    writer.write_calibration(&rig.calibration())?;
    writer.write_turntable(&rig.turntable())?;
    for &a in &opts.angles {
        writer.write_table_pose(a, &rig.table_pose(a))?;
    }
    let jobs: Vec<(SensorId, u32)> =
        opts.sensors.iter().flat_map(|&s| opts.angles.iter().map(move |&a| (s, a))).collect();
    let done = AtomicUsize::new(0);
    jobs.par_iter().try_for_each(|&(sensor, angle)| -> Result<(), SynthError> {
        let f = render_frame(scene, rig, sensor, angle, opts.noise.as_ref(), opts.seed);
        writer.write_color(f.id, &f.color)?;
        writer.write_depth(f.id, &f.raw_depth)?;
        writer.write_mask(f.id, &f.mask)?;
        progress(done.fetch_add(1, Ordering::Relaxed) + 1, jobs.len());
        Ok(())
    })?;
    writer.write_status(CaptureStatus { complete: true, frames })?;
    Ok(())
}

/// A turbo-like colour map of `t` in [0, 1].
fn colormap(t: f32) -> [u8; 3] {
    let t = t.clamp(0.0, 1.0);
    let r = (34.61 + t * (1172.33 - t * (10793.56 - t * (33300.12 - t * (38394.49 - t * 14825.05))))) / 255.0;
    let g = (23.31 + t * (557.33 + t * (1225.33 - t * (3574.96 - t * (1073.77 + t * 707.56))))) / 255.0;
    let b = (27.2 + t * (3211.1 - t * (15327.97 - t * (27814.0 - t * (22569.18 - t * 6838.66))))) / 255.0;
    [r, g, b].map(|v| (v.clamp(0.0, 1.0) * 255.0) as u8)
}

/// A contact sheet: one row per frame with the colour image, the mask and the raw depth
/// colour-mapped (near = blue, far = red, no reading = black), each scaled to 320 px wide.
pub fn contact_sheet(frames: &[&RenderedFrame], metres_per_unit: f64) -> RgbImage {
    let (cw, ch) = (320u32, 256u32);
    let mut sheet = RgbImage::from_pixel(3 * cw + 40, frames.len() as u32 * (ch + 10) + 10, Rgb([255, 255, 255]));
    for (row, f) in frames.iter().enumerate() {
        let y0 = 10 + row as u32 * (ch + 10);
        let color = image::imageops::resize(&f.color, cw, ch, image::imageops::FilterType::Triangle);
        image::imageops::replace(&mut sheet, &color, 10, i64::from(y0));
        let (mw, mh) = f.mask.dims();
        let mask = RgbImage::from_fn(cw, ch, |x, y| {
            let on = *f.mask.at(x as usize * mw / cw as usize, y as usize * mh / ch as usize);
            if on { Rgb([0, 0, 0]) } else { Rgb([235, 235, 235]) }
        });
        image::imageops::replace(&mut sheet, &mask, i64::from(cw + 20), i64::from(y0));
        let (dw, dh) = f.raw_depth.dims();
        let valid: Vec<f64> =
            f.raw_depth.as_slice().iter().filter(|&&d| d > 0).map(|&d| f64::from(d) * metres_per_unit).collect();
        let (lo, hi) = valid.iter().fold((f64::MAX, f64::MIN), |(a, b), &z| (a.min(z), b.max(z)));
        let dh_scaled = cw * dh as u32 / dw as u32;
        let depth = RgbImage::from_fn(cw, dh_scaled, |x, y| {
            let d = *f.raw_depth.at(x as usize * dw / cw as usize, y as usize * dh / dh_scaled as usize);
            if d == 0 {
                return Rgb([0, 0, 0]);
            }
            let z = f64::from(d) * metres_per_unit;
            Rgb(colormap(((z - lo) / (hi - lo).max(1e-6)) as f32))
        });
        image::imageops::replace(&mut sheet, &depth, i64::from(2 * cw + 30), i64::from(y0));
    }
    sheet
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angle_ranges() {
        assert_eq!(parse_angles("0:357:3").unwrap().len(), 120);
        assert_eq!(parse_angles("30,0,15,15").unwrap(), vec![0, 15, 30]);
        assert_eq!(parse_angles("45").unwrap(), vec![45]);
        assert_eq!(parse_fractional_angles("0:1:0.25").unwrap(), vec![0.0, 0.25, 0.5, 0.75, 1.0]);
        assert_eq!(parse_fractional_angles("3,0.5").unwrap(), vec![0.5, 3.0]);
        assert!(matches!(parse_angles("0.5"), Err(SynthError::BadAngles { .. })));
        for bad in ["0:357:0", "30:0:3", "0:360:3", "a:b:c", "0:10", "", "370", "1,-2", "nan", "0:1:-0.5"] {
            let e = parse_angles(bad);
            assert!(matches!(e, Err(SynthError::BadAngles { .. })), "{bad}: {e:?}");
        }
    }
}
