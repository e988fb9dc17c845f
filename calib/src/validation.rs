//! Posterior validation (`rlpkg posterior CONFIG --validate N`): the posterior's draws checked on
//! the simulator.
//!
//! [`crate::posterior`] samples the GP surrogate of the calibration loss; where the calibration's
//! evaluations are sparse, the surrogate can promise a fit the simulator does not give (and
//! packages no gripper carries). This replays `N` draws, evenly spaced through `samples.csv`,
//! with the calibration's own objective (its trajectories, their first `sim.max_seconds`, its loss
//! weights) and keeps those whose loss is within the posterior's likelihood threshold `ε`:
//! rejection with the surrogate posterior as the proposal, so the kept draws are that posterior
//! restricted to parameters that really fit the recordings. A draw that diverges is rejected.
//!
//! The outputs ([`Validated`]): `samples.csv` (the kept draws, the format of any posterior, so
//! `randomization.package.posterior` and `eval --params` take the folder), `summary.json` (the
//! posterior's, with a `validation` block: threshold, counts and the kept draws' 90 % intervals)
//! and `replayed.csv` (every replayed draw: its row in the posterior's `samples.csv`, its values,
//! loss, Chamfer, object MSE and whether it was kept). This module owns `replayed.csv`: it writes
//! it and reads it back ([`read_replayed`]) for a posterior fitted to the replays as well.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::config::CalibrateConfig;
use crate::driver::{BatchObjective, CandidateResult};
use crate::objective::{Observer, SimObjective};
use crate::posterior::{quantile, Evaluation};
use crate::posterior_files::{self, samples_csv, Samples, SAMPLES_FILE, SUMMARY_FILE};

/// Draws replayed in one batched rollout (and between two progress reports).
pub const DRAWS_PER_BATCH: usize = 16;

/// The file of every replayed draw.
pub const REPLAYED_FILE: &str = "replayed.csv";

/// Largest `replayed.csv` read back (bytes), checked before reading.
const MAX_REPLAYED_BYTES: u64 = 64 << 20;

/// What stops a validation.
#[derive(Debug, thiserror::Error)]
pub enum ValidationError {
    /// A file or value given to it (the message names it and what was expected).
    #[error("{0}")]
    Input(String),
    /// The objective failed to replay a batch.
    #[error("{0}")]
    Replay(String),
    /// The progress report asked to stop.
    #[error("the validation was stopped")]
    Stopped,
    /// The summary could not be written as JSON.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
}

/// What to validate.
pub struct ValidationRequest<'a> {
    /// The calibration config the posterior was inferred for.
    pub config: &'a CalibrateConfig,
    /// Its file (its scene's paths are relative to it).
    pub config_path: &'a Path,
    /// Folder of the posterior to validate.
    pub posterior: &'a Path,
    /// Draws to replay.
    pub draws: usize,
    /// How the caller names `draws` in a message (e.g. `--validate`).
    pub draws_option: &'a str,
    /// A threshold instead of the posterior's own `epsilon_loss`, and where it came from.
    pub threshold: Option<(f64, &'static str)>,
}

/// One parameter of the kept draws.
#[derive(Debug, Clone, Serialize)]
pub struct KeptInterval {
    /// Parameter name.
    pub name: String,
    /// 5 % and 95 % quantiles of the kept draws (SI).
    pub interval: [f64; 2],
    /// `log10(high / low)`, for log parameters.
    pub interval_decades: Option<f64>,
}

/// The `validation` block of the output's `summary.json`.
#[derive(Debug, Clone, Serialize)]
pub struct Validation {
    /// The posterior folder whose draws were replayed.
    pub posterior: PathBuf,
    /// The loss a draw must not exceed to be kept.
    pub epsilon_loss: f64,
    /// Where that threshold came from.
    pub epsilon_from: &'static str,
    /// Draws replayed.
    pub replayed: usize,
    /// Draws kept.
    pub kept: usize,
    /// Replays that diverged (non-finite loss).
    pub diverged: usize,
    /// Replayed loss of the kept draws: lowest.
    pub kept_loss_min: Option<f64>,
    /// Replayed loss of the kept draws: median.
    pub kept_loss_median: Option<f64>,
    /// Per parameter, the kept draws' 90 % interval (empty when none is kept).
    pub parameters: Vec<KeptInterval>,
}

