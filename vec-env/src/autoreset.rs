//! What happens to a copy whose episode ends ([`AutoresetMode`], Gymnasium 1.x's modes), how the
//! copies of a reset are chosen and seeded ([`ResetCopies`]), and the per-copy bookkeeping every
//! environment shares ([`Autoreset`]).

use crate::EnvError;

/// When a copy whose episode ended starts its next episode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum AutoresetMode {
    /// In the step the episode ends: `obs` holds the new episode's first observation and
    /// `final_obs` the one the episode ended on (what `rlpkg train` uses).
    #[default]
    SameStep,
    /// In the step after: the step the episode ends returns its terminal observation in `obs`;
    /// the next step ignores that copy's action, starts the new episode and returns its first
    /// observation with reward 0 and neither flag set (Gymnasium 1.x's default).
    NextStep,
    /// Never by itself: a finished copy keeps its terminal observation until the caller resets
    /// it ([`crate::VecEnv::reset_copies`] with a mask); stepping it before is an error.
    Disabled,
}

impl AutoresetMode {
    /// The mode named `name`: `same_step`, `next_step` or `disabled` (Gymnasium's names).
    pub fn parse(name: &str) -> Option<Self> {
        match name {
            "same_step" => Some(Self::SameStep),
            "next_step" => Some(Self::NextStep),
            "disabled" => Some(Self::Disabled),
            _ => None,
        }
    }

    /// Gymnasium's name of the mode (`same_step`, `next_step`, `disabled`).
    pub fn name(self) -> &'static str {
        match self {
            Self::SameStep => "same_step",
            Self::NextStep => "next_step",
            Self::Disabled => "disabled",
        }
    }
}

/// How the copies of a reset draw their random streams.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Seeding<'a> {
    /// Copy `i` from `seed + i` ([`crate::env_rng`]), as [`crate::VecEnv::reset`].
    Base(u64),
    /// Copy `i` from `seeds[i]` (one seed per copy).
    PerCopy(&'a [u64]),
    /// Each copy continues its own stream (no reseeding).
    Continue,
}

/// Which copies a reset restarts and how they are seeded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ResetCopies<'a> {
    /// `mask[i]`: restart copy `i`; `None`: every copy. Rows of copies left out keep what the
    /// output buffers held.
    pub mask: Option<&'a [bool]>,
    /// How the restarted copies are seeded.
    pub seeding: Seeding<'a>,
}

impl<'a> ResetCopies<'a> {
    /// Every copy, copy `i` seeded from `seed + i`.
    pub fn all(seed: u64) -> Self {
        Self {
            mask: None,
            seeding: Seeding::Base(seed),
        }
    }

    /// Checks the mask's and the seeds' lengths against `num_envs`.
    pub fn check(&self, num_envs: usize) -> Result<(), EnvError> {
        let lengths = [
            ("reset mask", self.mask.map(<[bool]>::len)),
            (
                "per-copy seeds",
                match self.seeding {
                    Seeding::PerCopy(seeds) => Some(seeds.len()),
                    _ => None,
                },
            ),
        ];
        for (what, len) in lengths {
            if let Some(got) = len.filter(|&got| got != num_envs) {
                return Err(EnvError::BatchLength {
                    what,
                    expected: num_envs,
                    got,
                });
            }
        }
        Ok(())
    }

    /// Whether copy `env` is restarted.
    pub fn includes(&self, env: usize) -> bool {
        self.mask.is_none_or(|mask| mask[env])
    }

    /// Whether every copy is restarted.
    pub fn is_all(&self) -> bool {
        self.mask.is_none_or(|mask| mask.iter().all(|&m| m))
    }

    /// The seed copy `env` is reseeded from, `None` when it continues its stream.
    pub fn seed_of(&self, env: usize) -> Option<u64> {
        match self.seeding {
            Seeding::Base(seed) => Some(seed.wrapping_add(env as u64)),
            Seeding::PerCopy(seeds) => Some(seeds[env]),
            Seeding::Continue => None,
        }
    }

    /// The seed of the whole batch (things every copy shares, e.g. settled package variants):
    /// the base seed, or the first copy's seed; `None` when the copies are not reseeded.
    pub fn batch_seed(&self) -> Option<u64> {
        match self.seeding {
            Seeding::Base(seed) => Some(seed),
            Seeding::PerCopy(seeds) => seeds.first().copied(),
            Seeding::Continue => None,
        }
    }
}

