//! A calibration that returns the posterior: [`crate::smc`] over the config's box, every candidate
//! simulated on every recording with the labelled, phase-balanced likelihood
//! ([`rlpkg_replay::likelihood`]).
//!
//! Files in the output folder:
//! * `evaluations.csv`: every simulated candidate (parameters, `objective` = its log-likelihood,
//!   the loss, Chamfer, object and site errors), appended after each batch; a rerun into the
//!   folder serves the logged batches again and continues exactly where it stopped;
//! * `search.csv`: the mode search's generations (horizon, best and median log-likelihood, step
//!   size), a header only when the config has no `mode_search`;
//! * `stages.csv`: the tempering steps (inverse temperature, effective sample size, acceptance);
//! * `samples.csv`: the posterior draws ([`crate::posterior_files`], SI values);
//! * `posterior.toml`: per parameter the median, the 90 % credible interval, its share of the box
//!   and the best draw's value; the counts and the evidence;
//! * `best.toml`: the draw of highest likelihood, or the polished point when that is higher: with
//!   a mode search, `smc.polish_iterations` Levenberg–Marquardt steps ([`crate::polish`]) run from
//!   the search's best point before sampling, and the sampler starts from the Laplace
//!   approximation there (the Fisher information's inverse, [`crate::smc::sample_refined`]);
//!   without one, from the best draw after sampling ([`CalibratedParams`]);
//! * `fisher.toml`: the Fisher information at that draw ([`crate::fisher`]): which combinations
//!   of parameters the recordings pin down.
//!
//! The sampler's batches are simulated by a [`BatchEvaluator`]: [`sample_posterior`] on the
//! driver's own objective ([`SimBatches`]), [`sample_posterior_through`] by any other that gives
//! the same rows (Ray tasks through the Python calibration objective, `docs/python.md`). The
//! polish and the Fisher information always run on the driver's objective: they are a few
//! sequential rollouts, not batches worth sending away.

use std::cell::RefCell;
use std::path::{Path, PathBuf};

use serde::Serialize;

use rlpkg_replay::{Likelihood, LikelihoodSettings, ReplayError, RolloutOutcome};

use crate::cmaes::Generation;
use crate::driver::{write_atomically, write_toml, CalibratedParams, FitSummary};
use crate::evallog::{EvaluationLog, LogError, LoggedEvaluation};
use crate::fingerprint::{FingerprintError, OBJECTIVE_FILE};
use crate::fisher::{fisher_information, FisherAnalysis};
use crate::objective::{summarise, SimObjective};
use crate::polish::{polish, Polished};
use crate::posterior::quantile;
use crate::posterior_files::samples_csv;
use crate::smc::{self, Laplace, SmcError, SmcSettings, Stage};
use crate::space::ParamSpace;

/// The metric columns of a posterior's evaluation log, after `objective` (the log-likelihood).
/// `horizon_s` is the span of the recordings the row was scored on (a growing-horizon search's
/// shorter starts; the recordings' duration otherwise).
pub const POSTERIOR_METRICS: [&str; 5] = [
    "loss",
    "chamfer_m",
    "object_mse_m2",
    "site_mse_m2",
    "horizon_s",
];

/// The files a sampled posterior writes into its output folder.
pub const POSTERIOR_FILES: [&str; 8] = [
    OBJECTIVE_FILE,
    "evaluations.csv",
    "search.csv",
    "stages.csv",
    "samples.csv",
    "posterior.toml",
    "best.toml",
    "fisher.toml",
];

/// Every file a calibration folder may receive: the optimiser's ([`crate::driver::OUTPUT_FILES`]),
/// the sampled posterior's ([`POSTERIOR_FILES`]), its scene, corner plot and summary. None of them
/// may be one of the calibration's inputs ([`output_over_input`]).
pub fn folder_files() -> Vec<&'static str> {
    let mut names: Vec<&str> = crate::driver::OUTPUT_FILES.to_vec();
    names.extend(POSTERIOR_FILES);
    names.extend([
        "calibrated.toml",
        "corner.png",
        crate::posterior_files::SUMMARY_FILE,
    ]);
    names.sort_unstable();
    names.dedup();
    names
}

/// The first file a calibration into `out_dir` would write over one of its `inputs` (path, what
/// it is), as (the output, the input, what it is); `None` when there is none.
pub fn output_over_input<'a>(
    out_dir: &Path,
    inputs: &[(&'a Path, &'a str)],
) -> Option<(PathBuf, &'a Path, &'a str)> {
    rlpkg_files::output_over_input(out_dir, &folder_files(), inputs)
}

/// Finite-difference step (unit cube) of the Fisher analysis at the best draw: small against the
/// posterior's widths, large against the simulator's single-precision noise.
const FISHER_STEP: f64 = 1e-3;