/// A validation set up: the posterior read, the draws chosen, the objective built; nothing
/// replayed yet ([`ValidationPlan::run`]).
pub struct ValidationPlan {
    /// Ids of the calibration's trajectories the draws are replayed on.
    pub trajectory_ids: Vec<String>,
    /// The loss a draw must not exceed to be kept.
    pub epsilon_loss: f64,
    /// Draws in the posterior's `samples.csv`.
    pub available: usize,
    /// Rows of `samples.csv` (from 0) to replay.
    pub rows: Vec<usize>,
    epsilon_from: &'static str,
    posterior: PathBuf,
    summary: serde_json::Value,
    samples: Samples,
    config: CalibrateConfig,
    objective: SimObjective,
}

impl ValidationPlan {
    /// Reads the posterior's `summary.json` and `samples.csv`, picks the draws and builds the
    /// calibration's objective, with `observer` on its rollouts.
    pub fn new(
        request: &ValidationRequest,
        observer: Box<dyn Observer>,
    ) -> Result<Self, ValidationError> {
        let input = |e: &dyn std::fmt::Display| ValidationError::Input(e.to_string());
        let summary_path = request.posterior.join(SUMMARY_FILE);
        let samples_path = request.posterior.join(SAMPLES_FILE);
        let summary = posterior_files::read_summary(&summary_path).map_err(|e| {
            ValidationError::Input(format!(
                "{e}; {} needs the {SUMMARY_FILE} and {SAMPLES_FILE} of an `rlpkg posterior` \
                 folder",
                request.draws_option
            ))
        })?;
        let (epsilon_loss, epsilon_from) = match request.threshold {
            Some(given) => given,
            None => {
                let loss = summary["epsilon_loss"].as_f64().ok_or_else(|| {
                    ValidationError::Input(format!(
                        "{}: no `epsilon_loss` (the likelihood threshold `rlpkg posterior` records)",
                        summary_path.display()
                    ))
                })?;
                (loss, "the posterior's epsilon_loss")
            }
        };
        if !(epsilon_loss > 0.0 && epsilon_loss.is_finite()) {
            return Err(ValidationError::Input(format!(
                "threshold {epsilon_loss} ({epsilon_from}): expected a finite loss > 0"
            )));
        }
        let config = request.config;
        let names: Vec<String> = config.params.iter().map(|p| p.name.clone()).collect();
        let samples = Samples::read_columns(&samples_path, &names).map_err(|e| input(&e))?;
        let rows = samples
            .evenly_spaced_rows(&samples_path, request.draws, request.draws_option)
            .map_err(|e| input(&e))?;
        let (trajectory_ids, trajectories) =
            config.training_trajectories().map_err(|e| input(&e))?;
        let scene = config.scene(request.config_path).map_err(|e| input(&e))?;
        let objective = SimObjective::new(
            &scene,
            names,
            &trajectories,
            config.loss,
            config.sim.max_seconds,
        )
        .map_err(|e| input(&e))?
        .with_observer(observer);
        Ok(Self {
            trajectory_ids,
            epsilon_loss,
            available: samples.rows.len(),
            rows,
            epsilon_from,
            posterior: request.posterior.to_path_buf(),
            summary,
            samples,
            config: config.clone(),
            objective,
        })
    }

