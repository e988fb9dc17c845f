//! A small exact Gaussian process on nalgebra, the surrogate of the Bayesian optimiser.
//!
//! Why not a crate: the calibration objective is noisy (contact-rich rollouts, and a user may evaluate
//! a subset of trajectories), but egobox-ego models no observation noise and friedrich has only
//! isotropic kernels. The calibration needs per-dimension length scales *and* a learned noise term, which
//! takes ~300 lines here.
//!
//! Model: inputs live in the unit cube (the [`crate::space::ParamSpace`] maps parameters there, on a
//! log scale where they span decades); outputs are standardised to zero mean and unit variance. The
//! kernel is Matérn 5/2 with ARD length scales `l_i` and signal variance `s²`:
//!
//! `k(x, x') = s² (1 + √5 r + 5/3 r²) exp(−√5 r)`,  `r² = Σ_i (x_i − x'_i)² / l_i²`,
//!
//! plus a learned Gaussian noise variance `σ²` on the diagonal. Hyperparameters
//! `θ = (log l_1..log l_d, log s², log σ²)` maximise the log marginal likelihood with its analytic
//! gradient (Adam in log space, box-bounded, multi-start: the previous optimum, a default and random
//! starts). Cholesky factorisations retry with growing jitter.

use nalgebra::{Cholesky, DMatrix, DVector, Dyn};
use rand::Rng;

/// Box bounds (natural log) on the hyperparameters, for inputs in the unit cube and standardised outputs.
const LOG_LENGTH_SCALE: (f64, f64) = (-4.6, 2.3); // 0.01 .. 10
const LOG_SIGNAL_VAR: (f64, f64) = (-4.6, 4.6); // 0.01 .. 100
const LOG_NOISE_VAR: (f64, f64) = (-13.8, 0.0); // 1e-6 .. 1

/// Errors of the Gaussian process.
#[derive(Debug, thiserror::Error)]
pub enum GpError {
    /// Inputs and outputs disagree in count or dimension, or are empty.
    #[error("GP data: {0}")]
    Shape(String),
    /// An output is NaN or infinite.
    #[error("GP data: output {index} is not finite ({value})")]
    NonFinite {
        /// Index of the offending observation.
        index: usize,
        /// Its value.
        value: f64,
    },
    /// The covariance matrix stayed indefinite even with the largest jitter.
    #[error("GP covariance is not positive definite even with jitter")]
    NotPositiveDefinite,
}

/// Kernel and noise hyperparameters (natural logs, see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct Hyperparameters {
    /// `log l_i`, one per input dimension.
    pub log_length_scales: Vec<f64>,
    /// `log s²` (standardised output units).
    pub log_signal_var: f64,
    /// `log σ²`, the observation noise (standardised output units).
    pub log_noise_var: f64,
}

impl Hyperparameters {
    /// A neutral starting point: length scales 0.3, unit signal variance, noise variance 1e-2.
    pub fn default_for(dim: usize) -> Self {
        Self {
            log_length_scales: vec![0.3f64.ln(); dim],
            log_signal_var: 0.0,
            log_noise_var: 1e-2f64.ln(),
        }
    }

    fn to_vec(&self) -> Vec<f64> {
        let mut v = self.log_length_scales.clone();
        v.push(self.log_signal_var);
        v.push(self.log_noise_var);
        v
    }

    fn from_slice(v: &[f64]) -> Self {
        let d = v.len() - 2;
        Self {
            log_length_scales: v[..d].to_vec(),
            log_signal_var: v[d],
            log_noise_var: v[d + 1],
        }
    }

    fn bounds(dim: usize) -> Vec<(f64, f64)> {
        let mut b = vec![LOG_LENGTH_SCALE; dim];
        b.push(LOG_SIGNAL_VAR);
        b.push(LOG_NOISE_VAR);
        b
    }
}

