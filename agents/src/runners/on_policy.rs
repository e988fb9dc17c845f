//! The on-policy runner: collect a rollout from the vectorised environment, compute advantages,
//! run the PPO update, log, checkpoint; repeat.

use std::collections::VecDeque;
use std::io::Write as _;
use std::path::Path;
use std::time::Instant;

use burn::module::Module;
use burn::tensor::{Device, Tensor, TensorData};
use indicatif::{ProgressBar, ProgressStyle};
use rand_chacha::ChaCha8Rng;
use rlpkg_vec_env::info::{InfoKind, SUCCESS};
use rlpkg_vec_env::{EnvSpec, SpaceKind, StepBuffers, VecEnv};

use super::policy::{initial_actor_critic, model_rng};
use super::tensorboard::{EventWriter, EventsPosition};
use crate::algorithms::{PhaseTimes, Ppo, UpdateStats};
use crate::config::{config_hash, TrainConfig, TransformName};
use crate::export::{ActionTransform, ObsNormaliser};
use crate::modules::distributions::{
    categorical_log_prob_entropy, gaussian_log_prob, one_hot, sample_categorical, sample_gaussian,
};
use crate::modules::{ActorCritic, RewardNormalizer, RunningMeanStd};
use crate::storage::RolloutStorage;
use crate::{AgentError, Backend};

/// Episodes kept for the running mean return shown in the progress bar.
const RECENT_EPISODES: usize = 100;

/// Everything one update produced, for logging.
#[derive(Debug, Clone, PartialEq)]
pub struct UpdateLog {
    /// Updates done so far (1 after the first).
    pub update: usize,
    /// Environment steps so far.
    pub global_step: u64,
    /// Returns of the episodes that ended during this rollout.
    pub episode_returns: Vec<f32>,
    /// Lengths of those episodes.
    pub episode_lengths: Vec<usize>,
    /// Losses and diagnostics of the update.
    pub stats: UpdateStats,
    /// Explained variance of the rollout's values.
    pub explained_variance: f32,
    /// The environment's per-step values ([`VecEnv::info`]) over the rollout, each summarised as
    /// its name says ([`InfoKind`]): episode outcomes as a mean per finished episode (absent when
    /// none finished), the others as a mean per step and copy.
    pub env_info: Vec<(String, f32)>,
}

/// Where the wall time of the last update went (seconds), for the `perf/` scalars.
#[derive(Debug, Clone, Copy, Default)]
pub struct UpdateTiming {
    /// Collecting the rollout (environment steps, policy inference, GAE).
    pub rollout: f64,
    /// The part of the rollout spent inside the environment's `step`.
    pub env_step: f64,
    /// The PPO update (all epochs and minibatches).
    pub update: f64,
    /// The update's phases.
    pub phases: PhaseTimes,
}

/// What a training call did.
#[derive(Debug, Clone, PartialEq)]
pub struct TrainSummary {
    /// Updates done (in total, including before a resume).
    pub updates: usize,
    /// Environment steps done.
    pub global_step: u64,
    /// Mean return of the last (up to 100) finished episodes.
    pub recent_mean_return: f32,
    /// Wall time of this call in seconds.
    pub wall_seconds: f64,
    /// Ended early because the caller's `stop` said so ([`Trainer::train_until`]).
    pub stopped: bool,
}

