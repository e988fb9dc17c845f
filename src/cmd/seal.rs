//! `rlpkg seal fit CONFIG`: fits the suction seal's capacity (`[seal]` `vacuum_kpa`,
//! `lip_strength_ratio`) to a dataset's failure flags. Every take (train, test and excluded) is
//! replayed with the scene under each capacity of a grid (`rlpkg_replay::seal`); the capacity whose
//! simulated cup failures agree best with the flags, class by class (balanced agreement: failures
//! are rare), wins, ties going to the smaller error against the detachment observed in the markers
//! (`rlpkg_mocap::detach`), then to the largest margin.
//!
//! Files under the config's `out`: `candidates.csv` (every capacity: balanced and raw agreement,
//! confusion cells, timing error, margin), `takes.csv` (per take under the fitted capacity: flag,
//! observed detachment, simulated failure, timing error), `fit.toml` (fitted values, confusion table, timing error) and
//! `scene.toml` (the scene with the fitted `[seal]`; also written to `--write-params`).

use std::path::PathBuf;

use clap::{Args, Subcommand};
use rlpkg_calib::seal_fit::{SealFitConfig, SealFitPlan};

use crate::error::{input_error, output_error};
use crate::files::{check_not_input, check_output, write_atomic, Input};

/// Seal subcommands.
#[derive(Subcommand)]
pub enum SealCommand {
    /// Fit the seal's capacity (vacuum, lip strength) to a dataset's failure flags by replaying
    /// every take under a grid of capacities.
    Fit(FitArgs),
}

/// Arguments of `rlpkg seal fit`.
#[derive(Args, Debug)]
pub struct FitArgs {
    /// Seal fit config TOML (e.g. configs/seal/packages-v1.toml).
    pub config: PathBuf,
    /// Also write the scene with the fitted `[seal]` values to this file.
    #[arg(long, value_name = "FILE")]
    pub write_params: Option<PathBuf>,
}

/// Runs a seal subcommand.
pub fn run(command: SealCommand) -> anyhow::Result<()> {
    match command {
        SealCommand::Fit(args) => fit(args),
    }
}

/// The files `rlpkg seal fit` writes into its output folder.
const OUTPUT_FILES: [&str; 4] = ["candidates.csv", "takes.csv", "fit.toml", "scene.toml"];

/// The output folder and `--write-params`, checked before any replay: the folder must be one or
/// be creatable (no file in its place or above it) and hold nothing but an earlier fit's files,
/// and `--write-params` a writable file that is none of the fit's inputs (config, scene, dataset)
/// nor one of the folder's other files.
fn check_outputs(args: &FitArgs, config: &SealFitConfig) -> anyhow::Result<()> {
    let out = &config.out;
    let existing = out
        .ancestors()
        .find(|dir| dir.as_os_str().is_empty() || dir.exists());
    if let Some(dir) = existing.filter(|dir| !dir.as_os_str().is_empty() && !dir.is_dir()) {
        let what = if dir == out.as_path() {
            "is a file".to_string()
        } else {
            format!("{} is a file", dir.display())
        };
        return Err(input_error(format!(
            "{}: key `out` = {}: {what}; expected a folder for {}",
            args.config.display(),
            out.display(),
            OUTPUT_FILES.join(", ")
        )));
    }
    // The folder takes this command's files only: a folder holding anything else (the scene's
    // own folder, a dataset) would have same-named files replaced.
    if let Ok(entries) = std::fs::read_dir(out) {
        let mut foreign: Vec<String> = entries
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|name| {
                // An interrupted fit's temporaries are its own (written anew on success).
                let own = OUTPUT_FILES
                    .iter()
                    .any(|file| name == file || rlpkg_files::is_temporary_of(name, file));
                !own && name != ".lock"
            })
            .collect();
        foreign.sort();
        if let Some(first) = foreign.first() {
            return Err(input_error(format!(
                "{}: key `out` = {}: the folder holds other files ({first}{}); expected a new or \
                 empty folder, or one with only an earlier seal fit's {}",
                args.config.display(),
                out.display(),
                if foreign.len() > 1 { ", ..." } else { "" },
                OUTPUT_FILES.join(", ")
            )));
        }
    }
    let Some(path) = &args.write_params else {
        return Ok(());
    };
    const OPTION: &str = "--write-params";
    check_output(OPTION, path)?;
    let written: Vec<PathBuf> = OUTPUT_FILES[..3]
        .iter()
        .map(|name| out.join(name))
        .collect();
    let mut inputs = vec![
        Input::File(&args.config, "the seal fit config"),
        Input::File(&config.scene, "the config's scene (`scene`)"),
        Input::Folder(&config.dataset, "the config's dataset (`dataset`)"),
    ];
    inputs.extend(
        written
            .iter()
            .map(|file| Input::File(file, "a file the fit writes into `out`")),
    );
    check_not_input(OPTION, path, &inputs)
}

fn fit(args: FitArgs) -> anyhow::Result<()> {
    let config = SealFitConfig::load(&args.config).map_err(input_error)?;
    check_outputs(&args, &config)?;
    let plan = SealFitPlan::new(&config, &args.config).map_err(input_error)?;
    let takes = &plan.takes;
    println!(
        "seal fit: {} takes ({} flagged) x {} capacities ({} vacuum x {} lip strength), scene {}",
        takes.len(),
        takes.iter().filter(|t| t.flagged).count(),
        plan.capacities.len(),
        plan.vacuum_steps,
        plan.lip_strength_steps,
        config.scene.display()
    );
    // What the markers show comes first: it needs no simulation.
    for take in takes {
        let seen = take.observed.detachment.map_or("none".to_string(), |d| {
            format!("cup {} at t = {:.3} s", d.cup, d.t)
        });
        println!(
            "observed {:<18} flagged {:<5} detachment {seen} (largest held drift {:.1} mm)",
            take.id,
            take.flagged,
            1e3 * take.max_held_drift_m()
        );
    }
    let fit = plan.run().map_err(input_error)?;

    std::fs::create_dir_all(&config.out).map_err(|err| {
        input_error(format!(
            "{}: cannot create the output folder: {err}",
            config.out.display()
        ))
    })?;
    let takes_csv = fit.takes_csv();
    let scene_text = fit.scene_toml(&config.scene, &args.config)?;
    for (name, text) in OUTPUT_FILES.iter().zip([
        &fit.candidates_csv(),
        &takes_csv,
        &fit.fit_toml(&args.config),
        &scene_text,
    ]) {
        write_atomic(&config.out.join(name), text.as_bytes()).map_err(output_error)?;
    }
    if let Some(path) = &args.write_params {
        write_atomic(path, scene_text.as_bytes()).map_err(output_error)?;
    }

    let fitted = fit.fitted();
    let s = fit.fitted_score();
    let c = &s.confusion;
    println!("{takes_csv}");
    println!("{}", fit.confusion_table());
    println!(
        "fitted vacuum_kpa = {}, lip_strength_ratio = {}: balanced agreement {:.3}, {} of {} takes agree, timing error {}, {} diverged ({:.1} s wall)",
        fitted.vacuum_kpa,
        fitted.lip_strength_ratio,
        c.balanced_agreement(),
        c.agreement(),
        fit.takes.len(),
        s.timing_error_s
            .map_or("n/a".to_string(), |e| format!("{e:.3} s")),
        c.diverged(),
        fit.wall_s
    );
    println!(
        "wrote {}/{{candidates.csv,takes.csv,fit.toml,scene.toml}}",
        config.out.display()
    );
    if let Some(path) = &args.write_params {
        println!("wrote {}", path.display());
    }
    Ok(())
}
