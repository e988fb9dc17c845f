//! `rlpkg train`: PPO on a TOML configuration, or `--resume` of an earlier run; the trained policy
//! is exported as ONNX (`<run>/policy.onnx`) at the end.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use rlpkg_agents::config::check_memory;
use rlpkg_agents::runners::{clean_leftovers, POLICY_FILE};
use rlpkg_agents::{load_policy_graph, AgentError, TrainConfig, Trainer};

use crate::cmd::export::{export_policy, ExportOptions};
use crate::error::input_error;

#[derive(Args)]
#[command(
    after_help = "Examples:\n  rlpkg train configs/train/cartpole.toml\n  rlpkg train configs/train/pendulum.toml \
                        --name pendulum-seed2\n  rlpkg train --resume runs/cartpole"
)]
pub struct TrainArgs {
    /// Training configuration (TOML), e.g. configs/cartpole.toml.
    #[arg(required_unless_present = "resume", conflicts_with = "resume")]
    pub config: Option<PathBuf>,
    /// Continue the run in this folder from its latest checkpoint.
    #[arg(long, value_name = "RUN_DIR")]
    pub resume: Option<PathBuf>,
    /// Run name; the run is written to <OUT_DIR>/<NAME> [default: the config file's stem].
    #[arg(long, value_parser = parse_run_name)]
    pub name: Option<String>,
    /// Folder that holds run folders.
    #[arg(long, default_value = "runs")]
    pub out_dir: PathBuf,
    /// Stop after this many updates in total (continue later with --resume).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    pub stop_after: Option<u64>,
    /// Skip the ONNX export at the end.
    #[arg(long)]
    pub no_export: bool,
    /// No progress bar or progress lines.
    #[arg(long)]
    pub quiet: bool,
}

/// Errors in what the user gave exit with code 2.
fn wrap(err: AgentError) -> anyhow::Error {
    if err.is_input_error() {
        input_error(err)
    } else {
        err.into()
    }
}

/// Runs `rlpkg train`.
pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    let (mut trainer, run_dir) = match (&args.resume, &args.config) {
        (Some(run_dir), _) => (Trainer::resume(run_dir).map_err(wrap)?, run_dir.clone()),
        (None, Some(config_path)) => {
            let (config, text) = TrainConfig::load(config_path).map_err(|e| match e {
                AgentError::Io { .. } => input_error(e),
                other => wrap(other),
            })?;
            let name = match &args.name {
                Some(name) => name.clone(),
                None => default_name(config_path)?,
            };
            if args.out_dir.exists() && !args.out_dir.is_dir() {
                return Err(input_error(format!(
                    "--out-dir {}: is a file; expected a folder for run folders",
                    args.out_dir.display()
                )));
            }
            let run_dir = args.out_dir.join(name);
            let trainer = Trainer::new(config, text).map_err(wrap)?;
            trainer.create_run_dir(&run_dir).map_err(wrap)?;
            (trainer, run_dir)
        }
        (None, None) => {
            return Err(input_error(
                "give a configuration file or --resume <RUN_DIR>",
            ))
        }
    };
    // What a run stopped at once (a second signal, a kill) left behind; a new run's folder may
    // hold the leftovers of one stopped before its configuration was written.
    for path in clean_leftovers(&run_dir).map_err(wrap)? {
        eprintln!("removed the leftover temporary {}", path.display());
    }
    let stop_after = args.stop_after.map(|s| s as usize);
    // A signal ends training after the current update, which is checkpointed: `--resume`
    // continues from it.
    let _cooperation = crate::interrupt::Cooperation::start();
    let summary = trainer
        .train_until(
            &run_dir,
            stop_after,
            !args.quiet,
            &crate::interrupt::requested,
        )
        .map_err(wrap)
        .with_context(|| format!("training {}", run_dir.display()))?;
    let total = trainer.config().num_updates();
    println!(
        "{}: {} / {total} updates, {} environment steps, {:.1} s, mean return of the last episodes {:.2}",
        run_dir.display(),
        summary.updates,
        summary.global_step,
        summary.wall_seconds,
        summary.recent_mean_return
    );
    if summary.stopped {
        println!(
            "stopped at update {}, checkpointed: continue with `rlpkg train --resume {}`",
            summary.updates,
            run_dir.display()
        );
        return Err(crate::interrupt::Interrupted.into());
    }
    if summary.updates == total && !args.no_export {
        let mut graph = load_policy_graph(&run_dir).map_err(wrap)?;
        // Like `rlpkg export` without --with-value: the actor (and normaliser) only.
        graph.critic = None;
        let out = run_dir.join(POLICY_FILE);
        let options = ExportOptions {
            verify_rows: 1000,
            check_data: false,
            latency_runs: None,
        };
        let exported = export_policy(&graph, &out, &options)?;
        println!(
            "exported {} (max abs difference to the trained policy {:e})",
            exported.model.display(),
            exported.max_abs_diff
        );
    }
    Ok(())
}

