//! An approximate posterior over the calibrated parameters, from a calibration's evaluations:
//! BOLFI (Gutmann & Corander 2016, "Bayesian optimization for likelihood-free inference").
//!
//! A calibration returns one point, but the recordings may not pin it down: very different
//! parameters can fit them about equally well. This module turns the evaluations the optimiser
//! already made into a distribution over the parameters, without new simulations:
//!
//! * **Surrogate**: the [`GaussianProcess`] of the optimiser, fitted to the discrepancy
//!   `d = ln(loss)` of the finite evaluations in the unit cube of the [`ParamSpace`] (log units for
//!   log parameters).
//! * **Likelihood**: `L(θ) = P(d(θ) < ε) = Φ((ε − μ(θ)) / √(σ²(θ) + σ_n²))`, with the surrogate's mean
//!   `μ`, its variance `σ²` and the learned noise variance `σ_n²`. Where the surrogate has seen no data
//!   `σ` is large and `L` stays moderate: the posterior keeps mass where the calibration never looked
//!   rather than ruling it out.
//! * **Failed evaluations** (diverged rollouts) have no loss. A second Gaussian process, fitted to the
//!   failure indicator (1 failed, 0 finite) of every evaluation, gives the probability of success
//!   `1 − m(θ)` (its mean, clamped to [0, 1]: least-squares classification, Rasmussen & Williams
//!   §6.5), and the likelihood is `P(success) · P(d < ε)`. Its own length scales learn which
//!   parameters make the simulator diverge. Why not the optimiser's "worst finite value": that only
//!   has to steer a search away, but here a failure among good points is a cliff the loss surrogate
//!   cannot follow, so it raises the learned noise, shortens the length scales everywhere and blurs
//!   the whole posterior.
//! * **Threshold ε** ([`Threshold`]), by default the 0.1-quantile of the observed `ln(loss)`: "as good
//!   as the best tenth of what the calibration tried". Why a quantile rather than `min + k σ_n`: the
//!   simulator is deterministic (the same parameters give the same loss), so the learned noise may
//!   sit near its lower bound, and `min + k σ_n` would make `L` the indicator of the single best
//!   point, hiding exactly the trade-offs the posterior is for; a quantile is free of units and of
//!   the noise estimate. The optimiser's samples crowd around its optimum, so the tenth is tighter
//!   than it would be for a uniform design; [`Threshold::Loss`] sets an absolute tolerance instead
//!   (e.g. 1.1 x the best loss: "within 10 %").
//! * **Prior**: uniform over the calibration box in the unit cube, that is log-uniform for log
//!   parameters and uniform for linear ones.
//! * **Sampler**: the affine-invariant ensemble sampler of [`crate::mcmc`] in the unit cube, started
//!   from prior and evaluated points resampled by likelihood; deterministic for a seed, independent of
//!   the thread count.
//!
//! Per parameter: the median and the 90 % credible interval (5 % and 95 % quantiles; their ratio in
//! decades for log parameters), the share of the prior range the interval covers, and **identified**
//! when it covers less than half and the loss profile rises by at least 10 % over the range
//! ([`IDENTIFIED_RULE`]; a flat posterior covers 0.9). The
//! **profile** of the surrogate loss along a grid over the box (log-spaced for log parameters): at
//! every grid value, the lowest surrogate loss `exp(μ)` among posterior draws with that parameter
//! set to the value. A flat profile means the loss does not tell the values apart; its curvature at
//! the minimum (per decade² for log parameters) says how sharp the optimum is.

use std::path::{Path, PathBuf};

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

mod summary;
mod surrogate;

pub use summary::{profiles_csv, quantile};
pub use surrogate::log_normal_cdf;

use summary::{profiles, summarise};
use surrogate::{starting_walkers, Surrogate};

use crate::driver::METRIC_NAMES;
use crate::evallog::{EvaluationLog, LogError};
use crate::gp::{FitOptions, GaussianProcess, GpError};
use crate::mcmc::{self, EnsembleSettings, McmcError};
use crate::space::ParamSpace;

