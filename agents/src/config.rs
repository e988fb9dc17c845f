//! Training configuration read from TOML: every hyperparameter is named and required; unknown keys
//! and out-of-range values are rejected with the file, the key and the expected range.
//!
//! These are the learner's sections of a training file (`[run]`, `[ppo]`, `[policy]`,
//! `[normalization]`). A task's own settings table (e.g. `[transport]`) belongs to whatever builds
//! the task's environment, which reads the file with [`parse_toml`] into its own struct holding
//! these sections beside its table.

use std::path::Path;

use rlpkg_vec_env::{EnvSpec, SpaceKind};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::AgentError;

/// The learner's whole configuration (`configs/train/cartpole.toml`, `configs/train/pendulum.toml`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainConfig {
    /// Environment and run length.
    pub run: RunConfig,
    /// PPO hyperparameters.
    pub ppo: PpoConfig,
    /// Network shape and action head.
    pub policy: PolicyConfig,
    /// Observation and reward normalisation.
    pub normalization: NormalizationConfig,
    /// The file the configuration was read from (named in messages).
    #[serde(skip)]
    pub source: String,
}

/// Environment, seed, run length and checkpointing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    /// Environment id, e.g. `CartPole-v1`: which environment to build is the caller's choice (the
    /// trainer takes the environment it is handed and reads its spec).
    pub env: String,
    /// Number of environment copies stepped in lockstep.
    pub num_envs: usize,
    /// Seed of environments, initial weights and sampling.
    pub seed: u64,
    /// Environment steps (summed over copies) to train for.
    pub total_steps: u64,
    /// Write a checkpoint every this many updates (and after the last one).
    pub checkpoint_every: usize,
}

/// How the learning rate changes during training.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LrSchedule {
    /// Fixed learning rate.
    Constant,
    /// Linear decay to zero over the run (CleanRL).
    Linear,
    /// RSL-RL's adaptive schedule driven by the measured KL divergence.
    AdaptiveKl,
}

/// PPO hyperparameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PpoConfig {
    /// Steps per environment copy in each rollout.
    pub rollout_steps: usize,
    /// Passes over each rollout.
    pub epochs: usize,
    /// Minibatches per pass (rollout_steps x num_envs must divide evenly).
    pub minibatches: usize,
    /// Discount factor.
    pub gamma: f32,
    /// GAE lambda.
    pub gae_lambda: f32,
    /// Clip range of the probability ratio.
    pub clip_ratio: f32,
    /// Clip the value update around the rollout's values with the same range.
    pub clip_value_loss: bool,
    /// Weight of the value loss.
    pub value_coef: f32,
    /// Weight of the entropy bonus.
    pub entropy_coef: f32,
    /// Global gradient-norm clip.
    pub max_grad_norm: f32,
    /// Initial learning rate.
    pub learning_rate: f64,
    /// Learning-rate schedule.
    pub lr_schedule: LrSchedule,
    /// Target KL of the adaptive schedule.
    pub desired_kl: f32,
    /// Normalise advantages per minibatch.
    pub normalize_advantages: bool,
    /// Adam's epsilon.
    pub adam_epsilon: f32,
}

/// Hidden-layer activation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ActivationName {
    /// tanh
    Tanh,
    /// max(x, 0)
    Relu,
    /// ELU with alpha = 1
    Elu,
}

/// How a Gaussian sample is mapped to the environment's action bounds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TransformName {
    /// Clamp to the bounds (CleanRL).
    Clip,
    /// low + (tanh(a) + 1) / 2 (high - low).
    TanhScale,
}

/// Actor-critic network.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PolicyConfig {
    /// Hidden widths of the actor.
    pub actor_hidden: Vec<usize>,
    /// Hidden widths of the critic.
    pub critic_hidden: Vec<usize>,
    /// Hidden-layer activation.
    pub activation: ActivationName,
    /// Initial log standard deviation of the Gaussian head (ignored for discrete actions).
    pub init_log_std: f32,
    /// Map from Gaussian samples to the action bounds (ignored for discrete actions).
    pub action_transform: TransformName,
}

/// Running normalisation of observations and rewards.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NormalizationConfig {
    /// Normalise observations with running mean and variance.
    pub observations: bool,
    /// Scale rewards by the running standard deviation of the discounted return.
    pub rewards: bool,
    /// Normalised observations are clamped to +- this.
    pub clip_obs: f32,
    /// Scaled rewards are clamped to +- this.
    pub clip_reward: f32,
    /// Added to variances before the square root.
    pub epsilon: f32,
}