    /// Replays the draws [`DRAWS_PER_BATCH`] at a time; after each batch, `progress` is told how
    /// many are replayed of how many and how many are kept, and may stop the validation
    /// ([`ValidationError::Stopped`]).
    pub fn run(
        mut self,
        mut progress: impl FnMut(usize, usize, usize) -> ControlFlow<()>,
    ) -> Result<Validated, ValidationError> {
        let rows = &self.rows;
        let epsilon_loss = self.epsilon_loss;
        let mut results: Vec<CandidateResult> = Vec::with_capacity(rows.len());
        for chunk in rows.chunks(DRAWS_PER_BATCH) {
            let batch: Vec<Vec<f64>> = chunk
                .iter()
                .map(|&r| self.samples.rows[r].clone())
                .collect();
            let replayed = self
                .objective
                .evaluate(&batch)
                .map_err(ValidationError::Replay)?;
            results.extend(replayed);
            let kept = results.iter().filter(|r| r.loss <= epsilon_loss).count();
            if progress(results.len(), rows.len(), kept).is_break() {
                return Err(ValidationError::Stopped);
            }
        }

        let kept: Vec<usize> = (0..rows.len())
            .filter(|&i| results[i].loss <= epsilon_loss)
            .collect();
        let kept_draws: Vec<Vec<f64>> = kept
            .iter()
            .map(|&i| self.samples.rows[rows[i]].clone())
            .collect();
        let mut kept_losses: Vec<f64> = kept.iter().map(|&i| results[i].loss).collect();
        kept_losses.sort_by(f64::total_cmp);
        let parameters = if kept_draws.is_empty() {
            Vec::new()
        } else {
            self.config
                .params
                .iter()
                .enumerate()
                .map(|(k, p)| {
                    let mut values: Vec<f64> = kept_draws.iter().map(|d| d[k]).collect();
                    values.sort_by(f64::total_cmp);
                    let interval = [quantile(&values, 0.05), quantile(&values, 0.95)];
                    KeptInterval {
                        name: p.name.clone(),
                        interval,
                        interval_decades: p.log.then(|| (interval[1] / interval[0]).log10()),
                    }
                })
                .collect()
        };
        let validation = Validation {
            posterior: self.posterior,
            epsilon_loss,
            epsilon_from: self.epsilon_from,
            replayed: rows.len(),
            kept: kept.len(),
            diverged: results.iter().filter(|r| !r.loss.is_finite()).count(),
            kept_loss_min: kept_losses.first().copied(),
            kept_loss_median: (!kept_losses.is_empty()).then(|| quantile(&kept_losses, 0.5)),
            parameters,
        };
        let mut summary = self.summary;
        summary["validation"] = serde_json::to_value(&validation)?;

        let names: Vec<String> = self.config.params.iter().map(|p| p.name.clone()).collect();
        let mut replayed_csv = replayed_header(&names) + "\n";
        for (i, (&row, r)) in rows.iter().zip(&results).enumerate() {
            replayed_csv.push_str(&format!(
                "{row},{},{},{},{},{}\n",
                join(&self.samples.rows[row]),
                r.loss,
                r.chamfer_m,
                r.object_mse_m2,
                kept.binary_search(&i).is_ok()
            ));
        }
        Ok(Validated {
            samples_csv: samples_csv(&self.config.space(), &kept_draws),
            validation,
            summary,
            replayed_csv,
        })
    }
}

/// A finished validation: the outputs' contents.
pub struct Validated {
    /// The counts, threshold and kept intervals.
    pub validation: Validation,
    /// The posterior's `summary.json` with the `validation` block.
    pub summary: serde_json::Value,
    /// `samples.csv` of the kept draws.
    pub samples_csv: String,
    /// `replayed.csv` of every replayed draw.
    pub replayed_csv: String,
}

/// The header of `replayed.csv` for parameters `names`.
fn replayed_header(names: &[String]) -> String {
    format!("row,{},loss,chamfer_m,object_mse_m2,kept", names.join(","))
}

/// The draws of a `replayed.csv` as evaluations of `config`'s parameters (a diverged replay is a
/// failed evaluation), so that a posterior can be fitted to them as well.
pub fn read_replayed(
    path: &Path,
    config: &CalibrateConfig,
) -> Result<Vec<Evaluation>, ValidationError> {
    let input = ValidationError::Input;
    let size = std::fs::metadata(path)
        .map_err(|e| input(format!("{}: {e}", path.display())))?
        .len();
    if size > MAX_REPLAYED_BYTES {
        return Err(input(format!(
            "{}: {size} bytes; expected a replayed.csv of `rlpkg posterior --validate` (at most {} MiB)",
            path.display(),
            MAX_REPLAYED_BYTES >> 20
        )));
    }
    let text =
        std::fs::read_to_string(path).map_err(|e| input(format!("{}: {e}", path.display())))?;
    parse_replayed(&text, &path.display().to_string(), config)
}