/// How a parameter is called identified, as printed with the table.
pub const IDENTIFIED_RULE: &str =
    "identified: the 90 % credible interval covers less than half of the \
     search range (in decades for log parameters) and the loss profile rises by at least 10 % from \
     its lowest value over the range";

/// Share of the prior range below which a parameter's 90 % interval counts as narrow.
const IDENTIFIED_FRACTION: f64 = 0.5;

/// Highest over lowest profile loss from which the loss is taken to depend on a parameter: with a
/// flat profile a narrow interval comes from the surrogate, not from the recordings.
const PROFILE_RISE: f64 = 1.1;

/// Errors of the posterior.
#[derive(Debug, thiserror::Error)]
pub enum PosteriorError {
    /// The evaluation log does not exist.
    #[error("{0}: not found; expected the `evaluations.csv` that `rlpkg calibrate` writes in its output folder")]
    Missing(PathBuf),
    /// The evaluation log is malformed or was written for another parameter box.
    #[error(transparent)]
    Log(#[from] LogError),
    /// Too few finite evaluations to fit the surrogate.
    #[error(
        "{finite} evaluation(s) with a finite loss; expected at least {needed} for {dim} \
         parameter(s) (3 per parameter, at least 10)"
    )]
    TooFew {
        /// Evaluations with a finite, positive loss.
        finite: usize,
        /// The minimum.
        needed: usize,
        /// Number of parameters.
        dim: usize,
    },
    /// A setting out of range or evaluations of the wrong dimension.
    #[error("{0}")]
    Setting(String),
    /// The surrogate could not be fitted.
    #[error(transparent)]
    Gp(#[from] GpError),
    /// The sampler failed.
    #[error(transparent)]
    Mcmc(#[from] McmcError),
}

/// One evaluated point of a calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct Evaluation {
    /// Parameter values (SI), in the space's order.
    pub params: Vec<f64>,
    /// Training loss; non-finite (or not positive) for a failed evaluation.
    pub loss: f64,
}

/// The likelihood threshold `ε` on the loss.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Threshold {
    /// This quantile (in (0, 1)) of the finite observed losses.
    Quantile(f64),
    /// This loss (> 0).
    Loss(f64),
}

/// Settings of [`infer`].
#[derive(Debug, Clone, PartialEq)]
pub struct PosteriorSettings {
    /// The likelihood threshold.
    pub threshold: Threshold,
    /// Posterior draws to return.
    pub draws: usize,
    /// Sampler steps discarded at the start.
    pub burn_in: usize,
    /// Keep every `thin`-th sampler step.
    pub thin: usize,
    /// Grid points of each profile.
    pub profile_points: usize,
    /// Posterior draws (evenly spaced in the chain) the profiles minimise over.
    pub profile_draws: usize,
    /// Seed of the surrogate fit, the walkers' start and the sampler.
    pub seed: u64,
}

impl Default for PosteriorSettings {
    fn default() -> Self {
        Self {
            threshold: Threshold::Quantile(0.1),
            draws: 4000,
            burn_in: 1000,
            thin: 10,
            profile_points: 21,
            profile_draws: 256,
            seed: 0,
        }
    }
}

