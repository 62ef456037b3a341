//! Synthetic twins of real frames: an object's textured scan rendered where a real frame's
//! annotation puts it, through that frame's camera, with the sensor effects of the noise profile
//! and [`FrameEffects`]. A twin of a real sequence has the real views (camera, resolution,
//! distance, object pose and motion), so its errors predict the real ones object by object, or
//! show what the synthetic model of the sensor is missing.
//!
//! Other annotated objects may be rendered with it ([`Occluder`]): where one is nearer, it hides
//! the object (colour, depth and mask). The unannotated surroundings (table, background) are not
//! rendered. Each object is lit by the scene's light fixed in its own frame (a static scene). The
//! depth image is taken at the colour exposure (no delay between the two).

use crate::capture::{RenderedView, ViewTiming, render_view};
use crate::effects::{FrameDraw, FrameEffects};
use crate::error::{SynthError, positive_and_finite};
use crate::mesh::TexturedMesh;
use crate::noise::NoiseProfile;
use crate::rig::RigSensor;
use crate::scene::Scene;
use flowfilter_camera::RgbdSensor;
use flowfilter_geometry::{Mask, Pose, RawDepth};
use image::RgbImage;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// How a twin's frames are made.
#[derive(Debug, Clone)]
pub struct TwinOptions {
    /// Sensor noise (`None` = exact data).
    pub noise: Option<NoiseProfile>,
    /// Per-frame effects of real captures (the depth delay is not used: see the module
    /// documentation).
    pub effects: FrameEffects,
    /// Focal length of the depth sensor's own camera, pixels: structured-light disparity is
    /// quantised at it (575 for PrimeSense-class sensors such as the Xtion at 640 x 480).
    pub depth_focal_px: f64,
    /// Offset of the structured-light projector from the depth camera, metres (projector
    /// shadows).
    pub projector_baseline_m: f64,
    /// An offset of every frame's mask, pixels (x, y), on top of the frame's own draw: masks
    /// rendered from a pose annotation share its error in every frame.
    pub mask_offset_px: (i32, i32),
    /// Seed of all randomness.
    pub seed: u64,
}

impl Default for TwinOptions {
    /// The noise profile and the effects fitted to the real YCB-Video sample
    /// ([`NoiseProfile::xtion_sample`], [`FrameEffects::XTION_SAMPLE`] and its masks' common
    /// offset of (-2, 2) px), a PrimeSense-class depth sensor.
    fn default() -> Self {
        Self {
            noise: Some(NoiseProfile::xtion_sample()),
            effects: FrameEffects::XTION_SAMPLE,
            depth_focal_px: 575.0,
            projector_baseline_m: 0.075,
            mask_offset_px: (-2, 2),
            seed: 7,
        }
    }
}

/// One rendered frame of a twin.
#[derive(Debug, Clone)]
pub struct TwinView {
    /// Colour image (noise, gain and row shear applied).
    pub color: RgbImage,
    /// Depth in the sensor's units (0 = no reading), on its depth camera's grid (registered to
    /// colour for [`render_twin_view`], whose sensors are).
    pub depth: RawDepth,
    /// The object's mask as an annotation would give it (perturbed by the frame's effects).
    pub mask: Mask,
    /// The exact mask.
    pub true_mask: Mask,
    /// What the frame's effects drew.
    pub draw: FrameDraw,
}

/// Another object of the frame, rendered with the object so that it can hide it.
#[derive(Debug, Clone, Copy)]
pub struct Occluder<'a> {
    /// Its scan.
    pub mesh: &'a TexturedMesh,
    /// `T_camera_from_object` of it.
    pub camera_from_object: Pose,
}

/// The seed of frame `frame` of a twin seeded with `seed`; `salt` tells kinds of twin apart.
pub(crate) fn frame_seed(seed: u64, frame: u32, salt: u64) -> u64 {
    seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ u64::from(frame) ^ salt
}

/// One frame of a twin being rendered: its effects drawn first, then each mesh rendered
/// through the sensor with the profile's noise (one generator for the frame, so the order of
/// the renders is part of the draw), and the effects applied to the composed view.
pub(crate) struct FrameRender<'a> {
    rig_sensor: RigSensor,
    rng: ChaCha8Rng,
    draw: FrameDraw,
    opts: &'a TwinOptions,
    unlit: bool,
}

impl<'a> FrameRender<'a> {
    /// A frame seeded with `seed`; `unlit` meshes carry their light in their texture.
    pub(crate) fn new(sensor: &RgbdSensor, opts: &'a TwinOptions, seed: u64, unlit: bool) -> Self {
        let rig_sensor = RigSensor {
            rgbd: *sensor,
            h_color_from_world: Pose::identity(),
            projector_baseline: opts.projector_baseline_m,
            ir_depth_scale: 1.0,
        };
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut draw = opts.effects.draw(&mut rng);
        draw.mask_shift.0 += opts.mask_offset_px.0;
        draw.mask_shift.1 += opts.mask_offset_px.1;
        Self { rig_sensor, rng, draw, opts, unlit }
    }