/// Largest standard deviation (share of the box) of any direction of the Laplace reference that
/// starts the sampler: a sloppy direction the recordings hardly see is left to the sampler's
/// moves rather than spread over the whole box (assumption, not tuned).
const LAPLACE_MAX_SD: f64 = 0.1;

/// Errors of a sampled posterior.
#[derive(Debug, thiserror::Error)]
pub enum SampledPosteriorError {
    /// The evaluation log could not be read or written.
    #[error(transparent)]
    Log(#[from] LogError),
    /// The sampler failed.
    #[error(transparent)]
    Smc(#[from] SmcError),
    /// A logged batch does not hold the candidates this run asks for.
    #[error(
        "{path}: batch {batch} holds other candidates than this run asks for (written with other \
         sampler settings?); use --fresh to start over"
    )]
    LogMismatch {
        /// The log.
        path: PathBuf,
        /// The batch.
        batch: usize,
    },
    /// A file the calibration writes would replace one of its inputs.
    #[error(
        "{}: the calibration writes {} there, which is {}, {what}; expected another output folder",
        output.parent().unwrap_or(Path::new(".")).display(),
        output.display(),
        input.display()
    )]
    OutputOverInput {
        /// The output file.
        output: PathBuf,
        /// The input it would replace.
        input: PathBuf,
        /// What the input is to the calibration.
        what: String,
    },
    /// The batch evaluator gave rows that do not fit the batch.
    #[error("batch {batch}: {message}")]
    Evaluator {
        /// The batch.
        batch: usize,
        /// What went wrong.
        message: String,
    },
    /// The output folder holds the evaluations of another objective.
    #[error(transparent)]
    Fingerprint(#[from] FingerprintError),
    /// The output folder holds evaluations of an unrecorded objective.
    #[error(
        "{}: has an evaluations.csv but no objective.toml; use --fresh to start over or another --out",
        .0.display()
    )]
    Unrecorded(PathBuf),
    /// An output file could not be written.
    #[error("{0}")]
    Write(String),
}

/// Readies `out_dir` for a sampled posterior of the objective `record` (the text of its
/// [`crate::fingerprint::ObjectiveRecord`]): a folder where one of the calibration's `inputs`
/// (path, what it is) would be written over is refused before anything is touched; with `fresh`
/// the [`POSTERIOR_FILES`] there are removed; otherwise a folder whose log was made for another
/// objective, or for an unrecorded one, is refused, so that a rerun resumes only its own
/// evaluations. Removes the temporaries an interrupted write left (returned) and writes the record.
pub fn prepare_folder(
    out_dir: &Path,
    record: &str,
    fresh: bool,
    inputs: &[(&Path, &str)],
) -> Result<Vec<PathBuf>, SampledPosteriorError> {
    let fail = |path: &Path, e: std::io::Error| {
        SampledPosteriorError::Write(format!("{}: {e}", path.display()))
    };
    if let Some((output, input, what)) = output_over_input(out_dir, inputs) {
        return Err(SampledPosteriorError::OutputOverInput {
            output,
            input: input.to_path_buf(),
            what: what.to_string(),
        });
    }
    if fresh {
        for file in POSTERIOR_FILES {
            let path = out_dir.join(file);
            if path.exists() {
                std::fs::remove_file(&path).map_err(|e| fail(&path, e))?;
            }
        }
    } else if !crate::fingerprint::check(out_dir, record)?
        && out_dir.join("evaluations.csv").exists()
    {
        return Err(SampledPosteriorError::Unrecorded(out_dir.to_path_buf()));
    }
    let removed = crate::driver::clean_leftovers(out_dir, &POSTERIOR_FILES)
        .map_err(|e| SampledPosteriorError::Write(e.to_string()))?;
    std::fs::create_dir_all(out_dir).map_err(|e| fail(out_dir, e))?;
    write_atomically(&out_dir.join(OBJECTIVE_FILE), record.as_bytes())
        .map_err(|e| SampledPosteriorError::Write(e.to_string()))?;
    Ok(removed)
}

/// One candidate's row of a posterior's evaluation log: the log-likelihood (the log's
/// `objective` column) and the [`POSTERIOR_METRICS`], in that order.
#[derive(Debug, Clone, PartialEq)]
pub struct CandidateRow {
    /// `ln L` of the candidate on the batch's horizon (`−∞` or NaN: zero likelihood).
    pub log_likelihood: f64,
    /// The values of [`POSTERIOR_METRICS`].
    pub metrics: Vec<f64>,
}

/// Simulates the sampler's batches: one row per candidate, as the evaluation log holds it.
pub trait BatchEvaluator {
    /// The rows of `candidates` (SI values in the space's order), in their order, on the
    /// recordings' first `horizon` seconds (`None`: the whole recordings).
    fn evaluate(
        &mut self,
        horizon: Option<f64>,
        candidates: &[Vec<f64>],
    ) -> Result<Vec<CandidateRow>, String>;
}

