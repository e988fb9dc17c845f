//! The task registry: every environment id rlpkg builds, with the settings table each one takes.
//! The CLI (`rlpkg train`, `eval`, `export`, `bench`) and the Python package build their
//! environments here, so the same id and the same configuration give the same environment, with
//! the same rule for the relative paths a configuration names
//! ([`rlpkg_toml_input::find_relative`]).

use std::path::{Path, PathBuf};

use rlpkg_toml_input::{find_relative, read_composed};
use rlpkg_vec_env::{cartpole, pendulum, CartPole, EnvError, EnvSpec, Pendulum, VecEnv};

use crate::transport::{self, Transport, TransportConfig};

/// Every task id, in the order messages list them.
pub const IDS: [&str; 3] = [cartpole::ID, pendulum::ID, transport::ID];

/// The most copies [`Task::build`] makes: a million lanes is far beyond what a machine steps in
/// useful time, and a size from user input is checked before it is allocated.
pub const MAX_ENVS: usize = 1 << 20;

/// The settings table `Transport-v0` takes.
pub const TRANSPORT_TABLE: &str = "transport";

/// The keys of the `[transport]` table that name files or folders (dotted below the table).
const TRANSPORT_PATHS: [&[&str]; 3] = [
    &["scene"],
    &["recordings"],
    &["randomization", "package", "posterior"],
];

