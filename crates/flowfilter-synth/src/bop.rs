//! Synthetic scenes in the BOP layout: one rig sensor's colour camera (pinhole: BOP images are
//! undistorted) watching the object turn, with depth registered to colour as RealSense aligned
//! depth, YCB-Video and every BOP dataset deliver it.
//!
//! A scene folder gets `scene_camera.json` (`cam_K`, `depth_scale`), `scene_gt.json`
//! (`cam_R_m2c`, `cam_t_m2c` in millimetres, `obj_id`), `scene_gt_info.json` (boxes, pixel
//! counts, `visib_fract`), `rgb/{im_id:06d}.png`, `depth/{im_id:06d}.png` (16-bit, value x
//! `depth_scale` = millimetres), `mask/` and `mask_visib/{im_id:06d}_000000.png`. The object
//! frame is the table frame of the turntable scene; image `i` shows the turntable at
//! `angles_deg[i]`.
//!
//! Real frames differ from renders, and the scenes carry it: the noise profile's structured-light
//! depth (disparity quantised at the depth sensor's own focal length, flying and dropped pixels,
//! projector shadows) and colour noise and blur, plus [`FrameEffects`] per frame (exposure and
//! white balance, masks off by a few pixels, depth taken at another instant than colour, a rolling
//! shutter's row shear of the colour image). The
//! annotations stay exact: `scene_gt.json` is the pose at the colour exposure, and the pixel
//! counts of `scene_gt_info.json` come from the unperturbed masks.

use crate::capture::{ViewTiming, render_gbuffer, render_view};
use crate::effects::{FrameDraw, FrameEffects};
use crate::error::SynthError;
use crate::noise::NoiseProfile;
use crate::rig::{RigSensor, world_from_table};
use crate::scene::Scene;
use flowfilter_camera::raster::NO_TRIANGLE;
use flowfilter_camera::{CameraModel, Distortion, RgbdSensor};
use flowfilter_geometry::atomic::{write_atomic, write_atomic_with};
use flowfilter_geometry::{Mask, Pose, RawDepth, mask_bbox};
use image::{ImageBuffer, Luma, RgbImage};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde_json::{Value, json};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

/// What to synthesise for one BOP scene.
#[derive(Debug, Clone)]
pub struct BopSceneOptions {
    /// Turntable angle of each image (image id = index), degrees; fractions allowed.
    pub angles_deg: Vec<f64>,
    /// Sensor noise (`None` = exact data).
    pub noise: Option<NoiseProfile>,
    /// Per-frame effects of real captures.
    pub effects: FrameEffects,
    /// Seed of all randomness.
    pub seed: u64,
    /// The object's id in `scene_gt.json`.
    pub obj_id: u32,
    /// Millimetres per depth unit (`depth_scale`; YCB-Video 0.1, most BOP datasets 1.0 or 0.1).
    pub depth_scale_mm: f64,
}

/// One rendered image of a BOP scene with its annotation.
#[derive(Debug, Clone)]
pub struct BopView {
    /// Colour image (noise and gain applied).
    pub color: RgbImage,
    /// Depth registered to colour, in units of `depth_scale_mm` (0 = no reading).
    pub depth: RawDepth,
    /// The visible mask as written (perturbed by the frame's effects).
    pub mask_visib: Mask,
    /// The unoccluded silhouette as written (perturbed the same way).
    pub mask: Mask,
    /// The exact visible mask.
    pub true_visib: Mask,
    /// The exact unoccluded silhouette.
    pub true_mask: Mask,
    /// `T_cam_from_obj` at the colour exposure.
    pub cam_from_obj: Pose,
    /// What the frame's effects drew.
    pub draw: FrameDraw,
}

/// The registered, undistorted camera of a BOP scene taken with rig sensor `s`: its colour
/// camera without lens distortion, depth on the same grid, `depth_scale_mm` per unit.
///
/// # Errors
/// [`SynthError::BadOption`] for a depth scale that is not positive and finite.
pub fn bop_sensor(s: &RigSensor, depth_scale_mm: f64) -> Result<RigSensor, SynthError> {
    let camera = CameraModel::new(s.rgbd.color.intrinsics, Distortion::NONE, s.rgbd.color.size);
    let rgbd = RgbdSensor::registered(camera, depth_scale_mm * 1e-3)
        .map_err(|e| SynthError::BadOption { field: "depth_scale_mm", message: e.to_string() })?;
    Ok(RigSensor { rgbd, ..s.clone() })
}

