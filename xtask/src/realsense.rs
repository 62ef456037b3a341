//! Folders of RGB-D frames with calibrated camera poses, as `../shared/data/realsense-shelf`
//! ships them: `frame-NNNNNN.color.png`, `frame-NNNNNN.depth.png` (raw depth of the depth
//! camera, or depth registered to colour), `camera.json` (this project's camera file) and
//! `poses.json` (`camera_to_world_calibrated`: frame id -> 4x4 camera-to-world, metres).
//!
//! The scene is static, so any region of it is an "object" with exact truth: a region is a ball
//! of the scene ([`Region`]), its true mask in a frame the colour pixels its depth points cover
//! (holes of the sparse depth closed), and the mask a pair is given that true mask with a
//! segmentation network's defects ([`NetworkMaskModel`]), drawn from a seed per frame and
//! region.

use flowfilter_pipeline::camera::RgbdSensor;
use flowfilter_pipeline::{CameraFile, FrameFiles, Mask, MaskSource, Point3, Pose, RgbdFrame};
use flowfilter_synth::{NetworkMaskModel, grown};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// A ball of the static scene, in world coordinates: the stand-in for an object.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Region {
    /// Centre, world frame, metres.
    pub centre: Point3,
    /// Radius, metres.
    pub radius: f64,
}

/// A folder of frames with calibrated camera poses.
pub struct PosedFrames {
    dir: PathBuf,
    camera: CameraFile,
    /// Frame id -> camera-to-world.
    poses: BTreeMap<u32, Pose>,
}

/// Whether `dir` holds posed frames (`poses.json` and `camera.json`).
pub fn is_posed_folder(dir: &Path) -> bool {
    dir.join("poses.json").is_file() && dir.join("camera.json").is_file()
}

/// Smallest area of a region's true mask in both frames of a pair, pixels.
pub const MIN_REGION_PX: usize = 2500;

/// Smallest fraction of a region's pixels with texture (a grey step of at least
/// [`TEXTURE_GRADIENT`] across [`TEXTURE_SPAN`] pixels either way): regions stand in for objects a robot tracks (books, boxes,
/// bags), not for a blank shelf front that no image method can place.
pub const MIN_TEXTURED_FRACTION: f64 = 0.3;

/// Grey-level step (of 255) between a pixel's neighbours that counts as texture.
const TEXTURE_GRADIENT: f64 = 10.0;

/// Half the span of the differences that measure texture, pixels (a poster's flat squares
/// count near their edges).
const TEXTURE_SPAN: usize = 4;

/// Pixels the true mask is closed by (the registered SR300 depth leaves a grid of holes).
const CLOSING_PX: f64 = 4.0;

impl PosedFrames {
    /// Read `camera.json` and `poses.json` (only frames whose colour and depth files exist).
    ///
    /// # Errors
    /// A message naming the file and the field.
    pub fn open(dir: &Path) -> Result<Self, String> {
        let camera = CameraFile::from_file(&dir.join("camera.json")).map_err(|e| e.to_string())?;
        let cameras =
            flowfilter_track::tum::read_calibrated_poses(&dir.join("poses.json")).map_err(|e| e.to_string())?;
        let mut poses = BTreeMap::new();
        for (id, pose) in cameras {
            let im = u32::try_from(id).map_err(|_| format!("{}: frame number {id} is too large", dir.display()))?;
            let frames = Self::files_of(dir, im);
            if frames.color.is_file() && frames.depth.is_file() {
                poses.insert(im, pose);
            }
        }
        if poses.is_empty() {
            return Err(format!("{}: no posed frame has frame-NNNNNN.color.png and .depth.png", dir.display()));
        }
        Ok(Self { dir: dir.to_path_buf(), camera, poses })
    }

    fn files_of(dir: &Path, im: u32) -> FrameFiles {
        FrameFiles {
            color: dir.join(format!("frame-{im:06}.color.png")),
            depth: dir.join(format!("frame-{im:06}.depth.png")),
            mask: MaskSource::None,
        }
    }

    /// The frame ids, in order.
    pub fn ids(&self) -> Vec<u32> {
        self.poses.keys().copied().collect()
    }

    /// The scene's motion in the camera frame from frame `a` to frame `b`: `inv(C_b) * C_a`.
    ///
    /// # Errors
    /// A frame without a pose.
    pub fn relative_motion(&self, a: u32, b: u32) -> Result<Pose, String> {
        let pose = |i: u32| self.poses.get(&i).ok_or_else(|| format!("{}: no pose of frame {i}", self.dir.display()));
        Ok(pose(b)?.inverse() * pose(a)?)
    }

    /// Frame `im`, whole (its mask: every pixel).
    ///
    /// # Errors
    /// Files that cannot be read or do not fit the camera.
    pub fn frame(&self, im: u32) -> Result<RgbdFrame, String> {
        Self::files_of(&self.dir, im).load(&self.camera, &format!("frame-{im:06}")).map_err(|e| e.to_string())
    }