/// PPO training of one configuration on the environment it is handed: learner, normalisers,
/// random stream, counters.
pub struct Trainer {
    pub(super) config: TrainConfig,
    pub(super) config_text: String,
    pub(super) env: Box<dyn VecEnv>,
    pub(super) spec: EnvSpec,
    pub(super) buffers: StepBuffers,
    /// The learner (model, Adam, learning rate).
    pub ppo: Ppo,
    storage: RolloutStorage,
    pub(super) obs_stats: Option<RunningMeanStd>,
    /// Running statistics of the critic's own observations (asymmetric environments with
    /// observation normalisation only; a symmetric critic shares `obs_stats`).
    pub(super) critic_obs_stats: Option<RunningMeanStd>,
    pub(super) reward_norm: Option<RewardNormalizer>,
    transform: Option<ActionTransform>,
    pub(super) rng: ChaCha8Rng,
    /// Updates done.
    pub update: usize,
    /// Environment steps done.
    pub global_step: u64,
    pub(super) running_returns: Vec<f64>,
    pub(super) running_lengths: Vec<usize>,
    pub(super) recent_returns: VecDeque<f32>,
    /// The event file as it stood at the last checkpoint (saved with it, cut back to on resume).
    pub(super) events: Option<EventsPosition>,
    device: Device,
    /// Where the time of the last update went.
    pub timing: UpdateTiming,
    env_step_seconds: f64,
}

impl Trainer {
    /// A fresh run of `config` on `env` (`config.run.num_envs` copies of the environment, reset
    /// here with `config.run.seed`); `config_text` is the file the configuration came from,
    /// copied into the run folder.
    pub fn new(
        config: TrainConfig,
        config_text: String,
        env: Box<dyn VecEnv>,
    ) -> Result<Self, AgentError> {
        Self::with_backend(config, config_text, env, Backend::DEFAULT)
    }

    /// A fresh run on a chosen burn backend.
    pub fn with_backend(
        config: TrainConfig,
        config_text: String,
        mut env: Box<dyn VecEnv>,
        backend: Backend,
    ) -> Result<Self, AgentError> {
        if env.num_envs() != config.run.num_envs {
            return Err(AgentError::ConfigValue {
                path: config.source.clone().into(),
                key: "run.num_envs".into(),
                value: config.run.num_envs.to_string(),
                expected: format!("the environment's number of copies, {}", env.num_envs()),
            });
        }
        let device = backend.device();
        let spec = env.spec().clone();
        if matches!(spec.action.kind, SpaceKind::Discrete { .. })
            && config.policy.action_transform != TransformName::Clip
        {
            // A discrete action has no bounds to map a Gaussian sample to.
            return Err(AgentError::ConfigValue {
                path: config.source.clone().into(),
                key: "policy.action_transform".into(),
                value: "\"tanh_scale\"".into(),
                expected: format!(
                    "\"clip\" (the default, no effect) for {}'s discrete actions",
                    spec.id
                ),
            });
        }
        let mut buffers = env.buffers();
        env.reset(config.run.seed, &mut buffers)?;
        let mut rng = model_rng(config.run.seed);
        let (model, transform) =
            initial_actor_critic(&config, &spec, &mut rng, &device.clone().autodiff());
        let obs_dim = spec.observation.dim();
        let critic_obs_dim = spec.critic_obs_dim();
        let ppo = Ppo::new(model, &config.ppo, device.clone().autodiff());
        let norm = &config.normalization;
        let num_envs = config.run.num_envs;
        Ok(Self {
            storage: if spec.is_asymmetric() {
                RolloutStorage::asymmetric(
                    config.ppo.rollout_steps,
                    num_envs,
                    obs_dim,
                    critic_obs_dim,
                    spec.action.dim(),
                )
            } else {
                RolloutStorage::new(
                    config.ppo.rollout_steps,
                    num_envs,
                    obs_dim,
                    spec.action.dim(),
                )
            },
            obs_stats: norm.observations.then(|| RunningMeanStd::new(obs_dim)),
            critic_obs_stats: (norm.observations && spec.is_asymmetric())
                .then(|| RunningMeanStd::new(critic_obs_dim)),
            reward_norm: norm.rewards.then(|| {
                RewardNormalizer::new(
                    num_envs,
                    config.ppo.gamma as f64,
                    norm.epsilon,
                    norm.clip_reward,
                )
            }),
            transform,
            rng,
            update: 0,
            global_step: 0,
            running_returns: vec![0.0; num_envs],
            running_lengths: vec![0; num_envs],
            recent_returns: VecDeque::new(),
            events: None,
            env,
            spec,
            buffers,
            ppo,
            config,
            config_text,
            device,
            timing: UpdateTiming::default(),
            env_step_seconds: 0.0,
        })
    }

