//! Errors of reading and writing BigBIRD object directories. Every variant names the file.

use flowfilter_camera::CameraError;
use flowfilter_geometry::RigidTransformError;
use std::path::PathBuf;

/// A problem with a BigBIRD object directory or one of its files.
#[derive(Debug, thiserror::Error)]
pub enum BigBirdError {
    /// A file or directory that must exist does not.
    #[error("{}: not found", path.display())]
    NotFound {
        /// The missing path.
        path: PathBuf,
    },
    /// The path is a file where an object directory is expected.
    #[error("{}: is a file, not an object directory (give the directory holding calibration.h5 and the frames)", path.display())]
    NotADirectory {
        /// The path given.
        path: PathBuf,
    },
    /// The operating system could not read or write a file.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// A file is not a readable HDF5 file (truncated, corrupt, unsupported).
    #[error("{}: not a readable HDF5 file: {message}", path.display())]
    Hdf5 {
        /// The file.
        path: PathBuf,
        /// What the HDF5 decoder reported.
        message: String,
    },
    /// A required HDF5 dataset is missing.
    #[error("{}: dataset '{key}' is missing", path.display())]
    MissingDataset {
        /// The file.
        path: PathBuf,
        /// The missing dataset name.
        key: String,
    },
    /// A dataset has the wrong shape.
    #[error("{}: dataset '{key}' has shape {found:?}, expected {expected}", path.display())]
    Shape {
        /// The file.
        path: PathBuf,
        /// The dataset.
        key: String,
        /// Accepted shape(s), in words.
        expected: String,
        /// Shape found.
        found: Vec<u64>,
    },
    /// A dataset has the wrong element type.
    #[error("{}: dataset '{key}' has element type {found}, expected {expected}", path.display())]
    Dtype {
        /// The file.
        path: PathBuf,
        /// The dataset.
        key: String,
        /// Accepted type(s).
        expected: String,
        /// Type found.
        found: String,
    },
    /// A dataset holds NaN or infinite values where numbers are required.
    #[error("{}: dataset '{key}' holds a non-finite value at element {index}", path.display())]
    NonFinite {
        /// The file.
        path: PathBuf,
        /// The dataset.
        key: String,
        /// Index of the first bad element.
        index: usize,
    },
    /// A 4x4 dataset is not a rigid transform.
    #[error("{}: dataset '{key}' is not a rigid transform: {source}", path.display())]
    NotRigid {
        /// The file.
        path: PathBuf,
        /// The dataset.
        key: String,
        /// Why.
        #[source]
        source: RigidTransformError,
    },
    /// A calibration dataset is not a valid camera parameter.
    #[error("{}: dataset '{key}' is not a valid camera parameter: {source}", path.display())]
    Camera {
        /// The file.
        path: PathBuf,
        /// The dataset.
        key: String,
        /// Why.
        #[source]
        source: CameraError,
    },
    /// A colour image cannot be decoded.
    #[error("{}: cannot decode image: {message}", path.display())]
    Image {
        /// The file.
        path: PathBuf,
        /// What the decoder reported.
        message: String,
    },
    /// A mask file is not a valid PBM.
    #[error("{}: not a valid PBM mask: {message}", path.display())]
    Pbm {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The mask and the colour image of one frame differ in size.
    #[error("{}: mask is {found}, but the colour image is {expected}", path.display())]
    MaskSize {
        /// The mask file.
        path: PathBuf,
        /// Colour image size.
        expected: String,
        /// Mask size.
        found: String,
    },
    /// A value is present but unusable (e.g. a zero turntable normal).
    #[error("{}: {message}", path.display())]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// No frame files in an object directory.
    #[error("{}: no frames found (expected files named NP<c>_<angle>.h5 and NP<c>_<angle>.jpg)", dir.display())]
    NoFrames {
        /// The object directory.
        dir: PathBuf,
    },
    /// A frame, camera or angle that the directory does not hold was requested.
    #[error("{}: {what} is not present", dir.display())]
    NotPresent {
        /// The object directory.
        dir: PathBuf,
        /// What was asked for, e.g. "camera NP3" or "frame NP1_33".
        what: String,
    },
    /// Writing a file failed.
    #[error("{}: cannot write: {message}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        message: String,
    },
}