/// Matérn 5/2 value and the common factor of its length-scale derivative, given `r²`.
///
/// Returns `(k / s², g)` with `∂k/∂log l_i = s² · g · (x_i − x'_i)² / l_i²`.
fn matern52(r2: f64) -> (f64, f64) {
    let r = r2.sqrt();
    let s5r = 5f64.sqrt() * r;
    let e = (-s5r).exp();
    (
        (1.0 + s5r + 5.0 / 3.0 * r2) * e,
        5.0 / 3.0 * (1.0 + s5r) * e,
    )
}

/// Scaled squared distance `Σ (a_i − b_i)² / l_i²`.
fn scaled_r2(a: &[f64], b: &[f64], inv_l2: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .zip(inv_l2)
        .map(|((x, y), w)| (x - y).powi(2) * w)
        .sum()
}

/// Cholesky factor of `k + jitter·I`, retrying with growing jitter.
fn robust_cholesky(k: &DMatrix<f64>) -> Result<Cholesky<f64, Dyn>, GpError> {
    let mut jitter = 0.0;
    for _ in 0..8 {
        let mut m = k.clone();
        for i in 0..m.nrows() {
            m[(i, i)] += jitter;
        }
        if let Some(c) = Cholesky::new(m) {
            return Ok(c);
        }
        jitter = if jitter == 0.0 { 1e-10 } else { jitter * 10.0 };
    }
    Err(GpError::NotPositiveDefinite)
}

/// Checks shapes and finiteness of the training data; returns the input dimension.
fn validate(x: &[Vec<f64>], y: &[f64]) -> Result<usize, GpError> {
    if x.is_empty() || x.len() != y.len() {
        return Err(GpError::Shape(format!(
            "{} inputs for {} outputs (need the same, at least one)",
            x.len(),
            y.len()
        )));
    }
    let dim = x[0].len();
    if dim == 0 || x.iter().any(|xi| xi.len() != dim) {
        return Err(GpError::Shape(
            "inputs must share one non-zero dimension".into(),
        ));
    }
    if let Some((index, &value)) = y.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(GpError::NonFinite { index, value });
    }
    Ok(dim)
}

/// Standardisation of the outputs: `z = (y − mean) / scale`.
fn standardise(y: &[f64]) -> (f64, f64, DVector<f64>) {
    let n = y.len() as f64;
    let mean = y.iter().sum::<f64>() / n;
    let var = y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
    // A constant output gets unit scale so that z is all zeros rather than NaN.
    let scale = if var > 0.0 { var.sqrt() } else { 1.0 };
    let z = DVector::from_iterator(y.len(), y.iter().map(|v| (v - mean) / scale));
    (mean, scale, z)
}

/// Log marginal likelihood of standardised outputs `z` and its gradient with respect to `θ`.
fn log_marginal_likelihood(
    x: &[Vec<f64>],
    z: &DVector<f64>,
    theta: &Hyperparameters,
    want_gradient: bool,
) -> Result<(f64, Vec<f64>), GpError> {
    let n = x.len();
    let dim = theta.log_length_scales.len();
    let inv_l2: Vec<f64> = theta
        .log_length_scales
        .iter()
        .map(|l| (-2.0 * l).exp())
        .collect();
    let s2 = theta.log_signal_var.exp();
    let noise = theta.log_noise_var.exp();
    let mut k = DMatrix::zeros(n, n);
    let mut g = DMatrix::zeros(n, n);
    for i in 0..n {
        for j in 0..=i {
            let (kv, gv) = matern52(scaled_r2(&x[i], &x[j], &inv_l2));
            k[(i, j)] = s2 * kv;
            k[(j, i)] = s2 * kv;
            g[(i, j)] = s2 * gv;
            g[(j, i)] = s2 * gv;
        }
        k[(i, i)] += noise;
    }
    let chol = robust_cholesky(&k)?;
    let alpha = chol.solve(z);
    let log_det: f64 = 2.0
        * chol
            .l_dirty()
            .diagonal()
            .iter()
            .map(|v| v.ln())
            .sum::<f64>();
    let lml =
        -0.5 * z.dot(&alpha) - 0.5 * log_det - 0.5 * n as f64 * (2.0 * std::f64::consts::PI).ln();
    if !want_gradient {
        return Ok((lml, Vec::new()));
    }
    // ∂L/∂θ = ½ tr((ααᵀ − K⁻¹) ∂K/∂θ); W = ααᵀ − K⁻¹ is symmetric.
    let w = &alpha * alpha.transpose() - chol.inverse();
    let mut grad = vec![0.0; dim + 2];
    for i in 0..n {
        for j in 0..n {
            let wij = w[(i, j)];
            for (d, gd) in grad.iter_mut().take(dim).enumerate() {
                let diff2 = (x[i][d] - x[j][d]).powi(2) * inv_l2[d];
                *gd += 0.5 * wij * g[(i, j)] * diff2;
            }
            let signal_part = if i == j { k[(i, j)] - noise } else { k[(i, j)] };
            grad[dim] += 0.5 * wij * signal_part;
        }
        grad[dim + 1] += 0.5 * w[(i, i)] * noise;
    }
    Ok((lml, grad))
}

