//! What stops an evaluation or an optimisation of the transport task: [`RunError`], and the
//! check of the caller's stop request ([`check`]).

use crate::EnvError;

/// What stops an evaluation or an optimisation of the transport task.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The user's input: a setting, a configuration, a recording or a file it names (the message
    /// names it and what was expected).
    #[error("{0}")]
    Input(String),
    /// The environment failed while running.
    #[error(transparent)]
    Env(#[from] EnvError),
    /// The caller's stop request was seen between two control steps.
    #[error("stopped on request")]
    Stopped,
    /// The policy could not choose actions.
    #[error(transparent)]
    Policy(Box<dyn std::error::Error + Send + Sync>),
}

impl RunError {
    /// `err` as the user's input error (its text kept).
    pub(crate) fn input(err: impl std::fmt::Display) -> Self {
        RunError::Input(err.to_string())
    }
}

/// `Err(RunError::Stopped)` once `stop` says so.
pub(crate) fn check(stop: &dyn Fn() -> bool) -> Result<(), RunError> {
    if stop() {
        Err(RunError::Stopped)
    } else {
        Ok(())
    }
}
