//! A posterior evaluated by the simulator: adaptive tempered sequential Monte Carlo.
//!
//! Why this sampler: the batched simulator evaluates hundreds of candidates in one rollout, and a
//! population method spends its evaluations in exactly such batches. Every point of the posterior
//! it returns was simulated; nothing is extrapolated by a surrogate, so where the calibration never
//! looked the posterior has no mass because the sampler only keeps what the likelihood supports.
//!
//! The algorithm (Del Moral, Doucet & Jasra 2006; the "transitional MCMC" of Ching & Chen 2007 in
//! structural model updating) moves a population from the prior to the posterior through tempered
//! targets `π_β(θ) ∝ prior(θ) · L(θ)^β`, `0 = β_0 < β_1 < … < β_S = 1`:
//!
//! 1. `particles` points from the prior (uniform on the unit cube of the search space: log-uniform
//!    for log parameters), their log-likelihoods in one batch;
//! 2. the next `β` is the one at which the incremental weights `L^(β'−β)` keep an effective sample
//!    size of `ess_fraction · particles` (bisection), or 1;
//! 3. systematic resampling by those weights, then `moves` random-walk Metropolis steps per
//!    particle at `β'`, with a Gaussian proposal of the weighted population covariance scaled by a
//!    factor adapted towards an acceptance of about a quarter (all particles' proposals in one
//!    batch; a proposal outside the box is rejected without a simulation);
//! 4. repeat until `β = 1`, then `final_moves` more steps at `β = 1`.
//!
//! With `mode_search`, a CMA-ES search ([`crate::cmaes`]) runs first, and the population starts
//! from its final distribution instead of the prior: a Gaussian reference `q` (the search's
//! covariance, widened by `reference_scale`, truncated to the box). The targets are then
//! `π_β ∝ q^(1−β) · (prior · L)^β`, the same path from a reference that already sits where the
//! likelihood is high: the prior's volume is mostly where a ten-parameter likelihood is
//! negligible, and a population of tens started there misses the mode (measured on known
//! parameters: docs/calibration.md).
//!
//! Determinism: every random draw comes from one ChaCha stream in a fixed order, and the
//! likelihoods come back in batch order, so the result depends on the seed and the likelihood alone
//! (not on threads). Resume: [`sample`] asks for batches by index; a caller that logs every batch
//! can serve the logged ones again and the run continues exactly where it stopped.

use nalgebra::{DMatrix, DVector, SymmetricEigen};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::cmaes::{self, standard_normal, CmaEs, Generation, ModeSearchSettings};

/// Settings of the sampler.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SmcSettings {
    /// Population size.
    pub particles: usize,
    /// Effective sample size kept by each tempering step, as a share of the population.
    #[serde(default = "default_ess_fraction")]
    pub ess_fraction: f64,
    /// Metropolis steps per particle after each tempering step.
    pub moves: usize,
    /// Extra Metropolis steps at `β = 1`.
    #[serde(default)]
    pub final_moves: usize,
    /// Most tempering steps before giving up.
    #[serde(default = "default_max_stages")]
    pub max_stages: usize,
    /// Seed of every random choice.
    #[serde(default)]
    pub seed: u64,
    /// A CMA-ES search for the mode before sampling; the population then starts around it.
    #[serde(default)]
    pub mode_search: Option<ModeSearchSettings>,
    /// Levenberg–Marquardt steps ([`crate::polish`]) from the mode search's best point, whose
    /// Laplace approximation then starts the sampler ([`sample_refined`]); without a mode
    /// search, from the best draw after sampling. The polished point is the calibration's best
    /// when it is better than every draw.
    #[serde(default)]
    pub polish_iterations: usize,
    /// Replays of the mode search's best point with every coordinate moved by at most
    /// [`CHAOS_NUDGE`] of the box: their log-likelihoods differ only by what the simulator's own
    /// sensitivity gives one material (a film that folds one way or another), which is no evidence
    /// about the material. The sampler then targets the power posterior `prior · L^η` with
    /// `η = min(1, 1 / sd)`, `sd` their standard deviation, so that what one material's replays
    /// disagree by moves the tempered log-likelihood by one unit. 0 (the default): `η = 1`.
    /// Needs a mode search.
    #[serde(default)]
    pub chaos_replays: usize,
    /// How many of the mode search's good points the chaos replays share (each takes
    /// `chaos_replays / chaos_points` of them): the best point of each of the search's best
    /// generations on the whole data. One point can sit where its own neighbourhood happens to be
    /// smooth; the spread is then pooled within points (what one material's replays disagree by,
    /// not how far the points differ from one another). 1 (the default): the best point alone.
    #[serde(default = "default_chaos_points")]
    pub chaos_points: usize,
    /// Share of the sampler's reference that is the prior (uniform on the box), the rest the
    /// Gaussian the mode search (or the polish's Laplace approximation) hands it: a defensive
    /// mixture (Hesterberg 1995). Why: that Gaussian's width comes from the search's last steps or
    /// from finite differences of the likelihood at one point, and where the likelihood is rough
    /// those say nothing about how wide the posterior is; a population drawn from a reference
    /// narrower than the posterior stays inside it. With part of the reference on the whole box,
    /// the tempering path `q^(1−β) · (prior · L^η)^β` has support everywhere the posterior has,
    /// and the likelihood alone decides the width. 0 (the default): the Gaussian alone. Needs a
    /// mode search.
    #[serde(default)]
    pub prior_share: f64,
}

fn default_chaos_points() -> usize {
    1
}

/// How far [`SmcSettings::chaos_replays`] move each coordinate (share of the box): far below
/// anything a recording resolves.
pub const CHAOS_NUDGE: f64 = 1e-6;

impl SmcSettings {
    /// The sampler in a few words, for a sentence: "CMA-ES mode search (P x at most G
    /// generations), then N particles x M moves", with the prior's share of the reference when it
    /// has one.
    pub fn sampler_text(&self) -> String {
        let mixed = if self.prior_share > 0.0 {
            format!(
                ", {:.0} % of the reference from the prior",
                100.0 * self.prior_share
            )
        } else {
            String::new()
        };
        format!(
            "{}{} particles x {} moves{mixed}",
            self.mode_search_text(),
            self.particles,
            self.moves
        )
    }

    /// "CMA-ES mode search (P x at most G generations), then " when the sampler has one, for a
    /// sentence describing the sampler; empty otherwise.
    fn mode_search_text(&self) -> String {
        self.mode_search.map_or(String::new(), |m| {
            let horizon = m.first_horizon_s.map_or(String::new(), |h| {
                format!(" per horizon, from the first {h} s doubling to the whole recordings")
            });
            format!(
                "CMA-ES mode search ({} x at most {} generations{horizon}), then ",
                m.population, m.generations
            )
        })
    }
}

fn default_ess_fraction() -> f64 {
    0.5
}

fn default_max_stages() -> usize {
    100
}

