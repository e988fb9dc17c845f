//! Files written whole or not at all, the one way the workspace writes its result files (CSV, JSON,
//! TOML, ONNX, checkpoint pointers): a reader, or a crash half-way, never sees a half-written file.
//!
//! [`write_atomic`] writes a temporary file beside the destination and renames it over the
//! destination (the `atomic-write-file` crate). Around that it settles what the destination path
//! names:
//! * nothing yet: a new file is created;
//! * a regular file: it is replaced, keeping its permissions;
//! * a symbolic link: it is followed and its target replaced (the link stays a link, and the
//!   target keeps its permissions);
//! * a folder, a device node, a FIFO or a socket: refused with an error naming the path, because
//!   renaming a regular file over it would silently swap a device or a pipe for a plain file.
//!
//! [`check_destination`] applies the same rules before a command starts its work, so that a
//! destination that will be refused is refused at once, not after an hour of computation.
//!
//! An interrupted write can leave its temporary file behind; [`is_temporary_of`] recognises
//! those names so a command can remove them when it starts again. Only the command that writes a
//! folder may do so: [`lock`] keeps a second command out of a folder while the first one runs.

#![warn(missing_docs)]

use std::fs::FileType;
use std::io::{self, Write};
use std::os::unix::fs::FileTypeExt;
use std::path::{Path, PathBuf};

pub mod lock;

/// The file that writing `path` replaces, for comparing with other paths: its canonical path when
/// it exists (symbolic links followed, as a write follows them), else its folder's canonical path
/// joined with its file name; `None` when not even its folder exists.
pub fn resolved(path: &Path) -> Option<PathBuf> {
    if let Ok(path) = path.canonicalize() {
        return Some(path);
    }
    let folder = match path.parent() {
        Some(folder) if !folder.as_os_str().is_empty() => folder,
        _ => Path::new("."),
    };
    Some(folder.canonicalize().ok()?.join(path.file_name()?))
}

/// The first of the files `names` a command writes into `folder` that is one of its `inputs`
/// (path, what it is to the command), as (the output's path, the input's path, what it is);
/// `None` when none is (or the folder does not exist yet: nothing in it is an input).
pub fn output_over_input<'a>(
    folder: &Path,
    names: &[&str],
    inputs: &[(&'a Path, &'a str)],
) -> Option<(PathBuf, &'a Path, &'a str)> {
    for name in names {
        let output = folder.join(name);
        let Some(target) = resolved(&output) else {
            continue;
        };
        for &(input, what) in inputs {
            if resolved(input).is_some_and(|input| input == target) {
                return Some((output, input, what));
            }
        }
    }
    None
}

/// Longest chain of symbolic links followed before giving up (Linux's own limit).
const MAX_SYMLINKS: usize = 40;

/// Length of the random suffix `atomic-write-file` appends to a temporary file's name.
const TEMPORARY_SUFFIX_LEN: usize = 6;

/// Writes `bytes` to `path` atomically: a temporary file in the destination's folder, renamed over
/// the destination. Symbolic links are followed; a destination that is not a regular file is
/// refused (see the crate documentation). Errors of the file system come back unchanged, so the
/// caller names `path` in its own words.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let destination = regular_file_destination(path)?;
    let mut file = atomic_write_file::AtomicWriteFile::open(&destination)?;
    file.write_all(bytes)?;
    file.commit()
}

/// Checks, without writing anything, that [`write_atomic`] can write `path`: it names a file (not
/// `..` or a root), what it names (through symbolic links) is nothing yet or a regular file, and
/// the folder it goes into exists. The errors name `path` and what was expected.
pub fn check_destination(path: &Path) -> io::Result<()> {
    if path.file_name().is_none() {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("{}: expected the path of a file", path.display()),
        ));
    }
    let destination = regular_file_destination(path)?;
    let folder = match destination.parent() {
        Some(folder) if !folder.as_os_str().is_empty() => folder,
        _ => Path::new("."),
    };
    match std::fs::metadata(folder) {
        Ok(metadata) if metadata.is_dir() => Ok(()),
        Ok(_) => Err(io::Error::new(
            io::ErrorKind::NotADirectory,
            format!("{}: {} is not a folder", path.display(), folder.display()),
        )),
        Err(e) if e.kind() == io::ErrorKind::NotFound => Err(io::Error::new(
            io::ErrorKind::NotFound,
            format!(
                "{}: the folder {} does not exist",
                path.display(),
                folder.display()
            ),
        )),
        Err(e) => Err(io::Error::new(
            e.kind(),
            format!("{}: {}: {e}", path.display(), folder.display()),
        )),
    }
}

/// Whether `name` is a temporary file that [`write_atomic`] makes while writing a file called
/// `file`: `.`, the file name, `.` and six letters or digits.
pub fn is_temporary_of(name: &str, file: &str) -> bool {
    name.strip_prefix('.')
        .and_then(|rest| rest.strip_prefix(file))
        .and_then(|rest| rest.strip_prefix('.'))
        .is_some_and(|tail| {
            tail.len() == TEMPORARY_SUFFIX_LEN && tail.bytes().all(|b| b.is_ascii_alphanumeric())
        })
}

