//! The calibration loop: ask a batch, evaluate it with a [`BatchObjective`], log, tell, repeat.
//!
//! Files in the output folder:
//! * `evaluations.csv`: every evaluation (parameters, objective, loss and its two terms), appended
//!   after each batch; a rerun with the same folder replays it and continues (resume);
//! * `progress.csv`: one row per batch (best loss so far, best of the batch), rewritten atomically;
//! * `best.toml`: the best parameters so far ([`CalibratedParams`]), rewritten atomically.
//!
//! The optimiser models `ln(loss)`: the loss is positive and spans decades between good and bad
//! candidates, and the log keeps one bad region from flattening the surrogate everywhere else.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::bo::{BayesOpt, BoError, BoSettings};
use crate::evallog::{EvaluationLog, LogError, LoggedEvaluation};
use crate::space::ParamSpace;

/// The metric columns of the evaluation log, after `objective`.
pub const METRIC_NAMES: [&str; 3] = ["loss", "chamfer_m", "object_mse_m2"];

/// The result of simulating one candidate on every training trajectory.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CandidateResult {
    /// Weighted loss, mean over trajectories (non-finite when a rollout diverged).
    pub loss: f64,
    /// Mean package Chamfer distance per frame (m).
    pub chamfer_m: f64,
    /// Mean object squared error per frame (m²).
    pub object_mse_m2: f64,
}

/// Evaluates a batch of candidates (parameter values in the space's order) in one go.
pub trait BatchObjective {
    /// Evaluates every candidate; returns one result per candidate, in order.
    fn evaluate(&mut self, candidates: &[Vec<f64>]) -> Result<Vec<CandidateResult>, String>;
}

