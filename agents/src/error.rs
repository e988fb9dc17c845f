//! Errors of the PPO trainer: configuration, files, environments and checkpoints.

use std::path::PathBuf;

/// Everything that can go wrong while configuring, training, saving or loading a policy.
#[derive(Debug, thiserror::Error)]
pub enum AgentError {
    /// The configuration file could not be parsed (syntax, unknown or missing key, wrong type).
    #[error("{path}: {message}")]
    ConfigParse {
        /// The configuration file.
        path: PathBuf,
        /// The parser's message (names the key and line).
        message: String,
    },
    /// A configuration value is outside its allowed range.
    #[error("{path}: key `{key}` = {value}: expected {expected}")]
    ConfigValue {
        /// The configuration file.
        path: PathBuf,
        /// Dotted key, e.g. `ppo.gamma`.
        key: String,
        /// The value found.
        value: String,
        /// The allowed range or values.
        expected: String,
    },
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file or folder involved.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A run folder or checkpoint is missing a part or holds inconsistent data.
    #[error("{path}: {reason}")]
    Checkpoint {
        /// The file or folder involved.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A size from the input would need more memory than the machine has.
    #[error(
        "{what}: would need about {needed} of memory, more than the {available} of this machine"
    )]
    Memory {
        /// The option or key and its value, e.g. `--episodes 1000000000`.
        what: String,
        /// Estimated need, formatted.
        needed: String,
        /// The memory available, formatted.
        available: String,
    },
    /// The environment rejected a call.
    #[error("environment: {0}")]
    Env(#[from] rlpkg_vec_env::EnvError),
}

impl AgentError {
    /// Whether the error comes from what the user gave (config, run folder, output folder, disk
    /// space) rather than a fault of the program. Every file this crate touches is one the user
    /// named or a file inside a folder the user named, so I/O errors count as the user's.
    pub fn is_input_error(&self) -> bool {
        matches!(
            self,
            AgentError::ConfigParse { .. }
                | AgentError::ConfigValue { .. }
                | AgentError::Checkpoint { .. }
                | AgentError::Io { .. }
                | AgentError::Memory { .. }
                | AgentError::Env(_)
        )
    }

    /// An [`AgentError::Io`] for `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        AgentError::Io {
            path: path.into(),
            source,
        }
    }
}
