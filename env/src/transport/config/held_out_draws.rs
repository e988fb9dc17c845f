//! The posterior draws kept out of training (`[transport.randomization.held_out_draws]`,
//! [`HeldOutDraws`]) and which part of them a task uses ([`DrawRows`]).

use serde::{Deserialize, Serialize};

/// `[transport.randomization.held_out_draws]`: every `every`-th draw of the posterior (its rows
/// `every`, `2 every`, ... counted from 1) is held out, so that a policy can be evaluated on
/// materials it never trained on; the held-out rows alternate between test (the first, third,
/// ...) and validation (the second, fourth, ...), so that what is chosen by looking at results
/// is chosen on materials the reported table never sees. `rows` says which part the task draws
/// its packages from.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeldOutDraws {
    /// The period of the held-out rows, in [2, 100].
    pub every: usize,
    /// Which draws the packages take: `"training"` (the rest), `"held_out"` (all held-out
    /// rows), `"validation"` or `"test"` (their halves).
    pub rows: DrawRows,
}

/// Which part of a posterior's draws a task uses ([`HeldOutDraws`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DrawRows {
    /// Every draw but the held-out ones.
    Training,
    /// The held-out draws only.
    HeldOut,
    /// The held-out draws of even rank (the second, fourth, ...): where choices are made.
    Validation,
    /// The held-out draws of odd rank (the first, third, ...): where results are reported.
    Test,
}

impl HeldOutDraws {
    /// Whether the draw in row `index` (from 0) is held out.
    pub fn is_held_out(&self, index: usize) -> bool {
        (index + 1).is_multiple_of(self.every)
    }

    /// Whether the draw in row `index` (from 0) is in the part `rows` names.
    fn is_in(&self, index: usize, rows: DrawRows) -> bool {
        let held_out = self.is_held_out(index);
        // Rank among the held-out rows, from 1.
        let rank = (index + 1) / self.every;
        match rows {
            DrawRows::Training => !held_out,
            DrawRows::HeldOut => held_out,
            DrawRows::Validation => held_out && rank.is_multiple_of(2),
            DrawRows::Test => held_out && !rank.is_multiple_of(2),
        }
    }

    /// The rows of `draws` the task uses.
    pub fn select<T: Clone>(&self, draws: &[T]) -> Vec<T> {
        draws
            .iter()
            .enumerate()
            .filter(|(k, _)| self.is_in(*k, self.rows))
            .map(|(_, row)| row.clone())
            .collect()
    }
}
