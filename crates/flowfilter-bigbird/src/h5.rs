//! Typed, validated reads of HDF5 datasets (`hdf5-reader`), with errors naming file and key.

use crate::Result;
use crate::error::BigBirdError;
use flowfilter_geometry::{Pose, rigid_from_matrix};
use hdf5_reader::{Datatype, Hdf5File};
use nalgebra::{Matrix3, Matrix4, Vector3};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// An open HDF5 file with the names of its root datasets.
pub(crate) struct H5 {
    path: PathBuf,
    file: Hdf5File,
    names: BTreeSet<String>,
}

fn hdf5_error(path: &Path, e: impl std::fmt::Display) -> BigBirdError {
    BigBirdError::Hdf5 { path: path.to_path_buf(), message: e.to_string() }
}

impl H5 {
    /// Open a file; a missing file is [`BigBirdError::NotFound`], anything undecodable
    /// [`BigBirdError::Hdf5`].
    pub fn open(path: &Path) -> Result<Self> {
        if !path.is_file() {
            return Err(BigBirdError::NotFound { path: path.to_path_buf() });
        }
        let bytes = std::fs::read(path).map_err(|source| BigBirdError::Io { path: path.to_path_buf(), source })?;
        let file = Hdf5File::from_vec(bytes).map_err(|e| hdf5_error(path, e))?;
        let root = file.root_group().map_err(|e| hdf5_error(path, e))?;
        let (_, datasets) = root.member_names().map_err(|e| hdf5_error(path, e))?;
        Ok(Self { path: path.to_path_buf(), file, names: datasets.into_iter().collect() })
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Whether a root dataset exists.
    pub fn has(&self, key: &str) -> bool {
        self.names.contains(key)
    }

    fn dataset(&self, key: &str) -> Result<hdf5_reader::Dataset> {
        if !self.has(key) {
            return Err(BigBirdError::MissingDataset { path: self.path.clone(), key: key.to_string() });
        }
        self.file.dataset(key).map_err(|e| hdf5_error(&self.path, e))
    }

    fn shape_error(&self, key: &str, expected: &str, found: &[u64]) -> BigBirdError {
        BigBirdError::Shape {
            path: self.path.clone(),
            key: key.into(),
            expected: expected.into(),
            found: found.to_vec(),
        }
    }

    fn dtype_error(&self, key: &str, expected: &str, found: &Datatype) -> BigBirdError {
        BigBirdError::Dtype {
            path: self.path.clone(),
            key: key.into(),
            expected: expected.into(),
            found: describe(found),
        }
    }

    /// Read a floating-point dataset of exactly `len` elements whose shape is `len` with any
    /// number of unit dimensions (e.g. `[5]`, `[1, 5]`, `[5, 1]`; `[]` or `[1]` for a scalar),
    /// or, with `matrix = Some((r, c))`, exactly `[r, c]`. Values must be finite.
    fn read_floats(&self, key: &str, len: usize, matrix: Option<(u64, u64)>) -> Result<Vec<f64>> {
        let ds = self.dataset(key)?;
        let shape = ds.shape().to_vec();
        let ok = match matrix {
            Some((r, c)) => shape == [r, c],
            None => shape.iter().product::<u64>() == len as u64 && shape.iter().filter(|&&d| d != 1).count() <= 1,
        };
        if !ok {
            let expected = match matrix {
                Some((r, c)) => format!("[{r}, {c}]"),
                None if len == 1 => "a scalar ([] or [1])".to_string(),
                None => format!("[{len}] (or with unit dimensions)"),
            };
            return Err(self.shape_error(key, &expected, &shape));
        }
        let values: Vec<f64> = match ds.dtype() {
            Datatype::FloatingPoint { size: 8, .. } => {
                let mut v = vec![0.0f64; len];
                ds.read_into(&mut v).map_err(|e| hdf5_error(&self.path, e))?;
                v
            }
            Datatype::FloatingPoint { size: 4, .. } => {
                let mut v = vec![0.0f32; len];
                ds.read_into(&mut v).map_err(|e| hdf5_error(&self.path, e))?;
                v.into_iter().map(f64::from).collect()
            }
            other => return Err(self.dtype_error(key, "float64 (or float32)", other)),
        };
        if let Some(index) = values.iter().position(|v| !v.is_finite()) {
            return Err(BigBirdError::NonFinite { path: self.path.clone(), key: key.into(), index });
        }
        Ok(values)
    }

    /// A scalar.
    pub fn scalar(&self, key: &str) -> Result<f64> {
        Ok(self.read_floats(key, 1, None)?[0])
    }

    /// A vector of `N` floats.
    pub fn vector<const N: usize>(&self, key: &str) -> Result<[f64; N]> {
        let v = self.read_floats(key, N, None)?;
        Ok(std::array::from_fn(|i| v[i]))
    }

    /// A 3-vector.
    pub fn vector3(&self, key: &str) -> Result<Vector3<f64>> {
        let [x, y, z] = self.vector::<3>(key)?;
        Ok(Vector3::new(x, y, z))
    }

    /// A 3x3 matrix (row-major in the file, as numpy writes it).
    pub fn matrix3(&self, key: &str) -> Result<Matrix3<f64>> {
        let v = self.read_floats(key, 9, Some((3, 3)))?;
        Ok(Matrix3::from_row_slice(&v))
    }

    /// A 4x4 matrix validated as a rigid transform.
    pub fn pose(&self, key: &str) -> Result<Pose> {
        let v = self.read_floats(key, 16, Some((4, 4)))?;
        let m = Matrix4::from_row_slice(&v);
        rigid_from_matrix(&m).map_err(|source| BigBirdError::NotRigid {
            path: self.path.clone(),
            key: key.into(),
            source,
        })
    }

    /// A 2-D uint16 image `(height, width, row-major data)`.
    pub fn image_u16(&self, key: &str) -> Result<(usize, usize, Vec<u16>)> {
        let ds = self.dataset(key)?;
        let shape = ds.shape().to_vec();
        if shape.len() != 2 || shape.contains(&0) {
            return Err(self.shape_error(key, "2-D [rows, cols] (BigBIRD: [480, 640])", &shape));
        }
        match ds.dtype() {
            Datatype::FixedPoint { size: 2, signed: false, .. } => {}
            other => return Err(self.dtype_error(key, "uint16", other)),
        }
        let (rows, cols) = (shape[0] as usize, shape[1] as usize);
        let mut data = vec![0u16; rows * cols];
        ds.read_into(&mut data).map_err(|e| hdf5_error(&self.path, e))?;
        Ok((rows, cols, data))
    }
}

/// A short name of an HDF5 element type, e.g. `float32` or `int16`.
fn describe(dtype: &Datatype) -> String {
    match dtype {
        Datatype::FixedPoint { size, signed, .. } => format!("{}int{}", if *signed { "" } else { "u" }, size * 8),
        Datatype::FloatingPoint { size, .. } => format!("float{}", size * 8),
        other => format!("{other:?}").split([' ', '{', '(']).next().unwrap_or("unknown").to_string(),
    }
}
