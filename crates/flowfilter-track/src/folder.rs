//! [`FrameFolder`]: the frames of a folder of RGB-D files, in order.
//!
//! Two layouts are recognised, other files are ignored:
//! - `frame-NNNNNN.color.png|jpg` + `frame-NNNNNN.depth.png` (the shared RealSense sequences,
//!   7-Scenes);
//! - `NNNNNN-color.png|jpg` + `NNNNNN-depth.png` (YCB-Video).
//!
//! Or an image list ([`FrameFolder::from_list`]): a text file of `COLOR DEPTH` lines, or the TUM
//! RGB-D benchmark's associated lists (`T_COLOR COLOR T_DEPTH DEPTH`, as `associate.py` writes
//! them), paths relative to the list's folder.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One frame's files.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameEntry {
    /// The frame's number in its file name.
    pub number: u64,
    /// Colour image.
    pub color: PathBuf,
    /// Depth image (16-bit PNG).
    pub depth: PathBuf,
    /// The colour image's timestamp (seconds), when the input gives one (a TUM list).
    pub timestamp: Option<f64>,
}

impl FrameEntry {
    /// The frame's label in estimates and messages (`frame-000012`).
    pub fn label(&self) -> String {
        format!("frame-{:06}", self.number)
    }
}

/// Why a folder gives no frames.
#[derive(Debug, thiserror::Error)]
pub enum FolderError {
    /// The folder cannot be listed.
    #[error("{dir}: cannot list the folder: {source}")]
    Unreadable {
        /// The folder.
        dir: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A line of an image list is neither `COLOR DEPTH` nor `T_COLOR COLOR T_DEPTH DEPTH`.
    #[error("{file}:{line}: expected `COLOR DEPTH` or `T_COLOR COLOR T_DEPTH DEPTH` (TUM), found {found:?}")]
    ListLine {
        /// The list.
        file: PathBuf,
        /// The line's number (from 1).
        line: usize,
        /// The line.
        found: String,
    },
    /// No file matches a known layout.
    #[error(
        "{dir}: no RGB-D frames: expected frame-NNNNNN.color.png|jpg with frame-NNNNNN.depth.png, or \
         NNNNNN-color.png|jpg with NNNNNN-depth.png"
    )]
    Empty {
        /// The folder.
        dir: PathBuf,
    },
}

/// The frames of a folder, by number.
#[derive(Debug, Clone)]
pub struct FrameFolder {
    /// The folder.
    pub dir: PathBuf,
    /// The frames, by increasing number. A colour image without its depth image is a frame
    /// whose depth path does not exist (reading it reports the missing file).
    pub frames: Vec<FrameEntry>,
}

/// What a file name says: (number, is colour).
fn parse(name: &str) -> Option<(u64, bool)> {
    let digits = |s: &str| (!s.is_empty() && s.bytes().all(|b| b.is_ascii_digit())).then(|| s.parse().ok()).flatten();
    let (stem, ext) = name.rsplit_once('.')?;
    let ext = ext.to_ascii_lowercase();
    if let Some(rest) = stem.strip_prefix("frame-") {
        let (number, kind) = rest.split_once('.')?;
        return match (kind, ext.as_str()) {
            ("color", "png" | "jpg" | "jpeg") => Some((digits(number)?, true)),
            ("depth", "png") => Some((digits(number)?, false)),
            _ => None,
        };
    }
    let (number, kind) = stem.split_once('-')?;
    match (kind, ext.as_str()) {
        ("color", "png" | "jpg" | "jpeg") => Some((digits(number)?, true)),
        ("depth", "png") => Some((digits(number)?, false)),
        _ => None,
    }
}

