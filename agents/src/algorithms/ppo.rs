//! Proximal policy optimisation: one update over a rollout, readable top to bottom (CleanRL's
//! `ppo.py` / `ppo_continuous_action.py`), with RSL-RL's adaptive-KL learning rate as an option.

use std::time::Instant;

use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::{Device, Tensor, TensorData};
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

use super::clip_global_grad_norm;
use crate::config::{LrSchedule, PpoConfig};
use crate::modules::distributions::{
    categorical_log_prob_entropy, gaussian_entropy, gaussian_log_prob, one_hot,
};
use crate::modules::ActorCritic;
use crate::storage::RolloutStorage;

/// Averages over the minibatches of one update, for logging.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct UpdateStats {
    /// Clipped surrogate loss.
    pub policy_loss: f32,
    /// Value loss (0.5 x squared error, clipped if configured).
    pub value_loss: f32,
    /// Mean policy entropy.
    pub entropy: f32,
    /// Approximate KL divergence between the rollout and the updated policy.
    pub approx_kl: f32,
    /// Fraction of samples whose ratio left the clip range.
    pub clip_fraction: f32,
    /// Global gradient norm before clipping.
    pub grad_norm: f32,
    /// Learning rate at the end of the update.
    pub learning_rate: f64,
}

/// Wall time (seconds) spent in each phase of PPO minibatch updates, summed over minibatches.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PhaseTimes {
    /// Gathering the shuffled rows into tensors (and normalising advantages).
    pub batch: f64,
    /// Forward passes, the loss and reading the diagnostics back.
    pub forward: f64,
    /// Backpropagation down to the parameter gradients.
    pub backward: f64,
    /// Global gradient clipping and the Adam step.
    pub optimiser: f64,
}

impl PhaseTimes {
    /// Sum of the phases.
    pub fn total(&self) -> f64 {
        self.batch + self.forward + self.backward + self.optimiser
    }

    /// Adds `other` phase by phase.
    pub fn add(&mut self, other: &PhaseTimes) {
        self.batch += other.batch;
        self.forward += other.forward;
        self.backward += other.backward;
        self.optimiser += other.optimiser;
    }
}

/// The PPO learner: the actor-critic (on an autodiff device), Adam and the learning rate.
pub struct Ppo {
    /// The actor-critic being trained.
    pub model: ActorCritic,
    /// Adam state.
    pub optimizer: ModuleOptimizer,
    /// Current learning rate.
    pub learning_rate: f64,
    /// Phase times of the last call to [`Ppo::update`] (not part of any result: timing only).
    pub times: PhaseTimes,
    config: PpoConfig,
    device: Device,
    /// Width of the actor's output (number of classes for a categorical head).
    action_classes: usize,
}

/// One minibatch as tensors.
struct Minibatch {
    obs: Tensor<2>,
    /// The critic's observations (the same tensor as `obs` for a symmetric actor-critic).
    critic_obs: Tensor<2>,
    actions: Tensor<2>,
    old_log_probs: Tensor<1>,
    old_values: Tensor<1>,
    /// Rollout values minus returns (for the clipped value loss).
    old_values_minus_returns: Tensor<1>,
    advantages: Tensor<1>,
    returns: Tensor<1>,
}

impl Ppo {
    /// A learner for `model`; `device` must have autodiff enabled.
    pub fn new(model: ActorCritic, config: &PpoConfig, device: Device) -> Self {
        let optimizer = AdamConfig::new().with_epsilon(config.adam_epsilon).init();
        let action_classes = model.actor_layers().last().map_or(1, |l| l.d_out);
        Self {
            action_classes,
            model,
            optimizer,
            learning_rate: config.learning_rate,
            times: PhaseTimes::default(),
            config: config.clone(),
            device,
        }
    }

    /// Sets the learning rate CleanRL's linear annealing gives update `update` (0-based) of `total`.
    pub fn anneal(&mut self, update: usize, total: usize) {
        if self.config.lr_schedule == LrSchedule::Linear {
            self.learning_rate = (1.0 - update as f64 / total as f64) * self.config.learning_rate;
        }
    }