    /// The configuration being trained.
    pub fn config(&self) -> &TrainConfig {
        &self.config
    }

    /// Updates done so far (those of a resumed checkpoint included).
    pub fn updates_done(&self) -> usize {
        self.update
    }

    /// What the environment's last full reset reports ([`VecEnv::reset_counts`]).
    pub fn reset_counts(&self) -> Vec<(String, usize)> {
        self.env.reset_counts()
    }

    /// The environment's spec.
    pub fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    /// The device without autodiff the rollouts run on.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// Hash of the configuration text.
    pub fn config_hash(&self) -> String {
        config_hash(&self.config_text)
    }

    /// Map from Gaussian samples to the action bounds (`None` for discrete actions).
    pub fn action_transform(&self) -> Option<&ActionTransform> {
        self.transform.as_ref()
    }

    /// The frozen observation normaliser, if observations are normalised.
    pub fn obs_normaliser(&self) -> Option<ObsNormaliser> {
        let norm = &self.config.normalization;
        self.obs_stats
            .as_ref()
            .map(|s| s.to_obs_normaliser(norm.epsilon, norm.clip_obs))
    }

    /// Mean return of the last (up to 100) finished episodes (NaN before the first).
    pub fn recent_mean_return(&self) -> f32 {
        if self.recent_returns.is_empty() {
            return f32::NAN;
        }
        self.recent_returns.iter().sum::<f32>() / self.recent_returns.len() as f32
    }

    fn normalise(&self, raw: &[f32], n: usize) -> Vec<f32> {
        match self.obs_normaliser() {
            Some(norm) => norm.apply(raw, n),
            None => raw.to_vec(),
        }
    }

    /// `n` rows of raw critic observations, normalised with the critic's own statistics
    /// (asymmetric) or the actor's (symmetric).
    fn normalise_critic(&self, raw: &[f32], n: usize) -> Vec<f32> {
        if !self.spec.is_asymmetric() {
            return self.normalise(raw, n);
        }
        let norm = &self.config.normalization;
        match &self.critic_obs_stats {
            Some(stats) => stats
                .to_obs_normaliser(norm.epsilon, norm.clip_obs)
                .apply(raw, n),
            None => raw.to_vec(),
        }
    }

    fn obs_tensor(&self, obs: Vec<f32>, n: usize) -> Tensor<2> {
        let dim = self.spec.observation.dim();
        Tensor::from_data(TensorData::new(obs, [n, dim]), &self.device)
    }

    /// Critic values of `n` rows of normalised critic observations.
    fn critic_values(&self, policy: &ActorCritic, critic_obs: Vec<f32>, n: usize) -> Vec<f32> {
        let dim = self.spec.critic_obs_dim();
        let input = Tensor::from_data(TensorData::new(critic_obs, [n, dim]), &self.device);
        policy.value(input).try_into_vec_as().expect("f32 values")
    }

    /// One rollout and one PPO update.
    pub fn run_update(&mut self) -> Result<UpdateLog, AgentError> {
        let num_updates = self.config.num_updates();
        self.ppo.anneal(self.update, num_updates);
        let start = Instant::now();
        self.env_step_seconds = 0.0;
        let (episode_returns, episode_lengths, info_sums) = self.collect_rollout()?;
        let steps = (self.config.ppo.rollout_steps * self.config.run.num_envs) as f64;
        let episodes = episode_returns.len() as f64;
        let env_info = self
            .env
            .info_names()
            .iter()
            .zip(info_sums)
            .filter_map(|(name, sum)| match InfoKind::of(name) {
                InfoKind::PerEpisode => {
                    (episodes > 0.0).then(|| (name.clone(), (sum / episodes) as f32))
                }
                InfoKind::PerStep => Some((name.clone(), (sum / steps) as f32)),
            })
            .collect();
        let rollout_done = Instant::now();
        let stats = self.ppo.update(&self.storage, &mut self.rng);
        self.timing = UpdateTiming {
            rollout: (rollout_done - start).as_secs_f64(),
            env_step: self.env_step_seconds,
            update: rollout_done.elapsed().as_secs_f64(),
            phases: self.ppo.times,
        };
        self.update += 1;
        Ok(UpdateLog {
            update: self.update,
            global_step: self.global_step,
            episode_returns,
            episode_lengths,
            stats,
            explained_variance: self.storage.explained_variance(),
            env_info,
        })
    }

