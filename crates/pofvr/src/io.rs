//! Output files are written to a temp file beside the target and renamed into place, so a
//! failed or interrupted write never leaves a half-written file under the real name.

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

/// A file could not be written.
#[derive(Debug, thiserror::Error)]
#[error("cannot write {}: {err}", path.display())]
pub struct WriteError {
    /// The target path.
    pub path: PathBuf,
    /// The cause.
    #[source]
    pub err: std::io::Error,
}

/// Writes `path` atomically: `fill` writes into a temp file in the same directory, which
/// is synced and renamed over `path` only when `fill` succeeds.
///
/// # Errors
/// [`WriteError`] naming `path` when the directory is not writable, `fill` fails or the
/// rename fails; the temp file is removed in every case.
pub fn write_atomic(
    path: &Path,
    fill: impl FnOnce(&mut File) -> std::io::Result<()>,
) -> Result<(), WriteError> {
    let wrap = |err| WriteError {
        path: path.to_path_buf(),
        err,
    };
    write_atomic_with(path, |f| fill(f).map_err(wrap))
}

/// As [`write_atomic`], for a `fill` with its own error type and result (a writer that
/// also reads, say, and reports both kinds of failure): `fill`'s error is returned as it
/// is, and the temp file's own failures as [`WriteError`]s naming `path`.
///
/// # Errors
/// `fill`'s error, or a [`WriteError`] when the temp file cannot be made, synced or renamed;
/// the temp file is removed in every case.
pub fn write_atomic_with<T, E: From<WriteError>>(
    path: &Path,
    fill: impl FnOnce(&mut File) -> Result<T, E>,
) -> Result<T, E> {
    let wrap = |err| WriteError {
        path: path.to_path_buf(),
        err,
    };
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let mut tmp = tempfile::Builder::new()
        .prefix(".pofvr-")
        .suffix(".tmp")
        .tempfile_in(dir)
        .map_err(wrap)?;
    let value = fill(tmp.as_file_mut())?;
    tmp.as_file_mut().flush().map_err(wrap)?;
    tmp.as_file().sync_data().map_err(wrap)?;
    tmp.persist(path).map_err(|e| wrap(e.error))?;
    Ok(value)
}

/// Writes bytes atomically.
///
/// # Errors
/// As [`write_atomic`].
pub fn write_bytes_atomic(path: &Path, bytes: &[u8]) -> Result<(), WriteError> {
    write_atomic(path, |f| f.write_all(bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failed_fill_leaves_nothing_behind() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out.bin");
        let err = write_atomic(&target, |f| {
            f.write_all(b"half")?;
            Err(std::io::Error::other("boom"))
        })
        .unwrap_err();
        assert!(err.to_string().contains("out.bin") && err.to_string().contains("boom"));
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[test]
    fn unwritable_directory_names_the_path() {
        let err = write_bytes_atomic(Path::new("/nonexistent-dir/x/out.png"), b"x").unwrap_err();
        assert!(
            err.to_string().contains("/nonexistent-dir/x/out.png"),
            "{err}"
        );
    }
}
