//! `rlpkg eval`: one entry point, two jobs. With a run folder or `--policy`, it evaluates a policy in
//! its environment; with `--params`, it evaluates simulator parameters against recorded trajectories.

use std::path::PathBuf;

use clap::Args;
use rlpkg_agents::evaluate_run;
use serde::Serialize;

use crate::error::input_error;

#[derive(Args)]
pub struct EvalArgs {
    /// Run folder of a trained policy (runs/<name>).
    pub run: Option<PathBuf>,
    /// Evaluate this exported ONNX policy (through tract) instead of the run's burn checkpoint.
    #[arg(long)]
    pub policy: Option<PathBuf>,
    /// Number of deterministic evaluation episodes.
    #[arg(long, default_value_t = 100)]
    pub episodes: usize,
    /// Seed for the evaluation environments.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Simulator parameters (TOML) to evaluate against recorded trajectories.
    #[arg(long)]
    pub params: Option<PathBuf>,
    /// Which trajectories of the dataset to evaluate on.
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Dataset folder (manifest.toml + one folder per trajectory).
    #[arg(long, default_value = "data/deformable-sim-real")]
    pub data: PathBuf,
    /// Also run the grid-size sweep (the paper's Table 2).
    #[arg(long)]
    pub sweep_grid: bool,
    /// Sensitivity: scale every parameter by these percentages, e.g. 10,20,30.
    #[arg(long, value_delimiter = ',')]
    pub perturb: Vec<f64>,
    /// Where to write pictures and the JSON summary.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print a JSON summary on standard output.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    if args.params.is_some() {
        return crate::cmd::eval_params::run(&args);
    }
    if let Some(policy) = &args.policy {
        let summary = crate::cmd::export::eval_onnx_policy(policy, args.episodes, args.seed)?;
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
    if args.episodes == 0 {
        return Err(input_error("--episodes: expected at least 1"));
    }
    let summary = evaluate_run(run, args.episodes, args.seed).map_err(|e| {
        if e.is_input_error() {
            input_error(e)
        } else {
            e.into()
        }
    })?;
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