/// Errors of the sampler.
#[derive(Debug, thiserror::Error)]
pub enum SmcError {
    /// Settings out of range.
    #[error("sampler settings: {0}")]
    Settings(String),
    /// The likelihood failed.
    #[error("likelihood: {0}")]
    Likelihood(String),
    /// No particle has a finite likelihood.
    #[error("every particle of stage {stage} has zero likelihood (every rollout diverged?)")]
    Degenerate {
        /// The stage.
        stage: usize,
    },
    /// The mode search ended where the box holds almost none of its reference distribution.
    #[error("the mode search's reference distribution has {share:.1e} of its mass in the box")]
    ReferenceOutside {
        /// Share of the reference inside the box.
        share: f64,
    },
    /// `β = 1` was not reached within `max_stages`.
    #[error("the temperature reached only {beta:.3e} after {stages} stages (max_stages)")]
    TooManyStages {
        /// The last inverse temperature.
        beta: f64,
        /// Stages run.
        stages: usize,
    },
}

/// One tempering step, as reported.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Stage {
    /// Inverse temperature reached.
    pub beta: f64,
    /// Effective sample size of the incremental weights.
    pub ess: f64,
    /// Accepted Metropolis proposals / proposals of this stage's moves.
    pub acceptance: f64,
    /// Proposal scale (factor on the population covariance's square root).
    pub scale: f64,
    /// Evaluations so far.
    pub evaluations: usize,
    /// Highest log-likelihood in the population after the moves.
    pub best_log_likelihood: f64,
}

/// The final population: equally weighted draws from the posterior.
#[derive(Debug, Clone, PartialEq)]
pub struct SmcResult {
    /// Draws in the unit cube.
    pub draws: Vec<Vec<f64>>,
    /// Their log-likelihoods.
    pub log_likelihoods: Vec<f64>,
    /// Every tempering step.
    pub stages: Vec<Stage>,
    /// Evaluations of the likelihood (simulated candidates).
    pub evaluations: usize,
    /// Log of the model evidence estimate `ln ∫ prior · L^η` (sum of the stages' log mean weights).
    pub log_evidence: f64,
    /// The mode search's generations (empty without `mode_search`).
    pub search: Vec<Generation>,
    /// The likelihood's power `η` the sampler targeted (1 without `chaos_replays`).
    pub likelihood_power: f64,
    /// The standard deviation of the log-likelihood over the `chaos_replays` replays of one point
    /// (pooled within points when they share several).
    pub chaos_sd: Option<f64>,
    /// The points the chaos replays shared (0 without them).
    pub chaos_points: usize,
}

/// A Gaussian approximation of the posterior at its mode, in the unit cube: `N(mode, F⁻¹)` with
/// `F` the information there (Laplace's method).
#[derive(Debug, Clone, PartialEq)]
pub struct Laplace {
    /// The mode.
    pub mode: Vec<f64>,
    /// The covariance.
    pub covariance: DMatrix<f64>,
}

impl Laplace {
    /// `N(mode, F⁻¹)` from the information `F` at `mode`, each eigen-direction's standard
    /// deviation capped at `max_sd`: the data hardly see a sloppy direction, and an unbounded
    /// variance there would put the sampler's whole reference outside the box.
    pub fn from_information(mode: Vec<f64>, information: &DMatrix<f64>, max_sd: f64) -> Self {
        let eigen = SymmetricEigen::new(information.clone());
        let floor = 1.0 / (max_sd * max_sd);
        let variances = eigen.eigenvalues.map(|l| 1.0 / l.max(floor));
        let covariance = &eigen.eigenvectors
            * DMatrix::from_diagonal(&variances)
            * eigen.eigenvectors.transpose();
        Self { mode, covariance }
    }
}

/// Samples the posterior `prior · L` on the unit cube `[0, 1]^dim` (uniform prior), on data
/// `duration_s` long (the horizons of a growing-horizon mode search,
/// [`ModeSearchSettings::horizons`]).
///
/// `log_likelihood(batch, horizon, points)` returns one value per point (`−∞` or NaN: zero
/// likelihood) of the data up to `horizon` (`None`: all of it; the sampler itself always asks
/// for all), `batch` counting the calls from 0 in a fixed order (for logging and resuming).
pub fn sample(
    dim: usize,
    settings: &SmcSettings,
    duration_s: f64,
    log_likelihood: impl FnMut(usize, Option<f64>, &[Vec<f64>]) -> Result<Vec<f64>, String>,
) -> Result<SmcResult, SmcError> {
    sample_refined(dim, settings, duration_s, log_likelihood, |_| Ok(None))
}