/// The local [`BatchEvaluator`]: one batched rollout of the candidates on a [`SimObjective`],
/// scored with the labelled, phase-balanced likelihood.
pub struct SimBatches<'a> {
    objective: &'a mut SimObjective,
    likelihood: LikelihoodSettings,
}

impl<'a> SimBatches<'a> {
    /// Batches simulated on `objective` and scored with `likelihood`.
    pub fn new(objective: &'a mut SimObjective, likelihood: &LikelihoodSettings) -> Self {
        Self {
            objective,
            likelihood: *likelihood,
        }
    }
}

impl BatchEvaluator for SimBatches<'_> {
    fn evaluate(
        &mut self,
        horizon: Option<f64>,
        candidates: &[Vec<f64>],
    ) -> Result<Vec<CandidateRow>, String> {
        let objective = &mut *self.objective;
        let (outcomes, likelihood) = match horizon {
            None => (
                objective.rollouts(candidates),
                Likelihood::new(objective.targets(), &self.likelihood),
            ),
            Some(h) => {
                let outcomes = objective
                    .rollouts_within(h, candidates)
                    .ok_or_else(|| format!("no recording has a frame before {h} s"))?;
                let short = objective.targets_within(h).expect("rolled out above");
                (outcomes, Likelihood::new(short, &self.likelihood))
            }
        };
        let outcomes = outcomes.map_err(|e| e.to_string())?;
        let horizon_s = horizon.unwrap_or(objective.duration());
        Ok(outcomes
            .iter()
            .map(|outcome| candidate_row(outcome, &likelihood, objective, horizon_s))
            .collect())
    }
}

/// One parameter of the posterior.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ParameterInterval {
    /// Parameter name.
    pub name: String,
    /// 5 % quantile of the draws.
    pub lower_5: f64,
    /// Median of the draws.
    pub median: f64,
    /// 95 % quantile of the draws.
    pub upper_95: f64,
    /// Share of the search box the 90 % interval covers (in decades for log parameters).
    pub box_share: f64,
    /// The value of the draw of highest likelihood.
    pub best: f64,
}

/// The posterior a sampled calibration returns.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SampledPosterior {
    /// Per-parameter summary, in the search order.
    pub parameters: Vec<ParameterInterval>,
    /// Simulated candidates.
    pub evaluations: usize,
    /// Generations of the mode search (0 without one).
    pub search_generations: usize,
    /// Tempering steps.
    pub stages: usize,
    /// Log evidence `ln ∫ prior · L^η` (up to the likelihood's constant).
    pub log_evidence: f64,
    /// The likelihood's power `η` the sampler targeted (`smc.chaos_replays`; 1 without them).
    pub likelihood_power: f64,
    /// The log-likelihood's standard deviation over the replays of one material
    /// (`smc.chaos_replays`), whose inverse is `η`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub chaos_log_likelihood_sd: Option<f64>,
    /// The mode search's good points the chaos replays shared (`smc.chaos_points`; 0 without
    /// replays).
    pub chaos_points: usize,
    /// Independent residual coordinates of the package markers and of the object.
    pub independent_residuals: [f64; 2],
    /// Highest log-likelihood of the draws, or of the polished point when it is higher.
    pub best_log_likelihood: f64,
    /// Candidates simulated by the polish and its Fisher information (`smc.polish_iterations`).
    pub polished_evaluations: usize,
    /// The draws (SI values), in the search order.
    #[serde(skip)]
    pub draws: Vec<Vec<f64>>,
    /// The mode search's generations.
    #[serde(skip)]
    pub search_log: Vec<Generation>,
    /// The tempering steps.
    #[serde(skip)]
    pub stage_log: Vec<Stage>,
    /// The draw of highest likelihood with its metrics.
    #[serde(skip)]
    pub best: CalibratedParams,
    /// The Fisher information at the best draw.
    #[serde(skip)]
    pub fisher: FisherAnalysis,
}

/// Samples (or resumes) the posterior of `objective` over `space` and writes the files of the
/// module docs into `out_dir`. `on_batch(batch, evaluations)` is called after every batch.
pub fn sample_posterior(
    objective: &mut SimObjective,
    space: &ParamSpace,
    settings: &SmcSettings,
    likelihood: &LikelihoodSettings,
    out_dir: &Path,
    on_batch: impl FnMut(usize, usize),
) -> Result<SampledPosterior, SampledPosteriorError> {
    let settings_of_likelihood = *likelihood;
    sample_with(
        objective,
        |objective, _, horizon, candidates| {
            SimBatches::new(objective, &settings_of_likelihood).evaluate(horizon, candidates)
        },
        space,
        settings,
        likelihood,
        out_dir,
        on_batch,
    )
}

