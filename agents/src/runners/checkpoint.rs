//! Run folders and checkpoints.
//!
//! ```text
//! runs/<name>/config.toml                    the configuration, as given
//! runs/<name>/inputs.toml                    fingerprints of the files it names (`inputs`)
//! runs/<name>/events.out.tfevents.*          TensorBoard scalars
//! runs/<name>/checkpoints/update_000010/     model.bpk, optimizer.bpk, state.json
//! runs/<name>/checkpoints/latest             name of the newest complete checkpoint
//! ```
//! A checkpoint is written into a temporary folder, renamed into place, and only then named in
//! `latest` (itself replaced atomically), so a crash never leaves a half-written checkpoint in use.
//! Floats in `state.json` are stored as their bit patterns so a resume continues bit-identically.

use std::path::{Path, PathBuf};

use burn::module::{Module, ModuleVisitor, Param};
use burn::tensor::Tensor;
use rlpkg_vec_env::{EnvSpec, EnvState};
use serde::{Deserialize, Serialize};

use super::policy::{initial_actor_critic, model_rng};
use super::tensorboard::EventsPosition;
use super::{TrainedPolicy, Trainer};
use crate::config::{config_hash, TrainConfig};
use crate::modules::{ActorCritic, RunningMeanStd};
use crate::{AgentError, Backend};

/// The configuration's copy in a run folder.
pub const CONFIG_FILE: &str = "config.toml";
const CHECKPOINTS: &str = "checkpoints";
const LATEST: &str = "latest";
const MODEL: &str = "model.bpk";
const OPTIMIZER: &str = "optimizer.bpk";
const STATE: &str = "state.json";
/// Complete checkpoints kept in a run folder.
const KEEP: usize = 2;
/// Name prefix of the folder a checkpoint is written into before it is renamed into place.
const PARTIAL_PREFIX: &str = ".partial-";
/// The policy a finished run exports beside its checkpoints.
pub const POLICY_FILE: &str = "policy.onnx";

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct StatsBits {
    mean: Vec<u64>,
    var: Vec<u64>,
    count: u64,
}

impl StatsBits {
    fn from(stats: &RunningMeanStd) -> Self {
        Self {
            mean: bits(&stats.mean),
            var: bits(&stats.var),
            count: stats.count.to_bits(),
        }
    }

    fn restore(&self, stats: &mut RunningMeanStd) {
        stats.mean = floats(&self.mean);
        stats.var = floats(&self.var);
        stats.count = f64::from_bits(self.count);
    }
}

/// Counters, random streams, normalisers and environment state of a run (everything but the
/// model and Adam).
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct TrainerState {
    config_hash: String,
    update: usize,
    global_step: u64,
    learning_rate: u64,
    rng: [u64; rlpkg_vec_env::RNG_WORDS],
    obs_stats: Option<StatsBits>,
    reward_stats: Option<StatsBits>,
    reward_returns: Option<Vec<u64>>,
    env_reals: Vec<u64>,
    env_counters: Vec<u64>,
    obs: Vec<u32>,
    final_obs: Vec<u32>,
    rewards: Vec<u32>,
    terminated: Vec<bool>,
    truncated: Vec<bool>,
    running_returns: Vec<u64>,
    running_lengths: Vec<usize>,
    recent_returns: Vec<u32>,
    /// The event file at this checkpoint (absent in checkpoints of older versions).
    #[serde(default)]
    events: Option<EventsPosition>,
    /// Statistics of the critic's own observations (asymmetric environments only).
    #[serde(default)]
    critic_obs_stats: Option<StatsBits>,
    /// The critic's observations and final observations (empty for symmetric environments).
    #[serde(default)]
    critic_obs: Vec<u32>,
    #[serde(default)]
    final_critic_obs: Vec<u32>,
    /// The environment's serialised state beyond reals and counters (simulator snapshots).
    #[serde(default)]
    env_bytes: Vec<u8>,
    /// The configuration's text the run was trained with, so that a changed `config.toml` can be
    /// named by its first differing line (absent in checkpoints of older versions).
    #[serde(default)]
    config_text: Option<String>,
}

fn bits(values: &[f64]) -> Vec<u64> {
    values.iter().map(|v| v.to_bits()).collect()
}

fn floats(values: &[u64]) -> Vec<f64> {
    values.iter().map(|&v| f64::from_bits(v)).collect()
}

