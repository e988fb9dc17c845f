//! One command at a time in a folder: a lock file `<folder>/.lock` that holds the process id of
//! the command writing into the folder.
//!
//! [`FolderLock::acquire`] creates the lock file only if it does not exist (`O_EXCL`), so of two
//! commands started on the same folder exactly one holds it; the other gets
//! [`LockError::Held`], naming the folder and the holder's process id. A lock whose process no
//! longer runs (killed, or stopped by a crash of the machine) is stale: it is taken over, and
//! [`FolderLock::taken_over`] says from whom, so the command can say so; so is an empty one (its
//! holder stopped between creating it and writing its id). A lock file that holds anything else
//! was not written by this module, so nothing says who holds the folder: it is refused
//! ([`LockError::Foreign`]) and left for the user to remove.
//!
//! The lock file is removed when the [`FolderLock`] is dropped: on normal return, on an error,
//! and while unwinding from a panic. An exit that skips destructors (`std::process::exit` from a
//! signal handler) calls [`release_all`] first.

use std::fmt;
use std::fs::OpenOptions;
use std::io::{self, Write};
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::Duration;

/// Name of the lock file inside a locked folder.
pub const LOCK_FILE: &str = ".lock";

/// How often a lock that disappears or goes stale while being taken is tried again before giving
/// up (only many commands racing for one folder get that far).
const ATTEMPTS: usize = 8;

/// How long an empty lock file is given to receive its process id: the holder creates the file,
/// then writes its id, and a reader may come in between.
const EMPTY_GRACE: Duration = Duration::from_millis(500);

/// A held lock on a folder; dropping it removes the lock file (see the module documentation).
#[derive(Debug)]
pub struct FolderLock {
    id: u64,
    file: PathBuf,
    taken_over: Option<Stale>,
}

/// A stale lock that [`FolderLock::acquire`] took over.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Stale {
    /// It named this process, which no longer runs.
    Ended(u32),
    /// It was empty: its holder stopped before writing its id.
    Empty,
}

impl fmt::Display for Stale {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Stale::Ended(pid) => write!(f, "process {pid}, which no longer runs"),
            Stale::Empty => write!(f, "no process (it was empty)"),
        }
    }
}

/// Why a folder could not be locked.
#[derive(Debug)]
pub enum LockError {
    /// Another running process holds the folder.
    Held {
        /// The locked folder.
        folder: PathBuf,
        /// The process id the lock file holds.
        pid: u32,
    },
    /// The lock file holds something other than a process id: not written by this module.
    Foreign {
        /// The lock file.
        file: PathBuf,
        /// What it holds (trimmed).
        text: String,
    },
    /// The file system refused (a missing or read-only folder, a full disk).
    Io {
        /// The folder or file concerned.
        path: PathBuf,
        /// What could not be done, e.g. "cannot create the folder".
        action: &'static str,
        /// What the file system said.
        source: io::Error,
    },
}

impl fmt::Display for LockError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LockError::Held { folder, pid } => write!(
                f,
                "{}: in use by process {pid} (its lock file {}); wait until that process ends, \
                 or stop it, then try again",
                folder.display(),
                folder.join(LOCK_FILE).display()
            ),
            LockError::Foreign { file, text } => write!(
                f,
                "{}: a lock file that holds {text:?}, not a process id, so whoever holds the \
                 folder is unknown; if no command is writing into the folder, remove the file, \
                 then try again",
                file.display()
            ),
            LockError::Io {
                path,
                action,
                source,
            } => write!(f, "{}: {action}: {source}", path.display()),
        }
    }
}

impl std::error::Error for LockError {}

impl LockError {
    fn io(path: &Path, action: &'static str, source: io::Error) -> Self {
        LockError::Io {
            path: path.to_path_buf(),
            action,
            source,
        }
    }
}

/// What a held lock removes on release: its file (when it is still the one this process
/// created) and the folders [`FolderLock::create`] made, innermost first, while they are empty.
#[derive(Debug)]
struct Held {
    id: u64,
    file: PathBuf,
    inode: (u64, u64),
    created: Vec<PathBuf>,
}

/// The locks this process holds, for [`release_all`].
static HELD: Mutex<Vec<Held>> = Mutex::new(Vec::new());
static NEXT_ID: AtomicU64 = AtomicU64::new(0);

fn held() -> std::sync::MutexGuard<'static, Vec<Held>> {
    // A panic elsewhere while holding the list leaves it usable: each entry is complete.
    HELD.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