impl FrameFolder {
    /// List the frames of `dir`.
    ///
    /// # Errors
    /// [`FolderError`] when the folder cannot be read or holds no frame.
    ///
    /// ```
    /// let dir = tempfile::tempdir()?;
    /// for f in ["frame-000001.color.png", "frame-000001.depth.png", "frame-000000.color.jpg", "notes.txt"] {
    ///     std::fs::write(dir.path().join(f), b"")?;
    /// }
    /// let folder = flowfilter_track::FrameFolder::open(dir.path())?;
    /// assert_eq!(folder.frames.iter().map(|f| f.number).collect::<Vec<_>>(), [0, 1]);
    /// assert!(!folder.frames[0].depth.exists()); // reading frame 0 will name the missing depth file
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn open(dir: &Path) -> Result<Self, FolderError> {
        let unreadable = |source| FolderError::Unreadable { dir: dir.to_path_buf(), source };
        let mut colour: BTreeMap<u64, PathBuf> = BTreeMap::new();
        let mut depth: BTreeMap<u64, PathBuf> = BTreeMap::new();
        let mut style_frame = false;
        for entry in std::fs::read_dir(dir).map_err(unreadable)? {
            let path = entry.map_err(unreadable)?.path();
            let Some(name) = path.file_name().and_then(|n| n.to_str()) else { continue };
            let Some((number, is_colour)) = parse(name) else { continue };
            style_frame |= name.starts_with("frame-");
            if is_colour {
                colour.entry(number).or_insert(path);
            } else {
                depth.insert(number, path);
            }
        }
        let depth_path = |n: u64| {
            depth.get(&n).cloned().unwrap_or_else(|| {
                dir.join(if style_frame { format!("frame-{n:06}.depth.png") } else { format!("{n:06}-depth.png") })
            })
        };
        let frames: Vec<FrameEntry> = colour
            .into_iter()
            .map(|(number, color)| FrameEntry { number, color, depth: depth_path(number), timestamp: None })
            .collect();
        if frames.is_empty() {
            return Err(FolderError::Empty { dir: dir.to_path_buf() });
        }
        Ok(Self { dir: dir.to_path_buf(), frames })
    }

    /// The frames of an image list: one frame per line, `COLOR DEPTH` or the TUM RGB-D
    /// benchmark's `T_COLOR COLOR T_DEPTH DEPTH` (the colour timestamp kept), paths relative to
    /// the list's folder; blank lines and `#` comments skipped. Frames are numbered by their
    /// order in the list, from 0.
    ///
    /// # Errors
    /// [`FolderError::Unreadable`] when the list cannot be read, [`FolderError::ListLine`] for a
    /// line of another shape, [`FolderError::Empty`] for a list without frames.
    ///
    /// ```
    /// let dir = tempfile::tempdir()?;
    /// let list = dir.path().join("associate.txt");
    /// std::fs::write(&list, "# TUM\n1305031102.175 rgb/a.png 1305031102.160 depth/a.png\n1305031102.211 rgb/b.png 1305031102.194 depth/b.png\n")?;
    /// let folder = flowfilter_track::FrameFolder::from_list(&list)?;
    /// assert_eq!(folder.frames.len(), 2);
    /// assert_eq!(folder.frames[1].color, dir.path().join("rgb/b.png"));
    /// assert_eq!(folder.frames[1].timestamp, Some(1305031102.211));
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn from_list(file: &Path) -> Result<Self, FolderError> {
        let text = std::fs::read_to_string(file)
            .map_err(|source| FolderError::Unreadable { dir: file.to_path_buf(), source })?;
        let dir = file.parent().unwrap_or(Path::new(".")).to_path_buf();
        let mut frames = vec![];
        for (i, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let bad = || FolderError::ListLine { file: file.to_path_buf(), line: i + 1, found: line.to_string() };
            let fields: Vec<&str> = line.split_whitespace().collect();
            let (color, depth, timestamp) = match fields[..] {
                [color, depth] => (color, depth, None),
                [t, color, _, depth] => {
                    (color, depth, Some(t.parse::<f64>().ok().filter(|t| t.is_finite()).ok_or_else(bad)?))
                }
                _ => return Err(bad()),
            };
            let number = frames.len() as u64;
            frames.push(FrameEntry { number, color: dir.join(color), depth: dir.join(depth), timestamp });
        }
        if frames.is_empty() {
            return Err(FolderError::Empty { dir: file.to_path_buf() });
        }
        Ok(Self { dir, frames })
    }

    /// [`FrameFolder::open`] for a folder, [`FrameFolder::from_list`] for a file.
    ///
    /// # Errors
    /// As those.
    pub fn open_any(path: &Path) -> Result<Self, FolderError> {
        if path.is_file() { Self::from_list(path) } else { Self::open(path) }
    }
}

#[cfg(test)]
mod tests {
    use super::parse;

    #[test]
    fn both_layouts_and_nothing_else() {
        assert_eq!(parse("frame-000012.color.png"), Some((12, true)));
        assert_eq!(parse("frame-000012.depth.png"), Some((12, false)));
        assert_eq!(parse("000003-color.jpg"), Some((3, true)));
        assert_eq!(parse("000003-depth.png"), Some((3, false)));
        for other in
            ["frame-000012.pose.txt", "000003-label.png", "000003-meta.mat", "camera.json", "frame-x.color.png"]
        {
            assert_eq!(parse(other), None, "{other}");
        }
    }
}