/// The text of the configuration file at `path` (runs keep a copy of it).
pub fn read_config_text(path: &Path) -> Result<String, AgentError> {
    let bytes = std::fs::read(path).map_err(|e| AgentError::io(path, e))?;
    String::from_utf8(bytes).map_err(|e| AgentError::ConfigParse {
        path: path.into(),
        message: format!(
            "not UTF-8 text (byte {}); expected a TOML configuration",
            e.utf8_error().valid_up_to()
        ),
    })
}

/// Parses configuration text into `T`; errors name `path`, the key and the line.
pub fn parse_toml<T: DeserializeOwned>(text: &str, path: &Path) -> Result<T, AgentError> {
    toml::from_str(text).map_err(|e| AgentError::ConfigParse {
        path: path.into(),
        message: e.to_string().trim_end().to_string(),
    })
}

impl TrainConfig {
    /// Parses and validates the text of a file holding the learner's sections only; `path` is
    /// only used in messages. Whether the sizes fit in memory depends on the environment: see
    /// [`TrainConfig::check_memory_for`].
    pub fn parse(text: &str, path: &Path) -> Result<Self, AgentError> {
        let mut config: TrainConfig = parse_toml(text, path)?;
        config.source = path.display().to_string();
        config.validate(path)?;
        Ok(config)
    }

    /// Environment transitions in one rollout.
    pub fn batch_size(&self) -> usize {
        self.run.num_envs * self.ppo.rollout_steps
    }

    /// Number of updates the run performs.
    pub fn num_updates(&self) -> usize {
        (self.run.total_steps / self.batch_size() as u64) as usize
    }

    /// Bytes training would allocate, by part, for an environment with `obs_dim` observations
    /// (and `critic_obs_dim` for a critic with its own group), `action_dim` action values and
    /// `actor_out` actor outputs (logits or means).
    pub fn memory_estimate(
        &self,
        obs_dim: usize,
        critic_obs_dim: Option<usize>,
        action_dim: usize,
        actor_out: usize,
    ) -> TrainingMemory {
        const F32: f64 = 4.0;
        let (policy, ppo) = (&self.policy, &self.ppo);
        let transitions = self.run.num_envs as f64 * ppo.rollout_steps as f64;
        // Storage: observations (and the critic's own, if any), actions and six per-step values,
        // plus the batch tensors of the update.
        let stored = obs_dim + critic_obs_dim.unwrap_or(0) + action_dim + 6;
        let rollout = 2.0 * transitions * stored as f64 * F32;
        let parameters = |input: usize, hidden: &[usize], out: usize| {
            let mut widths = vec![input];
            widths.extend_from_slice(hidden);
            widths.push(out);
            widths
                .windows(2)
                .map(|w| (w[0] as f64 + 1.0) * w[1] as f64)
                .sum::<f64>()
        };
        // Weights, the rollout copy, gradients, two Adam moments and autodiff temporaries.
        let actor = 6.0 * parameters(obs_dim, &policy.actor_hidden, actor_out) * F32;
        let critic_input = critic_obs_dim.unwrap_or(obs_dim);
        let critic = 6.0 * parameters(critic_input, &policy.critic_hidden, 1) * F32;
        // Values, pre-activations and gradients of every layer for one minibatch.
        let minibatch = transitions / ppo.minibatches.max(1) as f64;
        let widths: usize = policy.actor_hidden.iter().sum::<usize>()
            + policy.critic_hidden.iter().sum::<usize>()
            + obs_dim
            + critic_obs_dim.unwrap_or(0)
            + actor_out;
        let activations = 4.0 * minibatch * widths as f64 * F32;
        TrainingMemory {
            rollout,
            actor,
            critic,
            activations,
        }
    }