/// A run name is one plain folder name, so the run stays inside `--out-dir`.
fn parse_run_name(name: &str) -> Result<String, String> {
    let mut parts = Path::new(name).components();
    match (parts.next(), parts.next()) {
        (Some(std::path::Component::Normal(part)), None) if part == name => Ok(name.to_string()),
        _ => Err(format!(
            "`{name}`: expected a plain folder name (not empty, no `/`, not `.` or `..`), e.g. cartpole-seed2"
        )),
    }
}

/// The config file's stem, e.g. `cartpole` for `configs/train/cartpole.toml`.
fn default_name(config_path: &Path) -> anyhow::Result<String> {
    config_path
        .file_stem()
        .and_then(|s| s.to_str())
        .and_then(|s| parse_run_name(s).ok())
        .ok_or_else(|| {
            input_error(format!(
                "{}: cannot derive a run name; pass --name",
                config_path.display()
            ))
        })
}

/// Arguments of `rlpkg bench ppo`.
#[derive(Args)]
pub struct PpoBenchArgs {
    /// burn backends to measure: flex, ndarray, or both (comma-separated).
    #[arg(long, default_value = "flex,ndarray", value_delimiter = ',')]
    pub backend: Vec<String>,
    /// Samples per minibatch.
    #[arg(long, default_value_t = 4096)]
    pub minibatch: usize,
    /// Timed minibatches per backend (at most 10000).
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u64).range(1..=10_000))]
    pub minibatches: u64,
    /// Observation width.
    #[arg(long, default_value_t = 48)]
    pub obs_dim: usize,
    /// Action width.
    #[arg(long, default_value_t = 6)]
    pub action_dim: usize,
    /// Hidden widths of actor and critic (comma-separated).
    #[arg(long, default_value = "256,256", value_delimiter = ',')]
    pub hidden: Vec<usize>,
    /// Lockstep steps of the environment benchmark (0 skips it; at most 10 million).
    #[arg(long, default_value_t = 20000, value_parser = clap::value_parser!(u64).range(0..=10_000_000))]
    pub env_steps: u64,
    /// Copies in the environment benchmark.
    #[arg(long, default_value_t = 64)]
    pub num_envs: usize,
    /// Print the results as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Bytes of the PPO benchmark: actor and critic with gradients and Adam moments (x6), and one
/// minibatch's data and activations with their gradients.
fn ppo_bench_memory_bytes(args: &PpoBenchArgs) -> f64 {
    let network = |out: usize| {
        let mut widths = vec![args.obs_dim];
        widths.extend_from_slice(&args.hidden);
        widths.push(out);
        widths
            .windows(2)
            .map(|w| (w[0] as f64 + 1.0) * w[1] as f64)
            .sum::<f64>()
    };
    let parameters = network(args.action_dim) + network(1);
    let widths = 2 * args.hidden.iter().sum::<usize>() + args.obs_dim + args.action_dim;
    let per_row = 4 * widths + 2 * (args.obs_dim + args.action_dim + 6);
    4.0 * (6.0 * parameters + args.minibatch as f64 * per_row as f64)
}

