//! What the actor observes (`transport.observation`, [`ObservationMode`]): the privileged state or
//! the cell's sensors.

use serde::{Deserialize, Serialize};

/// What the actor observes (`transport.observation`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ObservationMode {
    /// The simulator's exact tool state and each cup's utilisation (load over capacity), which no
    /// real sensor measures.
    #[default]
    Privileged,
    /// Only what a real cell measures, with noise and delay (`[transport.sensors]`); the critic
    /// keeps the exact, privileged state.
    Sensors,
}

impl ObservationMode {
    /// Whether this is the default, [`ObservationMode::Privileged`].
    pub fn is_privileged(&self) -> bool {
        *self == ObservationMode::Privileged
    }
}
