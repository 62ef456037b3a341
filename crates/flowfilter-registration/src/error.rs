//! Errors of registration.

/// Why a registration problem cannot be solved.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RegistrationError {
    /// A cloud has no points.
    #[error("the {which} cloud is empty")]
    EmptyCloud {
        /// `source` or `target`.
        which: &'static str,
    },
    /// A cloud has fewer than three points.
    #[error("the {which} cloud has {found} point(s); at least 3 are needed")]
    TooFewPoints {
        /// `source` or `target`.
        which: &'static str,
        /// Points found.
        found: usize,
    },
    /// All points of a cloud are collinear or coincident: the rotation is not determined.
    #[error("the {which} cloud is degenerate: its points are collinear or coincident")]
    Degenerate {
        /// `source` or `target`.
        which: &'static str,
    },
    /// A coordinate (or normal) is NaN or infinite.
    #[error("the {which} cloud has a non-finite value at point {index}")]
    NonFinite {
        /// `source` or `target`.
        which: &'static str,
        /// First bad point.
        index: usize,
    },
    /// A normal is NaN or infinite.
    #[error("the {which} cloud has a non-finite normal at point {index}")]
    NonFiniteNormal {
        /// `source` or `target`.
        which: &'static str,
        /// First bad point.
        index: usize,
    },
    /// A coordinate is beyond [`flowfilter_geometry::MAX_COORDINATE_M`] (a unit or file error).
    #[error(
        "the {which} cloud has a coordinate of {value:e} m at point {index}, beyond the {limit:e} m any scene spans (wrong unit?)"
    )]
    OutOfRange {
        /// `source` or `target`.
        which: &'static str,
        /// First bad point.
        index: usize,
        /// Its largest absolute coordinate.
        value: f64,
        /// The limit.
        limit: f64,
    },
    /// A method needs normals the cloud does not have.
    #[error("{method} needs normals on the {which} cloud, which has none")]
    MissingNormals {
        /// The method.
        method: &'static str,
        /// `source` or `target`.
        which: &'static str,
    },
    /// The correspondences are malformed.
    #[error(transparent)]
    BadCorrespondences(#[from] flowfilter_geometry::CorrespondenceError),
    /// A method name is unknown, or a problem's setting is unusable.
    #[error("registration config: {0}")]
    Config(String),
    /// A configuration value is NaN, infinite or out of range (the key is relative to the
    /// `[registration]` table: `flowfilter.inlier_threshold_m`).
    #[error("registration config: {0}")]
    Param(#[from] flowfilter_geometry::ParamError),
}
