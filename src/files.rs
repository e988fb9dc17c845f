//! Output files of the commands, written whole or not at all through [`rlpkg_files`]: a reader
//! (or a crash) never sees a half-written CSV or JSON. The one place the commands write their
//! result files through.

use std::path::Path;

use anyhow::Context;

/// Writes `bytes` to `path` atomically (see [`rlpkg_files::write_atomic`]); the error names the
/// file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    rlpkg_files::write_atomic(path, bytes)
        .with_context(|| format!("cannot write {}", path.display()))
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
