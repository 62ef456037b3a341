//! `calibration.h5`: intrinsics and extrinsics of the rig.

use crate::Result;
use crate::error::BigBirdError;
use crate::h5::H5;
use crate::layout::SensorId;
use flowfilter_camera::{CameraModel, Distortion, ImageSize, Intrinsics, RgbdSensor};
use flowfilter_geometry::Pose;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// Calibration of one Carmine sensor `NP{c}`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SensorCalibration {
    /// Colour camera intrinsics (`NP{c}_rgb_K`).
    pub rgb_k: Intrinsics,
    /// Colour camera distortion (`NP{c}_rgb_d`, k1 k2 p1 p2 k3).
    pub rgb_d: Distortion,
    /// Depth (IR) camera intrinsics (`NP{c}_ir_K`, or `NP{c}_depth_K` in older files).
    pub depth_k: Intrinsics,
    /// Which key the depth intrinsics came from.
    pub depth_k_key: String,
    /// `NP{c}_ir_depth_scale`: raw depth to metres is `d * scale * 1e-4`.
    pub ir_depth_scale: f64,
    /// `NP{c}_ir_depth_bias` (recorded; the documented conversion does not use it).
    pub ir_depth_bias: f64,
    /// `H_NP{c}_from_NP5`: colour camera of this sensor from the reference camera.
    pub h_from_np5: Pose,
    /// `H_NP{c}_ir_from_NP5`: depth camera of this sensor from the reference camera.
    pub h_ir_from_np5: Pose,
}

impl SensorCalibration {
    /// `H_rgb_from_ir = H_NP{c}_from_NP5 * inv(H_NP{c}_ir_from_NP5)`.
    pub fn color_from_depth(&self) -> Pose {
        self.h_from_np5 * self.h_ir_from_np5.inverse()
    }

    /// A note for people when `NP{c}_ir_depth_bias` is not 0: it is recorded, and the
    /// documented conversion (`raw x scale x 1e-4`) does not apply it. `sensor` names the key.
    pub fn depth_bias_note(&self, sensor: SensorId) -> Option<String> {
        (self.ir_depth_bias != 0.0).then(|| {
            format!(
                "{sensor}_ir_depth_bias = {} is not applied: depth is raw x {sensor}_ir_depth_scale x 1e-4 m, as \
                 BigBIRD documents it",
                self.ir_depth_bias
            )
        })
    }

    /// Metres per raw depth unit.
    pub fn metres_per_unit(&self) -> f64 {
        self.ir_depth_scale * 1e-4
    }

    /// The sensor model for the given colour and depth image sizes (the calibration file does
    /// not store sizes; they come from the frames). The depth camera has no distortion model
    /// in BigBIRD's calibration.
    pub fn rgbd_sensor(&self, color_size: ImageSize, depth_size: ImageSize) -> RgbdSensor {
        RgbdSensor {
            depth: CameraModel::new(self.depth_k, Distortion::NONE, depth_size),
            color: CameraModel::new(self.rgb_k, self.rgb_d, color_size),
            color_from_depth: self.color_from_depth(),
            metres_per_unit: self.metres_per_unit(),
        }
    }
}

/// Calibration of one high-resolution Canon camera `N{c}` (optional in this project).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CanonCalibration {
    /// Intrinsics (`N{c}_rgb_K`).
    pub k: Intrinsics,
    /// Distortion (`N{c}_rgb_d`).
    pub d: Distortion,
    /// `H_N{c}_from_NP5`.
    pub h_from_np5: Pose,
}

/// Everything in `calibration.h5`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Calibration {
    /// Carmine sensors present, by index 1..=5.
    pub sensors: BTreeMap<SensorId, SensorCalibration>,
    /// Canon cameras present, by index 1..=5.
    pub canon: BTreeMap<u8, CanonCalibration>,
}

fn intrinsics(h5: &H5, key: &str) -> Result<Intrinsics> {
    Intrinsics::from_matrix(&h5.matrix3(key)?).map_err(|source| BigBirdError::Camera {
        path: h5.path().into(),
        key: key.into(),
        source,
    })
}

fn distortion(h5: &H5, key: &str) -> Result<Distortion> {
    Distortion::from_slice(&h5.vector::<5>(key)?).map_err(|source| BigBirdError::Camera {
        path: h5.path().into(),
        key: key.into(),
        source,
    })
}

impl Calibration {
    /// Read `calibration.h5`. Sensors are discovered by their `NP{c}_rgb_K` key; every other
    /// key of a present sensor is then required. At least one sensor must be present.
    pub fn read(path: &Path) -> Result<Self> {
        let h5 = H5::open(path)?;
        let mut cal = Calibration::default();
        for id in SensorId::ALL {
            let c = id.index();
            if !h5.has(&format!("NP{c}_rgb_K")) {
                continue;
            }
            let depth_k_key =
                [format!("NP{c}_ir_K"), format!("NP{c}_depth_K")].into_iter().find(|k| h5.has(k)).ok_or_else(|| {
                    BigBirdError::MissingDataset { path: path.into(), key: format!("NP{c}_ir_K (or NP{c}_depth_K)") }
                })?;
            let scale_key = format!("NP{c}_ir_depth_scale");
            let ir_depth_scale = h5.scalar(&scale_key)?;
            // The documented scale is close to 1 (raw units of 100 micrometres).
            if !(0.01..=100.0).contains(&ir_depth_scale) {
                return Err(BigBirdError::Invalid {
                    path: path.into(),
                    message: format!(
                        "dataset '{scale_key}' must be in [0.01, 100] (raw depth x scale x 1e-4 = metres; \
                         BigBIRD's scales are close to 1), found {ir_depth_scale:e}"
                    ),
                });
            }
            let sensor = SensorCalibration {
                rgb_k: intrinsics(&h5, &format!("NP{c}_rgb_K"))?,
                rgb_d: distortion(&h5, &format!("NP{c}_rgb_d"))?,
                depth_k: intrinsics(&h5, &depth_k_key)?,
                depth_k_key,
                ir_depth_scale,
                ir_depth_bias: h5.scalar(&format!("NP{c}_ir_depth_bias"))?,
                h_from_np5: h5.pose(&format!("H_NP{c}_from_NP5"))?,
                h_ir_from_np5: h5.pose(&format!("H_NP{c}_ir_from_NP5"))?,
            };
            cal.sensors.insert(id, sensor);
        }
        if cal.sensors.is_empty() {
            return Err(BigBirdError::MissingDataset {
                path: path.into(),
                key: "NP1_rgb_K (no NP<c>_rgb_K at all)".into(),
            });
        }
        for c in 1..=5u8 {
            if !h5.has(&format!("N{c}_rgb_K")) {
                continue;
            }
            let canon = CanonCalibration {
                k: intrinsics(&h5, &format!("N{c}_rgb_K"))?,
                d: distortion(&h5, &format!("N{c}_rgb_d"))?,
                h_from_np5: h5.pose(&format!("H_N{c}_from_NP5"))?,
            };
            cal.canon.insert(c, canon);
        }
        Ok(cal)
    }
}