/// The posterior summary of one parameter.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ParameterSummary {
    /// Simulator parameter name.
    pub name: String,
    /// Searched (and summarised) on a log scale.
    pub log: bool,
    /// Lower bound of the search (SI).
    pub lower: f64,
    /// Upper bound of the search (SI).
    pub upper: f64,
    /// The value of the best evaluation (the calibrated point).
    pub best: f64,
    /// Posterior median (SI).
    pub median: f64,
    /// 90 % credible interval: the 5 % and 95 % quantiles (SI).
    pub interval: [f64; 2],
    /// `log10(upper / lower)` of the interval, for log parameters.
    pub interval_decades: Option<f64>,
    /// Share of the search range (log units for log parameters) the interval covers.
    pub prior_fraction: f64,
    /// Whether the parameter is identified ([`IDENTIFIED_RULE`]).
    pub identified: bool,
    /// The surrogate's length scale along this parameter (unit-cube units): long means the loss
    /// hardly changes along it.
    pub length_scale: f64,
    /// Highest over lowest surrogate loss along the profile.
    pub profile_ratio: f64,
    /// Curvature of `ln(loss)` along the profile at its minimum, per decade² for log parameters
    /// and per search range² for linear ones (NaN, written as null, without three finite points).
    pub profile_curvature: f64,
}

/// Everything [`infer`] reports besides the draws, as written to `summary.json`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PosteriorSummary {
    /// Evaluations in the log.
    pub evaluations: usize,
    /// Of those, failed ones (non-finite loss).
    pub failed: usize,
    /// The best finite loss.
    pub best_loss: f64,
    /// How the threshold was chosen.
    pub epsilon_rule: String,
    /// The threshold as a loss.
    pub epsilon_loss: f64,
    /// The surrogate's learned noise standard deviation, in units of `ln(loss)`.
    pub noise_std_ln_loss: f64,
    /// Posterior draws.
    pub draws: usize,
    /// Walkers of the ensemble sampler.
    pub walkers: usize,
    /// Sampler steps discarded.
    pub burn_in: usize,
    /// Thinning of the kept steps.
    pub thin: usize,
    /// Accepted proposals / all proposals of the sampler.
    pub acceptance: f64,
    /// The seed.
    pub seed: u64,
    /// The identification rule ([`IDENTIFIED_RULE`]).
    pub identified_rule: String,
    /// One entry per parameter, in search order.
    pub parameters: Vec<ParameterSummary>,
}

/// The surrogate-loss profile of one parameter.
#[derive(Debug, Clone, PartialEq)]
pub struct Profile {
    /// Parameter name.
    pub name: String,
    /// Grid values (SI), evenly spaced in the unit cube.
    pub values: Vec<f64>,
    /// Lowest surrogate loss among the posterior draws with the parameter at each value, over the
    /// draws predicted to succeed (`inf` when none is).
    pub surrogate_loss: Vec<f64>,
}

/// The result of [`infer`].
#[derive(Debug, Clone, PartialEq)]
pub struct Posterior {
    /// Posterior draws (SI), in the space's order.
    pub draws: Vec<Vec<f64>>,
    /// Per-parameter summary and the run's figures.
    pub summary: PosteriorSummary,
    /// One profile per parameter.
    pub profiles: Vec<Profile>,
}

/// The fewest finite evaluations [`infer`] accepts for `dim` parameters: a surrogate with one
/// length scale per dimension needs a few points per dimension to learn them.
pub fn minimum_evaluations(dim: usize) -> usize {
    (3 * dim).max(10)
}

/// Reads a calibration's `evaluations.csv` for the parameters of `space`. A log whose header names
/// other parameters, or with values outside the space's bounds, was written for another box and is
/// an error, as is a row whose `objective` is not `ln(loss)`.
pub fn read_evaluations(
    path: &Path,
    space: &ParamSpace,
) -> Result<Vec<Evaluation>, PosteriorError> {
    // `EvaluationLog::open` would create a missing log.
    if !path.is_file() {
        return Err(PosteriorError::Missing(path.to_path_buf()));
    }
    let bounds: Vec<(f64, f64)> = space.specs().iter().map(|s| (s.lower, s.upper)).collect();
    let (_, rows) = EvaluationLog::open(path, &space.names(), &METRIC_NAMES, &bounds)?;
    rows.into_iter()
        .map(|row| {
            let loss = row.metrics[0];
            let expected = ln_loss(loss);
            let agrees = if expected.is_nan() {
                row.objective.is_nan()
            } else {
                (row.objective - expected).abs() <= 1e-12 * expected.abs().max(1.0)
            };
            if !agrees {
                return Err(PosteriorError::Log(LogError::Inconsistent {
                    path: path.to_path_buf(),
                    batch: row.batch,
                    candidate: row.candidate,
                    message: format!(
                        "`objective` = {} but `loss` = {loss}; expected ln(loss) for a finite \
                         positive loss and NaN for a failed evaluation",
                        row.objective
                    ),
                }));
            }
            Ok(Evaluation {
                params: row.params,
                loss,
            })
        })
        .collect()
}

