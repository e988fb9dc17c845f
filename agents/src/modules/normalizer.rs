//! Running mean and variance (Chan et al.'s parallel update, f64) for observations, and the
//! discounted-return reward scaler of Gymnasium's `NormalizeReward`.

use crate::export::ObsNormaliser;

/// Running mean and population variance of vectors, merged batch by batch.
#[derive(Debug, Clone, PartialEq)]
pub struct RunningMeanStd {
    /// Mean per dimension.
    pub mean: Vec<f64>,
    /// Population variance per dimension.
    pub var: Vec<f64>,
    /// Number of vectors seen.
    pub count: f64,
}

impl RunningMeanStd {
    /// Empty statistics for `dim`-wide vectors (mean 0, variance 1 until data arrives).
    pub fn new(dim: usize) -> Self {
        Self {
            mean: vec![0.0; dim],
            var: vec![1.0; dim],
            count: 0.0,
        }
    }

    /// Merges `n` rows of `data` (row-major `[n, dim]`).
    pub fn update(&mut self, data: &[f32], n: usize) {
        let dim = self.mean.len();
        if n == 0 {
            return;
        }
        let rows = || data.chunks_exact(dim).take(n);
        let mut batch_mean = vec![0.0f64; dim];
        for row in rows() {
            for (m, &x) in batch_mean.iter_mut().zip(row) {
                *m += x as f64;
            }
        }
        batch_mean.iter_mut().for_each(|m| *m /= n as f64);
        let mut batch_var = vec![0.0f64; dim];
        for row in rows() {
            for ((v, &x), m) in batch_var.iter_mut().zip(row).zip(&batch_mean) {
                *v += (x as f64 - m).powi(2);
            }
        }
        batch_var.iter_mut().for_each(|v| *v /= n as f64);
        self.merge(&batch_mean, &batch_var, n as f64);
    }

    fn merge(&mut self, batch_mean: &[f64], batch_var: &[f64], batch_count: f64) {
        let total = self.count + batch_count;
        for k in 0..self.mean.len() {
            let delta = batch_mean[k] - self.mean[k];
            let m2 = self.var[k] * self.count
                + batch_var[k] * batch_count
                + delta * delta * self.count * batch_count / total;
            self.mean[k] += delta * batch_count / total;
            self.var[k] = m2 / total;
        }
        self.count = total;
    }

    /// The frozen f32 normaliser that training, evaluation and the ONNX export all apply.
    pub fn to_obs_normaliser(&self, eps: f32, clip: f32) -> ObsNormaliser {
        ObsNormaliser {
            mean: self.mean.iter().map(|&m| m as f32).collect(),
            var: self.var.iter().map(|&v| v as f32).collect(),
            eps,
            clip,
        }
    }
}

/// Scales rewards by the running standard deviation of each copy's discounted return.
#[derive(Debug, Clone, PartialEq)]
pub struct RewardNormalizer {
    /// Statistics of the discounted return.
    pub return_stats: RunningMeanStd,
    /// Discounted return of the current episode of each copy.
    pub returns: Vec<f64>,
    /// Discount factor.
    pub gamma: f64,
    /// Added to the variance before the square root.
    pub eps: f32,
    /// Scaled rewards are clamped to +- this.
    pub clip: f32,
}

impl RewardNormalizer {
    /// A scaler for `num_envs` copies.
    pub fn new(num_envs: usize, gamma: f64, eps: f32, clip: f32) -> Self {
        Self {
            return_stats: RunningMeanStd::new(1),
            returns: vec![0.0; num_envs],
            gamma,
            eps,
            clip,
        }
    }

    /// Updates the return statistics with this step's rewards and scales `rewards` in place;
    /// returns of copies whose episode ended (`done`) restart at zero.
    pub fn normalize(&mut self, rewards: &mut [f32], done: &[bool]) {
        let discounted: Vec<f32> = self
            .returns
            .iter_mut()
            .zip(rewards.iter())
            .map(|(ret, &r)| {
                *ret = *ret * self.gamma + r as f64;
                *ret as f32
            })
            .collect();
        self.return_stats.update(&discounted, discounted.len());
        let std = (self.return_stats.var[0] as f32 + self.eps).sqrt();
        for (r, (ret, &d)) in rewards.iter_mut().zip(self.returns.iter_mut().zip(done)) {
            *r = (*r / std).clamp(-self.clip, self.clip);
            if d {
                *ret = 0.0;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn running_statistics_match_a_two_pass_computation() {
        // Three uneven batches of 2-D data with very different scales per dimension.
        let data: Vec<f32> = (0..37)
            .flat_map(|i| {
                let t = i as f32;
                [1000.0 + (t * 0.7).sin() * 3.0, -0.01 * t * t + 0.5]
            })
            .collect();
        let mut stats = RunningMeanStd::new(2);
        let (a, b) = (5 * 2, 21 * 2);
        stats.update(&data[..a], 5);
        stats.update(&data[a..b], 16);
        stats.update(&data[b..], 16);
        for k in 0..2 {
            let column: Vec<f64> = data.iter().skip(k).step_by(2).map(|&x| x as f64).collect();
            let mean = column.iter().sum::<f64>() / column.len() as f64;
            let var = column.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / column.len() as f64;
            assert!(
                (stats.mean[k] - mean).abs() < 1e-9 * mean.abs().max(1.0),
                "{k}"
            );
            assert!(
                (stats.var[k] - var).abs() < 1e-9 * var.max(1.0),
                "{k}: {} vs {var}",
                stats.var[k]
            );
        }
        assert_eq!(stats.count, 37.0);
    }

    #[test]
    fn reward_scale_follows_discounted_returns_and_resets_on_done() {
        let mut norm = RewardNormalizer::new(2, 0.5, 0.0, 100.0);
        let mut rewards = [1.0f32, 2.0];
        norm.normalize(&mut rewards, &[false, true]);
        // Returns 1 and 2: variance 0.25, std 0.5.
        assert_eq!(rewards, [2.0, 4.0]);
        assert_eq!(norm.returns, vec![1.0, 0.0]);
        let mut rewards = [1.0f32, 1.0];
        norm.normalize(&mut rewards, &[false, false]);
        // Returns now 1.5 and 1: all four returns 1, 2, 1.5, 1 -> var 0.171875.
        let std = 0.171875f32.sqrt();
        assert!((rewards[0] - 1.0 / std).abs() < 1e-6, "{rewards:?}");
    }
}
