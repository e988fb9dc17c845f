//! `rlpkg train`: PPO on a TOML configuration, or `--resume` of an earlier run; the trained policy
//! is exported as ONNX (`<run>/policy.onnx`) at the end.
//!
//! The task's environment is built here from the configuration ([`crate::tasks`]) and handed to
//! the trainer. The run folder is locked while the command runs (`<run>/.lock`): a second
//! `train` of the same run is refused.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use rlpkg_agents::runners::{
    changed_inputs, clean_leftovers, record_inputs, run_config_path, INPUTS_FILE, POLICY_FILE,
};
use rlpkg_agents::{TrainedPolicy, Trainer};
use rlpkg_env::transport::replaced_packages_line;

use crate::error::{agent_error, input_error};
use crate::files::lock_folder;
use crate::onnx_file::{export_policy, ExportOptions};
use crate::overrides::Override;
use crate::tasks::Training;

#[derive(Args)]
#[command(
    after_help = "Examples:\n  rlpkg train configs/train/cartpole.toml\n  rlpkg train configs/train/pendulum.toml \
                        --name pendulum-seed2\n  rlpkg train configs/train/cartpole.toml --name lr1e-4-seed3 \
                        --set ppo.learning_rate=1e-4 --set run.seed=3\n  rlpkg train --resume runs/cartpole"
)]
pub struct TrainArgs {
    /// Training configuration (TOML), e.g. configs/cartpole.toml.
    #[arg(required_unless_present = "resume", conflicts_with = "resume")]
    pub config: Option<PathBuf>,
    /// Continue the run in this folder from its latest checkpoint.
    #[arg(long, value_name = "RUN_DIR")]
    pub resume: Option<PathBuf>,
    /// Override one configuration value, e.g. --set ppo.learning_rate=1e-4 (repeatable). KEY is a
    /// dotted key path (run.seed, policy.actor_hidden, transport.<key>); VALUE is TOML (1e-4, 3,
    /// true, "tanh", [64, 64]) or a bare word taken as a string. The result is checked like the
    /// file and stored as the run's config.toml; a resumed run keeps its own configuration.
    #[arg(long = "set", value_name = "KEY=VALUE", conflicts_with = "resume")]
    pub set: Vec<Override>,
    /// Run name; the run is written to <OUT_DIR>/<NAME> [default: the config file's stem].
    #[arg(long, value_parser = parse_run_name, conflicts_with = "resume")]
    pub name: Option<String>,
    /// Folder that holds run folders (a resumed run stays in its own folder).
    #[arg(long, default_value = "runs", conflicts_with = "resume")]
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

/// Prints how many of the randomised packages the environment's reset settled were replaced by
/// the unrandomised one (draws the scene's solver cannot carry at its step: not sealed, or
/// frozen; or grasps the grasp check refuses), for environments that report it.
fn report_reset(trainer: &Trainer) {
    let counts = trainer.reset_counts();
    let count = |name: &str| counts.iter().find(|(n, _)| n == name).map(|(_, c)| *c);
    if let (Some(settled), Some(replaced)) = (count("settled_variants"), count("replaced_variants"))
    {
        let weak = count("weak_grasps").unwrap_or(0);
        println!("{}", replaced_packages_line(settled, replaced, weak));
    }
}

/// Runs `rlpkg train`.
pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    // One command at a time trains a run folder: the lock is taken before anything in it is read
    // for a resume or written, and held until the end (export included).
    let (mut trainer, run_dir, _lock) = match (&args.resume, &args.config) {
        (Some(run_dir), _) => {
            // A folder that is not a run is named as such, not as one that cannot be locked.
            run_config_path(run_dir).map_err(agent_error)?;
            let lock = lock_folder(run_dir, false)?;
            let changed = changed_inputs(run_dir).map_err(agent_error)?;
            if !changed.is_empty() {
                let names: Vec<String> = changed.iter().map(|p| p.display().to_string()).collect();
                return Err(input_error(format!(
                    "{}: {} changed since the run was created ({INPUTS_FILE}); its checkpoints \
                     were trained on the earlier content: train a new run on the new one",
                    run_dir.display(),
                    names.join(", ")
                )));
            }
            let mut trainer = Training::of_run(run_dir)
                .and_then(Training::trainer)
                .map_err(agent_error)?;
            trainer.load_checkpoint(run_dir).map_err(agent_error)?;
            (trainer, run_dir.clone(), lock)
        }
        (None, Some(config_path)) => {
            let training = Training::load_with(config_path, &args.set)?;
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
            let trainer = training.trainer().map_err(agent_error)?;
            let lock = lock_folder(&run_dir, true)?;
            trainer.create_run_dir(&run_dir).map_err(agent_error)?;
            let inputs = rlpkg_env::tasks::named_files(config_path).map_err(input_error)?;
            record_inputs(&run_dir, &inputs).map_err(agent_error)?;
            (trainer, run_dir, lock)
        }
        (None, None) => {
            return Err(input_error(
                "give a configuration file or --resume <RUN_DIR>",
            ))
        }
    };
    // What a run stopped at once (a second signal, a kill) left behind; a new run's folder may
    // hold the leftovers of one stopped before its configuration was written. Under the lock, no
    // other command is writing these.
    for path in clean_leftovers(&run_dir).map_err(agent_error)? {
        eprintln!("removed the leftover temporary {}", path.display());
    }
    report_reset(&trainer);
    let stop_after = args.stop_after.map(|s| s as usize);
    if let Some(stop) = stop_after {
        let done = trainer.updates_done();
        if stop <= done {
            return Err(input_error(format!(
                "--stop-after {stop}: {} is already at update {done} of {}; expected a total \
                 number of updates > {done}",
                run_dir.display(),
                trainer.config().num_updates()
            )));
        }
    }
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
        .map_err(agent_error)
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
        // The checkpoint just written, read back as `rlpkg export` reads it.
        let policy = TrainedPolicy::load(
            &run_dir,
            trainer.config(),
            &trainer.config_hash(),
            trainer.spec(),
        )
        .map_err(agent_error)?;
        let mut graph = policy.policy_graph();
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

/// A run name is one plain folder name, so the run stays inside `--out-dir`, and printable (a
/// line break or other control character would split the name in logs and shells).
fn parse_run_name(name: &str) -> Result<String, String> {
    if name.chars().any(char::is_control) {
        return Err(format!(
            "{name:?}: expected a folder name without line breaks or other control characters"
        ));
    }
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
