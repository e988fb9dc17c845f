//! The covariance matrix adaptation evolution strategy (CMA-ES) on the unit cube, with an
//! ask-and-tell interface: the search for the mode that the posterior sampler starts from.
//!
//! Written here rather than taken from the `cmaes` crate (0.2): that crate evaluates one point
//! per call of a closure (`run`, `run_parallel`) and has no ask-and-tell, while here one generation
//! is one batched rollout of the simulator, and a resumed calibration must ask for exactly the
//! points it logged before. The update is the one of Hansen's tutorial (arXiv:1604.00772, Fig. 6
//! with the default constants of Table 1, positive weights only); the box is handled by mirroring
//! each coordinate into `[0, 1]`, the mirrored point being the one evaluated and recombined.

use nalgebra::{DMatrix, DVector};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

/// Settings of the mode search.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModeSearchSettings {
    /// Candidates per generation (one batched rollout).
    pub population: usize,
    /// Most generations; the search stops earlier once a generation's log-likelihoods are within
    /// the posterior's own spread ([`CONVERGED_SPREAD_PER_DIM`]).
    pub generations: usize,
    /// Initial step size on the unit cube.
    #[serde(default = "default_initial_step")]
    pub initial_step: f64,
    /// The sampler's reference is the final search distribution with its step size scaled by this
    /// factor (wider than the search ends, so that it covers the posterior).
    #[serde(default = "default_reference_scale")]
    pub reference_scale: f64,
    /// A growing horizon: the search first fits the recordings' first `first_horizon_s`, then
    /// twice that, and so on up to the whole recordings, each horizon until it converges (or for
    /// `generations`), every horizon continuing the last one's search distribution. Whole
    /// recordings from the start when absent.
    ///
    /// Why: a film solved to convergence is multistable (it folds one way or another), so on a
    /// whole recording the likelihood is piecewise smooth with basins a few per cent wide, and a
    /// search across the box lands in whichever basin its population happens to sample. Over a
    /// short start the replays have not yet parted, the basins are wide and the search finds the
    /// truth's neighbourhood; each longer horizon narrows it from there (continuation in the
    /// horizon, as in multiple shooting for chaotic systems).
    #[serde(default)]
    pub first_horizon_s: Option<f64>,
}

impl ModeSearchSettings {
    /// The horizons of the search on recordings `duration_s` long: `Some(seconds)` for each
    /// shorter start, `None` (the whole recordings) last.
    pub fn horizons(&self, duration_s: f64) -> Vec<Option<f64>> {
        let mut horizons = Vec::new();
        if let Some(first) = self.first_horizon_s {
            let mut h = first;
            while h < duration_s {
                horizons.push(Some(h));
                h *= 2.0;
            }
        }
        horizons.push(None);
        horizons
    }
}

fn default_initial_step() -> f64 {
    0.3
}

fn default_reference_scale() -> f64 {
    2.0
}

/// The search has converged once the best and the median log-likelihood of a generation differ by
/// less than this many units per parameter. Assumption (not measured): draws of a Gaussian
/// posterior in `d` dimensions sit `χ²_d / 2` below its peak, `d / 2` on average; a generation
/// spread over twice that is about as wide as the posterior, so going on would only shrink the
/// search below the posterior's scale.
pub const CONVERGED_SPREAD_PER_DIM: f64 = 1.0;

/// Checks `settings` for a space of `dim` parameters.
pub fn check_settings(dim: usize, s: &ModeSearchSettings) -> Result<(), String> {
    if !(4.max(dim / 2)..=100_000).contains(&s.population) {
        return Err(format!(
            "mode_search.population = {}: expected {}..=100000",
            s.population,
            4.max(dim / 2)
        ));
    }
    if !(1..=100_000).contains(&s.generations) {
        return Err(format!(
            "mode_search.generations = {}: expected 1..=100000",
            s.generations
        ));
    }
    if !(s.initial_step > 0.0 && s.initial_step <= 1.0) {
        return Err(format!(
            "mode_search.initial_step = {}: expected in (0, 1]",
            s.initial_step
        ));
    }
    if let Some(h) = s.first_horizon_s {
        if !(h.is_finite() && h > 0.0) {
            return Err(format!(
                "mode_search.first_horizon_s = {h}: expected a duration > 0 s"
            ));
        }
    }
    if !(s.reference_scale >= 1.0 && s.reference_scale <= 100.0) {
        return Err(format!(
            "mode_search.reference_scale = {}: expected in [1, 100]",
            s.reference_scale
        ));
    }
    Ok(())
}