/// Maximises the log marginal likelihood from one start with box-bounded Adam; returns (θ, LML).
fn ascend(
    x: &[Vec<f64>],
    z: &DVector<f64>,
    start: Vec<f64>,
    bounds: &[(f64, f64)],
    steps: usize,
) -> Option<(Vec<f64>, f64)> {
    let (lr, b1, b2) = (0.05, 0.9, 0.999);
    let mut theta = start;
    let mut m = vec![0.0; theta.len()];
    let mut v = vec![0.0; theta.len()];
    let mut best: Option<(Vec<f64>, f64)> = None;
    for t in 1..=steps {
        let Ok((lml, grad)) =
            log_marginal_likelihood(x, z, &Hyperparameters::from_slice(&theta), true)
        else {
            break;
        };
        if best.as_ref().is_none_or(|(_, b)| lml > *b) {
            best = Some((theta.clone(), lml));
        }
        for i in 0..theta.len() {
            m[i] = b1 * m[i] + (1.0 - b1) * grad[i];
            v[i] = b2 * v[i] + (1.0 - b2) * grad[i] * grad[i];
            let m_hat = m[i] / (1.0 - b1.powi(t as i32));
            let v_hat = v[i] / (1.0 - b2.powi(t as i32));
            // Ascent: the likelihood is maximised.
            theta[i] =
                (theta[i] + lr * m_hat / (v_hat.sqrt() + 1e-8)).clamp(bounds[i].0, bounds[i].1);
        }
    }
    best
}

/// Settings of the hyperparameter search.
#[derive(Debug, Clone, Copy)]
pub struct FitOptions {
    /// Random restarts in addition to the warm start and the default start.
    pub random_starts: usize,
    /// Adam steps per start.
    pub steps: usize,
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            random_starts: 2,
            steps: 150,
        }
    }
}

/// A conditioned Gaussian process: training data, hyperparameters and the Cholesky factor.
#[derive(Debug, Clone)]
pub struct GaussianProcess {
    x: Vec<Vec<f64>>,
    y_mean: f64,
    y_scale: f64,
    hyper: Hyperparameters,
    chol: Cholesky<f64, Dyn>,
    /// Standardised training outputs.
    z: DVector<f64>,
    /// `K⁻¹ z`.
    alpha: DVector<f64>,
}