    /// Steps every copy `rollout_steps` times with the current policy, fills the storage and
    /// computes advantages; returns the episodes that ended and the sums of the environment's
    /// per-step values ([`VecEnv::info`]) over steps and copies.
    #[allow(clippy::type_complexity)]
    fn collect_rollout(&mut self) -> Result<(Vec<f32>, Vec<usize>, Vec<f64>), AgentError> {
        let policy = self.ppo.model.valid();
        let n = self.config.run.num_envs;
        let gamma = self.config.ppo.gamma;
        let log_std = policy.log_std();
        let std: Option<Vec<f32>> = log_std
            .clone()
            .map(|l| l.exp().try_into_vec_as().expect("f32 std"));
        let mut finished = (Vec::new(), Vec::new());
        let info_dim = self.env.info_names().len();
        let mut info_sums = vec![0.0f64; info_dim];
        for step in 0..self.config.ppo.rollout_steps {
            if let Some(stats) = &mut self.obs_stats {
                stats.update(&self.buffers.obs, n);
            }
            if let Some(stats) = &mut self.critic_obs_stats {
                stats.update(&self.buffers.critic_obs, n);
            }
            let obs = self.normalise(&self.buffers.obs, n);
            let obs_t = self.obs_tensor(obs.clone(), n);
            let head = policy.actor(obs_t.clone());
            let head_host: Vec<f32> = head.clone().try_into_vec_as().expect("f32 head");
            let (actions, log_probs) = match (&log_std, &std) {
                (Some(log_std), Some(std)) => {
                    let actions = sample_gaussian(&head_host, std, &mut self.rng);
                    let a = self.spec.action.dim();
                    let actions_t =
                        Tensor::from_data(TensorData::new(actions.clone(), [n, a]), &self.device);
                    (actions, gaussian_log_prob(head, log_std.clone(), actions_t))
                }
                _ => {
                    let classes = head_host.len() / n;
                    let actions = sample_categorical(&head_host, classes, &mut self.rng);
                    let hot = Tensor::from_data(
                        TensorData::new(one_hot(&actions, classes), [n, classes]),
                        &self.device,
                    );
                    (actions, categorical_log_prob_entropy(head, hot).0)
                }
            };
            let log_probs: Vec<f32> = log_probs.try_into_vec_as().expect("f32 log-probs");
            let values: Vec<f32> = if self.spec.is_asymmetric() {
                let critic_obs = self.normalise_critic(&self.buffers.critic_obs, n);
                self.storage.record_critic_obs(step, &critic_obs);
                self.critic_values(&policy, critic_obs, n)
            } else {
                policy.value(obs_t).try_into_vec_as().expect("f32 values")
            };
            self.storage
                .record_action(step, &obs, &actions, &log_probs, &values);

            let env_actions = match &self.transform {
                Some(t) => {
                    let a = self.spec.action.dim();
                    actions
                        .iter()
                        .enumerate()
                        .map(|(k, &v)| t.apply(k % a, v))
                        .collect()
                }
                None => actions,
            };
            let env_start = Instant::now();
            self.env.step(&env_actions, &mut self.buffers)?;
            self.env_step_seconds += env_start.elapsed().as_secs_f64();
            for row in self.env.info().chunks_exact(info_dim.max(1)) {
                for (sum, &x) in info_sums.iter_mut().zip(row) {
                    *sum += x as f64;
                }
            }
            self.global_step += n as u64;

            let done: Vec<bool> = (0..n).map(|i| self.buffers.done(i)).collect();
            for (i, &episode_done) in done.iter().enumerate() {
                self.running_returns[i] += self.buffers.rewards[i] as f64;
                self.running_lengths[i] += 1;
                if episode_done {
                    let ret = self.running_returns[i] as f32;
                    finished.0.push(ret);
                    finished.1.push(self.running_lengths[i]);
                    self.recent_returns.push_back(ret);
                    if self.recent_returns.len() > RECENT_EPISODES {
                        self.recent_returns.pop_front();
                    }
                    self.running_returns[i] = 0.0;
                    self.running_lengths[i] = 0;
                }
            }
            let mut rewards = self.buffers.rewards.clone();
            if let Some(norm) = &mut self.reward_norm {
                norm.normalize(&mut rewards, &done);
            }
            // Truncation: bootstrap from the value of the observation the episode ended on.
            let truncated: Vec<usize> = (0..n)
                .filter(|&i| self.buffers.truncated[i] && !self.buffers.terminated[i])
                .collect();
            if !truncated.is_empty() {
                let dim = self.spec.critic_obs_dim();
                let final_critic = self.buffers.final_critic_input();
                let rows: Vec<f32> = truncated
                    .iter()
                    .flat_map(|&i| final_critic[i * dim..(i + 1) * dim].iter().copied())
                    .collect();
                let final_obs = self.normalise_critic(&rows, truncated.len());
                let final_values = self.critic_values(&policy, final_obs, truncated.len());
                for (&i, v) in truncated.iter().zip(final_values) {
                    rewards[i] += gamma * v;
                }
            }
            self.storage.record_outcome(step, &rewards, &done);
        }
        let next_obs = self.normalise_critic(self.buffers.critic_input(), n);
        let last_values = self.critic_values(&policy, next_obs, n);
        self.storage
            .compute_returns(&last_values, gamma, self.config.ppo.gae_lambda);
        Ok((finished.0, finished.1, info_sums))
    }