fn bits32(values: &[f32]) -> Vec<u32> {
    values.iter().map(|v| v.to_bits()).collect()
}

fn floats32(values: &[u32]) -> Vec<f32> {
    values.iter().map(|&v| f32::from_bits(v)).collect()
}

fn checkpoint_error(path: &Path, reason: impl Into<String>) -> AgentError {
    AgentError::Checkpoint {
        path: path.into(),
        reason: reason.into(),
    }
}

/// The configuration's copy in `run_dir`, which must exist (it makes the folder a run folder).
pub fn run_config_path(run_dir: &Path) -> Result<PathBuf, AgentError> {
    let config_path = run_dir.join(CONFIG_FILE);
    if !config_path.exists() {
        return Err(checkpoint_error(
            run_dir,
            format!("not a run folder (expected {})", config_path.display()),
        ));
    }
    Ok(config_path)
}

/// The newest complete checkpoint folder of `run_dir`: the `update_NNNNNN` folder named in
/// `checkpoints/latest`, which must be a plain name inside `checkpoints/` (never a path to another
/// run) and hold a checkpoint.
pub fn latest_checkpoint(run_dir: &Path) -> Result<PathBuf, AgentError> {
    let dir = run_dir.join(CHECKPOINTS);
    let latest = dir.join(LATEST);
    let name = match std::fs::read(&latest) {
        Ok(bytes) => String::from_utf8_lossy(&bytes).trim().to_string(),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(checkpoint_error(
                run_dir,
                format!(
                    "no checkpoint (expected {}; is this a folder written by `rlpkg train`?)",
                    latest.display()
                ),
            ))
        }
        Err(e) => return Err(AgentError::io(&latest, e)),
    };
    if update_number(&name).is_none() {
        return Err(checkpoint_error(
            &latest,
            format!(
                "holds `{name}`; expected the name of a checkpoint folder inside {}, e.g. update_000010",
                dir.display()
            ),
        ));
    }
    let checkpoint = dir.join(&name);
    if !checkpoint.join(STATE).is_file() {
        return Err(checkpoint_error(
            &latest,
            format!(
                "names {}, which holds no checkpoint (expected {STATE}, {MODEL} and {OPTIMIZER})",
                checkpoint.display()
            ),
        ));
    }
    Ok(checkpoint)
}

/// The update of a checkpoint folder name `update_NNNNNN` (at least six digits, nothing else).
fn update_number(name: &str) -> Option<usize> {
    let digits = name.strip_prefix("update_")?;
    if digits.len() < 6 || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    digits.parse().ok()
}

/// What `path` is among the files a run keeps in `run_dir` (both paths canonical): its
/// configuration, an event file, a file of its checkpoints (anything under `checkpoints/`, written
/// or not) or the lock of the command training it; `None` for any other path, the exported
/// policy among them. An output that is one of these would destroy the run.
pub fn run_file_kind(run_dir: &Path, path: &Path) -> Option<&'static str> {
    let inside = path.strip_prefix(run_dir).ok()?;
    let mut parts = inside.components();
    let first = parts.next()?.as_os_str().to_str()?;
    let alone = parts.next().is_none();
    if first == CHECKPOINTS {
        Some("a file of the run's checkpoints")
    } else if alone && first == CONFIG_FILE {
        Some("the run's configuration")
    } else if alone && first.starts_with(super::tensorboard::EVENTS_PREFIX) {
        Some("an event file of the run")
    } else if alone && first == rlpkg_files::lock::LOCK_FILE {
        Some("the run's lock file")
    } else if alone && first == super::inputs::INPUTS_FILE {
        Some("the run's input fingerprints")
    } else {
        None
    }
}

