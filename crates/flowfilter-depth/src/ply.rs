//! PLY import and export of point clouds (ASCII and binary little/big endian).
//!
//! Written: `x y z` as `double`, then `nx ny nz` (`double`) and `red green blue` (`uchar`) when
//! present, the layout Open3D writes. Read: any scalar property types, vertex element first or
//! after other elements; unknown vertex properties and other elements (faces) are skipped.

use crate::error::DepthError;
use flowfilter_geometry::{Point3, PointCloud, Vector3};
use std::path::Path;

/// PLY encoding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlyFormat {
    /// `format ascii 1.0`.
    Ascii,
    /// `format binary_little_endian 1.0`.
    BinaryLittleEndian,
}

fn ply_err(path: &Path, message: impl Into<String>) -> DepthError {
    DepthError::Ply { path: path.into(), message: message.into() }
}

/// Write a cloud.
pub fn write_ply(cloud: &PointCloud, path: &Path, format: PlyFormat) -> Result<(), DepthError> {
    cloud.validate().map_err(|e| ply_err(path, e.to_string()))?;
    let mut out = Vec::new();
    let fmt = match format {
        PlyFormat::Ascii => "ascii",
        PlyFormat::BinaryLittleEndian => "binary_little_endian",
    };
    let mut header =
        format!("ply\nformat {fmt} 1.0\ncomment written by flowfilter-depth\nelement vertex {}\n", cloud.len());
    header += "property double x\nproperty double y\nproperty double z\n";
    if cloud.normals.is_some() {
        header += "property double nx\nproperty double ny\nproperty double nz\n";
    }
    if cloud.colors.is_some() {
        header += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
    }
    header += "end_header\n";
    out.extend_from_slice(header.as_bytes());
    for i in 0..cloud.len() {
        let p = cloud.points[i];
        let n = cloud.normals.as_ref().map(|v| v[i]);
        let c = cloud.colors.as_ref().map(|v| v[i]);
        match format {
            PlyFormat::Ascii => {
                let mut line = format!("{:?} {:?} {:?}", p.x, p.y, p.z);
                if let Some(n) = n {
                    line += &format!(" {:?} {:?} {:?}", n.x, n.y, n.z);
                }
                if let Some(c) = c {
                    line += &format!(" {} {} {}", c[0], c[1], c[2]);
                }
                line.push('\n');
                out.extend_from_slice(line.as_bytes());
            }
            PlyFormat::BinaryLittleEndian => {
                for v in [p.x, p.y, p.z] {
                    out.extend_from_slice(&v.to_le_bytes());
                }
                if let Some(n) = n {
                    for v in [n.x, n.y, n.z] {
                        out.extend_from_slice(&v.to_le_bytes());
                    }
                }
                if let Some(c) = c {
                    out.extend_from_slice(&c);
                }
            }
        }
    }
    flowfilter_geometry::atomic::write_atomic(path, &out).map_err(|e| ply_err(path, format!("cannot write: {e}")))
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    fn read(self, b: &[u8], big: bool) -> f64 {
        macro_rules! num {
            ($t:ty, $n:literal) => {{
                let a: [u8; $n] = b[..$n].try_into().unwrap();
                f64::from(if big { <$t>::from_be_bytes(a) } else { <$t>::from_le_bytes(a) })
            }};
        }
        match self {
            Self::I8 => f64::from(b[0] as i8),
            Self::U8 => f64::from(b[0]),
            Self::I16 => num!(i16, 2),
            Self::U16 => num!(u16, 2),
            Self::I32 => num!(i32, 4),
            Self::U32 => num!(u32, 4),
            Self::F32 => num!(f32, 4),
            Self::F64 => num!(f64, 8),
        }
    }
}

#[derive(Debug, Clone)]
enum Property {
    Scalar(String, Scalar),
    List(Scalar, Scalar),
}

struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
}