/// Why a task could not be made from a configuration's settings.
#[derive(Debug, thiserror::Error)]
pub enum TaskError {
    /// The id and the settings tables do not fit together (or the id is unknown).
    #[error("{file}: key `{key}` = {value}: expected {expected}")]
    Settings {
        /// The configuration file.
        file: String,
        /// The key at fault: the id's key or the settings table.
        key: String,
        /// The value found.
        value: String,
        /// What the key should hold.
        expected: String,
    },
    /// The settings themselves were refused.
    #[error(transparent)]
    Env(#[from] EnvError),
}

impl From<TaskError> for EnvError {
    fn from(e: TaskError) -> Self {
        match e {
            TaskError::Settings {
                file,
                key,
                value,
                expected,
            } => EnvError::Config {
                file,
                key,
                value,
                expected,
            },
            TaskError::Env(e) => e,
        }
    }
}

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
            other => Err(unknown(other)),
        }
    }

    /// The tasks that take no settings.
    pub fn without_settings() -> [Task; 2] {
        [Task::CartPole, Task::Pendulum]
    }

    /// The task `id` with its settings `table` (`None` when the file has none) from the file at
    /// `path`. `key` names the id's key in messages (`run.env` in a training configuration).
    pub fn from_settings(
        id: &str,
        key: &str,
        table: Option<&toml::Table>,
        path: &Path,
    ) -> Result<Self, TaskError> {
        let file = path.display().to_string();
        let fail = |key: &str, value: String, expected: String| {
            Err(TaskError::Settings {
                file: file.clone(),
                key: key.into(),
                value,
                expected,
            })
        };
        match (id, table) {
            (transport::ID, Some(table)) => {
                let table = with_paths_found(table, path);
                let config = TransportConfig::from_table(&table, &file)?;
                Ok(Task::Transport {
                    config: Box::new(config),
                    source: file.clone(),
                })
            }
            (transport::ID, None) => fail(
                TRANSPORT_TABLE,
                "missing".into(),
                format!("a [{TRANSPORT_TABLE}] table for {key} = {id:?}"),
            ),
            (cartpole::ID | pendulum::ID, Some(_)) => fail(
                TRANSPORT_TABLE,
                "a table".into(),
                format!("no [{TRANSPORT_TABLE}] table for {key} = {id:?}"),
            ),
            (cartpole::ID, None) => Ok(Task::CartPole),
            (pendulum::ID, None) => Ok(Task::Pendulum),
            (other, _) => fail(
                key,
                format!("{other:?}"),
                format!("one of {}", IDS.join(", ")),
            ),
        }
    }

    /// The task `id`, its settings read from the file at `config` when it takes some (the
    /// file's `[transport]` table for `Transport-v0`, [`read_transport_config`]).
    pub fn from_file(id: &str, config: Option<&Path>) -> Result<Self, EnvError> {
        match config.filter(|_| id == transport::ID) {
            None => Self::by_id(id),
            Some(path) => Ok(Task::Transport {
                config: Box::new(read_transport_config(path)?),
                source: path.display().to_string(),
            }),
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
        if num_envs > MAX_ENVS {
            return Err(EnvError::TooManyEnvs {
                got: num_envs,
                max: MAX_ENVS,
            });
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

/// The `[transport]` table of the configuration file at `path` (its other tables are ignored),
/// with its relative paths found as the CLI finds them.
pub fn read_transport_config(path: &Path) -> Result<TransportConfig, EnvError> {
    let Some(table) = transport_table(path)? else {
        return Err(EnvError::ConfigParse {
            file: path.display().to_string(),
            message: format!(
                "no [{TRANSPORT_TABLE}] table; expected a {} configuration",
                transport::ID
            ),
        });
    };
    TransportConfig::from_table(&table, &path.display().to_string())
}

/// The `[transport]` table of the configuration file at `path` (the files it extends merged in,
/// [`read_composed`]), its relative paths found as the CLI finds them; `None` when it has none.
fn transport_table(path: &Path) -> Result<Option<toml::Table>, EnvError> {
    let composed = read_composed(path).map_err(|e| EnvError::ConfigParse {
        file: e.file().display().to_string(),
        message: e.message(),
    })?;
    Ok(match composed.table.get(TRANSPORT_TABLE) {
        Some(toml::Value::Table(table)) => Some(with_paths_found(table, path)),
        _ => None,
    })
}

fn unknown(id: &str) -> EnvError {
    EnvError::UnknownId {
        id: id.to_string(),
        known: IDS.iter().map(|id| id.to_string()).collect(),
    }
}

/// The files and folders the configuration file at `path` names (a transport task's scene,
/// recordings and posterior, each found as the task finds it); none for a task without any. The
/// files it extends are not among them: a run keeps the merged configuration, so it never reads
/// them again.
pub fn named_files(path: &Path) -> Result<Vec<PathBuf>, EnvError> {
    let Some(mut table) = transport_table(path)? else {
        return Ok(Vec::new());
    };
    Ok(TRANSPORT_PATHS
        .iter()
        .filter_map(|keys| string_at(&mut table, keys).map(|p| PathBuf::from(p.as_str())))
        .filter(|p| p.exists())
        .collect())
}

/// `table` with each relative path of [`TRANSPORT_PATHS`] found by [`find_relative`] from `path`.
fn with_paths_found(table: &toml::Table, path: &Path) -> toml::Table {
    let mut table = table.clone();
    for keys in TRANSPORT_PATHS {
        if let Some(value) = string_at(&mut table, keys) {
            *value = find_relative(Path::new(value.as_str()), path)
                .display()
                .to_string();
        }
    }
    table
}

/// The string at the dotted `keys` below `table`, if there is one.
fn string_at<'a>(table: &'a mut toml::Table, keys: &[&str]) -> Option<&'a mut String> {
    match keys {
        [] => None,
        [last] => match table.get_mut(*last)? {
            toml::Value::String(value) => Some(value),
            _ => None,
        },
        [first, rest @ ..] => match table.get_mut(*first)? {
            toml::Value::Table(inner) => string_at(inner, rest),
            _ => None,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The repository's root folder.
    fn root() -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .parent()
            .unwrap()
            .into()
    }

    #[test]
    fn tasks_without_settings_are_built_by_id() {
        assert_eq!(
            Task::by_id("CartPole-v1")
                .unwrap()
                .build(3)
                .unwrap()
                .num_envs(),
            3
        );
        let pendulum = Task::by_id("Pendulum-v1").unwrap();
        assert_eq!(pendulum.spec().unwrap().action.dim(), 1);
        assert_eq!(pendulum.build(2).unwrap().spec(), &pendulum.spec().unwrap());
        let err = Task::by_id("Transport-v0").err().unwrap().to_string();
        assert!(err.contains("[transport] table"), "{err}");
        let err = Task::from_file("MountainCar-v0", None)
            .err()
            .unwrap()
            .to_string();
        assert!(
            err.contains("MountainCar-v0") && err.contains("CartPole-v1"),
            "{err}"
        );
        assert!(Task::CartPole.build(0).is_err());
        let err = Task::CartPole.build(1 << 40).err().unwrap().to_string();
        assert!(err.contains("at most 1048576"), "{err}");
        let ids: Vec<String> = Task::without_settings()
            .iter()
            .map(|task| task.spec().unwrap().id)
            .collect();
        assert_eq!(ids, IDS[..2]);
    }

    #[test]
    fn a_shipped_configuration_builds_from_any_working_folder() {
        // The test's working folder is this crate's, not the repository root the configuration's
        // paths are relative to: they are found from the file's folder upwards.
        // The main job's configuration also names a posterior folder, whose summary names its
        // calibration config, both relative to the repository.
        for name in [
            "transport.toml",
            "transport-sensors-posterior.toml",
            "transport-cell.toml",
        ] {
            let path = root().join("configs/train").join(name);
            let task = Task::from_file("Transport-v0", Some(&path)).unwrap();
            let Task::Transport { config, .. } = &task else {
                panic!("a transport task");
            };
            assert!(Path::new(&config.scene).is_absolute(), "{}", config.scene);
            assert!(task.spec().unwrap().action.dim() > 0);
        }
        let main =
            read_transport_config(&root().join("configs/train/transport-sensors-posterior.toml"))
                .unwrap();
        assert_eq!(
            main.randomization
                .package
                .posterior_draws
                .unwrap()
                .rows
                .len(),
            64
        );
        // The cell job trains on the 30 draws its split does not hold out.
        let cell =
            read_transport_config(&root().join("configs/train/transport-cell.toml")).unwrap();
        assert_eq!(
            cell.randomization
                .package
                .posterior_draws
                .unwrap()
                .rows
                .len(),
            30
        );
    }

    #[test]
    fn settings_for_a_task_without_them_are_refused_naming_the_key() {
        let table: toml::Table = "scene = \"x\"".parse().unwrap();
        let err = Task::from_settings("CartPole-v1", "run.env", Some(&table), Path::new("a.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            err.starts_with("a.toml: key `transport`") && err.contains("run.env = \"CartPole-v1\""),
            "{err}"
        );
    }
}
