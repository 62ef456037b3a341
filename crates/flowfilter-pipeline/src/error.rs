//! Errors of the pipeline, naming the stage, file or key at fault.

use std::path::PathBuf;
use thiserror::Error;

/// Why the pipeline could not produce an estimate.
#[derive(Debug, Error)]
pub enum PipelineError {
    /// A configuration file cannot be read, is not TOML, has an unknown key or a bad value.
    #[error("{}: {message}", path.display())]
    Config {
        /// The file (or `<string>` for text given directly).
        path: PathBuf,
        /// What is wrong, with the key and line when known.
        message: String,
    },
    /// The depth stage rejected a frame.
    #[error("depth stage ({frame}): {source}")]
    Depth {
        /// Which frame.
        frame: String,
        /// The cause.
        #[source]
        source: flowfilter_depth::DepthError,
    },
    /// A frame's data are implausible: depth outside any sensor's range, no usable point.
    #[error("frame {frame}: {message}")]
    Frame {
        /// The frame's label.
        frame: String,
        /// What is wrong and what to check.
        message: String,
    },
    /// The flow stage failed in a way that is not a recoverable degradation.
    #[error("flow stage: {0}")]
    Flow(#[from] flowfilter_flow::FlowError),
    /// The registration backend failed.
    #[error("registration: {0}")]
    Registration(#[from] flowfilter_registration::RegistrationError),
    /// An input file (image, depth, mask) cannot be used.
    #[error("{}: {message}", path.display())]
    Input {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
    /// The camera file does not fit the frame.
    #[error("camera: {0}")]
    Camera(#[from] flowfilter_camera::CameraFileError),
    /// A dataset frame could not be loaded.
    #[error("dataset: {0}")]
    Dataset(#[from] flowfilter_bigbird::BigBirdError),
}

/// [`PipelineError::Input`] naming `path`.
pub(crate) fn input_error(path: &std::path::Path, message: impl Into<String>) -> PipelineError {
    PipelineError::Input { path: path.to_path_buf(), message: message.into() }
}
