//! `rlpkg`: learn to move deformable packages with a suction gripper.
//!
//! Each subcommand lives in its own module under `cmd/`; this file only parses and dispatches.
//! The tasks (which environment an id names, built from its settings table) live in `tasks/`.

/// `print!` through [`output`]: a closed pipe or a full disk never panics (see there).
macro_rules! print {
    ($($arg:tt)*) => {
        $crate::output::print(format_args!($($arg)*))
    };
}

/// `println!` through [`output`].
macro_rules! println {
    () => {
        $crate::output::print(format_args!("\n"))
    };
    ($($arg:tt)*) => {
        $crate::output::print(format_args!("{}\n", format_args!($($arg)*)))
    };
}

/// `eprint!` through [`output`].
macro_rules! eprint {
    ($($arg:tt)*) => {
        $crate::output::eprint(format_args!($($arg)*))
    };
}

/// `eprintln!` through [`output`].
macro_rules! eprintln {
    () => {
        $crate::output::eprint(format_args!("\n"))
    };
    ($($arg:tt)*) => {
        $crate::output::eprint(format_args!("{}\n", format_args!($($arg)*)))
    };
}

mod output;

mod cmd;
mod error;
mod files;
mod interrupt;
mod onnx_file;
mod overrides;
mod render;
mod tasks;

use clap::parser::ValueSource;
use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

/// glibc's malloc gives blocks of a few megabytes (a PPO minibatch's activations and gradients,
/// one fresh tensor per op) back to the kernel when they are freed, so the next op faults the same
/// pages in again: with its default thresholds `rlpkg bench ppo` spends most of a minibatch update
/// in page faults and zeroing pages (docs/ppo.md). Blocks up to glibc's largest mmap threshold
/// (32 MiB on 64-bit) are served from the heap instead, and up to 1 GiB of free heap is kept for
/// reuse rather than trimmed.
fn keep_freed_memory_in_the_heap() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets allocator parameters; called before any other thread exists.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
    }
}

#[derive(Parser)]
#[command(name = "rlpkg", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Train a policy with PPO from a TOML config (or resume a run).
    Train(cmd::train::TrainArgs),
    /// Evaluate a trained policy (run folder or ONNX file), or calibrated simulator parameters.
    Eval(cmd::eval::EvalArgs),
    /// Export a run's policy as an ONNX graph (normaliser included).
    Export(cmd::export::ExportArgs),
    /// Replay a recorded tool trajectory in the simulator; write CSVs and pictures.
    Simulate(cmd::simulate::SimulateArgs),
    /// Fit simulator parameters to recorded trajectories (Bayesian optimisation), or sample their
    /// posterior on the simulator (a config with [smc]).
    Calibrate(cmd::calibrate::CalibrateArgs),
    /// Optimise the transport task's open-loop command with the cross-entropy method.
    Optimize(cmd::optimize::OptimizeArgs),
    /// Approximate posterior over a calibration's parameters from its evaluations (no simulation).
    Posterior(cmd::posterior::PosteriorArgs),
    /// Import and clean motion-capture data.
    #[command(subcommand)]
    Data(cmd::data::DataCommand),
    /// Build scene configs (e.g. from a package's manifest.json).
    #[command(subcommand)]
    Scene(cmd::scene::SceneCommand),
    /// Fit the suction seal's capacity to a dataset's failure flags.
    #[command(subcommand)]
    Seal(cmd::seal::SealCommand),
    /// Benchmarks that print throughput figures.
    #[command(subcommand)]
    Bench(cmd::bench::BenchCommand),
}

/// Lets every option that takes a value take a negative number, so that `--seconds -1` reaches the
/// option's own check (which names the option and the expected range) instead of being read as an
/// unknown flag `-1`. Options whose values are numbers or grids (and the lists that say so in their
/// own attributes) take any value that starts with a hyphen (`-inf`, `-nan`, `-5x5`, which clap
/// does not count as numbers), and their parser names the option; options of paths and names keep
/// refusing a flag-like value.
fn negative_numbers_as_values(command: clap::Command) -> clap::Command {
    use std::any::TypeId;
    let numeric = [
        TypeId::of::<f64>(),
        TypeId::of::<f32>(),
        TypeId::of::<usize>(),
        TypeId::of::<u64>(),
        TypeId::of::<u32>(),
        TypeId::of::<i64>(),
        TypeId::of::<i32>(),
        TypeId::of::<[usize; 2]>(),
    ];
    command
        .mut_args(|arg| {
            if !arg.get_action().takes_values() {
                return arg;
            }
            let value = arg.get_value_parser().type_id();
            let arg = arg.allow_negative_numbers(true);
            if numeric.iter().any(|t| value == *t) {
                arg.allow_hyphen_values(true)
            } else {
                arg
            }
        })
        .mut_subcommands(negative_numbers_as_values)
}

fn main() {
    keep_freed_memory_in_the_heap();
    let matches = match negative_numbers_as_values(Cli::command()).try_get_matches() {
        Ok(matches) => matches,
        Err(err) => {
            // Help and version go to stdout, usage errors to stderr; a stdout that cannot take the
            // help is an error like any other output's.
            let code = err.exit_code();
            if let Err(e) = err.print() {
                if err.use_stderr() || e.kind() != std::io::ErrorKind::BrokenPipe {
                    eprintln!("error: standard output: {e}");
                    std::process::exit(2);
                }
            }
            std::process::exit(code);
        }
    };
    let mut cli = Cli::from_arg_matches(&matches).unwrap_or_else(|err| err.exit());
    if let (Command::Eval(args), Some(("eval", given))) = (&mut cli.command, matches.subcommand()) {
        args.given = cmd::eval::TRANSPORT_OPTIONS
            .into_iter()
            .filter(|id| given.value_source(id) == Some(ValueSource::CommandLine))
            .collect();
    }
    interrupt::install();
    let result = match cli.command {
        Command::Train(args) => cmd::train::run(args),
        Command::Eval(args) => cmd::eval::run(args),
        Command::Export(args) => cmd::export::run(args),
        Command::Simulate(args) => cmd::simulate::run(args),
        Command::Calibrate(args) => cmd::calibrate::run(args),
        Command::Optimize(args) => cmd::optimize::run(args),
        Command::Posterior(args) => cmd::posterior::run(args),
        Command::Data(command) => cmd::data::run(command),
        Command::Scene(command) => cmd::scene::run(command),
        Command::Seal(command) => cmd::seal::run(command),
        Command::Bench(command) => cmd::bench::run(command),
    };
    if let Err(err) = result {
        let err = interrupt::explain(err);
        eprintln!("error: {}", error::message(&err));
        std::process::exit(error::exit_code(&err));
    }
    if let Some(e) = output::stdout_error() {
        eprintln!("error: standard output: {e} (the command finished; its files are written)");
        std::process::exit(2);
    }
}
