//! `rlpkg eval`: one entry point, two jobs. With a run folder or `--policy`, it evaluates a policy in
//! its environment; with `--params`, it evaluates simulator parameters against recorded trajectories.

use std::path::PathBuf;

use clap::Args;

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

pub fn run(_args: EvalArgs) -> anyhow::Result<()> {
    anyhow::bail!("rlpkg eval is not available yet")
}
