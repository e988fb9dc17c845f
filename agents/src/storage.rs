//! Rollout storage and generalised advantage estimation.
//!
//! Truncated episodes are bootstrapped by the runner, which adds `gamma * V(final_obs)` to the
//! last reward; both truncation and termination then end the episode here (`done`), so the value
//! of the next (reset) observation never leaks across episodes.

/// One rollout: `steps x envs` transitions, row-major by step.
#[derive(Debug, Clone)]
pub struct RolloutStorage {
    /// Steps per copy.
    pub steps: usize,
    /// Environment copies.
    pub envs: usize,
    /// Observation width.
    pub obs_dim: usize,
    /// Action width (1 for discrete actions).
    pub action_dim: usize,
    /// Width of the critic's own observations (`None`: the critic reads `obs`).
    pub critic_obs_dim: Option<usize>,
    /// Normalised observations the policy acted on, `[T, E, obs_dim]`.
    pub obs: Vec<f32>,
    /// Normalised critic observations, `[T, E, critic_obs_dim]` (empty without a critic group).
    pub critic_obs: Vec<f32>,
    /// Raw sampled actions (before any transform to the bounds), `[T, E, action_dim]`.
    pub actions: Vec<f32>,
    /// Log-probabilities of the actions under the rollout policy, `[T, E]`.
    pub log_probs: Vec<f32>,
    /// Critic values of the observations, `[T, E]`.
    pub values: Vec<f32>,
    /// Rewards (with truncation bootstrap added), `[T, E]`.
    pub rewards: Vec<f32>,
    /// The episode ended at this step (terminated or truncated), `[T, E]`.
    pub dones: Vec<bool>,
    /// GAE advantages, `[T, E]`.
    pub advantages: Vec<f32>,
    /// Value targets `advantages + values`, `[T, E]`.
    pub returns: Vec<f32>,
}

impl RolloutStorage {
    /// Zeroed storage for a symmetric actor-critic (the critic reads the actor's observations).
    pub fn new(steps: usize, envs: usize, obs_dim: usize, action_dim: usize) -> Self {
        let n = steps * envs;
        Self {
            steps,
            envs,
            obs_dim,
            action_dim,
            critic_obs_dim: None,
            obs: vec![0.0; n * obs_dim],
            critic_obs: Vec::new(),
            actions: vec![0.0; n * action_dim],
            log_probs: vec![0.0; n],
            values: vec![0.0; n],
            rewards: vec![0.0; n],
            dones: vec![false; n],
            advantages: vec![0.0; n],
            returns: vec![0.0; n],
        }
    }

    /// Zeroed storage for an asymmetric actor-critic whose critic reads `critic_obs_dim`
    /// observations of its own.
    pub fn asymmetric(
        steps: usize,
        envs: usize,
        obs_dim: usize,
        critic_obs_dim: usize,
        action_dim: usize,
    ) -> Self {
        Self {
            critic_obs_dim: Some(critic_obs_dim),
            critic_obs: vec![0.0; steps * envs * critic_obs_dim],
            ..Self::new(steps, envs, obs_dim, action_dim)
        }
    }

    /// Number of transitions.
    pub fn len(&self) -> usize {
        self.steps * self.envs
    }

    /// Whether the storage holds no transitions.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Writes what the policy saw and did at `step`.
    pub fn record_action(
        &mut self,
        step: usize,
        obs: &[f32],
        actions: &[f32],
        log_probs: &[f32],
        values: &[f32],
    ) {
        let (e, d, a) = (self.envs, self.obs_dim, self.action_dim);
        self.obs[step * e * d..(step + 1) * e * d].copy_from_slice(obs);
        self.actions[step * e * a..(step + 1) * e * a].copy_from_slice(actions);
        self.log_probs[step * e..(step + 1) * e].copy_from_slice(log_probs);
        self.values[step * e..(step + 1) * e].copy_from_slice(values);
    }

    /// Writes the (normalised) critic observations of `step`; only for asymmetric storage.
    pub fn record_critic_obs(&mut self, step: usize, critic_obs: &[f32]) {
        let width = self
            .critic_obs_dim
            .expect("critic observations are stored only by asymmetric storage");
        let e = self.envs;
        self.critic_obs[step * e * width..(step + 1) * e * width].copy_from_slice(critic_obs);
    }

    /// Writes the outcome of `step`.
    pub fn record_outcome(&mut self, step: usize, rewards: &[f32], dones: &[bool]) {
        let e = self.envs;
        self.rewards[step * e..(step + 1) * e].copy_from_slice(rewards);
        self.dones[step * e..(step + 1) * e].copy_from_slice(dones);
    }