    /// Checks every range; the first violation is reported.
    pub fn validate(&self, path: &Path) -> Result<(), AgentError> {
        let fail = |key: &str, value: String, expected: &str| {
            Err(AgentError::ConfigValue {
                path: path.into(),
                key: key.into(),
                value,
                expected: expected.into(),
            })
        };
        let (run, ppo, policy, norm) = (&self.run, &self.ppo, &self.policy, &self.normalization);
        let counts = [
            ("run.num_envs", run.num_envs, 1, 1 << 20),
            ("run.checkpoint_every", run.checkpoint_every, 1, usize::MAX),
            ("ppo.rollout_steps", ppo.rollout_steps, 1, 1 << 20),
            ("ppo.epochs", ppo.epochs, 1, 1000),
            ("ppo.minibatches", ppo.minibatches, 1, 1 << 20),
        ];
        for (key, value, low, high) in counts {
            if !(low..=high).contains(&value) {
                return fail(
                    key,
                    value.to_string(),
                    &format!("an integer in [{low}, {high}]"),
                );
            }
        }
        if !self.batch_size().is_multiple_of(ppo.minibatches) || ppo.minibatches > self.batch_size()
        {
            return fail(
                "ppo.minibatches",
                ppo.minibatches.to_string(),
                &format!(
                    "a divisor of run.num_envs x ppo.rollout_steps = {}",
                    self.batch_size()
                ),
            );
        }
        if run.total_steps < self.batch_size() as u64 {
            return fail(
                "run.total_steps",
                run.total_steps.to_string(),
                &format!("at least one rollout (>= {})", self.batch_size()),
            );
        }
        let reals = [
            ("ppo.gamma", ppo.gamma as f64, 0.0, 1.0),
            ("ppo.gae_lambda", ppo.gae_lambda as f64, 0.0, 1.0),
            ("ppo.clip_ratio", ppo.clip_ratio as f64, 1e-6, 10.0),
            ("ppo.value_coef", ppo.value_coef as f64, 0.0, 1e3),
            ("ppo.entropy_coef", ppo.entropy_coef as f64, 0.0, 1e3),
            ("ppo.max_grad_norm", ppo.max_grad_norm as f64, 1e-8, 1e6),
            ("ppo.learning_rate", ppo.learning_rate, 1e-8, 1.0),
            ("ppo.desired_kl", ppo.desired_kl as f64, 1e-8, 10.0),
            ("ppo.adam_epsilon", ppo.adam_epsilon as f64, 1e-12, 1.0),
            (
                "policy.init_log_std",
                policy.init_log_std as f64,
                -10.0,
                5.0,
            ),
            ("normalization.clip_obs", norm.clip_obs as f64, 1e-3, 1e6),
            (
                "normalization.clip_reward",
                norm.clip_reward as f64,
                1e-3,
                1e6,
            ),
            ("normalization.epsilon", norm.epsilon as f64, 1e-12, 1.0),
        ];
        for (key, value, low, high) in reals {
            if !(value >= low && value <= high) {
                return fail(
                    key,
                    value.to_string(),
                    &format!("a number in [{low:e}, {high:e}]"),
                );
            }
        }
        for (key, widths) in [
            ("policy.actor_hidden", &policy.actor_hidden),
            ("policy.critic_hidden", &policy.critic_hidden),
        ] {
            if widths.is_empty() || widths.iter().any(|&w| !(1..=65536).contains(&w)) {
                return fail(
                    key,
                    format!("{widths:?}"),
                    "a non-empty list of widths in [1, 65536]",
                );
            }
        }
        Ok(())
    }

    /// Compares [`TrainConfig::memory_estimate`] for the environment `spec` describes with the
    /// memory of the machine and names the part that does not fit.
    pub fn check_memory_for(&self, spec: &EnvSpec, path: &Path) -> Result<(), AgentError> {
        let actor_out = match spec.action.kind {
            SpaceKind::Discrete { n } => n,
            SpaceKind::Continuous => spec.action.dim(),
        };
        let critic_obs_dim = spec.critic_observation.as_ref().map(|c| c.dim());
        let memory = self.memory_estimate(
            spec.observation.dim(),
            critic_obs_dim,
            spec.action.dim(),
            actor_out,
        );
        let budget = memory_budget_bytes() as f64;
        let total = memory.total();
        if total <= budget {
            return Ok(());
        }
        let (run, ppo, policy) = (&self.run, &self.ppo, &self.policy);
        let parts = [
            (
                memory.rollout,
                "run.num_envs x ppo.rollout_steps",
                format!("{} x {}", run.num_envs, ppo.rollout_steps),
                "rollout storage",
            ),
            (
                memory.actor,
                "policy.actor_hidden",
                format!("{:?}", policy.actor_hidden),
                "actor weights, gradients and Adam moments",
            ),
            (
                memory.critic,
                "policy.critic_hidden",
                format!("{:?}", policy.critic_hidden),
                "critic weights, gradients and Adam moments",
            ),
            (
                memory.activations,
                "run.num_envs x ppo.rollout_steps / ppo.minibatches",
                format!(
                    "{} x {} / {}",
                    run.num_envs, ppo.rollout_steps, ppo.minibatches
                ),
                "activations of one minibatch",
            ),
        ];
        let (bytes, key, value, what) = parts
            .into_iter()
            .max_by(|a, b| a.0.total_cmp(&b.0))
            .expect("four parts");
        Err(AgentError::ConfigValue {
            path: path.into(),
            key: key.into(),
            value,
            expected: format!(
                "sizes that fit in memory: training would need about {} ({} for the {what}), \
                 more than the {} of this machine",
                format_bytes(total),
                format_bytes(bytes),
                format_bytes(budget)
            ),
        })
    }
}

