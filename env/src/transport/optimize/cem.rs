//! The cross-entropy method: [`Cem`], the sampling distribution (a diagonal Gaussian clipped to
//! the bounds of the decision variables), its candidates and the update from their costs; and
//! [`RiskMeasure`], how a candidate's costs over K packages combine into one.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// Settings of the cross-entropy method.
#[derive(Debug, Clone, PartialEq)]
pub struct CemSettings {
    /// Candidates per iteration (the distribution's mean is the first).
    pub population: usize,
    /// Lowest-cost candidates the distribution is refitted to.
    pub elites: usize,
    /// Weight of the elites' mean and spread in each update (1 = replace the old ones).
    pub smoothing: f64,
    /// Seed of the samples.
    pub seed: u64,
}

/// The cross-entropy method's sampling distribution: a diagonal Gaussian whose samples are
/// clipped to `[lower, upper]`.
#[derive(Debug, Clone)]
pub struct Cem {
    /// Mean of each decision variable.
    pub mean: Vec<f64>,
    /// Standard deviation of each decision variable.
    pub std: Vec<f64>,
    lower: Vec<f64>,
    upper: Vec<f64>,
    settings: CemSettings,
    rng: ChaCha8Rng,
}

impl Cem {
    /// The distribution at `mean` with spread `std`, within `[lower, upper]`.
    pub fn new(
        mean: Vec<f64>,
        std: Vec<f64>,
        lower: Vec<f64>,
        upper: Vec<f64>,
        settings: CemSettings,
    ) -> Result<Self, String> {
        let n = mean.len();
        if std.len() != n || lower.len() != n || upper.len() != n || n == 0 {
            return Err(format!(
                "{n} means, {} spreads, {} lower and {} upper bounds: expected as many, >= 1",
                std.len(),
                lower.len(),
                upper.len()
            ));
        }
        if settings.population < 2 || settings.elites == 0 || settings.elites > settings.population
        {
            return Err(format!(
                "population {} and elites {}: expected population >= 2 and 1 <= elites <= \
                 population",
                settings.population, settings.elites
            ));
        }
        if !(settings.smoothing > 0.0 && settings.smoothing <= 1.0) {
            return Err(format!(
                "smoothing {}: expected in (0, 1]",
                settings.smoothing
            ));
        }
        let rng = ChaCha8Rng::seed_from_u64(settings.seed);
        let mean = mean
            .iter()
            .zip(lower.iter().zip(&upper))
            .map(|(m, (l, u))| m.clamp(*l, *u))
            .collect();
        Ok(Self {
            mean,
            std,
            lower,
            upper,
            settings,
            rng,
        })
    }

    /// This iteration's candidates: the mean, then `population - 1` clipped samples (drawn in
    /// order from the seeded stream, so the same whatever the threads that score them).
    pub fn candidates(&mut self) -> Vec<Vec<f64>> {
        let mut out = vec![self.mean.clone()];
        for _ in 1..self.settings.population {
            out.push(
                (0..self.mean.len())
                    .map(|i| {
                        let z: f64 = StandardNormal.sample(&mut self.rng);
                        (self.mean[i] + self.std[i] * z).clamp(self.lower[i], self.upper[i])
                    })
                    .collect(),
            );
        }
        out
    }

    /// Refits the distribution to the `elites` lowest-cost `candidates` (ties keep the earlier
    /// candidate; a non-finite cost ranks last), blended with the old one by `smoothing`.
    /// Returns the index of the lowest-cost candidate.
    pub fn update(&mut self, candidates: &[Vec<f64>], costs: &[f64]) -> usize {
        let rank = |c: f64| if c.is_finite() { c } else { f64::INFINITY };
        let mut order: Vec<usize> = (0..candidates.len()).collect();
        order.sort_by(|&a, &b| rank(costs[a]).total_cmp(&rank(costs[b])).then(a.cmp(&b)));
        let elites = &order[..self.settings.elites.min(order.len())];
        let w = self.settings.smoothing;
        let count = elites.len() as f64;
        for (i, (mean, std)) in self.mean.iter_mut().zip(&mut self.std).enumerate() {
            let m = elites.iter().map(|&e| candidates[e][i]).sum::<f64>() / count;
            let var = elites
                .iter()
                .map(|&e| (candidates[e][i] - m).powi(2))
                .sum::<f64>()
                / count;
            *mean = w * m + (1.0 - w) * *mean;
            *std = w * var.sqrt() + (1.0 - w) * *std;
        }
        order[0]
    }
}

/// How a candidate's costs over K packages combine into one: `(1 - weight) x mean + weight x
/// quantile`, the quantile by linear interpolation between the sorted costs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RiskMeasure {
    /// Quantile level in [0, 1] (0.9: the cost nine packages in ten stay below).
    pub quantile: f64,
    /// Weight of the quantile in [0, 1] (0: the mean alone).
    pub weight: f64,
}

