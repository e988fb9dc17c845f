//! `rlpkg eval`: one entry point, two jobs. With a run folder or `--policy`, it evaluates a policy in
//! its environment; with `--params`, it evaluates simulator parameters against recorded trajectories.
//!
//! - this module: the arguments, and a run folder of a classic-control task;
//! - [`transport`]: a run folder of the transport task, beside the scripted and recorded baselines;
//! - [`onnx`]: an exported policy (`--policy`);
//! - [`params`]: simulator parameters (`--params`).
//!
//! A run's policy is read from its latest checkpoint with the spec of its task; the environments
//! of the evaluation episodes are the only ones built.

mod onnx;
mod params;
mod predictive;
mod transport;

use std::path::PathBuf;

use clap::Args;
use rlpkg_agents::TrainedPolicy;
use rlpkg_env::transport::VacuumGovernor;
use serde::Serialize;

use crate::error::{agent_error, input_error};
use crate::overrides::Override;
use crate::tasks::{Task, Training};

/// Options of `--params` (simulator parameters against recordings) and of a policy (run folder or
/// `--policy`) exclude each other; clap rejects combinations that would silently ignore one.
#[derive(Args)]
pub struct EvalArgs {
    /// Run folder of a trained policy (runs/<name>).
    #[arg(conflicts_with_all = ["policy", "params"])]
    pub run: Option<PathBuf>,
    /// Evaluate this exported ONNX policy (through tract) instead of the run's burn checkpoint.
    #[arg(long, conflicts_with = "params")]
    pub policy: Option<PathBuf>,
    /// With --policy: the training configuration of a task that takes settings (Transport-v0):
    /// the file is evaluated on its task and printed as `rlpkg eval <run>` prints a run.
    #[arg(long, requires = "policy")]
    pub config: Option<PathBuf>,
    /// With --config: override one of its values, e.g. --set
    /// transport.scene=configs/scenes/calibrated-coarse-real-film.toml (repeatable; as `rlpkg train
    /// --set`), to evaluate the policy on a scene or randomisation it was not trained on.
    #[arg(long = "set", value_name = "KEY=VALUE", requires = "config")]
    pub set: Vec<Override>,
    /// Number of deterministic evaluation episodes (one environment copy each).
    #[arg(long, default_value_t = 100, conflicts_with = "params",
          value_parser = clap::value_parser!(u64).range(1..))]
    pub episodes: u64,
    /// Seed for the evaluation environments.
    #[arg(long, default_value_t = 0, conflicts_with = "params")]
    pub seed: u64,
    /// Simulator parameters (TOML) to evaluate against recorded trajectories.
    #[arg(long)]
    pub params: Option<PathBuf>,
    /// Which trajectories of the dataset to evaluate on (with --params) [default: test].
    #[arg(long, requires = "params", conflicts_with_all = ["run", "policy"])]
    pub split: Option<String>,
    /// Dataset folder (manifest.toml + one folder per trajectory; with --params)
    /// [default: data/deformable-sim-real].
    #[arg(long, requires = "params", conflicts_with_all = ["run", "policy"])]
    pub data: Option<PathBuf>,
    /// Also run the grid-size sweep (the paper's Table 2; with --params).
    #[arg(long, requires = "params", conflicts_with_all = ["run", "policy"])]
    pub sweep_grid: bool,
    /// Sensitivity: scale every parameter by these percentages, e.g. 10,20,30 (with --params).
    #[arg(long, value_delimiter = ',', requires = "params", conflicts_with_all = ["run", "policy"])]
    pub perturb: Vec<f64>,
    /// Posterior draws replayed when --params is an `rlpkg posterior` summary.json or samples.csv
    /// [default: 16].
    #[arg(long, value_name = "N", requires = "params", conflicts_with_all = ["run", "policy"])]
    pub draws: Option<usize>,
    /// Where to write pictures and the JSON summary (with --params).
    #[arg(long, requires = "params", conflicts_with_all = ["run", "policy"])]
    pub out: Option<PathBuf>,
    /// Transport policies: time scales of the scripted baseline evaluated beside the policy (the
    /// recorded high-velocity path played that many times as fast).
    #[arg(long, value_delimiter = ',', default_values_t = [1.0, 1.25, 1.5], conflicts_with = "params")]
    pub scripted: Vec<f64>,
    /// Transport policies: scales of the tool's motion limits (linear and angular speed,
    /// acceleration and jerk) for the time-optimal, jerk-limited motion profile along the
    /// episode's path evaluated beside the policy, e.g. 0.5,0.75,1 [default: none].
    #[arg(long, value_delimiter = ',', conflicts_with = "params")]
    pub profile: Vec<f64>,
    /// Transport policies: output folders of `rlpkg optimize` whose best open-loop command is
    /// evaluated beside the policy, each played from the start of every episode [default: none].
    #[arg(
        long,
        value_delimiter = ',',
        value_name = "DIR",
        conflicts_with = "params"
    )]
    pub optimized: Vec<PathBuf>,
    /// Transport policies with sensors and a plan: vacuum governors of the task's own plan
    /// evaluated beside the policy, each FULL:STOP (the plan at the task's largest rate while the
    /// lowest cup holds at least FULL of the supply vacuum, stopped at STOP or below, linear
    /// between; 0:0 is the plan at rate 1), e.g. 0:0,0.9:0.7 [default: none].
    #[arg(
        long,
        value_delimiter = ',',
        value_name = "FULL:STOP",
        conflicts_with = "params",
        allow_hyphen_values = true
    )]
    pub governor: Vec<VacuumGovernor>,
    /// Transport policies: velocity levels of the recorded baselines evaluated beside the policy (the
    /// timing of the low, medium or high-velocity recording of the episode's tilt level, played
    /// along the episode's path); `none` for none.
    #[arg(long, value_delimiter = ',', default_values_t = ["low".to_string(), "medium".to_string(), "high".to_string()],
          conflicts_with = "params")]
    pub recorded: Vec<String>,
    /// Transport policies: also evaluate the policy on the own conditions of the recordings of this
    /// split (`test`: HHLMM, HHMMM, HHHMM; `train`; `all`), beside the recording's own timing.
    #[arg(long, conflicts_with = "params")]
    pub trajectories: Option<String>,
    /// Print a JSON summary on standard output.
    #[arg(long)]
    pub json: bool,
    /// Which of [`TRANSPORT_OPTIONS`] the command line gave (filled in by `main`).
    #[arg(skip)]
    pub given: Vec<&'static str>,
}

