//! The domain randomisation (`[transport.randomization]`, [`TransportRandomization`]) and its
//! replay of the settled packages that fail ([`FailureReplay`]).

use rlpkg_sim::Randomization;
use serde::{Deserialize, Serialize};

use super::held_out_draws::HeldOutDraws;

/// Domain randomisation.
///
/// Quantities of the settled package (object mass, its place and tilt in the package, the
/// package's yaw under the tool, material scales, start jitter) are drawn for each of the
/// `settled_variants` states that `reset(seed)` settles once; every episode restores one of them
/// at random (drawn from the copy's own stream), so the package need not be re-simulated at each
/// reset. The target tilt and the goal jitter are drawn per episode. With `replay`, training
/// draws the packages whose episodes fail more often.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransportRandomization {
    /// Tilt of the tool at the place pose (degrees), uniform.
    #[serde(deserialize_with = "rlpkg_toml_input::array")]
    pub target_tilt_deg: [f64; 2],
    /// Largest offset of the place position (m), uniform in a ball.
    pub goal_jitter_m: f64,
    /// Largest offset of the pick position (m), uniform in a horizontal disc, per variant.
    pub start_jitter_m: f64,
    /// Package quantities per settled variant (the simulator's [`Randomization`]).
    pub package: Randomization,
    /// Replay of the settled packages that fail (optional; see [`FailureReplay`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub replay: Option<FailureReplay>,
    /// Posterior draws kept out of training (optional; see [`HeldOutDraws`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub held_out_draws: Option<HeldOutDraws>,
}

/// `[transport.randomization.replay]`: during training a share of the episodes starts from a
/// settled package drawn in proportion to its recent failure rate instead of uniformly
/// (prioritised level replay, Jiang et al. 2021), so the rare packages a policy fails on are
/// trained on more often than their share of the randomisation. A package's failure rate is an
/// exponential average over its finished episodes (1 for an episode that ends in anything but
/// success, else 0), from 0 at each reset; evaluation mode
/// ([`crate::Transport::set_retire_finished`]) draws uniformly.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FailureReplay {
    /// Share of the episodes that start from a package drawn by its failure rate, in [0, 1].
    pub share: f64,
    /// Weight of a package's earlier failure rate when one of its episodes ends, in [0, 1).
    pub memory: f64,
}