/// [`sample_posterior`] with the batches simulated by `batches` instead of `objective` (which
/// still runs the polish and the Fisher information). `batches` must give the rows `objective`
/// would ([`SimBatches`]): the log, the resume and the draws are then the same.
pub fn sample_posterior_through(
    objective: &mut SimObjective,
    batches: &mut dyn BatchEvaluator,
    space: &ParamSpace,
    settings: &SmcSettings,
    likelihood: &LikelihoodSettings,
    out_dir: &Path,
    on_batch: impl FnMut(usize, usize),
) -> Result<SampledPosterior, SampledPosteriorError> {
    sample_with(
        objective,
        |_, batch, horizon, candidates| {
            batches
                .evaluate(horizon, candidates)
                .map_err(|e| format!("batch {batch}: {e}"))
        },
        space,
        settings,
        likelihood,
        out_dir,
        on_batch,
    )
}

/// The sampler with `evaluate(objective, batch, horizon, candidates)` simulating the batches
/// that are not logged yet.
fn sample_with(
    objective: &mut SimObjective,
    mut evaluate: impl FnMut(
        &mut SimObjective,
        usize,
        Option<f64>,
        &[Vec<f64>],
    ) -> Result<Vec<CandidateRow>, String>,
    space: &ParamSpace,
    settings: &SmcSettings,
    likelihood: &LikelihoodSettings,
    out_dir: &Path,
    mut on_batch: impl FnMut(usize, usize),
) -> Result<SampledPosterior, SampledPosteriorError> {
    std::fs::create_dir_all(out_dir)
        .map_err(|e| SampledPosteriorError::Write(format!("{}: {e}", out_dir.display())))?;
    let settings_of_likelihood = *likelihood;
    let likelihood = Likelihood::new(objective.targets(), likelihood);
    let names = space.names();
    let bounds: Vec<(f64, f64)> = space.specs().iter().map(|s| (s.lower, s.upper)).collect();
    let log_path = out_dir.join("evaluations.csv");
    let (log, logged) = EvaluationLog::open(&log_path, &names, &POSTERIOR_METRICS, &bounds)?;
    let mut logged_batches: Vec<Vec<LoggedEvaluation>> = Vec::new();
    for row in logged {
        if row.batch == logged_batches.len() {
            logged_batches.push(Vec::new());
        }
        logged_batches[row.batch].push(row);
    }
    let mut evaluations = 0usize;
    let mut all: Vec<LoggedEvaluation> = Vec::new();
    let mut failure: Option<SampledPosteriorError> = None;
    let duration = objective.duration();
    // The sampler's batches and the refinement of its mode search both simulate; they take turns.
    let shared = RefCell::new(objective);
    // The refinement's polish, run before sampling (not logged: a resumed run repeats it, with
    // the same result).
    let mut refined: Option<(Polished, FisherAnalysis)> = None;
    let refine = |best: &[f64]| {
        if settings.polish_iterations == 0 {
            return Ok(None);
        }
        let objective = &mut **shared.borrow_mut();
        let start = space.from_unit(best);
        let (polished, fisher) =
            polish_with_information(objective, space, &settings_of_likelihood, &start, settings)
                .map_err(|e| e.to_string())?;
        // A diverged finite difference leaves no curvature to trust: the search's own reference.
        let laplace = fisher.information.iter().all(|v| v.is_finite()).then(|| {
            Laplace::from_information(
                space.to_unit(&polished.point),
                &fisher.information,
                LAPLACE_MAX_SD,
            )
        });
        refined = Some((polished, fisher));
        Ok(laplace)
    };
    let sampled = smc::sample_refined(
        space.dim(),
        settings,
        duration,
        |batch, horizon, unit| {
            let objective = &mut **shared.borrow_mut();
            let values: Vec<Vec<f64>> = unit.iter().map(|u| space.from_unit(u)).collect();
            let rows = match logged_batches.get(batch) {
                Some(rows) => {
                    let same = rows.len() == values.len()
                        && rows.iter().zip(&values).all(|(r, v)| &r.params == v);
                    if !same {
                        failure = Some(SampledPosteriorError::LogMismatch {
                            path: log_path.clone(),
                            batch,
                        });
                        return Err("the log does not match".into());
                    }
                    rows.clone()
                }
                None => {
                    let evaluated = evaluate(objective, batch, horizon, &values)?;
                    let horizon_s = horizon.unwrap_or(duration);
                    if let Err(message) = check_rows(&evaluated, values.len(), horizon_s) {
                        failure = Some(SampledPosteriorError::Evaluator { batch, message });
                        return Err("the batch's rows do not fit it".into());
                    }
                    let rows: Vec<LoggedEvaluation> = evaluated
                        .into_iter()
                        .zip(&values)
                        .enumerate()
                        .map(|(candidate, (row, params))| LoggedEvaluation {
                            batch,
                            candidate,
                            params: params.clone(),
                            objective: row.log_likelihood,
                            metrics: row.metrics,
                        })
                        .collect();
                    if let Err(e) = log.append(&rows) {
                        failure = Some(e.into());
                        return Err("the log could not be written".into());
                    }
                    rows
                }
            };
            evaluations += rows.len();
            on_batch(batch, evaluations);
            let ll = rows.iter().map(|r| r.objective).collect();
            all.extend(rows);
            Ok(ll)
        },
        refine,
    );
    let objective = shared.into_inner();
    let result = match (sampled, failure) {
        (_, Some(failure)) => return Err(failure),
        (result, None) => result?,
    };
    let draws: Vec<Vec<f64>> = result.draws.iter().map(|u| space.from_unit(u)).collect();
    let best_index = (0..draws.len())
        .max_by(|&a, &b| result.log_likelihoods[a].total_cmp(&result.log_likelihoods[b]))
        .expect("a population");
    let best_row = all
        .iter()
        .find(|r| r.params == draws[best_index] && r.metrics[4] == duration)
        .expect("every draw was evaluated");
    let mut best_point = draws[best_index].clone();
    let mut best_log_likelihood = result.log_likelihoods[best_index];
    let mut metrics = [
        best_row.metrics[0],
        best_row.metrics[1],
        best_row.metrics[2],
    ];
    let mut polished_evaluations = 0;
    let mut fisher_at_best = None;
    let polished = match refined {
        Some(found) => Some(found),
        None if settings.polish_iterations > 0 => Some(
            polish_with_information(
                objective,
                space,
                &settings_of_likelihood,
                &best_point,
                settings,
            )
            .map_err(|e| SampledPosteriorError::Smc(SmcError::Likelihood(e.to_string())))?,
        ),
        None => None,
    };
    if let Some((polished, fisher)) = polished {
        polished_evaluations = polished.evaluations + 1 + space.dim();
        if polished.log_likelihood > best_log_likelihood {
            let summary = summarise(&polished.outcome, objective.weights());
            metrics = [summary.loss, summary.chamfer_m, summary.object_mse_m2];
            best_point = polished.point;
            best_log_likelihood = polished.log_likelihood;
            fisher_at_best = Some(fisher);
        }
    }
    let best = CalibratedParams {
        params: names
            .iter()
            .map(|n| n.to_string())
            .zip(best_point.iter().copied())
            .collect(),
        fit: FitSummary {
            loss: metrics[0],
            chamfer_m: metrics[1],
            object_mse_m2: metrics[2],
            evaluations: all.len() + polished_evaluations,
        },
    };
    let parameters = intervals(space, &result.draws, &best_point);
    let fisher = match fisher_at_best {
        Some(fisher) => fisher,
        None => fisher_information(
            objective,
            space,
            &best_point,
            &settings_of_likelihood,
            FISHER_STEP,
        )
        .map_err(|e| SampledPosteriorError::Smc(SmcError::Likelihood(e.to_string())))?,
    };
    let posterior = SampledPosterior {
        parameters,
        evaluations: result.evaluations,
        search_generations: result.search.len(),
        stages: result.stages.len(),
        log_evidence: result.log_evidence,
        likelihood_power: result.likelihood_power,
        chaos_log_likelihood_sd: result.chaos_sd,
        chaos_points: result.chaos_points,
        independent_residuals: [likelihood.package_count, likelihood.object_count],
        best_log_likelihood,
        polished_evaluations,
        draws,
        search_log: result.search,
        stage_log: result.stages,
        best,
        fisher,
    };
    write_outputs(out_dir, space, &posterior)?;
    Ok(posterior)
}