/// [`sample`], with the mode search's outcome refined before the population is drawn:
/// `refine(best)` gets the search's best point on the whole data and may return a [`Laplace`]
/// approximation of the posterior (e.g. after Gauss–Newton steps from `best`), which then
/// replaces the search's distribution as the reference (widened by `reference_scale` the same
/// way). Why: the search's covariance is the shape of its last steps, not of the posterior; on a
/// sharp ten-parameter likelihood it is far narrower in some directions and wider in others,
/// and a population of tens drawn from it collapses onto the search's basin.
/// Not called without a mode search.
pub fn sample_refined(
    dim: usize,
    settings: &SmcSettings,
    duration_s: f64,
    mut log_likelihood: impl FnMut(usize, Option<f64>, &[Vec<f64>]) -> Result<Vec<f64>, String>,
    mut refine: impl FnMut(&[f64]) -> Result<Option<Laplace>, String>,
) -> Result<SmcResult, SmcError> {
    check_settings(dim, settings)?;
    let n = settings.particles;
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    let mut batch = 0usize;
    let mut evaluations = 0usize;
    let mut evaluate = |horizon: Option<f64>, points: &[Vec<f64>], evaluations: &mut usize| {
        let values = log_likelihood(batch, horizon, points).map_err(SmcError::Likelihood)?;
        batch += 1;
        if values.len() != points.len() {
            return Err(SmcError::Likelihood(format!(
                "{} values for {} points",
                values.len(),
                points.len()
            )));
        }
        *evaluations += points.len();
        Ok(values
            .into_iter()
            .map(|v| if v.is_nan() { f64::NEG_INFINITY } else { v })
            .collect::<Vec<f64>>())
    };
    let mut search = Vec::new();
    let (mut power, mut chaos, mut chaos_points) = (1.0, None, 0);
    let reference = match &settings.mode_search {
        None => None,
        Some(mode) => {
            let (cma, good) = search_mode(
                dim,
                mode,
                &mode.horizons(duration_s),
                &mut rng,
                &mut search,
                &mut |h, p| evaluate(h, p, &mut evaluations),
            )?;
            let best = good[0].clone();
            let (mean, covariance) = match refine(&best).map_err(SmcError::Likelihood)? {
                Some(laplace) => (laplace.mode, laplace.covariance),
                None => (cma.mean(), cma.covariance()),
            };
            if settings.chaos_replays > 0 {
                let points = &good[..settings.chaos_points.min(good.len())];
                let per_point = settings.chaos_replays / settings.chaos_points;
                let nudged: Vec<Vec<f64>> = points
                    .iter()
                    .flat_map(|point| std::iter::repeat_n(point, per_point))
                    .map(|point| {
                        point
                            .iter()
                            .map(|&v| {
                                let u = 2.0 * rng.random::<f64>() - 1.0;
                                (v + CHAOS_NUDGE * u).clamp(0.0, 1.0)
                            })
                            .collect()
                    })
                    .collect();
                let values = evaluate(None, &nudged, &mut evaluations)?;
                let sd = chaos_sd(&values.chunks(per_point).collect::<Vec<_>>())?;
                chaos = Some(sd);
                chaos_points = points.len();
                power = (1.0 / sd).min(1.0);
            }
            // The power posterior is wider than the likelihood's by 1/√η (exactly so where it is
            // Gaussian): the reference too.
            let covariance = covariance * (mode.reference_scale.powi(2) / power);
            Some(Reference::new(
                mean,
                covariance,
                settings.prior_share,
                &mut rng,
            )?)
        }
    };
    let log_reference = |p: &[f64]| reference.as_ref().map_or(0.0, |r| r.log_density(p));
    let mut particles: Vec<Vec<f64>> = match &reference {
        None => (0..n)
            .map(|_| (0..dim).map(|_| rng.random::<f64>()).collect())
            .collect(),
        Some(r) => r.draw(n, &mut rng)?,
    };
    // From here on the sampler sees `η · ln L`.
    let tempered = |values: Vec<f64>| values.into_iter().map(|v| power * v).collect::<Vec<f64>>();
    let mut ll = tempered(evaluate(None, &particles, &mut evaluations)?);
    let mut lq: Vec<f64> = particles.iter().map(|p| log_reference(p)).collect();
    let mut beta = 0.0;
    let mut scale = 2.38 / (dim as f64).sqrt();
    let mut stages = Vec::new();
    let mut log_evidence = 0.0;
    while beta < 1.0 {
        if stages.len() == settings.max_stages {
            return Err(SmcError::TooManyStages {
                beta,
                stages: stages.len(),
            });
        }
        // The tempered potential: log(prior · L / q), the log-likelihood itself from the prior.
        let potential: Vec<f64> = ll.iter().zip(&lq).map(|(l, q)| l - q).collect();
        let best = potential.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        if best == f64::NEG_INFINITY {
            return Err(SmcError::Degenerate {
                stage: stages.len(),
            });
        }
        let next = next_beta(&potential, beta, settings.ess_fraction * n as f64);
        let weights = incremental_weights(&potential, next - beta);
        let mean_weight = weights.iter().sum::<f64>() / n as f64;
        log_evidence += mean_weight.ln() + (next - beta) * best;
        let ess = effective_sample_size(&weights);
        let cholesky = proposal_factor(&particles, &weights, dim);
        let chosen = systematic_resample(&weights, &mut rng);
        particles = chosen.iter().map(|&i| particles[i].clone()).collect();
        ll = chosen.iter().map(|&i| ll[i]).collect();
        lq = chosen.iter().map(|&i| lq[i]).collect();
        beta = next;
        let acceptance = metropolis(
            (&mut particles, &mut ll, &mut lq),
            Tempered {
                beta,
                log_reference: &log_reference,
            },
            &cholesky,
            &mut scale,
            settings.moves,
            &mut rng,
            &mut |p| evaluate(None, p, &mut evaluations).map(tempered),
        )?;
        stages.push(Stage {
            beta,
            ess,
            acceptance,
            scale,
            evaluations,
            best_log_likelihood: ll.iter().copied().fold(f64::NEG_INFINITY, f64::max) / power,
        });
    }
    if settings.final_moves > 0 {
        let weights = vec![1.0; n];
        let cholesky = proposal_factor(&particles, &weights, dim);
        let acceptance = metropolis(
            (&mut particles, &mut ll, &mut lq),
            Tempered {
                beta: 1.0,
                log_reference: &log_reference,
            },
            &cholesky,
            &mut scale,
            settings.final_moves,
            &mut rng,
            &mut |p| evaluate(None, p, &mut evaluations).map(tempered),
        )?;
        stages.push(Stage {
            beta: 1.0,
            ess: n as f64,
            acceptance,
            scale,
            evaluations,
            best_log_likelihood: ll.iter().copied().fold(f64::NEG_INFINITY, f64::max) / power,
        });
    }
    Ok(SmcResult {
        draws: particles,
        log_likelihoods: ll.into_iter().map(|v| v / power).collect(),
        stages,
        evaluations,
        log_evidence,
        search,
        likelihood_power: power,
        chaos_sd: chaos,
        chaos_points,
    })
}

/// The standard deviation of the finite log-likelihoods of nudged replays, pooled within the
/// points they replay (`groups`, one per point): deviations from each point's own mean over the
/// degrees of freedom left (a replay that diverged says nothing about the spread of those that
/// did not). With one point, its sample standard deviation.
fn chaos_sd(groups: &[&[f64]]) -> Result<f64, SmcError> {
    let (mut squares, mut freedom, mut total) = (0.0, 0usize, 0usize);
    for group in groups {
        let finite: Vec<f64> = group.iter().copied().filter(|v| v.is_finite()).collect();
        total += group.len();
        if finite.len() < 2 {
            continue;
        }
        let mean = finite.iter().sum::<f64>() / finite.len() as f64;
        squares += finite.iter().map(|v| (v - mean).powi(2)).sum::<f64>();
        freedom += finite.len() - 1;
    }
    if freedom == 0 {
        return Err(SmcError::Likelihood(format!(
            "the {total} replays of the mode search's good points leave no point with two finite \
             likelihoods: no spread to measure"
        )));
    }
    Ok((squares / freedom as f64).sqrt())
}

/// Runs the CMA-ES search from the cube's centre, logging each generation into `search`; returns
/// the search and the best point of each generation on the last horizon (the whole data), best
/// first (the earlier generation first among equals).
fn search_mode(
    dim: usize,
    settings: &ModeSearchSettings,
    horizons: &[Option<f64>],
    rng: &mut ChaCha8Rng,
    search: &mut Vec<Generation>,
    evaluate: &mut SearchEvaluate,
) -> Result<(CmaEs, Vec<Vec<f64>>), SmcError> {
    let mut cma = CmaEs::new(&vec![0.5; dim], settings.initial_step, settings.population);
    let mut evaluations = 0;
    let mut good: Vec<(Vec<f64>, f64)> = Vec::new();
    for &horizon in horizons {
        for _ in 0..settings.generations {
            let points = cma.ask(rng);
            let values = evaluate(horizon, &points)?;
            evaluations += points.len();
            if horizon.is_none() {
                let mut best = (cma.mean(), f64::NEG_INFINITY);
                for (p, &v) in points.iter().zip(&values) {
                    if v > best.1 {
                        best = (p.clone(), v);
                    }
                }
                good.push(best);
            }
            cma.tell(&points, &values);
            let mut sorted = values.clone();
            sorted.sort_by(|a, b| b.total_cmp(a));
            let (best, median) = (sorted[0], sorted[sorted.len() / 2]);
            search.push(Generation {
                best_log_likelihood: best,
                median_log_likelihood: median,
                step: cma.step(),
                horizon_s: horizon,
                evaluations,
            });
            if best - median < cmaes::CONVERGED_SPREAD_PER_DIM * dim as f64 {
                break;
            }
        }
    }
    if good.is_empty() {
        good.push((cma.mean(), f64::NEG_INFINITY));
    }
    good.sort_by(|a, b| b.1.total_cmp(&a.1));
    Ok((cma, good.into_iter().map(|(p, _)| p).collect()))
}

/// The reference a mode search hands the sampler: a Gaussian truncated to the unit cube, mixed
/// with the prior (uniform on the cube) by [`SmcSettings::prior_share`].
struct Reference {
    mean: DVector<f64>,
    /// Lower Cholesky factor of the covariance.
    factor: DMatrix<f64>,
    /// `ln` of the truncated density's normalising constant (Gaussian and box share together).
    log_normaliser: f64,
    /// The prior's share of the mixture.
    prior_share: f64,
}

