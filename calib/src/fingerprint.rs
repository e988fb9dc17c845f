//! The objective a calibration folder was made for, recorded beside its evaluation log as
//! `objective.toml`: the dataset and trajectories, the time window, the loss weights, the
//! parameters and their bounds, the design's seed and sizes, and the whole scene the candidates are
//! simulated in. A rerun into the folder resumes only when it would fit the same objective: logged
//! evaluations of another objective would silently mislead the optimiser.

use std::path::{Path, PathBuf};

use rlpkg_replay::loss::LossWeights;
use rlpkg_sim::SceneConfig;
use serde::Serialize;

use crate::config::CalibrateConfig;
use crate::smc::SmcSettings;
use crate::space::ParamSpec;

/// The file, in the output folder, that records the objective.
pub const OBJECTIVE_FILE: &str = "objective.toml";

/// Everything that decides which loss a logged evaluation measured (and which design produced it).
#[derive(Debug, Serialize)]
pub struct ObjectiveRecord<'a> {
    /// Dataset folder.
    pub data: &'a Path,
    /// Trajectory ids fitted.
    pub trajectories: &'a [String],
    /// Seconds of each trajectory compared; absent for whole trajectories.
    pub max_seconds: Option<f64>,
    /// Seed of the initial design and the acquisition search.
    pub seed: u64,
    /// Latin-hypercube points of the initial design.
    pub initial_points: usize,
    /// Candidates per batch.
    pub batch_size: usize,
    /// Loss weights.
    pub loss: LossWeights,
    /// Calibrated parameters with their bounds.
    pub param: &'a [ParamSpec],
    /// The sampler of a posterior calibration (absent for Bayesian optimisation).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub smc: Option<crate::smc::SmcSettings>,
    /// The likelihood of a posterior calibration (absent for Bayesian optimisation).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub likelihood: Option<rlpkg_replay::LikelihoodSettings>,
    /// The scene the candidates are simulated in (preset, overrides, base parameter values).
    pub scene: &'a SceneConfig,
}

/// A rerun that would fit another objective than the folder's.
#[derive(Debug, thiserror::Error)]
pub enum FingerprintError {
    /// The recorded objective differs from this run's.
    #[error(
        "{path} line {line}: this folder's evaluations were made with `{recorded}`, this run has \
         `{now}`; resuming would mix two objectives (use --fresh to start over, or another --out)"
    )]
    Changed {
        /// The recorded objective file.
        path: PathBuf,
        /// First differing line (1-based).
        line: usize,
        /// That line as recorded (empty past the end).
        recorded: String,
        /// That line for this run (empty past the end).
        now: String,
    },
    /// The record could not be serialised or read.
    #[error("{path}: {message}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
}

impl<'a> ObjectiveRecord<'a> {
    /// The record of a sampled posterior of `config` (its `[smc]` settings `smc`) on
    /// `trajectories` in `scene`: every batch holds `smc.particles` candidates.
    pub fn posterior(
        config: &'a CalibrateConfig,
        smc: SmcSettings,
        trajectories: &'a [String],
        scene: &'a SceneConfig,
    ) -> Self {
        Self {
            data: &config.data,
            trajectories,
            max_seconds: config.sim.max_seconds,
            seed: smc.seed,
            initial_points: smc.particles,
            batch_size: smc.particles,
            loss: config.loss,
            param: &config.params,
            smc: Some(smc),
            likelihood: Some(config.likelihood),
            scene,
        }
    }

    /// The record as TOML text.
    pub fn to_text(&self) -> Result<String, FingerprintError> {
        let body = toml::to_string_pretty(self).map_err(|e| FingerprintError::Io {
            path: PathBuf::from(OBJECTIVE_FILE),
            message: e.to_string(),
        })?;
        Ok(format!(
            "# The objective this calibration folder fits (`rlpkg calibrate` resumes only the same one).\n\n{body}"
        ))
    }
}

/// Compares `text` with the record in `out_dir`. Returns whether a record exists; an error names
/// the first line that differs.
pub fn check(out_dir: &Path, text: &str) -> Result<bool, FingerprintError> {
    let path = out_dir.join(OBJECTIVE_FILE);
    let recorded = match std::fs::read_to_string(&path) {
        Ok(recorded) => recorded,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(false),
        Err(e) => {
            return Err(FingerprintError::Io {
                path,
                message: e.to_string(),
            })
        }
    };
    let mut recorded_lines = recorded.lines();
    let mut lines = text.lines();
    for line in 1.. {
        match (recorded_lines.next(), lines.next()) {
            (None, None) => break,
            (a, b) if a == b => continue,
            (a, b) => {
                return Err(FingerprintError::Changed {
                    path,
                    line,
                    recorded: a.unwrap_or_default().to_string(),
                    now: b.unwrap_or_default().to_string(),
                })
            }
        }
    }
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_the_first_differing_line() {
        let dir = tempfile::tempdir().unwrap();
        assert!(!check(dir.path(), "a = 1\nb = 2\n").unwrap());
        std::fs::write(dir.path().join(OBJECTIVE_FILE), "a = 1\nb = 2\n").unwrap();
        assert!(check(dir.path(), "a = 1\nb = 2\n").unwrap());
        let err = check(dir.path(), "a = 1\nb = 3\n").unwrap_err().to_string();
        assert!(err.contains("line 2") && err.contains("`b = 2`") && err.contains("`b = 3`"));
        let err = check(dir.path(), "a = 1\n").unwrap_err().to_string();
        assert!(err.contains("line 2"), "{err}");
    }
}
