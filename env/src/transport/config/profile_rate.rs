//! The profile-rate action (`[transport.profile_rate]`, [`ProfileRateAction`]): the first action
//! as the rate of a motion profile's clock.

use serde::{Deserialize, Serialize};

/// `[transport.profile_rate]`: the policy plays a time-optimal, jerk-limited motion profile along
/// each episode's path (planned at the episode's start under the tool's limits times
/// `limits_scale`, the tilt following the minimum-jerk schedule) and its first action is the
/// rate of the profile's clock: 1 plays the plan as planned, 0 holds the reference, 2 plays it
/// twice as fast. The result still goes through the path speed's clamps. Training starts from
/// the profile's careful driving and may speed it up or slow it down per package.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProfileRateAction {
    /// The plan's limits as a multiple of the tool's (`[transport.limits]`), in (0, 3]. Above 1
    /// the plan asks for more than the tool gives and the path speed's clamps shape it, as they
    /// shape the profile baseline's rows above x1.
    pub limits_scale: f64,
    /// Largest rate of the profile's clock, in [1, 4].
    pub max_rate: f64,
    /// Largest change of the rate per second (1/s): the clock speeds up and slows down smoothly.
    pub max_rate_change_per_s: f64,
}
