//! Output files of the commands, written whole or not at all through [`rlpkg_files`]: a reader
//! (or a crash) never sees a half-written CSV or JSON. The one place the commands write their
//! result files through, check their output paths before they start working, and lock the
//! folders they write ([`lock_folder`]).

use std::path::{Path, PathBuf};

use anyhow::Context;
use rlpkg_files::lock::FolderLock;

use crate::error::{input_error, output_error};

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

/// Checks, before any work, that the output file `path` (given as `option`, e.g.
/// `--write-params`) can be written: it names a file whose folder exists, and nothing but a
/// regular file (or nothing yet) is there. Exit 2 otherwise, nothing written.
pub fn check_output(option: &str, path: &Path) -> anyhow::Result<()> {
    rlpkg_files::check_destination(path).map_err(|err| input_error(format!("{option} {err}")))
}

pub use rlpkg_files::resolved;

/// An input of a command, which none of its outputs may be.
pub enum Input<'a> {
    /// A file, and what it is to the command (e.g. "the calibration config"); also one the
    /// command is yet to write and read back (a log of its output folder).
    File(&'a Path, &'a str),
    /// Every existing file inside a folder, and what the folder is (e.g. "the dataset").
    Folder(&'a Path, &'a str),
}

/// Refuses the output file `path` (given as `option`) when it is one of `inputs` once both are
/// canonicalised (see [`resolved`]): writing it would replace what the command reads.
pub fn check_not_input(option: &str, path: &Path, inputs: &[Input]) -> anyhow::Result<()> {
    let Some(target) = resolved(path) else {
        return Ok(()); // its folder does not exist: `check_output` refuses it
    };
    for input in inputs {
        match *input {
            Input::File(file, what) => {
                if resolved(file).is_some_and(|file| file == target) {
                    return Err(input_error(format!(
                        "{option} {}: is {}, {what}, which this command reads; expected \
                         another file",
                        path.display(),
                        file.display()
                    )));
                }
            }
            Input::Folder(folder, what) => {
                let inside = folder
                    .canonicalize()
                    .is_ok_and(|folder| target.starts_with(folder));
                if inside && target.exists() {
                    return Err(input_error(format!(
                        "{option} {}: is a file of {}, {what}, which this command reads; \
                         expected a file outside it",
                        path.display(),
                        folder.display()
                    )));
                }
            }
        }
    }
    Ok(())
}

/// A hidden folder inside a command's output folder that its final files are written into and
/// then moved into place together ([`Staging::place`]): a signal, a full disk or an error before
/// then leaves the output folder as it was (the staging folder is removed when dropped). One that
/// a command killed outright left behind is removed by the next ([`remove_staging_leftovers`]).
pub struct Staging {
    dir: tempfile::TempDir,
    out: PathBuf,
}

impl Staging {
    /// A new staging folder `<out>/<prefix>XXXXXX`; `out` must exist.
    pub fn new(out: &Path, prefix: &str) -> anyhow::Result<Self> {
        let dir = tempfile::Builder::new()
            .prefix(prefix)
            .tempdir_in(out)
            .map_err(|e| {
                output_error(
                    anyhow::Error::new(e)
                        .context(format!("{}: cannot stage the output files", out.display())),
                )
            })?;
        Ok(Self {
            dir,
            out: out.to_path_buf(),
        })
    }

    /// Where the output file `name` is written before it is moved into place.
    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }

    /// Moves the staged files `names` into the output folder in this order (the file that marks
    /// a complete output last); a name that was not staged is skipped. A symbolic link or a FIFO
    /// the user placed where an output goes is written through (or refused) as any output is.
    pub fn place(self, names: &[&str]) -> anyhow::Result<()> {
        for name in names {
            let (from, to) = (self.path(name), self.out.join(name));
            if !from.exists() {
                continue;
            }
            let moved = if std::fs::symlink_metadata(&to).is_ok_and(|m| !m.is_file()) {
                std::fs::read(&from)
                    .map_err(anyhow::Error::new)
                    .and_then(|bytes| write_atomic(&to, &bytes))
            } else {
                std::fs::rename(&from, &to).map_err(anyhow::Error::new)
            };
            moved.map_err(|e| {
                output_error(e.context(format!("{}: cannot move the output here", to.display())))
            })?;
        }
        Ok(())
    }
}

