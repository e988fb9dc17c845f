//! `rlpkg optimize <config.toml>`: sampling-based trajectory optimisation (the cross-entropy
//! method) of the transport task's open-loop command for one package condition, robustly for K
//! of them, or for the nominal package at each of a list of target tilts (a library of
//! commands); with `--mpc`, receding-horizon control of the K packages instead (crate
//! `rlpkg-env`, modules `transport::optimize` and `transport::mpc`).
//!
//! Writes to the output folder: `trajectory.csv` (the best command's tool motion on the first
//! package, in the robot-file format of `rlpkg data import`), `commands.csv` (its actions every
//! control interval), `costs.csv` (cost per iteration), `costs.png` and `summary.json`; a library
//! writes those into `tilt-<degrees>/` per tilt and a `summary.json` listing them; `--mpc` writes
//! `mpc.json`. The files depend only on the config, whatever the number of threads. The config,
//! the optimisation, the receding-horizon loop and the files' formats are the library's
//! (`rlpkg_env::transport`); this module shows progress, writes the files and prints.

use std::path::{Path, PathBuf};

use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use rlpkg_env::transport::{
    control_packages, library_summary_json, optimise_open_loop, IterationCosts, OpenLoopResult,
    OptimizeConfig, OutcomeSummary, TransportConfig, OUTPUT_FILES,
};

use crate::error::{input_error, output_error, run_error};
use crate::render::plot::write_cost_plot;

/// Arguments of `rlpkg optimize`.
#[derive(Args, Debug)]
pub struct OptimizeArgs {
    /// Optimisation config (TOML), e.g. configs/optimize/transport.toml.
    pub config: PathBuf,
    /// Output folder [default: the config's `out_dir`].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// Receding-horizon control of the `[conditions]` packages instead (settings in `[mpc]`):
    /// every control step re-optimises the command over the horizon from the episode's state.
    #[arg(long)]
    pub mpc: bool,
}

/// Runs `rlpkg optimize`.
pub fn run(args: OptimizeArgs) -> anyhow::Result<()> {
    let config = OptimizeConfig::load(&args.config).map_err(run_error)?;
    // summary.json echoes the config as written; --out only moves the files.
    let out = args.out.clone().unwrap_or_else(|| config.out_dir.clone());
    if out.exists() && !out.is_dir() {
        return Err(input_error(format!(
            "{}: is a file; expected a folder (`out_dir` of {} or --out)",
            out.display(),
            args.config.display()
        )));
    }
    let (transport, source) = config.load_task(&args.config).map_err(run_error)?;
    let _cooperation = crate::interrupt::Cooperation::start();
    if args.mpc {
        return run_mpc(&args, &config, transport, &source, &out);
    }
    let tilts = &config.conditions.nominal_target_tilts_deg;
    if tilts.is_empty() {
        let found = optimise(&config, transport, &source, args.quiet, "")?;
        write_outputs(&out, &config, &found)?;
        println!(
            "cost {:.4} at the start, {:.4} at the end ({} iterations of {} candidates x {} \
             packages)",
            found.summary.start_cost,
            found.summary.best_cost,
            config.cem.iterations,
            config.cem.population,
            config.conditions.packages
        );
        println!(
            "wall time: {:.1} s to settle the packages, {:.2} s per iteration, {:.1} s in all",
            found.setup_s,
            found.optimise_s / config.cem.iterations as f64,
            found.setup_s + found.optimise_s
        );
    } else {
        let mut library = Vec::new();
        for &tilt in tilts {
            let label = format!("tilt {tilt} deg: ");
            let mut found = optimise(
                &config,
                transport.nominal(tilt),
                &source,
                args.quiet,
                &label,
            )?;
            found.summary.target_tilt_deg = Some(tilt);
            let folder = format!("tilt-{tilt}");
            write_outputs(&out.join(&folder), &config, &found)?;
            let s = &found.summary;
            println!(
                "{label}cost {:.4} at the start, {:.4} at the end, {:.1} s",
                s.start_cost,
                s.best_cost,
                found.setup_s + found.optimise_s
            );
            library.push(found.library_entry(tilt, folder));
        }
        let json = library_summary_json(&config, &library);
        write_file(&out.join("summary.json"), json.as_bytes())?;
    }
    println!("wrote {}", out.display());
    Ok(())
}

fn progress_bar(quiet: bool, len: usize, template: &str) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    ProgressBar::new(len as u64).with_style(
        ProgressStyle::with_template(template)
            .expect("valid template")
            .progress_chars("=> "),
    )
}

