//! Writing the BigBIRD layout (HDF5 through `hdf5-pure`, JPEG and PNG through `image`, PBM).

use crate::calibration::Calibration;
use crate::capture_status::{CaptureStatus, capture_status_path};
use crate::error::BigBirdError;
use crate::layout::{FrameId, calibration_path, table_pose_path, turntable_path};
use crate::object::{TablePose, Turntable};
use crate::{Result, pbm};
use flowfilter_geometry::atomic::{write_atomic, write_atomic_with};
use flowfilter_geometry::{Mask, Pose, RawDepth};
use hdf5_pure::{FileBuilder, LibVer};
use image::RgbImage;
use nalgebra::{Matrix3, Vector3};
use std::path::{Path, PathBuf};

/// The HDF5 file format to write.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum H5Format {
    /// HDF5 1.8 structures (superblock 2, v2 object headers): the oldest `hdf5-pure` writes;
    /// readable by every current libhdf5.
    V18,
    /// HDF5 1.10 structures (superblock 3): `hdf5-pure`'s default.
    #[default]
    V110,
}

/// Writes one object directory in the BigBIRD layout.
#[derive(Debug, Clone)]
pub struct ObjectWriter {
    dir: PathBuf,
    format: H5Format,
    jpeg_quality: u8,
}

fn write_error(path: &Path, e: impl std::fmt::Display) -> BigBirdError {
    BigBirdError::Write { path: path.into(), message: e.to_string() }
}

fn row_major3(m: &Matrix3<f64>) -> Vec<f64> {
    (0..3).flat_map(|r| (0..3).map(move |c| m[(r, c)])).collect()
}

fn pose_rows(p: &Pose) -> Vec<f64> {
    let m = p.to_homogeneous();
    (0..4).flat_map(|r| (0..4).map(move |c| m[(r, c)])).collect()
}

impl ObjectWriter {
    /// Create (or reuse) `dir` with its `masks/` and `poses/` subdirectories.
    pub fn create(dir: impl AsRef<Path>, format: H5Format) -> Result<Self> {
        let dir = dir.as_ref().to_path_buf();
        for sub in [dir.clone(), dir.join("masks"), dir.join("poses")] {
            std::fs::create_dir_all(&sub).map_err(|source| BigBirdError::Io { path: sub.clone(), source })?;
        }
        Ok(Self { dir, format, jpeg_quality: 92 })
    }

    /// JPEG quality (1-100) of colour images; default 92.
    pub fn with_jpeg_quality(mut self, quality: u8) -> Self {
        self.jpeg_quality = quality.clamp(1, 100);
        self
    }

