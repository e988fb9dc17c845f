//! `rlpkg data ...`: import and clean motion-capture recordings.

use std::path::PathBuf;

use clap::{Args, Subcommand};
use rayon::prelude::*;
use rlpkg_mocap::clean::{percent, MarkerRetention};
use rlpkg_mocap::dataset::{clean_leftovers, write_manifest};
use rlpkg_mocap::description::PackageDescription;
use rlpkg_mocap::import::{import_take_with_robot, take_id, ImportConfig, ImportedTake};
use rlpkg_mocap::{DataError, Dataset, ManifestEntry, Split};

use crate::error::input_error;

/// Data subcommands.
#[derive(Subcommand)]
pub enum DataCommand {
    /// Convert OptiTrack Motive CSV exports (.csv or .csv.gz) into a dataset folder: clean the
    /// markers (low-pass, re-identification, spurious rejection, gap filling), print a retention
    /// report per take, write one trajectory folder per take and the manifest. With --robot, the
    /// tool track is the robot's commanded motion instead of the Motive tool rigid body.
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
    /// Cleaning and conversion settings, with every take listed in [takes] (or a [default_take]);
    /// see configs/import.toml.
    #[arg(long)]
    pub config: PathBuf,
    /// Robot trajectory files named `<take id>_robot.csv` (commanded tool pose, velocity and
    /// acceleration in the robot base frame; see the README). When given, every take needs one,
    /// and its command, carried into the mocap frame by the config's [robot] transform (or one
    /// estimated from the Motive tool rigid body), becomes the tool track.
    #[arg(long, num_args = 1..)]
    pub robot: Vec<PathBuf>,
    /// The take collection's manifest.json (e.g. data/packages-v1/manifest.json): each take's
    /// split, failure flag, object mass, speed and placement angle come from it instead of the
    /// config's [takes]. Failure takes are written with split "excluded" and `failure = true`,
    /// out of train and test.
    #[arg(long, value_name = "FILE")]
    pub manifest: Option<PathBuf>,
}

/// Runs a data subcommand.
pub fn run(command: DataCommand) -> anyhow::Result<()> {
    match command {
        DataCommand::ImportMotive(args) => import_motive(args),
    }
}

/// The file-name suffix that pairs a robot trajectory file with its take.
const ROBOT_SUFFIX: &str = "_robot.csv";

fn import_motive(args: ImportMotiveArgs) -> anyhow::Result<()> {
    let mut config = ImportConfig::load(&args.config).map_err(input_error)?;
    let description = args
        .manifest
        .as_deref()
        .map(PackageDescription::load)
        .transpose()
        .map_err(input_error)?;
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
        if !path.is_file() {
            return Err(input_error(format!(
                "{}: take file not found (expected a Motive CSV export, .csv or .csv.gz)",
                path.display()
            )));
        }
        ids.push(id);
    }
    if let Some(description) = &description {
        config
            .apply_description(description, &ids)
            .map_err(|message| input_error(format!("{}: {message}", args.config.display())))?;
    }
    for id in &ids {
        config
            .take(id)
            .map_err(|message| input_error(format!("{}: {message}", args.config.display())))?;
    }
    let robots = pair_robot_files(&ids, &args.robot)?;
    if args.out.exists() && !args.out.is_dir() {
        return Err(input_error(format!(
            "{}: exists and is not a folder; expected a dataset folder (--out) or nothing",
            args.out.display()
        )));
    }

    // From here on a signal stops the import between two takes: every trajectory folder written
    // by then is whole and listed, and none is half-written.
    let _cooperation = crate::interrupt::Cooperation::start();
    // What an interrupted earlier import left behind, before the manifest is read: a trajectory
    // folder moved aside is put back first.
    for line in clean_leftovers(&args.out).map_err(input_error)? {
        println!("{line}");
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
        .zip(&robots)
        .map(|(path, robot)| {
            crate::interrupt::check()?;
            import_take_with_robot(path, robot.as_deref(), &config).map_err(input_error)
        })
        .collect::<anyhow::Result<_>>()?;

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
    }
    let written_in = |split: Split| {
        imported
            .iter()
            .filter(|t| t.include && t.entry.split == split)
            .count()
    };
    println!(
        "split: {} train, {} test, {} excluded (failure takes, written and flagged), {} not written",
        written_in(Split::Train),
        written_in(Split::Test),
        written_in(Split::Excluded),
        imported.iter().filter(|t| !t.include).count()
    );
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
    let created = !args.out.exists();
    std::fs::create_dir_all(&args.out)
        .map_err(|err| input_error(format!("{}: {err}", args.out.display())))?;
    let written = write_takes(&args.out, &imported, &mut entries);
    if !matches!(written, Ok(true)) && created {
        // Best effort: a folder this run created and left empty goes again.
        let _ = std::fs::remove_dir(&args.out);
    }
    if !written.map_err(input_error)? {
        return Err(crate::interrupt::Interrupted.into());
    }
    let written = imported.iter().filter(|t| t.include).count();
    println!(
        "wrote {written} trajectory folder(s) and {} ({} entries)",
        args.out.join("manifest.toml").display(),
        entries.len()
    );
    Ok(())
}

/// Writes the included takes into `out`. Each trajectory folder appears whole (written beside it,
/// then renamed), and its manifest entry only after it: an interrupted import leaves the takes
/// finished so far, complete and listed, and leftovers that the next run removes. Stops between
/// two takes when a signal asks it to; returns whether it wrote them all.
fn write_takes(
    out: &std::path::Path,
    imported: &[ImportedTake],
    entries: &mut Vec<ManifestEntry>,
) -> Result<bool, DataError> {
    for take in imported.iter().filter(|t| t.include) {
        if crate::interrupt::requested() {
            return Ok(false);
        }
        take.trajectory.save_folder(out)?;
        entries.retain(|e| e.id != take.entry.id);
        entries.push(take.entry.clone());
        write_manifest(out, entries)?;
    }
    if !out.join("manifest.toml").exists() {
        write_manifest(out, entries)?;
    }
    Ok(true)
}

/// The robot file of each take (in the order of `ids`), matched by the name
/// `<take id>_robot.csv`; all `None` without robot files. Every robot file must match a take and,
/// when any is given, every take needs its own.
fn pair_robot_files(ids: &[String], robots: &[PathBuf]) -> anyhow::Result<Vec<Option<PathBuf>>> {
    let mut paired: Vec<Option<PathBuf>> = vec![None; ids.len()];
    if robots.is_empty() {
        return Ok(paired);
    }
    for robot in robots {
        let name = robot
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let Some(id) = name.strip_suffix(ROBOT_SUFFIX) else {
            return Err(input_error(format!(
                "{}: a robot file must be named <take id>{ROBOT_SUFFIX}",
                robot.display()
            )));
        };
        let Some(index) = ids.iter().position(|i| i == id) else {
            return Err(input_error(format!(
                "{}: no take '{id}' among the takes given; expected the robot file of one of: {}",
                robot.display(),
                ids.join(", ")
            )));
        };
        if paired[index].is_some() {
            return Err(input_error(format!(
                "{}: take '{id}' already has a robot file; expected one per take",
                robot.display()
            )));
        }
        paired[index] = Some(robot.clone());
    }
    if let Some(index) = paired.iter().position(Option::is_none) {
        return Err(input_error(format!(
            "take '{}' has no robot file; with --robot every take needs its {}{ROBOT_SUFFIX}",
            ids[index], ids[index]
        )));
    }
    Ok(paired)
}
