//! File naming of the BigBIRD layout.

use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::{Path, PathBuf};

/// One of the five Carmine RGB-D sensors `NP1`..`NP5` (NP5 is the reference camera).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct SensorId(u8);

impl SensorId {
    /// All five sensors, NP1 (lowest elevation) to NP5 (highest, the reference).
    pub const ALL: [SensorId; 5] = [SensorId(1), SensorId(2), SensorId(3), SensorId(4), SensorId(5)];
    /// The reference camera NP5.
    pub const REFERENCE: SensorId = SensorId(5);

    /// Sensor `NP{index}`, `index` in 1..=5.
    pub fn new(index: u8) -> Option<Self> {
        (1..=5).contains(&index).then_some(Self(index))
    }

    /// The index 1..=5.
    pub fn index(self) -> u8 {
        self.0
    }
}

impl fmt::Display for SensorId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "NP{}", self.0)
    }
}

impl std::str::FromStr for SensorId {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        s.strip_prefix("NP")
            .and_then(|d| d.parse::<u8>().ok())
            .and_then(SensorId::new)
            .ok_or_else(|| format!("'{s}' is not a sensor name (expected NP1..NP5)"))
    }
}

/// One frame: a sensor at a turntable angle (degrees).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct FrameId {
    /// The sensor.
    pub sensor: SensorId,
    /// Turntable angle in degrees (0, 3, ..., 357 in BigBIRD).
    pub angle: u32,
}

impl fmt::Display for FrameId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}_{}", self.sensor, self.angle)
    }
}

impl FrameId {
    /// Parse a frame stem such as `NP3_120`.
    pub fn parse_stem(stem: &str) -> Option<Self> {
        let (cam, angle) = stem.split_once('_')?;
        let sensor = cam.parse().ok()?;
        if angle.is_empty() || !angle.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        Some(Self { sensor, angle: angle.parse().ok()? })
    }

    /// `NP{c}_{angle}.jpg`.
    pub fn color_path(&self, dir: &Path) -> PathBuf {
        dir.join(format!("{self}.jpg"))
    }

    /// `NP{c}_{angle}.h5`.
    pub fn depth_path(&self, dir: &Path) -> PathBuf {
        dir.join(format!("{self}.h5"))
    }

    /// `masks/NP{c}_{angle}_mask.pbm`.
    pub fn mask_path(&self, dir: &Path) -> PathBuf {
        dir.join("masks").join(format!("{self}_mask.pbm"))
    }
}

/// `calibration.h5`.
pub(crate) fn calibration_path(dir: &Path) -> PathBuf {
    dir.join("calibration.h5")
}

/// `poses/turntable.h5`.
pub(crate) fn turntable_path(dir: &Path) -> PathBuf {
    dir.join("poses").join("turntable.h5")
}

/// `poses/NP5_{angle}_pose.h5`.
pub(crate) fn table_pose_path(dir: &Path, angle: u32) -> PathBuf {
    dir.join("poses").join(format!("NP5_{angle}_pose.h5"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_frame_stems() {
        let id = FrameId::parse_stem("NP3_120").unwrap();
        assert_eq!((id.sensor.index(), id.angle), (3, 120));
        assert_eq!(id.to_string(), "NP3_120");
        assert!(FrameId::parse_stem("NP6_0").is_none());
        assert!(FrameId::parse_stem("N1_0").is_none());
        assert!(FrameId::parse_stem("NP1_a").is_none());
        assert!(FrameId::parse_stem("NP1_").is_none());
        assert_eq!(id.mask_path(Path::new("o")), Path::new("o/masks/NP3_120_mask.pbm"));
    }
}
