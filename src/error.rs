//! Exit-code policy: bad user input (a file, a key, a value) exits with code 2, a command stopped by
//! Ctrl-C or SIGTERM with 130, anything else with 1.

use std::fmt;

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

/// The process exit code for an error returned by a command: 130 when a signal stopped it, 2 for
/// bad input, 1 otherwise.
pub fn exit_code(err: &anyhow::Error) -> i32 {
    if err
        .chain()
        .any(|cause| cause.is::<crate::interrupt::Interrupted>())
    {
        crate::interrupt::EXIT_CODE
    } else if err.chain().any(|cause| cause.is::<InputError>()) {
        2
    } else {
        1
    }
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
}
