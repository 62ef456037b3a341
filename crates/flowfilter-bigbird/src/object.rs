//! An object directory: discovery, frames, poses and ground-truth motion.

use crate::calibration::{Calibration, SensorCalibration};
use crate::error::BigBirdError;
use crate::h5::H5;
use crate::layout::{FrameId, SensorId, calibration_path, table_pose_path, turntable_path};
use crate::{Result, pbm};
use flowfilter_camera::{ImageSize, RgbdSensor};
use flowfilter_geometry::{Mask, Pose, RawDepth, Vector3};
use image::RgbImage;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The turntable pose of one angle (`poses/NP5_{angle}_pose.h5`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TablePose {
    /// `H_table_from_reference_camera`: maps points in the reference camera (NP5) frame into
    /// the table frame, which turns with the object.
    pub h_table_from_reference: Pose,
    /// `board_frame_offset`.
    pub board_frame_offset: Vector3,
}

impl TablePose {
    /// Read one pose file.
    pub fn read(path: &Path) -> Result<Self> {
        let h5 = H5::open(path)?;
        Ok(Self {
            h_table_from_reference: h5.pose("H_table_from_reference_camera")?,
            board_frame_offset: h5.vector3("board_frame_offset")?,
        })
    }
}

/// The turntable axis (`poses/turntable.h5`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Turntable {
    /// `center`: a point on the axis.
    pub center: Vector3,
    /// `normal`: the axis direction, normalised on reading.
    pub normal: Vector3,
}

impl Turntable {
    /// Read `poses/turntable.h5`; a zero normal is an error.
    pub fn read(path: &Path) -> Result<Self> {
        let h5 = H5::open(path)?;
        let center = h5.vector3("center")?;
        let normal = h5.vector3("normal")?;
        let norm = normal.norm();
        if norm < 1e-9 {
            return Err(BigBirdError::Invalid {
                path: path.into(),
                message: "dataset 'normal' is the zero vector".into(),
            });
        }
        Ok(Self { center, normal: normal / norm })
    }
}

/// One loaded frame of one sensor at one angle.
#[derive(Debug, Clone)]
pub struct Frame {
    /// Which frame.
    pub id: FrameId,
    /// Colour image.
    pub color: RgbImage,
    /// Raw depth (0 = no reading) on the depth camera's grid.
    pub depth: RawDepth,
    /// Object mask on the colour grid (`true` = object).
    pub mask: Mask,
}

impl Frame {
    /// Colour image size.
    pub fn color_size(&self) -> ImageSize {
        ImageSize { width: self.color.width(), height: self.color.height() }
    }

    /// Depth image size.
    pub fn depth_size(&self) -> ImageSize {
        ImageSize { width: self.depth.width() as u32, height: self.depth.height() as u32 }
    }
}

/// A BigBIRD object directory, opened: calibration, turntable and per-angle poses loaded,
/// frames discovered (loaded on demand with [`BigBirdObject::load_frame`]).
#[derive(Debug, Clone)]
pub struct BigBirdObject {
    dir: PathBuf,
    /// Object name (the directory name).
    pub name: String,
    /// `calibration.h5`.
    pub calibration: Calibration,
    /// `poses/turntable.h5`.
    pub turntable: Turntable,
    /// Per-angle table poses.
    pub table_poses: BTreeMap<u32, TablePose>,
    frames: BTreeSet<FrameId>,
}

/// Frames whose depth or colour file exists in `dir`.
pub(crate) fn discover_frames(dir: &Path) -> Result<BTreeSet<FrameId>> {
    let entries = std::fs::read_dir(dir).map_err(|source| BigBirdError::Io { path: dir.into(), source })?;
    let mut frames = BTreeSet::new();
    for entry in entries {
        let entry = entry.map_err(|source| BigBirdError::Io { path: dir.into(), source })?;
        let name = entry.file_name();
        let Some(name) = name.to_str() else { continue };
        let stem = name.strip_suffix(".h5").or_else(|| name.strip_suffix(".jpg"));
        if let Some(id) = stem.and_then(FrameId::parse_stem) {
            frames.insert(id);
        }
    }
    Ok(frames)
}

impl BigBirdObject {
    /// Open an object directory: read `calibration.h5`, `poses/turntable.h5`, the pose of every
    /// angle that has a frame, and list the frames. Fails on the first problem; use
    /// [`crate::inspect`] to collect all of them.
    pub fn open(dir: impl AsRef<Path>) -> Result<Self> {
        let dir = dir.as_ref().to_path_buf();
        if dir.is_file() {
            return Err(BigBirdError::NotADirectory { path: dir });
        }
        if !dir.is_dir() {
            return Err(BigBirdError::NotFound { path: dir });
        }
        let frames = discover_frames(&dir)?;
        if frames.is_empty() {
            return Err(BigBirdError::NoFrames { dir });
        }
        let calibration = Calibration::read(&calibration_path(&dir))?;
        if let Some(id) = frames.iter().find(|id| !calibration.sensors.contains_key(&id.sensor)) {
            return Err(BigBirdError::MissingDataset {
                path: calibration_path(&dir),
                key: format!("{}_rgb_K (frame {id} exists but its sensor is not calibrated)", id.sensor),
            });
        }
        let turntable = Turntable::read(&turntable_path(&dir))?;
        let mut table_poses = BTreeMap::new();
        for angle in frames.iter().map(|f| f.angle).collect::<BTreeSet<_>>() {
            table_poses.insert(angle, TablePose::read(&table_pose_path(&dir, angle))?);
        }
        let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        Ok(Self { dir, name, calibration, turntable, table_poses, frames })
    }