/// `smc.polish_iterations` Levenberg–Marquardt steps from `start` (SI values), then the Fisher
/// information at the point they reach.
fn polish_with_information(
    objective: &mut SimObjective,
    space: &ParamSpace,
    likelihood: &LikelihoodSettings,
    start: &[f64],
    settings: &SmcSettings,
) -> Result<(Polished, FisherAnalysis), ReplayError> {
    let polished = polish(
        objective,
        space,
        likelihood,
        start,
        settings.polish_iterations,
    )?;
    let fisher = fisher_information(objective, space, &polished.point, likelihood, FISHER_STEP)?;
    Ok((polished, fisher))
}

/// The row of one candidate from its `outcome` on recordings `horizon_s` long.
fn candidate_row(
    outcome: &[RolloutOutcome],
    likelihood: &Likelihood,
    objective: &SimObjective,
    horizon_s: f64,
) -> CandidateRow {
    let summary = summarise(outcome, objective.weights());
    let n = outcome.len() as f64;
    let site = outcome
        .iter()
        .map(|o| o.loss.balanced_site_sq())
        .sum::<f64>()
        / n;
    CandidateRow {
        log_likelihood: likelihood.log_likelihood(outcome),
        metrics: vec![
            summary.loss,
            summary.chamfer_m,
            summary.object_mse_m2,
            site,
            horizon_s,
        ],
    }
}