/// One generation, as reported.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Generation {
    /// Highest log-likelihood of the generation.
    pub best_log_likelihood: f64,
    /// Median log-likelihood of the generation.
    pub median_log_likelihood: f64,
    /// Step size after the generation's update.
    pub step: f64,
    /// The horizon it was scored on (s of trajectory time; `None`: the whole recordings).
    pub horizon_s: Option<f64>,
    /// Evaluations so far.
    pub evaluations: usize,
}

/// The state of a CMA-ES search on `[0, 1]^dim`.
#[derive(Debug, Clone)]
pub struct CmaEs {
    mean: DVector<f64>,
    step: f64,
    covariance: DMatrix<f64>,
    /// Eigenvectors `B` and square roots of the eigenvalues `D` of the covariance.
    basis: DMatrix<f64>,
    scales: DVector<f64>,
    path_step: DVector<f64>,
    path_covariance: DVector<f64>,
    population: usize,
    weights: Vec<f64>,
    mu_eff: f64,
    c_step: f64,
    damping: f64,
    c_path: f64,
    c_rank_one: f64,
    c_rank_mu: f64,
    expected_norm: f64,
    generation: usize,
}

impl CmaEs {
    /// A search around `mean` with step size `step` and `population` candidates per generation.
    pub fn new(mean: &[f64], step: f64, population: usize) -> Self {
        let n = mean.len() as f64;
        let mu = population / 2;
        let raw: Vec<f64> = (1..=mu)
            .map(|i| ((population as f64 + 1.0) / 2.0).ln() - (i as f64).ln())
            .collect();
        let total: f64 = raw.iter().sum();
        let weights: Vec<f64> = raw.iter().map(|w| w / total).collect();
        let mu_eff = 1.0 / weights.iter().map(|w| w * w).sum::<f64>();
        let c_step = (mu_eff + 2.0) / (n + mu_eff + 5.0);
        let damping = 1.0 + 2.0 * (((mu_eff - 1.0) / (n + 1.0)).sqrt() - 1.0).max(0.0) + c_step;
        let c_path = (4.0 + mu_eff / n) / (n + 4.0 + 2.0 * mu_eff / n);
        let c_rank_one = 2.0 / ((n + 1.3).powi(2) + mu_eff);
        let c_rank_mu = (1.0 - c_rank_one)
            .min(2.0 * (mu_eff - 2.0 + 1.0 / mu_eff) / ((n + 2.0).powi(2) + mu_eff));
        let dim = mean.len();
        Self {
            mean: DVector::from_column_slice(mean),
            step,
            covariance: DMatrix::identity(dim, dim),
            basis: DMatrix::identity(dim, dim),
            scales: DVector::from_element(dim, 1.0),
            path_step: DVector::zeros(dim),
            path_covariance: DVector::zeros(dim),
            population,
            weights,
            mu_eff,
            c_step,
            damping,
            c_path,
            c_rank_one,
            c_rank_mu,
            expected_norm: n.sqrt() * (1.0 - 1.0 / (4.0 * n) + 1.0 / (21.0 * n * n)),
            generation: 0,
        }
    }

    /// The next generation's candidates, each mirrored into the unit cube.
    pub fn ask(&self, rng: &mut ChaCha8Rng) -> Vec<Vec<f64>> {
        let dim = self.mean.len();
        (0..self.population)
            .map(|_| {
                let z = DVector::from_iterator(dim, (0..dim).map(|_| standard_normal(rng)));
                let y = &self.basis * z.component_mul(&self.scales);
                (0..dim)
                    .map(|a| mirror(self.mean[a] + self.step * y[a]))
                    .collect()
            })
            .collect()
    }