impl GaussianProcess {
    /// Conditions a GP with fixed hyperparameters on inputs `x` (unit cube) and outputs `y`.
    pub fn with_hyperparameters(
        x: Vec<Vec<f64>>,
        y: &[f64],
        hyper: Hyperparameters,
    ) -> Result<Self, GpError> {
        let dim = validate(&x, y)?;
        if hyper.log_length_scales.len() != dim {
            return Err(GpError::Shape(format!(
                "{} length scales for {dim}-D inputs",
                hyper.log_length_scales.len()
            )));
        }
        let (y_mean, y_scale, z) = standardise(y);
        let n = x.len();
        let inv_l2: Vec<f64> = hyper
            .log_length_scales
            .iter()
            .map(|l| (-2.0 * l).exp())
            .collect();
        let s2 = hyper.log_signal_var.exp();
        let k = DMatrix::from_fn(n, n, |i, j| {
            let noise = if i == j {
                hyper.log_noise_var.exp()
            } else {
                0.0
            };
            s2 * matern52(scaled_r2(&x[i], &x[j], &inv_l2)).0 + noise
        });
        let chol = robust_cholesky(&k)?;
        let alpha = chol.solve(&z);
        Ok(Self {
            x,
            y_mean,
            y_scale,
            hyper,
            chol,
            z,
            alpha,
        })
    }

    /// Fits hyperparameters by maximising the log marginal likelihood, then conditions the GP.
    ///
    /// `warm_start` (e.g. the previous fit's hyperparameters) is tried first; the result depends only
    /// on the data, `warm_start` and `rng`.
    pub fn fit(
        x: Vec<Vec<f64>>,
        y: &[f64],
        warm_start: Option<&Hyperparameters>,
        options: FitOptions,
        rng: &mut impl Rng,
    ) -> Result<Self, GpError> {
        let dim = validate(&x, y)?;
        let (_, _, z) = standardise(y);
        let bounds = Hyperparameters::bounds(dim);
        let mut starts = vec![Hyperparameters::default_for(dim).to_vec()];
        if let Some(h) = warm_start.filter(|h| h.log_length_scales.len() == dim) {
            starts.push(h.to_vec());
        }
        for _ in 0..options.random_starts {
            starts.push(
                bounds
                    .iter()
                    .map(|&(lo, hi)| rng.random_range(lo..hi))
                    .collect(),
            );
        }
        let best = starts
            .into_iter()
            .filter_map(|s| ascend(&x, &z, s, &bounds, options.steps))
            .max_by(|a, b| a.1.total_cmp(&b.1));
        let hyper = match best {
            Some((theta, _)) => Hyperparameters::from_slice(&theta),
            None => Hyperparameters::default_for(dim),
        };
        Self::with_hyperparameters(x, y, hyper)
    }

    /// The fitted hyperparameters.
    pub fn hyperparameters(&self) -> &Hyperparameters {
        &self.hyper
    }

    /// The learned observation-noise variance `σ²` in original output units.
    pub fn noise_variance(&self) -> f64 {
        self.hyper.log_noise_var.exp() * self.y_scale * self.y_scale
    }

    /// Log marginal likelihood of the (standardised) training outputs under the current hyperparameters.
    pub fn log_marginal_likelihood(&self) -> f64 {
        let log_det: f64 = 2.0
            * self
                .chol
                .l_dirty()
                .diagonal()
                .iter()
                .map(|v| v.ln())
                .sum::<f64>();
        -0.5 * self.z.dot(&self.alpha)
            - 0.5 * log_det
            - 0.5 * self.x.len() as f64 * (2.0 * std::f64::consts::PI).ln()
    }