    /// `epochs` passes over `storage` in `minibatches` shuffled minibatches.
    pub fn update(&mut self, storage: &RolloutStorage, rng: &mut ChaCha8Rng) -> UpdateStats {
        let cfg = &self.config;
        let minibatch_size = storage.len() / cfg.minibatches;
        let mut indices: Vec<usize> = (0..storage.len()).collect();
        let mut sums = [0.0f64; 6];
        let mut count = 0.0;
        self.times = PhaseTimes::default();
        for _epoch in 0..cfg.epochs {
            indices.shuffle(rng);
            for chunk in indices.chunks_exact(minibatch_size) {
                let start = Instant::now();
                let mb = self.minibatch(storage, chunk);
                self.times.batch += start.elapsed().as_secs_f64();
                let diagnostics = self.step(mb);
                for (sum, value) in sums.iter_mut().zip(diagnostics) {
                    *sum += value as f64;
                }
                count += 1.0;
            }
        }
        let mean = |k: usize| (sums[k] / count) as f32;
        UpdateStats {
            policy_loss: mean(0),
            value_loss: mean(1),
            entropy: mean(2),
            approx_kl: mean(3),
            clip_fraction: mean(4),
            grad_norm: mean(5),
            learning_rate: self.learning_rate,
        }
    }

    /// The loss of one minibatch and the diagnostics (policy loss, value loss, entropy,
    /// approximate KL, clip fraction), still on the device.
    fn loss(&self, mb: Minibatch) -> (Tensor<1>, Tensor<1>) {
        let cfg = &self.config;
        // Policy loss: clipped surrogate.
        let head = self.model.actor(mb.obs.clone());
        let (new_log_probs, entropy) = match self.model.log_std() {
            Some(log_std) => (
                gaussian_log_prob(head, log_std.clone(), mb.actions),
                gaussian_entropy(log_std),
            ),
            None => {
                let (log_probs, entropy) = categorical_log_prob_entropy(head, mb.actions);
                (log_probs, entropy.mean())
            }
        };
        let log_ratio = new_log_probs - mb.old_log_probs;
        let ratio = log_ratio.clone().exp();
        // max(-A r, -A clip(r)) = -min(A r, A clip(r)).
        let surrogate = mb.advantages.clone() * ratio.clone();
        let surrogate_clipped = mb.advantages
            * ratio
                .clone()
                .clamp(1.0 - cfg.clip_ratio, 1.0 + cfg.clip_ratio);
        let policy_loss = surrogate.min_pair(surrogate_clipped).mean().neg();

        // Value loss, optionally clipped around the rollout's values.
        let values = self.model.value(mb.critic_obs);
        let value_loss = if cfg.clip_value_loss {
            let delta = values - mb.old_values;
            // (old + clip(v - old) - R) with old - R precomputed on the host.
            let unclipped = (delta.clone() + mb.old_values_minus_returns.clone()).powi_scalar(2);
            let clipped = (delta.clamp(-cfg.clip_ratio, cfg.clip_ratio)
                + mb.old_values_minus_returns)
                .powi_scalar(2);
            unclipped.max_pair(clipped).mean().mul_scalar(0.5)
        } else {
            (values - mb.returns).powi_scalar(2).mean().mul_scalar(0.5)
        };

        let loss = policy_loss.clone() - entropy.clone().mul_scalar(cfg.entropy_coef)
            + value_loss.clone().mul_scalar(cfg.value_coef);

        let ratio = ratio.detach();
        let approx_kl = ((ratio.clone() - 1.0) - log_ratio.detach()).mean();
        let clip_fraction = (ratio - 1.0)
            .abs()
            .greater_elem(cfg.clip_ratio)
            .float()
            .mean();
        let diagnostics = Tensor::cat(
            vec![
                policy_loss.detach(),
                value_loss.detach(),
                entropy.detach(),
                approx_kl,
                clip_fraction,
            ],
            0,
        );
        (loss, diagnostics)
    }

