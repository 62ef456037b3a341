//! [`CameraFile`]: a camera described by a small JSON file, in this project's layout or in the
//! two layouts other tools write (a BOP `scene_camera.json` entry or `camera.json`, and Open3D's
//! `PinholeCameraIntrinsic`).
//!
//! | layout | keys | intrinsic matrix | depth unit |
//! | --- | --- | --- | --- |
//! | flowfilter | `K`, optional `width` and `height`, optional `distortion` (`k1 k2 p1 p2 k3`), optional `depth_unit_m` (or `depth_png_units_per_metre`) | `K`: 9 numbers row-major, or 3 rows of 3 | metres per raw depth unit |
//! | BOP | `cam_K` (or `fx`, `fy`, `cx`, `cy`), `depth_scale`, optional `width`, `height` | `cam_K`: 9 numbers, row-major | `depth_scale` millimetres per unit |
//! | Open3D | `width`, `height`, `intrinsic_matrix` | 9 numbers, column-major | none |
//!
//! A sensor whose depth is *not* registered to colour (BigBIRD, raw Kinect or Azure depth) adds,
//! in this project's layout, a `depth` object (its own `K`, `width`, `height`, optional
//! `distortion`) and `color_from_depth`: the rigid motion from the depth camera's frame to the
//! colour camera's, 16 numbers row-major or 4 rows of 4, translation in metres. The depth stage
//! then registers depth to colour; without them depth is taken as registered and is not moved.
//!
//! Any layout may add `depth_bias` ([`DepthBias`]: `cols`, `rows`, `width`, `height`, `metres`),
//! the depth sensor's own error over its depth image, as `flowfilter calibrate-depth` writes it.
//!
//! A BOP `scene_camera.json` holds one entry per image (`{"0": {...}, "1": {...}}`): pass the
//! entry, e.g. with [`CameraFile::from_json_value`]. Without `width` and `height` the images give
//! the size ([`CameraFile::model`]).

use crate::{CameraError, CameraModel, DepthBias, Distortion, ImageSize, Intrinsics, RgbdSensor};
use flowfilter_geometry::{Pose, rigid_from_matrix};
use nalgebra::{Matrix3, Matrix4};
use serde_json::Value;
use std::path::Path;

/// Which layout a camera file was written in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CameraFileLayout {
    /// This project's own (`K`).
    Flowfilter,
    /// The BOP toolkit's (`cam_K` or `fx`/`fy`/`cx`/`cy`, `depth_scale` in millimetres).
    Bop,
    /// Open3D's `PinholeCameraIntrinsic` (`intrinsic_matrix`, column-major).
    Open3d,
}

/// Why a camera file cannot be used; every variant names the file (or `<string>`).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraFileError {
    /// The file cannot be read.
    #[error("{path}: cannot read: {message}")]
    Read {
        /// The file.
        path: String,
        /// The system's message.
        message: String,
    },
    /// The text is not JSON.
    #[error("{path}: not JSON: {message}")]
    Json {
        /// The file.
        path: String,
        /// The parser's message.
        message: String,
    },
    /// No known layout's keys are present.
    #[error(
        "{path}: not a camera file: expected `K` (flowfilter), `cam_K` or `fx` (BOP) or `intrinsic_matrix` (Open3D); found keys {found:?}"
    )]
    UnknownLayout {
        /// The file.
        path: String,
        /// The keys found.
        found: Vec<String>,
    },
    /// A field is missing or has the wrong type or length.
    #[error("{path}: field '{field}': expected {expected}, found {found}")]
    Field {
        /// The file.
        path: String,
        /// The field.
        field: &'static str,
        /// What it must be.
        expected: &'static str,
        /// What it is.
        found: String,
    },
    /// The values do not make a camera (zero focal length, skew, a bad depth unit...).
    #[error("{path}: field '{field}': {source}")]
    Camera {
        /// The file.
        path: String,
        /// The field at fault.
        field: &'static str,
        /// Why.
        #[source]
        source: CameraError,
    },
}

