//! Batched Bayesian optimisation (minimisation) with an ask/tell interface.
//!
//! * Initial design: a Latin hypercube of `initial_points` in the unit cube (optionally preceded by
//!   user-given points such as the study's defaults).
//! * Then each [`BayesOpt::ask`] fits the [`GaussianProcess`] (hyperparameters by marginal likelihood)
//!   and returns a batch of `batch_size` candidates chosen by Kriging believer: maximise the
//!   acquisition, pretend the GP mean was observed there, recondition (same hyperparameters), repeat.
//! * The acquisition (expected improvement or a lower confidence bound) is maximised by random
//!   sampling (uniform plus Gaussian perturbations of the best points) and a local pattern search.
//!
//! Determinism and resume: the random stream of every `ask` depends only on the seed and the number of
//! observations told so far, so replaying a log with [`BayesOpt::tell`] and asking again gives exactly
//! the batch an uninterrupted run would have asked.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::gp::{FitOptions, GaussianProcess, GpError};
use crate::space::ParamSpace;

/// Errors of the optimiser.
#[derive(Debug, thiserror::Error)]
pub enum BoError {
    /// The surrogate could not be fitted.
    #[error(transparent)]
    Gp(#[from] GpError),
    /// Every observation so far is NaN or infinite: there is nothing to model.
    #[error(
        "every objective value so far is non-finite (diverged rollouts?); widen or fix the bounds"
    )]
    NoFiniteObservation,
    /// A told point has the wrong dimension.
    #[error("told a point with {got} values, the space has {expected} parameters")]
    Dimension {
        /// Values given.
        got: usize,
        /// Parameters in the space.
        expected: usize,
    },
}

/// The acquisition function (for minimisation).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum Acquisition {
    /// Expected improvement over the best posterior mean at an observed point, minus margin `xi`
    /// (in standard deviations of the observed values).
    ExpectedImprovement {
        /// Exploration margin.
        xi: f64,
    },
    /// Lower confidence bound `μ − κ σ` (UCB for a minimisation).
    ConfidenceBound {
        /// Exploration weight κ.
        kappa: f64,
    },
}

impl Default for Acquisition {
    fn default() -> Self {
        Acquisition::ExpectedImprovement { xi: 0.01 }
    }
}

/// Settings of the optimiser.
#[derive(Debug, Clone, PartialEq)]
pub struct BoSettings {
    /// Points of the Latin-hypercube initial design.
    pub initial_points: usize,
    /// Candidates per `ask` after the initial design.
    pub batch_size: usize,
    /// Acquisition function.
    pub acquisition: Acquisition,
    /// Random candidates scored per acquisition maximisation.
    pub random_candidates: usize,
    /// Best candidates refined by local pattern search.
    pub refined_candidates: usize,
    /// Seed of every random choice.
    pub seed: u64,
}

impl Default for BoSettings {
    fn default() -> Self {
        Self {
            initial_points: 8,
            batch_size: 4,
            acquisition: Acquisition::default(),
            random_candidates: 2000,
            refined_candidates: 4,
            seed: 0,
        }
    }
}

/// One evaluated point.
#[derive(Debug, Clone, PartialEq)]
pub struct Observation {
    /// Parameter values (not unit-cube coordinates).
    pub params: Vec<f64>,
    /// Objective value (lower is better); may be non-finite for a failed evaluation.
    pub value: f64,
}

/// The Bayesian optimiser: a search space, settings and the observations told so far.
#[derive(Debug, Clone)]
pub struct BayesOpt {
    space: ParamSpace,
    settings: BoSettings,
    seeds: Vec<Vec<f64>>,
    observations: Vec<Observation>,
}

impl BayesOpt {
    /// A new optimiser with no observation.
    pub fn new(space: ParamSpace, settings: BoSettings) -> Self {
        Self {
            space,
            settings,
            seeds: Vec::new(),
            observations: Vec::new(),
        }
    }