/// Optimises the open-loop command of `transport`'s task for the `[conditions]` packages, with a
/// progress bar (its lines start with `label`).
fn optimise(
    config: &OptimizeConfig,
    transport: TransportConfig,
    source: &str,
    quiet: bool,
    label: &str,
) -> anyhow::Result<OpenLoopResult> {
    let bar = progress_bar(
        quiet,
        config.cem.iterations,
        &format!("{label}{{elapsed_precise}} [{{bar:30}}] iteration {{pos}}/{{len}} {{msg}} (eta {{eta}})"),
    );
    let found = optimise_open_loop(
        config,
        transport,
        source,
        &crate::interrupt::requested,
        &mut |row: &IterationCosts| {
            bar.set_message(format!("best {:.3}", row.best_so_far));
            bar.inc(1);
        },
    )
    .map_err(run_error)?;
    bar.finish_and_clear();
    Ok(found)
}

/// `--mpc`: runs the `[conditions]` packages' episodes under receding-horizon control, prints
/// their outcome and the planning time per control step, writes `mpc.json`.
fn run_mpc(
    args: &OptimizeArgs,
    config: &OptimizeConfig,
    transport: TransportConfig,
    source: &str,
    out: &Path,
) -> anyhow::Result<()> {
    let settings = config.mpc_settings(&args.config).map_err(run_error)?;
    let time_limit_steps = (transport.time_limit_s * transport.control_hz).ceil() as usize;
    let bar = progress_bar(
        args.quiet,
        time_limit_steps,
        "{elapsed_precise} [{bar:30}] control step {pos}/{len} ({msg} running)",
    );
    let run = control_packages(
        config,
        settings,
        transport,
        source,
        &crate::interrupt::requested,
        &mut |running| {
            bar.set_message(running.to_string());
            bar.inc(1);
        },
    )
    .map_err(run_error)?;
    bar.finish_and_clear();
    print!(
        "{}",
        OutcomeSummary::table(std::slice::from_ref(&run.outcome))
    );
    println!(
        "planning: {} control steps of {} episode(s), {:.1} s; {:.3} s per control step of one \
         episode ({:.0} x the {:.3} s control interval)",
        run.control_steps,
        config.conditions.packages,
        run.planning_s,
        run.wall_per_control_step_s,
        run.real_time_factor(),
        run.control_interval_s
    );
    std::fs::create_dir_all(out)
        .map_err(|e| input_error(format!("{}: cannot create: {e}", out.display())))?;
    write_file(&out.join("mpc.json"), run.summary_json(config).as_bytes())?;
    println!("wrote {}", out.join("mpc.json").display());
    Ok(())
}

fn write_file(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    rlpkg_files::write_atomic(path, bytes)
        .map_err(|e| anyhow::anyhow!("writing {}: {e}", path.display()))
}

/// Writes the trajectory, commands, costs, plot and summary into `out`: all of them into a hidden
/// staging folder first, then moved into place (`summary.json` last) unless a signal asked the
/// command to stop, so that a signal, a full disk or an error leaves `out` as it was.
fn write_outputs(
    out: &Path,
    config: &OptimizeConfig,
    found: &OpenLoopResult,
) -> anyhow::Result<()> {
    std::fs::create_dir_all(out)
        .map_err(|e| input_error(format!("{}: cannot create: {e}", out.display())))?;
    let staging = tempfile::Builder::new()
        .prefix(".optimize-")
        .tempdir_in(out)
        .map_err(|e| output_error(anyhow::Error::new(e).context(out.display().to_string())))?;
    write_staged(staging.path(), config, found)?;
    crate::interrupt::check()?;
    for name in OUTPUT_FILES {
        let (from, to) = (staging.path().join(name), out.join(name));
        std::fs::rename(&from, &to).map_err(|e| {
            output_error(anyhow::Error::new(e).context(format!("moving {}", to.display())))
        })?;
    }
    Ok(())
}

/// Writes the files of [`OUTPUT_FILES`] into `out`.
fn write_staged(out: &Path, config: &OptimizeConfig, found: &OpenLoopResult) -> anyhow::Result<()> {
    let write = |name: &str, bytes: &[u8]| -> anyhow::Result<()> {
        let path = out.join(name);
        rlpkg_files::write_atomic(&path, bytes).map_err(|e| {
            output_error(anyhow::Error::new(e).context(format!("writing {}", path.display())))
        })
    };
    write("trajectory.csv", found.trajectory_csv().as_bytes())?;
    write("commands.csv", found.commands_csv().as_bytes())?;
    write("costs.csv", found.costs_csv().as_bytes())?;
    let line = |f: fn(&IterationCosts) -> f64| -> Vec<(f64, f64)> {
        found
            .summary
            .iterations
            .iter()
            .map(|r| (r.iteration as f64, f(r)))
            .collect()
    };
    write_cost_plot(
        &out.join("costs.png"),
        &format!(
            "CEM: {} candidates x {} packages",
            config.cem.population, config.conditions.packages
        ),
        &[
            ("best so far", line(|r| r.best_so_far)),
            ("elite mean", line(|r| r.elite_mean)),
            ("distribution mean", line(|r| r.mean_candidate)),
        ],
    )?;
    write("summary.json", found.summary_json(config).as_bytes())
}
