//! Action distributions: diagonal Gaussian with a state-independent log-std, and categorical.
//! Log-probabilities and entropies are tensors (they enter the loss); sampling happens on the
//! host with the trainer's seeded random stream.

use burn::tensor::activation::log_softmax;
use burn::tensor::Tensor;
use rand::Rng;
use rand_distr::StandardNormal;

/// ln(2 pi) / 2.
const HALF_LN_2PI: f32 = 0.918_938_5;

/// Log-density of `actions` `[B, A]` under N(mean `[B, A]`, exp(log_std `[A]`)^2), summed over
/// action dimensions: `[B]`.
pub fn gaussian_log_prob(mean: Tensor<2>, log_std: Tensor<1>, actions: Tensor<2>) -> Tensor<1> {
    let log_std = log_std.unsqueeze_dim::<2>(0);
    let z = (actions - mean) / log_std.clone().exp();
    let per_dim = z.powi_scalar(2).mul_scalar(-0.5) - log_std - HALF_LN_2PI;
    per_dim.sum_dim(1).squeeze_dim(1)
}

/// Entropy of the diagonal Gaussian, summed over dimensions (the same for every state): `[1]`.
pub fn gaussian_entropy(log_std: Tensor<1>) -> Tensor<1> {
    (log_std + (0.5 + HALF_LN_2PI)).sum()
}

/// Log-probability of the chosen `one_hot` `[B, n]` actions under softmax(`logits` `[B, n]`)
/// and the entropy of each row: (`[B]`, `[B]`).
pub fn categorical_log_prob_entropy(
    logits: Tensor<2>,
    one_hot: Tensor<2>,
) -> (Tensor<1>, Tensor<1>) {
    let log_p = log_softmax(logits, 1);
    let chosen = (log_p.clone() * one_hot).sum_dim(1).squeeze_dim(1);
    let entropy = (log_p.clone().exp() * log_p)
        .sum_dim(1)
        .squeeze_dim(1)
        .neg();
    (chosen, entropy)
}

/// Samples `mean + std * N(0, 1)` per value of `mean` (row-major `[B, A]`, `std` is `[A]`).
pub fn sample_gaussian(mean: &[f32], std: &[f32], rng: &mut impl Rng) -> Vec<f32> {
    mean.iter()
        .zip(std.iter().cycle())
        .map(|(&m, &s)| m + s * rng.sample::<f32, _>(StandardNormal))
        .collect()
}

/// Samples one index per row of `logits` (`[B, n]`) by inverting the softmax CDF.
pub fn sample_categorical(logits: &[f32], n: usize, rng: &mut impl Rng) -> Vec<f32> {
    logits
        .chunks_exact(n)
        .map(|row| {
            let max = row.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            let weights: Vec<f32> = row.iter().map(|&l| (l - max).exp()).collect();
            let mut u = rng.random::<f32>() * weights.iter().sum::<f32>();
            for (index, w) in weights.iter().enumerate() {
                if u < *w {
                    return index as f32;
                }
                u -= w;
            }
            (n - 1) as f32
        })
        .collect()
}

