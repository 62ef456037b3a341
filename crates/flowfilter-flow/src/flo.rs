//! Middlebury `.flo` files: the float tag 202021.25, int32 width, int32 height, then
//! `width * height` `(u, v)` float32 pairs, row-major, little-endian. Values above 1e9 mark
//! unknown flow (read as invalid).

use crate::FlowField;
use flowfilter_geometry::{Grid, Mask};
use std::path::{Path, PathBuf};

const TAG: f32 = 202021.25;
const UNKNOWN: f32 = 1e9;

/// Why a `.flo` file cannot be read or written.
#[derive(Debug, thiserror::Error)]
pub enum FloError {
    /// The file cannot be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// The first four bytes are not the tag 202021.25.
    #[error("{}: not a .flo file (tag {found} instead of 202021.25)", path.display())]
    BadTag {
        /// The file.
        path: PathBuf,
        /// The tag found.
        found: f32,
    },
    /// Width or height are not positive, or implausibly large.
    #[error("{}: bad size {width}x{height}", path.display())]
    BadSize {
        /// The file.
        path: PathBuf,
        /// Width found.
        width: i64,
        /// Height found.
        height: i64,
    },
    /// The file is shorter than its header says.
    #[error("{}: truncated: {expected} bytes expected for {width}x{height}, found {found}", path.display())]
    Truncated {
        /// The file.
        path: PathBuf,
        /// Width.
        width: usize,
        /// Height.
        height: usize,
        /// Bytes expected.
        expected: usize,
        /// Bytes found.
        found: usize,
    },
}

/// Decode `.flo` bytes (`path` only names the source in errors).
pub fn decode(bytes: &[u8], path: &Path) -> Result<FlowField, FloError> {
    let p = || path.to_path_buf();
    if bytes.len() < 12 {
        return Err(FloError::Truncated { path: p(), width: 0, height: 0, expected: 12, found: bytes.len() });
    }
    let word = |i: usize| [bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]];
    let tag = f32::from_le_bytes(word(0));
    if tag != TAG {
        return Err(FloError::BadTag { path: p(), found: tag });
    }
    let (w, h) = (i32::from_le_bytes(word(4)) as i64, i32::from_le_bytes(word(8)) as i64);
    if w <= 0 || h <= 0 || w * h > 1 << 28 {
        return Err(FloError::BadSize { path: p(), width: w, height: h });
    }
    let (w, h) = (w as usize, h as usize);
    let expected = 12 + w * h * 8;
    if bytes.len() < expected {
        return Err(FloError::Truncated { path: p(), width: w, height: h, expected, found: bytes.len() });
    }
    let mut flow = Vec::with_capacity(w * h);
    let mut valid = Vec::with_capacity(w * h);
    for k in 0..w * h {
        let (u, v) = (f32::from_le_bytes(word(12 + 8 * k)), f32::from_le_bytes(word(16 + 8 * k)));
        let ok = u.is_finite() && v.is_finite() && u.abs() < UNKNOWN && v.abs() < UNKNOWN;
        flow.push(if ok { [u, v] } else { [0.0, 0.0] });
        valid.push(ok);
    }
    Ok(FlowField {
        flow: Grid::from_vec(w, h, flow).expect("sized"),
        valid: Mask::from_vec(w, h, valid).expect("sized"),
    })
}

/// Read a `.flo` file.
pub fn read(path: &Path) -> Result<FlowField, FloError> {
    let bytes = std::fs::read(path).map_err(|source| FloError::Io { path: path.into(), source })?;
    decode(&bytes, path)
}

/// Encode a field as `.flo` bytes (invalid pixels written as unknown, 1e10).
pub fn encode(field: &FlowField) -> Vec<u8> {
    let mut out = Vec::with_capacity(12 + field.width() * field.height() * 8);
    out.extend_from_slice(&TAG.to_le_bytes());
    out.extend_from_slice(&(field.width() as i32).to_le_bytes());
    out.extend_from_slice(&(field.height() as i32).to_le_bytes());
    for (f, &ok) in field.flow.as_slice().iter().zip(field.valid.as_slice()) {
        let [u, v] = if ok { *f } else { [1e10, 1e10] };
        out.extend_from_slice(&u.to_le_bytes());
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// Write a `.flo` file.
pub fn write(field: &FlowField, path: &Path) -> Result<(), FloError> {
    flowfilter_geometry::atomic::write_atomic(path, &encode(field))
        .map_err(|source| FloError::Io { path: path.into(), source })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_with_invalid_pixels() {
        let mut f = FlowField::zeros(7, 3);
        for (k, v) in f.flow.as_mut_slice().iter_mut().enumerate() {
            *v = [k as f32 * 0.25, -(k as f32)];
        }
        f.valid.as_mut_slice()[4] = false;
        let back = decode(&encode(&f), Path::new("mem.flo")).unwrap();
        assert_eq!(back.valid, f.valid);
        for k in 0..21 {
            if k != 4 {
                assert_eq!(back.flow.as_slice()[k], f.flow.as_slice()[k]);
            }
        }
    }

    #[test]
    fn corrupt_files_are_typed_errors() {
        let good = encode(&FlowField::zeros(4, 4));
        let p = Path::new("x.flo");
        assert!(matches!(decode(&good[..40], p), Err(FloError::Truncated { expected: 140, found: 40, .. })));
        let mut bad = good.clone();
        bad[0] = 0;
        assert!(matches!(decode(&bad, p), Err(FloError::BadTag { .. })));
        let mut neg = good.clone();
        neg[4..8].copy_from_slice(&(-3i32).to_le_bytes());
        assert!(matches!(decode(&neg, p), Err(FloError::BadSize { width: -3, .. })));
        assert!(decode(&[], p).unwrap_err().to_string().contains("x.flo"));
        assert!(matches!(read(Path::new("/no/such.flo")), Err(FloError::Io { .. })));
    }
}
