//! A trained policy: deterministic actions (Gaussian mean through the action transform, or the
//! argmax of the logits), its [`PolicyGraph`] for the ONNX exporter, and its evaluation.
//!
//! A policy is taken from a trainer ([`TrainedPolicy::from_trainer`]) or read from a run's
//! checkpoint with the environment's spec alone ([`TrainedPolicy::load`]): no environment is built.

use burn::module::Module;
use burn::tensor::{Device, Tensor, TensorData};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rlpkg_vec_env::{EnvSpec, SpaceKind, VecEnv};
use serde::Serialize;

use super::Trainer;
use crate::config::{check_memory, ActivationName, TrainConfig, TransformName};
use crate::export::graph::argmax;
use crate::export::runtime::run_episodes;
use crate::export::{
    ActionHead, ActionTransform, Activation, ObsNormaliser, PolicyGraph, PolicyMeta,
};
use crate::modules::ActorCritic;
use crate::AgentError;

/// The deterministic policy of a run, on a device without autodiff.
pub struct TrainedPolicy {
    /// The actor-critic.
    pub model: ActorCritic,
    /// Frozen observation normaliser, if the run normalised observations.
    pub normaliser: Option<ObsNormaliser>,
    /// Map from Gaussian means to action bounds (`None` for discrete actions).
    pub transform: Option<ActionTransform>,
    /// The environment's spec.
    pub spec: EnvSpec,
    /// Hash of the training configuration.
    pub config_hash: String,
    /// Updates of training behind the policy.
    pub update: usize,
    /// Environment steps of training behind the policy.
    pub global_step: u64,
    pub(super) device: Device,
}

/// The random stream that draws a run's initial weights (and then samples its actions and
/// minibatches); independent of the environments' streams (which use `seed + i`).
pub(super) fn model_rng(seed: u64) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(1);
    rng
}

/// The actor-critic `config` describes for the environment `spec` describes, with initial weights
/// drawn from `rng` on `device`, and the map from its Gaussian samples to the action bounds
/// (`None` for discrete actions).
pub(super) fn initial_actor_critic(
    config: &TrainConfig,
    spec: &EnvSpec,
    rng: &mut ChaCha8Rng,
    device: &Device,
) -> (ActorCritic, Option<ActionTransform>) {
    let (actor_out, log_std, transform) = match spec.action.kind {
        SpaceKind::Discrete { n } => (n, None, None),
        SpaceKind::Continuous => {
            let (low, high) = (spec.action.low.clone(), spec.action.high.clone());
            let transform = match config.policy.action_transform {
                TransformName::Clip => ActionTransform::Clip { low, high },
                TransformName::TanhScale => ActionTransform::TanhScale { low, high },
            };
            (
                spec.action.dim(),
                Some(config.policy.init_log_std),
                Some(transform),
            )
        }
    };
    let activation = match config.policy.activation {
        ActivationName::Tanh => Activation::Tanh,
        ActivationName::Relu => Activation::Relu,
        ActivationName::Elu => Activation::Elu,
    };
    let model = ActorCritic::new(
        spec.observation.dim(),
        spec.critic_obs_dim(),
        actor_out,
        &config.policy.actor_hidden,
        &config.policy.critic_hidden,
        activation,
        log_std,
        rng,
        device,
    );
    (model, transform)
}

impl TrainedPolicy {
    /// The trainer's current policy, frozen.
    pub fn from_trainer(trainer: &Trainer) -> Self {
        let model = trainer.ppo.model.valid();
        let device = trainer.device().clone();
        Self {
            model,
            normaliser: trainer.obs_normaliser(),
            transform: trainer.action_transform().cloned(),
            spec: trainer.spec().clone(),
            config_hash: trainer.config_hash().to_string(),
            update: trainer.update,
            global_step: trainer.global_step,
            device,
        }
    }