    /// `mesh` seen from `camera_from_mesh`.
    pub(crate) fn render(&mut self, mesh: &TexturedMesh, camera_from_mesh: &Pose) -> RenderedView {
        let mut scene = Scene::alone(mesh.clone(), self.opts.seed);
        if self.unlit {
            (scene.ambient, scene.diffuse) = (1.0, 0.0);
        }
        let timing = ViewTiming {
            color_from_table: *camera_from_mesh,
            color_from_table_at_depth: *camera_from_mesh,
            world_from_table: Pose::identity(),
        };
        let focal = self.opts.depth_focal_px;
        render_view(&scene, &self.rig_sensor, timing, self.opts.noise.as_ref(), focal, &mut self.rng)
    }

    /// The composed view with the frame's gain, row shear and mask defects.
    pub(crate) fn finish(self, mut view: RenderedView) -> TwinView {
        self.draw.apply_gain(&mut view.color);
        self.draw.apply_row_shear(&mut view.color);
        TwinView {
            color: view.color,
            depth: view.raw_depth,
            mask: self.draw.perturb_mask(&view.mask),
            true_mask: view.mask,
            draw: self.draw,
        }
    }
}

/// Render `object` seen by `sensor` (depth registered to colour) at `camera_from_object`, hidden
/// where any of `occluders` is nearer, as frame `frame` of a twin (the frame number seeds its
/// noise and effects).
///
/// # Errors
/// [`SynthError::BadOption`] when `sensor`'s depth is not registered to its colour image, or for
/// a depth focal length or projector baseline that is not positive and finite.
///
/// # Example
/// ```
/// use flowfilter_camera::{CameraModel, Distortion, ImageSize, Intrinsics, RgbdSensor};
/// use flowfilter_geometry::{Pose, Vector3};
/// use flowfilter_synth::{TwinOptions, procedural, render_twin_view};
///
/// let camera = CameraModel::new(Intrinsics::new(500.0, 500.0, 80.0, 60.0)?, Distortion::NONE, ImageSize::new(160, 120)?);
/// let sensor = RgbdSensor::registered(camera, 1e-4)?;
/// let object = procedural("box", 1)?;
/// let pose = Pose::new(Vector3::new(0.0, 0.0, 0.8), Vector3::new(1.6, 0.0, 0.0));
/// let view = render_twin_view(&object, &sensor, &pose, &[], &TwinOptions::default(), 1)?;
/// assert!(view.true_mask.as_slice().iter().any(|m| *m));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn render_twin_view(
    object: &TexturedMesh,
    sensor: &RgbdSensor,
    camera_from_object: &Pose,
    occluders: &[Occluder<'_>],
    opts: &TwinOptions,
    frame: u32,
) -> Result<TwinView, SynthError> {
    check_options(sensor, opts)?;
    let mut frame_render = FrameRender::new(sensor, opts, frame_seed(opts.seed, frame, 0x7781), false);
    let mut view = frame_render.render(object, camera_from_object);
    for o in occluders {
        let other = frame_render.render(o.mesh, &o.camera_from_object);
        hide_behind(&mut view, &other);
    }
    Ok(frame_render.finish(view))
}

/// Where `other`'s surface is nearer than `view`'s (or `view` shows nothing), `view` shows
/// `other`: its colour and depth, and no object in the mask.
fn hide_behind(view: &mut RenderedView, other: &RenderedView) {
    let width = view.color.width() as usize;
    for (k, &o) in other.clean_depth.as_slice().iter().enumerate() {
        let z = view.clean_depth.as_slice()[k];
        if o > 0.0 && (z <= 0.0 || o < z) {
            let (x, y) = ((k % width) as u32, (k / width) as u32);
            view.color.put_pixel(x, y, *other.color.get_pixel(x, y));
            view.raw_depth.as_mut_slice()[k] = other.raw_depth.as_slice()[k];
            view.clean_depth.as_mut_slice()[k] = o;
            view.mask.as_mut_slice()[k] = false;
        }
    }
}