/// Removes what a run stopped at once (a second Ctrl-C, a kill) left in `run_dir`: the temporary
/// copies of `config.toml`, `policy.onnx` and `checkpoints/latest`, and unfinished checkpoint
/// folders. Nothing in use is touched: these are only ever renamed into place or dropped. Returns
/// what it removed.
pub fn clean_leftovers(run_dir: &Path) -> Result<Vec<PathBuf>, AgentError> {
    let mut removed = Vec::new();
    let checkpoints = run_dir.join(CHECKPOINTS);
    for (dir, files) in [
        (
            run_dir,
            &[CONFIG_FILE, POLICY_FILE, super::inputs::INPUTS_FILE][..],
        ),
        (checkpoints.as_path(), &[LATEST][..]),
    ] {
        let entries = match std::fs::read_dir(dir) {
            Ok(entries) => entries,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
            Err(e) => return Err(AgentError::io(dir, e)),
        };
        for entry in entries {
            let entry = entry.map_err(|e| AgentError::io(dir, e))?;
            let name = entry.file_name().to_string_lossy().into_owned();
            let path = entry.path();
            let partial = dir == checkpoints && name.starts_with(PARTIAL_PREFIX);
            if partial && path.is_dir() {
                std::fs::remove_dir_all(&path).map_err(|e| AgentError::io(&path, e))?;
            } else if files
                .iter()
                .any(|file| rlpkg_files::is_temporary_of(&name, file))
            {
                std::fs::remove_file(&path).map_err(|e| AgentError::io(&path, e))?;
            } else {
                continue;
            }
            removed.push(path);
        }
    }
    Ok(removed)
}

/// Writes `bytes` to `path` through a temporary file in the same folder.
fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), AgentError> {
    rlpkg_files::write_atomic(path, bytes).map_err(|e| AgentError::io(path, e))
}

impl Trainer {
    /// Creates `run_dir` (which must not hold a run yet) and copies the configuration into it.
    pub fn create_run_dir(&self, run_dir: &Path) -> Result<(), AgentError> {
        if run_dir.join(CONFIG_FILE).exists() {
            return Err(checkpoint_error(
                run_dir,
                "already holds a run (use --resume to continue it, or choose another --name)",
            ));
        }
        std::fs::create_dir_all(run_dir.join(CHECKPOINTS))
            .map_err(|e| AgentError::io(run_dir, e))?;
        write_atomically(&run_dir.join(CONFIG_FILE), self.config_text.as_bytes())
    }

    /// Writes a checkpoint of the current state into `run_dir` and points `latest` at it.
    pub fn save_checkpoint(&self, run_dir: &Path) -> Result<(), AgentError> {
        let dir = run_dir.join(CHECKPOINTS);
        std::fs::create_dir_all(&dir).map_err(|e| AgentError::io(&dir, e))?;
        let tmp = tempfile::Builder::new()
            .prefix(PARTIAL_PREFIX)
            .tempdir_in(&dir)
            .map_err(|e| AgentError::io(&dir, e))?;
        let model_path = tmp.path().join(MODEL);
        self.ppo
            .model
            .clone()
            .save_file(&model_path)
            .map_err(|e| checkpoint_error(&model_path, e.to_string()))?;
        let optim_path = tmp.path().join(OPTIMIZER);
        self.ppo
            .optimizer
            .save(&optim_path)
            .map_err(|e| checkpoint_error(&optim_path, e.to_string()))?;
        let state = self.trainer_state();
        let json = serde_json::to_vec(&state).expect("plain data serialises");
        std::fs::write(tmp.path().join(STATE), json).map_err(|e| AgentError::io(tmp.path(), e))?;

        let name = format!("update_{:06}", self.update);
        let target = dir.join(&name);
        if target.exists() {
            std::fs::remove_dir_all(&target).map_err(|e| AgentError::io(&target, e))?;
        }
        let tmp_path = tmp.keep();
        std::fs::rename(&tmp_path, &target).map_err(|e| AgentError::io(&target, e))?;
        write_atomically(&dir.join(LATEST), name.as_bytes())?;
        prune_old_checkpoints(&dir, KEEP)
    }

    fn trainer_state(&self) -> TrainerState {
        let env = self.env.save_state();
        TrainerState {
            config_hash: config_hash(&self.config_text),
            update: self.update,
            global_step: self.global_step,
            learning_rate: self.ppo.learning_rate.to_bits(),
            rng: rlpkg_vec_env::rng_to_words(&self.rng),
            obs_stats: self.obs_stats.as_ref().map(StatsBits::from),
            reward_stats: self
                .reward_norm
                .as_ref()
                .map(|r| StatsBits::from(&r.return_stats)),
            reward_returns: self.reward_norm.as_ref().map(|r| bits(&r.returns)),
            env_reals: bits(&env.reals),
            env_counters: env.counters,
            obs: bits32(&self.buffers.obs),
            final_obs: bits32(&self.buffers.final_obs),
            rewards: bits32(&self.buffers.rewards),
            terminated: self.buffers.terminated.clone(),
            truncated: self.buffers.truncated.clone(),
            running_returns: bits(&self.running_returns),
            running_lengths: self.running_lengths.clone(),
            recent_returns: self.recent_returns.iter().map(|r| r.to_bits()).collect(),
            events: self.events.clone(),
            critic_obs_stats: self.critic_obs_stats.as_ref().map(StatsBits::from),
            critic_obs: bits32(&self.buffers.critic_obs),
            final_critic_obs: bits32(&self.buffers.final_critic_obs),
            env_bytes: env.bytes,
            config_text: Some(self.config_text.clone()),
        }
    }