/// [`read_replayed`] of the text of a `replayed.csv`; `file` names it in messages.
fn parse_replayed(
    text: &str,
    file: &str,
    config: &CalibrateConfig,
) -> Result<Vec<Evaluation>, ValidationError> {
    let input = ValidationError::Input;
    let names: Vec<String> = config.params.iter().map(|p| p.name.clone()).collect();
    let header = replayed_header(&names);
    let mut lines = text.lines();
    let first = lines.next().unwrap_or("");
    if first != header {
        return Err(input(format!(
            "{file}: header `{first}`; expected `{header}` (a replayed.csv of `rlpkg posterior \
             --validate` for the parameters of this config)"
        )));
    }
    lines
        .enumerate()
        .map(|(i, line)| {
            let at = || format!("{file}: line {}", i + 2);
            let cells: Vec<&str> = line.split(',').map(str::trim).collect();
            if cells.len() != names.len() + 5 {
                return Err(input(format!(
                    "{}: {} cells; expected {}",
                    at(),
                    cells.len(),
                    names.len() + 5
                )));
            }
            let mut params = Vec::with_capacity(names.len());
            for (p, cell) in config.params.iter().zip(&cells[1..=names.len()]) {
                match cell.parse::<f64>() {
                    Ok(v) if (p.lower..=p.upper).contains(&v) => params.push(v),
                    _ => {
                        return Err(input(format!(
                            "{}: {} = `{cell}`; expected a number within [{:e}, {:e}]",
                            at(),
                            p.name,
                            p.lower,
                            p.upper
                        )))
                    }
                }
            }
            let loss = cells[names.len() + 1].parse::<f64>().map_err(|_| {
                input(format!(
                    "{}: loss = `{}`; expected a number (NaN or inf for a diverged replay)",
                    at(),
                    cells[names.len() + 1]
                ))
            })?;
            Ok(Evaluation { params, loss })
        })
        .collect()
}

/// `values` as `samples_csv` writes a draw.
fn join(values: &[f64]) -> String {
    values
        .iter()
        .map(f64::to_string)
        .collect::<Vec<_>>()
        .join(",")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config() -> CalibrateConfig {
        CalibrateConfig::parse(
            "data = \"d\"\nout_dir = \"o\"\n\n[sim]\npreset = \"reference\"\n\n\
             [optimiser]\niterations = 1\nbatch_size = 1\ninitial_points = 1\n\n\
             [[param]]\nname = \"k_tri_e\"\nlower = 1e2\nupper = 1e6\nlog = true\n\n\
             [[param]]\nname = \"mu_con\"\nlower = 0.1\nupper = 2.0\n",
            Path::new("c.toml"),
        )
        .unwrap()
    }

    #[test]
    fn replayed_rows_read_back_as_evaluations_and_bad_cells_are_located() {
        let config = config();
        let text = "row,k_tri_e,mu_con,loss,chamfer_m,object_mse_m2,kept\n\
                    0,1000,0.5,0.25,0.01,0.001,true\n\
                    7,2e5,1.5,NaN,NaN,NaN,false\n";
        let back = parse_replayed(text, "r.csv", &config).unwrap();
        assert_eq!(back.len(), 2);
        assert_eq!(back[0].params, [1000.0, 0.5]);
        assert_eq!(back[0].loss, 0.25);
        assert_eq!(back[1].params, [2e5, 1.5]);
        assert!(back[1].loss.is_nan());
        for (bad, expected) in [
            (text.replace("mu_con,loss", "mu,loss"), "r.csv: header"),
            (
                text.replace("0,1000,0.5", "0,1e9,0.5"),
                "r.csv: line 2: k_tri_e",
            ),
            (text.replace("0.25,", "x,"), "r.csv: line 2: loss = `x`"),
            (
                text.replace(",false", ""),
                "r.csv: line 3: 6 cells; expected 7",
            ),
        ] {
            let err = parse_replayed(&bad, "r.csv", &config)
                .unwrap_err()
                .to_string();
            assert!(err.starts_with(expected), "{expected}: {err}");
        }
    }

    #[test]
    fn a_folder_without_a_posterior_is_refused_naming_the_option() {
        let dir = tempfile::tempdir().unwrap();
        let config = config();
        let request = ValidationRequest {
            config: &config,
            config_path: Path::new("c.toml"),
            posterior: dir.path(),
            draws: 2,
            draws_option: "--validate",
            threshold: None,
        };
        let err = ValidationPlan::new(&request, Box::new(NoObserver))
            .err()
            .expect("refused")
            .to_string();
        assert!(
            err.contains(SUMMARY_FILE) && err.contains("; --validate needs the"),
            "{err}"
        );
        std::fs::write(dir.path().join(SUMMARY_FILE), "{\"epsilon_loss\": -1}").unwrap();
        let err = ValidationPlan::new(&request, Box::new(NoObserver))
            .err()
            .expect("refused")
            .to_string();
        assert!(
            err.contains("threshold -1 (the posterior's epsilon_loss)"),
            "{err}"
        );
    }

    struct NoObserver;

    impl Observer for NoObserver {}
}