/// The discrepancy the surrogate models: `ln(loss)`, NaN for a failed evaluation.
fn ln_loss(loss: f64) -> f64 {
    if loss.is_finite() && loss > 0.0 {
        loss.ln()
    } else {
        f64::NAN
    }
}

/// Fits the surrogate to `evaluations` and samples the posterior over `space` (see the module docs).
pub fn infer(
    space: &ParamSpace,
    evaluations: &[Evaluation],
    settings: &PosteriorSettings,
) -> Result<Posterior, PosteriorError> {
    let dim = space.dim();
    if let Some(e) = evaluations.iter().find(|e| e.params.len() != dim) {
        return Err(PosteriorError::Setting(format!(
            "an evaluation has {} values for {dim} parameters",
            e.params.len()
        )));
    }
    if settings.draws == 0 || settings.profile_points < 2 || settings.profile_draws == 0 {
        return Err(PosteriorError::Setting(
            "expected at least one draw, two profile points and one profile draw".into(),
        ));
    }
    let discrepancy: Vec<f64> = evaluations.iter().map(|e| ln_loss(e.loss)).collect();
    let mut finite: Vec<f64> = discrepancy
        .iter()
        .copied()
        .filter(|d| d.is_finite())
        .collect();
    finite.sort_by(f64::total_cmp);
    let needed = minimum_evaluations(dim);
    if finite.len() < needed {
        return Err(PosteriorError::TooFew {
            finite: finite.len(),
            needed,
            dim,
        });
    }
    let (epsilon, epsilon_rule) = epsilon(settings.threshold, &finite)?;

    let unit: Vec<Vec<f64>> = evaluations
        .iter()
        .map(|e| clamp_unit(space.to_unit(&e.params)))
        .collect();
    let evaluated: Vec<Vec<f64>> = unit
        .iter()
        .zip(&discrepancy)
        .filter(|(_, d)| d.is_finite())
        .map(|(u, _)| u.clone())
        .collect();
    let y: Vec<f64> = discrepancy
        .iter()
        .copied()
        .filter(|d| d.is_finite())
        .collect();
    // Streams: one per walker from 0 up (the sampler), the two last for the fits and the start.
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    rng.set_stream(u64::MAX - 1);
    let fit = FitOptions {
        random_starts: 4,
        steps: 200,
    };
    let gp = GaussianProcess::fit(evaluated.clone(), &y, None, fit, &mut rng)?;
    let failure = if evaluated.len() < evaluations.len() {
        let labels: Vec<f64> = discrepancy
            .iter()
            .map(|d| if d.is_finite() { 0.0 } else { 1.0 })
            .collect();
        Some(GaussianProcess::fit(unit, &labels, None, fit, &mut rng)?)
    } else {
        None
    };
    let surrogate = Surrogate {
        noise_var: gp.noise_variance(),
        gp,
        failure,
        epsilon,
    };
    let log_likelihood = |u: &[f64]| surrogate.log_likelihood(u);

    // Even, and comfortably above the sampler's minimum of 2 d + 2.
    let walkers = (4 * dim).max(32);
    let start = starting_walkers(&log_likelihood, &evaluated, walkers, dim, settings.seed);
    let sampler = EnsembleSettings {
        burn_in: settings.burn_in,
        thin: settings.thin,
        seed: settings.seed,
        ..EnsembleSettings::default()
    };
    let chain = mcmc::sample(&log_likelihood, &start, settings.draws, &sampler)?;

    let profiles = profiles(space, &surrogate, &chain.draws, settings);

    let best = evaluations
        .iter()
        .zip(&discrepancy)
        .filter(|(_, d)| d.is_finite())
        .min_by(|a, b| a.1.total_cmp(b.1))
        .map(|(e, _)| e)
        .expect("at least one finite value");
    let parameters = (0..dim)
        .map(|i| {
            let length_scale = surrogate.gp.hyperparameters().log_length_scales[i].exp();
            summarise(
                space,
                i,
                &chain.draws,
                &profiles[i],
                best.params[i],
                length_scale,
            )
        })
        .collect();

    let summary = PosteriorSummary {
        evaluations: evaluations.len(),
        failed: evaluations.len() - finite.len(),
        best_loss: finite[0].exp(),
        epsilon_rule,
        epsilon_loss: epsilon.exp(),
        noise_std_ln_loss: surrogate.noise_var.sqrt(),
        draws: chain.draws.len(),
        walkers,
        burn_in: settings.burn_in,
        thin: settings.thin,
        acceptance: chain.acceptance,
        seed: settings.seed,
        identified_rule: IDENTIFIED_RULE.into(),
        parameters,
    };
    Ok(Posterior {
        draws: chain.draws.iter().map(|u| space.from_unit(u)).collect(),
        summary,
        profiles,
    })
}