    /// The object directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// All frames present.
    pub fn frames(&self) -> impl Iterator<Item = FrameId> + '_ {
        self.frames.iter().copied()
    }

    /// Sensors with at least one frame.
    pub fn sensors(&self) -> BTreeSet<SensorId> {
        self.frames.iter().map(|f| f.sensor).collect()
    }

    /// Angles (degrees) with at least one frame.
    pub fn angles(&self) -> BTreeSet<u32> {
        self.frames.iter().map(|f| f.angle).collect()
    }

    /// Whether the frame is present.
    pub fn has_frame(&self, id: FrameId) -> bool {
        self.frames.contains(&id)
    }

    fn not_present(&self, what: String) -> BigBirdError {
        BigBirdError::NotPresent { dir: self.dir.clone(), what }
    }

    /// Calibration of one sensor.
    pub fn sensor_calibration(&self, sensor: SensorId) -> Result<&SensorCalibration> {
        self.calibration.sensors.get(&sensor).ok_or_else(|| self.not_present(format!("calibration of {sensor}")))
    }

    /// The RGB-D sensor model of `sensor`, with image sizes taken from a loaded frame.
    pub fn rgbd_sensor(&self, frame: &Frame) -> Result<RgbdSensor> {
        Ok(self.sensor_calibration(frame.id.sensor)?.rgbd_sensor(frame.color_size(), frame.depth_size()))
    }

    /// Load colour, raw depth and mask of one frame; the mask must match the colour size.
    pub fn load_frame(&self, id: FrameId) -> Result<Frame> {
        if !self.has_frame(id) {
            return Err(self.not_present(format!("frame {id}")));
        }
        load_frame_files(&self.dir, id)
    }

    /// `H_NP{c}_from_table(angle) = H_NP{c}_from_NP5 * inv(H_table_from_reference_camera(angle))`:
    /// maps table-frame (object) points into the colour camera of `sensor` at `angle`.
    pub fn h_cam_from_table(&self, sensor: SensorId, angle: u32) -> Result<Pose> {
        let cal = self.sensor_calibration(sensor)?;
        let pose =
            self.table_poses.get(&angle).ok_or_else(|| self.not_present(format!("table pose at angle {angle}")))?;
        Ok(cal.h_from_np5 * pose.h_table_from_reference.inverse())
    }

    /// Relative motion of the object seen by `sensor` from angle `a` to angle `b`, in the colour
    /// camera frame: `T_ab = H_cam_from_table(b) * inv(H_cam_from_table(a))`, so that
    /// `P_b = T_ab * P_a` for the same object point.
    pub fn relative_motion(&self, sensor: SensorId, a: u32, b: u32) -> Result<Pose> {
        Ok(self.h_cam_from_table(sensor, b)? * self.h_cam_from_table(sensor, a)?.inverse())
    }
}

/// Load the three files of a frame.
pub(crate) fn load_frame_files(dir: &Path, id: FrameId) -> Result<Frame> {
    let color = read_color(&id.color_path(dir))?;
    let depth = read_depth(&id.depth_path(dir))?;
    let mask_path = id.mask_path(dir);
    let mask = read_mask(&mask_path)?;
    if mask.dims() != (color.width() as usize, color.height() as usize) {
        return Err(BigBirdError::MaskSize {
            path: mask_path,
            expected: format!("{}x{}", color.width(), color.height()),
            found: format!("{}x{}", mask.width(), mask.height()),
        });
    }
    Ok(Frame { id, color, depth, mask })
}

fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    if !path.is_file() {
        return Err(BigBirdError::NotFound { path: path.into() });
    }
    std::fs::read(path).map_err(|source| BigBirdError::Io { path: path.into(), source })
}

/// Decode a colour JPEG (any format `image` reads) into RGB8.
pub(crate) fn read_color(path: &Path) -> Result<RgbImage> {
    let bytes = read_bytes(path)?;
    if bytes.starts_with(&[0xFF, 0xD8]) {
        // JPEG decoders fill a truncated scan with grey instead of failing: require the
        // end-of-image marker (allowing trailing padding after it).
        let end = bytes.iter().rposition(|&b| b != 0 && b != b'\n' && b != b'\r').map_or(0, |i| i + 1);
        if end < 4 || bytes[end - 2..end] != [0xFF, 0xD9] {
            return Err(BigBirdError::Image {
                path: path.into(),
                message: "JPEG is truncated (no end-of-image marker FF D9)".into(),
            });
        }
    }
    let img = image::load_from_memory(&bytes)
        .map_err(|e| BigBirdError::Image { path: path.into(), message: e.to_string() })?;
    Ok(img.to_rgb8())
}

/// Read a depth file in the BigBIRD layout (dataset `depth`, uint16, 2-D).
pub fn read_depth(path: &Path) -> Result<RawDepth> {
    let (rows, cols, data) = H5::open(path)?.image_u16("depth")?;
    Ok(RawDepth::from_vec(cols, rows, data).expect("reader returns rows*cols values"))
}

/// Read a PBM mask.
pub(crate) fn read_mask(path: &Path) -> Result<Mask> {
    let bytes = read_bytes(path)?;
    pbm::decode(&bytes).map_err(|e| BigBirdError::Pbm { path: path.into(), message: e.to_string() })
}
