//! [`RecordError`]: why a recording could not be written.

use std::path::PathBuf;

/// Why a recording could not be written.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// This build has no Rerun SDK (the `rerun` feature is off).
    #[error(
        "{path}: this build cannot write Rerun recordings; rebuild with the `rerun` feature \
         (cargo build --release -p flowfilter --features rerun)"
    )]
    NotBuilt {
        /// The file asked for.
        path: PathBuf,
    },
    /// The file could not be created.
    #[error("{path}: cannot create the Rerun recording: {message}")]
    Create {
        /// The file.
        path: PathBuf,
        /// Rerun's message.
        message: String,
    },
    /// An entity could not be logged.
    #[error("{path}: cannot log entity '{entity}': {message}")]
    Log {
        /// The file.
        path: PathBuf,
        /// The entity path.
        entity: String,
        /// Rerun's message.
        message: String,
    },
}