/// The threshold `ε` on `ln(loss)` and how it was chosen, given the sorted finite `ln(loss)`.
fn epsilon(threshold: Threshold, sorted: &[f64]) -> Result<(f64, String), PosteriorError> {
    match threshold {
        Threshold::Quantile(q) if q > 0.0 && q < 1.0 => Ok((
            quantile(sorted, q),
            format!("quantile {q} of the finite losses"),
        )),
        // Below the best loss no evaluation passes: the "posterior" would be the surrogate's
        // extrapolation alone, excluding the best fit.
        Threshold::Loss(loss) if loss > 0.0 && loss.is_finite() && loss.ln() < sorted[0] => {
            Err(PosteriorError::Setting(format!(
                "threshold loss {loss} is below the best loss of the evaluations ({:.6e}): no \
                 evaluation is within it; expected a loss >= {:.6e}",
                sorted[0].exp(),
                sorted[0].exp()
            )))
        }
        Threshold::Loss(loss) if loss > 0.0 && loss.is_finite() => {
            Ok((loss.ln(), format!("loss {loss}")))
        }
        Threshold::Quantile(q) => Err(PosteriorError::Setting(format!(
            "threshold quantile {q}: expected a value in (0, 1)"
        ))),
        Threshold::Loss(loss) => Err(PosteriorError::Setting(format!(
            "threshold loss {loss}: expected a finite loss > 0"
        ))),
    }
}