/// A camera read from a JSON file.
///
/// ```
/// use flowfilter_camera::{CameraFile, CameraFileLayout};
/// // One entry of a BOP scene_camera.json (YCB-Video: depth in 0.1 mm units).
/// let text = r#"{"cam_K": [1066.778, 0.0, 312.9869, 0.0, 1067.487, 241.3109, 0.0, 0.0, 1.0], "depth_scale": 0.1}"#;
/// let camera = CameraFile::from_json_str(text, "scene_camera.json")?;
/// assert_eq!(camera.layout, CameraFileLayout::Bop);
/// assert!((camera.metres_per_unit.unwrap() - 1e-4).abs() < 1e-15);
/// let sensor = camera.registered_sensor(Some((640, 480)))?;
/// assert_eq!(sensor.depth, sensor.color);
/// # Ok::<(), flowfilter_camera::CameraFileError>(())
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct CameraFile {
    /// The layout the file was written in.
    pub layout: CameraFileLayout,
    /// Focal lengths and principal point (pixels).
    pub intrinsics: Intrinsics,
    /// Lens distortion (none unless the file gives it).
    pub distortion: Distortion,
    /// The image size, when the file gives it.
    pub size: Option<ImageSize>,
    /// Metres per raw depth unit, when the file gives it.
    pub metres_per_unit: Option<f64>,
    /// A separate depth camera and its pose, when depth is not registered to colour.
    pub depth: Option<DepthCamera>,
    /// The depth sensor's own error over its image (`depth_bias`), when the file gives it:
    /// frames read with this camera have their raw depth corrected by it.
    pub depth_bias: Option<DepthBias>,
    /// The file, for messages.
    pub origin: String,
}

/// The depth camera of a sensor whose depth is not registered to colour.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthCamera {
    /// Its focal lengths and principal point (pixels).
    pub intrinsics: Intrinsics,
    /// Its lens distortion.
    pub distortion: Distortion,
    /// Its image size, when given.
    pub size: Option<ImageSize>,
    /// Maps points in the depth camera's frame into the colour camera's.
    pub color_from_depth: Pose,
}

impl CameraFile {
    /// Read and parse a camera file.
    ///
    /// # Errors
    /// [`CameraFileError`] naming the file and, for bad values, the field.
    pub fn from_file(path: &Path) -> Result<Self, CameraFileError> {
        let origin = path.display().to_string();
        let text = std::fs::read_to_string(path)
            .map_err(|e| CameraFileError::Read { path: origin.clone(), message: e.to_string() })?;
        Self::from_json_str(&text, &origin)
    }

    /// Parse JSON text; `origin` names it in errors.
    ///
    /// # Errors
    /// As [`CameraFile::from_file`].
    pub fn from_json_str(text: &str, origin: &str) -> Result<Self, CameraFileError> {
        let value: Value = serde_json::from_str(text)
            .map_err(|e| CameraFileError::Json { path: origin.to_string(), message: e.to_string() })?;
        Self::from_json_value(&value, origin)
    }

