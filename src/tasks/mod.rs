//! How a training configuration is split into the learner's sections (`[run]`, `[ppo]`,
//! `[policy]`, `[normalization]`, read by `rlpkg-agents`) and the task's own settings table
//! (`[transport]` for `Transport-v0`; the classic-control tasks take none), which the task
//! registry ([`rlpkg_env::tasks`], shared with the Python package) turns into a [`Task`].

use std::path::Path;

use rlpkg_agents::config::{
    config_hash, parse_toml, NormalizationConfig, PolicyConfig, PpoConfig, RunConfig,
};
use rlpkg_agents::runners::run_config_path;
use rlpkg_agents::{AgentError, TrainConfig, Trainer};
use rlpkg_vec_env::EnvSpec;
use serde::Deserialize;

use crate::error::{agent_error, input_error};
use crate::overrides::{self, Override};

pub use rlpkg_env::tasks::Task;
use rlpkg_env::tasks::TaskError;
use rlpkg_toml_input::{read_composed, ComposeError, Composed};

/// A training configuration file as written: the learner's sections beside the task's table
/// (the field order is the order messages list the sections in).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TrainingFile {
    run: RunConfig,
    ppo: PpoConfig,
    policy: PolicyConfig,
    normalization: NormalizationConfig,
    #[serde(default)]
    transport: Option<toml::Table>,
}

/// A checked training configuration, split into the learner's settings and the task's.
pub struct Training {
    /// The learner's sections.
    pub config: TrainConfig,
    /// The task `config.run.env` names, with its settings.
    pub task: Task,
    /// The spec of the task's environment.
    pub spec: EnvSpec,
    /// The file's text (a run folder keeps a copy; checkpoints are tied to its hash).
    pub text: String,
}

impl Training {
    /// Reads and checks the training configuration at `path`, with the files it extends merged
    /// in ([`rlpkg_toml_input::read_composed`]).
    pub fn load(path: &Path) -> Result<Self, AgentError> {
        let composed = read_composed(path).map_err(compose_error)?;
        Self::parse_composed(composed, path)
    }

    /// [`Training::parse`] of a composed configuration. The merged text's line numbers are none
    /// of the files', so its errors name the key and the chain of files instead.
    fn parse_composed(composed: Composed, path: &Path) -> Result<Self, AgentError> {
        if !composed.is_merged() {
            return Self::parse(composed.text, path);
        }
        Self::parse(composed.text.clone(), path).map_err(|err| match err {
            AgentError::ConfigParse { .. } => AgentError::ConfigParse {
                path: path.into(),
                message: composed
                    .merged_error::<TrainingFile>()
                    .unwrap_or_else(|| err.to_string()),
            },
            other => other,
        })
    }

    /// The configuration at `path` with the `--set` overrides applied, checked like a file. A
    /// configuration that fails only with the overrides names the first `--set` that breaks it.
    pub fn load_with(path: &Path, sets: &[Override]) -> anyhow::Result<Self> {
        if sets.is_empty() {
            return Self::load(path).map_err(agent_error);
        }
        let text = read_composed(path)
            .map_err(compose_error)
            .map_err(agent_error)?
            .text;
        let source = path.display().to_string();
        let with_first = |n: usize| overrides::apply(&text, &source, &sets[..n]);
        let err = match Self::parse(with_first(sets.len()).map_err(input_error)?, path) {
            Ok(training) => return Ok(training),
            Err(err) if err.is_input_error() => err,
            Err(err) => return Err(agent_error(err)),
        };
        // Each prefix applies (the whole list did); the first one that fails is to blame.
        let fails = |n: usize| with_first(n).map_or(true, |t| Self::parse(t, path).is_err());
        if fails(0) {
            // The file itself: its own error, with its own line numbers.
            let all: Vec<String> = sets.iter().map(ToString::to_string).collect();
            let own = Self::load(path).err().unwrap_or(err);
            return Err(input_error(format!("with {}: {own}", all.join(" "))));
        }
        let n = (1..=sets.len()).find(|&n| fails(n)).unwrap_or(sets.len());
        // A parse error of the merged text would cite its lines, which are not the file's: name the
        // key instead.
        let merged = with_first(n).map_err(input_error)?;
        let err = match toml::from_str::<TrainingFile>(&merged) {
            Err(e) if matches!(err, AgentError::ConfigParse { .. }) => {
                let (_, message) = rlpkg_toml_input::error_at(&merged, &e);
                format!("{}: {message}", path.display())
            }
            _ => err.to_string(),
        };
        Err(input_error(format!("{}: {err}", sets[n - 1])))
    }

    /// The configuration of the run in `run_dir` (its copy of the file the run started from).
    pub fn of_run(run_dir: &Path) -> Result<Self, AgentError> {
        Self::load(&run_config_path(run_dir)?)
    }

    /// Parses and checks configuration text (the first problem is reported); `path` names the
    /// file in messages.
    pub fn parse(text: String, path: &Path) -> Result<Self, AgentError> {
        let file: TrainingFile = parse_toml(&text, path)?;
        let config = TrainConfig {
            run: file.run,
            ppo: file.ppo,
            policy: file.policy,
            normalization: file.normalization,
            source: path.display().to_string(),
        };
        let task = Task::from_settings(&config.run.env, "run.env", file.transport.as_ref(), path)
            .map_err(|e| match e {
            // The key's own error, as the learner's sections report theirs.
            TaskError::Settings {
                key,
                value,
                expected,
                ..
            } => AgentError::ConfigValue {
                path: path.into(),
                key,
                value,
                expected,
            },
            TaskError::Env(e) => AgentError::from(e),
        })?;
        config.validate(path)?;
        let spec = task.spec()?;
        config.check_memory_for(&spec, path)?;
        Ok(Self {
            config,
            task,
            spec,
            text,
        })
    }

    /// Hash of the configuration text (stored in checkpoints and exports).
    pub fn config_hash(&self) -> String {
        config_hash(&self.text)
    }

    /// A fresh trainer on `config.run.num_envs` copies of the task's environment.
    pub fn trainer(self) -> Result<Trainer, AgentError> {
        let env = self.task.build(self.config.run.num_envs)?;
        Trainer::new(self.config, self.text, env)
    }
}

/// A configuration that could not be composed, as the learner reports a file it cannot parse:
/// the file at fault and what is wrong with it.
fn compose_error(e: ComposeError) -> AgentError {
    AgentError::ConfigParse {
        path: e.file().into(),
        message: e.message(),
    }
}

#[cfg(test)]
mod tests;
