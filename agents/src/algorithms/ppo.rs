//! Proximal policy optimisation: one update over a rollout, readable top to bottom (CleanRL's
//! `ppo.py` / `ppo_continuous_action.py`), with RSL-RL's adaptive-KL learning rate as an option.

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

/// The PPO learner: the actor-critic (on an autodiff device), Adam and the learning rate.
pub struct Ppo {
    /// The actor-critic being trained.
    pub model: ActorCritic,
    /// Adam state.
    pub optimizer: ModuleOptimizer,
    /// Current learning rate.
    pub learning_rate: f64,
    config: PpoConfig,
    device: Device,
    /// Width of the actor's output (number of classes for a categorical head).
    action_classes: usize,
}

/// One minibatch as tensors.
struct Minibatch {
    obs: Tensor<2>,
    actions: Tensor<2>,
    old_log_probs: Tensor<1>,
    old_values: Tensor<1>,
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
        let cfg = self.config.clone();
        let minibatch_size = storage.len() / cfg.minibatches;
        let mut indices: Vec<usize> = (0..storage.len()).collect();
        let mut sums = [0.0f64; 6];
        let mut count = 0.0;
        for _epoch in 0..cfg.epochs {
            indices.shuffle(rng);
            for chunk in indices.chunks_exact(minibatch_size) {
                let mb = self.minibatch(storage, chunk);

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
                let surrogate = mb.advantages.clone().neg() * ratio.clone();
                let surrogate_clipped = mb.advantages.neg()
                    * ratio
                        .clone()
                        .clamp(1.0 - cfg.clip_ratio, 1.0 + cfg.clip_ratio);
                let policy_loss = surrogate.max_pair(surrogate_clipped).mean();

                // Value loss, optionally clipped around the rollout's values.
                let values = self.model.value(mb.obs);
                let value_loss = if cfg.clip_value_loss {
                    let unclipped = (values.clone() - mb.returns.clone()).powi_scalar(2);
                    let clipped = mb.old_values.clone()
                        + (values - mb.old_values).clamp(-cfg.clip_ratio, cfg.clip_ratio);
                    let clipped = (clipped - mb.returns).powi_scalar(2);
                    unclipped.max_pair(clipped).mean().mul_scalar(0.5)
                } else {
                    (values - mb.returns).powi_scalar(2).mean().mul_scalar(0.5)
                };

                let loss = policy_loss.clone() - entropy.clone().mul_scalar(cfg.entropy_coef)
                    + value_loss.clone().mul_scalar(cfg.value_coef);

                // Diagnostics, read back in one transfer.
                let ratio = ratio.detach();
                let approx_kl = ((ratio.clone() - 1.0) - log_ratio.detach()).mean();
                let clip_fraction = (ratio - 1.0)
                    .abs()
                    .greater_elem(cfg.clip_ratio)
                    .float()
                    .mean();
                let diagnostics: Vec<f32> = Tensor::cat(
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
                .expect("f32 diagnostics");
                if cfg.lr_schedule == LrSchedule::AdaptiveKl {
                    self.adapt_learning_rate(diagnostics[3]);
                }

                // Backward, global gradient clip, Adam.
                let mut grads = GradientsParams::from_grads(loss.backward(), &self.model);
                let grad_norm = clip_global_grad_norm(&self.model, &mut grads, cfg.max_grad_norm);
                // Modules are handles to shared tensors: the clone is cheap.
                self.model = self
                    .optimizer
                    .step(self.learning_rate, self.model.clone(), grads);

                for (sum, value) in sums.iter_mut().zip(diagnostics.iter().chain([&grad_norm])) {
                    *sum += *value as f64;
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
        Minibatch {
            obs: Tensor::from_data(
                TensorData::new(gather(&storage.obs, d), [n, d]),
                &self.device,
            ),
            actions,
            old_log_probs: vector(gather(&storage.log_probs, 1)),
            old_values: vector(gather(&storage.values, 1)),
            advantages: vector(advantages),
            returns: vector(gather(&storage.returns, 1)),
        }
    }
}
