//! Folders of RGB-D frames with calibrated camera poses, as `../shared/data/realsense-shelf`
//! ships them: `frame-NNNNNN.color.png`, `frame-NNNNNN.depth.png` (raw depth of the depth
//! camera, or depth registered to colour), `camera.json` (this project's camera file) and
//! `poses.json` (`camera_to_world_calibrated`: frame id -> 4x4 camera-to-world, metres; and
//! `camera_to_world_robot`, the arm's kinematics with its nominal mount).
//!
//! The truth of a pair is the calibrated poses' camera motion ([`Truth::Calibrated`]) or the
//! arm's corrected by a mount fitted to the calibrated poses of every sequence
//! ([`Truth::Arm`], [`fit_arm_mount`]): a second truth without the calibration's per-frame
//! errors. The regions and their masks come from the calibrated poses either way, so the two
//! truths score the same estimates.
//!
//! The scene is static, so any region of it is an "object" with exact truth: a region is a ball
//! of the scene ([`Region`]), its true mask in a frame the colour pixels its depth points cover
//! (holes of the sparse depth closed), and the mask a pair is given that true mask with a
//! segmentation network's defects ([`NetworkMaskModel`]), drawn from a seed per frame and
//! region.

use crate::in_repo;
use anyhow::Context;
use flowfilter_eval::hand_eye::{MotionPair, MountFit, fit_mount};
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

/// Which record of the camera's poses gives a pair's truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Truth {
    /// The calibrated poses (`camera_to_world_calibrated`).
    Calibrated,
    /// The arm's poses (`camera_to_world_robot`) with the fitted mount: a pair's motion is
    /// `X^-1 * inv(A_j) * A_i * X`.
    Arm(MountFit),
}

impl Truth {
    /// The truth in words, for a summary's protocol line.
    pub fn describe(&self) -> String {
        match self {
            Self::Calibrated => "calibrated camera poses".into(),
            Self::Arm(fit) => format!(
                "the arm's poses with a fitted mount (turned {:.2} deg, shifted {:.1} mm from the nominal; {} motions, \
                 median disagreement with the calibrated poses {:.2} deg, {:.1} mm)",
                fit.mount.rotation.angle().to_degrees(),
                fit.mount.translation.vector.norm() * 1e3,
                fit.pairs,
                fit.median_rotation_deg,
                fit.median_translation_m * 1e3
            ),
        }
    }
}

/// The record of camera poses a pair's truth is made of (`--truth` of `bench-real` and
/// `bench-track`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum TruthRecord {
    /// `camera_to_world_calibrated`.
    Calibrated,
    /// `camera_to_world_robot` with the mount fitted by [`fit_arm_mount`].
    Arm,
}

impl TruthRecord {
    /// The truth of this record; for the arm's, the mount fitted over every folder in `dirs`.
    ///
    /// # Errors
    /// As [`fit_arm_mount`].
    pub fn truth(self, dirs: &[PathBuf]) -> Result<Truth, String> {
        match self {
            Self::Calibrated => Ok(Truth::Calibrated),
            Self::Arm => fit_arm_mount(dirs).map(Truth::Arm),
        }
    }
}

/// The reference row of the arm's record (the fitted mount) when the truth is the calibrated
/// poses.
pub const ARM_RECORD: &str = "arm-record";
/// The reference row of the calibrated poses when the truth is the arm's record.
pub const CALIBRATED_RECORD: &str = "calibrated-record";

/// The record of the camera's motion that is not `truth`, as a reference row's name and its
/// truth; `None` (with a warning) where the arm's mount cannot be fitted (no arm poses).
pub fn other_record(truth: TruthRecord, dirs: &[PathBuf]) -> Option<(&'static str, Truth)> {
    match truth {
        TruthRecord::Arm => Some((CALIBRATED_RECORD, Truth::Calibrated)),
        TruthRecord::Calibrated => match TruthRecord::Arm.truth(dirs) {
            Ok(arm) => Some((ARM_RECORD, arm)),
            Err(e) => {
                tracing::warn!(error = %e, "no arm record to score beside the methods");
                None
            }
        },
    }
}

/// A folder of frames with calibrated camera poses.
pub struct PosedFrames {
    dir: PathBuf,
    camera: CameraFile,
    /// Frame id -> camera-to-world (calibrated): where the regions are.
    poses: BTreeMap<u32, Pose>,
    /// Frame id -> the pose a pair's truth is made of: the calibrated one, or the arm's with
    /// the fitted mount (`A * X`).
    truth_poses: BTreeMap<u32, Pose>,
}

