//! Errors of the depth stage.

use std::path::PathBuf;

/// Why the depth stage cannot process its input.
#[derive(Debug, thiserror::Error)]
pub enum DepthError {
    /// An image does not have the size the calibration (or another image) says.
    #[error("{what} is {found}, expected {expected}")]
    SizeMismatch {
        /// Which input.
        what: &'static str,
        /// Expected size `WxH`.
        expected: String,
        /// Size found.
        found: String,
    },
    /// The object mask has no pixel.
    #[error("the object mask is empty: nothing to register")]
    EmptyMask,
    /// The depth image has no reading at all.
    #[error("the depth image has no valid reading (all zero)")]
    NoDepth,
    /// A calibration value is not finite.
    #[error("calibration value '{name}' is not finite ({value})")]
    NonFiniteCalibration {
        /// Which value.
        name: &'static str,
        /// Value found.
        value: f64,
    },
    /// A configuration value is out of range.
    #[error("invalid depth configuration: {0}")]
    Config(String),
    /// A PLY file cannot be read or written.
    #[error("{}: {message}", path.display())]
    Ply {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}