    /// Trains until `stop_after` updates (or the configured number), logging to TensorBoard and
    /// checkpointing into `run_dir`.
    pub fn train(
        &mut self,
        run_dir: &Path,
        stop_after: Option<usize>,
        show_progress: bool,
    ) -> Result<TrainSummary, AgentError> {
        self.train_until(run_dir, stop_after, show_progress, &|| false)
    }

    /// As [`Trainer::train`], and asks `stop` after every update: when it says yes, the update just
    /// done is checkpointed (so a resume continues from it) and training ends early
    /// ([`TrainSummary::stopped`]).
    pub fn train_until(
        &mut self,
        run_dir: &Path,
        stop_after: Option<usize>,
        show_progress: bool,
        stop: &dyn Fn() -> bool,
    ) -> Result<TrainSummary, AgentError> {
        let num_updates = self.config.num_updates();
        let last = stop_after.map_or(num_updates, |s| s.min(num_updates));
        let start = Instant::now();
        let start_step = self.global_step;
        let mut writer = if self.update == 0 {
            EventWriter::create(run_dir)?
        } else {
            EventWriter::resume(run_dir, self.events.as_ref(), self.global_step + 1)?
        };
        let total_steps = (num_updates * self.config.batch_size()) as u64;
        let bar = if show_progress {
            ProgressBar::new(total_steps)
        } else {
            ProgressBar::hidden()
        };
        bar.set_style(
            ProgressStyle::with_template(
                "{elapsed_precise} [{bar:30}] {human_pos}/{human_len} steps | {msg} | ETA {eta}",
            )
            .expect("valid template")
            .progress_chars("=> "),
        );
        bar.set_position(self.global_step);
        while self.update < last {
            let log = self.run_update()?;
            let sps =
                (self.global_step - start_step) as f64 / start.elapsed().as_secs_f64().max(1e-9);
            write_scalars(&mut writer, &log, sps);
            write_perf_scalars(&mut writer, &self.timing, log.global_step as usize);
            writer.flush()?;
            bar.set_position(self.global_step);
            let success = log
                .env_info
                .iter()
                .find(|(name, _)| name == SUCCESS)
                .map_or(String::new(), |(_, rate)| {
                    format!(" | success {:.0} %", 100.0 * rate)
                });
            bar.set_message(format!(
                "{sps:.0} SPS | mean return {:.1}{success}",
                self.recent_mean_return()
            ));
            if bar.is_hidden()
                && show_progress
                && (self.update.is_multiple_of(10) || self.update == last)
            {
                // A progress line that cannot be written (stderr closed or full) is dropped:
                // `eprintln!` would panic and lose the run.
                let _ = writeln!(
                    std::io::stderr(),
                    "update {}/{num_updates}  steps {}  SPS {sps:.0}  mean return {:.1}",
                    self.update,
                    self.global_step,
                    self.recent_mean_return()
                );
            }
            let stopped = stop();
            if self.update.is_multiple_of(self.config.run.checkpoint_every)
                || self.update == last
                || stopped
            {
                self.events = Some(writer.position()?);
                self.save_checkpoint(run_dir)?;
            }
            if stopped {
                bar.finish_and_clear();
                return Ok(self.summary(start, true));
            }
        }
        bar.finish_and_clear();
        Ok(self.summary(start, false))
    }