/// Whether an evaluator's `rows` fit a batch of `candidates` scored on recordings `horizon_s`
/// long: one each, every metric present, the horizon that one (the best draw is found by it).
fn check_rows(rows: &[CandidateRow], candidates: usize, horizon_s: f64) -> Result<(), String> {
    if rows.len() != candidates {
        return Err(format!(
            "{} rows for {candidates} candidates; expected one per candidate",
            rows.len()
        ));
    }
    for (k, row) in rows.iter().enumerate() {
        if row.metrics.len() != POSTERIOR_METRICS.len() {
            return Err(format!(
                "candidate {k} has {} metrics; expected {} ({})",
                row.metrics.len(),
                POSTERIOR_METRICS.len(),
                POSTERIOR_METRICS.join(", ")
            ));
        }
        let scored = row.metrics[POSTERIOR_METRICS.len() - 1];
        if scored != horizon_s {
            return Err(format!(
                "candidate {k} has horizon_s = {scored}; expected {horizon_s} (the batch's horizon)"
            ));
        }
    }
    Ok(())
}

/// Median, 90 % interval and box share of each coordinate of `unit_draws`.
fn intervals(space: &ParamSpace, unit_draws: &[Vec<f64>], best: &[f64]) -> Vec<ParameterInterval> {
    space
        .specs()
        .iter()
        .enumerate()
        .map(|(i, spec)| {
            let mut u: Vec<f64> = unit_draws.iter().map(|d| d[i]).collect();
            u.sort_by(f64::total_cmp);
            let at = |q: f64| {
                let mut point = vec![0.5; space.dim()];
                point[i] = quantile(&u, q);
                space.from_unit(&point)[i]
            };
            ParameterInterval {
                name: spec.name.clone(),
                lower_5: at(0.05),
                median: at(0.5),
                upper_95: at(0.95),
                box_share: quantile(&u, 0.95) - quantile(&u, 0.05),
                best: best[i],
            }
        })
        .collect()
}

fn write_outputs(
    out_dir: &Path,
    space: &ParamSpace,
    posterior: &SampledPosterior,
) -> Result<(), SampledPosteriorError> {
    let fail = |e: crate::driver::DriverError| SampledPosteriorError::Write(e.to_string());
    let mut search = String::from(
        "generation,evaluations,horizon_s,best_log_likelihood,median_log_likelihood,step\n",
    );
    for (k, g) in posterior.search_log.iter().enumerate() {
        // The whole recordings' horizon is left empty.
        let horizon = g.horizon_s.map_or(String::new(), |h| h.to_string());
        search.push_str(&format!(
            "{k},{},{horizon},{},{},{}\n",
            g.evaluations, g.best_log_likelihood, g.median_log_likelihood, g.step
        ));
    }
    write_atomically(&out_dir.join("search.csv"), search.as_bytes()).map_err(fail)?;
    let mut stages =
        String::from("stage,beta,ess,acceptance,scale,evaluations,best_log_likelihood\n");
    for (k, s) in posterior.stage_log.iter().enumerate() {
        stages.push_str(&format!(
            "{k},{},{},{},{},{},{}\n",
            s.beta, s.ess, s.acceptance, s.scale, s.evaluations, s.best_log_likelihood
        ));
    }
    write_atomically(&out_dir.join("stages.csv"), stages.as_bytes()).map_err(fail)?;
    write_atomically(
        &out_dir.join("samples.csv"),
        samples_csv(space, &posterior.draws).as_bytes(),
    )
    .map_err(fail)?;
    write_toml(&out_dir.join("posterior.toml"), posterior).map_err(fail)?;
    write_toml(&out_dir.join("fisher.toml"), &posterior.fisher).map_err(fail)?;
    write_toml(&out_dir.join("best.toml"), &posterior.best).map_err(fail)
}