    /// Deterministic actions for `n` rows of raw observations, as the environment receives them.
    pub fn act(&self, obs: &[f32], n: usize) -> Vec<f32> {
        let dim = self.spec.observation.dim();
        let normalised = match &self.normaliser {
            Some(norm) => norm.apply(obs, n),
            None => obs[..n * dim].to_vec(),
        };
        let input = Tensor::<2>::from_data(TensorData::new(normalised, [n, dim]), &self.device);
        let head: Vec<f32> = self
            .model
            .actor(input)
            .try_into_vec_as()
            .expect("f32 output");
        match &self.transform {
            Some(transform) => {
                let a = self.spec.action.dim();
                head.chunks_exact(a)
                    .flat_map(|mean| mean.iter().enumerate().map(|(j, &m)| transform.apply(j, m)))
                    .collect()
            }
            None => {
                let classes = head.len() / n;
                head.chunks_exact(classes)
                    .map(|row| argmax(row) as f32)
                    .collect()
            }
        }
    }

    /// The plain-number description the ONNX exporter writes (the critic included when it reads
    /// the actor's observations; a critic with privileged observations is left out, since the
    /// exported graph has one input, what a real cell measures).
    pub fn policy_graph(&self) -> PolicyGraph {
        let actor = self.model.actor_layers();
        let head = match &self.transform {
            Some(transform) => ActionHead::Gaussian {
                transform: transform.clone(),
            },
            None => ActionHead::Categorical {
                n: actor.last().map_or(0, |l| l.d_out),
            },
        };
        PolicyGraph {
            normaliser: self.normaliser.clone(),
            actor,
            critic: (!self.spec.is_asymmetric()).then(|| self.model.critic_layers()),
            activation: self.model.activation(),
            head,
            meta: PolicyMeta::from_spec(&self.spec, env!("CARGO_PKG_VERSION"), &self.config_hash),
        }
    }
}

/// Result of a deterministic evaluation.
#[derive(Debug, Clone, Serialize)]
pub struct EvalSummary {
    /// Environment id.
    pub env_id: String,
    /// Episodes run.
    pub episodes: usize,
    /// Seed of the evaluation environments.
    pub seed: u64,
    /// Update the checkpoint was written after.
    pub update: usize,
    /// Environment steps of training behind the checkpoint.
    pub global_step: u64,
    /// Mean undiscounted return.
    pub mean_return: f64,
    /// Population standard deviation of the returns.
    pub std_return: f64,
    /// Smallest return.
    pub min_return: f64,
    /// Largest return.
    pub max_return: f64,
    /// Mean episode length.
    pub mean_length: f64,
}

/// Bytes an evaluation of `episodes` environment copies in lockstep needs: per copy, the
/// environment's buffers and state, and one row of every layer (`layer_widths`, the sum of the
/// widths after the input) with its normalised input.
pub fn evaluation_memory_bytes(episodes: usize, obs_dim: usize, layer_widths: usize) -> f64 {
    let floats_per_copy = 4 * obs_dim + 2 * layer_widths + 16;
    episodes as f64 * floats_per_copy as f64 * 4.0
}

impl TrainedPolicy {
    /// An error when `episodes` environment copies in lockstep would not fit in memory with this
    /// policy (see [`evaluation_memory_bytes`]); check before building them.
    pub fn check_evaluation_memory(&self, episodes: usize) -> Result<(), AgentError> {
        let widths: usize = self
            .model
            .actor_layers()
            .iter()
            .map(|layer| layer.d_out)
            .sum();
        check_memory(
            &format!("--episodes {episodes}"),
            evaluation_memory_bytes(episodes, self.spec.observation.dim(), widths),
        )
    }

    /// Runs one deterministic episode per copy of `env` (copy `i` seeded `seed + i`).
    pub fn evaluate(&self, env: &mut dyn VecEnv, seed: u64) -> Result<EvalSummary, AgentError> {
        let episodes = env.num_envs();
        let stats = run_episodes::<AgentError>(env, seed, 0, |obs, n| Ok(self.act(obs, n)))?;
        let returns = stats.returns.iter().map(|&r| r as f64);
        Ok(EvalSummary {
            env_id: self.spec.id.clone(),
            episodes,
            seed,
            update: self.update,
            global_step: self.global_step,
            mean_return: stats.mean_return(),
            std_return: stats.std_return(),
            min_return: returns.clone().fold(f64::INFINITY, f64::min),
            max_return: returns.fold(f64::NEG_INFINITY, f64::max),
            mean_length: stats.lengths.iter().sum::<usize>() as f64 / episodes.max(1) as f64,
        })
    }
}
