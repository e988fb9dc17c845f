//! Output files of the commands, written whole or not at all through [`rlpkg_files`]: a reader
//! (or a crash) never sees a half-written CSV or JSON. The one place the commands write their
//! result files through, and lock the folders they write ([`lock_folder`]).

use std::path::Path;

use anyhow::Context;
use rlpkg_files::lock::FolderLock;

use crate::error::input_error;

/// Writes `bytes` to `path` atomically (see [`rlpkg_files::write_atomic`]); the error names the
/// file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    rlpkg_files::write_atomic(path, bytes)
        .with_context(|| format!("cannot write {}", path.display()))
}

/// Locks `folder` for this command ([`rlpkg_files::lock`]), creating it first when `create` (the
/// folders made are removed again on release when left empty). A folder another running command
/// holds, or one the file system refuses, is the user's (exit 2). Taking over a stale lock is
/// said on standard error.
pub fn lock_folder(folder: &Path, create: bool) -> anyhow::Result<FolderLock> {
    let lock = if create {
        FolderLock::create(folder)
    } else {
        FolderLock::acquire(folder)
    }
    .map_err(input_error)?;
    if let Some(stale) = lock.taken_over() {
        eprintln!(
            "took over the stale lock {} of {stale}",
            lock.file().display()
        );
    }
    Ok(lock)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_error_names_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("no-such-folder").join("metrics.csv");
        let err = write_atomic(&missing, b"x").unwrap_err();
        assert!(format!("{err}").contains("no-such-folder"), "{err}");
        assert!(!missing.exists());
    }
}