/// `rlpkg bench ppo`: PPO update throughput (forward + backward + global clip + Adam) per backend,
/// and CartPole / Pendulum steps per second.
pub fn run_bench(args: PpoBenchArgs) -> anyhow::Result<()> {
    use rlpkg_agents::bench::{
        env_throughput, matmul_throughput, ppo_update_throughput, PpoBenchConfig,
    };
    if args.minibatch == 0 || args.obs_dim == 0 || args.action_dim == 0 {
        return Err(input_error(
            "--minibatch, --obs-dim and --action-dim: expected at least 1",
        ));
    }
    if args.hidden.is_empty() || args.hidden.contains(&0) {
        return Err(input_error(
            "--hidden: expected widths of at least 1, e.g. 256,256",
        ));
    }
    check_memory(
        &format!(
            "--minibatch {} --hidden {:?} --obs-dim {} --action-dim {}",
            args.minibatch, args.hidden, args.obs_dim, args.action_dim
        ),
        ppo_bench_memory_bytes(&args),
    )
    .map_err(input_error)?;
    let (minibatches, env_steps) = (args.minibatches as usize, args.env_steps as usize);
    if env_steps > 0 {
        check_memory(
            &format!("--num-envs {}", args.num_envs),
            rlpkg_agents::runners::evaluation_memory_bytes(args.num_envs, 4, 0),
        )
        .map_err(input_error)?;
    }
    let mut updates = Vec::new();
    let mut matmuls = Vec::new();
    for name in &args.backend {
        let backend = rlpkg_agents::Backend::parse(name)
            .ok_or_else(|| input_error(format!("--backend {name}: expected flex or ndarray")))?;
        let result = ppo_update_throughput(&PpoBenchConfig {
            obs_dim: args.obs_dim,
            action_dim: args.action_dim,
            hidden: args.hidden.clone(),
            minibatch: args.minibatch,
            minibatches,
            backend,
        });
        let shares = &result.shares;
        eprintln!(
            "ppo update [{}] {}-{:?}-{} ({} parameters), minibatch {}: {:.0} samples/s ({:.1} ms/minibatch; forward {:.0} %, backward {:.0} %, optimiser {:.0} %, batching {:.0} %; {:.0} samples per CPU second)",
            result.backend,
            args.obs_dim,
            args.hidden,
            args.action_dim,
            result.parameters,
            args.minibatch,
            result.samples_per_second,
            result.ms_per_minibatch,
            100.0 * shares.forward,
            100.0 * shares.backward,
            100.0 * shares.optimiser,
            100.0 * shares.batch,
            result.samples_per_cpu_second.unwrap_or(f64::NAN),
        );
        updates.push(result);
        // The layer products of the update: the forward x W of the first two layers and the
        // weight gradient x^T dz of the second.
        let (m, h0) = (args.minibatch, args.hidden[0]);
        let h1 = args.hidden.get(1).copied().unwrap_or(h0);
        for (shape, transposed) in [
            ([m, args.obs_dim, h0], false),
            ([m, h0, h1], false),
            ([h0, m, h1], true),
        ] {
            let result = matmul_throughput(backend, shape, transposed, 5);
            eprintln!(
                "matmul [{}] {}x{}{} x {}x{}: {:.1} GFLOP/s",
                result.backend,
                shape[0],
                shape[1],
                if transposed { " (transposed view)" } else { "" },
                shape[1],
                shape[2],
                result.gflops
            );
            matmuls.push(result);
        }
    }
    let mut envs = Vec::new();
    if env_steps > 0 {
        for id in rlpkg_env::KNOWN_IDS {
            let result = env_throughput(id, args.num_envs.max(1), env_steps)?;
            eprintln!(
                "env {} x{}: {:.3e} steps/s",
                result.env_id, result.num_envs, result.steps_per_second
            );
            envs.push(result);
        }
    }
    if args.json {
        let json = serde_json::json!({ "ppo_update": updates, "matmul": matmuls, "env": envs });
        println!("{}", serde_json::to_string_pretty(&json)?);
    }
    Ok(())
}