    /// Updates the search with the log-likelihoods of the candidates [`CmaEs::ask`] returned
    /// (higher is better; NaN counts as the worst).
    pub fn tell(&mut self, candidates: &[Vec<f64>], log_likelihoods: &[f64]) {
        let dim = self.mean.len();
        let n = dim as f64;
        let mut order: Vec<usize> = (0..candidates.len()).collect();
        let key = |i: usize| {
            let v = log_likelihoods[i];
            if v.is_nan() {
                f64::NEG_INFINITY
            } else {
                v
            }
        };
        order.sort_by(|&a, &b| key(b).total_cmp(&key(a)));
        let steps: Vec<DVector<f64>> = order[..self.weights.len()]
            .iter()
            .map(|&i| (DVector::from_column_slice(&candidates[i]) - &self.mean) / self.step)
            .collect();
        let mut mean_step = DVector::zeros(dim);
        for (w, y) in self.weights.iter().zip(&steps) {
            mean_step += y * *w;
        }
        self.mean += &mean_step * self.step;
        // C^{-1/2} y = B D^{-1} B^T y.
        let whitened =
            &self.basis * (self.basis.transpose() * &mean_step).component_div(&self.scales);
        self.path_step = &self.path_step * (1.0 - self.c_step)
            + whitened * (self.c_step * (2.0 - self.c_step) * self.mu_eff).sqrt();
        self.generation += 1;
        let decay = 1.0 - (1.0 - self.c_step).powi(2 * self.generation as i32);
        let stalled =
            self.path_step.norm() / decay.sqrt() >= (1.4 + 2.0 / (n + 1.0)) * self.expected_norm;
        let h = if stalled { 0.0 } else { 1.0 };
        self.path_covariance = &self.path_covariance * (1.0 - self.c_path)
            + &mean_step * (h * (self.c_path * (2.0 - self.c_path) * self.mu_eff).sqrt());
        let mut rank_mu = DMatrix::zeros(dim, dim);
        for (w, y) in self.weights.iter().zip(&steps) {
            rank_mu += y * y.transpose() * *w;
        }
        let lost = (1.0 - h) * self.c_rank_one * self.c_path * (2.0 - self.c_path);
        self.covariance = &self.covariance * (1.0 - self.c_rank_one - self.c_rank_mu + lost)
            + &self.path_covariance * self.path_covariance.transpose() * self.c_rank_one
            + rank_mu * self.c_rank_mu;
        self.step *= ((self.c_step / self.damping)
            * (self.path_step.norm() / self.expected_norm - 1.0))
            .exp();
        // A step beyond the cube's size only mirrors back and forth.
        self.step = self.step.min(1.0);
        self.decompose();
    }

    /// Symmetrises the covariance and refreshes its eigen-decomposition.
    fn decompose(&mut self) {
        let c = (&self.covariance + self.covariance.transpose()) * 0.5;
        let eigen = c.clone().symmetric_eigen();
        self.covariance = c;
        self.basis = eigen.eigenvectors;
        self.scales = eigen.eigenvalues.map(|v| v.max(1e-300).sqrt());
    }

    /// The search distribution's mean.
    pub fn mean(&self) -> Vec<f64> {
        self.mean.iter().copied().collect()
    }

    /// The search distribution's covariance `σ² C`.
    pub fn covariance(&self) -> DMatrix<f64> {
        &self.covariance * (self.step * self.step)
    }

    /// The step size `σ`.
    pub fn step(&self) -> f64 {
        self.step
    }
}

/// `x` mirrored at the faces of `[0, 1]` until it lies inside.
fn mirror(x: f64) -> f64 {
    if !x.is_finite() {
        return 0.5;
    }
    let r = x.rem_euclid(2.0);
    if r > 1.0 {
        2.0 - r
    } else {
        r
    }
}