fn clamp_unit(u: Vec<f64>) -> Vec<f64> {
    u.into_iter().map(|v| v.clamp(0.0, 1.0)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::space::ParamSpec;
    use rand::Rng;

    fn space() -> ParamSpace {
        ParamSpace::new(vec![
            ParamSpec {
                name: "k_tri_e".into(),
                lower: 1e2,
                upper: 1e6,
                log: true,
            },
            ParamSpec {
                name: "k_edge_e".into(),
                lower: 1e-6,
                upper: 1e-1,
                log: true,
            },
        ])
        .unwrap()
    }

    /// A loss that is sharp in `k_tri_e` (minimum at 1e4, the middle of its log range) and does not
    /// depend on `k_edge_e`, with 2 % multiplicative noise.
    fn synthetic_evaluations(space: &ParamSpace) -> Vec<Evaluation> {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        // A design like an optimiser's: spread over the box, then crowded near the optimum.
        let mut unit: Vec<Vec<f64>> = (0..30)
            .map(|_| vec![rng.random::<f64>(), rng.random::<f64>()])
            .collect();
        unit.extend((0..30).map(|_| vec![0.4 + 0.2 * rng.random::<f64>(), rng.random::<f64>()]));
        let mut evaluations: Vec<Evaluation> = unit
            .iter()
            .map(|u| {
                let noise = 1.0 + 0.02 * (2.0 * rng.random::<f64>() - 1.0);
                Evaluation {
                    params: space.from_unit(u),
                    loss: 0.01 * (1.0 + ((u[0] - 0.5) / 0.05).powi(2)) * noise,
                }
            })
            .collect();
        // A diverged rollout.
        evaluations.push(Evaluation {
            params: space.from_unit(&[0.95, 0.1]),
            loss: f64::NAN,
        });
        evaluations
    }

    fn quick() -> PosteriorSettings {
        PosteriorSettings {
            draws: 3000,
            burn_in: 400,
            thin: 5,
            profile_draws: 64,
            ..PosteriorSettings::default()
        }
    }

    #[test]
    fn a_sharp_parameter_is_identified_and_a_flat_one_is_not() {
        let space = space();
        let posterior = infer(&space, &synthetic_evaluations(&space), &quick()).unwrap();
        let s = &posterior.summary;
        assert_eq!((s.evaluations, s.failed, s.draws), (61, 1, 3000));
        let [sharp, flat] = [&s.parameters[0], &s.parameters[1]];
        assert!(sharp.identified, "{sharp:?}");
        assert!(
            sharp.interval[0] < 1e4 && 1e4 < sharp.interval[1],
            "the interval covers the truth: {sharp:?}"
        );
        assert!(sharp.prior_fraction < 0.2, "{sharp:?}");
        assert!(!flat.identified, "{flat:?}");
        assert!(flat.prior_fraction > 0.75, "{flat:?}");
        assert!(
            flat.length_scale > 3.0 * sharp.length_scale,
            "{flat:?} {sharp:?}"
        );
        // The profile of the flat parameter hardly moves; the sharp one rises by decades.
        assert!(flat.profile_ratio < 1.5, "{flat:?}");
        assert!(sharp.profile_ratio > 10.0, "{sharp:?}");
        let decades = sharp.interval_decades.unwrap();
        assert!((decades - (sharp.interval[1] / sharp.interval[0]).log10()).abs() < 1e-12);
        assert!(posterior.draws.iter().all(|d| d[0] >= 1e2 && d[0] <= 1e6));
        assert_eq!(posterior.profiles[0].values.len(), 21);
        assert!((posterior.profiles[0].values[10] - 1e4).abs() < 1e-6);
    }

    #[test]
    fn is_deterministic_for_a_seed_and_independent_of_the_thread_count() {
        let space = space();
        let evaluations = synthetic_evaluations(&space);
        let settings = PosteriorSettings {
            draws: 500,
            burn_in: 100,
            ..quick()
        };
        let on = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| infer(&space, &evaluations, &settings).unwrap())
        };
        assert_eq!(on(1), on(2));
    }

    #[test]
    fn the_threshold_is_a_quantile_or_a_loss() {
        let space = space();
        let evaluations = synthetic_evaluations(&space);
        let settings = |threshold| PosteriorSettings {
            threshold,
            draws: 200,
            burn_in: 50,
            ..quick()
        };
        let mut losses: Vec<f64> = evaluations
            .iter()
            .map(|e| e.loss)
            .filter(|l| l.is_finite())
            .collect();
        losses.sort_by(f64::total_cmp);
        let median = infer(&space, &evaluations, &settings(Threshold::Quantile(0.5))).unwrap();
        // 60 finite losses: the median lies halfway between the 30th and 31st (geometric mean).
        let expected = (losses[29] * losses[30]).sqrt();
        assert!((median.summary.epsilon_loss - expected).abs() < 1e-12 * expected);
        let fixed = infer(&space, &evaluations, &settings(Threshold::Loss(0.02))).unwrap();
        assert!((fixed.summary.epsilon_loss - 0.02).abs() < 1e-15);
        match infer(
            &space,
            &evaluations,
            &settings(Threshold::Loss(losses[0] / 2.0)),
        ) {
            Err(PosteriorError::Setting(m)) => assert!(m.contains("below the best loss"), "{m}"),
            _ => panic!("a threshold below the best loss was accepted"),
        }
        for bad in [Threshold::Quantile(0.0), Threshold::Loss(-1.0)] {
            assert!(matches!(
                infer(&space, &evaluations, &settings(bad)),
                Err(PosteriorError::Setting(_))
            ));
        }
    }

    #[test]
    fn the_posterior_avoids_where_the_simulator_fails() {
        // The same loss, but every evaluation with k_edge_e above unit coordinate 0.75 diverges.
        let space = space();
        let mut evaluations = synthetic_evaluations(&space);
        for e in &mut evaluations {
            if space.to_unit(&e.params)[1] > 0.75 {
                e.loss = f64::NAN;
            }
        }
        let posterior = infer(&space, &evaluations, &quick()).unwrap();
        let edge = &posterior.summary.parameters[1];
        assert!(posterior.summary.failed >= 8, "{:?}", posterior.summary);
        let boundary = space.from_unit(&[0.5, 0.8])[1];
        assert!(edge.interval[1] < boundary, "{edge:?}");
        assert!(
            posterior.draws.iter().filter(|d| d[1] > boundary).count() < 60,
            "under 2 % of the draws where it fails"
        );
        // The profile is infinite where every draw is predicted to fail, finite elsewhere.
        let profile = &posterior.profiles[1].surrogate_loss;
        assert_eq!(profile.last(), Some(&f64::INFINITY), "{profile:?}");
        assert!(profile[..14].iter().all(|l| l.is_finite()), "{profile:?}");
        assert!(posterior.summary.parameters[0].identified);
    }

    #[test]
    fn too_few_evaluations_are_an_error() {
        let space = space();
        let mut evaluations = synthetic_evaluations(&space);
        evaluations.truncate(9);
        let err = infer(&space, &evaluations, &quick()).unwrap_err();
        assert!(
            matches!(
                err,
                PosteriorError::TooFew {
                    finite: 9,
                    needed: 10,
                    dim: 2
                }
            ),
            "{err}"
        );
    }

    #[test]
    fn reads_the_log_and_rejects_other_boxes_and_edited_rows() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("evaluations.csv");
        let space = space();
        assert!(matches!(
            read_evaluations(&path, &space),
            Err(PosteriorError::Missing(_))
        ));
        assert!(!path.exists(), "reading does not create the log");
        let header = "batch,candidate,k_tri_e,k_edge_e,objective,loss,chamfer_m,object_mse_m2\n";
        let good = format!(
            "{header}0,0,1000,0.001,{},0.5,0.1,0.4\n0,1,1e5,1e-3,NaN,NaN,NaN,NaN\n",
            0.5f64.ln()
        );
        std::fs::write(&path, &good).unwrap();
        let rows = read_evaluations(&path, &space).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[0].params, vec![1000.0, 0.001]);
        assert!(rows[1].loss.is_nan());

        std::fs::write(&path, good.replace("1000,", "10,")).unwrap();
        let err = read_evaluations(&path, &space).unwrap_err().to_string();
        assert!(err.contains("outside its bounds"), "{err}");
        std::fs::write(&path, good.replace("k_edge_e", "mu_con")).unwrap();
        let err = read_evaluations(&path, &space).unwrap_err().to_string();
        assert!(err.contains("header"), "{err}");
        std::fs::write(&path, good.replace("NaN,NaN,NaN,NaN", "NaN,0.3,0.1,0.2")).unwrap();
        let err = read_evaluations(&path, &space).unwrap_err().to_string();
        assert!(
            err.contains("candidate 1") && err.contains("ln(loss)"),
            "{err}"
        );
    }
}