/// The options (argument ids) that only an evaluation of the transport task reads.
pub const TRANSPORT_OPTIONS: [&str; 6] = [
    "scripted",
    "profile",
    "optimized",
    "governor",
    "recorded",
    "trajectories",
];

/// Runs `rlpkg eval`.
pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    if args.params.is_some() {
        return params::run(&args);
    }
    if let Some(policy) = &args.policy {
        let episodes = episode_count(args.episodes)?;
        if let Some(config) = &args.config {
            return onnx::eval_onnx_with_config(policy, config, episodes, &args);
        }
        // A transport policy is evaluated only with --config (above).
        if let Some(id) = args.given.first() {
            return Err(input_error(format!(
                "--{id}: only an evaluation of {} reads it, with its training configuration \
                 (--config <file.toml>)",
                rlpkg_env::transport::ID
            )));
        }
        let summary = onnx::eval_onnx_policy(policy, episodes, args.seed)?;
        return print_policy_summary(&summary, args.json, &|s| {
            format!(
                "{} on {}: {} episodes, return {:.2} +- {:.2} (mean length {:.1})",
                s.policy.display(),
                s.env_id,
                s.episodes,
                s.mean_return,
                s.std_return,
                s.mean_length
            )
        });
    }
    let Some(run) = &args.run else {
        return Err(input_error(
            "give a run folder (runs/<name>), --policy <file.onnx> or --params <file.toml>",
        ));
    };
    let episodes = episode_count(args.episodes)?;
    let training = Training::of_run(run).map_err(agent_error)?;
    for path in rlpkg_agents::runners::changed_inputs(run).map_err(agent_error)? {
        eprintln!(
            "note: {} changed since {} was trained; evaluating on its current content",
            path.display(),
            run.display()
        );
    }
    let policy = TrainedPolicy::load(
        run,
        &training.config,
        &training.config_hash(),
        &training.spec,
    )
    .map_err(agent_error)?;
    if let Task::Transport { config, source } = &training.task {
        return transport::run(run, &policy, config, source, episodes, &args);
    }
    if let Some(id) = args.given.first() {
        return Err(input_error(format!(
            "--{id}: only an evaluation of {} reads it; {} is a {} run",
            rlpkg_env::transport::ID,
            run.display(),
            training.spec.id
        )));
    }
    policy
        .check_evaluation_memory(episodes)
        .map_err(agent_error)?;
    let mut env = training
        .task
        .build(episodes)
        .map_err(|e| agent_error(e.into()))?;
    let summary = policy
        .evaluate(env.as_mut(), args.seed)
        .map_err(agent_error)?;
    print_policy_summary(&summary, args.json, &|s| {
        format!(
            "{} ({}, update {}, {} steps): {} deterministic episodes, return {:.2} +- {:.2} \
             [min {:.2}, max {:.2}], mean length {:.1}",
            run.display(),
            s.env_id,
            s.update,
            s.global_step,
            s.episodes,
            s.mean_return,
            s.std_return,
            s.min_return,
            s.max_return,
            s.mean_length
        )
    })
}

/// `--episodes` as a count of environment copies (the memory they need is checked where the
/// environment is known).
fn episode_count(episodes: u64) -> anyhow::Result<usize> {
    usize::try_from(episodes)
        .map_err(|_| input_error(format!("--episodes {episodes}: too large for this machine")))
}

/// Prints `summary` as pretty JSON (`--json`) or as one line of text.
fn print_policy_summary<T: Serialize>(
    summary: &T,
    json: bool,
    text: &dyn Fn(&T) -> String,
) -> anyhow::Result<()> {
    if json {
        println!("{}", serde_json::to_string_pretty(summary)?);
    } else {
        println!("{}", text(summary));
    }
    Ok(())
}