fn image_seed(seed: u64, obj_id: u32, im_id: usize) -> u64 {
    seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (u64::from(obj_id) << 32) ^ im_id as u64 ^ 0xB0B0
}

/// Render image `im_id` of a scene seen by rig sensor `s` (see [`bop_sensor`]).
///
/// # Errors
/// [`SynthError::BadOption`] for an image id without an angle or a bad depth scale.
pub fn render_bop_view(
    scene: &Scene,
    s: &RigSensor,
    opts: &BopSceneOptions,
    im_id: usize,
) -> Result<BopView, SynthError> {
    let camera = BopCamera::new(scene, s, opts)?;
    camera.render(scene, opts, im_id)
}

/// What every image of a scene shares: the rig sensor, its registered BOP camera, and the object
/// without the table (for the unoccluded silhouette).
struct BopCamera<'a> {
    sensor: &'a RigSensor,
    registered: RigSensor,
    alone: Scene,
}

impl<'a> BopCamera<'a> {
    fn new(scene: &Scene, sensor: &'a RigSensor, opts: &BopSceneOptions) -> Result<Self, SynthError> {
        Ok(Self { sensor, registered: bop_sensor(sensor, opts.depth_scale_mm)?, alone: scene.object_only() })
    }

    /// Image `im_id` (see [`render_bop_view`]).
    fn render(&self, scene: &Scene, opts: &BopSceneOptions, im_id: usize) -> Result<BopView, SynthError> {
        let (s, registered) = (self.sensor, &self.registered);
        let angle = *opts.angles_deg.get(im_id).ok_or_else(|| SynthError::BadOption {
            field: "angles_deg",
            message: format!("no angle for image {im_id} ({} angles)", opts.angles_deg.len()),
        })?;
        let mut rng = ChaCha8Rng::seed_from_u64(image_seed(opts.seed, opts.obj_id, im_id));
        let draw = opts.effects.draw(&mut rng);
        let timing = ViewTiming::turntable(registered, angle, angle + draw.depth_delay_deg);
        // Disparity is measured by the depth sensor: its focal length sets the quantisation.
        let mut view =
            render_view(scene, registered, timing, opts.noise.as_ref(), s.rgbd.depth.intrinsics.fx, &mut rng);
        draw.apply_gain(&mut view.color);
        draw.apply_row_shear(&mut view.color);
        let cam_from_obj = registered.h_color_from_world * world_from_table(angle);
        let alone = render_gbuffer(&self.alone, &registered.rgbd.color, &cam_from_obj);
        let silhouette =
            Mask::from_vec(alone.width, alone.height, alone.triangle.iter().map(|&t| t != NO_TRIANGLE).collect())
                .expect("sized");
        Ok(BopView {
            color: view.color,
            depth: view.raw_depth,
            mask_visib: draw.perturb_mask(&view.mask),
            mask: draw.perturb_mask(&silhouette),
            true_mask: silhouette,
            true_visib: view.mask,
            cam_from_obj,
            draw,
        })
    }
}

/// `[x, y, width, height]` of a mask's pixels (`[-1, -1, -1, -1]` when empty, as BOP writes).
fn bbox(mask: &Mask) -> [i64; 4] {
    mask_bbox(mask).map_or([-1; 4], |(x0, y0, x1, y1)| [x0, y0, x1 - x0 + 1, y1 - y0 + 1].map(|v| v as i64))
}

fn write_error(path: &Path, e: impl std::fmt::Display) -> SynthError {
    SynthError::Write { path: path.to_path_buf(), message: e.to_string() }
}

fn save_mask(mask: &Mask, path: &Path) -> Result<(), SynthError> {
    let (w, h) = mask.dims();
    let img: ImageBuffer<Luma<u8>, Vec<u8>> =
        ImageBuffer::from_fn(w as u32, h as u32, |x, y| Luma([if *mask.at(x as usize, y as usize) { 255 } else { 0 }]));
    save_image(&img, path)
}

fn save_depth(depth: &RawDepth, path: &Path) -> Result<(), SynthError> {
    let (w, h) = depth.dims();
    let img: ImageBuffer<Luma<u16>, Vec<u16>> =
        ImageBuffer::from_fn(w as u32, h as u32, |x, y| Luma([*depth.at(x as usize, y as usize)]));
    save_image(&img, path)
}

