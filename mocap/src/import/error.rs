//! The import error: a take, config or robot file that cannot be read or converted.

use std::path::PathBuf;

use thiserror::Error;

use crate::dataset::DataError;
use crate::motive::MotiveError;

/// An import failure; the message names the file and what was expected.
#[derive(Debug, Error)]
pub enum ImportError {
    /// The take could not be read or parsed.
    #[error(transparent)]
    Motive(#[from] MotiveError),
    /// The config file could not be read, parsed, or holds a value out of range.
    #[error("{}: {message}", path.display())]
    Config {
        /// The config file.
        path: PathBuf,
        /// Key (and line) and what was expected.
        message: String,
    },
    /// A robot trajectory file could not be read or is malformed.
    #[error(transparent)]
    Robot(#[from] DataError),
    /// The take parsed but cannot be converted (a rigid body missing, too few markers, ...).
    #[error("{}: {message}", path.display())]
    Take {
        /// The take file.
        path: PathBuf,
        /// What is missing and what was expected.
        message: String,
    },
}
