//! An affine-invariant ensemble sampler (Goodman & Weare 2010, the "stretch move" of emcee).
//!
//! Why this sampler: the posterior of a calibration is strongly correlated and badly scaled (a
//! stiffness and a damping that trade off, a flat direction next to a sharp one), and the stretch
//! move is invariant under affine maps of the space, so it needs no tuned proposal covariance. Its
//! one parameter, the stretch scale `a`, is 2 as in the paper.
//!
//! Determinism: the walkers are split into two halves; each half moves with the positions of the
//! other half fixed, so its walkers move independently of each other (in parallel on rayon). Every
//! walker draws from its own random stream (the seed's stream number = the walker's index), so the
//! chain depends only on the seed and the starting points, never on the number of threads.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// Errors of the sampler.
#[derive(Debug, thiserror::Error)]
pub enum McmcError {
    /// Too few walkers, or walkers of different dimensions.
    #[error("ensemble: {0}")]
    Ensemble(String),
    /// A starting point has zero density: no move away from it could ever be accepted reliably.
    #[error("walker {walker} starts where the log-density is {value} (expected a finite value)")]
    Start {
        /// Index of the walker.
        walker: usize,
        /// Its log-density.
        value: f64,
    },
}

/// Settings of the ensemble sampler.
#[derive(Debug, Clone, PartialEq)]
pub struct EnsembleSettings {
    /// Steps discarded at the start of the chain (every walker moves once per step).
    pub burn_in: usize,
    /// Keep every `thin`-th step after the burn-in.
    pub thin: usize,
    /// Stretch scale `a` (> 1): proposals `z` are drawn from `g(z) ∝ 1/√z` on `[1/a, a]`.
    pub stretch: f64,
    /// Seed of every random choice.
    pub seed: u64,
}

impl Default for EnsembleSettings {
    fn default() -> Self {
        Self {
            burn_in: 1000,
            thin: 10,
            stretch: 2.0,
            seed: 0,
        }
    }
}

/// The draws of a chain after burn-in and thinning.
#[derive(Debug, Clone, PartialEq)]
pub struct Chain {
    /// Draws, step-major (all walkers of a kept step, then the next kept step).
    pub draws: Vec<Vec<f64>>,
    /// The log-density of every draw.
    pub log_densities: Vec<f64>,
    /// Accepted proposals / all proposals, burn-in included (0.2–0.5 is healthy).
    pub acceptance: f64,
}

/// One walker: position, log-density and its own random stream.
struct Walker {
    position: Vec<f64>,
    log_density: f64,
    rng: ChaCha8Rng,
    accepted: usize,
}

/// Samples `log_density` (up to a constant; `-inf` outside its support) with the stretch move.
///
/// `start` gives one point per walker (an even number, at least twice the dimension plus two, with
/// finite log-density). Returns `draws` points: the walkers' positions at every `thin`-th step
/// after `burn_in`, truncated to `draws`.
pub fn sample(
    log_density: &(impl Fn(&[f64]) -> f64 + Sync),
    start: &[Vec<f64>],
    draws: usize,
    settings: &EnsembleSettings,
) -> Result<Chain, McmcError> {
    let dim = start.first().map_or(0, Vec::len);
    if dim == 0 || start.iter().any(|p| p.len() != dim) {
        return Err(McmcError::Ensemble(
            "starting points must share one non-zero dimension".into(),
        ));
    }
    if !start.len().is_multiple_of(2) || start.len() < 2 * dim + 2 {
        return Err(McmcError::Ensemble(format!(
            "{} walkers in {dim}-D: expected an even number of at least {}",
            start.len(),
            2 * dim + 2
        )));
    }
    if settings.stretch.is_nan() || settings.stretch <= 1.0 {
        return Err(McmcError::Ensemble(format!(
            "stretch scale {} (expected > 1)",
            settings.stretch
        )));
    }
    let mut walkers: Vec<Walker> = start
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
            rng.set_stream(i as u64);
            Walker {
                position: p.clone(),
                log_density: log_density(p),
                rng,
                accepted: 0,
            }
        })
        .collect();
    if let Some((walker, w)) = walkers
        .iter()
        .enumerate()
        .find(|(_, w)| !w.log_density.is_finite())
    {
        return Err(McmcError::Start {
            walker,
            value: w.log_density,
        });
    }

    let half = walkers.len() / 2;
    let thin = settings.thin.max(1);
    let mut chain = Chain {
        draws: Vec::with_capacity(draws + walkers.len()),
        log_densities: Vec::with_capacity(draws + walkers.len()),
        acceptance: 0.0,
    };
    let mut steps = 0;
    while chain.draws.len() < draws {
        for moving_first in [true, false] {
            let (first, second) = walkers.split_at_mut(half);
            let (moving, fixed) = if moving_first {
                (first, &*second)
            } else {
                (second, &*first)
            };
            let partners: Vec<&[f64]> = fixed.iter().map(|w| w.position.as_slice()).collect();
            moving
                .par_iter_mut()
                .for_each(|w| stretch_move(w, &partners, log_density, settings.stretch));
        }
        steps += 1;
        if steps > settings.burn_in && (steps - settings.burn_in).is_multiple_of(thin) {
            for w in &walkers {
                chain.draws.push(w.position.clone());
                chain.log_densities.push(w.log_density);
            }
        }
    }
    chain.draws.truncate(draws);
    chain.log_densities.truncate(draws);
    let accepted: usize = walkers.iter().map(|w| w.accepted).sum();
    chain.acceptance = accepted as f64 / (steps * walkers.len()).max(1) as f64;
    Ok(chain)
}