    /// Puts `points` (parameter values, e.g. a known good guess) ahead of the Latin hypercube.
    pub fn with_seed_points(mut self, points: Vec<Vec<f64>>) -> Self {
        self.seeds = points;
        self
    }

    /// The search space.
    pub fn space(&self) -> &ParamSpace {
        &self.space
    }

    /// The observations told so far, in order.
    pub fn observations(&self) -> &[Observation] {
        &self.observations
    }

    /// The best finite observation so far.
    pub fn best(&self) -> Option<&Observation> {
        self.observations
            .iter()
            .filter(|o| o.value.is_finite())
            .min_by(|a, b| a.value.total_cmp(&b.value))
    }

    /// Records one evaluation.
    pub fn tell(&mut self, params: Vec<f64>, value: f64) -> Result<(), BoError> {
        if params.len() != self.space.dim() {
            return Err(BoError::Dimension {
                got: params.len(),
                expected: self.space.dim(),
            });
        }
        self.observations.push(Observation { params, value });
        Ok(())
    }

    /// The initial design (parameter values): seed points as given, then a Latin hypercube fixed
    /// by the seed.
    fn initial_design(&self) -> Vec<Vec<f64>> {
        let mut rng = ChaCha8Rng::seed_from_u64(self.settings.seed);
        rng.set_stream(u64::MAX);
        let lhs = latin_hypercube(self.settings.initial_points, self.space.dim(), &mut rng);
        self.seeds
            .iter()
            .cloned()
            .chain(lhs.iter().map(|u| self.space.from_unit(u)))
            .collect()
    }

    /// The next batch of candidates (parameter values) to evaluate.
    pub fn ask(&self) -> Result<Vec<Vec<f64>>, BoError> {
        let told = self.observations.len();
        let batch_size = self.settings.batch_size.max(1);
        let design = self.initial_design();
        let pending: Vec<Vec<f64>> = design.into_iter().skip(told).take(batch_size).collect();
        // The design alone fills the batch, or there is no data yet to model.
        if pending.len() == batch_size || told == 0 {
            return Ok(pending);
        }
        let mut rng = ChaCha8Rng::seed_from_u64(self.settings.seed);
        rng.set_stream(told as u64);

        // Failed evaluations are modelled as the worst finite value: "bad here", without wrecking
        // the output scale.
        let worst = self
            .observations
            .iter()
            .map(|o| o.value)
            .filter(|v| v.is_finite())
            .fold(f64::NEG_INFINITY, f64::max);
        if worst == f64::NEG_INFINITY {
            return Err(BoError::NoFiniteObservation);
        }
        let mut x: Vec<Vec<f64>> = self
            .observations
            .iter()
            .map(|o| clamp_unit(self.space.to_unit(&o.params)))
            .collect();
        let mut y: Vec<f64> = self
            .observations
            .iter()
            .map(|o| if o.value.is_finite() { o.value } else { worst })
            .collect();
        let gp = GaussianProcess::fit(x.clone(), &y, None, FitOptions::default(), &mut rng)?;
        let hyper = gp.hyperparameters().clone();
        let y_std = std_dev(&y);

        // Kriging believer: every point already in the batch (the rest of the initial design,
        // then each chosen candidate) is "observed" at the GP mean before choosing the next.
        let mut batch = Vec::with_capacity(batch_size);
        for params in pending {
            let u = clamp_unit(self.space.to_unit(&params));
            y.push(gp.predict(&u).0);
            x.push(u);
            batch.push(params);
        }
        let mut current = gp;
        while batch.len() < batch_size {
            if x.len() > told {
                current = GaussianProcess::with_hyperparameters(x.clone(), &y, hyper.clone())?;
            }
            let incumbent = x[..told]
                .iter()
                .map(|xi| current.predict(xi).0)
                .fold(f64::INFINITY, f64::min);
            // The objective is deterministic: a point next to one already evaluated or chosen
            // would be wasted (a GP with a learned noise term still rates it highly).
            let score = |u: &[f64]| {
                if x.iter().any(|xi| distance(xi, u) < MIN_SEPARATION) {
                    return f64::NEG_INFINITY;
                }
                let (m, v) = current.predict(u);
                acquisition_value(self.settings.acquisition, m, v.sqrt(), incumbent, y_std)
            };
            let chosen = maximise(&score, &x, &self.settings, self.space.dim(), &mut rng);
            let believed = current.predict(&chosen).0;
            x.push(chosen.clone());
            y.push(believed);
            batch.push(self.space.from_unit(&chosen));
        }
        Ok(batch)
    }
}