    /// GAE(lambda) advantages and returns, given the values of the observations after the last step.
    pub fn compute_returns(&mut self, last_values: &[f32], gamma: f32, lambda: f32) {
        let e = self.envs;
        let mut next_advantage = vec![0.0f32; e];
        for step in (0..self.steps).rev() {
            for env in 0..e {
                let i = step * e + env;
                let next_value = if step + 1 == self.steps {
                    last_values[env]
                } else {
                    self.values[i + e]
                };
                let not_done = if self.dones[i] { 0.0 } else { 1.0 };
                let delta = self.rewards[i] + gamma * next_value * not_done - self.values[i];
                next_advantage[env] = delta + gamma * lambda * not_done * next_advantage[env];
                self.advantages[i] = next_advantage[env];
                self.returns[i] = self.advantages[i] + self.values[i];
            }
        }
    }

    /// Fraction of the return variance the values explain (1 = perfect, <= 0 = useless).
    pub fn explained_variance(&self) -> f32 {
        let n = self.len() as f64;
        let mean = |x: &mut dyn Iterator<Item = f64>| x.sum::<f64>() / n;
        let ret_mean = mean(&mut self.returns.iter().map(|&r| r as f64));
        let var_ret = mean(&mut self.returns.iter().map(|&r| (r as f64 - ret_mean).powi(2)));
        let diff: Vec<f64> = self
            .returns
            .iter()
            .zip(&self.values)
            .map(|(&r, &v)| (r - v) as f64)
            .collect();
        let diff_mean = mean(&mut diff.iter().copied());
        let var_diff = mean(&mut diff.iter().map(|d| (d - diff_mean).powi(2)));
        if var_ret == 0.0 {
            f32::NAN
        } else {
            (1.0 - var_diff / var_ret) as f32
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gae_by_hand_with_a_truncation_and_a_termination() {
        // One copy, 5 steps, gamma = 0.5, lambda = 0.5 (gamma * lambda = 0.25).
        // Step 1 is truncated: its reward already holds r + gamma * V(final_obs) = 1 + 0.5 * 4 = 3.
        // Step 3 terminates. The value after the last step is 8.
        let mut storage = RolloutStorage::new(5, 1, 1, 1);
        let values = [1.0, 2.0, 3.0, 4.0, 5.0];
        let rewards = [1.0, 3.0, 1.0, 1.0, 1.0];
        let dones = [false, true, false, true, false];
        for step in 0..5 {
            storage.record_action(step, &[0.0], &[0.0], &[0.0], &[values[step]]);
            storage.record_outcome(step, &[rewards[step]], &[dones[step]]);
        }
        storage.compute_returns(&[8.0], 0.5, 0.5);
        // deltas: d4 = 1 + 0.5 * 8 - 5 = 0;   A4 = 0
        //         d3 = 1 - 4 = -3 (done);      A3 = -3
        //         d2 = 1 + 0.5 * 4 - 3 = 0;    A2 = 0 + 0.25 * -3 = -0.75
        //         d1 = 3 - 2 = 1 (done);       A1 = 1
        //         d0 = 1 + 0.5 * 2 - 1 = 1;    A0 = 1 + 0.25 * 1 = 1.25
        assert_eq!(storage.advantages, vec![1.25, 1.0, -0.75, -3.0, 0.0]);
        assert_eq!(storage.returns, vec![2.25, 3.0, 2.25, 1.0, 5.0]);
    }

    #[test]
    fn copies_are_independent() {
        let mut storage = RolloutStorage::new(2, 2, 1, 1);
        storage.record_action(0, &[0.0, 0.0], &[0.0, 0.0], &[0.0, 0.0], &[1.0, 0.0]);
        storage.record_action(1, &[0.0, 0.0], &[0.0, 0.0], &[0.0, 0.0], &[1.0, 0.0]);
        storage.record_outcome(0, &[1.0, 0.0], &[false, false]);
        storage.record_outcome(1, &[1.0, 0.0], &[false, false]);
        storage.compute_returns(&[1.0, 0.0], 0.9, 1.0);
        // Copy 0: TD errors are all 0.9 (r + 0.9 * 1 - 1); copy 1 is all zeros.
        assert!((storage.advantages[0] - (0.9 + 0.9 * 0.9)).abs() < 1e-6);
        assert_eq!((storage.advantages[1], storage.advantages[3]), (0.0, 0.0));
        assert!(storage.explained_variance().is_finite());
    }
}