    /// Forward, backward, global gradient clip and Adam on one minibatch; returns the five
    /// diagnostics of [`Ppo::loss`] and the gradient norm.
    fn step(&mut self, mb: Minibatch) -> [f32; 6] {
        let start = Instant::now();
        let (loss, diagnostics) = self.loss(mb);
        // One read-back per minibatch.
        let d: Vec<f32> = diagnostics.try_into_vec_as().expect("f32 diagnostics");
        if self.config.lr_schedule == LrSchedule::AdaptiveKl {
            self.adapt_learning_rate(d[3]);
        }
        let forward_done = Instant::now();
        let mut grads = GradientsParams::from_grads(loss.backward(), &self.model);
        let backward_done = Instant::now();
        let grad_norm = clip_global_grad_norm(&self.model, &mut grads, self.config.max_grad_norm);
        // Modules are handles to shared tensors: the clone is cheap.
        self.model = self
            .optimizer
            .step(self.learning_rate, self.model.clone(), grads);
        let end = Instant::now();
        self.times.forward += (forward_done - start).as_secs_f64();
        self.times.backward += (backward_done - forward_done).as_secs_f64();
        self.times.optimiser += (end - backward_done).as_secs_f64();
        [d[0], d[1], d[2], d[3], d[4], grad_norm]
    }

    /// RSL-RL's schedule: divide by 1.5 above twice the target KL, multiply by 1.5 below half.
    fn adapt_learning_rate(&mut self, kl: f32) {
        let target = self.config.desired_kl;
        if kl > 2.0 * target {
            self.learning_rate = (self.learning_rate / 1.5).max(1e-5);
        } else if kl < 0.5 * target && kl > 0.0 {
            self.learning_rate = (self.learning_rate * 1.5).min(1e-2);
        }
    }

