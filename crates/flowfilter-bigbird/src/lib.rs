//! The BigBIRD RGB-D turntable dataset layout: reader, writer and ground truth.
//!
//! The layout, as the BigBIRD download ships it, per object directory: colour JPEGs
//! `NP{c}_{angle}.jpg`, raw depth `NP{c}_{angle}.h5` (dataset `depth`, uint16), PBM masks
//! `masks/NP{c}_{angle}_mask.pbm`, `calibration.h5` (intrinsics, distortion and the
//! depth-to-colour extrinsics of every camera), per-angle `poses/NP5_{angle}_pose.h5` and
//! `poses/turntable.h5`.
//!
//! - [`BigBirdObject::open`] discovers cameras and angles and loads calibration and poses;
//!   [`BigBirdObject::load_frame`] loads one frame (colour, raw depth, mask).
//! - [`BigBirdObject::h_cam_from_table`] and [`BigBirdObject::relative_motion`] give ground truth.
//! - [`ObjectWriter`] writes exactly the same layout.
//! - [`inspect`] validates every file of an object directory and collects all problems.
//!
//! HDF5 is read with `hdf5-reader` (old and new file formats) and written with `hdf5-pure`;
//! no system library is involved.

#![warn(missing_docs)]

mod calibration;
mod capture_status;
mod error;
mod h5;
mod inspect;
mod layout;
mod object;
pub mod pbm;
mod writer;

pub use calibration::{Calibration, CanonCalibration, SensorCalibration};
pub use capture_status::{CAPTURE_STATUS_FILE, CaptureStatus, capture_status_path};
pub use error::BigBirdError;
pub use inspect::{InspectReport, ObjectSummary, inspect};
pub use layout::{FrameId, SensorId};
pub use object::{BigBirdObject, Frame, TablePose, Turntable, read_depth};
pub use writer::{H5Format, ObjectWriter};

/// Result type of this crate.
pub type Result<T> = std::result::Result<T, BigBirdError>;

/// The README's examples, compiled and run as doctests.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