/// Removes the staging folders `<out>/<prefix>*` that a command killed outright left behind
/// (only the command holding the folder's lock may); returns what it removed.
pub fn remove_staging_leftovers(out: &Path, prefix: &str) -> anyhow::Result<Vec<PathBuf>> {
    let mut removed = Vec::new();
    let Ok(entries) = std::fs::read_dir(out) else {
        return Ok(removed);
    };
    for entry in entries.flatten() {
        let staged = entry.file_name().to_string_lossy().starts_with(prefix)
            && entry.file_type().is_ok_and(|t| t.is_dir());
        if staged {
            std::fs::remove_dir_all(entry.path()).map_err(|err| {
                input_error(format!(
                    "{}: cannot remove this leftover staging folder: {err}",
                    entry.path().display()
                ))
            })?;
            removed.push(entry.path());
        }
    }
    Ok(removed)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::exit_code;

    #[test]
    fn the_error_names_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("no-such-folder").join("metrics.csv");
        let err = write_atomic(&missing, b"x").unwrap_err();
        assert!(format!("{err}").contains("no-such-folder"), "{err}");
        assert!(!missing.exists());
    }

    #[test]
    fn outputs_are_checked_before_work() {
        let dir = tempfile::tempdir().unwrap();
        check_output("--write-params", &dir.path().join("x.toml")).unwrap();
        for (path, words) in [
            (dir.path().join("nodir/x.toml"), "nodir does not exist"),
            (
                PathBuf::from("/dev/null"),
                "/dev/null is a character device",
            ),
        ] {
            let err = check_output("--write-params", &path).unwrap_err();
            assert_eq!(exit_code(&err), 2);
            let message = err.to_string();
            assert!(message.starts_with("--write-params "), "{message}");
            assert!(message.contains(words), "{message}");
        }
    }

    #[test]
    fn staged_files_reach_the_folder_only_when_placed() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path();
        std::fs::write(out.join("a.toml"), "earlier").unwrap();
        // Dropped before it is placed: the folder is as it was.
        let staging = Staging::new(out, ".stage-").unwrap();
        std::fs::write(staging.path("a.toml"), "new").unwrap();
        drop(staging);
        assert_eq!(
            std::fs::read_to_string(out.join("a.toml")).unwrap(),
            "earlier"
        );
        assert_eq!(std::fs::read_dir(out).unwrap().count(), 1);
        // Placed: the staged files replace the folder's, a name not staged is skipped.
        let staging = Staging::new(out, ".stage-").unwrap();
        std::fs::write(staging.path("a.toml"), "new").unwrap();
        std::fs::write(staging.path("b.json"), "{}").unwrap();
        staging.place(&["a.toml", "missing.csv", "b.json"]).unwrap();
        assert_eq!(std::fs::read_to_string(out.join("a.toml")).unwrap(), "new");
        assert!(out.join("b.json").exists() && !out.join("missing.csv").exists());
        assert_eq!(std::fs::read_dir(out).unwrap().count(), 2);
        // What a killed command left behind goes; other hidden folders stay.
        std::fs::create_dir_all(out.join(".stage-Ab12/x")).unwrap();
        std::fs::create_dir(out.join(".other")).unwrap();
        let removed = remove_staging_leftovers(out, ".stage-").unwrap();
        assert_eq!(removed, vec![out.join(".stage-Ab12")]);
        assert!(out.join(".other").exists());
    }

    #[test]
    fn an_output_that_is_an_input_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let config = dir.path().join("c.toml");
        std::fs::write(&config, "x").unwrap();
        let data = dir.path().join("data");
        std::fs::create_dir_all(data.join("HHHHH")).unwrap();
        std::fs::write(data.join("HHHHH/meta.toml"), "x").unwrap();
        let inputs = [
            Input::File(&config, "the calibration config"),
            Input::Folder(&data, "the dataset"),
        ];
        // The same file reached another way, through `..` and through a symbolic link.
        let link = dir.path().join("link.toml");
        std::os::unix::fs::symlink(&config, &link).unwrap();
        for path in [
            config.clone(),
            data.join("HHHHH/../../c.toml"),
            link.clone(),
        ] {
            let err = check_not_input("--write-params", &path, &inputs).unwrap_err();
            assert_eq!(exit_code(&err), 2);
            assert!(err.to_string().contains("the calibration config"), "{err}");
        }
        let err =
            check_not_input("--write-params", &data.join("HHHHH/meta.toml"), &inputs).unwrap_err();
        assert!(err.to_string().contains("the dataset"), "{err}");
        // New files are not inputs, also inside the dataset's folder.
        for path in [dir.path().join("calibrated.toml"), data.join("new.toml")] {
            check_not_input("--write-params", &path, &inputs).unwrap();
        }
        assert_eq!(resolved(&dir.path().join("nodir/x.toml")), None);
    }
}
