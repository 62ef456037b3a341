//! Errors of camera-model construction.

/// Why a camera model or sensor calibration is invalid.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraError {
    /// A parameter is NaN or infinite.
    #[error("camera parameter '{name}' is not finite (found {value})")]
    NonFinite {
        /// Parameter name.
        name: &'static str,
        /// Value found.
        value: f64,
    },
    /// A focal length is not positive.
    #[error("focal length '{name}' must be > 0, found {value}")]
    NonPositiveFocal {
        /// Parameter name (`fx` or `fy`).
        name: &'static str,
        /// Value found.
        value: f64,
    },
    /// A parameter is finite but absurd (a unit or file error).
    #[error("camera parameter '{name}' = {value:e} is beyond {limit:e}: wrong unit or a damaged file")]
    OutOfRange {
        /// Parameter name.
        name: &'static str,
        /// Value found.
        value: f64,
        /// The limit.
        limit: f64,
    },
    /// A 3x3 intrinsic matrix does not have the pinhole form `[fx 0 cx; 0 fy cy; 0 0 1]`.
    #[error("intrinsic matrix entry ({row}, {col}) must be {expected}, found {found}")]
    NotPinhole {
        /// Row of the entry.
        row: usize,
        /// Column of the entry.
        col: usize,
        /// Expected value.
        expected: f64,
        /// Value found.
        found: f64,
    },
    /// An image size with a zero dimension.
    #[error("image size must be non-zero, found {width}x{height}")]
    EmptyImage {
        /// Width found.
        width: u32,
        /// Height found.
        height: u32,
    },
    /// A distortion vector of the wrong length.
    #[error("distortion needs 5 coefficients (k1 k2 p1 p2 k3), found {found}")]
    DistortionLength {
        /// Number of coefficients found.
        found: usize,
    },
    /// The depth unit is not a finite number of metres per raw unit in
    /// [`crate::MIN_METRES_PER_UNIT`, `crate::MAX_METRES_PER_UNIT`].
    #[error("depth unit must be between 1e-6 and 1 metre per raw unit, found {value:e} m")]
    BadDepthScale {
        /// Value found.
        value: f64,
    },
}

pub(crate) fn finite(name: &'static str, value: f64) -> Result<f64, CameraError> {
    if value.is_finite() { Ok(value) } else { Err(CameraError::NonFinite { name, value }) }
}