    /// Loads the latest checkpoint of `run_dir` into this trainer, freshly built from the same
    /// configuration on an environment built the same way (continues the run).
    pub fn load_checkpoint(&mut self, run_dir: &Path) -> Result<(), AgentError> {
        let trainer = self;
        let (checkpoint, state_path, state) = read_state(run_dir, &trainer.config_hash())?;
        trainer.ppo.model = load_model(trainer.ppo.model.clone(), &checkpoint)?;
        let optim_path = checkpoint.join(OPTIMIZER);
        trainer.ppo.optimizer = trainer
            .ppo
            .optimizer
            .clone()
            .load(&optim_path)
            .map_err(|e| checkpoint_error(&optim_path, e.to_string()))?;
        check_counters(&trainer.config, &state, &checkpoint, &state_path)?;
        trainer.restore_state(state, &state_path)
    }

    fn restore_state(&mut self, state: TrainerState, path: &Path) -> Result<(), AgentError> {
        let n = self.config.run.num_envs;
        let dim = self.spec.observation.dim();
        let critic_len = self.buffers.critic_obs.len();
        if state.obs.len() != n * dim
            || state.final_obs.len() != n * dim
            || state.critic_obs.len() != critic_len
            || state.final_critic_obs.len() != critic_len
            || [
                state.rewards.len(),
                state.terminated.len(),
                state.truncated.len(),
            ] != [n; 3]
            || state.running_returns.len() != n
        {
            return Err(checkpoint_error(
                path,
                "buffer sizes do not match the configuration",
            ));
        }
        self.update = state.update;
        self.global_step = state.global_step;
        self.ppo.learning_rate = f64::from_bits(state.learning_rate);
        self.rng = rlpkg_vec_env::rng_from_words(&state.rng);
        match (&mut self.obs_stats, &state.obs_stats) {
            (Some(stats), Some(saved)) if saved.mean.len() == dim => saved.restore(stats),
            (None, None) => {}
            _ => {
                return Err(checkpoint_error(
                    path,
                    "observation statistics do not match",
                ))
            }
        }
        match (&mut self.critic_obs_stats, &state.critic_obs_stats) {
            (Some(stats), Some(saved)) if saved.mean.len() == self.spec.critic_obs_dim() => {
                saved.restore(stats)
            }
            (None, None) => {}
            _ => {
                return Err(checkpoint_error(
                    path,
                    "critic observation statistics do not match",
                ))
            }
        }
        match (
            &mut self.reward_norm,
            &state.reward_stats,
            &state.reward_returns,
        ) {
            (Some(norm), Some(saved), Some(returns)) if returns.len() == n => {
                saved.restore(&mut norm.return_stats);
                norm.returns = floats(returns);
            }
            (None, None, None) => {}
            _ => return Err(checkpoint_error(path, "reward statistics do not match")),
        }
        self.env.load_state(&EnvState {
            reals: floats(&state.env_reals),
            counters: state.env_counters,
            bytes: state.env_bytes,
        })?;
        self.buffers.obs = floats32(&state.obs);
        self.buffers.final_obs = floats32(&state.final_obs);
        self.buffers.critic_obs = floats32(&state.critic_obs);
        self.buffers.final_critic_obs = floats32(&state.final_critic_obs);
        self.buffers.rewards = floats32(&state.rewards);
        self.buffers.terminated = state.terminated;
        self.buffers.truncated = state.truncated;
        self.running_returns = floats(&state.running_returns);
        self.running_lengths = state.running_lengths;
        self.recent_returns = floats32(&state.recent_returns).into();
        self.events = state.events;
        Ok(())
    }
}

