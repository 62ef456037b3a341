//! `capture-status.txt`: how far a writer got. [`crate::ObjectWriter`] users that write a whole
//! capture (the synthesiser) mark it incomplete before the first frame and complete after the
//! last, so that [`crate::inspect`] reports an interrupted capture instead of accepting its
//! frames. Real BigBIRD downloads have no such file, and are not affected.

use crate::error::BigBirdError;
use std::path::{Path, PathBuf};

/// The file's name in the object directory.
pub const CAPTURE_STATUS_FILE: &str = "capture-status.txt";

/// The first line of the file.
const HEADER: &str = "flowfilter capture v1";

/// What a capture-status file says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CaptureStatus {
    /// Whether the writer finished.
    pub complete: bool,
    /// Frames the capture holds (or will hold, while incomplete).
    pub frames: usize,
}

/// The file's path in `dir`.
pub fn capture_status_path(dir: &Path) -> PathBuf {
    dir.join(CAPTURE_STATUS_FILE)
}

impl CaptureStatus {
    /// The file's text.
    pub fn to_text(self) -> String {
        let status = if self.complete { "complete" } else { "incomplete" };
        format!("{HEADER}\nstatus = {status}\nframes = {}\n", self.frames)
    }

    /// Read `dir`'s status file: `None` when there is none.
    ///
    /// # Errors
    /// [`BigBirdError::Invalid`] for a file that cannot be read or parsed.
    pub fn read(dir: &Path) -> Result<Option<Self>, BigBirdError> {
        let path = capture_status_path(dir);
        if !path.exists() {
            return Ok(None);
        }
        let invalid = |message: String| BigBirdError::Invalid { path: path.clone(), message };
        let text = std::fs::read_to_string(&path).map_err(|e| invalid(format!("cannot read: {e}")))?;
        let mut lines = text.lines();
        if lines.next() != Some(HEADER) {
            return Err(invalid(format!("first line must be '{HEADER}'")));
        }
        let (mut complete, mut frames) = (None, None);
        for line in lines.filter(|l| !l.trim().is_empty()) {
            match line.split_once('=').map(|(k, v)| (k.trim(), v.trim())) {
                Some(("status", "complete")) => complete = Some(true),
                Some(("status", "incomplete")) => complete = Some(false),
                Some(("frames", n)) => frames = n.parse().ok(),
                _ => return Err(invalid(format!("unexpected line '{line}'"))),
            }
        }
        match (complete, frames) {
            (Some(complete), Some(frames)) => Ok(Some(Self { complete, frames })),
            _ => Err(invalid("needs 'status = complete|incomplete' and 'frames = N'".into())),
        }
    }
}