impl RiskMeasure {
    /// The risk of `costs` (one per package; at least one).
    pub fn of(&self, costs: &[f64]) -> f64 {
        let mean = costs.iter().sum::<f64>() / costs.len() as f64;
        if self.weight == 0.0 {
            return mean;
        }
        let mut sorted = costs.to_vec();
        sorted.sort_by(f64::total_cmp);
        let x = self.quantile.clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
        let i = (x.floor() as usize).min(sorted.len() - 1);
        let j = (i + 1).min(sorted.len() - 1);
        let q = sorted[i] + (sorted[j] - sorted[i]) * (x - i as f64);
        (1.0 - self.weight) * mean + self.weight * q
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(population: usize, elites: usize, smoothing: f64) -> CemSettings {
        CemSettings {
            population,
            elites,
            smoothing,
            seed: 7,
        }
    }

    #[test]
    fn cem_candidates_are_seeded_bounded_and_start_with_the_mean() {
        let make = || {
            Cem::new(
                vec![0.5, 0.0],
                vec![1.0, 0.2],
                vec![0.0, -0.1],
                vec![1.0, 0.1],
                settings(50, 5, 1.0),
            )
            .unwrap()
        };
        let (mut a, mut b) = (make(), make());
        let candidates = a.candidates();
        assert_eq!(candidates, b.candidates());
        assert_eq!(candidates[0], vec![0.5, 0.0]);
        assert_eq!(candidates.len(), 50);
        assert!(candidates
            .iter()
            .all(|c| (0.0..=1.0).contains(&c[0]) && (-0.1..=0.1).contains(&c[1])));
        // Samples differ from each other and from the next iteration's.
        assert_ne!(candidates[1], candidates[2]);
        assert_ne!(candidates[1], a.candidates()[1]);
    }

    #[test]
    fn the_cem_update_refits_to_the_elites_and_converges_on_a_quadratic() {
        let mut cem = Cem::new(
            vec![0.0, 0.0],
            vec![1.0, 1.0],
            vec![-5.0; 2],
            vec![5.0; 2],
            settings(4, 2, 1.0),
        )
        .unwrap();
        let candidates = vec![
            vec![0.0, 0.0],
            vec![1.0, 3.0],
            vec![3.0, 1.0],
            vec![2.0, 2.0],
        ];
        let best = cem.update(&candidates, &[5.0, f64::NAN, 1.0, 2.0]);
        assert_eq!(best, 2);
        assert_eq!(cem.mean, vec![2.5, 1.5]);
        assert_eq!(cem.std, vec![0.5, 0.5]);
        // Sampling, scoring and refitting finds the minimum of a bowl at (1.2, -0.7).
        let mut cem = Cem::new(
            vec![-3.0, 3.0],
            vec![2.0, 2.0],
            vec![-5.0; 2],
            vec![5.0; 2],
            settings(40, 8, 0.8),
        )
        .unwrap();
        let cost = |x: &[f64]| (x[0] - 1.2).powi(2) + (x[1] + 0.7).powi(2);
        let start = cost(&cem.mean);
        for _ in 0..30 {
            let candidates = cem.candidates();
            let costs: Vec<f64> = candidates.iter().map(|c| cost(c)).collect();
            cem.update(&candidates, &costs);
        }
        assert!(cost(&cem.mean) < 1e-4 * start, "{:?}", cem.mean);
        assert!(Cem::new(
            vec![0.0],
            vec![1.0],
            vec![0.0],
            vec![1.0],
            settings(4, 5, 1.0)
        )
        .is_err());
        assert!(Cem::new(
            vec![0.0],
            vec![1.0],
            vec![0.0],
            vec![1.0],
            settings(4, 2, 0.0)
        )
        .is_err());
    }

    #[test]
    fn the_risk_blends_the_mean_with_a_quantile() {
        let costs = [4.0, 1.0, 3.0, 2.0, 10.0];
        let mean = RiskMeasure {
            quantile: 0.9,
            weight: 0.0,
        };
        assert_eq!(mean.of(&costs), 4.0);
        let worst = RiskMeasure {
            quantile: 1.0,
            weight: 1.0,
        };
        assert_eq!(worst.of(&costs), 10.0);
        let blend = RiskMeasure {
            quantile: 0.5,
            weight: 0.5,
        };
        assert_eq!(blend.of(&costs), 0.5 * 4.0 + 0.5 * 3.0);
        let between = RiskMeasure {
            quantile: 0.875,
            weight: 1.0,
        };
        // The 0.875 quantile of 1, 2, 3, 4, 10 lies halfway between 4 and 10.
        assert!((between.of(&costs) - 7.0).abs() < 1e-12);
    }
}
