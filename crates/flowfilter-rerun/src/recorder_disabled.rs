//! [`Recorder`] in a build without the `rerun` feature: the same interface, and
//! [`Recorder::create`] says how to get one that records.

use crate::error::RecordError;
use crate::scene::PairScene;
use std::convert::Infallible;
use std::path::Path;

/// A Rerun recording being written to a `.rrd` file (this build cannot create one: see
/// [`crate::CAN_RECORD`]).
pub struct Recorder {
    never: Infallible,
}

impl Recorder {
    /// Always [`RecordError::NotBuilt`] in this build.
    ///
    /// # Errors
    /// [`RecordError::NotBuilt`].
    pub fn create(path: &Path, _application: &'static str) -> Result<Self, RecordError> {
        Err(RecordError::NotBuilt { path: path.to_path_buf() })
    }

    /// Log one pair (never reached: no recorder exists in this build).
    ///
    /// # Errors
    /// None.
    pub fn log_pair(&self, _step: i64, _scene: &PairScene) -> Result<(), RecordError> {
        match self.never {}
    }

    /// Flush and close the file (never reached).
    ///
    /// # Errors
    /// None.
    pub fn finish(self) -> Result<(), RecordError> {
        match self.never {}
    }
}