    /// A camera from a parsed JSON object (e.g. one entry of a BOP `scene_camera.json`).
    ///
    /// # Errors
    /// As [`CameraFile::from_file`].
    pub fn from_json_value(value: &Value, origin: &str) -> Result<Self, CameraFileError> {
        let r = Reader { value, origin };
        let Some(object) = value.as_object() else {
            return Err(r.field_error("(the file)", "a JSON object", value));
        };
        if let Some(entry) = Self::single_bop_entry(object, origin)? {
            return Self::from_json_value(entry, origin);
        }
        let layout = if object.contains_key("K") {
            CameraFileLayout::Flowfilter
        } else if object.contains_key("cam_K") || object.contains_key("fx") {
            CameraFileLayout::Bop
        } else if object.contains_key("intrinsic_matrix") {
            CameraFileLayout::Open3d
        } else {
            return Err(CameraFileError::UnknownLayout {
                path: origin.into(),
                found: object.keys().cloned().collect(),
            });
        };
        let (field, k) = match layout {
            CameraFileLayout::Flowfilter => ("K", Matrix3::from_row_slice(&r.square_matrix("K", 3)?)),
            CameraFileLayout::Open3d => {
                ("intrinsic_matrix", Matrix3::from_column_slice(&r.numbers("intrinsic_matrix", 9)?))
            }
            CameraFileLayout::Bop if object.contains_key("cam_K") => {
                ("cam_K", Matrix3::from_row_slice(&r.numbers("cam_K", 9)?))
            }
            CameraFileLayout::Bop => {
                let [fx, fy, cx, cy] = [r.number("fx")?, r.number("fy")?, r.number("cx")?, r.number("cy")?];
                ("fx", Matrix3::new(fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0))
            }
        };
        let intrinsics = Intrinsics::from_matrix(&k).map_err(|source| r.camera_error(field, source))?;
        let (distortion, size) = r.distortion_and_size()?;
        let depth = match object.get("depth") {
            Some(entry) if layout == CameraFileLayout::Flowfilter => Some(r.depth_camera(entry)?),
            _ => None,
        };
        let metres_per_unit = match layout {
            CameraFileLayout::Flowfilter if object.contains_key("depth_png_units_per_metre") => {
                Some(1.0 / r.number("depth_png_units_per_metre")?)
            }
            CameraFileLayout::Flowfilter => object.get("depth_unit_m").map(|_| r.number("depth_unit_m")).transpose()?,
            CameraFileLayout::Bop => {
                object.get("depth_scale").map(|_| r.number("depth_scale").map(|mm| mm * 1e-3)).transpose()?
            }
            CameraFileLayout::Open3d => None,
        };
        if let Some(unit) = metres_per_unit
            && !(crate::MIN_METRES_PER_UNIT..=crate::MAX_METRES_PER_UNIT).contains(&unit)
        {
            let field = match layout {
                CameraFileLayout::Bop => "depth_scale",
                _ if object.contains_key("depth_png_units_per_metre") => "depth_png_units_per_metre",
                _ => "depth_unit_m",
            };
            return Err(r.camera_error(field, CameraError::BadDepthScale { value: unit }));
        }
        let depth_bias = object.get("depth_bias").map(|v| r.depth_bias(v)).transpose()?;
        Ok(Self { layout, intrinsics, distortion, size, metres_per_unit, depth, depth_bias, origin: origin.into() })
    }