/// Draws of the reference used to measure its share inside the box.
const REFERENCE_SHARE_DRAWS: usize = 20_000;

impl Reference {
    fn new(
        mean: Vec<f64>,
        covariance: DMatrix<f64>,
        prior_share: f64,
        rng: &mut ChaCha8Rng,
    ) -> Result<Self, SmcError> {
        let dim = mean.len();
        let mut covariance = covariance;
        for i in 0..dim {
            covariance[(i, i)] += 1e-12;
        }
        let factor = match covariance.clone().cholesky() {
            Some(c) => c.l(),
            None => DMatrix::from_diagonal(&covariance.diagonal().map(|v| v.max(1e-12).sqrt())),
        };
        let mut reference = Self {
            mean: DVector::from_vec(mean),
            factor,
            log_normaliser: 0.0,
            prior_share,
        };
        let inside = (0..REFERENCE_SHARE_DRAWS)
            .filter(|_| in_cube(&reference.propose(rng)))
            .count();
        let share = inside as f64 / REFERENCE_SHARE_DRAWS as f64;
        if inside < 10 {
            return Err(SmcError::ReferenceOutside { share });
        }
        let log_det: f64 = (0..dim).map(|i| reference.factor[(i, i)].ln()).sum();
        reference.log_normaliser =
            log_det + 0.5 * dim as f64 * std::f64::consts::TAU.ln() + share.ln();
        Ok(reference)
    }

    /// A draw of the untruncated Gaussian.
    fn propose(&self, rng: &mut ChaCha8Rng) -> Vec<f64> {
        let dim = self.mean.len();
        let z = DVector::from_iterator(dim, (0..dim).map(|_| standard_normal(rng)));
        (&self.mean + &self.factor * z).iter().copied().collect()
    }

    /// `n` draws inside the box: each from the prior with probability `prior_share`, else from
    /// the truncated Gaussian (by rejection: the component is chosen once per draw, so that the
    /// draws follow [`Self::log_density`] however much of the Gaussian lies outside the box).
    fn draw(&self, n: usize, rng: &mut ChaCha8Rng) -> Result<Vec<Vec<f64>>, SmcError> {
        let mut draws = Vec::with_capacity(n);
        let most = n.saturating_mul(REFERENCE_SHARE_DRAWS);
        let mut proposals = 0usize;
        while draws.len() < n {
            if self.prior_share > 0.0 && rng.random::<f64>() < self.prior_share {
                draws.push((0..self.mean.len()).map(|_| rng.random::<f64>()).collect());
                continue;
            }
            loop {
                if proposals == most {
                    return Err(SmcError::ReferenceOutside {
                        share: draws.len() as f64 / most as f64,
                    });
                }
                proposals += 1;
                let p = self.propose(rng);
                if in_cube(&p) {
                    draws.push(p);
                    break;
                }
            }
        }
        Ok(draws)
    }

    /// The mixture's density's logarithm at `p` (inside the box; the prior's density is 1 there).
    fn log_density(&self, p: &[f64]) -> f64 {
        let d = DVector::from_column_slice(p) - &self.mean;
        let z = self
            .factor
            .solve_lower_triangular(&d)
            .expect("a Cholesky factor with a positive diagonal");
        let gaussian = -0.5 * z.norm_squared() - self.log_normaliser;
        if self.prior_share == 0.0 {
            return gaussian;
        }
        let (g, u) = (
            (1.0 - self.prior_share).ln() + gaussian,
            self.prior_share.ln(),
        );
        let top = g.max(u);
        top + ((g - top).exp() + (u - top).exp()).ln()
    }
}

fn in_cube(p: &[f64]) -> bool {
    p.iter().all(|v| (0.0..=1.0).contains(v))
}

/// Checks `settings` for a space of `dim` parameters.
pub fn check_settings(dim: usize, s: &SmcSettings) -> Result<(), SmcError> {
    let fail = |m: String| Err(SmcError::Settings(m));
    if dim == 0 {
        return fail("no parameter to sample".into());
    }
    if !(2 * dim + 2..=1_000_000).contains(&s.particles) {
        return fail(format!(
            "particles = {}: expected {}..=1000000 (at least twice the dimension plus two)",
            s.particles,
            2 * dim + 2
        ));
    }
    if !(s.ess_fraction > 0.0 && s.ess_fraction < 1.0) {
        return fail(format!(
            "ess_fraction = {}: expected in (0, 1)",
            s.ess_fraction
        ));
    }
    if !(1..=1000).contains(&s.moves) || s.final_moves > 10_000 {
        return fail(format!(
            "moves = {}, final_moves = {}: expected 1..=1000 and 0..=10000",
            s.moves, s.final_moves
        ));
    }
    if !(1..=10_000).contains(&s.max_stages) {
        return fail(format!("max_stages = {}: expected 1..=10000", s.max_stages));
    }
    if s.polish_iterations > 1000 {
        return fail(format!(
            "polish_iterations = {}: expected 0..=1000",
            s.polish_iterations
        ));
    }
    if let Some(mode) = &s.mode_search {
        cmaes::check_settings(dim, mode).map_err(SmcError::Settings)?;
    }
    if s.chaos_replays == 1 || s.chaos_replays > 10_000 {
        return fail(format!(
            "chaos_replays = {}: expected 0 (off) or 2..=10000",
            s.chaos_replays
        ));
    }
    if s.chaos_replays > 0 && s.mode_search.is_none() {
        return fail("chaos_replays needs [smc.mode_search]: they replay its best point".into());
    }
    if !(0.0..1.0).contains(&s.prior_share) || (s.prior_share > 0.0 && s.mode_search.is_none()) {
        return fail(format!(
            "prior_share = {}: expected in [0, 1), and a [smc.mode_search] whose reference it \
             mixes with the prior",
            s.prior_share
        ));
    }
    if !(1..=64).contains(&s.chaos_points)
        || (s.chaos_replays > 0
            && (!s.chaos_replays.is_multiple_of(s.chaos_points)
                || s.chaos_replays / s.chaos_points < 2))
    {
        return fail(format!(
            "chaos_points = {} with chaos_replays = {}: expected 1..=64 points, each taking the \
             same number (at least 2) of the replays",
            s.chaos_points, s.chaos_replays
        ));
    }
    Ok(())
}

/// `exp(δ · (ℓ_i − max ℓ))`: the incremental weights up to a common factor.
fn incremental_weights(ll: &[f64], delta: f64) -> Vec<f64> {
    let best = ll.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    ll.iter()
        .map(|&l| {
            if l == f64::NEG_INFINITY {
                0.0
            } else {
                (delta * (l - best)).exp()
            }
        })
        .collect()
}

fn effective_sample_size(weights: &[f64]) -> f64 {
    let sum: f64 = weights.iter().sum();
    let squares: f64 = weights.iter().map(|w| w * w).sum();
    if squares == 0.0 {
        0.0
    } else {
        sum * sum / squares
    }
}

