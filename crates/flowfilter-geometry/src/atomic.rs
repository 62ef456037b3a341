//! Files written whole or not at all, and output paths checked before the work.
//!
//! A writer writes a temporary file beside the destination (same directory, so the rename
//! stays on one file system; same extension, so writers that choose the format by it still
//! do), then renames it over the destination: a reader, or a process killed half-way, never
//! sees a partial file.
//!
//! ```
//! use flowfilter_geometry::atomic::write_atomic;
//! let dir = std::env::temp_dir().join(format!("ff-atomic-doc-{}", std::process::id()));
//! std::fs::create_dir_all(&dir)?;
//! write_atomic(&dir.join("a.txt"), b"whole")?;
//! assert_eq!(std::fs::read(dir.join("a.txt"))?, b"whole");
//! # std::fs::remove_dir_all(&dir)?;
//! # Ok::<(), std::io::Error>(())
//! ```

use std::io;
use std::path::{Path, PathBuf};

/// The temporary file [`write_atomic_with`] writes before renaming it to `path`:
/// `.NAME.PID.partial.EXT` in the same directory.
pub fn partial_path(path: &Path) -> PathBuf {
    let stem = path.file_stem().map_or_else(|| "out".into(), |s| s.to_string_lossy().into_owned());
    let ext = path.extension().map(|e| format!(".{}", e.to_string_lossy())).unwrap_or_default();
    path.with_file_name(format!(".{stem}.{}.partial{ext}", std::process::id()))
}

/// Write `path` through `write` (which writes the temporary path it is given), then rename it
/// into place; on failure the temporary file is removed and `path` is left as it was.
///
/// # Errors
/// `write`'s error, or the rename's as `E::from(io::Error)`.
pub fn write_atomic_with<E: From<io::Error>>(path: &Path, write: impl FnOnce(&Path) -> Result<(), E>) -> Result<(), E> {
    let partial = partial_path(path);
    let result = write(&partial).and_then(|()| std::fs::rename(&partial, path).map_err(E::from));
    if result.is_err() {
        let _ = std::fs::remove_file(&partial);
    }
    result
}

/// Write `bytes` to `path` atomically.
///
/// # Errors
/// The I/O error of the write or the rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> io::Result<()> {
    write_atomic_with(path, |p| std::fs::write(p, bytes))
}

/// Check, before any work, that a file can be written at `path`: its directory exists and takes
/// a new file, and `path` is not a directory. Nothing is left behind.
///
/// # Errors
/// An I/O error whose message names the path and the reason.
pub fn check_writable_file(path: &Path) -> io::Result<()> {
    if path.is_dir() {
        return Err(io::Error::new(io::ErrorKind::IsADirectory, format!("{}: is a directory", path.display())));
    }
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if !dir.is_dir() {
        return Err(io::Error::new(io::ErrorKind::NotFound, format!("{}: no such directory", dir.display())));
    }
    probe(dir)
}

/// Check, before any work, that files can be written into the directory `dir` (created with
/// its parents when missing).
///
/// # Errors
/// An I/O error whose message names the directory and the reason.
pub fn check_writable_dir(dir: &Path) -> io::Result<()> {
    std::fs::create_dir_all(dir)
        .map_err(|e| io::Error::new(e.kind(), format!("{}: cannot create: {e}", dir.display())))?;
    probe(dir)
}

/// Create and remove a probe file in `dir`.
fn probe(dir: &Path) -> io::Result<()> {
    let p = dir.join(format!(".flowfilter-probe-{}", std::process::id()));
    std::fs::write(&p, b"")
        .map_err(|e| io::Error::new(e.kind(), format!("{}: cannot write there: {e}", dir.display())))?;
    std::fs::remove_file(&p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failed_write_leaves_the_destination_and_no_partial_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.json");
        write_atomic(&path, b"old").unwrap();
        let r: io::Result<()> = write_atomic_with(&path, |p| {
            std::fs::write(p, b"half")?;
            Err(io::Error::other("killed"))
        });
        assert!(r.is_err());
        assert_eq!(std::fs::read(&path).unwrap(), b"old");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        assert!(partial_path(&path).to_string_lossy().ends_with(".partial.json"));
    }

    #[test]
    fn output_paths_are_checked() {
        let dir = tempfile::tempdir().unwrap();
        assert!(check_writable_file(&dir.path().join("x.png")).is_ok());
        assert!(check_writable_file(dir.path()).unwrap_err().to_string().contains("is a directory"));
        assert!(
            check_writable_file(&dir.path().join("no/x.png")).unwrap_err().to_string().contains("no such directory")
        );
        assert!(check_writable_dir(&dir.path().join("a/b")).is_ok());
        assert!(check_writable_file(Path::new("/proc/x.png")).is_err());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }
}