/// The posterior's table: one line per parameter.
pub fn posterior_table(posterior: &SampledPosterior) -> String {
    let mut text = format!(
        "{:<16} {:>12} {:>12} {:>12} {:>12} {:>9}\n",
        "parameter", "5 %", "median", "95 %", "best", "box share"
    );
    for p in &posterior.parameters {
        text.push_str(&format!(
            "{:<16} {:>12.4e} {:>12.4e} {:>12.4e} {:>12.4e} {:>8.1} %\n",
            p.name,
            p.lower_5,
            p.median,
            p.upper_95,
            p.best,
            100.0 * p.box_share
        ));
    }
    if let Some(sd) = posterior.chaos_log_likelihood_sd {
        let whose = match posterior.chaos_points {
            1 => "one material's replays".to_string(),
            k => format!("each of {k} good materials' replays"),
        };
        let pooled = if posterior.chaos_points > 1 {
            "pooled "
        } else {
            ""
        };
        text.push_str(&format!(
            "sampled prior x L^{:.4}: {whose}, nudged by {:e} of the box, differ by a \
             {pooled}log-likelihood sd of {sd:.2}\n",
            posterior.likelihood_power,
            crate::smc::CHAOS_NUDGE
        ));
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cmaes::ModeSearchSettings;
    use crate::space::ParamSpec;
    use rlpkg_replay::loss::{LossKind, LossWeights};
    use rlpkg_replay::{load_scene, Target};

    /// The first 0.05 s of HHHHH on the physical scene's 6 x 7 grid after a 0.1 s rest, fitted
    /// by the membrane's stiffness (a fraction of a second of CPU per batch).
    fn small_objective() -> SimObjective {
        let mut scene = load_scene("physical", Some(0), None).unwrap();
        scene.cups.rest_time_s = 0.1;
        // The disc may slip through the 6 x 7 sheet; these tests are about the batches.
        scene.health.object_outside = false;
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/deformable-sim-real");
        let recorded = rlpkg_mocap::Dataset::open(&root)
            .unwrap()
            .load("HHHHH")
            .unwrap();
        let target = Target::new(&recorded, Some(0.05), false).unwrap();
        let weights = LossWeights {
            object: 1.0,
            package: 1.0,
            kind: LossKind::Labelled,
        };
        SimObjective::from_targets(&scene, vec!["k_tri_e".into()], vec![target], weights).unwrap()
    }

    fn space() -> ParamSpace {
        ParamSpace::new(vec![ParamSpec {
            name: "k_tri_e".into(),
            lower: 1.0e3,
            upper: 1.0e5,
            log: true,
        }])
        .unwrap()
    }

    /// Four particles after a growing-horizon search (0.025 s, then the whole 0.05 s).
    fn settings() -> SmcSettings {
        SmcSettings {
            particles: 4,
            ess_fraction: 0.5,
            moves: 1,
            final_moves: 1,
            max_stages: 20,
            seed: 5,
            mode_search: Some(ModeSearchSettings {
                population: 4,
                generations: 1,
                initial_step: 0.3,
                reference_scale: 2.0,
                first_horizon_s: Some(0.025),
            }),
            polish_iterations: 0,
            chaos_replays: 2,
            chaos_points: 1,
            prior_share: 0.0,
        }
    }

    /// Simulates each batch on its own objective one candidate at a time, as remote workers
    /// given one chunk each would; counts the horizons it was asked for.
    struct OneAtATime {
        objective: SimObjective,
        likelihood: LikelihoodSettings,
        horizons: Vec<Option<f64>>,
    }

    impl BatchEvaluator for OneAtATime {
        fn evaluate(
            &mut self,
            horizon: Option<f64>,
            candidates: &[Vec<f64>],
        ) -> Result<Vec<CandidateRow>, String> {
            self.horizons.push(horizon);
            let mut rows = Vec::new();
            for candidate in candidates {
                let mut local = SimBatches::new(&mut self.objective, &self.likelihood);
                rows.extend(local.evaluate(horizon, std::slice::from_ref(candidate))?);
            }
            Ok(rows)
        }
    }

    #[test]
    fn batches_through_another_evaluator_give_the_same_files() {
        let likelihood = LikelihoodSettings::default();
        let local_dir = tempfile::tempdir().unwrap();
        let local = sample_posterior(
            &mut small_objective(),
            &space(),
            &settings(),
            &likelihood,
            local_dir.path(),
            |_, _| {},
        )
        .unwrap();
        let mut remote = OneAtATime {
            objective: small_objective(),
            likelihood,
            horizons: Vec::new(),
        };
        let through_dir = tempfile::tempdir().unwrap();
        let through = sample_posterior_through(
            &mut small_objective(),
            &mut remote,
            &space(),
            &settings(),
            &likelihood,
            through_dir.path(),
            |_, _| {},
        )
        .unwrap();
        assert_eq!(
            (&local.draws, local.evaluations),
            (&through.draws, through.evaluations)
        );
        // The search's short start went through the evaluator too.
        assert_eq!(remote.horizons[0], Some(0.025));
        assert!(remote.horizons[1..].iter().all(Option::is_none));
        for file in POSTERIOR_FILES.iter().filter(|f| **f != OBJECTIVE_FILE) {
            let read = |dir: &Path| std::fs::read(dir.join(file)).unwrap();
            assert_eq!(read(local_dir.path()), read(through_dir.path()), "{file}");
        }
        let log = std::fs::read_to_string(local_dir.path().join("evaluations.csv")).unwrap();
        assert_eq!(log.lines().count(), 1 + local.evaluations, "{log}");
        assert!(log.contains(",0.025\n") && log.contains(",0.05\n"), "{log}");
    }

    /// What an evaluator gets wrong.
    #[derive(Clone, Copy)]
    enum Fault {
        Fails,
        DropsARow,
        WrongHorizon,
    }

    impl BatchEvaluator for Fault {
        fn evaluate(
            &mut self,
            horizon: Option<f64>,
            candidates: &[Vec<f64>],
        ) -> Result<Vec<CandidateRow>, String> {
            let row = |horizon_s: f64| CandidateRow {
                log_likelihood: 0.0,
                metrics: vec![0.0, 0.0, 0.0, 0.0, horizon_s],
            };
            match self {
                Fault::Fails => Err("the workers are gone".into()),
                Fault::DropsARow => Ok(vec![row(horizon.unwrap()); candidates.len() - 1]),
                Fault::WrongHorizon => Ok(vec![row(0.05); candidates.len()]),
            }
        }
    }

    #[test]
    fn an_evaluator_that_fails_or_gives_rows_that_do_not_fit_is_an_error_naming_the_batch() {
        let likelihood = LikelihoodSettings::default();
        let dir = tempfile::tempdir().unwrap();
        let run = |mut fault: Fault| {
            sample_posterior_through(
                &mut small_objective(),
                &mut fault,
                &space(),
                &settings(),
                &likelihood,
                dir.path(),
                |_, _| {},
            )
            .unwrap_err()
            .to_string()
        };
        assert_eq!(
            run(Fault::DropsARow),
            "batch 0: 3 rows for 4 candidates; expected one per candidate"
        );
        // The search's first batch scores the first 0.025 s.
        assert_eq!(
            run(Fault::WrongHorizon),
            "batch 0: candidate 0 has horizon_s = 0.05; expected 0.025 (the batch's horizon)"
        );
        // Nothing of the batch was logged.
        let log = std::fs::read_to_string(dir.path().join("evaluations.csv")).unwrap();
        assert_eq!(log.lines().count(), 1, "{log}");
        assert_eq!(
            run(Fault::Fails),
            "likelihood: batch 0: the workers are gone",
            "the evaluator's own error"
        );
    }

    #[test]
    fn a_folder_resumes_only_its_own_objective() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("posterior");
        assert!(prepare_folder(&out, "a = 1\n", false, &[])
            .unwrap()
            .is_empty());
        std::fs::write(out.join("evaluations.csv"), "batch\n").unwrap();
        let leftover = out.join(".samples.csv.a1B2c3");
        std::fs::write(&leftover, "").unwrap();
        assert_eq!(
            prepare_folder(&out, "a = 1\n", false, &[]).unwrap(),
            [leftover]
        );
        let other = prepare_folder(&out, "a = 2\n", false, &[])
            .unwrap_err()
            .to_string();
        assert!(
            other.contains("line 1") && other.contains("`a = 1`"),
            "{other}"
        );
        std::fs::remove_file(out.join(OBJECTIVE_FILE)).unwrap();
        let unrecorded = prepare_folder(&out, "a = 2\n", false, &[])
            .unwrap_err()
            .to_string();
        assert!(unrecorded.contains("no objective.toml"), "{unrecorded}");
        prepare_folder(&out, "a = 2\n", true, &[]).unwrap();
        assert!(!out.join("evaluations.csv").exists());
        assert_eq!(
            std::fs::read_to_string(out.join(OBJECTIVE_FILE)).unwrap(),
            "a = 2\n"
        );
    }

    #[test]
    fn a_folder_whose_outputs_are_the_calibration_s_inputs_is_refused_untouched() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["posterior.toml", OBJECTIVE_FILE, "summary.json"] {
            let config = dir.path().join(name);
            std::fs::write(&config, "the config").unwrap();
            for fresh in [false, true] {
                let err = prepare_folder(dir.path(), "a = 1\n", fresh, &[(&config, "the config")])
                    .unwrap_err();
                assert!(
                    matches!(err, SampledPosteriorError::OutputOverInput { .. }),
                    "{err}"
                );
                assert!(err.to_string().contains(name), "{err}");
                assert_eq!(std::fs::read_to_string(&config).unwrap(), "the config");
            }
            std::fs::remove_file(&config).unwrap();
        }
        // A config beside the outputs under another name is no output.
        let config = dir.path().join("posterior-job.toml");
        std::fs::write(&config, "the config").unwrap();
        prepare_folder(dir.path(), "a = 1\n", false, &[(&config, "the config")]).unwrap();
    }
}