/// Smallest distance (unit cube) between a new candidate and any evaluated or chosen point.
const MIN_SEPARATION: f64 = 0.02;

fn distance(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| (p - q) * (p - q))
        .sum::<f64>()
        .sqrt()
}

/// Acquisition value to maximise, for posterior mean `m` and standard deviation `s`.
fn acquisition_value(acq: Acquisition, m: f64, s: f64, incumbent: f64, y_std: f64) -> f64 {
    match acq {
        Acquisition::ExpectedImprovement { xi } => {
            let improvement = incumbent - m - xi * y_std;
            if s <= 1e-12 {
                return improvement.max(0.0);
            }
            let z = improvement / s;
            improvement * normal_cdf(z) + s * normal_pdf(z)
        }
        Acquisition::ConfidenceBound { kappa } => -(m - kappa * s),
    }
}

/// Maximises `score` over the unit cube: random candidates (uniform, and Gaussian around the best
/// observed points), then a pattern search from the best few.
fn maximise(
    score: &impl Fn(&[f64]) -> f64,
    observed: &[Vec<f64>],
    settings: &BoSettings,
    dim: usize,
    rng: &mut ChaCha8Rng,
) -> Vec<f64> {
    let mut candidates: Vec<(f64, Vec<f64>)> = Vec::with_capacity(settings.random_candidates + 1);
    let local_share = settings.random_candidates / 4;
    for i in 0..settings.random_candidates.max(1) {
        let u: Vec<f64> = if i < local_share && !observed.is_empty() {
            let centre = &observed[rng.random_range(0..observed.len())];
            clamp_unit(
                centre
                    .iter()
                    .map(|c| c + 0.05 * standard_normal(rng))
                    .collect(),
            )
        } else {
            (0..dim).map(|_| rng.random::<f64>()).collect()
        };
        candidates.push((score(&u), u));
    }
    candidates.sort_by(|a, b| b.0.total_cmp(&a.0));
    candidates.truncate(settings.refined_candidates.max(1));
    candidates
        .into_iter()
        .map(|(s, u)| pattern_search(score, u, s))
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, u)| u)
        .expect("at least one candidate")
}

/// Compass search in the unit cube: try ± step on each coordinate, halve the step when stuck.
fn pattern_search(
    score: &impl Fn(&[f64]) -> f64,
    mut u: Vec<f64>,
    mut best: f64,
) -> (f64, Vec<f64>) {
    let mut step = 0.05;
    while step > 1e-3 {
        let mut improved = false;
        for d in 0..u.len() {
            for sign in [1.0, -1.0] {
                let mut trial = u.clone();
                trial[d] = (trial[d] + sign * step).clamp(0.0, 1.0);
                let s = score(&trial);
                if s > best {
                    best = s;
                    u = trial;
                    improved = true;
                }
            }
        }
        if !improved {
            step *= 0.5;
        }
    }
    (best, u)
}

/// `n` points of a Latin hypercube in `[0, 1]^dim`: one point per stratum on every axis.
pub fn latin_hypercube(n: usize, dim: usize, rng: &mut impl Rng) -> Vec<Vec<f64>> {
    let mut points = vec![vec![0.0; dim]; n];
    for d in 0..dim {
        let mut strata: Vec<usize> = (0..n).collect();
        // Fisher-Yates shuffle.
        for i in (1..n).rev() {
            strata.swap(i, rng.random_range(0..=i));
        }
        for (p, s) in points.iter_mut().zip(strata) {
            p[d] = (s as f64 + rng.random::<f64>()) / n as f64;
        }
    }
    points
}

