//! Errors of scene loading and capture synthesis.

use std::path::PathBuf;

/// Why a capture cannot be synthesised.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    /// The OBJ file cannot be opened or parsed.
    #[error("{}: cannot read OBJ: {message}", path.display())]
    Obj {
        /// The OBJ file.
        path: PathBuf,
        /// What the parser reported.
        message: String,
    },
    /// A face of the OBJ has more than three vertices.
    #[error("{}: mesh '{mesh}' is not triangulated (face {face} has {arity} vertices); triangulate it first", path.display())]
    NotTriangulated {
        /// The OBJ file.
        path: PathBuf,
        /// The mesh (object) name inside the file.
        mesh: String,
        /// Index of the first non-triangular face.
        face: usize,
        /// Its number of vertices.
        arity: u32,
    },
    /// The mesh has no texture coordinates, no material, or its texture image is missing.
    #[error("{}: {message}", path.display())]
    Texture {
        /// The OBJ, MTL or image file concerned.
        path: PathBuf,
        /// What is missing or wrong.
        message: String,
    },
    /// The mesh has no usable triangles, or non-finite coordinates.
    #[error("{}: degenerate mesh: {message}", path.display())]
    DegenerateMesh {
        /// The mesh source.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// An unknown procedural object name.
    #[error("unknown procedural object '{name}' (available: {available})")]
    UnknownProcedural {
        /// Name asked for.
        name: String,
        /// Names available.
        available: String,
    },
    /// A malformed angle range.
    #[error("bad angle range '{text}': {message}")]
    BadAngles {
        /// The text given.
        text: String,
        /// What is wrong.
        message: String,
    },
    /// A noise profile cannot be read or is invalid.
    #[error("noise profile {source_name}: {message}")]
    NoiseProfile {
        /// Profile file or name.
        source_name: String,
        /// What is wrong.
        message: String,
    },
    /// A file of a synthesised dataset cannot be written.
    #[error("{}: cannot write: {message}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// The system's message.
        message: String,
    },
    /// A value of the options cannot make a dataset.
    #[error("{field}: {message}")]
    BadOption {
        /// The option.
        field: &'static str,
        /// What is wrong.
        message: String,
    },
    /// Writing the dataset failed.
    #[error(transparent)]
    Dataset(#[from] flowfilter_bigbird::BigBirdError),
}

/// [`SynthError::BadOption`] naming the first of `fields` (name, value) that is not positive and
/// finite.
pub(crate) fn positive_and_finite(fields: &[(&'static str, f64)]) -> Result<(), SynthError> {
    match fields.iter().find(|(_, v)| !(v.is_finite() && *v > 0.0)) {
        Some(&(field, v)) => {
            Err(SynthError::BadOption { field, message: format!("must be positive and finite, got {v}") })
        }
        None => Ok(()),
    }
}