fn write_json(path: &Path, value: &Value) -> Result<(), SynthError> {
    let text = serde_json::to_string_pretty(value).map_err(|e| write_error(path, e))?;
    write_atomic(path, (text + "\n").as_bytes()).map_err(|e| write_error(path, e))
}

/// Save an image (format by extension) whole or not at all.
fn save_image<P, C>(img: &ImageBuffer<P, C>, path: &Path) -> Result<(), SynthError>
where
    P: image::PixelWithColorType,
    [P::Subpixel]: image::EncodableLayout,
    C: std::ops::Deref<Target = [P::Subpixel]>,
{
    write_atomic_with(path, |p| img.save(p).map_err(std::io::Error::other)).map_err(|e| write_error(path, e))
}

/// The three annotation entries of one image.
fn annotations(view: &BopView, s: &RigSensor, opts: &BopSceneOptions) -> (Value, Value, Value) {
    let k = &s.rgbd.color.intrinsics;
    let camera =
        json!({"cam_K": [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0], "depth_scale": opts.depth_scale_mm});
    let r = view.cam_from_obj.rotation.to_rotation_matrix();
    let t = view.cam_from_obj.translation.vector * 1e3;
    let gt = json!([{
        "cam_R_m2c": (0..3).flat_map(|i| (0..3).map(move |j| r[(i, j)])).collect::<Vec<f64>>(),
        "cam_t_m2c": [t.x, t.y, t.z],
        "obj_id": opts.obj_id,
    }]);
    let count = |m: &Mask| m.as_slice().iter().filter(|v| **v).count();
    let (all, visib) = (count(&view.true_mask), count(&view.true_visib));
    let valid = view.true_visib.as_slice().iter().zip(view.depth.as_slice()).filter(|(m, d)| **m && **d > 0).count();
    let info = json!([{
        "bbox_obj": bbox(&view.true_mask),
        "bbox_visib": bbox(&view.true_visib),
        "px_count_all": all,
        "px_count_valid": valid,
        "px_count_visib": visib,
        "visib_fract": if all > 0 { visib as f64 / all as f64 } else { 0.0 },
    }]);
    (camera, gt, info)
}

/// Render every image of a scene seen by rig sensor `s` and write the scene folder `dir` in the
/// BOP layout. `progress(done, total)` is called after each image (from worker threads).
///
/// # Errors
/// [`SynthError::BadOption`] for no angles or a bad depth scale, [`SynthError::Write`] naming a
/// file that cannot be written.
pub fn write_bop_scene(
    dir: &Path,
    scene: &Scene,
    s: &RigSensor,
    opts: &BopSceneOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<(), SynthError> {
    if opts.angles_deg.is_empty() {
        return Err(SynthError::BadOption { field: "angles_deg", message: "no angles".into() });
    }
    let camera = BopCamera::new(scene, s, opts)?;
    for sub in ["rgb", "depth", "mask", "mask_visib"] {
        let d = dir.join(sub);
        std::fs::create_dir_all(&d).map_err(|e| write_error(&d, e))?;
    }
    let done = AtomicUsize::new(0);
    let n = opts.angles_deg.len();
    let entries = (0..n)
        .into_par_iter()
        .map(|im| -> Result<(Value, Value, Value), SynthError> {
            let view = camera.render(scene, opts, im)?;
            let rgb = dir.join("rgb").join(format!("{im:06}.png"));
            save_image(&view.color, &rgb)?;
            save_depth(&view.depth, &dir.join("depth").join(format!("{im:06}.png")))?;
            save_mask(&view.mask, &dir.join("mask").join(format!("{im:06}_000000.png")))?;
            save_mask(&view.mask_visib, &dir.join("mask_visib").join(format!("{im:06}_000000.png")))?;
            progress(done.fetch_add(1, Ordering::Relaxed) + 1, n);
            Ok(annotations(&view, &camera.registered, opts))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let by_image = |pick: fn(&(Value, Value, Value)) -> &Value| -> Value {
        Value::Object(entries.iter().enumerate().map(|(im, e)| (im.to_string(), pick(e).clone())).collect())
    };
    write_json(&dir.join("scene_camera.json"), &by_image(|e| &e.0))?;
    write_json(&dir.join("scene_gt.json"), &by_image(|e| &e.1))?;
    write_json(&dir.join("scene_gt_info.json"), &by_image(|e| &e.2))
}
