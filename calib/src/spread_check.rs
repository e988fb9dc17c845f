//! The simulator's own sensitivity at a calibration config's scene (`rlpkg posterior CONFIG
//! --spread NUDGE`): how far the calibration's replays move when its parameters are nudged far
//! below what the recordings can tell apart ([`SimObjective::spread`]), beside the recordings'
//! marker noise. A spread near the noise means the loss is rough at the scale the likelihood
//! resolves: the scene is not fit for calibration at that solver setting.

use std::path::Path;

use rlpkg_replay::synthetic::marker_noise_std;
use rlpkg_sim::SceneConfig;

use crate::config::CalibrateConfig;
use crate::objective::{SimObjective, Spread};

/// Nudges up to this size are far below what a recording resolves: their spread says whether the
/// loss is smooth.
pub const ROUGHNESS_NUDGE: f64 = 1e-5;

/// A config's objective at its scene's own values, ready to be nudged ([`SpreadCheck::run`]).
pub struct SpreadCheck {
    /// Ids of the calibration's trajectories.
    pub trajectory_ids: Vec<String>,
    /// The scene the config calibrates.
    pub scene: SceneConfig,
    objective: SimObjective,
}

/// The spreads of every nudged parameter set, beside the recordings' noise.
pub struct SpreadReport {
    /// The relative nudge.
    pub nudge: f64,
    /// One per parameter, then all of them ([`crate::objective::ALL_PARAMETERS`]).
    pub spreads: Vec<Spread>,
    /// The largest marker noise of the recordings (m per axis); `None` when none is long
    /// enough to estimate it.
    pub noise_std_m: Option<f64>,
}

impl SpreadCheck {
    /// The objective of `config` (`config_path` names it in messages) on its training
    /// trajectories.
    pub fn new(config: &CalibrateConfig, config_path: &Path) -> Result<Self, String> {
        let (trajectory_ids, trajectories) = config.training_trajectories()?;
        let scene = config.scene(config_path)?;
        let names: Vec<String> = config.params.iter().map(|p| p.name.clone()).collect();
        let objective = SimObjective::new(
            &scene,
            names,
            &trajectories,
            config.loss,
            config.sim.max_seconds,
        )
        .map_err(|e| e.to_string())?;
        Ok(Self {
            trajectory_ids,
            scene,
            objective,
        })
    }

    /// Replays the scene's own values and each nudge by `1 + nudge` ([`SimObjective::spread`]).
    pub fn run(&self, nudge: f64) -> Result<SpreadReport, String> {
        let noise_std_m = self
            .objective
            .targets()
            .iter()
            .filter_map(marker_noise_std)
            .reduce(f64::max);
        let spreads = self
            .objective
            .spread(&self.objective.base_values(), nudge)
            .map_err(|e| e.to_string())?;
        Ok(SpreadReport {
            nudge,
            spreads,
            noise_std_m,
        })
    }
}

impl SpreadReport {
    /// The marker noise as a distance (m): a site's noise is `sigma` per axis, `sqrt(3) sigma`
    /// in space.
    pub fn noise_distance_m(&self) -> Option<f64> {
        self.noise_std_m.map(|sigma| 3f64.sqrt() * sigma)
    }

    /// The largest 90th-percentile spread of any nudged set (m).
    pub fn largest_p90_m(&self) -> f64 {
        self.spreads.iter().map(|s| s.p90_m).fold(0.0, f64::max)
    }

    /// Whether the loss is smooth at the noise's scale (the largest p90 spread under the noise
    /// distance); `None` when the nudge is too large to tell ([`ROUGHNESS_NUDGE`]) or the noise is
    /// unknown. Far below the recordings' resolution, any spread is the solver's, not the
    /// material's.
    pub fn smooth(&self) -> Option<bool> {
        let noise = self.noise_distance_m()?;
        (self.nudge <= ROUGHNESS_NUDGE).then(|| self.largest_p90_m() < noise)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spread(parameter: &str, p90_m: f64) -> Spread {
        Spread {
            parameter: parameter.into(),
            median_m: p90_m / 2.0,
            p90_m,
            max_m: 2.0 * p90_m,
            disc_max_m: 0.0,
            phase_p90_m: Vec::new(),
        }
    }

    #[test]
    fn smooth_means_every_p90_under_the_noise_at_a_tiny_nudge() {
        let mut report = SpreadReport {
            nudge: 1e-6,
            spreads: vec![spread("k_tri_e", 1e-5), spread("all", 3e-5)],
            noise_std_m: Some(1e-4),
        };
        assert_eq!(report.largest_p90_m(), 3e-5);
        assert!((report.noise_distance_m().unwrap() - 3f64.sqrt() * 1e-4).abs() < 1e-15);
        assert_eq!(report.smooth(), Some(true));
        report.spreads.push(spread("mu_con", 2e-4));
        assert_eq!(report.smooth(), Some(false));
        report.nudge = 1e-3;
        assert_eq!(report.smooth(), None, "a large nudge says nothing");
        report.nudge = 1e-6;
        report.noise_std_m = None;
        assert_eq!(report.smooth(), None);
    }
}
