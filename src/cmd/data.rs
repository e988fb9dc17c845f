//! `rlpkg data ...`: import and clean motion-capture recordings.

use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, Subcommand};
use rayon::prelude::*;
use rlpkg_mocap::clean::{percent, MarkerRetention};
use rlpkg_mocap::dataset::write_manifest;
use rlpkg_mocap::import::{import_take, take_id, ImportConfig, ImportedTake};
use rlpkg_mocap::Dataset;

use crate::error::input_error;

/// Data subcommands.
#[derive(Subcommand)]
pub enum DataCommand {
    /// Convert OptiTrack Motive CSV exports (.csv or .csv.gz) into a dataset folder: clean the
    /// markers (low-pass, re-identification, spurious rejection, gap filling), print a retention
    /// report per take, write one trajectory folder per take and the manifest.
    ImportMotive(ImportMotiveArgs),
}

/// Arguments of `rlpkg data import-motive`.
#[derive(Args)]
pub struct ImportMotiveArgs {
    /// Motive CSV exports, one take each; the file name (without .csv / .csv.gz) is the trajectory id.
    #[arg(required = true)]
    pub takes: Vec<PathBuf>,
    /// Dataset folder to write (created if needed; an existing manifest keeps its other entries).
    #[arg(long)]
    pub out: PathBuf,
    /// Cleaning and conversion settings (default: the built-in values of configs/import.toml).
    #[arg(long)]
    pub config: Option<PathBuf>,
}

/// Runs a data subcommand.
pub fn run(command: DataCommand) -> anyhow::Result<()> {
    match command {
        DataCommand::ImportMotive(args) => import_motive(args),
    }
}

fn import_motive(args: ImportMotiveArgs) -> anyhow::Result<()> {
    let config = match &args.config {
        Some(path) => ImportConfig::load(path).map_err(input_error)?,
        None => ImportConfig::default(),
    };
    let mut ids: Vec<String> = Vec::new();
    for path in &args.takes {
        let id = take_id(path);
        if id.is_empty() || id.starts_with('.') {
            return Err(input_error(format!(
                "{}: cannot derive a trajectory id from the file name; expected <id>.csv or <id>.csv.gz",
                path.display()
            )));
        }
        if ids.contains(&id) {
            return Err(input_error(format!(
                "{}: trajectory id '{id}' is given twice; expected one file per take",
                path.display()
            )));
        }
        ids.push(id);
    }
    // An existing dataset keeps the entries that are not re-imported.
    let mut entries = if args.out.join("manifest.toml").exists() {
        Dataset::open(&args.out).map_err(input_error)?.entries
    } else {
        Vec::new()
    };

    // Convert everything before writing anything, so a bad file leaves the dataset untouched.
    let imported: Vec<ImportedTake> = args
        .takes
        .par_iter()
        .map(|path| import_take(path, &config))
        .collect::<Result<_, _>>()
        .map_err(input_error)?;

    let mut total = MarkerRetention::default();
    let (mut frames_total, mut frames_kept) = (0, 0);
    for take in &imported {
        println!("{}", take.report);
        let m = take.report.markers;
        total.raw_samples += m.raw_samples;
        total.spurious_samples += m.spurious_samples;
        total.observed_kept += m.observed_kept;
        total.velocity_filled += m.velocity_filled;
        total.interpolated += m.interpolated;
        total.unrecovered += m.unrecovered;
        frames_total += take.report.frames_total;
        frames_kept += take.report.frames_kept;
        if !take.include {
            continue;
        }
        let dir = args.out.join(&take.entry.id);
        take.trajectory
            .save(&dir)
            .with_context(|| format!("writing trajectory {}", dir.display()))?;
        entries.retain(|e| e.id != take.entry.id);
        entries.push(take.entry.clone());
    }
    println!(
        "total over {} take(s): frames kept {frames_kept} of {frames_total} ({:.1} %); marker samples kept {} of {} ({:.1} %), written incl. filled {} ({:.1} %)",
        imported.len(),
        percent(frames_kept, frames_total),
        total.observed_kept,
        total.raw_samples,
        total.kept_percent(),
        total.observed_kept + total.velocity_filled + total.interpolated,
        total.output_percent()
    );
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    write_manifest(&args.out, &entries).context("writing the manifest")?;
    let written = imported.iter().filter(|t| t.include).count();
    println!(
        "wrote {written} trajectory folder(s) and {} ({} entries)",
        args.out.join("manifest.toml").display(),
        entries.len()
    );
    Ok(())
}