fn clamp_unit(u: Vec<f64>) -> Vec<f64> {
    u.into_iter().map(|v| v.clamp(0.0, 1.0)).collect()
}

fn std_dev(y: &[f64]) -> f64 {
    let m = y.iter().sum::<f64>() / y.len() as f64;
    (y.iter().map(|v| (v - m).powi(2)).sum::<f64>() / y.len() as f64).sqrt()
}

/// A standard normal sample (Box-Muller).
fn standard_normal(rng: &mut impl Rng) -> f64 {
    let u1: f64 = 1.0 - rng.random::<f64>();
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

fn normal_pdf(z: f64) -> f64 {
    (-0.5 * z * z).exp() / (2.0 * std::f64::consts::PI).sqrt()
}

/// Standard normal CDF through [`erfc`].
fn normal_cdf(z: f64) -> f64 {
    0.5 * erfc(-z / std::f64::consts::SQRT_2)
}

/// Complementary error function (Numerical Recipes `erfcc`, fractional error < 1.2e-7).
fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let r = t
        * (-z * z - 1.26551223
            + t * (1.00002368
                + t * (0.37409196
                    + t * (0.09678418
                        + t * (-0.18628806
                            + t * (0.27886807
                                + t * (-1.13520398
                                    + t * (1.48851587 + t * (-0.82215223 + t * 0.17087277)))))))))
            .exp();
    if x >= 0.0 {
        r
    } else {
        2.0 - r
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::space::ParamSpec;

    fn branin_space() -> ParamSpace {
        ParamSpace::new(vec![
            ParamSpec {
                name: "x1".into(),
                lower: -5.0,
                upper: 10.0,
                log: false,
            },
            ParamSpec {
                name: "x2".into(),
                lower: 0.0,
                upper: 15.0,
                log: false,
            },
        ])
        .unwrap()
    }

    /// Branin-Hoo, global minimum 0.397887 at three points.
    fn branin(p: &[f64]) -> f64 {
        let (x1, x2) = (p[0], p[1]);
        let pi = std::f64::consts::PI;
        let b = 5.1 / (4.0 * pi * pi);
        let c = 5.0 / pi;
        let t = 1.0 / (8.0 * pi);
        (x2 - b * x1 * x1 + c * x1 - 6.0).powi(2) + 10.0 * (1.0 - t) * x1.cos() + 10.0
    }

    fn run_bo(seed: u64, budget: usize, acquisition: Acquisition) -> BayesOpt {
        let settings = BoSettings {
            initial_points: 6,
            batch_size: 3,
            acquisition,
            random_candidates: 500,
            refined_candidates: 3,
            seed,
        };
        let mut bo = BayesOpt::new(branin_space(), settings);
        while bo.observations().len() < budget {
            for p in bo.ask().unwrap() {
                let v = branin(&p);
                bo.tell(p, v).unwrap();
            }
        }
        bo
    }

    fn random_search(seed: u64, budget: usize) -> f64 {
        let space = branin_space();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..budget)
            .map(|_| branin(&space.from_unit(&[rng.random(), rng.random()])))
            .fold(f64::INFINITY, f64::min)
    }

    #[test]
    fn bo_beats_random_search_on_branin() {
        let budget = 24;
        for seed in 0..3 {
            let bo = run_bo(seed, budget, Acquisition::default());
            let bo_best = bo.best().unwrap().value;
            let rs_best = random_search(seed, budget);
            assert!(
                bo_best < rs_best && bo_best < 0.397887 + 0.3,
                "seed {seed}: BO {bo_best} vs random {rs_best}"
            );
        }
    }

    #[test]
    fn confidence_bound_also_converges() {
        let bo = run_bo(5, 24, Acquisition::ConfidenceBound { kappa: 2.0 });
        let best = bo.best().unwrap().value;
        assert!(best < 0.397887 + 0.5, "UCB best {best}");
    }

    #[test]
    fn batch_candidates_are_distinct_even_at_a_bound() {
        // A rough objective whose minimum lies at the upper bound: the GP learns a noise term, and
        // without a separation rule the believer batch piles up at the bound.
        let space = ParamSpace::new(vec![ParamSpec {
            name: "x".into(),
            lower: 0.0,
            upper: 1.0,
            log: false,
        }])
        .unwrap();
        let settings = BoSettings {
            initial_points: 8,
            batch_size: 4,
            random_candidates: 200,
            seed: 2,
            ..BoSettings::default()
        };
        let mut bo = BayesOpt::new(space, settings);
        for k in 0..8 {
            let x = k as f64 / 8.0 + 0.03;
            let rough = 0.2 * ((k * 7919 % 13) as f64 / 13.0 - 0.5);
            bo.tell(vec![x], -x + rough).unwrap();
        }
        let batch = bo.ask().unwrap();
        let mut points: Vec<f64> = bo.observations().iter().map(|o| o.params[0]).collect();
        for p in &batch {
            assert!(
                points.iter().all(|q| (p[0] - q).abs() >= MIN_SEPARATION),
                "{p:?} repeats a point of {points:?}"
            );
            points.push(p[0]);
        }
    }

    #[test]
    fn resume_by_replaying_observations_asks_the_same_batch() {
        let bo = run_bo(11, 12, Acquisition::default());
        let next = bo.ask().unwrap();
        let mut replayed = BayesOpt::new(branin_space(), bo.settings.clone());
        for o in bo.observations() {
            replayed.tell(o.params.clone(), o.value).unwrap();
        }
        assert_eq!(replayed.ask().unwrap(), next);
        // A different seed gives a different design.
        let other = run_bo(12, 6, Acquisition::default());
        assert_ne!(other.observations()[0].params, bo.observations()[0].params);
    }

    #[test]
    fn seed_points_come_first_and_failures_are_tolerated() {
        let settings = BoSettings {
            initial_points: 2,
            batch_size: 2,
            random_candidates: 200,
            ..BoSettings::default()
        };
        let mut bo = BayesOpt::new(branin_space(), settings).with_seed_points(vec![vec![3.0, 2.0]]);
        let first = bo.ask().unwrap();
        assert_eq!(first.len(), 2);
        assert_eq!(first[0], vec![3.0, 2.0]);
        // A diverged evaluation (NaN) must not stop the search.
        bo.tell(first[0].clone(), f64::NAN).unwrap();
        bo.tell(first[1].clone(), branin(&first[1])).unwrap();
        // The last design point shares its batch with a model-based candidate.
        let design = bo.initial_design();
        let second = bo.ask().unwrap();
        assert_eq!(second.len(), 2);
        assert_eq!(second[0], design[2]);
        assert_ne!(second[1], second[0]);
        while bo.observations().len() < 8 {
            for p in bo.ask().unwrap() {
                let v = branin(&p);
                bo.tell(p, v).unwrap();
            }
        }
        assert!(bo.best().unwrap().value.is_finite());
        // Full batches of 2 only.
        assert_eq!(bo.observations().len(), 8);
        assert!(matches!(
            bo.tell(vec![1.0], 0.0),
            Err(BoError::Dimension {
                got: 1,
                expected: 2
            })
        ));
    }

    #[test]
    fn latin_hypercube_fills_every_stratum() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let pts = latin_hypercube(10, 3, &mut rng);
        for d in 0..3 {
            let mut strata: Vec<usize> = pts.iter().map(|p| (p[d] * 10.0) as usize).collect();
            strata.sort();
            assert_eq!(strata, (0..10).collect::<Vec<_>>());
        }
    }

    #[test]
    fn normal_cdf_is_accurate() {
        for (z, phi) in [
            (0.0, 0.5),
            (1.0, 0.841344746),
            (-1.96, 0.024997895),
            (3.0, 0.998650102),
        ] {
            assert!((normal_cdf(z) - phi).abs() < 2e-7, "Φ({z})");
        }
    }
}
