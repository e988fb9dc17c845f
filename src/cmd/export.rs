//! `rlpkg export`: writes a run's policy as an ONNX graph (normaliser and action transform
//! included), after loading the encoding in tract and checking it against the run's policy: a
//! policy that fails the check leaves no file.
//!
//! The policy is read from the run's latest checkpoint with the spec of its task; the task's
//! environment is built only to compare the two on observations the policy visits.

use std::path::{Path, PathBuf};

use clap::Args;
use rlpkg_agents::export::check::check_path;
use rlpkg_agents::export::runtime::{max_abs_diff, random_observations, run_episodes};
use rlpkg_agents::export::{ExportError, OnnxPolicy, PolicyGraph, TOLERANCE};
use rlpkg_agents::runners::{evaluation_memory_bytes, run_file_kind, TrainedPolicy, POLICY_FILE};
use rlpkg_vec_env::VecEnv;

use crate::error::{agent_error, input_error};
use crate::files::resolved;
use crate::onnx_file::{
    check_export, check_out_path, BurnComparison, ExportOptions, ExportSummary,
};
use crate::tasks::{Task, Training};

/// Upper bound of `--latency`: each run is timed and kept for the median.
const MAX_LATENCY_RUNS: u64 = 1_000_000;

#[derive(Args)]
#[command(
    after_help = "Examples:\n  rlpkg export runs/cartpole\n  rlpkg export runs/pendulum \
                        --out pendulum.onnx --with-value --check-data --latency 2000"
)]
pub struct ExportArgs {
    /// Run folder written by `rlpkg train` (runs/<name>).
    pub run: PathBuf,
    /// Where to write the ONNX file [default: <run>/policy.onnx].
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Also export the critic, as output `value`.
    #[arg(long)]
    pub with_value: bool,
    /// Number of random observations on which the written file is checked (tract vs the run's
    /// policy, max abs difference <= 1e-5).
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u64).range(1..))]
    pub verify: u64,
    /// Save those observations and the expected outputs next to the model
    /// (`policy.check.json`), for `tests/onnx_check.py` or another runtime.
    #[arg(long)]
    pub check_data: bool,
    /// Time this many single-observation inferences of the written file in tract (at most a
    /// million: about 10 s at 10 us each).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=MAX_LATENCY_RUNS))]
    pub latency: Option<u64>,
    /// Print a JSON summary on standard output.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: ExportArgs) -> anyhow::Result<()> {
    let run = &args.run;
    if !run.is_dir() {
        return Err(input_error(format!(
            "{}: not a run folder (expected a folder written by `rlpkg train`, e.g. runs/<name>)",
            run.display()
        )));
    }
    let out = args.out.clone().unwrap_or_else(|| run.join(POLICY_FILE));
    check_not_run_file(run, &out)?;
    if args.check_data {
        check_not_run_file(run, &check_path(&out))?;
    }
    check_out_path(&out)?;
    let training = Training::of_run(run).map_err(agent_error)?;
    let burn = TrainedPolicy::load(
        run,
        &training.config,
        &training.config_hash(),
        &training.spec,
    )
    .map_err(agent_error)?;
    let mut graph = burn.policy_graph();
    if args.with_value && graph.critic.is_none() {
        return Err(input_error(format!(
            "{}: --with-value: this run's critic reads privileged simulator observations that a \
             real cell does not measure, so only the actor is exported",
            run.display()
        )));
    }
    if !args.with_value {
        graph.critic = None;
    }
    let rows = usize::try_from(args.verify)
        .map_err(|_| input_error(format!("--verify {}: too large", args.verify)))?;
    let widths: usize = graph.actor.iter().map(|layer| layer.d_out).sum();
    // The rows go through the reference, tract and burn, and into the check data.
    rlpkg_agents::config::check_memory(
        &format!("--verify {rows}"),
        4.0 * evaluation_memory_bytes(rows, graph.obs_dim(), widths),
    )
    .map_err(input_error)?;
    let options = ExportOptions {
        verify_rows: rows,
        check_data: args.check_data,
        latency_runs: args.latency.map(|runs| runs as usize),
    };
    let checked = check_export(&graph, &out, &options)?;
    // The environment the run trained on: 100 episodes of a classic-control task, 8 of a
    // simulated one (each copy is a simulator lane).
    let episodes = match training.task {
        Task::Transport { .. } => 8,
        Task::CartPole | Task::Pendulum => 100,
    };
    let mut env = training
        .task
        .build(episodes)
        .map_err(|e| input_error(format!("{}: {e}", run.display())))?;
    let burn = compare_with_burn(
        &burn,
        &graph,
        checked.policy(),
        &out,
        options.verify_rows,
        env.as_mut(),
    )?;
    let mut summary = checked.write(&out, &options)?;
    summary.burn = Some(burn);
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        print_summary(&summary);
    }
    Ok(())
}

