//! The vacuum governor: a cell engineer's first closed-loop controller for a suction transport.
//! It plays the task's own plan (`[transport.profile_rate]`: the same pipeline, delays and
//! noise a policy has) and sets the plan's clock rate from the lowest cup's vacuum reading as a
//! fraction of the cell's supply vacuum: the task's largest rate (`max_rate`, the reach a policy
//! has) while every cup holds at least `full_ratio`, stopped at `stop_ratio` or below, linear
//! between; the tool's tilt stays the plan's. With both ratios 0 it is the plan at rate 1, the
//! plan a policy modulates.

use std::fmt;
use std::str::FromStr;

use super::run_error::RunError;
use super::{ObservationMode, Transport, TransportConfig};
use crate::{EnvSpec, VecEnv};

/// A vacuum governor's two thresholds (fractions of the supply vacuum).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VacuumGovernor {
    /// The lowest cup's vacuum over the supply's at or above which the plan runs at rate 1.
    pub full_ratio: f64,
    /// The ratio at or below which the plan stops (rate 0).
    pub stop_ratio: f64,
}

impl VacuumGovernor {
    /// The plan at rate 1 whatever the readings.
    pub const PLAN: Self = Self {
        full_ratio: 0.0,
        stop_ratio: 0.0,
    };

    /// The plan's clock rate for the lowest cup's vacuum over the supply's, with `max_rate` the
    /// task's largest (the plan at rate 1 ignores it).
    pub fn rate(&self, lowest_ratio: f64, max_rate: f64) -> f64 {
        if *self == Self::PLAN {
            1.0
        } else if lowest_ratio >= self.full_ratio {
            max_rate
        } else if lowest_ratio <= self.stop_ratio {
            0.0
        } else {
            max_rate * (lowest_ratio - self.stop_ratio) / (self.full_ratio - self.stop_ratio)
        }
    }

    /// The row label of its episodes.
    pub fn label(&self) -> String {
        if *self == Self::PLAN {
            "plan x1".to_string()
        } else {
            format!("governor {self}")
        }
    }

    /// The actions of every copy of `env` for the actor observations `obs`: rate from the
    /// lowest cup's reading (`vacuum_columns` of each row, gauge Pa) up to `max_rate`, no tilt
    /// offset.
    pub fn actions(
        &self,
        env: &Transport,
        obs: &[f32],
        vacuum_columns: &[usize],
        max_rate: f64,
    ) -> Vec<f32> {
        let width = obs.len() / env.num_envs().max(1);
        let mut actions = Vec::with_capacity(3 * env.num_envs());
        for (copy, row) in obs.chunks(width).enumerate() {
            let supply = env.supply_vacuum_pa(copy).unwrap_or(f64::NAN);
            let lowest = vacuum_columns
                .iter()
                .map(|&k| -(row[k] as f64))
                .fold(f64::INFINITY, f64::min);
            actions.extend([self.rate(lowest / supply, max_rate) as f32, 0.0, 0.0]);
        }
        actions
    }

    /// The actor observation columns (of `spec`) of the cups' vacuum readings of a task, refused
    /// (naming the config `source`) unless the task has sensors and a plan to govern.
    pub fn vacuum_columns(
        config: &TransportConfig,
        spec: &EnvSpec,
        source: &str,
    ) -> Result<Vec<usize>, RunError> {
        if config.profile_rate.is_none() || config.observation != ObservationMode::Sensors {
            return Err(RunError::Input(format!(
                "{source}: a vacuum governor needs a task with [transport.profile_rate] (a plan to \
                 govern) and observation = \"sensors\" (the cups' vacuum readings)"
            )));
        }
        Ok(spec
            .observation
            .names
            .iter()
            .enumerate()
            .filter(|(_, name)| name.ends_with("_vacuum_pressure"))
            .map(|(k, _)| k)
            .collect())
    }
}

impl fmt::Display for VacuumGovernor {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}", self.full_ratio, self.stop_ratio)
    }
}

impl FromStr for VacuumGovernor {
    type Err = String;

    /// `FULL:STOP`, e.g. `0.9:0.7`: `1 >= FULL >= STOP >= 0`, `FULL > STOP` unless both are 0.
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let expected =
            "expected FULL:STOP, fractions of the supply vacuum with 1 >= FULL > STOP >= 0 \
                        (0:0 is the plan at rate 1), e.g. 0.9:0.7";
        let (full, stop) = text
            .split_once(':')
            .ok_or_else(|| format!("`{text}`: {expected}"))?;
        let parse = |s: &str| s.trim().parse::<f64>().ok().filter(|v| v.is_finite());
        let (Some(full_ratio), Some(stop_ratio)) = (parse(full), parse(stop)) else {
            return Err(format!("`{text}`: {expected}"));
        };
        let governor = Self {
            full_ratio,
            stop_ratio,
        };
        let ordered = (0.0..=1.0).contains(&full_ratio)
            && (0.0..=1.0).contains(&stop_ratio)
            && full_ratio > stop_ratio;
        if ordered || governor == Self::PLAN {
            Ok(governor)
        } else {
            Err(format!("`{text}`: {expected}"))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rate_falls_from_full_to_stop_with_the_lowest_vacuum() {
        let g: VacuumGovernor = "0.9:0.7".parse().unwrap();
        assert_eq!(g.rate(0.95, 1.5), 1.5);
        assert_eq!(g.rate(0.9, 1.0), 1.0);
        assert!((g.rate(0.8, 1.5) - 0.75).abs() < 1e-12);
        assert_eq!(g.rate(0.7, 1.5), 0.0);
        assert_eq!(g.rate(0.1, 1.5), 0.0);
        assert_eq!(g.label(), "governor 0.9:0.7");
        let plan: VacuumGovernor = "0:0".parse().unwrap();
        assert_eq!(plan, VacuumGovernor::PLAN);
        assert_eq!((plan.rate(0.0, 1.5), plan.rate(0.5, 1.5)), (1.0, 1.0));
        assert_eq!(plan.label(), "plan x1");
        for bad in ["0.7:0.9", "0.9", "1.5:0.5", "x:0.5", "0.5:0.5", "NaN:0"] {
            let err = bad.parse::<VacuumGovernor>().unwrap_err();
            assert!(err.contains(bad) && err.contains("FULL:STOP"), "{err}");
        }
    }
}