/// One-hot rows (`[B, n]`) of integral action values.
pub fn one_hot(actions: &[f32], n: usize) -> Vec<f32> {
    let mut out = vec![0.0; actions.len() * n];
    for (row, &a) in out.chunks_exact_mut(n).zip(actions) {
        row[a as usize] = 1.0;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::{Device, TensorData};
    use rand::SeedableRng;

    fn device() -> Device {
        crate::Backend::DEFAULT.device()
    }

    fn t2(values: Vec<f32>, rows: usize, cols: usize) -> Tensor<2> {
        Tensor::from_data(TensorData::new(values, [rows, cols]), &device())
    }

    fn t1(values: Vec<f32>) -> Tensor<1> {
        let n = values.len();
        Tensor::from_data(TensorData::new(values, [n]), &device())
    }

    fn host(t: Tensor<1>) -> Vec<f32> {
        t.try_into_vec_as::<f32>().unwrap()
    }

    #[test]
    fn gaussian_log_prob_matches_the_closed_form() {
        // N(0, 1) at 0: -ln(2 pi)/2; N(1, 2^2) at 3: -1/2 - ln 2 - ln(2 pi)/2; in 2-D they add.
        let mean = t2(vec![0.0, 1.0, 0.0, 1.0], 2, 2);
        let log_std = t1(vec![0.0, 2f32.ln()]);
        let actions = t2(vec![0.0, 3.0, 1.0, 1.0], 2, 2);
        let got = host(gaussian_log_prob(mean, log_std, actions));
        let half_ln_2pi = 0.5 * (2.0 * std::f64::consts::PI).ln();
        let row0 = -half_ln_2pi + (-0.5 - 2f64.ln() - half_ln_2pi);
        let row1 = (-0.5 - half_ln_2pi) + (-2f64.ln() - half_ln_2pi);
        assert!((got[0] as f64 - row0).abs() < 1e-5, "{got:?} vs {row0}");
        assert!((got[1] as f64 - row1).abs() < 1e-5, "{got:?} vs {row1}");
    }

    #[test]
    fn gaussian_density_integrates_to_one_and_entropy_is_minus_its_mean_log() {
        // Riemann sum over [-8 sigma, 8 sigma] of a 1-D Gaussian with sigma = 0.7.
        let sigma = 0.7f32;
        let n = 4001;
        let step = 16.0 * sigma / (n - 1) as f32;
        let xs: Vec<f32> = (0..n)
            .map(|i| 0.3 - 8.0 * sigma + i as f32 * step)
            .collect();
        let log_p = host(gaussian_log_prob(
            t2(vec![0.3; n], n, 1),
            t1(vec![sigma.ln()]),
            t2(xs, n, 1),
        ));
        let mass: f64 = log_p.iter().map(|&l| (l as f64).exp() * step as f64).sum();
        let neg_mean_log: f64 = log_p
            .iter()
            .map(|&l| -(l as f64) * (l as f64).exp() * step as f64)
            .sum();
        let entropy = host(gaussian_entropy(t1(vec![sigma.ln()])))[0] as f64;
        let closed =
            0.5 * (2.0 * std::f64::consts::PI * std::f64::consts::E * (sigma as f64).powi(2)).ln();
        assert!((mass - 1.0).abs() < 1e-4, "{mass}");
        assert!((entropy - closed).abs() < 1e-5, "{entropy} vs {closed}");
        assert!(
            (neg_mean_log - closed).abs() < 1e-3,
            "{neg_mean_log} vs {closed}"
        );
    }

    #[test]
    fn categorical_matches_softmax_by_hand() {
        // logits [0, ln 3]: p = [1/4, 3/4]; entropy = -(1/4 ln 1/4 + 3/4 ln 3/4).
        let logits = t2(vec![0.0, 3f32.ln(), 0.0, 3f32.ln()], 2, 2);
        let (log_p, entropy) =
            categorical_log_prob_entropy(logits, t2(one_hot(&[0.0, 1.0], 2), 2, 2));
        let (log_p, entropy) = (host(log_p), host(entropy));
        assert!((log_p[0] - 0.25f32.ln()).abs() < 1e-6 && (log_p[1] - 0.75f32.ln()).abs() < 1e-6);
        let h = -(0.25f32 * 0.25f32.ln() + 0.75 * 0.75f32.ln());
        assert!((entropy[0] - h).abs() < 1e-6 && (entropy[1] - h).abs() < 1e-6);
    }

    #[test]
    fn samplers_follow_their_distributions() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let samples = sample_categorical(&[0.0, 3f32.ln()].repeat(20000), 2, &mut rng);
        let ones = samples.iter().filter(|&&a| a == 1.0).count() as f32 / 20000.0;
        assert!((ones - 0.75).abs() < 0.015, "{ones}");
        let draws = sample_gaussian(&[2.0; 20000], &[0.5], &mut rng);
        let mean = draws.iter().sum::<f32>() / 20000.0;
        let var = draws.iter().map(|d| (d - mean).powi(2)).sum::<f32>() / 20000.0;
        assert!(
            (mean - 2.0).abs() < 0.02 && (var - 0.25).abs() < 0.01,
            "{mean} {var}"
        );
    }
}