/// Compares the actions of the burn policy and of tract on the encoding `onnx` (for `out`), on `rows` random
/// observations and up to `rows` observations the burn policy visits (one episode per copy of
/// `env`, seed 0); an error when either difference exceeds [`TOLERANCE`].
fn compare_with_burn(
    burn: &TrainedPolicy,
    graph: &PolicyGraph,
    onnx: &OnnxPolicy,
    out: &Path,
    rows: usize,
    env: &mut dyn VecEnv,
) -> anyhow::Result<BurnComparison> {
    let action_dim = graph.action_dim();
    let diff = |obs: &[f32], n: usize| -> anyhow::Result<f32> {
        let (diff, row) = max_abs_diff(&burn.act(obs, n), &onnx.act(obs, n)?, action_dim);
        if diff.is_nan() || diff > TOLERANCE {
            anyhow::bail!(
                "{}: actions differ from the trainer's burn policy by {diff:e} (row {row}, \
                 tolerance {TOLERANCE:e}); nothing written",
                out.display()
            );
        }
        Ok(diff)
    };
    let random = random_observations(graph, rows, 0);
    let random_max_abs_diff = diff(&random, rows)?;
    let visited = run_episodes(env, 0, rows, |obs, n| {
        Ok::<_, ExportError>(burn.act(obs, n))
    })?
    .visited_obs;
    let obs_dim = graph.obs_dim();
    let visited_rows = (visited.len() / obs_dim).min(rows);
    let visited_max_abs_diff = diff(&visited[..visited_rows * obs_dim], visited_rows)?;
    Ok(BurnComparison {
        random_rows: rows,
        random_max_abs_diff,
        visited_rows,
        visited_max_abs_diff,
    })
}

/// An output inside the run folder must not be one of the run's own files (its configuration,
/// event files, checkpoints, lock), compared once canonicalised: the run's policy, or a new file
/// beside it, is fine.
fn check_not_run_file(run: &Path, out: &Path) -> anyhow::Result<()> {
    let (Ok(run_dir), Some(target)) = (run.canonicalize(), resolved(out)) else {
        return Ok(()); // no folder to write into: `check_out_path` says so
    };
    match run_file_kind(&run_dir, &target) {
        Some(kind) => Err(input_error(format!(
            "--out {}: is {kind} ({}); writing it would destroy the run: expected a file \
             outside the run's files, e.g. {} or a path outside {}",
            out.display(),
            target.display(),
            run.join(POLICY_FILE).display(),
            run.display()
        ))),
        None => Ok(()),
    }
}

fn print_summary(s: &ExportSummary) {
    println!(
        "wrote {} ({} bytes) for {}",
        s.model.display(),
        s.bytes,
        s.env_id
    );
    println!(
        "verified in tract on {} random observations: max abs diff {:.3e} (tolerance {TOLERANCE:e})",
        s.verified_rows, s.max_abs_diff
    );
    if let Some(b) = &s.burn {
        println!(
            "burn policy vs tract: max abs action diff {:.3e} on {} random and {:.3e} on {} visited \
             observations",
            b.random_max_abs_diff, b.random_rows, b.visited_max_abs_diff, b.visited_rows
        );
    }
    if let Some(path) = &s.check_data {
        println!(
            "check data: {} (python3 tests/onnx_check.py {})",
            path.display(),
            s.model.display()
        );
    }
    if let Some(l) = &s.latency_us {
        println!(
            "tract single-observation latency: median {:.1} us, p90 {:.1} us over {} runs",
            l.median, l.p90, l.runs
        );
    }
}