/// The state of the latest checkpoint of `run_dir`, which must have been written for the
/// configuration hashed `config_hash`; with the checkpoint folder and the state file.
fn read_state(
    run_dir: &Path,
    config_hash: &str,
) -> Result<(PathBuf, PathBuf, TrainerState), AgentError> {
    let checkpoint = latest_checkpoint(run_dir)?;
    let state_path = checkpoint.join(STATE);
    let json = std::fs::read(&state_path).map_err(|e| AgentError::io(&state_path, e))?;
    let state: TrainerState = serde_json::from_slice(&json)
        .map_err(|e| checkpoint_error(&state_path, format!("malformed checkpoint state: {e}")))?;
    if state.config_hash != config_hash {
        let config_path = run_dir.join(CONFIG_FILE);
        let now = std::fs::read_to_string(&config_path).unwrap_or_default();
        let mut reason =
            String::from("differs from the configuration the checkpoint was trained with");
        if let Some(trained) = &state.config_text {
            reason.push_str(&first_differing_line(trained, &now));
        }
        return Err(checkpoint_error(&config_path, reason));
    }
    if let Some(reason) = non_finite_state(&state) {
        return Err(checkpoint_error(&state_path, reason));
    }
    Ok((checkpoint, state_path, state))
}

/// Where `now` first departs from `trained`, as `: line N is `...`, trained with `...``.
pub(super) fn first_differing_line(trained: &str, now: &str) -> String {
    let mut trained_lines = trained.lines();
    let mut now_lines = now.lines();
    for line in 1.. {
        match (trained_lines.next(), now_lines.next()) {
            (Some(a), Some(b)) if a == b => continue,
            (None, None) => break,
            (a, b) => {
                let shown =
                    |l: Option<&str>| l.map_or("the end of the file".into(), |l| format!("`{l}`"));
                return format!(": line {line} is {}, trained with {}", shown(b), shown(a));
            }
        }
    }
    // Same lines, different bytes (line endings or a final newline).
    String::from(": the lines are the same but the line endings differ")
}

/// What in `state` no run could have written: a learning rate that is not a finite number >= 0,
/// normaliser statistics that are not finite (a variance < 0, a count <= 0), returns, rewards or
/// observations that are not finite. Such a state would train or act on NaN without a word.
fn non_finite_state(state: &TrainerState) -> Option<String> {
    let learning_rate = f64::from_bits(state.learning_rate);
    if !(learning_rate.is_finite() && learning_rate >= 0.0) {
        return Some(format!(
            "`learning_rate` = {learning_rate}: expected a finite rate >= 0"
        ));
    }
    let stats = [
        ("obs_stats", &state.obs_stats),
        ("reward_stats", &state.reward_stats),
        ("critic_obs_stats", &state.critic_obs_stats),
    ];
    for (key, saved) in stats {
        let Some(saved) = saved else { continue };
        let count = f64::from_bits(saved.count);
        if let Some(i) = floats(&saved.mean).iter().position(|v| !v.is_finite()) {
            return Some(format!(
                "`{key}.mean[{i}]` is not finite: expected a finite mean"
            ));
        }
        if let Some(i) = floats(&saved.var)
            .iter()
            .position(|v| !(v.is_finite() && *v >= 0.0))
        {
            return Some(format!(
                "`{key}.var[{i}]` = {}: expected a finite variance >= 0",
                f64::from_bits(saved.var[i])
            ));
        }
        if !(count.is_finite() && count > 0.0) {
            return Some(format!(
                "`{key}.count` = {count}: expected a finite count > 0"
            ));
        }
    }
    let doubles = [
        (
            "reward_returns",
            state.reward_returns.as_deref().unwrap_or(&[]),
        ),
        ("running_returns", &state.running_returns[..]),
    ];
    for (key, values) in doubles {
        if let Some(i) = floats(values).iter().position(|v| !v.is_finite()) {
            return Some(format!("`{key}[{i}]` is not finite"));
        }
    }
    let singles = [
        ("obs", &state.obs),
        ("final_obs", &state.final_obs),
        ("rewards", &state.rewards),
        ("recent_returns", &state.recent_returns),
        ("critic_obs", &state.critic_obs),
        ("final_critic_obs", &state.final_critic_obs),
    ];
    for (key, values) in singles {
        if let Some(i) = floats32(values).iter().position(|v| !v.is_finite()) {
            return Some(format!("`{key}[{i}]` is not finite"));
        }
    }
    None
}

/// Finds the first weight of a module that is not finite.
struct NonFiniteWeight {
    found: Option<String>,
}