/// A standard normal draw (Box–Muller).
pub(crate) fn standard_normal(rng: &mut ChaCha8Rng) -> f64 {
    let u: f64 = 1.0 - rng.random::<f64>();
    let v: f64 = rng.random();
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// Runs the search on `log_likelihood` for `generations` and returns the best point seen.
    fn search(
        dim: usize,
        population: usize,
        generations: usize,
        log_likelihood: impl Fn(&[f64]) -> f64,
    ) -> (Vec<f64>, f64, CmaEs) {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut cma = CmaEs::new(&vec![0.5; dim], 0.3, population);
        let mut best = (vec![], f64::NEG_INFINITY);
        for _ in 0..generations {
            let points = cma.ask(&mut rng);
            let values: Vec<f64> = points.iter().map(|p| log_likelihood(p)).collect();
            for (p, &v) in points.iter().zip(&values) {
                if v > best.1 {
                    best = (p.clone(), v);
                }
            }
            cma.tell(&points, &values);
        }
        (best.0, best.1, cma)
    }

    #[test]
    fn finds_the_minimum_of_an_ill_conditioned_rotated_quadratic() {
        // Ten parameters whose curvatures span six decades along rotated axes: the sloppy shape of
        // a simulator's loss. Optimum inside the cube, off its centre.
        let dim = 10;
        let optimum: Vec<f64> = (0..dim).map(|i| 0.2 + 0.06 * i as f64).collect();
        let ll = |p: &[f64]| {
            let mut sum = 0.0;
            for k in 0..dim {
                // Rotate pairs by 30 degrees.
                let (a, b) = (k, (k + 1) % dim);
                let (c, s) = (0.866, 0.5);
                let u = c * (p[a] - optimum[a]) + s * (p[b] - optimum[b]);
                sum += 10f64.powf(6.0 * k as f64 / (dim - 1) as f64) * u * u;
            }
            -sum
        };
        let (best, value, _) = search(dim, 16, 600, ll);
        assert!(value > -1e-8, "best log-likelihood {value}");
        for (b, o) in best.iter().zip(&optimum) {
            assert!((b - o).abs() < 1e-3, "{best:?}");
        }
    }

    #[test]
    fn an_optimum_on_a_face_of_the_cube_is_reached_and_candidates_stay_inside() {
        let ll = |p: &[f64]| -((p[0] - 1.0).powi(2) + (p[1] - 0.3).powi(2));
        let (best, _, cma) = search(2, 8, 200, ll);
        assert!(best[0] > 0.999 && (best[1] - 0.3).abs() < 1e-3, "{best:?}");
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for p in cma.ask(&mut rng) {
            assert!(p.iter().all(|v| (0.0..=1.0).contains(v)), "{p:?}");
        }
    }

    #[test]
    fn the_search_distribution_learns_the_shape_of_a_correlated_quadratic() {
        // ll = −(a² − 2ρab + b²) / (2(1 − ρ²)) has Hessian ∝ the inverse correlation matrix: a
        // converged search's covariance is proportional to that correlation.
        let rho = 0.9;
        let ll = |p: &[f64]| {
            let (a, b) = ((p[0] - 0.5) / 0.01, (p[1] - 0.5) / 0.01);
            -(a * a - 2.0 * rho * a * b + b * b) / (2.0 * (1.0 - rho * rho))
        };
        let (_, _, cma) = search(2, 12, 60, ll);
        let c = cma.covariance();
        let correlation = c[(0, 1)] / (c[(0, 0)] * c[(1, 1)]).sqrt();
        assert!((correlation - rho).abs() < 0.1, "correlation {correlation}");
    }

    #[test]
    fn mirroring_keeps_points_in_the_cube() {
        assert_eq!(mirror(1.25), 0.75);
        assert_eq!(mirror(-0.25), 0.25);
        assert_eq!(mirror(2.5), 0.5);
        assert_eq!(mirror(f64::NAN), 0.5);
    }

    #[test]
    fn settings_out_of_range_are_named() {
        let good = ModeSearchSettings {
            population: 16,
            generations: 50,
            initial_step: 0.3,
            reference_scale: 2.0,
            first_horizon_s: None,
        };
        assert!(check_settings(10, &good).is_ok());
        let small = ModeSearchSettings {
            population: 2,
            ..good
        };
        assert!(check_settings(10, &small)
            .unwrap_err()
            .contains("mode_search.population = 2"));
        let wide = ModeSearchSettings {
            initial_step: 2.0,
            ..good
        };
        assert!(check_settings(10, &wide)
            .unwrap_err()
            .contains("initial_step"));
        let instant = ModeSearchSettings {
            first_horizon_s: Some(0.0),
            ..good
        };
        assert!(check_settings(10, &instant)
            .unwrap_err()
            .contains("mode_search.first_horizon_s = 0"));
    }

    #[test]
    fn horizons_double_up_to_the_whole_recordings() {
        let growing = ModeSearchSettings {
            population: 16,
            generations: 50,
            initial_step: 0.3,
            reference_scale: 2.0,
            first_horizon_s: Some(0.5),
        };
        assert_eq!(
            growing.horizons(3.0),
            vec![Some(0.5), Some(1.0), Some(2.0), None]
        );
        assert_eq!(growing.horizons(0.4), vec![None]);
        let whole = ModeSearchSettings {
            first_horizon_s: None,
            ..growing
        };
        assert_eq!(whole.horizons(3.0), vec![None]);
    }
}