/// Read a PLY point cloud (vertex positions; normals and colours when present).
pub fn read_ply(path: &Path) -> Result<PointCloud, DepthError> {
    let bytes = std::fs::read(path).map_err(|e| ply_err(path, format!("cannot read: {e}")))?;
    let end =
        bytes.windows(11).position(|w| w == b"end_header\n").ok_or_else(|| ply_err(path, "no 'end_header' line"))?;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| ply_err(path, "header is not text"))?;
    let mut body = &bytes[end + 11..];
    let mut lines = header.lines();
    if lines.next().map(str::trim) != Some("ply") {
        return Err(ply_err(path, "not a PLY file (first line is not 'ply')"));
    }
    let (mut format, mut elements) = (None, Vec::<Element>::new());
    for line in lines {
        let t: Vec<&str> = line.split_whitespace().collect();
        match t.as_slice() {
            ["format", f, _] => format = Some(f.to_string()),
            ["element", name, count] => elements.push(Element {
                name: name.to_string(),
                count: count.parse().map_err(|_| ply_err(path, format!("bad element count '{count}'")))?,
                props: vec![],
            }),
            ["property", "list", c, i, _] => {
                let (c, i) = (Scalar::parse(c), Scalar::parse(i));
                let e = elements.last_mut().ok_or_else(|| ply_err(path, "property before any element"))?;
                e.props.push(Property::List(
                    c.ok_or_else(|| ply_err(path, "bad list count type"))?,
                    i.ok_or_else(|| ply_err(path, "bad list item type"))?,
                ));
            }
            ["property", ty, name] => {
                let s = Scalar::parse(ty).ok_or_else(|| ply_err(path, format!("unknown property type '{ty}'")))?;
                let e = elements.last_mut().ok_or_else(|| ply_err(path, "property before any element"))?;
                e.props.push(Property::Scalar(name.to_string(), s));
            }
            [] | ["comment", ..] | ["obj_info", ..] => {}
            _ => return Err(ply_err(path, format!("unexpected header line '{line}'"))),
        }
    }
    let format = format.ok_or_else(|| ply_err(path, "no 'format' line"))?;
    let big = match format.as_str() {
        "ascii" => None,
        "binary_little_endian" => Some(false),
        "binary_big_endian" => Some(true),
        other => return Err(ply_err(path, format!("unknown format '{other}'"))),
    };
    let mut cloud = PointCloud::default();
    let mut text = if big.is_none() {
        Some(std::str::from_utf8(body).map_err(|_| ply_err(path, "ASCII body is not text"))?.split_ascii_whitespace())
    } else {
        None
    };
    let truncated = || ply_err(path, "data ends before the header's element counts");
    for e in &elements {
        let is_vertex = e.name == "vertex";
        let names: Vec<&str> =
            e.props.iter().map(|p| if let Property::Scalar(n, _) = p { n.as_str() } else { "" }).collect();
        let find = |n: &str| names.iter().position(|x| *x == n);
        let (ix, iy, iz) = (find("x"), find("y"), find("z"));
        let normals = [find("nx"), find("ny"), find("nz")];
        let colors = [find("red"), find("green"), find("blue")];
        if is_vertex && (ix.is_none() || iy.is_none() || iz.is_none()) {
            return Err(ply_err(path, "vertex element lacks x, y or z"));
        }
        let has_n = is_vertex && normals.iter().all(Option::is_some);
        let has_c = is_vertex && colors.iter().all(Option::is_some);
        // A damaged header may declare any count: reserve no more than the data can hold.
        let reserve = e.count.min(bytes.len());
        if is_vertex {
            cloud.points.reserve(reserve);
        }
        if has_n {
            cloud.normals = Some(Vec::with_capacity(reserve));
        }
        if has_c {
            cloud.colors = Some(Vec::with_capacity(reserve));
        }
        let mut vals = vec![0.0f64; e.props.len()];
        for _ in 0..e.count {
            for (j, p) in e.props.iter().enumerate() {
                match (p, &mut text) {
                    (Property::Scalar(_, _), Some(t)) => {
                        let tok = t.next().ok_or_else(truncated)?;
                        vals[j] = tok.parse().map_err(|_| ply_err(path, format!("'{tok}' is not a number")))?;
                    }
                    (Property::Scalar(_, s), None) => {
                        if body.len() < s.size() {
                            return Err(truncated());
                        }
                        vals[j] = s.read(body, big == Some(true));
                        body = &body[s.size()..];
                    }
                    (Property::List(_, _), Some(t)) => {
                        let n: usize =
                            t.next().ok_or_else(truncated)?.parse().map_err(|_| ply_err(path, "bad list length"))?;
                        for _ in 0..n {
                            t.next().ok_or_else(truncated)?;
                        }
                    }
                    (Property::List(c, i), None) => {
                        if body.len() < c.size() {
                            return Err(truncated());
                        }
                        let n = c.read(body, big == Some(true)) as usize;
                        let skip = c.size() + n * i.size();
                        if body.len() < skip {
                            return Err(truncated());
                        }
                        body = &body[skip..];
                    }
                }
            }
            if is_vertex {
                let g = |i: Option<usize>| vals[i.expect("checked")];
                cloud.points.push(Point3::new(g(ix), g(iy), g(iz)));
                if let Some(v) = &mut cloud.normals {
                    v.push(Vector3::new(g(normals[0]), g(normals[1]), g(normals[2])));
                }
                if let Some(v) = &mut cloud.colors {
                    v.push(colors.map(|c| g(c).clamp(0.0, 255.0) as u8));
                }
            }
        }
    }
    let trailing = match &mut text {
        Some(t) => t.next().is_some(),
        None => body.iter().any(|b| !b.is_ascii_whitespace()),
    };
    if trailing {
        let declared: Vec<String> = elements.iter().map(|e| format!("{} {}", e.count, e.name)).collect();
        return Err(ply_err(
            path,
            format!(
                "data continues after the elements the header declares ({}): wrong count or a damaged file",
                declared.join(", ")
            ),
        ));
    }
    if let Some(i) = cloud.normals.as_ref().and_then(|n| n.iter().position(|v| !v.iter().all(|c| c.is_finite()))) {
        return Err(ply_err(path, format!("vertex {i}: the normal (nx, ny, nz) is not finite")));
    }
    cloud.validate().map_err(|e| ply_err(path, e.to_string()))?;
    Ok(cloud)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> PointCloud {
        let points: Vec<Point3> =
            (0..50).map(|i| Point3::new(i as f64 * 0.1, -(i as f64).sqrt(), 1.0 / (1.0 + i as f64))).collect();
        PointCloud {
            normals: Some(points.iter().map(|p| p.coords.try_normalize(1e-9).unwrap_or(Vector3::z())).collect()),
            colors: Some((0..50).map(|i| [i as u8, 255 - i as u8, 7]).collect()),
            pixels: None,
            points,
        }
    }

    #[test]
    fn round_trips_exactly_in_both_formats() {
        let dir = tempfile::tempdir().unwrap();
        for f in [PlyFormat::Ascii, PlyFormat::BinaryLittleEndian] {
            let p = dir.path().join("c.ply");
            write_ply(&sample(), &p, f).unwrap();
            assert_eq!(read_ply(&p).unwrap(), sample(), "{f:?}");
        }
    }

    #[test]
    fn bad_files_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("bad.ply");
        std::fs::write(&p, b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n\0\0").unwrap();
        assert!(read_ply(&p).unwrap_err().to_string().contains("data ends"));
        std::fs::write(&p, b"hello").unwrap();
        assert!(read_ply(&p).unwrap_err().to_string().contains("end_header"));
        assert!(read_ply(&dir.path().join("none.ply")).is_err());
        let header = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n";
        std::fs::write(&p, format!("{header}end_header\n0 0 0\n1 1 1\n2 2 2\n")).unwrap();
        assert!(read_ply(&p).unwrap_err().to_string().contains("data continues after the elements"));
        let normals = "property float nx\nproperty float ny\nproperty float nz\n";
        std::fs::write(&p, format!("{header}{normals}end_header\n0 0 0 0 0 1\n1 1 1 nan 0 1\n")).unwrap();
        let e = read_ply(&p).unwrap_err().to_string();
        assert!(e.contains("bad.ply") && e.contains("vertex 1: the normal"), "{e}");
        let huge = "ply\nformat binary_little_endian 1.0\nelement vertex 999999999999999\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nend_header\n";
        std::fs::write(&p, huge).unwrap();
        assert!(read_ply(&p).unwrap_err().to_string().contains("data ends"));
    }
}