/// The camera motions of consecutive frames of `dir` by the arm's poses and by the calibrated
/// ones.
///
/// # Errors
/// A `poses.json` that cannot be read.
fn arm_motions(dir: &Path) -> Result<Vec<MotionPair>, String> {
    let path = dir.join("poses.json");
    let read = |key| flowfilter_track::tum::read_camera_poses(&path, key).map_err(|e| e.to_string());
    let (arm, calibrated) = (read(flowfilter_track::tum::ARM)?, read(flowfilter_track::tum::CALIBRATED)?);
    let both: Vec<u64> = calibrated.keys().copied().filter(|k| arm.contains_key(k)).collect();
    Ok(both
        .windows(2)
        .map(|w| MotionPair {
            arm: arm[&w[1]].inverse() * arm[&w[0]],
            reference: calibrated[&w[1]].inverse() * calibrated[&w[0]],
        })
        .collect())
}

/// The mount correction of the arm's poses, fitted to the calibrated poses' consecutive camera
/// motions of every folder in `dirs` (one rig, one mount).
///
/// # Errors
/// A `poses.json` that cannot be read, or motions that do not determine a mount.
pub fn fit_arm_mount(dirs: &[PathBuf]) -> Result<MountFit, String> {
    let mut motions = vec![];
    for dir in dirs {
        motions.append(&mut arm_motions(dir)?);
    }
    fit_mount(&motions).map_err(|e| format!("fitting the arm's mount over {} sequence(s): {e}", dirs.len()))
}

