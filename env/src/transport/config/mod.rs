//! The `[transport]` table of a training configuration (`configs/train/transport.toml`): scene, paths
//! from the recordings, control rate, limits, success tolerances, reward weights and domain
//! randomisation. Every key is required unless said otherwise; unknown keys and out-of-range
//! values are rejected with the file, the key and what was expected. [`load_scene`] resolves the
//! scene the table names.
//!
//! One file per concept: the table (`table.rs`), its plain sections (`sections.rs`), the
//! randomisation (`randomization.rs`) with its held-out draws (`held_out_draws.rs`), the
//! profile-rate action (`profile_rate.rs`) and the observation mode (`observation.rs`); parsing
//! (`loading.rs`), the posterior's draws (`posterior.rs`), the range checks (`validation.rs`,
//! `sensor_validation.rs`), the limits against the recordings' peaks (`headroom.rs`), the nominal
//! task (`nominal.rs`) and the scene (`scene.rs`).

mod headroom;
mod held_out_draws;
mod loading;
mod nominal;
mod observation;
mod posterior;
mod profile_rate;
mod randomization;
mod scene;
mod sections;
mod sensor_validation;
mod table;
mod validation;

pub use headroom::LIMIT_HEADROOM;
pub use held_out_draws::{DrawRows, HeldOutDraws};
pub use observation::ObservationMode;
pub use profile_rate::ProfileRateAction;
pub use randomization::{FailureReplay, TransportRandomization};
pub use scene::load_scene;
pub use sections::{FailureLimits, RewardWeights, SuccessTolerances, TransportLimits};
pub use table::TransportConfig;
