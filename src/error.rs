//! Exit-code policy: bad user input (a file, a key, a value) exits with code 2, anything else with 1.

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

/// The process exit code for an error returned by a command.
pub fn exit_code(err: &anyhow::Error) -> i32 {
    if err.chain().any(|cause| cause.is::<InputError>()) {
        2
    } else {
        1
    }
}