/// Errors of the calibration loop.
#[derive(Debug, thiserror::Error)]
pub enum DriverError {
    /// The evaluation log could not be read or written.
    #[error(transparent)]
    Log(#[from] LogError),
    /// The optimiser failed.
    #[error(transparent)]
    Bo(#[from] BoError),
    /// The objective failed.
    #[error("objective: {0}")]
    Objective(String),
    /// An output file could not be written.
    #[error("{path}: {message}")]
    Write {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
}

/// Best parameters found, as written to `best.toml` (and shipped as `configs/scenes/calibrated-study.toml`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibratedParams {
    /// Parameter values by name (SI units).
    pub params: BTreeMap<String, f64>,
    /// How they were obtained.
    pub fit: FitSummary,
}

/// Provenance of calibrated parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FitSummary {
    /// Weighted training loss of the best candidate.
    pub loss: f64,
    /// Its mean package Chamfer distance per frame (m).
    pub chamfer_m: f64,
    /// Its mean object squared error per frame (m²).
    pub object_mse_m2: f64,
    /// Evaluations so far.
    pub evaluations: usize,
}

/// What happened in one batch, for progress display.
#[derive(Debug, Clone, PartialEq)]
pub struct BatchReport {
    /// Batch index (0-based, continues across resumes).
    pub batch: usize,
    /// Batches of this run's plan (initial design + iterations).
    pub planned_batches: usize,
    /// Evaluations so far.
    pub evaluations: usize,
    /// Best loss of this batch.
    pub batch_best_loss: f64,
    /// Best loss so far.
    pub best_loss: f64,
}

/// The calibration plan.
#[derive(Debug, Clone)]
pub struct Plan {
    /// The search space.
    pub space: ParamSpace,
    /// Optimiser settings.
    pub settings: BoSettings,
    /// Points evaluated before the Latin hypercube (e.g. the preset's values).
    pub seed_points: Vec<Vec<f64>>,
    /// Batches after the initial design.
    pub iterations: usize,
    /// Output folder.
    pub out_dir: PathBuf,
}

impl Plan {
    /// Total number of batches: the initial design in batches, then the iterations.
    pub fn planned_batches(&self) -> usize {
        let initial = self.seed_points.len() + self.settings.initial_points;
        initial.div_ceil(self.settings.batch_size.max(1)) + self.iterations
    }
}

/// Runs (or resumes) a calibration; returns the best parameters.
pub fn run(
    plan: &Plan,
    objective: &mut impl BatchObjective,
    mut on_batch: impl FnMut(&BatchReport),
) -> Result<CalibratedParams, DriverError> {
    std::fs::create_dir_all(&plan.out_dir).map_err(|e| DriverError::Write {
        path: plan.out_dir.clone(),
        message: e.to_string(),
    })?;
    let names = plan.space.names();
    let bounds: Vec<(f64, f64)> = plan
        .space
        .specs()
        .iter()
        .map(|s| (s.lower, s.upper))
        .collect();
    let log_path = plan.out_dir.join("evaluations.csv");
    let (log, previous) = EvaluationLog::open(&log_path, &names, &METRIC_NAMES, &bounds)?;
    for row in &previous {
        check_objective(&log_path, row)?;
    }
    let mut bo = BayesOpt::new(plan.space.clone(), plan.settings.clone())
        .with_seed_points(plan.seed_points.clone());
    let mut rows = Vec::with_capacity(previous.len());
    for row in previous {
        bo.tell(row.params.clone(), row.objective)?;
        rows.push(row);
    }
    let mut batch = rows.last().map_or(0, |r| r.batch + 1);
    let planned = plan.planned_batches();
    while batch < planned {
        let candidates = bo.ask()?;
        let results = objective
            .evaluate(&candidates)
            .map_err(DriverError::Objective)?;
        if results.len() != candidates.len() {
            return Err(DriverError::Objective(format!(
                "{} results for {} candidates",
                results.len(),
                candidates.len()
            )));
        }
        let new_rows: Vec<LoggedEvaluation> = candidates
            .into_iter()
            .zip(&results)
            .enumerate()
            .map(|(candidate, (params, r))| LoggedEvaluation {
                batch,
                candidate,
                params,
                objective: objective_value(r.loss),
                metrics: vec![r.loss, r.chamfer_m, r.object_mse_m2],
            })
            .collect();
        log.append(&new_rows)?;
        for row in &new_rows {
            bo.tell(row.params.clone(), row.objective)?;
        }
        rows.extend(new_rows);
        write_progress(&plan.out_dir.join("progress.csv"), &rows)?;
        let best = best_params(&names, &rows);
        if let Some(best) = &best {
            write_toml(&plan.out_dir.join("best.toml"), best)?;
        }
        on_batch(&BatchReport {
            batch,
            planned_batches: planned,
            evaluations: rows.len(),
            batch_best_loss: results
                .iter()
                .map(|r| r.loss)
                .filter(|l| l.is_finite())
                .fold(f64::INFINITY, f64::min),
            best_loss: best.map_or(f64::INFINITY, |b| b.fit.loss),
        });
        batch += 1;
    }
    best_params(&names, &rows).ok_or(DriverError::Bo(BoError::NoFiniteObservation))
}

/// A logged row's objective must be the one [`objective_value`] gives for its loss: anything else
/// was not written by this driver and would feed the optimiser a wrong observation.
fn check_objective(path: &Path, row: &LoggedEvaluation) -> Result<(), DriverError> {
    let expected = objective_value(row.metrics[0]);
    let agrees = if expected.is_nan() {
        row.objective.is_nan()
    } else {
        (row.objective - expected).abs() <= 1e-12 * expected.abs().max(1.0)
    };
    if agrees {
        return Ok(());
    }
    Err(DriverError::Log(LogError::Inconsistent {
        path: path.to_path_buf(),
        batch: row.batch,
        candidate: row.candidate,
        message: format!(
            "`objective` = {} but ln(`loss`) = {expected}; this log was not written by `rlpkg calibrate`",
            row.objective
        ),
    }))
}

/// What the optimiser models: `ln(loss)`, NaN for a failed or non-positive loss.
fn objective_value(loss: f64) -> f64 {
    if loss.is_finite() && loss > 0.0 {
        loss.ln()
    } else {
        f64::NAN
    }
}

/// The best finite row as calibrated parameters.
fn best_params(names: &[&str], rows: &[LoggedEvaluation]) -> Option<CalibratedParams> {
    let best = rows
        .iter()
        .filter(|r| r.metrics[0].is_finite())
        .min_by(|a, b| a.metrics[0].total_cmp(&b.metrics[0]))?;
    Some(CalibratedParams {
        params: names
            .iter()
            .zip(&best.params)
            .map(|(n, v)| (n.to_string(), *v))
            .collect(),
        fit: FitSummary {
            loss: best.metrics[0],
            chamfer_m: best.metrics[1],
            object_mse_m2: best.metrics[2],
            evaluations: rows.len(),
        },
    })
}

/// Writes `progress.csv`: per batch, its best loss and the best loss so far.
fn write_progress(path: &Path, rows: &[LoggedEvaluation]) -> Result<(), DriverError> {
    let mut text = String::from("batch,evaluations,batch_best_loss,best_loss\n");
    let mut best = f64::INFINITY;
    let last_batch = rows.last().map_or(0, |r| r.batch);
    for batch in 0..=last_batch {
        let in_batch: Vec<f64> = rows
            .iter()
            .filter(|r| r.batch == batch)
            .map(|r| r.metrics[0])
            .collect();
        if in_batch.is_empty() {
            continue;
        }
        let batch_best = in_batch
            .iter()
            .copied()
            .filter(|l| l.is_finite())
            .fold(f64::INFINITY, f64::min);
        best = best.min(batch_best);
        let evaluations = rows.iter().filter(|r| r.batch <= batch).count();
        text.push_str(&format!("{batch},{evaluations},{batch_best},{best}\n"));
    }
    write_atomically(path, text.as_bytes())
}

/// Serialises `value` as TOML and writes it atomically.
pub fn write_toml(path: &Path, value: &impl Serialize) -> Result<(), DriverError> {
    let text = toml::to_string_pretty(value).map_err(|e| DriverError::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    write_atomically(path, text.as_bytes())
}

/// The files a calibration writes into its output folder.
pub const OUTPUT_FILES: [&str; 4] = [
    "evaluations.csv",
    "progress.csv",
    "best.toml",
    "calibrated.toml",
];

/// Removes from `dir` the temporary files that [`write_atomically`] leaves when the process is
/// stopped at once (a second Ctrl-C, a kill) while writing one of `files`
/// ([`rlpkg_files::is_temporary_of`]). Returns what it removed.
pub fn clean_leftovers(dir: &Path, files: &[&str]) -> Result<Vec<PathBuf>, DriverError> {
    let fail = |path: &Path, e: std::io::Error| DriverError::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let entries = match std::fs::read_dir(dir) {
        Ok(entries) => entries,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(fail(dir, e)),
    };
    let mut removed = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| fail(dir, e))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        let temporary = files
            .iter()
            .any(|file| rlpkg_files::is_temporary_of(&name, file));
        if temporary {
            let path = entry.path();
            std::fs::remove_file(&path).map_err(|e| fail(&path, e))?;
            removed.push(path);
        }
    }
    Ok(removed)
}

