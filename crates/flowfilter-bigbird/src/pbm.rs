//! PBM (portable bitmap) masks, as BigBIRD stores them.
//!
//! In the raw bits a 1 is black; BigBIRD draws the object black on white, so a set bit is an
//! object pixel. (Decoded as an 8-bit image, as the public tools do, the object is 0 and the
//! background 255.) Both the binary `P4` and the plain `P1` variants are read; `P4` is written.

use flowfilter_geometry::Mask;

/// Why a byte buffer is not a PBM image.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PbmError {
    /// The magic number is not `P4` or `P1`.
    #[error("magic number is {found:?}, expected \"P4\" (binary PBM) or \"P1\" (plain PBM)")]
    BadMagic {
        /// The first bytes found.
        found: String,
    },
    /// The header ends early or holds a non-number.
    #[error("header is malformed: {0}")]
    BadHeader(String),
    /// The pixel data is shorter than the header says.
    #[error("pixel data is truncated: {width}x{height} needs {expected} bytes, found {found}")]
    Truncated {
        /// Width from the header.
        width: usize,
        /// Height from the header.
        height: usize,
        /// Bytes (P4) or pixels (P1) needed.
        expected: usize,
        /// Bytes or pixels found.
        found: usize,
    },
}

struct Cursor<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl Cursor<'_> {
    fn skip_space_and_comments(&mut self) {
        while self.pos < self.bytes.len() {
            match self.bytes[self.pos] {
                b'#' => {
                    while self.pos < self.bytes.len() && self.bytes[self.pos] != b'\n' {
                        self.pos += 1;
                    }
                }
                b if b.is_ascii_whitespace() => self.pos += 1,
                _ => break,
            }
        }
    }

    fn number(&mut self, what: &str) -> Result<usize, PbmError> {
        self.skip_space_and_comments();
        let start = self.pos;
        while self.pos < self.bytes.len() && self.bytes[self.pos].is_ascii_digit() {
            self.pos += 1;
        }
        let text = std::str::from_utf8(&self.bytes[start..self.pos]).unwrap_or("");
        text.parse::<usize>().map_err(|_| PbmError::BadHeader(format!("{what} is missing or not a number")))
    }
}

/// Decode a PBM image into a mask (`true` = set bit = black = object).
pub fn decode(bytes: &[u8]) -> Result<Mask, PbmError> {
    let magic = &bytes[..bytes.len().min(2)];
    let binary = match magic {
        b"P4" => true,
        b"P1" => false,
        _ => return Err(PbmError::BadMagic { found: String::from_utf8_lossy(magic).into_owned() }),
    };
    let mut c = Cursor { bytes, pos: 2 };
    let width = c.number("width")?;
    let height = c.number("height")?;
    if width == 0 || height == 0 {
        return Err(PbmError::BadHeader(format!("image size {width}x{height} is empty")));
    }
    if width.checked_mul(height).is_none_or(|n| n > 1 << 30) {
        return Err(PbmError::BadHeader(format!("image size {width}x{height} is implausibly large")));
    }
    if binary {
        // Exactly one whitespace byte separates the header from the raster.
        if c.pos >= bytes.len() || !bytes[c.pos].is_ascii_whitespace() {
            return Err(PbmError::BadHeader("no whitespace after the height".into()));
        }
        let data = &bytes[c.pos + 1..];
        let stride = width.div_ceil(8);
        let expected = stride * height;
        if data.len() < expected {
            return Err(PbmError::Truncated { width, height, expected, found: data.len() });
        }
        Ok(Mask::from_fn(width, height, |x, y| data[y * stride + x / 8] & (0x80 >> (x % 8)) != 0))
    } else {
        let mut bits = Vec::with_capacity(width * height);
        while bits.len() < width * height {
            c.skip_space_and_comments();
            match bytes.get(c.pos) {
                Some(b'0') => bits.push(false),
                Some(b'1') => bits.push(true),
                Some(other) => {
                    return Err(PbmError::BadHeader(format!("unexpected byte {other:#04x} in plain PBM data")));
                }
                None => break,
            }
            c.pos += 1;
        }
        if bits.len() < width * height {
            return Err(PbmError::Truncated { width, height, expected: width * height, found: bits.len() });
        }
        Ok(Mask::from_vec(width, height, bits).expect("length checked"))
    }
}

/// Encode a mask as binary PBM (`P4`), object pixels as set bits.
pub fn encode(mask: &Mask) -> Vec<u8> {
    let (w, h) = mask.dims();
    let stride = w.div_ceil(8);
    let mut out = format!("P4\n{w} {h}\n").into_bytes();
    let header = out.len();
    out.resize(header + stride * h, 0);
    for y in 0..h {
        for (x, &set) in mask.row(y).iter().enumerate() {
            if set {
                out[header + y * stride + x / 8] |= 0x80 >> (x % 8);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_with_padding() {
        let m = Mask::from_fn(13, 5, |x, y| (x * 7 + y * 3) % 4 == 0);
        assert_eq!(decode(&encode(&m)).unwrap(), m);
    }

    #[test]
    fn reads_plain_with_comments() {
        let m = decode(b"P1\n# a comment\n3 2\n1 0 1\n0 1 0\n").unwrap();
        assert_eq!(m.as_slice(), &[true, false, true, false, true, false]);
    }

    #[test]
    fn rejects_bad_input() {
        assert!(matches!(decode(b"P5\n1 1\n\0"), Err(PbmError::BadMagic { .. })));
        assert!(matches!(decode(b"P4\n16 2\n\xff"), Err(PbmError::Truncated { expected: 4, found: 1, .. })));
        assert!(matches!(decode(b"P4\nx 2\n"), Err(PbmError::BadHeader(_))));
        assert!(matches!(decode(b"P4\n0 2\n"), Err(PbmError::BadHeader(_))));
        assert!(matches!(decode(b""), Err(PbmError::BadMagic { .. })));
        assert!(matches!(decode(b"P1\n2 2\n1 0 1"), Err(PbmError::Truncated { .. })));
    }
}