/// One stretch move of `walker` towards a random walker of the other half:
/// `y = x_j + z (x − x_j)`, accepted with probability `min(1, z^(d−1) p(y) / p(x))`.
fn stretch_move(
    walker: &mut Walker,
    partners: &[&[f64]],
    log_density: &impl Fn(&[f64]) -> f64,
    stretch: f64,
) {
    let u: f64 = walker.rng.random();
    let z = ((stretch - 1.0) * u + 1.0).powi(2) / stretch;
    let partner = partners[walker.rng.random_range(0..partners.len())];
    let proposal: Vec<f64> = walker
        .position
        .iter()
        .zip(partner)
        .map(|(x, xj)| xj + z * (x - xj))
        .collect();
    let proposed = log_density(&proposal);
    let log_ratio = (walker.position.len() as f64 - 1.0) * z.ln() + proposed - walker.log_density;
    let accept: f64 = walker.rng.random();
    // `ln(accept) < log_ratio` is false for a NaN or `-inf` proposal: it stays where it is.
    if accept.ln() < log_ratio {
        walker.position = proposal;
        walker.log_density = proposed;
        walker.accepted += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A correlated 3-D Gaussian with mean `MEAN` and covariance `COV` (precision by hand below).
    const MEAN: [f64; 3] = [1.0, -2.0, 0.5];
    const COV: [[f64; 3]; 3] = [[1.0, 0.8, 0.0], [0.8, 2.0, -0.3], [0.0, -0.3, 0.25]];

    fn precision() -> nalgebra::Matrix3<f64> {
        nalgebra::Matrix3::from_fn(|i, j| COV[i][j])
            .try_inverse()
            .unwrap()
    }

    fn gaussian_log_density(p: &[f64]) -> f64 {
        let d = nalgebra::Vector3::from_fn(|i, _| p[i] - MEAN[i]);
        -0.5 * (d.transpose() * precision() * d)[0]
    }

    fn start(walkers: usize) -> Vec<Vec<f64>> {
        let mut rng = ChaCha8Rng::seed_from_u64(99);
        (0..walkers)
            .map(|_| (0..3).map(|_| rng.random::<f64>() * 4.0 - 2.0).collect())
            .collect()
    }

    fn settings(seed: u64) -> EnsembleSettings {
        EnsembleSettings {
            burn_in: 300,
            thin: 5,
            seed,
            ..EnsembleSettings::default()
        }
    }

    fn run_on(threads: usize, seed: u64) -> Chain {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| sample(&gaussian_log_density, &start(32), 20_000, &settings(seed)).unwrap())
    }

    #[test]
    fn recovers_mean_and_covariance_of_a_correlated_gaussian() {
        // Tolerance: 20 000 draws of 32 walkers thinned by 5 are a few thousand independent draws;
        // the mean is within 0.1 (about 4 standard errors of the widest coordinate) and every
        // covariance entry within 0.15 of the truth.
        let chain = run_on(2, 7);
        assert_eq!(chain.draws.len(), 20_000);
        let n = chain.draws.len() as f64;
        let mean: Vec<f64> = (0..3)
            .map(|i| chain.draws.iter().map(|p| p[i]).sum::<f64>() / n)
            .collect();
        for i in 0..3 {
            assert!((mean[i] - MEAN[i]).abs() < 0.1, "mean {mean:?}");
            for j in 0..3 {
                let cov = chain
                    .draws
                    .iter()
                    .map(|p| (p[i] - mean[i]) * (p[j] - mean[j]))
                    .sum::<f64>()
                    / (n - 1.0);
                assert!(
                    (cov - COV[i][j]).abs() < 0.15,
                    "cov[{i}][{j}] = {cov}, expected {}",
                    COV[i][j]
                );
            }
        }
        assert!(
            chain.acceptance > 0.2 && chain.acceptance < 0.8,
            "acceptance {}",
            chain.acceptance
        );
    }

    #[test]
    fn is_deterministic_for_a_seed_and_independent_of_the_thread_count() {
        let one = run_on(1, 3);
        let two = run_on(2, 3);
        assert_eq!(one, two);
        assert_ne!(one.draws, run_on(2, 4).draws);
    }

    #[test]
    fn stays_inside_a_bounded_support_and_rejects_bad_starts() {
        // Uniform on the unit square: every draw inside, the marginals uniform.
        let inside = |p: &[f64]| {
            if p.iter().all(|v| (0.0..=1.0).contains(v)) {
                0.0
            } else {
                f64::NEG_INFINITY
            }
        };
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let start: Vec<Vec<f64>> = (0..8)
            .map(|_| vec![rng.random::<f64>(), rng.random::<f64>()])
            .collect();
        let chain = sample(&inside, &start, 8000, &settings(0)).unwrap();
        assert!(chain
            .draws
            .iter()
            .flatten()
            .all(|v| (0.0..=1.0).contains(v)));
        let below_half = chain.draws.iter().filter(|p| p[0] < 0.5).count() as f64 / 8000.0;
        assert!((below_half - 0.5).abs() < 0.05, "{below_half}");

        let mut bad = start.clone();
        bad[3] = vec![2.0, 0.5];
        assert!(matches!(
            sample(&inside, &bad, 10, &settings(0)),
            Err(McmcError::Start { walker: 3, .. })
        ));
        assert!(matches!(
            sample(&inside, &start[..5], 10, &settings(0)),
            Err(McmcError::Ensemble(_))
        ));
    }
}