/// Writes `bytes` to `path` atomically ([`rlpkg_files::write_atomic`]).
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), DriverError> {
    rlpkg_files::write_atomic(path, bytes).map_err(|e| DriverError::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::space::ParamSpec;

    /// A quadratic bowl in log-space with its minimum at (1e4, 0.3); NaN beyond k = 1e6 (a
    /// "diverged rollout"). Counts its calls.
    struct Bowl {
        calls: usize,
    }

    impl BatchObjective for Bowl {
        fn evaluate(&mut self, candidates: &[Vec<f64>]) -> Result<Vec<CandidateResult>, String> {
            self.calls += candidates.len();
            Ok(candidates
                .iter()
                .map(|p| {
                    let a = (p[0].log10() - 4.0) / 2.0;
                    let b = p[1] - 0.3;
                    let loss = if p[0] > 1e6 {
                        f64::NAN
                    } else {
                        0.01 + a * a + b * b
                    };
                    CandidateResult {
                        loss,
                        chamfer_m: loss / 2.0,
                        object_mse_m2: loss / 4.0,
                    }
                })
                .collect())
        }
    }

    fn plan(dir: &Path, iterations: usize) -> Plan {
        Plan {
            space: ParamSpace::new(vec![
                ParamSpec {
                    name: "k_tri_e".into(),
                    lower: 1e2,
                    upper: 1e7,
                    log: true,
                },
                ParamSpec {
                    name: "mu_con".into(),
                    lower: 0.0,
                    upper: 1.0,
                    log: false,
                },
            ])
            .unwrap(),
            settings: BoSettings {
                initial_points: 5,
                batch_size: 3,
                random_candidates: 300,
                seed: 4,
                ..BoSettings::default()
            },
            seed_points: vec![vec![1e5, 0.5]],
            iterations,
            out_dir: dir.to_path_buf(),
        }
    }

    #[test]
    fn finds_the_bowl_minimum_writes_files_and_resumes_identically() {
        let dir = tempfile::tempdir().unwrap();
        // Uninterrupted: 2 initial batches + 6 iterations.
        let full_dir = dir.path().join("full");
        let mut bowl = Bowl { calls: 0 };
        let mut reports = Vec::new();
        let best = run(&plan(&full_dir, 6), &mut bowl, |r| reports.push(r.clone())).unwrap();
        assert_eq!(bowl.calls, 6 + 6 * 3);
        assert_eq!(reports.len(), 8);
        assert!(best.fit.loss < 0.03, "best loss {}", best.fit.loss);
        assert!(
            (best.params["k_tri_e"].log10() - 4.0).abs() < 0.4,
            "{best:?}"
        );
        let on_disk: CalibratedParams =
            toml::from_str(&std::fs::read_to_string(full_dir.join("best.toml")).unwrap()).unwrap();
        assert_eq!(on_disk, best);
        let progress = std::fs::read_to_string(full_dir.join("progress.csv")).unwrap();
        assert_eq!(progress.lines().count(), 1 + 8);

        // Interrupted after 3 batches, then resumed: same evaluations, same result.
        let split_dir = dir.path().join("split");
        let mut first = Bowl { calls: 0 };
        run(&plan(&split_dir, 1), &mut first, |_| {}).unwrap();
        let mut second = Bowl { calls: 0 };
        let resumed = run(&plan(&split_dir, 6), &mut second, |_| {}).unwrap();
        assert_eq!(
            second.calls,
            5 * 3,
            "only the missing batches are evaluated"
        );
        assert_eq!(resumed, best);
        assert_eq!(
            std::fs::read_to_string(split_dir.join("evaluations.csv")).unwrap(),
            std::fs::read_to_string(full_dir.join("evaluations.csv")).unwrap()
        );
    }

    #[test]
    fn resume_rejects_an_edited_objective() {
        let dir = tempfile::tempdir().unwrap();
        let mut bowl = Bowl { calls: 0 };
        run(&plan(dir.path(), 1), &mut bowl, |_| {}).unwrap();
        let path = dir.path().join("evaluations.csv");
        let text = std::fs::read_to_string(&path).unwrap();
        let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
        let mut cells: Vec<String> = lines[2].split(',').map(str::to_string).collect();
        cells[4] = "-100".into();
        lines[2] = cells.join(",");
        std::fs::write(&path, lines.join("\n") + "\n").unwrap();
        let err = run(&plan(dir.path(), 2), &mut bowl, |_| {})
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("batch 0 candidate 1") && err.contains("`objective` = -100"),
            "{err}"
        );
    }

    #[test]
    fn objective_is_log_loss_and_failures_are_nan() {
        assert!((objective_value(std::f64::consts::E) - 1.0).abs() < 1e-12);
        assert!(objective_value(f64::NAN).is_nan());
        assert!(objective_value(0.0).is_nan());
        assert_eq!(plan(Path::new("."), 2).planned_batches(), 2 + 2);
    }
}
