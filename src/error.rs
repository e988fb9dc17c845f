//! Exit-code policy, for every command: bad user input (a file, a key, a value) exits with code 2,
//! a command stopped by Ctrl-C or SIGTERM with 130, anything else with 1. The errors of the library
//! crates are sorted here ([`agent_error`], [`export_error`], [`run_error`]).

use std::fmt;
use std::path::Path;

use rlpkg_agents::export::ExportError;
use rlpkg_agents::AgentError;
use rlpkg_env::transport::RunError;

/// An error in what the user gave: a file that is missing or malformed, a key that is unknown, a
/// value out of range. The message must name the file, the key or line, and what was expected.
#[derive(Debug)]
pub struct InputError(pub String);

impl fmt::Display for InputError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for InputError {}

/// Wraps any displayable error as an [`InputError`] (exit code 2).
pub fn input_error(err: impl fmt::Display) -> anyhow::Error {
    anyhow::Error::new(InputError(err.to_string()))
}

/// An error of the learner (a configuration, a run folder or checkpoint, a size, the environment):
/// the user's (exit 2) when [`AgentError::is_input_error`] says so, a fault otherwise.
pub fn agent_error(err: AgentError) -> anyhow::Error {
    if err.is_input_error() {
        input_error(err)
    } else {
        err.into()
    }
}

/// An error of the ONNX exporter or runtime; `given` is the ONNX file the user gave to run
/// (`rlpkg eval --policy`), `None` for a file the command wrote. The user's (exit 2): a file that
/// cannot be read or written, is not an ONNX model, holds a weight that is not finite or lacks the
/// metadata `rlpkg export` writes; a given file that tract cannot run, or that does not fit the environment its metadata names (the
/// message then names the file). A fault otherwise (an inconsistent graph, a written file that
/// tract cannot run or that does not reproduce the policy).
pub fn export_error(err: ExportError, given: Option<&Path>) -> anyhow::Error {
    match (&err, given) {
        (
            ExportError::Io { .. }
            | ExportError::NotOnnx { .. }
            | ExportError::Metadata { .. }
            | ExportError::NonFinite { .. },
            _,
        )
        | (ExportError::Runtime { .. }, Some(_)) => input_error(err),
        (ExportError::Env(_) | ExportError::ObsShape { .. }, Some(path)) => {
            input_error(format!("{}: {err}", path.display()))
        }
        _ => err.into(),
    }
}

/// An error of an evaluation or an optimisation of the transport task: the user's (exit 2) for
/// bad input, [`crate::interrupt::Interrupted`] (exit 130) for a stop request, a fault otherwise.
pub fn run_error(err: RunError) -> anyhow::Error {
    match err {
        RunError::Input(message) => input_error(message),
        RunError::Stopped => crate::interrupt::Interrupted.into(),
        RunError::Env(e) => e.into(),
        RunError::Policy(e) => anyhow::Error::from_boxed(e),
    }
}

/// The process exit code for an error returned by a command: 130 when a signal stopped it, 2 for
/// bad input, 1 otherwise.
pub fn exit_code(err: &anyhow::Error) -> i32 {
    if holds::<crate::interrupt::Interrupted>(err) {
        crate::interrupt::EXIT_CODE
    } else if holds::<InputError>(err) {
        2
    } else {
        1
    }
}

/// Whether `err` holds an `E` anywhere: as a cause in its chain, or as the context anyhow wrapped
/// around a cause (`err.context(E)`: the chain then shows a wrapper type that is not `E`, which only
/// anyhow's downcast sees through).
fn holds<E>(err: &anyhow::Error) -> bool
where
    E: std::error::Error + Send + Sync + 'static,
{
    err.downcast_ref::<E>().is_some() || err.chain().any(|cause| cause.is::<E>())
}

/// An error while writing outputs: the user's (exit 2) when it comes from the file system (a
/// folder that is read-only or full), a fault otherwise.
pub fn output_error(err: anyhow::Error) -> anyhow::Error {
    let from_file_system = err.chain().any(|cause| {
        cause.is::<std::io::Error>()
            || matches!(
                cause.downcast_ref::<crate::render::RenderError>(),
                Some(crate::render::RenderError::Write { .. })
            )
    });
    if from_file_system {
        input_error(message(&err))
    } else {
        err
    }
}

/// The error and its causes joined by `: `, leaving out a cause whose text the message already
/// holds (errors that print their source, like `path: os error`, would otherwise repeat it).
pub fn message(err: &anyhow::Error) -> String {
    let mut message = String::new();
    for cause in err.chain() {
        let text = cause.to_string();
        if message.contains(&text) {
            continue;
        }
        if !message.is_empty() {
            message.push_str(": ");
        }
        message.push_str(&text);
    }
    message
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, thiserror::Error)]
    #[error("{path}: {source}")]
    struct PathError {
        path: String,
        source: std::io::Error,
    }

    #[test]
    fn os_errors_are_not_repeated_and_input_errors_exit_2() {
        let io = std::io::Error::from_raw_os_error(28);
        let err = anyhow::Error::new(PathError {
            path: "runs/x/events".into(),
            source: io,
        })
        .context("training runs/x");
        let text = message(&err);
        assert_eq!(text.matches("os error 28").count(), 1, "{text}");
        assert!(
            text.starts_with("training runs/x: runs/x/events: "),
            "{text}"
        );
        assert_eq!(exit_code(&err), 1);
        assert_eq!(exit_code(&input_error("bad").context("while reading")), 2);
    }

    #[test]
    fn an_interruption_given_as_context_exits_130() {
        let stopped = anyhow::anyhow!("the rollout was stopped").context("objective");
        let err = stopped.context(crate::interrupt::Interrupted);
        assert_eq!(exit_code(&err), crate::interrupt::EXIT_CODE);
        let wrapped = err.context("calibrating");
        assert_eq!(exit_code(&wrapped), crate::interrupt::EXIT_CODE);
        assert_eq!(
            exit_code(&anyhow::anyhow!("x").context(InputError("y".into()))),
            2
        );
    }
}