impl FolderLock {
    /// Locks the existing folder `folder`.
    pub fn acquire(folder: &Path) -> Result<FolderLock, LockError> {
        lock(folder, Vec::new())
    }

    /// Creates `folder` (and the folders above it) where missing, and locks it. On release the
    /// folders this call made are removed again when they are empty, so a command that fails
    /// before writing anything leaves no folder behind.
    pub fn create(folder: &Path) -> Result<FolderLock, LockError> {
        let mut created = Vec::new();
        let mut missing = Some(folder);
        while let Some(dir) = missing.filter(|dir| !dir.as_os_str().is_empty() && !dir.exists()) {
            created.push(dir.to_path_buf());
            missing = dir.parent();
        }
        // On failure the folders made so far go again.
        std::fs::create_dir_all(folder)
            .map_err(|e| LockError::io(folder, "cannot create the folder", e))
            .and_then(|()| lock(folder, created.clone()))
            .inspect_err(|_| remove_empty(&created))
    }

    /// The stale lock this lock replaced, if any.
    pub fn taken_over(&self) -> Option<&Stale> {
        self.taken_over.as_ref()
    }

    /// The lock file.
    pub fn file(&self) -> &Path {
        &self.file
    }
}

impl Drop for FolderLock {
    fn drop(&mut self) {
        let mine = {
            let mut list = held();
            list.iter()
                .position(|h| h.id == self.id)
                .map(|at| list.remove(at))
        };
        if let Some(held) = mine {
            release(&held);
        }
    }
}

/// Removes every lock this process holds (and the empty folders they created), for an exit that
/// skips destructors. Best effort: the next command takes over what is left as stale.
pub fn release_all() {
    for held in held().drain(..) {
        release(&held);
    }
}

/// Removes the folders in `dirs`, innermost first, stopping at the first that is not empty (or
/// cannot be removed). One that does not exist (never made, or removed already) is passed over.
fn remove_empty(dirs: &[PathBuf]) {
    for dir in dirs {
        match std::fs::remove_dir(dir) {
            Ok(()) => {}
            Err(_) if !dir.exists() => {}
            Err(_) => break,
        }
    }
}

fn release(held: &Held) {
    // A lock file that is no longer the one this process made belongs to whoever replaced it.
    if inode(&held.file).is_some_and(|inode| inode == held.inode) {
        let _ = std::fs::remove_file(&held.file);
    }
    remove_empty(&held.created);
}

fn inode(path: &Path) -> Option<(u64, u64)> {
    let metadata = std::fs::symlink_metadata(path).ok()?;
    Some((metadata.dev(), metadata.ino()))
}

/// Takes the lock of `folder`; `created` lists the folders made for it, innermost first.
fn lock(folder: &Path, created: Vec<PathBuf>) -> Result<FolderLock, LockError> {
    let file = folder.join(LOCK_FILE);
    let mut taken_over = None;
    for _ in 0..ATTEMPTS {
        match OpenOptions::new().write(true).create_new(true).open(&file) {
            Ok(mut opened) => {
                let written =
                    writeln!(opened, "{}", std::process::id()).and_then(|()| opened.metadata());
                let metadata = match written {
                    Ok(metadata) => metadata,
                    Err(e) => {
                        let _ = std::fs::remove_file(&file);
                        return Err(LockError::io(&file, "cannot write the lock file", e));
                    }
                };
                let id = NEXT_ID.fetch_add(1, Ordering::SeqCst);
                held().push(Held {
                    id,
                    file: file.clone(),
                    inode: (metadata.dev(), metadata.ino()),
                    created,
                });
                return Ok(FolderLock {
                    id,
                    file,
                    taken_over,
                });
            }
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {
                let Some(holder) = read_holder(&file)? else {
                    continue; // released in the meantime
                };
                match holder.pid {
                    Some(pid) if process_runs(pid) => {
                        return Err(LockError::Held {
                            folder: folder.to_path_buf(),
                            pid,
                        })
                    }
                    Some(pid) => taken_over = Some(Stale::Ended(pid)),
                    None if holder.text.is_empty() => taken_over = Some(Stale::Empty),
                    None => {
                        return Err(LockError::Foreign {
                            file,
                            text: holder.text,
                        })
                    }
                }
                set_aside(&file, &holder)?;
            }
            Err(e) => return Err(LockError::io(folder, "cannot take the lock", e)),
        }
    }
    Err(LockError::io(
        &file,
        "cannot take the lock",
        io::Error::other(format!(
            "the lock changed hands {ATTEMPTS} times while it was being taken"
        )),
    ))
}