/// The path [`write_atomic`] replaces for `path`: `path` itself unless it is a symbolic link, then
/// the end of the link chain. Errors when that is a folder, a device node, a FIFO or a socket.
///
/// A path whose type cannot be read (a missing folder, no permission) is returned as it is: the
/// write then fails with the file system's own error.
fn regular_file_destination(path: &Path) -> io::Result<PathBuf> {
    let mut destination = path.to_path_buf();
    for _ in 0..MAX_SYMLINKS {
        let Ok(metadata) = std::fs::symlink_metadata(&destination) else {
            return Ok(destination);
        };
        let file_type = metadata.file_type();
        if file_type.is_symlink() {
            let link = std::fs::read_link(&destination)?;
            // A relative link is relative to the folder holding it; `join` keeps an absolute one.
            destination = match destination.parent() {
                Some(folder) => folder.join(link),
                None => link,
            };
        } else if file_type.is_file() {
            return Ok(destination);
        } else {
            return Err(not_a_regular_file(path, &destination, file_type));
        }
    }
    Err(io::Error::other(format!(
        "{}: more than {MAX_SYMLINKS} symbolic links in a row",
        path.display()
    )))
}

/// The refusal to replace `destination` (reached from `path`), which is of `file_type`.
fn not_a_regular_file(path: &Path, destination: &Path, file_type: FileType) -> io::Error {
    let (kind, what) = if file_type.is_dir() {
        (io::ErrorKind::IsADirectory, "a folder")
    } else if file_type.is_char_device() {
        (io::ErrorKind::InvalidInput, "a character device")
    } else if file_type.is_block_device() {
        (io::ErrorKind::InvalidInput, "a block device")
    } else if file_type.is_fifo() {
        (io::ErrorKind::InvalidInput, "a FIFO (named pipe)")
    } else if file_type.is_socket() {
        (io::ErrorKind::InvalidInput, "a socket")
    } else {
        (io::ErrorKind::InvalidInput, "not a regular file")
    };
    let found = if destination == path {
        format!("{} is {what}", path.display())
    } else {
        format!(
            "{} links to {}, which is {what}",
            path.display(),
            destination.display()
        )
    };
    io::Error::new(
        kind,
        format!("{found}; only a regular file is replaced by a new version"),
    )
}

#[cfg(test)]
mod tests {
    use std::os::unix::fs::{symlink, PermissionsExt};
    use std::process::Command;

    use super::*;

    /// The names in `dir`, sorted.
    fn names(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|entry| entry.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }

    fn mode(path: &Path) -> u32 {
        std::fs::metadata(path).unwrap().permissions().mode() & 0o7777
    }