/// The largest `β' ≤ 1` whose incremental weights keep an effective sample size of `target`.
fn next_beta(ll: &[f64], beta: f64, target: f64) -> f64 {
    let ess = |b: f64| effective_sample_size(&incremental_weights(ll, b - beta));
    if ess(1.0) >= target {
        return 1.0;
    }
    let (mut low, mut high) = (beta, 1.0);
    for _ in 0..100 {
        let mid = 0.5 * (low + high);
        if ess(mid) >= target {
            low = mid;
        } else {
            high = mid;
        }
    }
    // Progress even when a single particle dominates from the start.
    if low > beta {
        low
    } else {
        high
    }
}

/// Indices drawn by systematic resampling (one uniform offset, `n` evenly spaced pointers).
fn systematic_resample(weights: &[f64], rng: &mut ChaCha8Rng) -> Vec<usize> {
    let n = weights.len();
    let total: f64 = weights.iter().sum();
    let offset: f64 = rng.random::<f64>();
    let mut chosen = Vec::with_capacity(n);
    let mut cumulative = 0.0;
    let mut i = 0;
    for k in 0..n {
        let pointer = (k as f64 + offset) / n as f64 * total;
        while i + 1 < n && cumulative + weights[i] < pointer {
            cumulative += weights[i];
            i += 1;
        }
        chosen.push(i);
    }
    chosen
}

/// Lower Cholesky factor of the weighted covariance of `points` (with a small ridge so that a
/// collapsed direction still moves).
fn proposal_factor(points: &[Vec<f64>], weights: &[f64], dim: usize) -> DMatrix<f64> {
    let total: f64 = weights.iter().sum();
    let mut mean = DVector::zeros(dim);
    for (p, &w) in points.iter().zip(weights) {
        mean += DVector::from_column_slice(p) * (w / total);
    }
    let mut cov = DMatrix::zeros(dim, dim);
    for (p, &w) in points.iter().zip(weights) {
        let d = DVector::from_column_slice(p) - &mean;
        cov += &d * d.transpose() * (w / total);
    }
    for i in 0..dim {
        cov[(i, i)] += 1e-10;
    }
    match cov.clone().cholesky() {
        Some(c) => c.l(),
        None => DMatrix::from_diagonal(&cov.diagonal().map(|v| v.max(1e-10).sqrt())),
    }
}

/// The tempered target `q^(1−β) L^β` a Metropolis step samples.
#[derive(Clone, Copy)]
struct Tempered<'a> {
    beta: f64,
    /// `ln q` of the reference (0 for the prior).
    log_reference: &'a dyn Fn(&[f64]) -> f64,
}

/// Evaluates a batch of points (the sampler's view of the likelihood).
type Evaluate<'a> = dyn FnMut(&[Vec<f64>]) -> Result<Vec<f64>, SmcError> + 'a;

/// The mode search's likelihood: points scored on the data up to a horizon (`None`: all).
type SearchEvaluate<'a> = dyn FnMut(Option<f64>, &[Vec<f64>]) -> Result<Vec<f64>, SmcError> + 'a;