/// Bytes training would allocate, by part (see [`TrainConfig::memory_estimate`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrainingMemory {
    /// Rollout storage and the batch tensors built from it.
    pub rollout: f64,
    /// Actor weights, gradients and Adam moments.
    pub actor: f64,
    /// Critic weights, gradients and Adam moments.
    pub critic: f64,
    /// Activations and their gradients for one minibatch.
    pub activations: f64,
}

impl TrainingMemory {
    /// All parts together.
    pub fn total(&self) -> f64 {
        self.rollout + self.actor + self.critic + self.activations
    }
}

/// Bytes a command may plan to allocate: the machine's physical memory, or the container's
/// (cgroup) limit when that is lower, as `sysinfo` reads them; 16 GiB when neither can be read.
pub fn memory_budget_bytes() -> u64 {
    use sysinfo::{MemoryRefreshKind, RefreshKind, System};
    let system = System::new_with_specifics(
        RefreshKind::nothing().with_memory(MemoryRefreshKind::everything()),
    );
    let total = system.total_memory();
    let limit = system
        .cgroup_limits()
        .map_or(total, |c| c.total_memory.min(total));
    if limit == 0 {
        16 << 30
    } else {
        limit
    }
}

/// `bytes` with a binary unit, e.g. `16.0 TiB`.
pub fn format_bytes(bytes: f64) -> String {
    let units = ["B", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"];
    let mut value = bytes;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < units.len() {
        value /= 1024.0;
        unit += 1;
    }
    format!("{value:.1} {}", units[unit])
}

/// An error when `bytes` exceed [`memory_budget_bytes`]: `what` (an option or key, with its value)
/// would need about `bytes`.
pub fn check_memory(what: &str, bytes: f64) -> Result<(), AgentError> {
    let budget = memory_budget_bytes() as f64;
    if bytes <= budget {
        return Ok(());
    }
    Err(AgentError::Memory {
        what: what.into(),
        needed: format_bytes(bytes),
        available: format_bytes(budget),
    })
}

/// FNV-1a hash of the configuration text, as 16 hex digits (stored in checkpoints and exports).
pub fn config_hash(text: &str) -> String {
    let mut hash = crate::runners::Fnv::new();
    hash.update(text.as_bytes());
    hash.hex()
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A small valid CartPole configuration used across the crate's tests.
    pub(crate) const CARTPOLE_TEST: &str = r#"
[run]
env = "CartPole-v1"
num_envs = 4
seed = 1
total_steps = 2048
checkpoint_every = 2

[ppo]
rollout_steps = 64
epochs = 2
minibatches = 4
gamma = 0.99
gae_lambda = 0.95
clip_ratio = 0.2
clip_value_loss = true
value_coef = 0.5
entropy_coef = 0.01
max_grad_norm = 0.5
learning_rate = 2.5e-3
lr_schedule = "linear"
desired_kl = 0.01
normalize_advantages = true
adam_epsilon = 1e-5

[policy]
actor_hidden = [32, 32]
critic_hidden = [32, 32]
activation = "tanh"
init_log_std = 0.0
action_transform = "clip"

[normalization]
observations = true
rewards = true
clip_obs = 10.0
clip_reward = 10.0
epsilon = 1e-8
"#;

    /// `num_envs` copies of the classic-control environment `id`.
    pub(crate) fn classic_env(id: &str, num_envs: usize) -> Box<dyn rlpkg_vec_env::VecEnv> {
        match id {
            rlpkg_vec_env::cartpole::ID => Box::new(rlpkg_vec_env::CartPole::new(num_envs)),
            rlpkg_vec_env::pendulum::ID => Box::new(rlpkg_vec_env::Pendulum::new(num_envs)),
            other => panic!("no classic-control environment {other}"),
        }
    }

    fn parse(text: &str) -> Result<TrainConfig, AgentError> {
        TrainConfig::parse(text, Path::new("cfg.toml"))
    }

    /// [`parse`], then the memory check for CartPole.
    fn parse_for_cartpole(text: &str) -> Result<TrainConfig, AgentError> {
        use rlpkg_vec_env::VecEnv;
        let config = parse(text)?;
        let spec = rlpkg_vec_env::CartPole::new(1).spec().clone();
        config.check_memory_for(&spec, Path::new("cfg.toml"))?;
        Ok(config)
    }

    #[test]
    fn the_test_config_parses() {
        let config = parse(CARTPOLE_TEST).unwrap();
        assert_eq!(config.batch_size(), 256);
        assert_eq!(config.num_updates(), 8);
        assert_eq!(config.ppo.lr_schedule, LrSchedule::Linear);
    }

    #[test]
    fn unknown_and_missing_keys_name_the_key() {
        let unknown = CARTPOLE_TEST.replace("gamma = 0.99", "gamma = 0.99\ngama = 0.9");
        let err = parse(&unknown).unwrap_err().to_string();
        assert!(
            err.starts_with("cfg.toml:") && err.contains("gama"),
            "{err}"
        );
        let missing = CARTPOLE_TEST.replace("gae_lambda = 0.95\n", "");
        let err = parse(&missing).unwrap_err().to_string();
        assert!(err.contains("gae_lambda"), "{err}");
    }

    #[test]
    fn out_of_range_values_name_key_and_range() {
        let cases = [
            ("gamma = 0.99", "gamma = 1.5", "ppo.gamma", "[0e0, 1e0]"),
            (
                "minibatches = 4",
                "minibatches = 3",
                "ppo.minibatches",
                "divisor",
            ),
            ("num_envs = 4", "num_envs = 0", "run.num_envs", "[1,"),
            (
                "actor_hidden = [32, 32]",
                "actor_hidden = []",
                "policy.actor_hidden",
                "non-empty",
            ),
            (
                "learning_rate = 2.5e-3",
                "learning_rate = -1.0",
                "ppo.learning_rate",
                "[1e-8",
            ),
        ];
        for (from, to, key, expected) in cases {
            let err = parse(&CARTPOLE_TEST.replace(from, to)).unwrap_err();
            let message = err.to_string();
            assert!(
                matches!(err, AgentError::ConfigValue { .. }) && message.contains(key),
                "{message}"
            );
            assert!(
                message.contains(expected) && message.starts_with("cfg.toml:"),
                "{message}"
            );
        }
    }

    #[test]
    fn sizes_that_do_not_fit_in_memory_name_the_key_and_the_memory() {
        let cases = [
            (
                "num_envs = 4",
                "num_envs = 1048576",
                "rollout_steps = 64",
                "rollout_steps = 1048576",
                "run.num_envs x ppo.rollout_steps",
            ),
            (
                "actor_hidden = [32, 32]",
                "actor_hidden = [65536, 65536]",
                "",
                "",
                "policy.actor_hidden",
            ),
        ];
        for (from, to, from2, to2, key) in cases {
            let mut text = CARTPOLE_TEST.replace(from, to);
            if !from2.is_empty() {
                text = text
                    .replace(from2, to2)
                    .replace("total_steps = 2048", "total_steps = 1099511627776");
            }
            let err = parse_for_cartpole(&text).unwrap_err().to_string();
            assert!(
                err.contains(key) && err.contains("would need about"),
                "{err}"
            );
            assert!(
                err.contains("iB") && err.contains("of this machine"),
                "{err}"
            );
        }
        let config = parse_for_cartpole(CARTPOLE_TEST).unwrap();
        let memory = config.memory_estimate(4, None, 1, 2);
        // 256 transitions x (4 + 1 + 6) floats, twice.
        assert_eq!(memory.rollout, 2.0 * 256.0 * 11.0 * 4.0);
        assert!(memory.total() < 10e6);
    }

    #[test]
    fn bytes_are_formatted_with_binary_units() {
        assert_eq!(format_bytes(512.0), "512.0 B");
        assert_eq!(format_bytes(1.5 * 1024.0 * 1024.0), "1.5 MiB");
        assert_eq!(format_bytes(16.0 * 1024f64.powi(4)), "16.0 TiB");
        assert!(check_memory("--x 1", 1e30)
            .unwrap_err()
            .to_string()
            .contains("--x 1"));
        assert!(check_memory("--x 1", 1.0).is_ok());
    }

    #[test]
    fn config_hash_changes_with_text() {
        assert_ne!(config_hash("a"), config_hash("b"));
        assert_eq!(config_hash("abc").len(), 16);
    }
}