fn check_options(sensor: &RgbdSensor, opts: &TwinOptions) -> Result<(), SynthError> {
    if !sensor.is_registered() {
        return Err(SynthError::BadOption {
            field: "sensor",
            message: "a twin's depth must be registered to its colour image (one camera for both)".into(),
        });
    }
    positive_and_finite(&[("depth_focal_px", opts.depth_focal_px), ("projector_baseline_m", opts.projector_baseline_m)])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::procedural::procedural;
    use flowfilter_camera::{CameraModel, Distortion, ImageSize, Intrinsics};
    use flowfilter_geometry::Vector3;

    fn sensor() -> RgbdSensor {
        let camera = CameraModel::new(
            Intrinsics::new(520.0, 520.0, 160.0, 120.0).unwrap(),
            Distortion::NONE,
            ImageSize::new(320, 240).unwrap(),
        );
        RgbdSensor::registered(camera, 1e-4).unwrap()
    }

    /// The object appears where the pose puts it: the mask's centre is the projection of the
    /// object's centre (within 6 px: the faces the camera sees pull it; an object off by half
    /// its size would be 30 px off), and the depth there is on the object.
    #[test]
    fn the_object_is_rendered_where_its_pose_puts_it() {
        let object = procedural("box", 3).unwrap().centred();
        let opts =
            TwinOptions { noise: None, effects: FrameEffects::NONE, mask_offset_px: (0, 0), ..TwinOptions::default() };
        for (x, y) in [(0.0, 0.0), (0.06, -0.03)] {
            let pose = Pose::new(Vector3::new(x, y, 0.9), Vector3::new(0.3, 0.2, 0.1));
            let view = render_twin_view(&object, &sensor(), &pose, &[], &opts, 1).unwrap();
            let (w, _) = view.true_mask.dims();
            let on: Vec<usize> =
                (0..view.true_mask.as_slice().len()).filter(|&k| view.true_mask.as_slice()[k]).collect();
            let (u, v) = on.iter().fold((0.0, 0.0), |(u, v), &k| (u + (k % w) as f64, v + (k / w) as f64));
            let (u, v) = (u / on.len() as f64, v / on.len() as f64);
            let (eu, ev) = (160.0 + 520.0 * x / 0.9, 120.0 + 520.0 * y / 0.9);
            assert!(
                (u - eu).abs() < 6.0 && (v - ev).abs() < 6.0,
                "mask centre ({u:.1}, {v:.1}) against ({eu:.1}, {ev:.1})"
            );
            let k = on[on.len() / 2];
            let z = f64::from(view.depth.as_slice()[k]) * 1e-4;
            // In front of the centre, within the object's half diagonal.
            let (lo, hi) = object.bounds();
            let reach = f64::from((hi - lo).norm()) / 2.0;
            assert!(z < 0.9 && z > 0.9 - reach, "{z} m, half diagonal {reach} m");
            assert_eq!(view.mask, view.true_mask, "no effects: the mask is exact");
        }
    }

    /// An object in front hides what it covers: colour, depth and mask show the occluder
    /// there; one behind hides nothing.
    #[test]
    fn a_nearer_object_hides_the_object() {
        let object = procedural("box", 3).unwrap().centred();
        let other = procedural("can", 4).unwrap().centred();
        let opts =
            TwinOptions { noise: None, effects: FrameEffects::NONE, mask_offset_px: (0, 0), ..TwinOptions::default() };
        let pose = Pose::new(Vector3::new(0.0, 0.0, 0.9), Vector3::new(0.3, 0.2, 0.1));
        let count = |m: &Mask| m.as_slice().iter().filter(|v| **v).count();
        let alone = render_twin_view(&object, &sensor(), &pose, &[], &opts, 1).unwrap();
        let front =
            Occluder { mesh: &other, camera_from_object: Pose::new(Vector3::new(0.03, 0.0, 0.6), Vector3::zeros()) };
        let hidden = render_twin_view(&object, &sensor(), &pose, &[front], &opts, 1).unwrap();
        assert!(count(&hidden.mask) < count(&alone.mask) * 9 / 10, "{} of {}", count(&hidden.mask), count(&alone.mask));
        let k =
            (0..alone.mask.as_slice().len()).find(|&k| alone.mask.as_slice()[k] && !hidden.mask.as_slice()[k]).unwrap();
        let (z_alone, z_hidden) = (alone.depth.as_slice()[k], hidden.depth.as_slice()[k]);
        assert!(z_hidden > 0 && z_hidden < z_alone, "{z_hidden} against {z_alone}");
        let behind =
            Occluder { camera_from_object: Pose::new(Vector3::new(0.03, 0.0, 1.4), Vector3::zeros()), ..front };
        let unhidden = render_twin_view(&object, &sensor(), &pose, &[behind], &opts, 1).unwrap();
        assert_eq!(unhidden.mask, alone.mask);
    }

    #[test]
    fn bad_options_are_refused() {
        let object = procedural("can", 1).unwrap().centred();
        let pose = Pose::new(Vector3::new(0.0, 0.0, 0.8), Vector3::zeros());
        let opts = TwinOptions { depth_focal_px: 0.0, ..TwinOptions::default() };
        let e = render_twin_view(&object, &sensor(), &pose, &[], &opts, 1).unwrap_err().to_string();
        assert!(e.contains("depth_focal_px"), "{e}");
        let camera = sensor().color;
        let apart = RgbdSensor::new(camera, camera, Pose::translation(0.025, 0.0, 0.0), 1e-4).unwrap();
        let e = render_twin_view(&object, &apart, &pose, &[], &TwinOptions::default(), 1).unwrap_err().to_string();
        assert!(e.contains("registered"), "{e}");
    }
}
