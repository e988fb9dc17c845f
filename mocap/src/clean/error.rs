//! The cleaning error: parameters that cannot be used (a filter that cannot be designed).

use thiserror::Error;

/// Invalid cleaning parameters.
#[derive(Debug, Error, PartialEq)]
pub enum CleanError {
    /// A filter design that cannot be built.
    #[error("Butterworth filter: {0}")]
    Filter(String),
}
