//! The tasks `rlpkg` trains on, in one place: each task id with how its environment is built and
//! described, and how a training configuration is split into the learner's sections (`[run]`,
//! `[ppo]`, `[policy]`, `[normalization]`, read by `rlpkg-agents`) and the task's own settings
//! table (`[transport]` for `Transport-v0`; the classic-control tasks take none).

use std::path::Path;

use rlpkg_agents::config::{
    config_hash, parse_toml, read_config_text, NormalizationConfig, PolicyConfig, PpoConfig,
    RunConfig,
};
use rlpkg_agents::runners::run_config_path;
use rlpkg_agents::{AgentError, TrainConfig, Trainer};
use rlpkg_env::{transport, Transport, TransportConfig};
use rlpkg_vec_env::{cartpole, pendulum, CartPole, EnvError, EnvSpec, Pendulum, VecEnv};
use serde::Deserialize;

use crate::error::{agent_error, input_error};
use crate::overrides::{self, Override};

/// Every task id, in the order messages list them.
pub const IDS: [&str; 3] = [cartpole::ID, pendulum::ID, transport::ID];

/// The settings table `Transport-v0` takes.
const TRANSPORT_TABLE: &str = "transport";

/// A task with its settings.
#[derive(Debug, Clone)]
pub enum Task {
    /// Gymnasium's `CartPole-v1`.
    CartPole,
    /// Gymnasium's `Pendulum-v1`.
    Pendulum,
    /// `Transport-v0` with its `[transport]` table.
    Transport {
        /// The table.
        config: Box<TransportConfig>,
        /// The file it came from (named in messages).
        source: String,
    },
}

impl Task {
    /// The task `id` when it takes no settings (an exported policy names only its task's id).
    pub fn by_id(id: &str) -> Result<Self, EnvError> {
        match id {
            cartpole::ID => Ok(Task::CartPole),
            pendulum::ID => Ok(Task::Pendulum),
            transport::ID => Err(EnvError::NeedsSettings {
                id: id.to_string(),
                table: TRANSPORT_TABLE.to_string(),
            }),
            other => Err(EnvError::UnknownId {
                id: other.to_string(),
                known: IDS.iter().map(|id| id.to_string()).collect(),
            }),
        }
    }

    /// The tasks that take no settings.
    pub fn without_settings() -> [Task; 2] {
        [Task::CartPole, Task::Pendulum]
    }

    /// The task `run.env` names, with its settings table (`None` when the file has none) from
    /// the configuration at `path`.
    fn from_config(id: &str, table: Option<&toml::Table>, path: &Path) -> Result<Self, AgentError> {
        let fail = |key: &str, value: String, expected: String| {
            Err(AgentError::ConfigValue {
                path: path.into(),
                key: key.into(),
                value,
                expected,
            })
        };
        match (id, table) {
            (transport::ID, Some(table)) => {
                let source = path.display().to_string();
                let config = TransportConfig::from_table(table, &source)?;
                Ok(Task::Transport {
                    config: Box::new(config),
                    source,
                })
            }
            (transport::ID, None) => fail(
                TRANSPORT_TABLE,
                "missing".into(),
                format!("a [{TRANSPORT_TABLE}] table for run.env = {id:?}"),
            ),
            (cartpole::ID | pendulum::ID, Some(_)) => fail(
                TRANSPORT_TABLE,
                "a table".into(),
                format!("no [{TRANSPORT_TABLE}] table for run.env = {id:?}"),
            ),
            (cartpole::ID, None) => Ok(Task::CartPole),
            (pendulum::ID, None) => Ok(Task::Pendulum),
            (other, _) => fail(
                "run.env",
                format!("{other:?}"),
                format!("one of {}", IDS.join(", ")),
            ),
        }
    }

    /// The spec of the task's environment, without building it (the transport scene is loaded
    /// for its number of cups; nothing is simulated).
    pub fn spec(&self) -> Result<EnvSpec, EnvError> {
        match self {
            Task::CartPole => Ok(CartPole::new(1).spec().clone()),
            Task::Pendulum => Ok(Pendulum::new(1).spec().clone()),
            Task::Transport { config, source } => transport::spec_of(config, source),
        }
    }

    /// `num_envs` copies of the task's environment.
    pub fn build(&self, num_envs: usize) -> Result<Box<dyn VecEnv>, EnvError> {
        if num_envs == 0 {
            return Err(EnvError::NoEnvs(num_envs));
        }
        Ok(match self {
            Task::CartPole => Box::new(CartPole::new(num_envs)),
            Task::Pendulum => Box::new(Pendulum::new(num_envs)),
            Task::Transport { config, source } => {
                Box::new(Transport::new((**config).clone(), num_envs, source)?)
            }
        })
    }
}

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
    /// Reads and checks the training configuration at `path`.
    pub fn load(path: &Path) -> Result<Self, AgentError> {
        let text = read_config_text(path)?;
        Self::parse(text, path)
    }

    /// The configuration at `path` with the `--set` overrides applied, checked like a file. A
    /// configuration that fails only with the overrides names the first `--set` that breaks it.
    pub fn load_with(path: &Path, sets: &[Override]) -> anyhow::Result<Self> {
        if sets.is_empty() {
            return Self::load(path).map_err(agent_error);
        }
        let text = read_config_text(path).map_err(agent_error)?;
        let source = path.display().to_string();
        let with_first = |n: usize| overrides::apply(&text, &source, &sets[..n]);
        let err = match Self::parse(with_first(sets.len()).map_err(input_error)?, path) {
            Ok(training) => return Ok(training),
            Err(err) if err.is_input_error() => err,
            Err(err) => return Err(agent_error(err)),
        };
        // Each prefix applies (the whole list did); the first one that fails is to blame.
        let fails = |n: usize| with_first(n).map_or(true, |t| Self::parse(t, path).is_err());
        let blamed = if fails(0) {
            let all: Vec<String> = sets.iter().map(ToString::to_string).collect();
            format!("with {}", all.join(" "))
        } else {
            let n = (1..=sets.len()).find(|&n| fails(n)).unwrap_or(sets.len());
            sets[n - 1].to_string()
        };
        Err(input_error(format!("{blamed}: {err}")))
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
        let task = Task::from_config(&config.run.env, file.transport.as_ref(), path)?;
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

#[cfg(test)]
mod tests;
