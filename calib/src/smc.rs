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
//! Determinism: every random draw comes from one ChaCha stream in a fixed order, and the
//! likelihoods come back in batch order, so the result depends on the seed and the likelihood alone
//! (not on threads). Resume: [`sample`] asks for batches by index; a caller that logs every batch
//! can serve the logged ones again and the run continues exactly where it stopped.

use nalgebra::{DMatrix, DVector};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

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
    /// Log of the model evidence estimate `ln ∫ prior · L` (sum of the stages' log mean weights).
    pub log_evidence: f64,
}

/// Samples the posterior `prior · L` on the unit cube `[0, 1]^dim` (uniform prior).
///
/// `log_likelihood(batch, points)` returns one value per point (`−∞` or NaN: zero likelihood),
/// `batch` counting the calls from 0 in a fixed order (for logging and resuming).
pub fn sample(
    dim: usize,
    settings: &SmcSettings,
    mut log_likelihood: impl FnMut(usize, &[Vec<f64>]) -> Result<Vec<f64>, String>,
) -> Result<SmcResult, SmcError> {
    check_settings(dim, settings)?;
    let n = settings.particles;
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    let mut batch = 0usize;
    let mut evaluations = 0usize;
    let mut evaluate = |points: &[Vec<f64>], evaluations: &mut usize| {
        let values = log_likelihood(batch, points).map_err(SmcError::Likelihood)?;
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
    let mut particles: Vec<Vec<f64>> = (0..n)
        .map(|_| (0..dim).map(|_| rng.random::<f64>()).collect())
        .collect();
    let mut ll = evaluate(&particles, &mut evaluations)?;
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
        let best = ll.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        if best == f64::NEG_INFINITY {
            return Err(SmcError::Degenerate {
                stage: stages.len(),
            });
        }
        let next = next_beta(&ll, beta, settings.ess_fraction * n as f64);
        let weights = incremental_weights(&ll, next - beta);
        let mean_weight = weights.iter().sum::<f64>() / n as f64;
        log_evidence += mean_weight.ln() + (next - beta) * best;
        let ess = effective_sample_size(&weights);
        let cholesky = proposal_factor(&particles, &weights, dim);
        let chosen = systematic_resample(&weights, &mut rng);
        particles = chosen.iter().map(|&i| particles[i].clone()).collect();
        ll = chosen.iter().map(|&i| ll[i]).collect();
        beta = next;
        let acceptance = metropolis(
            &mut particles,
            &mut ll,
            beta,
            &cholesky,
            &mut scale,
            settings.moves,
            &mut rng,
            &mut |p| evaluate(p, &mut evaluations),
        )?;
        stages.push(Stage {
            beta,
            ess,
            acceptance,
            scale,
            evaluations,
            best_log_likelihood: ll.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        });
    }
    if settings.final_moves > 0 {
        let weights = vec![1.0; n];
        let cholesky = proposal_factor(&particles, &weights, dim);
        let acceptance = metropolis(
            &mut particles,
            &mut ll,
            1.0,
            &cholesky,
            &mut scale,
            settings.final_moves,
            &mut rng,
            &mut |p| evaluate(p, &mut evaluations),
        )?;
        stages.push(Stage {
            beta: 1.0,
            ess: n as f64,
            acceptance,
            scale,
            evaluations,
            best_log_likelihood: ll.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        });
    }
    Ok(SmcResult {
        draws: particles,
        log_likelihoods: ll,
        stages,
        evaluations,
        log_evidence,
    })
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

/// Evaluates a batch of points (the sampler's view of the likelihood).
type Evaluate<'a> = dyn FnMut(&[Vec<f64>]) -> Result<Vec<f64>, SmcError> + 'a;

/// Random-walk Metropolis steps of every particle at `beta`; returns the acceptance rate and adapts
/// `scale` after each step towards an acceptance of 0.25.
#[allow(clippy::too_many_arguments)]
fn metropolis(
    particles: &mut [Vec<f64>],
    ll: &mut [f64],
    beta: f64,
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
            if q.iter().all(|v| (0.0..=1.0).contains(v)) {
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
            let log_ratio = beta * (values[k] - ll[i]);
            if values[k] > f64::NEG_INFINITY && (log_ratio >= 0.0 || uniforms[k].ln() < log_ratio) {
                particles[i] = q;
                ll[i] = values[k];
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

/// A standard normal draw (Box–Muller).
fn standard_normal(rng: &mut ChaCha8Rng) -> f64 {
    let u: f64 = 1.0 - rng.random::<f64>();
    let v: f64 = rng.random();
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(seed: u64) -> SmcSettings {
        SmcSettings {
            particles: 2000,
            ess_fraction: 0.5,
            moves: 4,
            final_moves: 4,
            max_stages: 100,
            seed,
        }
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
        let result = sample(2, &settings(3), |_, points| {
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
        let whole = sample(2, &small, |batch, points| {
            assert_eq!(batch, logged.len());
            let values = ll(points);
            logged.push((points.to_vec(), values.clone()));
            Ok(values)
        })
        .unwrap();
        assert!(logged.len() > 5);
        // Interrupted after three batches...
        let mut partial = Vec::new();
        let stopped = sample(2, &small, |batch, points| {
            if batch == 3 {
                return Err("stopped".into());
            }
            partial.push(ll(points));
            Ok(partial.last().unwrap().clone())
        });
        assert!(matches!(stopped, Err(SmcError::Likelihood(_))));
        // ...and resumed: the logged batches are served again, asked with the same points.
        let resumed = sample(2, &small, |batch, points| {
            if batch < partial.len() {
                assert_eq!(points, &logged[batch].0[..], "batch {batch}");
                return Ok(partial[batch].clone());
            }
            Ok(ll(points))
        })
        .unwrap();
        assert_eq!(resumed, whole);
        let other = sample(2, &SmcSettings { seed: 10, ..small }, |_, p| Ok(ll(p))).unwrap();
        assert_ne!(other.draws, whole.draws);
    }

    #[test]
    fn zero_likelihood_everywhere_and_bad_settings_are_errors() {
        let none = sample(2, &settings(0), |_, p| Ok(vec![f64::NEG_INFINITY; p.len()]));
        assert!(matches!(none, Err(SmcError::Degenerate { stage: 0 })));
        let few = SmcSettings {
            particles: 5,
            ..settings(0)
        };
        let err = sample(2, &few, |_, p| Ok(vec![0.0; p.len()])).unwrap_err();
        assert!(err.to_string().contains("particles = 5"), "{err}");
    }
}