    /// Gathers rows `chunk` of the rollout into tensors, normalising advantages if configured.
    fn minibatch(&self, storage: &RolloutStorage, chunk: &[usize]) -> Minibatch {
        let n = chunk.len();
        let (d, a) = (storage.obs_dim, storage.action_dim);
        let gather = |source: &[f32], width: usize| -> Vec<f32> {
            chunk
                .iter()
                .flat_map(|&i| source[i * width..(i + 1) * width].iter().copied())
                .collect()
        };
        let mut advantages = gather(&storage.advantages, 1);
        if self.config.normalize_advantages && n > 1 {
            // Mean and sample standard deviation, as torch's `std()`.
            let mean = advantages.iter().map(|&x| x as f64).sum::<f64>() / n as f64;
            let var = advantages
                .iter()
                .map(|&x| (x as f64 - mean).powi(2))
                .sum::<f64>()
                / (n - 1) as f64;
            let std = var.sqrt() + 1e-8;
            advantages
                .iter_mut()
                .for_each(|x| *x = ((*x as f64 - mean) / std) as f32);
        }
        let actions = match self.model.log_std() {
            Some(_) => Tensor::from_data(
                TensorData::new(gather(&storage.actions, a), [n, a]),
                &self.device,
            ),
            None => {
                let classes = self.action_classes;
                let rows = one_hot(&gather(&storage.actions, 1), classes);
                Tensor::from_data(TensorData::new(rows, [n, classes]), &self.device)
            }
        };
        let vector =
            |values: Vec<f32>| Tensor::from_data(TensorData::new(values, [n]), &self.device);
        let (old_values, returns) = (gather(&storage.values, 1), gather(&storage.returns, 1));
        let obs = Tensor::from_data(
            TensorData::new(gather(&storage.obs, d), [n, d]),
            &self.device,
        );
        let critic_obs = match storage.critic_obs_dim {
            Some(c) => Tensor::from_data(
                TensorData::new(gather(&storage.critic_obs, c), [n, c]),
                &self.device,
            ),
            None => obs.clone(),
        };
        Minibatch {
            obs,
            critic_obs,
            actions,
            old_log_probs: vector(gather(&storage.log_probs, 1)),
            old_values_minus_returns: vector(
                old_values
                    .iter()
                    .zip(&returns)
                    .map(|(v, r)| v - r)
                    .collect(),
            ),
            old_values: vector(old_values),
            advantages: vector(advantages),
            returns: vector(returns),
        }
    }
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};

    use super::*;
    use crate::export::Activation;

    /// One minibatch step exactly as the trainer did it before the fused layers and the loss
    /// rewrite (burn's `Linear` + `tanh`, the loss op by op): the reference for the fast path.
    fn reference_step(ppo: &mut Ppo, mb: Minibatch) -> [f32; 6] {
        let cfg = ppo.config.clone();
        let head = ppo.model.reference_actor(mb.obs.clone());
        let (new_log_probs, entropy) = match ppo.model.log_std() {
            Some(log_std) => (
                gaussian_log_prob(head, log_std.clone(), mb.actions),
                gaussian_entropy(log_std),
            ),
            None => {
                let (log_probs, entropy) = categorical_log_prob_entropy(head, mb.actions);
                (log_probs, entropy.mean())
            }
        };
        let log_ratio = new_log_probs - mb.old_log_probs;
        let ratio = log_ratio.clone().exp();
        let surrogate = mb.advantages.clone().neg() * ratio.clone();
        let surrogate_clipped = mb.advantages.neg()
            * ratio
                .clone()
                .clamp(1.0 - cfg.clip_ratio, 1.0 + cfg.clip_ratio);
        let policy_loss = surrogate.max_pair(surrogate_clipped).mean();
        let values = ppo.model.reference_value(mb.critic_obs);
        let unclipped = (values.clone() - mb.returns.clone()).powi_scalar(2);
        let clipped =
            mb.old_values.clone() + (values - mb.old_values).clamp(-cfg.clip_ratio, cfg.clip_ratio);
        let clipped = (clipped - mb.returns).powi_scalar(2);
        let value_loss = unclipped.max_pair(clipped).mean().mul_scalar(0.5);
        let loss = policy_loss.clone() - entropy.clone().mul_scalar(cfg.entropy_coef)
            + value_loss.clone().mul_scalar(cfg.value_coef);
        let ratio = ratio.detach();
        let approx_kl = ((ratio.clone() - 1.0) - log_ratio.detach()).mean();
        let clip_fraction = (ratio - 1.0)
            .abs()
            .greater_elem(cfg.clip_ratio)
            .float()
            .mean();
        let d: Vec<f32> = Tensor::cat(
            vec![
                policy_loss.detach(),
                value_loss.detach(),
                entropy.detach(),
                approx_kl,
                clip_fraction,
            ],
            0,
        )
        .try_into_vec_as()
        .unwrap();
        let mut grads = GradientsParams::from_grads(loss.backward(), &ppo.model);
        let grad_norm = clip_global_grad_norm(&ppo.model, &mut grads, cfg.max_grad_norm);
        ppo.model = ppo
            .optimizer
            .step(ppo.learning_rate, ppo.model.clone(), grads);
        [d[0], d[1], d[2], d[3], d[4], grad_norm]
    }

    /// `classes`: `None` for a Gaussian head with `actions` dimensions, `Some(n)` for a
    /// categorical head over `n` classes.
    fn learner(
        backend: crate::Backend,
        obs_dim: usize,
        hidden: usize,
        actions: usize,
        classes: Option<usize>,
    ) -> Ppo {
        let device = backend.device().autodiff();
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let model = ActorCritic::new(
            obs_dim,
            obs_dim,
            classes.unwrap_or(actions),
            &[hidden, hidden],
            &[hidden, hidden],
            Activation::Tanh,
            classes.is_none().then_some(-0.5),
            &mut rng,
            &device,
        );
        let config = PpoConfig {
            rollout_steps: 1024,
            epochs: 2,
            minibatches: 2,
            gamma: 0.99,
            gae_lambda: 0.95,
            clip_ratio: 0.2,
            clip_value_loss: true,
            value_coef: 0.5,
            entropy_coef: 0.01,
            max_grad_norm: 1.0,
            learning_rate: 1e-3,
            lr_schedule: LrSchedule::Constant,
            desired_kl: 0.01,
            normalize_advantages: true,
            adam_epsilon: 1e-5,
        };
        Ppo::new(model, &config, device)
    }

    /// A rollout of random numbers whose old log-probs sit near the current policy's, so some
    /// ratios leave the clip range and some do not.
    fn random_rollout(obs_dim: usize, actions: usize, classes: Option<usize>) -> RolloutStorage {
        let mut storage = RolloutStorage::new(1024, 1, obs_dim, actions);
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut fill = |v: &mut Vec<f32>, scale: f32, offset: f32| {
            v.iter_mut()
                .for_each(|x| *x = offset + scale * (rng.random::<f32>() - 0.5))
        };
        fill(&mut storage.obs, 4.0, 0.0);
        match classes {
            None => {
                fill(&mut storage.actions, 2.0, 0.0);
                // E[log N(a; ~0, e^-1)] for a ~ U(-1, 1) is about -0.87 per dimension.
                fill(&mut storage.log_probs, 1.0, -0.87 * actions as f32);
            }
            Some(n) => {
                // Classes 0..n from uniform draws in [0, n).
                fill(&mut storage.actions, n as f32, 0.5 * n as f32);
                storage.actions.iter_mut().for_each(|a| *a = a.floor());
                // The initial policy is nearly uniform.
                fill(&mut storage.log_probs, 1.0, -(n as f32).ln());
            }
        }
        fill(&mut storage.values, 2.0, 0.0);
        fill(&mut storage.advantages, 2.0, 0.3);
        fill(&mut storage.returns, 2.0, 0.0);
        storage
    }

    #[test]
    fn fast_update_gives_the_reference_parameters() {
        // 4 Adam steps (2 epochs x 2 minibatches of 512) on a 20-64-64 actor-critic with a
        // 3-dimensional Gaussian head, and with a 4-class categorical head (one action value).
        let cases = [
            (crate::Backend::Flex, 3, None),
            (crate::Backend::NdArray, 3, None),
            (crate::Backend::Flex, 1, Some(4)),
        ];
        for (backend, actions, classes) in cases {
            let (obs_dim, hidden) = (20, 64);
            let storage = random_rollout(obs_dim, actions, classes);
            let mut fast = learner(backend, obs_dim, hidden, actions, classes);
            let mut reference = learner(backend, obs_dim, hidden, actions, classes);
            let initial = fast.model.flat_parameters();
            assert_eq!(initial, reference.model.flat_parameters());

            let fast_stats = fast.update(&storage, &mut ChaCha8Rng::seed_from_u64(3));
            let mut rng = ChaCha8Rng::seed_from_u64(3);
            let mut indices: Vec<usize> = (0..storage.len()).collect();
            let mut reference_diagnostics = Vec::new();
            for _ in 0..2 {
                indices.shuffle(&mut rng);
                for chunk in indices.chunks_exact(512) {
                    let mb = reference.minibatch(&storage, chunk);
                    reference_diagnostics.push(reference_step(&mut reference, mb));
                }
            }

            let (a, b) = (
                fast.model.flat_parameters(),
                reference.model.flat_parameters(),
            );
            let moved = a
                .iter()
                .zip(&initial)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f32::max);
            let worst = a
                .iter()
                .zip(&b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f32::max);
            // Adam moves parameters by up to 4 x lr = 4e-3 here; the two paths agree to float
            // rounding (measured: at most 7.5e-8; the fused layer's tanh is within 4 ulp of
            // the exact value).
            assert!(
                moved > 1e-3,
                "{backend:?}: the update barely moved: {moved}"
            );
            assert!(
                worst < 5e-7,
                "{backend:?}: parameters differ by up to {worst}"
            );
            let mean = |k: usize| reference_diagnostics.iter().map(|d| d[k]).sum::<f32>() / 4.0;
            let clip_fraction = mean(4);
            assert!(
                clip_fraction > 0.05 && clip_fraction < 0.95,
                "both branches of the clipped surrogate are exercised: {clip_fraction}"
            );
            for (fast, reference) in [
                (fast_stats.policy_loss, mean(0)),
                (fast_stats.value_loss, mean(1)),
                (fast_stats.approx_kl, mean(3)),
                (fast_stats.grad_norm, mean(5)),
            ] {
                assert!(
                    (fast - reference).abs() <= 1e-5 * (1.0 + reference.abs()),
                    "{backend:?}: {fast} vs {reference}"
                );
            }
            // A ratio within rounding of the clip bound may fall on either side.
            assert!((fast_stats.clip_fraction - clip_fraction).abs() < 0.01);
        }
    }
}
