//! The whole `[transport]` table ([`TransportConfig`]): its top-level keys and one field per
//! section.

use serde::{Deserialize, Serialize};

use super::observation::ObservationMode;
use super::profile_rate::ProfileRateAction;
use super::randomization::TransportRandomization;
use super::sections::{FailureLimits, RewardWeights, SuccessTolerances, TransportLimits};
use crate::transport::sensors::SensorConfig;

/// The whole `[transport]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransportConfig {
    /// Scene file (e.g. `configs/scenes/physical-explicit.toml`) or preset name (`physical`); needs SI masses
    /// and the seal model on.
    pub scene: String,
    /// Package grid `[rows, columns]` (overrides the scene's; coarse grids train faster).
    #[serde(deserialize_with = "rlpkg_toml_input::array")]
    pub grid: [usize; 2],
    /// Folder of the recordings (`data/deformable-sim-real`).
    pub recordings: String,
    /// Recordings whose tool paths the episodes follow; each episode takes the one whose final
    /// tilt is nearest its target tilt.
    pub paths: Vec<String>,
    /// Control rate (Hz): one action per `1 / control_hz` seconds.
    pub control_hz: f64,
    /// Episodes are truncated after this long (s).
    pub time_limit_s: f64,
    /// Settled package states built at each `reset(seed)` (see [`TransportRandomization`]).
    pub settled_variants: usize,
    /// Extra settling after the scene's rest period before the snapshot is taken (s).
    pub settle_s: f64,
    /// The cell's grasp check (optional), as a vacuum switch confirms a pick before the move: a
    /// settled package counts as grasped only if every cup holds at least this fraction of the
    /// supply vacuum under the sensors' leak model
    /// ([`crate::transport::sensors::cup_vacuum_pa`]: 0.98 for a sound, unloaded seal, about 0.75
    /// at the failure load); a package below it is replaced by the unrandomised one, as an
    /// unsealed one is. In [0.5, 0.98].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grasp_min_vacuum_ratio: Option<f64>,
    /// Limits of the action and of the robot.
    pub limits: TransportLimits,
    /// When an episode counts as a success.
    pub success: SuccessTolerances,
    /// When an episode counts as a failure besides seal and health events.
    pub failure: FailureLimits,
    /// Reward weights.
    pub reward: RewardWeights,
    /// Domain randomisation.
    pub randomization: TransportRandomization,
    /// What the actor observes (optional; default `"privileged"`).
    #[serde(default, skip_serializing_if = "ObservationMode::is_privileged")]
    pub observation: ObservationMode,
    /// The cell's sensors: required with `observation = "sensors"`, refused otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sensors: Option<SensorConfig>,
    /// With this table the first action is the rate of a motion profile's clock instead of the
    /// path speed (optional; see [`ProfileRateAction`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub profile_rate: Option<ProfileRateAction>,
}
