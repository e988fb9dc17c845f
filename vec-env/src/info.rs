//! How the per-step values an environment reports beside the reward ([`crate::VecEnv::info`])
//! are read: the name of a value says what it is.
//!
//! - `episode/<outcome>`: an episode outcome, 1 on the step an episode ends that way and 0 on
//!   every other step; over a rollout, its sum divided by the episodes that ended is the outcome's
//!   rate. [`SUCCESS`] is the outcome that means the task was solved.
//! - any other name (`reward/<term>`, `state/<figure>`, ...): a value of every step, averaged over
//!   the steps and copies of a rollout.

/// Prefix of the names of episode outcomes.
pub const EPISODE_PREFIX: &str = "episode/";

/// The episode outcome that means the task was solved (a trainer shows its rate beside the
/// return).
pub const SUCCESS: &str = "episode/success";

/// How a trainer summarises one info value over a rollout.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InfoKind {
    /// A value of every step: the mean over the rollout's steps and copies.
    PerStep,
    /// An episode outcome: the mean over the episodes that ended in the rollout (none when no
    /// episode ended).
    PerEpisode,
}

impl InfoKind {
    /// The kind of the info value named `name` (see the module documentation).
    pub fn of(name: &str) -> Self {
        if name.starts_with(EPISODE_PREFIX) {
            InfoKind::PerEpisode
        } else {
            InfoKind::PerStep
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn episode_outcomes_are_named_under_episode() {
        assert_eq!(InfoKind::of(SUCCESS), InfoKind::PerEpisode);
        assert_eq!(InfoKind::of("episode/truncated"), InfoKind::PerEpisode);
        assert_eq!(InfoKind::of("reward/progress"), InfoKind::PerStep);
        assert_eq!(InfoKind::of("state/episode/x"), InfoKind::PerStep);
    }
}
