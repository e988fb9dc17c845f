//! `rlpkg eval --policy <file.onnx> [--config <training config>]`: an exported policy run through
//! tract in the environment its metadata names (a task that takes settings, Transport-v0, gets
//! them from its training configuration).

use std::path::{Path, PathBuf};

use rlpkg_agents::config::check_memory;
use rlpkg_agents::export::runtime::run_episodes;
use rlpkg_agents::export::{ExportError, OnnxPolicy};
use rlpkg_agents::runners::evaluation_memory_bytes;
use serde::Serialize;

use super::EvalArgs;
use crate::error::{export_error, input_error};
use crate::tasks::{Task, Training};

/// Result of [`eval_onnx_policy`].
#[derive(Debug, Serialize)]
pub struct OnnxEvalSummary {
    /// The ONNX file evaluated.
    pub policy: PathBuf,
    /// Environment id read from the file's metadata.
    pub env_id: String,
    /// Number of deterministic episodes.
    pub episodes: usize,
    /// Seed of the evaluation environments.
    pub seed: u64,
    /// Mean undiscounted return.
    pub mean_return: f64,
    /// Standard deviation of the returns.
    pub std_return: f64,
    /// Mean episode length in steps.
    pub mean_length: f64,
}

/// Runs the exported file at `path` through tract in `episodes` deterministic episodes of the
/// environment named in its metadata (`env_id`; a task that needs no settings table).
pub fn eval_onnx_policy(
    path: &Path,
    episodes: usize,
    seed: u64,
) -> anyhow::Result<OnnxEvalSummary> {
    if episodes == 0 {
        return Err(input_error("--episodes: expected at least 1"));
    }
    let given = |e: ExportError| export_error(e, Some(path));
    let policy = OnnxPolicy::load(path).map_err(given)?;
    let env_id = policy.metadata().get("env_id").cloned().ok_or_else(|| {
        input_error(format!(
            "{}: metadata key `env_id` missing (expected a file written by `rlpkg export`)",
            path.display()
        ))
    })?;
    // The layer widths of an ONNX file are not read here; 1024 per row stands for the hidden layers.
    check_memory(
        &format!("--episodes {episodes}"),
        evaluation_memory_bytes(episodes, policy.obs_dim(), 1024),
    )
    .map_err(input_error)?;
    if env_id == rlpkg_env::transport::ID {
        return Err(input_error(format!(
            "{}: {env_id} takes settings: give its training configuration with --config <file.toml>",
            path.display()
        )));
    }
    let mut env = Task::by_id(&env_id)
        .and_then(|task| task.build(episodes))
        .map_err(|e| given(e.into()))?;
    let stats = run_episodes(env.as_mut(), seed, 0, |obs, n| policy.act(obs, n)).map_err(given)?;
    Ok(OnnxEvalSummary {
        policy: path.to_path_buf(),
        env_id,
        episodes,
        seed,
        mean_return: stats.mean_return(),
        std_return: stats.std_return(),
        mean_length: stats.lengths.iter().sum::<usize>() as f64 / episodes as f64,
    })
}

/// `rlpkg eval --policy <path> --config <config>`: the exported file at `path` evaluated on the
/// task of the training configuration `config` (Transport-v0), printed as `rlpkg eval <run>`
/// prints a run of that task. The file's observations (names and units, in order) must be the
/// task's actor observations.
pub fn eval_onnx_with_config(
    path: &Path,
    config: &Path,
    episodes: usize,
    args: &EvalArgs,
) -> anyhow::Result<()> {
    let policy = OnnxPolicy::load(path).map_err(|e| export_error(e, Some(path)))?;
    let training = Training::load_with(config, &args.set)?;
    let Task::Transport {
        config: transport,
        source,
    } = &training.task
    else {
        return Err(input_error(format!(
            "--config {}: expected a Transport-v0 training configuration (the other tasks need \
             none: drop --config)",
            config.display()
        )));
    };
    let meta = policy.metadata();
    let list = |key: &str| -> Vec<String> {
        meta.get(key)
            .and_then(|text| serde_json::from_str(text).ok())
            .unwrap_or_default()
    };
    let observation = &training.spec.observation;
    if meta.get("env_id") != Some(&training.spec.id)
        || list("obs_names") != observation.names
        || list("obs_units") != observation.units
    {
        return Err(input_error(format!(
            "{}: its environment and observations (metadata `env_id`, `obs_names`, `obs_units`) \
             are not those of --config {} ({}, {} observations)",
            path.display(),
            config.display(),
            training.spec.id,
            observation.dim()
        )));
    }
    check_memory(
        &format!("--episodes {episodes}"),
        evaluation_memory_bytes(episodes, policy.obs_dim(), 1024),
    )
    .map_err(input_error)?;
    super::transport::run_onnx(path, &policy, transport, source, episodes, args)
}

#[cfg(test)]
mod tests {
    use rlpkg_agents::export::random::{cartpole_like, pendulum_like};
    use rlpkg_vec_env::CartPole;

    use super::*;
    use crate::error::exit_code;
    use crate::onnx_file::{export_policy, ExportOptions};

    fn options() -> ExportOptions {
        ExportOptions {
            verify_rows: 200,
            check_data: true,
            latency_runs: Some(20),
        }
    }

    #[test]
    fn eval_runs_the_exported_file_like_the_reference() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("cartpole.onnx");
        let graph = cartpole_like(3);
        export_policy(&graph, &out, &options()).unwrap();
        let summary = eval_onnx_policy(&out, 5, 11).unwrap();
        let reference = run_episodes(&mut CartPole::new(5), 11, usize::MAX, |obs, n| {
            Ok::<_, ExportError>(graph.act(obs, n))
        })
        .unwrap();
        assert_eq!(summary.env_id, "CartPole-v1");
        assert_eq!(summary.mean_return, reference.mean_return());
        assert!(summary.mean_length >= 1.0);
    }

    #[test]
    fn eval_rejects_bad_files_with_exit_code_2() {
        let dir = tempfile::tempdir().unwrap();
        let garbage = dir.path().join("garbage.onnx");
        std::fs::write(&garbage, b"not a model").unwrap();
        let mut unknown_env = pendulum_like(4);
        unknown_env.meta.env_id = "MountainCar-v0".into();
        let unknown = dir.path().join("unknown.onnx");
        export_policy(&unknown_env, &unknown, &options()).unwrap();
        let mut transport = pendulum_like(5);
        transport.meta.env_id = "Transport-v0".into();
        let needs_settings = dir.path().join("transport.onnx");
        export_policy(&transport, &needs_settings, &options()).unwrap();
        for path in [
            dir.path().join("absent.onnx"),
            garbage,
            unknown,
            needs_settings,
        ] {
            let err = eval_onnx_policy(&path, 2, 0).unwrap_err();
            assert_eq!(exit_code(&err), 2, "{err:#}");
            assert!(
                format!("{err:#}").contains(&*path.to_string_lossy()),
                "{err:#}"
            );
        }
    }
}
