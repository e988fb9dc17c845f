//! Errors returned by the simulator crate.

use std::path::PathBuf;

/// Everything that can go wrong building or driving a simulation.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// A config file could not be read.
    #[error("cannot read config file {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A config file is not valid TOML for the expected schema (unknown key, wrong type...).
    #[error("invalid config {file}: {message}")]
    Parse {
        /// The file (or preset name).
        file: String,
        /// The TOML parser's message, which names the key and line.
        message: String,
    },
    /// A config value is outside its allowed range.
    #[error("invalid config {file}: key `{key}` = {value}: expected {expected}")]
    Range {
        /// The file (or preset name).
        file: String,
        /// Dotted key, e.g. `params.k_tri_e`.
        key: String,
        /// The offending value as written.
        value: String,
        /// What was expected.
        expected: String,
    },
    /// An unknown preset name.
    #[error("unknown preset `{0}`: expected `reference` or `physical`")]
    UnknownPreset(String),
    /// An environment description is inconsistent with the model.
    #[error("environment {env}: {message}")]
    Env {
        /// Environment index.
        env: usize,
        /// What is wrong.
        message: String,
    },
    /// A placement cannot be derived from the given points.
    #[error("placement: {0}")]
    Placement(String),
    /// A tool trajectory is unusable.
    #[error("tool trajectory: {0}")]
    Trajectory(String),
}
