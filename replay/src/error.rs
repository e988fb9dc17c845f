//! Errors of setting up or running a replay.

use rlpkg_sim::SimError;

/// Errors of setting up or running a replay.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// The simulator rejected the scene or an environment.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// A recorded trajectory cannot be replayed.
    #[error("trajectory {id}: {message}")]
    Trajectory {
        /// Trajectory id.
        id: String,
        /// What is wrong.
        message: String,
    },
    /// The recordings cannot be read.
    #[error(transparent)]
    Data(#[from] rlpkg_mocap::DataError),
    /// An unknown parameter name.
    #[error("unknown simulator parameter `{0}`")]
    UnknownParameter(String),
    /// The observer asked the rollout to stop ([`Observer::stop`]).
    #[error("the rollout was stopped")]
    Stopped,
}