/// An existing lock file: what it holds and which file it is.
#[derive(Debug)]
struct Holder {
    text: String,
    pid: Option<u32>,
    inode: (u64, u64),
}

/// Reads the lock file `file`; `None` when it no longer exists. An empty file is read again for a
/// while: its holder may be about to write its id.
fn read_holder(file: &Path) -> Result<Option<Holder>, LockError> {
    let started = std::time::Instant::now();
    loop {
        let metadata = match std::fs::symlink_metadata(file) {
            Ok(metadata) => metadata,
            Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(LockError::io(file, "cannot read the lock file", e)),
        };
        let bytes = match std::fs::read(file) {
            Ok(bytes) => bytes,
            Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(LockError::io(file, "cannot read the lock file", e)),
        };
        if bytes.is_empty() && started.elapsed() < EMPTY_GRACE {
            std::thread::sleep(Duration::from_millis(20));
            continue;
        }
        let text = String::from_utf8_lossy(&bytes).trim().to_string();
        return Ok(Some(Holder {
            pid: parse_pid(&text),
            text,
            inode: (metadata.dev(), metadata.ino()),
        }));
    }
}

/// A process id as a lock file holds it: a positive decimal number that fits a `pid_t`.
fn parse_pid(text: &str) -> Option<u32> {
    text.parse::<u32>()
        .ok()
        .filter(|&pid| pid > 0 && i32::try_from(pid).is_ok())
}

/// Removes the stale lock file `file`, read as `stale`. The file is first moved aside, which only
/// one of several processes taking over the same stale lock manages; when what was moved is not
/// the stale file (another process took it over and locked anew in between: another file, or
/// another text), that new lock is put back. The caller then tries to lock again.
fn set_aside(file: &Path, stale: &Holder) -> Result<(), LockError> {
    let aside = file.with_file_name(format!("{LOCK_FILE}.stale.{}", std::process::id()));
    match std::fs::rename(file, &aside) {
        Ok(()) => {}
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(LockError::io(file, "cannot remove the stale lock file", e)),
    }
    // A file system may give a new file the number of one just removed: the text tells too.
    let moved = std::fs::read(&aside).ok();
    let same = inode(&aside) == Some(stale.inode)
        && moved.is_some_and(|bytes| String::from_utf8_lossy(&bytes).trim() == stale.text);
    if !same {
        // `hard_link` does not replace: a lock made in the meantime stays.
        let _ = std::fs::hard_link(&aside, file);
    }
    std::fs::remove_file(&aside)
        .map_err(|e| LockError::io(&aside, "cannot remove the stale lock file", e))
}

/// Whether process `pid` runs. A zombie (ended, not yet waited for by its parent) does not.
///
/// On Linux `/proc/<pid>/stat` tells, zombies included. Where it cannot (no `/proc`, or a
/// `/proc` that hides other users' processes), `kill(pid, 0)` does: it signals nothing, and
/// succeeds, or fails for lack of permission, exactly when the process exists.
fn process_runs(pid: u32) -> bool {
    #[cfg(target_os = "linux")]
    if let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        return !is_zombie(&stat);
    }
    let Ok(pid) = libc::pid_t::try_from(pid) else {
        return false;
    };
    // SAFETY: `kill` with signal 0 reads nothing of this process's memory and sends no signal.
    let sent = unsafe { libc::kill(pid, 0) };
    sent == 0 || io::Error::last_os_error().raw_os_error() == Some(libc::EPERM)
}

/// Whether a `/proc/<pid>/stat` line is a zombie's or a dead process's: the state follows the
/// command name, which is in parentheses and may itself hold `)` and spaces.
#[cfg(target_os = "linux")]
fn is_zombie(stat: &str) -> bool {
    stat.rsplit_once(')')
        .and_then(|(_, rest)| rest.trim_start().chars().next())
        .is_some_and(|state| state == 'Z' || state == 'X')
}

#[cfg(test)]
mod tests {
    use std::process::{Command, Stdio};

    use super::*;

    /// The tests share this process's list of held locks ([`release_all`] empties it): one at a
    /// time.
    static SERIAL: Mutex<()> = Mutex::new(());

    fn serial() -> std::sync::MutexGuard<'static, ()> {
        SERIAL
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    fn names(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|entry| entry.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }

    /// The id of a process that has ended and been waited for.
    fn ended_pid() -> u32 {
        let mut child = Command::new("true").spawn().unwrap();
        let pid = child.id();
        child.wait().unwrap();
        pid
    }