/// The autoreset mode and which copies have ended an episode without being restarted yet: the
/// bookkeeping each environment keeps beside its own state.
#[derive(Debug, Clone, PartialEq)]
pub struct Autoreset {
    mode: AutoresetMode,
    /// Copy ended its episode and waits for its restart (next step, or the caller's reset).
    waiting: Vec<bool>,
}

impl Autoreset {
    /// Bookkeeping for `num_envs` copies in [`AutoresetMode::SameStep`].
    pub fn new(num_envs: usize) -> Self {
        Self {
            mode: AutoresetMode::SameStep,
            waiting: vec![false; num_envs],
        }
    }

    /// The current mode.
    pub fn mode(&self) -> AutoresetMode {
        self.mode
    }

    /// Switches the mode; copies waiting for a restart are forgotten (reset the environment
    /// after switching).
    pub fn set_mode(&mut self, mode: AutoresetMode) {
        self.mode = mode;
        self.waiting.fill(false);
    }

    /// Checks a step may start: in [`AutoresetMode::Disabled`], no copy may have finished.
    pub fn check_step(&self) -> Result<(), EnvError> {
        match self.waiting.iter().position(|&w| w) {
            Some(env) if self.mode == AutoresetMode::Disabled => {
                Err(EnvError::FinishedCopy { env })
            }
            _ => Ok(()),
        }
    }

    /// Whether copy `env` starts its new episode in this step instead of being stepped
    /// ([`AutoresetMode::NextStep`]); the caller restarts it and calls [`Autoreset::restarted`].
    pub fn restarts_now(&self, env: usize) -> bool {
        self.mode == AutoresetMode::NextStep && self.waiting[env]
    }

    /// Copy `env` ended its episode in this step: `true` when it restarts at once
    /// ([`AutoresetMode::SameStep`]); otherwise it is marked as waiting and keeps its terminal
    /// observation.
    pub fn episode_ended(&mut self, env: usize) -> bool {
        if self.mode == AutoresetMode::SameStep {
            return true;
        }
        self.waiting[env] = true;
        false
    }

    /// Copy `env` started a new episode.
    pub fn restarted(&mut self, env: usize) {
        self.waiting[env] = false;
    }

    /// Whether copy `env` ended its episode and waits for its restart.
    pub fn is_waiting(&self, env: usize) -> bool {
        self.waiting[env]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_lengths_are_checked() {
        for mode in [
            AutoresetMode::SameStep,
            AutoresetMode::NextStep,
            AutoresetMode::Disabled,
        ] {
            assert_eq!(AutoresetMode::parse(mode.name()), Some(mode));
        }
        assert_eq!(AutoresetMode::parse("next"), None);
        let mask = [true, false];
        let reset = ResetCopies {
            mask: Some(&mask),
            seeding: Seeding::PerCopy(&[4, 9]),
        };
        assert!(reset.check(2).is_ok());
        assert!(matches!(
            reset.check(3),
            Err(EnvError::BatchLength {
                what: "reset mask",
                expected: 3,
                got: 2
            })
        ));
        assert!(reset.includes(0) && !reset.includes(1) && !reset.is_all());
        assert_eq!((reset.seed_of(1), reset.batch_seed()), (Some(9), Some(4)));
        assert_eq!(ResetCopies::all(5).seed_of(2), Some(7));
    }

    #[test]
    fn waiting_copies_follow_the_mode() {
        let mut same = Autoreset::new(2);
        assert!(same.episode_ended(1) && !same.is_waiting(1));
        let mut next = Autoreset::new(2);
        next.set_mode(AutoresetMode::NextStep);
        assert!(!next.episode_ended(1));
        assert!(next.restarts_now(1) && !next.restarts_now(0));
        assert!(next.check_step().is_ok());
        next.restarted(1);
        assert!(!next.restarts_now(1));
        let mut disabled = Autoreset::new(2);
        disabled.set_mode(AutoresetMode::Disabled);
        assert!(!disabled.episode_ended(0) && !disabled.restarts_now(0));
        assert!(matches!(
            disabled.check_step(),
            Err(EnvError::FinishedCopy { env: 0 })
        ));
        disabled.restarted(0);
        assert!(disabled.check_step().is_ok());
    }
}
