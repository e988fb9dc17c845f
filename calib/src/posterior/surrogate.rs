//! The fitted surrogates of a calibration's discrepancy and failures, the likelihood they give,
//! and where the sampler's walkers start.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::gp::GaussianProcess;

/// The fitted surrogates and what the likelihood needs besides them.
pub(super) struct Surrogate {
    /// Fitted to `ln(loss)` of the finite evaluations.
    pub(super) gp: GaussianProcess,
    /// Fitted to the failure indicator (1 failed, 0 finite) of every evaluation; none when no
    /// evaluation failed.
    pub(super) failure: Option<GaussianProcess>,
    /// The learned noise variance `σ_n²` of `gp` (units of `ln(loss)`²).
    pub(super) noise_var: f64,
    /// The threshold `ε` on `ln(loss)`.
    pub(super) epsilon: f64,
}

impl Surrogate {
    /// `ln(P(success) · P(ln loss(u) < ε))` under the surrogates; `-inf` outside the unit cube and
    /// where failure is certain.
    pub(super) fn log_likelihood(&self, u: &[f64]) -> f64 {
        if !u.iter().all(|v| (0.0..=1.0).contains(v)) {
            return f64::NEG_INFINITY;
        }
        let success = self.success_probability(u);
        if success <= 0.0 {
            return f64::NEG_INFINITY;
        }
        let (mean, var) = self.gp.predict(u);
        success.ln() + log_normal_cdf((self.epsilon - mean) / (var + self.noise_var).sqrt())
    }

    /// The probability that the simulation succeeds at `u`: one minus the failure surrogate's mean,
    /// clamped to [0, 1] (least-squares classification).
    pub(super) fn success_probability(&self, u: &[f64]) -> f64 {
        self.failure
            .as_ref()
            .map_or(1.0, |f| (1.0 - f.predict(u).0).clamp(0.0, 1.0))
    }
}

/// Starting points of the walkers: prior draws and the evaluated points, resampled in proportion to
/// their likelihood (systematic resampling) and spread by a small uniform jitter so that no two
/// walkers coincide. Starting near the likely region shortens the burn-in when the likelihood is
/// sharp.
pub(super) fn starting_walkers(
    log_likelihood: &impl Fn(&[f64]) -> f64,
    evaluated: &[Vec<f64>],
    walkers: usize,
    dim: usize,
    seed: u64,
) -> Vec<Vec<f64>> {
    const JITTER: f64 = 0.02;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(u64::MAX);
    let mut pool: Vec<Vec<f64>> = evaluated.to_vec();
    pool.extend((0..64 * walkers).map(|_| (0..dim).map(|_| rng.random::<f64>()).collect()));
    let log_weights: Vec<f64> = pool.iter().map(|u| log_likelihood(u)).collect();
    let top = log_weights
        .iter()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max);
    let weights: Vec<f64> = log_weights.iter().map(|l| (l - top).exp()).collect();
    let total: f64 = weights.iter().sum();
    let best = (0..pool.len())
        .max_by(|&a, &b| log_weights[a].total_cmp(&log_weights[b]))
        .expect("a non-empty pool");
    // In (0, 1]: every target is above zero, so no zero-weight point is picked.
    let offset = 1.0 - rng.random::<f64>();
    let mut start = Vec::with_capacity(walkers);
    let (mut cumulative, mut index) = (weights[0], 0);
    for k in 0..walkers {
        let target = (k as f64 + offset) / walkers as f64 * total;
        while cumulative < target && index + 1 < pool.len() {
            index += 1;
            cumulative += weights[index];
        }
        // Rounding can run past the last positive weight.
        let centre = if weights[index] > 0.0 { index } else { best };
        // A jittered point may leave the likely region (e.g. next to a failed evaluation): jitter
        // less, and at worst start at the pool point itself.
        let mut jitter = JITTER;
        let point = loop {
            let candidate: Vec<f64> = pool[centre]
                .iter()
                .map(|v| (v + jitter * (2.0 * rng.random::<f64>() - 1.0)).clamp(0.0, 1.0))
                .collect();
            if log_likelihood(&candidate).is_finite() {
                break candidate;
            }
            if jitter < JITTER / 100.0 {
                break pool[centre].clone();
            }
            jitter /= 2.0;
        };
        start.push(point);
    }
    start
}

/// `ln Φ(z)` of the standard normal CDF, finite far into the lower tail (where `Φ` underflows) by
/// its asymptotic series, so that the sampler can climb out of regions of negligible likelihood.
pub fn log_normal_cdf(z: f64) -> f64 {
    if z > -30.0 {
        (0.5 * libm::erfc(-z / std::f64::consts::SQRT_2)).ln()
    } else {
        // Φ(z) = φ(z)/|z| · (1 − 1/z² + 3/z⁴ − 15/z⁶ + …); the next term is below 2e-10 here.
        let z2 = z * z;
        -0.5 * z2 - (-z).ln() - 0.5 * (2.0 * std::f64::consts::PI).ln()
            + (1.0 - 1.0 / z2 + 3.0 / (z2 * z2) - 15.0 / (z2 * z2 * z2)).ln()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_normal_cdf_is_accurate_and_continuous_in_the_tail() {
        for (z, phi) in [
            (0.0, 0.5),
            (1.0, 0.841_344_746_068_543),
            (-1.96, 0.024_997_895_148_220),
            (-10.0, 7.619_853_024_160_527e-24),
        ] {
            let got = log_normal_cdf(z).exp();
            assert!(
                (got - phi).abs() < 1e-12 * phi.max(1e-300) + 1e-15,
                "Φ({z}) = {got}"
            );
        }
        // The two branches meet at z = −30.
        let erfc_branch = (0.5 * libm::erfc(30.0 / std::f64::consts::SQRT_2)).ln();
        assert!((log_normal_cdf(-30.0) - erfc_branch).abs() < 1e-8);
        assert!(log_normal_cdf(-1e3).is_finite() && log_normal_cdf(-1e3) < -4e5);
    }
}