/// The posed folders of `root`: `root` itself when it holds posed frames, else its
/// sub-folders that do, sorted.
///
/// # Errors
/// `root` cannot be listed.
pub fn posed_folders(root: &Path) -> std::io::Result<Vec<PathBuf>> {
    if is_posed_folder(root) {
        return Ok(vec![root.to_path_buf()]);
    }
    let mut dirs: Vec<PathBuf> =
        std::fs::read_dir(root)?.filter_map(Result::ok).map(|e| e.path()).filter(|p| is_posed_folder(p)).collect();
    dirs.sort();
    Ok(dirs)
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
    #[cfg(test)]
    pub fn open(dir: &Path) -> Result<Self, String> {
        Self::open_with_truth(dir, &Truth::Calibrated)
    }

    /// [`PosedFrames::open`], the pairs' truth taken from `truth`'s record (a frame without
    /// a pose in it is left out).
    ///
    /// # Errors
    /// As [`PosedFrames::open`].
    pub fn open_with_truth(dir: &Path, truth: &Truth) -> Result<Self, String> {
        let camera = CameraFile::from_file(&dir.join("camera.json")).map_err(|e| e.to_string())?;
        let path = dir.join("poses.json");
        let read = |key| flowfilter_track::tum::read_camera_poses(&path, key).map_err(|e| e.to_string());
        let cameras = read(flowfilter_track::tum::CALIBRATED)?;
        let truth_cameras = match truth {
            Truth::Calibrated => cameras.clone(),
            Truth::Arm(fit) => {
                read(flowfilter_track::tum::ARM)?.into_iter().map(|(id, a)| (id, a * fit.mount)).collect()
            }
        };
        let mut poses = BTreeMap::new();
        let mut truth_poses = BTreeMap::new();
        for (id, pose) in cameras {
            let im = u32::try_from(id).map_err(|_| format!("{}: frame number {id} is too large", dir.display()))?;
            let frames = Self::files_of(dir, im);
            if let Some(t) = truth_cameras.get(&id).filter(|_| frames.color.is_file() && frames.depth.is_file()) {
                poses.insert(im, pose);
                truth_poses.insert(im, *t);
            }
        }
        if poses.is_empty() {
            return Err(format!("{}: no posed frame has frame-NNNNNN.color.png and .depth.png", dir.display()));
        }
        Ok(Self { dir: dir.to_path_buf(), camera, poses, truth_poses })
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

    /// The scene's motion in the camera frame from frame `a` to frame `b` by the truth's
    /// record: `inv(C_b) * C_a`; with the arm's poses `C = A * X`, so `X^-1 * inv(A_b) * A_a * X`.
    ///
    /// # Errors
    /// A frame without a pose.
    pub fn relative_motion(&self, a: u32, b: u32) -> Result<Pose, String> {
        self.motion_in(&self.truth_poses, a, b)
    }

    /// The camera's motion from frame `a` to frame `b` by the calibrated poses, whatever the
    /// truth: `inv(C_b) * C_a` (what a twin of the pair is rendered with).
    ///
    /// # Errors
    /// A frame without a pose.
    pub fn calibrated_motion(&self, a: u32, b: u32) -> Result<Pose, String> {
        self.motion_in(&self.poses, a, b)
    }

    /// `inv(C_b) * C_a` with the camera poses `cameras`.
    fn motion_in(&self, cameras: &BTreeMap<u32, Pose>, a: u32, b: u32) -> Result<Pose, String> {
        let pose = |i: u32| cameras.get(&i).ok_or_else(|| format!("{}: no pose of frame {i}", self.dir.display()));
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

/// Where a run's depth correction comes from (`--depth-bias`).
pub enum DepthBiasSource {
    /// No correction.
    None,
    /// Each sequence's own field, fitted from its frames without truth.
    OwnFrames,
    /// One field for every sequence, from a camera file.
    Given(flowfilter_pipeline::camera::DepthBias),
}

impl DepthBiasSource {
    /// `none`, `self` or a camera file holding a `depth_bias`.
    ///
    /// # Errors
    /// A camera file that cannot be read or holds no field.
    pub fn parse(text: &str) -> anyhow::Result<Self> {
        Ok(match text {
            "none" => Self::None,
            "self" => Self::OwnFrames,
            path => {
                let camera = flowfilter_pipeline::CameraFile::from_file(Path::new(path)).context("--depth-bias")?;
                let bias = camera.depth_bias.with_context(|| {
                    format!("--depth-bias: {path} holds no depth_bias (expected none, self or such a file)")
                })?;
                Self::Given(bias)
            }
        })
    }

    /// Correct the frames of the sequence `label` (in order; read without a field) in place:
    /// by the given field, or by the field fitted from them (tracked with the pipeline
    /// configuration `pipeline`) when it is the sequence's own. Nothing is done for `none`.
    ///
    /// # Errors
    /// A configuration that cannot be read, a stream that cannot be calibrated, or a field of
    /// another size than the frames' depth.
    pub fn correct(&self, mut frames: Vec<&mut RgbdFrame>, pipeline: &Path, label: &str) -> anyhow::Result<()> {
        use flowfilter_track::depth_calibration::{DepthCalibrationConfig, calibrate_depth};
        let fitted;
        let bias = match self {
            Self::None => return Ok(()),
            Self::Given(bias) => bias,
            Self::OwnFrames => {
                let mut config = flowfilter_pipeline::PipelineConfig::from_file(&in_repo(pipeline))?;
                config.method = "flowfilter".into();
                let pipeline = flowfilter_pipeline::Pipeline::from_config(config)?;
                let uncorrected: Vec<RgbdFrame> = frames.iter().map(|f| (**f).clone()).collect();
                let c = calibrate_depth(&uncorrected, pipeline, &DepthCalibrationConfig::default())
                    .with_context(|| format!("--depth-bias self: sequence {label}"))?;
                tracing::info!(
                    sequence = %label,
                    pairs = c.pairs.iter().filter(|p| p.left_out.is_none()).count(),
                    rms_before_mm = c.fit.rms_before_m * 1e3,
                    rms_after_mm = c.fit.rms_after_m * 1e3,
                    "depth bias fitted from the sequence's own frames"
                );
                fitted = c.fit.bias;
                &fitted
            }
        };
        for f in &mut frames {
            bias.correct(&mut f.depth, f.sensor.metres_per_unit)
                .with_context(|| format!("--depth-bias: sequence {label}, {}", f.label))?;
        }
        Ok(())
    }
}

/// A seed from a run's seed, a sequence's name and `parts` (FNV-1a: stable across platforms
/// and releases, unlike the standard library's hasher).
pub fn seed_of(label: &str, seed: u64, parts: &[u64]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let bytes = label
        .bytes()
        .chain(std::iter::once(0))
        .chain(std::iter::once(seed).chain(parts.iter().copied()).flat_map(u64::to_le_bytes));
    for b in bytes {
        h = (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
    }
    h
}