    #[test]
    fn creates_and_replaces_whole_files_leaving_nothing_else() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("summary.json");
        write_atomic(&path, b"first, longer content").unwrap();
        write_atomic(&path, b"second").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"second");
        assert_eq!(names(dir.path()), ["summary.json"]);
    }

    #[test]
    fn a_missing_folder_gives_the_file_systems_own_error() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("no-such-folder").join("metrics.csv");
        let err = write_atomic(&missing, b"x").unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::NotFound, "{err}");
        assert!(!missing.exists());
    }

    #[test]
    fn an_existing_files_permissions_are_kept() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("best.toml");
        std::fs::write(&path, "old").unwrap();
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o640)).unwrap();
        write_atomic(&path, b"new").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"new");
        assert_eq!(mode(&path), 0o640);
    }

    #[test]
    fn a_symlink_is_written_through_and_kept() {
        let dir = tempfile::tempdir().unwrap();
        let store = dir.path().join("store");
        std::fs::create_dir(&store).unwrap();
        let target = store.join("policy.onnx");
        std::fs::write(&target, "old").unwrap();
        std::fs::set_permissions(&target, std::fs::Permissions::from_mode(0o604)).unwrap();
        // A relative link, resolved from the folder holding it, then a second link in a chain.
        let link = dir.path().join("latest.onnx");
        symlink("store/policy.onnx", &link).unwrap();
        let chained = dir.path().join("current.onnx");
        symlink(&link, &chained).unwrap();

        write_atomic(&chained, b"new").unwrap();
        assert_eq!(std::fs::read(&target).unwrap(), b"new");
        assert_eq!(mode(&target), 0o604);
        for path in [&link, &chained] {
            assert!(std::fs::symlink_metadata(path)
                .unwrap()
                .file_type()
                .is_symlink());
        }
        assert_eq!(names(&store), ["policy.onnx"]);
    }

    #[test]
    fn a_dangling_symlink_creates_its_target() {
        let dir = tempfile::tempdir().unwrap();
        let link = dir.path().join("metrics.csv");
        symlink("written-here.csv", &link).unwrap();
        write_atomic(&link, b"a,b\n").unwrap();
        assert_eq!(
            std::fs::read(dir.path().join("written-here.csv")).unwrap(),
            b"a,b\n"
        );
        assert!(std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
    }

    #[test]
    fn a_symlink_loop_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a"), dir.path().join("b"));
        symlink(&b, &a).unwrap();
        symlink(&a, &b).unwrap();
        let err = write_atomic(&a, b"x").unwrap_err();
        assert!(err.to_string().contains("symbolic links"), "{err}");
    }

    /// Asserts that writing `path` is refused with an error naming `path` and `what`, and that
    /// nothing was created beside it.
    fn assert_refused(path: &Path, what: &str) {
        let before = names(path.parent().unwrap());
        let err = write_atomic(path, b"x").unwrap_err();
        let message = err.to_string();
        assert!(message.contains(&path.display().to_string()), "{message}");
        assert!(message.contains(what), "{message}");
        assert_eq!(names(path.parent().unwrap()), before);
    }

    #[test]
    fn a_folder_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let folder = dir.path().join("summary.json");
        std::fs::create_dir(&folder).unwrap();
        assert_refused(&folder, "is a folder");
        assert_eq!(
            write_atomic(&folder, b"x").unwrap_err().kind(),
            io::ErrorKind::IsADirectory
        );
        assert!(folder.is_dir());
    }

    #[test]
    fn a_fifo_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("progress.csv");
        let made = Command::new("mkfifo").arg(&fifo).status().unwrap();
        assert!(made.success());
        assert_refused(&fifo, "is a FIFO");
        assert!(std::fs::symlink_metadata(&fifo)
            .unwrap()
            .file_type()
            .is_fifo());
    }

    #[test]
    fn a_socket_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let socket = dir.path().join("latest");
        let _listener = std::os::unix::net::UnixListener::bind(&socket).unwrap();
        assert_refused(&socket, "is a socket");
    }

    #[test]
    fn a_device_node_is_refused_also_through_a_symlink() {
        // Reading the type of the system's null device is harmless; it must be refused before
        // anything is written.
        let null = Path::new("/dev/null");
        let err = regular_file_destination(null).unwrap_err();
        assert!(
            err.to_string().contains("/dev/null is a character device"),
            "{err}"
        );
        let dir = tempfile::tempdir().unwrap();
        let link = dir.path().join("metrics.csv");
        symlink(null, &link).unwrap();
        let err = write_atomic(&link, b"x").unwrap_err();
        assert!(
            err.to_string()
                .contains("metrics.csv links to /dev/null, which is a character device"),
            "{err}"
        );
        assert!(std::fs::symlink_metadata(null)
            .unwrap()
            .file_type()
            .is_char_device());
        // A device node of its own where the system allows making one (as root).
        let node = dir.path().join("object_sim.csv");
        let made = Command::new("mknod")
            .arg(&node)
            .args(["c", "1", "3"])
            .status()
            .is_ok_and(|status| status.success());
        if made {
            assert_refused(&node, "is a character device");
        }
    }

    #[test]
    fn destinations_are_checked_before_writing() {
        let dir = tempfile::tempdir().unwrap();
        let new = dir.path().join("calibrated.toml");
        check_destination(&new).unwrap();
        std::fs::write(&new, "x").unwrap();
        check_destination(&new).unwrap();
        let link = dir.path().join("link.toml");
        symlink("calibrated.toml", &link).unwrap();
        check_destination(&link).unwrap();

        let missing = dir.path().join("nodir/x.toml");
        let err = check_destination(&missing).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::NotFound);
        assert!(err.to_string().contains("nodir does not exist"), "{err}");
        let under_a_file = new.join("x.toml");
        let err = check_destination(&under_a_file).unwrap_err();
        assert!(err.to_string().contains("is not a folder"), "{err}");
        let err = check_destination(Path::new("/dev/null")).unwrap_err();
        assert!(
            err.to_string().contains("/dev/null is a character device"),
            "{err}"
        );
        let err = check_destination(dir.path()).unwrap_err();
        assert!(err.to_string().contains("is a folder"), "{err}");
        let err = check_destination(&dir.path().join("..")).unwrap_err();
        assert!(
            err.to_string().contains("expected the path of a file"),
            "{err}"
        );
        assert_eq!(names(dir.path()), ["calibrated.toml", "link.toml"]);
    }

    #[test]
    fn temporary_names_are_recognised() {
        assert!(is_temporary_of(".summary.json.AbC123", "summary.json"));
        assert!(is_temporary_of(".latest.x0Y9z8", "latest"));
        for other in [
            "summary.json",
            ".summary.json.AbC12",
            ".summary.json.AbC1234",
            ".summary.json.AbC-23",
            "summary.json.AbC123",
            ".other.json.AbC123",
        ] {
            assert!(!is_temporary_of(other, "summary.json"), "{other}");
        }
    }

    #[test]
    fn temporary_names_match_the_files_left_by_an_unfinished_write() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("manifest.toml");
        let mut file = atomic_write_file::AtomicWriteFile::open(&path).unwrap();
        file.write_all(b"x").unwrap();
        let temporary: Vec<String> = names(dir.path());
        assert_eq!(temporary.len(), 1);
        assert!(
            is_temporary_of(&temporary[0], "manifest.toml"),
            "{temporary:?}"
        );
        drop(file);
    }
}
