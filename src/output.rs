//! Standard output and error that a closed pipe or a full disk cannot crash.
//!
//! `std`'s `println!` panics when stdout cannot be written (`rlpkg eval ... | head`, `> /dev/full`),
//! which would end a command in the middle of its work: a training run that had finished its
//! updates would never be exported. Every command prints through the crate's `print!`/`println!`
//! and `eprint!`/`eprintln!` (defined in `main.rs`, over the standard macros' names), which write
//! here instead:
//!
//! * a write to stdout that fails is remembered (the first error) and later writes are dropped; the
//!   command goes on and finishes its work. At the end, [`stdout_error`] tells `main` what happened:
//!   a closed pipe (EPIPE) is the reader's choice and ends quietly, as in ripgrep and cargo; any other
//!   error (a full disk) is reported on stderr with exit code 2, naming standard output;
//! * a write to stderr that fails is dropped: there is nowhere left to report it.

use std::fmt;
use std::io::Write;
use std::sync::Mutex;

/// The first error writing stdout.
static STDOUT_ERROR: Mutex<Option<std::io::Error>> = Mutex::new(None);

/// Writes to stdout; see the module docs.
pub fn print(args: fmt::Arguments) {
    let mut failed = STDOUT_ERROR.lock().unwrap_or_else(|e| e.into_inner());
    if failed.is_some() {
        return;
    }
    if let Err(e) = std::io::stdout().lock().write_fmt(args) {
        *failed = Some(e);
    }
}

/// Writes to stderr; a failure is dropped.
pub fn eprint(args: fmt::Arguments) {
    let _ = std::io::stderr().lock().write_fmt(args);
}

/// Flushes stdout and returns the first error writing it that is not a closed pipe.
pub fn stdout_error() -> Option<std::io::Error> {
    let mut failed = STDOUT_ERROR.lock().unwrap_or_else(|e| e.into_inner());
    if failed.is_none() {
        if let Err(e) = std::io::stdout().lock().flush() {
            *failed = Some(e);
        }
    }
    failed
        .take()
        .filter(|e| e.kind() != std::io::ErrorKind::BrokenPipe)
}