    /// The object directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    fn builder(&self) -> FileBuilder {
        let mut b = FileBuilder::new();
        if self.format == H5Format::V18 {
            b.with_libver_bounds(LibVer::V18, LibVer::V18);
        }
        b
    }

    fn finish(&self, b: FileBuilder, path: &Path) -> Result<()> {
        write_atomic_with(path, |p| b.write(p).map_err(std::io::Error::other)).map_err(|e| write_error(path, e))
    }

    /// Write `calibration.h5`.
    pub fn write_calibration(&self, cal: &Calibration) -> Result<()> {
        let mut b = self.builder();
        for (id, s) in &cal.sensors {
            let c = id.index();
            b.create_dataset(&format!("NP{c}_rgb_K")).with_f64_data(&row_major3(&s.rgb_k.matrix())).with_shape(&[3, 3]);
            b.create_dataset(&format!("NP{c}_rgb_d")).with_f64_data(&s.rgb_d.to_array()).with_shape(&[5]);
            // Real BigBIRD files hold the depth camera's intrinsics under both names, and public
            // loaders read either.
            for key in [format!("NP{c}_ir_K"), format!("NP{c}_depth_K")] {
                b.create_dataset(&key).with_f64_data(&row_major3(&s.depth_k.matrix())).with_shape(&[3, 3]);
            }
            b.create_dataset(&format!("NP{c}_ir_depth_scale")).with_f64_data(&[s.ir_depth_scale]).with_shape(&[1]);
            b.create_dataset(&format!("NP{c}_ir_depth_bias")).with_f64_data(&[s.ir_depth_bias]).with_shape(&[1]);
            b.create_dataset(&format!("H_NP{c}_from_NP5")).with_f64_data(&pose_rows(&s.h_from_np5)).with_shape(&[4, 4]);
            b.create_dataset(&format!("H_NP{c}_ir_from_NP5"))
                .with_f64_data(&pose_rows(&s.h_ir_from_np5))
                .with_shape(&[4, 4]);
        }
        for (c, n) in &cal.canon {
            b.create_dataset(&format!("N{c}_rgb_K")).with_f64_data(&row_major3(&n.k.matrix())).with_shape(&[3, 3]);
            b.create_dataset(&format!("N{c}_rgb_d")).with_f64_data(&n.d.to_array()).with_shape(&[5]);
            b.create_dataset(&format!("H_N{c}_from_NP5")).with_f64_data(&pose_rows(&n.h_from_np5)).with_shape(&[4, 4]);
        }
        self.finish(b, &calibration_path(&self.dir))
    }

    /// Write `poses/turntable.h5`.
    pub fn write_turntable(&self, t: &Turntable) -> Result<()> {
        let mut b = self.builder();
        b.create_dataset("center").with_f64_data(t.center.as_slice()).with_shape(&[3]);
        b.create_dataset("normal").with_f64_data(t.normal.as_slice()).with_shape(&[3]);
        self.finish(b, &turntable_path(&self.dir))
    }

    /// Write `poses/NP5_{angle}_pose.h5`.
    pub fn write_table_pose(&self, angle: u32, pose: &TablePose) -> Result<()> {
        let mut b = self.builder();
        b.create_dataset("H_table_from_reference_camera")
            .with_f64_data(&pose_rows(&pose.h_table_from_reference))
            .with_shape(&[4, 4]);
        let offset: &Vector3<f64> = &pose.board_frame_offset;
        b.create_dataset("board_frame_offset").with_f64_data(offset.as_slice()).with_shape(&[3]);
        self.finish(b, &table_pose_path(&self.dir, angle))
    }

    /// Write the raw depth `NP{c}_{angle}.h5` (dataset `depth`, uint16, deflate-compressed).
    pub fn write_depth(&self, id: FrameId, depth: &RawDepth) -> Result<()> {
        let path = id.depth_path(&self.dir);
        let mut b = self.builder();
        let (w, h) = depth.dims();
        let ds = b.create_dataset("depth");
        ds.with_u16_data(depth.as_slice()).with_shape(&[h as u64, w as u64]);
        if self.format == H5Format::V110 {
            ds.with_chunks(&[(h as u64).min(120), w as u64]).with_deflate(4);
        }
        self.finish(b, &path)
    }

    /// Write the colour image `NP{c}_{angle}.jpg`.
    pub fn write_color(&self, id: FrameId, color: &RgbImage) -> Result<()> {
        let path = id.color_path(&self.dir);
        let mut bytes = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, self.jpeg_quality)
            .encode_image(color)
            .map_err(|e| write_error(&path, e))?;
        write_atomic(&path, &bytes).map_err(|source| BigBirdError::Io { path, source })
    }

    /// Write `capture-status.txt` ([`CaptureStatus`]): incomplete before the first frame of a
    /// capture, complete after the last.
    pub fn write_status(&self, status: CaptureStatus) -> Result<()> {
        let path = capture_status_path(&self.dir);
        write_atomic(&path, status.to_text().as_bytes()).map_err(|source| BigBirdError::Io { path, source })
    }

    /// Write the mask `masks/NP{c}_{angle}_mask.pbm` (binary PBM, object = set bit).
    pub fn write_mask(&self, id: FrameId, mask: &Mask) -> Result<()> {
        let path = id.mask_path(&self.dir);
        write_atomic(&path, &pbm::encode(mask)).map_err(|source| BigBirdError::Io { path, source })
    }
}