    /// The true mask of `region` in frame `im` (`frame` is that frame): the colour pixels that
    /// its depth points inside the ball fall on, closed over the depth's holes.
    pub fn true_mask(&self, frame: &RgbdFrame, im: u32, region: &Region) -> Mask {
        let world_from_camera = self.poses[&im];
        let sensor = &frame.sensor;
        let (w, h) = frame.mask.dims();
        let mut hit = Mask::filled(w, h, false);
        for (p, pixel) in depth_points(sensor, frame) {
            if (world_from_camera * p - region.centre).norm() <= region.radius {
                let (x, y) = (pixel.0.round(), pixel.1.round());
                if x >= 0.0 && y >= 0.0 && (x as usize) < w && (y as usize) < h {
                    *hit.at_mut(x as usize, y as usize) = true;
                }
            }
        }
        grown(&grown(&hit, CLOSING_PX), -CLOSING_PX)
    }

    /// A region seen in frames `a` and `b` (each true mask at least [`MIN_REGION_PX`]), drawn
    /// from `seed`: the ball around a random depth point of frame `a` away from the image's
    /// border, 6-11 cm in radius. `None` when 40 draws find none.
    pub fn draw_region(&self, frames: (&RgbdFrame, &RgbdFrame), (a, b): (u32, u32), seed: u64) -> Option<Region> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let points: Vec<(Point3, (f64, f64))> = depth_points(&frames.0.sensor, frames.0).collect();
        let (w, h) = frames.0.mask.dims();
        let central = |(x, y): (f64, f64)| (0.2..0.8).contains(&(x / w as f64)) && (0.2..0.8).contains(&(y / h as f64));
        let candidates: Vec<Point3> = points.iter().filter(|(_, px)| central(*px)).map(|(p, _)| *p).collect();
        if candidates.is_empty() {
            return None;
        }
        (0..40).find_map(|_| {
            let p = candidates[rng.random_range(0..candidates.len())];
            let region = Region { centre: self.poses[&a] * p, radius: rng.random_range(0.06..0.11) };
            let mask = self.true_mask(frames.0, a, &region);
            let seen = mask.count() >= MIN_REGION_PX
                && self.true_mask(frames.1, b, &region).count() >= MIN_REGION_PX
                && textured_fraction(frames.0, &mask) >= MIN_TEXTURED_FRACTION;
            seen.then_some(region)
        })
    }
}

/// The mask a segmentation network gives of `truth`, drawn from `seed` under `model`; `None`
/// when it gives none (a model frame always gets one: the user's first mask).
pub fn network_mask(truth: &Mask, model: &NetworkMaskModel, seed: u64, is_model_frame: bool) -> Option<Mask> {
    let mut defects = model.draw(&mut ChaCha8Rng::seed_from_u64(seed));
    defects.missing &= !is_model_frame;
    defects.apply(truth)
}

/// The fraction of `mask`'s pixels whose grey step across [`TEXTURE_SPAN`] pixels either way
/// is at least [`TEXTURE_GRADIENT`].
fn textured_fraction(frame: &RgbdFrame, mask: &Mask) -> f64 {
    let (w, h) = mask.dims();
    let grey = |x: usize, y: usize| {
        let p = frame.color.get_pixel(x as u32, y as u32).0;
        0.299 * f64::from(p[0]) + 0.587 * f64::from(p[1]) + 0.114 * f64::from(p[2])
    };
    let (mut n, mut textured) = (0usize, 0usize);
    let k = TEXTURE_SPAN;
    for y in k..h - k {
        for x in k..w - k {
            if *mask.at(x, y) {
                n += 1;
                let gx = grey(x + k, y) - grey(x - k, y);
                let gy = grey(x, y + k) - grey(x, y - k);
                textured += usize::from(gx.hypot(gy) >= TEXTURE_GRADIENT);
            }
        }
    }
    if n == 0 { 0.0 } else { textured as f64 / n as f64 }
}

/// Every depth reading of a frame as a point in the colour camera's frame and the colour pixel
/// it falls on.
fn depth_points<'a>(sensor: &'a RgbdSensor, frame: &'a RgbdFrame) -> impl Iterator<Item = (Point3, (f64, f64))> + 'a {
    let (dw, dh) = frame.depth.dims();
    (0..dh).flat_map(move |y| (0..dw).map(move |x| (x, y))).filter_map(move |(x, y)| {
        let z = sensor.metric_depth(*frame.depth.at(x, y))?;
        let pixel = flowfilter_pipeline::camera::Pixel::new(x as f64, y as f64);
        let p = sensor.depth_pixel_to_color_frame(&pixel, z)?;
        let c = sensor.color.project(&p)?;
        Some((p, (c.x, c.y)))
    })
}