    fn summary(&self, start: Instant, stopped: bool) -> TrainSummary {
        TrainSummary {
            updates: self.update,
            global_step: self.global_step,
            recent_mean_return: self.recent_mean_return(),
            wall_seconds: start.elapsed().as_secs_f64(),
            stopped,
        }
    }
}

fn write_scalars(writer: &mut EventWriter, log: &UpdateLog, sps: f64) {
    let step = log.global_step as usize;
    if !log.episode_returns.is_empty() {
        let count = log.episode_returns.len() as f32;
        writer.add_scalar(
            "charts/episodic_return",
            log.episode_returns.iter().sum::<f32>() / count,
            step,
        );
        let lengths = log.episode_lengths.iter().sum::<usize>() as f32;
        writer.add_scalar("charts/episodic_length", lengths / count, step);
    }
    let s = &log.stats;
    writer.add_scalar("charts/learning_rate", s.learning_rate as f32, step);
    writer.add_scalar("charts/SPS", sps as f32, step);
    writer.add_scalar("losses/policy_loss", s.policy_loss, step);
    writer.add_scalar("losses/value_loss", s.value_loss, step);
    writer.add_scalar("losses/entropy", s.entropy, step);
    writer.add_scalar("losses/approx_kl", s.approx_kl, step);
    writer.add_scalar("losses/clipfrac", s.clip_fraction, step);
    writer.add_scalar("losses/grad_norm", s.grad_norm, step);
    writer.add_scalar("losses/explained_variance", log.explained_variance, step);
    for (name, value) in &log.env_info {
        writer.add_scalar(&format!("env/{name}"), *value, step);
    }
}

/// `perf/`: wall-time shares of one rollout + update (environment steps, the rest of the rollout,
/// the PPO update, and the update's phases) and the update's seconds.
fn write_perf_scalars(writer: &mut EventWriter, timing: &UpdateTiming, step: usize) {
    let total = (timing.rollout + timing.update).max(1e-12);
    let phases = &timing.phases;
    let update_total = phases.total().max(1e-12);
    for (name, value) in [
        ("perf/env_step_share", timing.env_step / total),
        (
            "perf/rollout_other_share",
            (timing.rollout - timing.env_step) / total,
        ),
        ("perf/update_share", timing.update / total),
        ("perf/update_seconds", timing.update),
        ("perf/update_forward_share", phases.forward / update_total),
        ("perf/update_backward_share", phases.backward / update_total),
        (
            "perf/update_optimiser_share",
            phases.optimiser / update_total,
        ),
        ("perf/update_batch_share", phases.batch / update_total),
    ] {
        writer.add_scalar(name, value as f32, step);
    }
}