/// Random-walk Metropolis steps of every particle at `beta` on `q^(1−β) L^β` (`ll`, `lq`: the
/// particles' log-likelihoods and log reference densities); returns the acceptance rate and adapts
/// `scale` after each step towards an acceptance of 0.25.
fn metropolis(
    (particles, ll, lq): (&mut [Vec<f64>], &mut [f64], &mut [f64]),
    target: Tempered,
    cholesky: &DMatrix<f64>,
    scale: &mut f64,
    steps: usize,
    rng: &mut ChaCha8Rng,
    evaluate: &mut Evaluate,
) -> Result<f64, SmcError> {
    let dim = cholesky.nrows();
    let (mut accepted, mut proposed) = (0usize, 0usize);
    for _ in 0..steps {
        let mut proposals = Vec::new();
        let mut owners = Vec::new();
        for (i, p) in particles.iter().enumerate() {
            let z = DVector::from_iterator(dim, (0..dim).map(|_| standard_normal(rng)));
            let step = cholesky * z * *scale;
            let q: Vec<f64> = (0..dim).map(|a| p[a] + step[a]).collect();
            if in_cube(&q) {
                proposals.push(q);
                owners.push(i);
            }
        }
        let uniforms: Vec<f64> = (0..owners.len()).map(|_| rng.random::<f64>()).collect();
        let values = if proposals.is_empty() {
            Vec::new()
        } else {
            evaluate(&proposals)?
        };
        let mut step_accepted = 0;
        for (k, (&i, q)) in owners.iter().zip(proposals).enumerate() {
            let reference = (target.log_reference)(&q);
            let beta = target.beta;
            let log_ratio = (1.0 - beta) * (reference - lq[i]) + beta * (values[k] - ll[i]);
            if values[k] > f64::NEG_INFINITY && (log_ratio >= 0.0 || uniforms[k].ln() < log_ratio) {
                particles[i] = q;
                ll[i] = values[k];
                lq[i] = reference;
                step_accepted += 1;
            }
        }
        let rate = step_accepted as f64 / particles.len() as f64;
        *scale = (*scale * (2.0 * (rate - 0.25)).exp()).clamp(0.01, 3.0);
        accepted += step_accepted;
        proposed += particles.len();
    }
    Ok(accepted as f64 / proposed.max(1) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A mode search of `population` x at most `generations`, from the default step.
    fn search(
        population: usize,
        generations: usize,
        first_horizon_s: Option<f64>,
    ) -> ModeSearchSettings {
        ModeSearchSettings {
            population,
            generations,
            initial_step: 0.3,
            reference_scale: 2.0,
            first_horizon_s,
        }
    }

    fn settings(seed: u64) -> SmcSettings {
        SmcSettings {
            particles: 2000,
            ess_fraction: 0.5,
            moves: 4,
            final_moves: 4,
            max_stages: 100,
            seed,
            mode_search: None,
            polish_iterations: 0,
            chaos_replays: 0,
            chaos_points: 1,
            prior_share: 0.0,
        }
    }

    #[test]
    fn the_mode_search_is_described_with_its_horizons() {
        assert_eq!(settings(0).mode_search_text(), "");
        let mut with = SmcSettings {
            mode_search: Some(search(16, 50, None)),
            ..settings(0)
        };
        assert_eq!(
            with.mode_search_text(),
            "CMA-ES mode search (16 x at most 50 generations), then "
        );
        with.prior_share = 0.5;
        assert_eq!(
            with.sampler_text(),
            "CMA-ES mode search (16 x at most 50 generations), then 2000 particles x 4 moves, \
             50 % of the reference from the prior"
        );
        with.mode_search = Some(search(16, 50, Some(0.5)));
        assert!(with
            .mode_search_text()
            .contains("generations per horizon, from the first 0.5 s doubling"));
    }

    /// A correlated 2-D Gaussian likelihood well inside the unit square: the posterior is that
    /// Gaussian (the box cuts less than 1e-6 of its mass).
    fn gaussian(p: &[f64]) -> f64 {
        let (mu, sd, rho) = ([0.4, 0.6], [0.05, 0.07], 0.8);
        let (a, b) = ((p[0] - mu[0]) / sd[0], (p[1] - mu[1]) / sd[1]);
        -(a * a - 2.0 * rho * a * b + b * b) / (2.0 * (1.0 - rho * rho))
    }

    #[test]
    fn recovers_a_known_two_dimensional_posterior() {
        let result = sample(2, &settings(3), 1.0, |_, _, points| {
            Ok(points.iter().map(|p| gaussian(p)).collect())
        })
        .unwrap();
        let n = result.draws.len() as f64;
        let mean = |a: usize| result.draws.iter().map(|p| p[a]).sum::<f64>() / n;
        let (m0, m1) = (mean(0), mean(1));
        let cov = |a: usize, b: usize, ma: f64, mb: f64| {
            result
                .draws
                .iter()
                .map(|p| (p[a] - ma) * (p[b] - mb))
                .sum::<f64>()
                / n
        };
        let (s0, s1) = (cov(0, 0, m0, m0).sqrt(), cov(1, 1, m1, m1).sqrt());
        let rho = cov(0, 1, m0, m1) / (s0 * s1);
        assert!(
            (m0 - 0.4).abs() < 0.006 && (m1 - 0.6).abs() < 0.008,
            "{m0} {m1}"
        );
        assert!((s0 / 0.05 - 1.0).abs() < 0.12, "sd0 {s0}");
        assert!((s1 / 0.07 - 1.0).abs() < 0.12, "sd1 {s1}");
        assert!((rho - 0.8).abs() < 0.06, "rho {rho}");
        assert_eq!(result.stages.last().unwrap().beta, 1.0);
        // Evidence: ∫ over the unit square of exp(ℓ) = 2π σ0 σ1 √(1 − ρ²).
        let exact = (std::f64::consts::TAU * 0.05 * 0.07 * 0.6f64).ln();
        assert!(
            (result.log_evidence - exact).abs() < 0.15,
            "{} vs {exact}",
            result.log_evidence
        );
        // Counted evaluations: the prior population and every proposal inside the box.
        assert!(result.evaluations > 2000 && result.evaluations <= 2000 * (1 + 4 * 20));
    }

    #[test]
    fn a_seed_fixes_the_result_and_a_resumed_run_continues_exactly() {
        let ll = |points: &[Vec<f64>]| points.iter().map(|p| gaussian(p)).collect::<Vec<_>>();
        let small = SmcSettings {
            particles: 200,
            ..settings(9)
        };
        let mut logged: Vec<(Vec<Vec<f64>>, Vec<f64>)> = Vec::new();
        let whole = sample(2, &small, 1.0, |batch, _, points| {
            assert_eq!(batch, logged.len());
            let values = ll(points);
            logged.push((points.to_vec(), values.clone()));
            Ok(values)
        })
        .unwrap();
        assert!(logged.len() > 5);
        // Interrupted after three batches...
        let mut partial = Vec::new();
        let stopped = sample(2, &small, 1.0, |batch, _, points| {
            if batch == 3 {
                return Err("stopped".into());
            }
            partial.push(ll(points));
            Ok(partial.last().unwrap().clone())
        });
        assert!(matches!(stopped, Err(SmcError::Likelihood(_))));
        // ...and resumed: the logged batches are served again, asked with the same points.
        let resumed = sample(2, &small, 1.0, |batch, _, points| {
            if batch < partial.len() {
                assert_eq!(points, &logged[batch].0[..], "batch {batch}");
                return Ok(partial[batch].clone());
            }
            Ok(ll(points))
        })
        .unwrap();
        assert_eq!(resumed, whole);
        let other = sample(2, &SmcSettings { seed: 10, ..small }, 1.0, |_, _, p| {
            Ok(ll(p))
        })
        .unwrap();
        assert_ne!(other.draws, whole.draws);
    }

    #[test]
    fn started_from_a_mode_search_it_recovers_the_posterior_and_its_evidence() {
        let searched = SmcSettings {
            particles: 1000,
            mode_search: Some(search(12, 100, None)),
            ..settings(4)
        };
        let result = sample(2, &searched, 1.0, |_, _, points| {
            Ok(points.iter().map(|p| gaussian(p)).collect())
        })
        .unwrap();
        assert!(!result.search.is_empty() && result.search.len() < 100);
        let n = result.draws.len() as f64;
        let mean = |a: usize| result.draws.iter().map(|p| p[a]).sum::<f64>() / n;
        let sd = |a: usize, m: f64| {
            (result.draws.iter().map(|p| (p[a] - m).powi(2)).sum::<f64>() / n).sqrt()
        };
        let (m0, m1) = (mean(0), mean(1));
        assert!(
            (m0 - 0.4).abs() < 0.008 && (m1 - 0.6).abs() < 0.01,
            "{m0} {m1}"
        );
        assert!((sd(0, m0) / 0.05 - 1.0).abs() < 0.15, "sd0 {}", sd(0, m0));
        assert!((sd(1, m1) / 0.07 - 1.0).abs() < 0.15, "sd1 {}", sd(1, m1));
        let exact = (std::f64::consts::TAU * 0.05 * 0.07 * 0.6f64).ln();
        assert!(
            (result.log_evidence - exact).abs() < 0.15,
            "{} vs {exact}",
            result.log_evidence
        );
    }

    /// A narrow Gaussian log-likelihood (sd 0.004 around (0.4, 0.6)) plus a term of standard
    /// deviation `tau` that changes completely between points a bit apart (a hash of their bits),
    /// as a film that folds one way or another: a rough likelihood whose roughness is known.
    fn chaotic(p: &[f64], tau: f64) -> f64 {
        let mut h = 0xcbf2_9ce4_8422_2325u64;
        for v in p {
            h = (h ^ v.to_bits()).wrapping_mul(0x100_0000_01b3);
            h ^= h >> 29;
        }
        let u = (h >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0;
        let (a, b) = ((p[0] - 0.4) / 0.004, (p[1] - 0.6) / 0.004);
        -0.5 * (a * a + b * b) + tau * 3f64.sqrt() * u
    }

    #[test]
    fn the_chaos_spread_is_pooled_within_points() {
        // Two points 100 apart, each replayed twice 2 apart: what one material's replays disagree
        // by is sqrt((2 + 2) / 2), not the spread across the points (57.7).
        let sd = chaos_sd(&[&[0.0, 2.0], &[100.0, 102.0]]).unwrap();
        assert!((sd - 2f64.sqrt()).abs() < 1e-12, "{sd}");
        // A replay that diverged drops out, and a point left with one finite value with it.
        let inf = f64::NEG_INFINITY;
        let sd = chaos_sd(&[&[0.0, 2.0, inf], &[5.0, inf]]).unwrap();
        assert!((sd - 2f64.sqrt()).abs() < 1e-12, "{sd}");
        assert!(chaos_sd(&[&[1.0, inf], &[inf, inf]]).is_err());
        // The replays must split evenly, at least two per point.
        let settings = |chaos_replays, chaos_points| SmcSettings {
            chaos_replays,
            chaos_points,
            mode_search: Some(search(12, 10, None)),
            ..settings(1)
        };
        assert!(check_settings(2, &settings(16, 4)).is_ok());
        for (replays, points) in [(16, 3), (16, 9), (16, 0), (16, 65)] {
            let err = check_settings(2, &settings(replays, points))
                .unwrap_err()
                .to_string();
            assert!(err.contains("chaos_points"), "{replays} {points}: {err}");
        }
    }

    #[test]
    fn chaos_replays_measure_the_roughness_and_sample_the_power_posterior() {
        let tau = 100.0;
        let with = |chaos_replays| SmcSettings {
            particles: 400,
            chaos_replays,
            mode_search: Some(search(12, 100, None)),
            ..settings(6)
        };
        let run = |s: &SmcSettings| {
            sample(2, s, 1.0, |_, _, points| {
                Ok(points.iter().map(|p| chaotic(p, tau)).collect())
            })
            .unwrap()
        };
        let sd = |r: &SmcResult, a: usize| {
            let n = r.draws.len() as f64;
            let m = r.draws.iter().map(|p| p[a]).sum::<f64>() / n;
            (r.draws.iter().map(|p| (p[a] - m).powi(2)).sum::<f64>() / n).sqrt()
        };
        let powered = run(&with(64));
        // The replays' spread is the known roughness, η its inverse.
        let chaos = powered.chaos_sd.unwrap();
        assert!((chaos / tau - 1.0).abs() < 0.25, "chaos sd {chaos}");
        assert_eq!(powered.likelihood_power, 1.0 / chaos);
        // The power posterior of a Gaussian likelihood is Gaussian, 1/√η as wide.
        let expected = 0.004 / powered.likelihood_power.sqrt();
        for a in 0..2 {
            let s = sd(&powered, a);
            assert!(
                (s / expected - 1.0).abs() < 0.3,
                "sd {a}: {s} against {expected}"
            );
        }
        // Without the replays the sampler chases the roughness: a posterior far narrower than
        // what one material's replays allow.
        // Shared by four of the search's good points, the replays measure the same roughness
        // (pooled within the points, not across them).
        let shared = run(&SmcSettings {
            chaos_points: 4,
            ..with(64)
        });
        let pooled = shared.chaos_sd.unwrap();
        assert_eq!(shared.chaos_points, 4);
        assert!(
            (pooled / tau - 1.0).abs() < 0.25,
            "pooled chaos sd {pooled}"
        );
        let plain = run(&with(0));
        assert_eq!((plain.likelihood_power, plain.chaos_sd), (1.0, None));
        assert!(sd(&plain, 0) < 0.3 * expected, "{}", sd(&plain, 0));
        assert!(powered.log_likelihoods.iter().all(|v| v.is_finite()));
    }

    /// Per axis of `result`'s draws: whether the 90 % interval (between the 5 % and 95 % order
    /// statistics) covers `centre`, and its width over the exact one of a Gaussian of sd `sd`.
    fn ninety_percent_intervals(
        result: &SmcResult,
        centre: &[f64],
        sd: &[f64],
    ) -> Vec<(bool, f64)> {
        let n = result.draws.len();
        (0..centre.len())
            .map(|a| {
                let mut u: Vec<f64> = result.draws.iter().map(|p| p[a]).collect();
                u.sort_by(f64::total_cmp);
                let (low, high) = (u[n * 5 / 100], u[n * 95 / 100]);
                (
                    low < centre[a] && centre[a] < high,
                    (high - low) / (2.0 * 1.645 * sd[a]),
                )
            })
            .collect()
    }

    #[test]
    fn a_reference_mixed_with_the_prior_lets_the_likelihood_set_the_width() {
        // A 10-D Gaussian posterior as wide as a tempered film's (sd 0.08-0.12 of the box per
        // axis), sampled by a population a simulator can afford (64, two moves per stage), with
        // the refinement handing the sampler a Laplace approximation fifty times narrower than
        // the posterior (what finite differences of a rough likelihood at one point give). From
        // that reference alone the population stays too narrow and misses the centre on a third
        // of the axes; with half of it on the prior, the likelihood sets the width.
        let dim = 10;
        let centre: Vec<f64> = (0..dim).map(|i| 0.35 + 0.03 * i as f64).collect();
        let sd: Vec<f64> = (0..dim).map(|i| 0.08 + 0.004 * i as f64).collect();
        let ll = |p: &[f64]| -> f64 {
            (0..dim)
                .map(|a| -0.5 * ((p[a] - centre[a]) / sd[a]).powi(2))
                .sum()
        };
        let run = |prior_share, seed| {
            let settings = SmcSettings {
                particles: 64,
                moves: 2,
                final_moves: 2,
                prior_share,
                mode_search: Some(search(16, 30, None)),
                ..settings(seed)
            };
            sample_refined(
                dim,
                &settings,
                1.0,
                |_, _, points| Ok(points.iter().map(|p| ll(p)).collect()),
                |best| {
                    let narrow = sd.iter().map(|s| (s / 50.0).powi(-2)).collect::<Vec<_>>();
                    Ok(Some(Laplace::from_information(
                        best.to_vec(),
                        &DMatrix::from_diagonal(&DVector::from_vec(narrow)),
                        0.1,
                    )))
                },
            )
            .unwrap()
        };
        let intervals = |result: &SmcResult| ninety_percent_intervals(result, &centre, &sd);
        // Over twelve seeds: the share of the 120 intervals that cover the centre, and their mean
        // width over the exact ones.
        let over_seeds = |prior_share| {
            let all: Vec<(bool, f64)> = (0..12)
                .flat_map(|seed| intervals(&run(prior_share, seed)))
                .collect();
            let covered = all.iter().filter(|(covers, _)| *covers).count();
            (
                covered,
                all.iter().map(|(_, w)| w).sum::<f64>() / all.len() as f64,
            )
        };
        let (covered, width) = over_seeds(0.5);
        assert!(
            covered >= 110 && (0.7..1.3).contains(&width),
            "{covered} {width}"
        );
        let (covered, width) = over_seeds(0.0);
        assert!(covered <= 90 && width < 0.65, "{covered} {width}");
        // A share must leave the Gaussian some of the reference, and needs a search to have one.
        for (share, search_too) in [(1.0, true), (-0.1, true), (0.5, false)] {
            let s = SmcSettings {
                prior_share: share,
                mode_search: search_too.then(|| search(12, 10, None)),
                ..settings(1)
            };
            let err = check_settings(2, &s).unwrap_err().to_string();
            assert!(err.contains("prior_share"), "{share}: {err}");
        }
    }

    #[test]
    fn the_mixed_reference_draws_what_its_density_says() {
        // A Gaussian mostly outside the box (mean at its edge, sd 1: a third inside), half the
        // mixture on the prior: the share of draws per tenth of the box matches the density's
        // integral there (a draw that picks the Gaussian keeps it until a proposal lands inside).
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let reference =
            Reference::new(vec![1.0], DMatrix::from_element(1, 1, 1.0), 0.5, &mut rng).unwrap();
        let n = 200_000;
        let draws = reference.draw(n, &mut rng).unwrap();
        for bin in 0..10 {
            let (low, high) = (0.1 * bin as f64, 0.1 * (bin + 1) as f64);
            let share =
                draws.iter().filter(|p| low <= p[0] && p[0] < high).count() as f64 / n as f64;
            let steps = 200;
            let mass: f64 = (0..steps)
                .map(|k| {
                    let x = low + (k as f64 + 0.5) * (high - low) / steps as f64;
                    reference.log_density(&[x]).exp() * (high - low) / steps as f64
                })
                .sum();
            assert!(
                (share - mass).abs() < 0.003,
                "bin {bin}: {share} drawn, {mass} density"
            );
        }
    }

    #[test]
    fn a_mode_search_finds_a_narrow_posterior_in_ten_dimensions() {
        // Sd 0.004 per axis around an off-centre point: the prior's population of 64 holds no
        // point within several widths of it.
        let centre: Vec<f64> = (0..10).map(|i| 0.15 + 0.07 * i as f64).collect();
        let ll = |p: &[f64]| {
            -0.5 * p
                .iter()
                .zip(&centre)
                .map(|(x, c)| ((x - c) / 0.004).powi(2))
                .sum::<f64>()
        };
        let searched = SmcSettings {
            particles: 64,
            moves: 4,
            final_moves: 8,
            mode_search: Some(search(16, 300, None)),
            ..settings(2)
        };
        let result = sample(10, &searched, 1.0, |_, _, points| {
            Ok(points.iter().map(|p| ll(p)).collect())
        })
        .unwrap();
        for (a, c) in centre.iter().enumerate() {
            let mut u: Vec<f64> = result.draws.iter().map(|p| p[a]).collect();
            u.sort_by(f64::total_cmp);
            let (low, high) = (u[3], u[60]);
            assert!(low < *c && *c < high, "axis {a}: [{low}, {high}] vs {c}");
            assert!(high - low < 0.03, "axis {a}: [{low}, {high}]");
        }
        assert!(result.evaluations < 10_000, "{}", result.evaluations);
    }

    #[test]
    fn the_laplace_covariance_inverts_the_information_and_caps_sloppy_directions() {
        let f = DMatrix::from_diagonal(&DVector::from_vec(vec![1e4, 1e-2]));
        let laplace = Laplace::from_information(vec![0.5, 0.5], &f, 0.1);
        assert!((laplace.covariance[(0, 0)] - 1e-4).abs() < 1e-12);
        assert!((laplace.covariance[(1, 1)] - 1e-2).abs() < 1e-12);
        assert!(laplace.covariance[(0, 1)].abs() < 1e-12);
    }

    #[test]
    fn a_refined_mode_search_starts_the_sampler_from_the_laplace_approximation() {
        // A correlated 10-D Gaussian posterior, sd 0.002-0.02 per axis, sampled by a population
        // as small as a simulator can afford (32, two moves per stage). The refinement (one
        // Newton step from the search's best point with the exact information, as Gauss-Newton
        // is on a quadratic) hands the sampler the posterior's own shape; the search's own
        // distribution after a few generations is not that shape, and its population collapses.
        let dim = 10;
        let centre: Vec<f64> = (0..dim).map(|i| 0.2 + 0.06 * i as f64).collect();
        let sd: Vec<f64> = (0..dim).map(|i| 0.002 * 1.29f64.powi(i as i32)).collect();
        let correlation = |a: usize, b: usize| if a == b { 1.0 } else { 0.3 };
        let covariance = DMatrix::from_fn(dim, dim, |a, b| correlation(a, b) * sd[a] * sd[b]);
        let information = covariance.clone().try_inverse().unwrap();
        let ll = |p: &[f64]| {
            let d = DVector::from_iterator(dim, p.iter().zip(&centre).map(|(x, c)| x - c));
            -0.5 * (d.transpose() * &information * &d)[(0, 0)]
        };
        let settings = SmcSettings {
            particles: 32,
            moves: 2,
            final_moves: 2,
            mode_search: Some(search(16, 8, None)),
            ..settings(8)
        };
        let run = |refined: bool| {
            let mut handed = Vec::new();
            let result = sample_refined(
                dim,
                &settings,
                1.0,
                |_, _, points| Ok(points.iter().map(|p| ll(p)).collect()),
                |best| {
                    handed = best.to_vec();
                    let offset =
                        DVector::from_iterator(dim, best.iter().zip(&centre).map(|(x, c)| x - c));
                    let newton = DVector::from_column_slice(best) - &offset;
                    Ok(refined.then(|| {
                        Laplace::from_information(
                            newton.iter().copied().collect(),
                            &information,
                            0.1,
                        )
                    }))
                },
            )
            .unwrap();
            (result, handed)
        };
        let intervals = |result: &SmcResult| ninety_percent_intervals(result, &centre, &sd);
        let (refined, handed) = run(true);
        assert!(
            ll(&handed) < -5.0,
            "the search stopped short: {}",
            ll(&handed)
        );
        let found = intervals(&refined);
        assert!(found.iter().all(|&(covers, _)| covers), "{found:?}");
        assert!(
            found.iter().all(|&(_, w)| (0.5..1.5).contains(&w)),
            "{found:?}"
        );
        let (plain, _) = run(false);
        let collapsed = intervals(&plain);
        assert!(
            collapsed.iter().filter(|(covers, _)| *covers).count() <= 3,
            "{collapsed:?}"
        );
    }

    #[test]
    fn a_growing_horizon_finds_a_narrow_mode_that_a_search_on_the_whole_data_misses() {
        // On the whole data: a narrow peak (sd 0.01) at `c`, and a broad lower basin around `d`
        // that fills the rest of the box, as a film whose replays part beyond a basin's edge.
        // Over shorter starts the data only say "near c", more sharply the longer the start
        // (sd 0.08, 0.04, 0.02 at 1/8, 1/4, 1/2 of the data).
        let (c, d) = ([0.23, 0.71, 0.37, 0.62], [0.75, 0.25, 0.8, 0.2]);
        let sq = |p: &[f64], centre: &[f64; 4], sd: f64| {
            p.iter()
                .zip(centre)
                .map(|(x, m)| ((x - m) / sd).powi(2))
                .sum::<f64>()
        };
        let ll = |horizon: Option<f64>, p: &[f64]| match horizon {
            Some(h) => -0.5 * sq(p, &c, 0.01 / h),
            None => (-0.5 * sq(p, &c, 0.01)).max(-30.0 - 0.5 * sq(p, &d, 0.3)),
        };
        let searched = |first_horizon_s| SmcSettings {
            particles: 64,
            moves: 4,
            final_moves: 4,
            mode_search: Some(search(12, 100, first_horizon_s)),
            ..settings(5)
        };
        let run = |settings: &SmcSettings| {
            let mut horizons = Vec::new();
            let result = sample(4, settings, 1.0, |_, h, points| {
                horizons.push(h);
                Ok(points.iter().map(|p| ll(h, p)).collect())
            })
            .unwrap();
            (result, horizons)
        };
        let near_c = |p: &[f64]| p.iter().zip(&c).all(|(x, m)| (x - m).abs() < 0.04);
        let (growing, horizons) = run(&searched(Some(0.125)));
        assert_eq!(horizons[0], Some(0.125));
        assert!(horizons.contains(&Some(0.5)) && horizons.last() == Some(&None));
        assert!(growing.search.iter().any(|g| g.horizon_s.is_none()));
        assert!(
            growing.draws.iter().all(|p| near_c(p)),
            "{:?}",
            growing.draws[0]
        );
        let (whole, _) = run(&searched(None));
        assert!(
            !whole.draws.iter().any(|p| near_c(p)),
            "{:?}",
            whole.draws[0]
        );
    }

    #[test]
    fn zero_likelihood_everywhere_and_bad_settings_are_errors() {
        let none = sample(2, &settings(0), 1.0, |_, _, p| {
            Ok(vec![f64::NEG_INFINITY; p.len()])
        });
        assert!(matches!(none, Err(SmcError::Degenerate { stage: 0 })));
        let few = SmcSettings {
            particles: 5,
            ..settings(0)
        };
        let err = sample(2, &few, 1.0, |_, _, p| Ok(vec![0.0; p.len()])).unwrap_err();
        assert!(err.to_string().contains("particles = 5"), "{err}");
    }
}