impl ModuleVisitor for NonFiniteWeight {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if self.found.is_some() {
            return;
        }
        let values = param
            .val()
            .into_data()
            .try_to_vec::<f32>()
            .unwrap_or_default();
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            self.found = Some(format!(
                "weight {i} of a {:?} parameter is {}: expected finite weights",
                param.val().dims(),
                values[i]
            ));
        }
    }
}

/// `model` with the weights saved in `checkpoint`.
fn load_model(model: ActorCritic, checkpoint: &Path) -> Result<ActorCritic, AgentError> {
    let model_path = checkpoint.join(MODEL);
    let model = model
        .try_load_file(&model_path)
        .map_err(|e| checkpoint_error(&model_path, e.to_string()))?;
    let mut check = NonFiniteWeight { found: None };
    model.visit(&mut check);
    match check.found {
        Some(reason) => Err(checkpoint_error(&model_path, reason)),
        None => Ok(model),
    }
}

/// The counters of `state` must agree with `config` and the folder they are in: every update adds
/// `num_envs x rollout_steps` steps, a run never goes past its last update, and the folder is
/// named after its update.
fn check_counters(
    config: &TrainConfig,
    state: &TrainerState,
    checkpoint: &Path,
    path: &Path,
) -> Result<(), AgentError> {
    let folder = checkpoint
        .file_name()
        .and_then(|n| n.to_str())
        .and_then(update_number);
    let num_updates = config.num_updates();
    let expected_steps = state.update as u64 * config.batch_size() as u64;
    let problem = if state.update == 0 || state.update > num_updates {
        Some(format!(
            "`update` = {}: expected an update in [1, {num_updates}] (the configuration's run length)",
            state.update
        ))
    } else if folder != Some(state.update) {
        Some(format!(
            "`update` = {} does not match the checkpoint folder {}",
            state.update,
            checkpoint.display()
        ))
    } else if state.global_step != expected_steps {
        Some(format!(
            "`global_step` = {}: expected update x run.num_envs x ppo.rollout_steps = {expected_steps}",
            state.global_step
        ))
    } else {
        None
    };
    match problem {
        Some(reason) => Err(checkpoint_error(path, reason)),
        None => Ok(()),
    }
}

impl TrainedPolicy {
    /// The policy of the latest checkpoint of `run_dir`, trained with `config` (whose text hashes
    /// to `config_hash`) on an environment described by `spec`; no environment is built.
    pub fn load(
        run_dir: &Path,
        config: &TrainConfig,
        config_hash: &str,
        spec: &EnvSpec,
    ) -> Result<Self, AgentError> {
        let (checkpoint, state_path, state) = read_state(run_dir, config_hash)?;
        let device = Backend::DEFAULT.device();
        let (model, transform) = initial_actor_critic(
            config,
            spec,
            &mut model_rng(config.run.seed),
            &device.clone().autodiff(),
        );
        let model = load_model(model, &checkpoint)?;
        check_counters(config, &state, &checkpoint, &state_path)?;
        let norm = &config.normalization;
        let dim = spec.observation.dim();
        let normaliser = match (norm.observations, &state.obs_stats) {
            (true, Some(saved)) if saved.mean.len() == dim => {
                let mut stats = RunningMeanStd::new(dim);
                saved.restore(&mut stats);
                Some(stats.to_obs_normaliser(norm.epsilon, norm.clip_obs))
            }
            (false, None) => None,
            _ => {
                return Err(checkpoint_error(
                    &state_path,
                    "observation statistics do not match",
                ))
            }
        };
        Ok(Self {
            model: model.valid(),
            normaliser,
            transform,
            spec: spec.clone(),
            config_hash: config_hash.to_string(),
            update: state.update,
            global_step: state.global_step,
            device,
        })
    }
}

/// Removes all but the `keep` newest `update_*` folders (names sort by update).
fn prune_old_checkpoints(dir: &Path, keep: usize) -> Result<(), AgentError> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .map_err(|e| AgentError::io(dir, e))?
        .filter_map(|entry| entry.ok()?.file_name().into_string().ok())
        .filter(|name| name.starts_with("update_"))
        .collect();
    names.sort();
    for name in names.iter().rev().skip(keep) {
        let path = dir.join(name);
        std::fs::remove_dir_all(&path).map_err(|e| AgentError::io(&path, e))?;
    }
    Ok(())
}