    #[test]
    fn a_lock_holds_the_pid_and_is_removed_on_drop() {
        let _serial = serial();
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("evaluations.csv"), "x").unwrap();
        let lock = FolderLock::acquire(dir.path()).unwrap();
        assert_eq!(lock.file(), dir.path().join(LOCK_FILE));
        assert_eq!(lock.taken_over(), None);
        let text = std::fs::read_to_string(dir.path().join(LOCK_FILE)).unwrap();
        assert_eq!(text, format!("{}\n", std::process::id()));
        drop(lock);
        assert_eq!(names(dir.path()), ["evaluations.csv"]);
    }

    #[test]
    fn a_held_folder_is_refused_naming_the_folder_and_the_pid() {
        let _serial = serial();
        let dir = tempfile::tempdir().unwrap();
        let _first = FolderLock::acquire(dir.path()).unwrap();
        let err = FolderLock::acquire(dir.path()).unwrap_err();
        let pid = std::process::id();
        assert!(
            matches!(&err, LockError::Held { folder, pid: p } if folder == dir.path() && *p == pid),
            "{err:?}"
        );
        let message = err.to_string();
        assert!(
            message.contains(&dir.path().display().to_string()),
            "{message}"
        );
        assert!(message.contains(&format!("process {pid}")), "{message}");
        // The refused attempt left the holder's file alone.
        let text = std::fs::read_to_string(dir.path().join(LOCK_FILE)).unwrap();
        assert_eq!(text.trim(), pid.to_string());
    }

    #[test]
    fn a_lock_of_another_running_process_is_refused() {
        let _serial = serial();
        let dir = tempfile::tempdir().unwrap();
        let mut sleeper = Command::new("sleep")
            .arg("30")
            .stdout(Stdio::null())
            .spawn()
            .unwrap();
        std::fs::write(dir.path().join(LOCK_FILE), format!("{}\n", sleeper.id())).unwrap();
        let err = FolderLock::acquire(dir.path()).unwrap_err();
        assert!(
            matches!(err, LockError::Held { pid, .. } if pid == sleeper.id()),
            "{err:?}"
        );
        sleeper.kill().unwrap();
        sleeper.wait().unwrap();
        // Once it has ended, its lock is stale.
        let lock = FolderLock::acquire(dir.path()).unwrap();
        assert_eq!(lock.taken_over(), Some(&Stale::Ended(sleeper.id())));
    }

    #[test]
    fn a_stale_lock_is_taken_over() {
        let _serial = serial();
        let dir = tempfile::tempdir().unwrap();
        let ended = ended_pid();
        std::fs::write(dir.path().join(LOCK_FILE), format!("{ended}\n")).unwrap();
        let lock = FolderLock::acquire(dir.path()).unwrap();
        assert_eq!(lock.taken_over(), Some(&Stale::Ended(ended)));
        assert!(lock
            .taken_over()
            .unwrap()
            .to_string()
            .contains("no longer runs"));
        let text = std::fs::read_to_string(dir.path().join(LOCK_FILE)).unwrap();
        assert_eq!(text.trim(), std::process::id().to_string());
        drop(lock);
        assert!(names(dir.path()).is_empty(), "{:?}", names(dir.path()));
    }

    #[test]
    fn an_empty_lock_is_taken_over_and_a_foreign_one_refused() {
        let _serial = serial();
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join(LOCK_FILE), "").unwrap();
        let lock = FolderLock::acquire(dir.path()).unwrap();
        assert_eq!(lock.taken_over(), Some(&Stale::Empty));
        drop(lock);
        for text in ["not a pid", "0", "-3", "4294967295"] {
            let dir = tempfile::tempdir().unwrap();
            let file = dir.path().join(LOCK_FILE);
            std::fs::write(&file, text).unwrap();
            let err = FolderLock::acquire(dir.path()).unwrap_err();
            assert!(matches!(err, LockError::Foreign { .. }), "{text}: {err}");
            assert!(err.to_string().contains(".lock"), "{err}");
            // The file is left as it was.
            assert_eq!(std::fs::read_to_string(&file).unwrap(), text);
        }
    }

    #[test]
    fn a_lock_made_anew_while_a_stale_one_is_set_aside_stays() {
        let _serial = serial();
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join(LOCK_FILE);
        std::fs::write(&file, format!("{}\n", ended_pid())).unwrap();
        let stale = read_holder(&file).unwrap().unwrap();
        // Another process takes the stale lock over first and locks anew.
        std::fs::remove_file(&file).unwrap();
        std::fs::write(&file, format!("{}\n", std::process::id())).unwrap();
        set_aside(&file, &stale).unwrap();
        let text = std::fs::read_to_string(&file).unwrap();
        assert_eq!(text.trim(), std::process::id().to_string());
        assert_eq!(names(dir.path()), [LOCK_FILE]);
        // The stale file itself is removed.
        let stale = read_holder(&file).unwrap().unwrap();
        set_aside(&file, &stale).unwrap();
        assert!(names(dir.path()).is_empty());
    }

    #[test]
    fn create_makes_the_folders_and_removes_them_when_left_empty() {
        let _serial = serial();
        let dir = tempfile::tempdir().unwrap();
        let run = dir.path().join("runs/tiny");
        let lock = FolderLock::create(&run).unwrap();
        assert_eq!(names(&run), [LOCK_FILE]);
        drop(lock);
        assert!(names(dir.path()).is_empty(), "{:?}", names(dir.path()));

        // A folder that received a file is kept, and so is the folder above it.
        let lock = FolderLock::create(&run).unwrap();
        std::fs::write(run.join("config.toml"), "x").unwrap();
        drop(lock);
        assert_eq!(names(&run), ["config.toml"]);

        // An existing folder is never removed.
        std::fs::remove_file(run.join("config.toml")).unwrap();
        drop(FolderLock::create(&run).unwrap());
        assert!(run.is_dir());
    }

    #[test]
    fn folders_made_before_a_failure_are_removed() {
        let _serial = serial();
        let dir = tempfile::tempdir().unwrap();
        // A file stands in the way: nothing is made, nothing else removed.
        let lock = FolderLock::create(&dir.path().join("runs/tiny")).unwrap();
        std::fs::write(dir.path().join("runs/tiny/config.toml"), "x").unwrap();
        let err = FolderLock::create(&dir.path().join("runs/tiny/config.toml/x/y")).unwrap_err();
        assert!(
            err.to_string().contains("cannot create the folder"),
            "{err}"
        );
        drop(lock);
        assert_eq!(names(&dir.path().join("runs/tiny")), ["config.toml"]);
        // `a` and `a/b` were made, `a/b/c` not (the failure came in between): both go.
        std::fs::create_dir_all(dir.path().join("a/b")).unwrap();
        let made = ["a/b/c", "a/b", "a"].map(|dir_name| dir.path().join(dir_name));
        remove_empty(&made);
        assert_eq!(names(dir.path()), ["runs"]);
    }

    #[test]
    fn a_missing_folder_is_an_error_naming_it() {
        let _serial = serial();
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("no-such-run");
        let err = FolderLock::acquire(&missing).unwrap_err();
        let message = err.to_string();
        assert!(message.contains("no-such-run"), "{message}");
        assert!(
            matches!(&err, LockError::Io { source, .. } if source.kind() == io::ErrorKind::NotFound)
        );
        assert!(!missing.exists());
    }

    #[test]
    fn release_all_removes_the_held_locks_and_their_folders() {
        let _serial = serial();
        let dir = tempfile::tempdir().unwrap();
        let kept = FolderLock::acquire(dir.path()).unwrap();
        let made = dir.path().join("out");
        let created = FolderLock::create(&made).unwrap();
        release_all();
        assert!(names(dir.path()).is_empty(), "{:?}", names(dir.path()));
        // Dropping them afterwards removes nothing more, and nothing of another lock.
        let other = FolderLock::acquire(dir.path()).unwrap();
        drop(kept);
        drop(created);
        assert_eq!(names(dir.path()), [LOCK_FILE]);
        drop(other);
    }

    #[test]
    fn this_process_runs_an_ended_one_does_not() {
        assert!(process_runs(std::process::id()));
        assert!(!process_runs(ended_pid()));
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn a_zombie_does_not_run() {
        let mut child = Command::new("true").spawn().unwrap();
        let pid = child.id();
        // Not waited for yet: a zombie once it has exited.
        let deadline = std::time::Instant::now() + Duration::from_secs(10);
        while process_runs(pid) {
            assert!(std::time::Instant::now() < deadline, "{pid} still runs");
            std::thread::sleep(Duration::from_millis(10));
        }
        assert!(Path::new(&format!("/proc/{pid}")).exists());
        child.wait().unwrap();
        assert!(is_zombie("12 (a) b) Z 1 2"));
        assert!(!is_zombie("12 (sleep) S 1 2"));
    }
}