    /// A whole BOP `scene_camera.json` (entries keyed by image id) stands for its camera when
    /// every entry is the same; with cameras that differ one must pick the image's entry.
    fn single_bop_entry<'v>(
        object: &'v serde_json::Map<String, Value>,
        origin: &str,
    ) -> Result<Option<&'v Value>, CameraFileError> {
        let by_image = !object.is_empty() && object.keys().all(|k| k.parse::<u32>().is_ok());
        if !by_image {
            return Ok(None);
        }
        let mut entries = object.values();
        let first = entries.next().expect("not empty");
        if entries.all(|e| e == first) {
            return Ok(Some(first));
        }
        Err(CameraFileError::Field {
            path: origin.into(),
            field: "(image ids)",
            expected: "one camera for every image (or pass the entry of the image, e.g. with from_json_value)",
            found: format!("{} entries that differ", object.len()),
        })
    }

    /// The camera model; `image_size` (width, height) is used when the file gives no size and
    /// must agree with it when it does.
    ///
    /// # Errors
    /// [`CameraFileError::Field`] when neither gives a size or the two disagree.
    pub fn model(&self, image_size: Option<(u32, u32)>) -> Result<CameraModel, CameraFileError> {
        let size = self.resolve_size(self.size, image_size, "width")?;
        Ok(CameraModel::new(self.intrinsics, self.distortion, size))
    }

    /// The size of a camera: the file's, or the images' (the two must agree).
    fn resolve_size(
        &self,
        file: Option<ImageSize>,
        images: Option<(u32, u32)>,
        field: &'static str,
    ) -> Result<ImageSize, CameraFileError> {
        match (file, images) {
            (Some(s), Some((w, h))) if (s.width, s.height) != (w, h) => Err(CameraFileError::Field {
                path: self.origin.clone(),
                field,
                expected: "the images' size",
                found: format!("{}x{} against images of {w}x{h}", s.width, s.height),
            }),
            (Some(s), _) => Ok(s),
            (None, Some((w, h))) => ImageSize::new(w, h).map_err(|source| CameraFileError::Camera {
                path: self.origin.clone(),
                field,
                source,
            }),
            (None, None) => Err(CameraFileError::Field {
                path: self.origin.clone(),
                field,
                expected: "an image size (in the file, or from the images)",
                found: "none".into(),
            }),
        }
    }

    /// The file's depth unit, or an error naming the field that should give it.
    fn depth_unit(&self) -> Result<f64, CameraFileError> {
        self.metres_per_unit.ok_or_else(|| CameraFileError::Field {
            path: self.origin.clone(),
            field: if self.layout == CameraFileLayout::Bop { "depth_scale" } else { "depth_unit_m" },
            expected: "the depth unit (a positive number)",
            found: "none".into(),
        })
    }

    /// Whether the file describes depth registered to colour (no separate depth camera).
    pub fn is_registered(&self) -> bool {
        self.depth.is_none()
    }

    /// The sensor the file describes: [`CameraFile::registered_sensor`] without a `depth`
    /// camera, else the two cameras and their pose. `color_size` and `depth_size` are the
    /// images' sizes (used when the file gives none; checked when it does).
    ///
    /// # Errors
    /// As [`CameraFile::registered_sensor`].
    pub fn sensor(
        &self,
        color_size: Option<(u32, u32)>,
        depth_size: Option<(u32, u32)>,
    ) -> Result<RgbdSensor, CameraFileError> {
        let Some(d) = &self.depth else { return self.registered_sensor(color_size) };
        let color = self.model(color_size)?;
        let depth = CameraModel::new(d.intrinsics, d.distortion, self.resolve_size(d.size, depth_size, "depth.width")?);
        RgbdSensor::new(depth, color, d.color_from_depth, self.depth_unit()?)
            .map_err(|source| CameraFileError::Camera { path: self.origin.clone(), field: "depth_unit_m", source })
    }

    /// The sensor of depth registered to colour (RealSense aligned depth, YCB-Video, BOP): one
    /// camera model for both, identity extrinsics, the file's depth unit.
    ///
    /// # Errors
    /// As [`CameraFile::model`], and [`CameraFileError::Field`] when the file gives no depth
    /// unit.
    pub fn registered_sensor(&self, image_size: Option<(u32, u32)>) -> Result<RgbdSensor, CameraFileError> {
        let camera = self.model(image_size)?;
        RgbdSensor::registered(camera, self.depth_unit()?).map_err(|source| CameraFileError::Camera {
            path: self.origin.clone(),
            field: "depth_unit_m",
            source,
        })
    }
}

/// Typed access to the fields of one JSON object, with errors naming file and field.
struct Reader<'a> {
    value: &'a Value,
    origin: &'a str,
}