    /// Number of training points.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// Whether the GP has no training points (never true for a constructed GP).
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Posterior mean and variance of the latent function at `x` (original output units; the
    /// variance excludes the observation noise).
    pub fn predict(&self, x: &[f64]) -> (f64, f64) {
        let inv_l2: Vec<f64> = self
            .hyper
            .log_length_scales
            .iter()
            .map(|l| (-2.0 * l).exp())
            .collect();
        let s2 = self.hyper.log_signal_var.exp();
        let k_star = DVector::from_iterator(
            self.x.len(),
            self.x
                .iter()
                .map(|xi| s2 * matern52(scaled_r2(xi, x, &inv_l2)).0),
        );
        let mean_z = k_star.dot(&self.alpha);
        let v = self
            .chol
            .l_dirty()
            .solve_lower_triangular(&k_star)
            .unwrap_or_else(|| DVector::zeros(self.x.len()));
        let var_z = (s2 - v.dot(&v)).max(0.0);
        (
            self.y_mean + self.y_scale * mean_z,
            self.y_scale * self.y_scale * var_z,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn hyper(l: f64, s2: f64, noise: f64) -> Hyperparameters {
        Hyperparameters {
            log_length_scales: vec![l.ln()],
            log_signal_var: s2.ln(),
            log_noise_var: noise.ln(),
        }
    }

    /// Matérn 5/2 in 1-D written out by hand.
    fn k1(a: f64, b: f64, l: f64, s2: f64) -> f64 {
        let r = (a - b).abs() / l;
        s2 * (1.0 + 5f64.sqrt() * r + 5.0 / 3.0 * r * r) * (-(5f64.sqrt()) * r).exp()
    }

    #[test]
    fn posterior_matches_closed_form_two_points() {
        // y = [-1, 1] is already standardised (mean 0, population std 1), so the closed form
        // applies directly: mean = k*ᵀ K⁻¹ y, var = k** − k*ᵀ K⁻¹ k*, with K 2×2 inverted by hand.
        let (l, s2, noise) = (0.4, 1.5, 0.01);
        let xs = [0.2, 0.7];
        let ys = [-1.0, 1.0];
        let gp = GaussianProcess::with_hyperparameters(
            xs.iter().map(|&v| vec![v]).collect(),
            &ys,
            hyper(l, s2, noise),
        )
        .unwrap();
        let (a, b, d) = (
            k1(xs[0], xs[0], l, s2) + noise,
            k1(xs[0], xs[1], l, s2),
            k1(xs[1], xs[1], l, s2) + noise,
        );
        let det = a * d - b * b;
        let inv = [[d / det, -b / det], [-b / det, a / det]];
        for &t in &[0.0, 0.2, 0.45, 0.9] {
            let ks = [k1(t, xs[0], l, s2), k1(t, xs[1], l, s2)];
            let w = [
                inv[0][0] * ks[0] + inv[0][1] * ks[1],
                inv[1][0] * ks[0] + inv[1][1] * ks[1],
            ];
            let mean = w[0] * ys[0] + w[1] * ys[1];
            let var = s2 - (w[0] * ks[0] + w[1] * ks[1]);
            let (m, v) = gp.predict(&[t]);
            assert!((m - mean).abs() < 1e-10, "mean at {t}: {m} vs {mean}");
            assert!((v - var).abs() < 1e-10, "var at {t}: {v} vs {var}");
        }
    }

    #[test]
    fn outputs_are_destandardised() {
        // Shifting and scaling y shifts and scales the posterior mean and scales the variance.
        let x: Vec<Vec<f64>> = [0.1, 0.5, 0.8].iter().map(|&v| vec![v]).collect();
        let y = [0.3, -0.2, 0.9];
        let y2: Vec<f64> = y.iter().map(|v| 5.0 + 3.0 * v).collect();
        let h = hyper(0.3, 1.0, 1e-3);
        let g1 = GaussianProcess::with_hyperparameters(x.clone(), &y, h.clone()).unwrap();
        let g2 = GaussianProcess::with_hyperparameters(x, &y2, h).unwrap();
        let (m1, v1) = g1.predict(&[0.33]);
        let (m2, v2) = g2.predict(&[0.33]);
        assert!((m2 - (5.0 + 3.0 * m1)).abs() < 1e-9);
        assert!((v2 - 9.0 * v1).abs() < 1e-9);
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let x: Vec<Vec<f64>> = (0..12)
            .map(|_| vec![rng.random::<f64>(), rng.random::<f64>()])
            .collect();
        let y: Vec<f64> = x.iter().map(|p| (4.0 * p[0]).sin() + p[1] * p[1]).collect();
        let (_, _, z) = standardise(&y);
        let theta = Hyperparameters {
            log_length_scales: vec![0.25f64.ln(), 0.6f64.ln()],
            log_signal_var: 0.3,
            log_noise_var: 0.05f64.ln(),
        };
        let (_, grad) = log_marginal_likelihood(&x, &z, &theta, true).unwrap();
        let base = theta.to_vec();
        for i in 0..base.len() {
            let h = 1e-5;
            let mut plus = base.clone();
            plus[i] += h;
            let mut minus = base.clone();
            minus[i] -= h;
            let lp = log_marginal_likelihood(&x, &z, &Hyperparameters::from_slice(&plus), false)
                .unwrap()
                .0;
            let lm = log_marginal_likelihood(&x, &z, &Hyperparameters::from_slice(&minus), false)
                .unwrap()
                .0;
            let fd = (lp - lm) / (2.0 * h);
            assert!(
                (fd - grad[i]).abs() < 1e-5 * (1.0 + fd.abs()),
                "component {i}: analytic {} vs finite difference {fd}",
                grad[i]
            );
        }
    }

    #[test]
    fn fit_learns_noise_and_relevance() {
        // y depends on x0 only, with noise of std 0.1 (variance 0.01 before standardisation).
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let x: Vec<Vec<f64>> = (0..40)
            .map(|_| vec![rng.random::<f64>(), rng.random::<f64>()])
            .collect();
        let y: Vec<f64> = x
            .iter()
            .map(|p| (6.0 * p[0]).sin() + 0.1 * (rng.random::<f64>() - 0.5) * 12f64.sqrt())
            .collect();
        let gp = GaussianProcess::fit(x, &y, None, FitOptions::default(), &mut rng).unwrap();
        let h = gp.hyperparameters();
        // The irrelevant dimension gets a much longer length scale.
        assert!(
            h.log_length_scales[1] > h.log_length_scales[0] + 1.0,
            "length scales {:?}",
            h.log_length_scales
        );
        // Learned noise in original units is near 0.01 (within a factor 4), not the 1e-6 floor.
        let y_var = {
            let m = y.iter().sum::<f64>() / y.len() as f64;
            y.iter().map(|v| (v - m).powi(2)).sum::<f64>() / y.len() as f64
        };
        let noise = h.log_noise_var.exp() * y_var;
        assert!(noise > 0.0025 && noise < 0.04, "noise variance {noise}");
        // And the posterior mean tracks the true function.
        let (m, _) = gp.predict(&[0.25, 0.5]);
        assert!((m - (1.5f64).sin()).abs() < 0.15, "mean {m}");
    }

    #[test]
    fn fitting_beats_the_default_likelihood_and_is_deterministic() {
        let x: Vec<Vec<f64>> = (0..15).map(|i| vec![i as f64 / 14.0]).collect();
        let y: Vec<f64> = x.iter().map(|p| (10.0 * p[0]).cos()).collect();
        let fit = |seed| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            GaussianProcess::fit(x.clone(), &y, None, FitOptions::default(), &mut rng).unwrap()
        };
        let a = fit(1);
        let b = fit(1);
        assert_eq!(a.hyperparameters(), b.hyperparameters());
        let default =
            GaussianProcess::with_hyperparameters(x.clone(), &y, Hyperparameters::default_for(1))
                .unwrap();
        assert!(a.log_marginal_likelihood() > default.log_marginal_likelihood());
    }

    #[test]
    fn rejects_bad_data() {
        let h = Hyperparameters::default_for(1);
        assert!(matches!(
            GaussianProcess::with_hyperparameters(vec![vec![0.0]], &[f64::NAN], h.clone()),
            Err(GpError::NonFinite { index: 0, .. })
        ));
        assert!(matches!(
            GaussianProcess::with_hyperparameters(vec![vec![0.0], vec![1.0]], &[1.0], h),
            Err(GpError::Shape(_))
        ));
    }
}
