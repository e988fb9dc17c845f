//! Ctrl-C (SIGINT), SIGTERM and SIGHUP. Outside a [`Cooperation`] a signal ends the process at once
//! (exit code 130), as if there were no handler: nothing is being written then. Inside one (the
//! long commands hold one while they work and write), the first signal only asks the command to
//! stop: it looks at [`requested`] between two writes, returns [`Interrupted`], and its
//! temporary files are removed as their owners are dropped, so it leaves no half-written output.
//! A second signal ends the process at once; the temporary files it leaves are never mistaken for
//! output, and the next run of the command into the same folder removes them. Ending at once still
//! removes the folder locks the command holds ([`rlpkg_files::lock::release_all`]), which their
//! destructors would otherwise have removed.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// The exit code of a command stopped by a signal (128 + SIGINT, as a shell reports it).
pub const EXIT_CODE: i32 = 130;

static REQUESTED: AtomicBool = AtomicBool::new(false);
static COOPERATING: AtomicUsize = AtomicUsize::new(0);

/// A command stopped because the user asked it to.
#[derive(Debug, thiserror::Error)]
#[error("interrupted")]
pub struct Interrupted;

/// Installs the handler (once, at start-up). When the signals cannot be caught (their disposition
/// was set to "ignore" by `nohup` and the like), they keep their disposition.
pub fn install() {
    let _ = ctrlc::set_handler(|| {
        if COOPERATING.load(Ordering::SeqCst) == 0 || REQUESTED.swap(true, Ordering::SeqCst) {
            rlpkg_files::lock::release_all();
            std::process::exit(EXIT_CODE);
        }
        eprintln!("\nstopping at the next safe point (send the signal again to stop at once)");
    });
}

/// While it lives, a signal asks the command to stop instead of ending the process.
pub struct Cooperation(());

impl Cooperation {
    /// Starts cooperating.
    pub fn start() -> Self {
        COOPERATING.fetch_add(1, Ordering::SeqCst);
        Cooperation(())
    }
}

impl Drop for Cooperation {
    fn drop(&mut self) {
        COOPERATING.fetch_sub(1, Ordering::SeqCst);
    }
}

/// Whether a signal asked the command to stop.
pub fn requested() -> bool {
    REQUESTED.load(Ordering::SeqCst)
}

/// A replay's observer that stops the rollout once a signal asked the command to stop.
pub struct Interruptible;

impl rlpkg_replay::Observer for Interruptible {
    fn stop(&mut self) -> bool {
        requested()
    }
}

/// `Err(Interrupted)` once a signal asked the command to stop.
pub fn check() -> anyhow::Result<()> {
    if requested() {
        Err(Interrupted.into())
    } else {
        Ok(())
    }
}

/// `err`, marked as [`Interrupted`] when a signal asked the command to stop (the error is then
/// how the command stopped, e.g. "the rollout was stopped").
pub fn explain(err: anyhow::Error) -> anyhow::Error {
    if requested() && !err.chain().any(|cause| cause.is::<Interrupted>()) {
        err.context(Interrupted)
    } else {
        err
    }
}