impl Reader<'_> {
    fn field_error(&self, field: &'static str, expected: &'static str, found: &Value) -> CameraFileError {
        let mut found = found.to_string();
        if found.len() > 60 {
            found.truncate(57);
            found.push_str("...");
        }
        CameraFileError::Field { path: self.origin.into(), field, expected, found }
    }

    fn camera_error(&self, field: &'static str, source: CameraError) -> CameraFileError {
        CameraFileError::Camera { path: self.origin.into(), field, source }
    }

    fn get(&self, field: &'static str) -> Result<&Value, CameraFileError> {
        self.value.get(field).ok_or_else(|| CameraFileError::Field {
            path: self.origin.into(),
            field,
            expected: "a value",
            found: "nothing (missing)".into(),
        })
    }

    fn number(&self, field: &'static str) -> Result<f64, CameraFileError> {
        let v = self.get(field)?;
        v.as_f64().ok_or_else(|| self.field_error(field, "a number", v))
    }

    fn dimension(&self, field: &'static str) -> Result<u32, CameraFileError> {
        let v = self.get(field)?;
        v.as_u64()
            .and_then(|n| u32::try_from(n).ok())
            .ok_or_else(|| self.field_error(field, "a whole number of pixels", v))
    }

    /// An `n`x`n` matrix as `n * n` numbers (row-major), from a flat array or from `n` rows of
    /// `n` (`n` is 3 or 4).
    fn square_matrix(&self, field: &'static str, n: usize) -> Result<Vec<f64>, CameraFileError> {
        let v = self.get(field)?;
        let row = |r: &Value| r.as_array().filter(|r| r.len() == n).and_then(|r| r.iter().map(Value::as_f64).collect());
        let values: Option<Vec<f64>> = match v.as_array() {
            Some(rows) if rows.len() == n && rows.iter().all(Value::is_array) => {
                rows.iter().map(row).collect::<Option<Vec<Vec<f64>>>>().map(|rows| rows.concat())
            }
            Some(flat) if flat.len() == n * n => flat.iter().map(Value::as_f64).collect(),
            _ => None,
        };
        let expected = if n == 3 { "9 numbers, or 3 rows of 3 numbers" } else { "16 numbers, or 4 rows of 4 numbers" };
        values.ok_or_else(|| self.field_error(field, expected, v))
    }

    /// Optional `distortion` (5 numbers) and optional `width` and `height`.
    fn distortion_and_size(&self) -> Result<(Distortion, Option<ImageSize>), CameraFileError> {
        let distortion = match self.value.get("distortion") {
            Some(_) => Distortion::from_slice(&self.numbers("distortion", 5)?)
                .map_err(|source| self.camera_error("distortion", source))?,
            None => Distortion::NONE,
        };
        let size = match (self.value.get("width"), self.value.get("height")) {
            (None, None) => None,
            _ => Some(
                ImageSize::new(self.dimension("width")?, self.dimension("height")?)
                    .map_err(|source| self.camera_error("width", source))?,
            ),
        };
        Ok((distortion, size))
    }

    /// The `depth` object and `color_from_depth` of a sensor with a separate depth camera.
    fn depth_camera(&self, entry: &Value) -> Result<DepthCamera, CameraFileError> {
        let origin = format!("{} (depth camera)", self.origin);
        let d = Reader { value: entry, origin: &origin };
        if !entry.is_object() {
            return Err(self.field_error("depth", "an object with K, width, height", entry));
        }
        let k = Matrix3::from_row_slice(&d.square_matrix("K", 3)?);
        let intrinsics = Intrinsics::from_matrix(&k).map_err(|source| d.camera_error("K", source))?;
        let (distortion, size) = d.distortion_and_size()?;
        let m = Matrix4::from_row_slice(&self.square_matrix("color_from_depth", 4)?);
        let color_from_depth = rigid_from_matrix(&m).map_err(|e| CameraFileError::Field {
            path: self.origin.into(),
            field: "color_from_depth",
            expected: "a rigid transform (rotation and translation in metres)",
            found: e.to_string(),
        })?;
        Ok(DepthCamera { intrinsics, distortion, size, color_from_depth })
    }

    /// The `depth_bias` object: `cols`, `rows`, `width`, `height` and `metres` (row-major).
    fn depth_bias(&self, entry: &Value) -> Result<DepthBias, CameraFileError> {
        let bias: DepthBias = serde_json::from_value(entry.clone()).map_err(|e| CameraFileError::Field {
            path: self.origin.into(),
            field: "depth_bias",
            expected: "an object with cols, rows, width, height and metres (rows * cols numbers)",
            found: e.to_string(),
        })?;
        bias.validate().map_err(|e| CameraFileError::Field {
            path: self.origin.into(),
            field: "depth_bias",
            expected: "a field of at most 128 x 128 finite values within 0.1 m",
            found: e.to_string(),
        })?;
        Ok(bias)
    }

    fn numbers(&self, field: &'static str, n: usize) -> Result<Vec<f64>, CameraFileError> {
        let v = self.get(field)?;
        let expected = if n == 9 { "an array of 9 numbers" } else { "an array of 5 numbers" };
        let values: Option<Vec<f64>> = v.as_array().and_then(|a| a.iter().map(Value::as_f64).collect());
        match values {
            Some(values) if values.len() == n => Ok(values),
            _ => Err(self.field_error(field, expected, v)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_three_layouts_give_the_same_camera() {
        let ours =
            r#"{"width": 640, "height": 480, "K": [525.0, 0, 319.5, 0, 526.0, 239.5, 0, 0, 1], "depth_unit_m": 0.001}"#;
        let bop = r#"{"cam_K": [525.0, 0, 319.5, 0, 526.0, 239.5, 0, 0, 1], "depth_scale": 1.0}"#;
        let bop_camera =
            r#"{"fx": 525.0, "fy": 526.0, "cx": 319.5, "cy": 239.5, "width": 640, "height": 480, "depth_scale": 1.0}"#;
        let open3d =
            r#"{"width": 640, "height": 480, "intrinsic_matrix": [525.0, 0, 0, 0, 526.0, 0, 319.5, 239.5, 1]}"#;
        let cams: Vec<CameraFile> =
            [ours, bop, bop_camera, open3d].iter().map(|t| CameraFile::from_json_str(t, "c.json").unwrap()).collect();
        let layouts: Vec<CameraFileLayout> = cams.iter().map(|c| c.layout).collect();
        assert_eq!(
            layouts,
            [CameraFileLayout::Flowfilter, CameraFileLayout::Bop, CameraFileLayout::Bop, CameraFileLayout::Open3d]
        );
        let model = cams[0].model(None).unwrap();
        for c in &cams {
            assert_eq!(c.model(Some((640, 480))).unwrap(), model, "{:?}", c.layout);
        }
        assert_eq!(cams[0].metres_per_unit, Some(0.001));
        assert_eq!(cams[1].metres_per_unit, Some(0.001));
        assert_eq!(cams[3].metres_per_unit, None);
        assert!(cams[3].registered_sensor(None).is_err());
        assert!(cams[0].registered_sensor(None).unwrap().is_registered());
    }

    #[test]
    fn k_may_be_given_as_rows() {
        let t = r#"{"K": [[50, 0, 32], [0, 51, 24], [0, 0, 1]], "width": 64, "height": 48, "depth_png_units_per_metre": 10000.0}"#;
        let c = CameraFile::from_json_str(t, "gt.json").unwrap();
        assert_eq!((c.intrinsics.fx, c.intrinsics.fy, c.intrinsics.cx, c.intrinsics.cy), (50.0, 51.0, 32.0, 24.0));
        assert_eq!(c.metres_per_unit, Some(1e-4));
        let bad = r#"{"K": [[50, 0, 32], [0, 51, 24]], "width": 64, "height": 48}"#;
        let e = CameraFile::from_json_str(bad, "gt.json").unwrap_err().to_string();
        assert!(e.contains("3 rows of 3"), "{e}");
    }

    #[test]
    fn distortion_is_read_in_opencv_order() {
        let t = r#"{"width": 64, "height": 48, "K": [50, 0, 32, 0, 50, 24, 0, 0, 1], "distortion": [0.1, -0.2, 0.001, 0.002, 0.05]}"#;
        let c = CameraFile::from_json_str(t, "c.json").unwrap();
        assert_eq!(c.distortion.to_array(), [0.1, -0.2, 0.001, 0.002, 0.05]);
    }

    #[test]
    fn bad_files_name_the_file_and_the_field() {
        let cases = [
            ("{", "not JSON"),
            (r#"[1, 2]"#, "a JSON object"),
            (r#"{"focal": 500}"#, "not a camera file"),
            (r#"{"cam_K": [0, 0, 320, 0, 500, 240, 0, 0, 1], "depth_scale": 1}"#, "'cam_K'"),
            (r#"{"cam_K": [500, 0, 320, 0, 500, 240, 0, 0, 1], "depth_scale": 0}"#, "'depth_scale'"),
            (
                r#"{"cam_K": [500, 0, 320, 0, 500, 240, 0, 0, 1], "depth_scale": "1"}"#,
                "'depth_scale': expected a number",
            ),
            (r#"{"cam_K": [500, 0, 320, 0, 500, 240], "depth_scale": 1}"#, "expected an array of 9 numbers"),
            (r#"{"K": [500, 0, 320, 0, 500, 240, 0, 0, 1], "height": 480}"#, "'width'"),
            (r#"{"K": [500, 0, 320, 0, 500, 240, 0, 0, 1], "width": 640.5, "height": 480}"#, "whole number"),
            (r#"{"K": [500, 0, 320, 0, 500, 240, 0, 0, 1], "width": 0, "height": 480}"#, "non-zero"),
            (r#"{"K": [500, 3, 320, 0, 500, 240, 0, 0, 1], "width": 640, "height": 480}"#, "entry (0, 1)"),
            (
                r#"{"K": [500, 0, 320, 0, 500, 240, 0, 0, 1], "width": 640, "height": 480, "distortion": [1]}"#,
                "'distortion'",
            ),
        ];
        for (text, needle) in cases {
            let e = CameraFile::from_json_str(text, "cam.json").unwrap_err().to_string();
            assert!(e.starts_with("cam.json") && e.contains(needle), "{text}: {e}");
        }
        let e = CameraFile::from_file(Path::new("/no/such/camera.json")).unwrap_err().to_string();
        assert!(e.contains("/no/such/camera.json") && e.contains("cannot read"), "{e}");
    }

    #[test]
    fn a_whole_scene_camera_file_stands_for_its_one_camera() {
        let entry = r#"{"cam_K": [500, 0, 320, 0, 500, 240, 0, 0, 1], "depth_scale": 0.1}"#;
        let whole = format!(r#"{{"0": {entry}, "1": {entry}, "7": {entry}}}"#);
        let c = CameraFile::from_json_str(&whole, "scene_camera.json").unwrap();
        assert_eq!(c, CameraFile::from_json_str(entry, "scene_camera.json").unwrap());
        let other = r#"{"cam_K": [510, 0, 320, 0, 510, 240, 0, 0, 1], "depth_scale": 0.1}"#;
        let e = CameraFile::from_json_str(&format!(r#"{{"0": {entry}, "1": {other}}}"#), "scene_camera.json")
            .unwrap_err()
            .to_string();
        assert!(e.contains("scene_camera.json") && e.contains("2 entries that differ"), "{e}");
    }

    #[test]
    fn a_bop_entry_takes_its_size_from_the_images_and_must_agree_with_a_given_one() {
        let bop = r#"{"cam_K": [500, 0, 320, 0, 500, 240, 0, 0, 1], "depth_scale": 0.1}"#;
        let c = CameraFile::from_json_str(bop, "scene_camera.json").unwrap();
        assert!(c.model(None).unwrap_err().to_string().contains("image size"));
        assert_eq!(c.model(Some((640, 480))).unwrap().size, ImageSize::new(640, 480).unwrap());
        let sized = r#"{"K": [500, 0, 320, 0, 500, 240, 0, 0, 1], "width": 640, "height": 480}"#;
        let c = CameraFile::from_json_str(sized, "c.json").unwrap();
        let e = c.model(Some((320, 240))).unwrap_err().to_string();
        assert!(e.contains("640x480") && e.contains("320x240"), "{e}");
    }

    #[test]
    fn a_depth_bias_is_read_and_a_bad_one_named() {
        let text = r#"{"K": [500, 0, 320, 0, 500, 240, 0, 0, 1], "depth_unit_m": 0.001,
            "depth_bias": {"cols": 2, "rows": 1, "width": 640, "height": 480, "metres": [0.001, -0.002]}}"#;
        let camera = CameraFile::from_json_str(text, "cam.json").unwrap();
        let bias = camera.depth_bias.unwrap();
        assert_eq!((bias.cols, bias.rows), (2, 1));
        assert!((bias.at(639.0, 0.0) + 0.002).abs() < 1e-12);
        let short = text.replace("[0.001, -0.002]", "[0.001]");
        let e = CameraFile::from_json_str(&short, "cam.json").unwrap_err().to_string();
        assert!(e.contains("cam.json") && e.contains("depth_bias") && e.contains("2 values"), "{e}");
        let missing = text.replace(r#""rows": 1, "#, "");
        let e = CameraFile::from_json_str(&missing, "cam.json").unwrap_err().to_string();
        assert!(e.contains("depth_bias") && e.contains("rows"), "{e}");
    }
}
