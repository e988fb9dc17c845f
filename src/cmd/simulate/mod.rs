//! `rlpkg simulate`: replays a recorded tool trajectory in the simulator with the reference scene
//! placement (`reference-model.md` §1: package at the row-0 markers, cups around the initial cup
//! point, disc at the object's x/z and the markers' mean y, a rest period first) and writes the
//! simulated marker sites and disc pose as CSV, per-frame errors against the recording, PNG stills
//! and an animated GIF.
//!
//! Files under `--out` (one CSV row per recorded frame, t = recording time, metres):
//! * `markers_sim.csv`: `frame, t`, then `m<i>_x, m<i>_y, m<i>_z` for every row-0 marker of
//!   `meta.toml` (in its order) embedded in the upper sheet, then `g<m>_x, g<m>_y, g<m>_z` for the
//!   42 points of the nominal 6 x 7 marker grid (row-major; the reference's loss points).
//! * `object_sim.csv`: `t, px, py, pz, qx, qy, qz, qw` (disc centre and orientation).
//! * `metrics.csv`: `frame, t, chamfer_m, object_error_m`: the symmetric mean nearest-neighbour
//!   distance between the 42 grid points and that frame's recorded markers, and the distance between
//!   the simulated and recorded disc centres.
//! * `summary.json`: settings, wall time, means and maxima, and the reference's per-second sums.
//! * `frames/NNN_t<time>s.png` stills and `replay.gif` (rest period included, t < 0).
//!
//! Layout: [`schedule`] (when the replay stops), [`replay`] (the rollout of `rlpkg-replay` with a
//! recorder of rows and pictures), [`outcome`] (the CSV rows, the summary and the report).

mod outcome;
mod replay;
mod schedule;

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use rlpkg_mocap::load_trajectory;
use rlpkg_sim::SceneConfig;

use crate::error::{input_error, output_error};
use crate::files::write_atomic;
use replay::Replay;
use schedule::{ScheduleOptions, RECORDING_RATE_HZ};

/// Arguments of `rlpkg simulate`.
#[derive(Args, Debug)]
pub struct SimulateArgs {
    /// Trajectory folder with tool.csv, object.csv, markers.csv and meta.toml
    /// (e.g. data/deformable-sim-real/HHMMM).
    pub trajectory: PathBuf,
    /// Scene config TOML [default: the built-in reference preset, configs/scenes/study.toml].
    #[arg(long, value_name = "FILE")]
    pub params: Option<PathBuf>,
    /// Package vertices per layer, ROWSxCOLS (rows along the short side), e.g. 11x13.
    #[arg(long, value_name = "RxC", value_parser = parse_grid, conflicts_with = "between")]
    pub grid: Option<[usize; 2]>,
    /// The reference marker grid with P particles between neighbouring markers: (6+5P)x(7+6P).
    #[arg(long, value_name = "P")]
    pub between: Option<usize>,
    /// Output folder [default: runs/simulate-<trajectory id>].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// One GIF frame every N recorded frames (240 Hz); 24 gives 10 frames per simulated second.
    #[arg(long, value_name = "N", default_value_t = 24)]
    pub frames_every: usize,
    /// One PNG still every S seconds of simulated time (plus the first and the last instant).
    #[arg(long, value_name = "S", default_value_t = 1.0)]
    pub png_every: f64,
    /// Do not write the animated GIF.
    #[arg(long)]
    pub no_gif: bool,
    /// Replay only the first S seconds of the recording (after the rest period).
    #[arg(long, value_name = "S")]
    pub seconds: Option<f64>,
}

fn parse_grid(text: &str) -> Result<[usize; 2], String> {
    let expected =
        || format!("`{text}`: expected ROWSxCOLS with two integers of at least 2, e.g. 11x13");
    let (rows, cols) = text.split_once(['x', 'X']).ok_or_else(expected)?;
    let rows: usize = rows.trim().parse().map_err(|_| expected())?;
    let cols: usize = cols.trim().parse().map_err(|_| expected())?;
    if rows < 2 || cols < 2 {
        return Err(expected());
    }
    Ok([rows, cols])
}

/// Runs the command.
pub fn run(args: SimulateArgs) -> anyhow::Result<()> {
    check_options(&args)?;
    let dir = &args.trajectory;
    if !dir.is_dir() {
        return Err(input_error(format!(
            "{}: trajectory folder not found (expected a folder with tool.csv, object.csv, markers.csv and meta.toml)",
            dir.display()
        )));
    }
    let recording = load_trajectory(dir).map_err(input_error)?;
    check_span(&args, &recording)?;
    let (config, config_source) = scene_config(&args)?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("runs/simulate-{}", recording.id)));
    refuse_earlier_output(&out)?;
    let options = ScheduleOptions {
        frames_every: args.frames_every,
        png_every: args.png_every,
        seconds: args.seconds,
    };
    let replay = Replay::new(&recording, dir, &config, options)?;
    // From here on a signal stops the replay between two pictures. Everything is written into a
    // hidden staging folder inside `out` and moved into place once the replay ended: a signal, a
    // full disk or an error leaves `out` as it was (the staging folder is removed when dropped).
    let _cooperation = crate::interrupt::Cooperation::start();
    let mut new_folder = NewFolder((!out.exists()).then(|| out.clone()));
    prepare_output(&out)?;
    let staging = tempfile::Builder::new()
        .prefix(STAGING_PREFIX)
        .tempdir_in(&out)
        .and_then(|staging| std::fs::create_dir(staging.path().join("frames")).map(|_| staging))
        .map_err(|e| {
            output_error(anyhow::Error::new(e).context(format!(
                "{}: cannot stage the replay's files",
                out.display()
            )))
        })?;
    println!(
        "simulate {}: {} package + {} cup particles, dt = 1/{} s, {:.2} s rest + {:.3} s replay ({} substeps)",
        recording.id,
        replay.model.num_package,
        replay.model.num_cup,
        config.integrator.substep_rate_hz,
        replay.rest_s,
        replay.replayed_s(),
        replay.total_substeps(),
    );
    let started = Instant::now();
    let mut outcome = replay.run(&recording, args.no_gif, staging.path())?;
    let wall_s = started.elapsed().as_secs_f64();
    if let Some(gif) = &mut outcome.gif {
        gif.0 = out.join("replay.gif");
    }
    let summary = outcome.summary(
        &recording,
        &replay.model,
        replay.rest_s,
        &config_source,
        wall_s,
        &out,
    );
    write_atomic(
        &staging.path().join("summary.json"),
        serde_json::to_string_pretty(&summary)?.as_bytes(),
    )
    .map_err(output_error)?;
    move_into_place(staging.path(), &out)?;
    new_folder.0 = None;
    outcome.print(wall_s, &out);
    // The scene's values and step are the user's: a replay they cannot carry is bad input (exit 2).
    if let Some((frame, t)) = outcome.non_finite {
        return Err(input_error(format!(
            "{config_source}: the simulation produced non-finite values at frame {frame} (recording \
             time t = {t:.4} s); expected a scene whose values and step carry this motion; the files \
             in {} stop at the frame before",
            out.display()
        )));
    }
    if let Some(event) = outcome.health {
        return Err(input_error(format!(
            "{config_source}: the simulation became unhealthy ({:?}) at recording time t = {:.4} s; \
             expected a scene whose values and step carry this motion; the files in {} stop there",
            event.reason,
            event.time - replay.rest_s,
            out.display()
        )));
    }
    Ok(())
}

/// The output folder a replay created, removed again (when empty) unless its files were moved into
/// it: a replay stopped by a signal or an error leaves no empty folder behind. Declared before
/// the staging folder inside it, so dropped after it.
struct NewFolder(Option<PathBuf>);

impl Drop for NewFolder {
    fn drop(&mut self) {
        if let Some(folder) = &self.0 {
            let _ = std::fs::remove_dir(folder.join("frames"));
            let _ = std::fs::remove_dir(folder);
        }
    }
}

/// `--seconds` beyond the recording would do nothing (the whole recording is replayed).
fn check_span(args: &SimulateArgs, recording: &rlpkg_mocap::Trajectory) -> anyhow::Result<()> {
    let times = &recording.tool.t;
    let duration = times.last().zip(times.first()).map_or(0.0, |(l, f)| l - f);
    if let Some(seconds) = args.seconds {
        if seconds > duration {
            return Err(input_error(format!(
                "--seconds {seconds:?}: expected at most the recording's {duration:.4} s \
                 ({}); leave it out to replay the whole recording",
                args.trajectory.display()
            )));
        }
    }
    Ok(())
}

/// The hidden folder inside `--out` a replay's files are written into before they are moved.
const STAGING_PREFIX: &str = ".simulate-";

/// Moves every file `staging` holds (and its `frames/`) into `out`, the stills first and
/// `summary.json` last, so that a folder with a summary holds the whole replay.
fn move_into_place(staging: &Path, out: &Path) -> anyhow::Result<()> {
    let io = |path: &Path, e: std::io::Error| {
        output_error(anyhow::Error::new(e).context(format!(
            "{}: cannot move the replay's file here",
            path.display()
        )))
    };
    let frames = staging.join("frames");
    let mut stills: Vec<PathBuf> = std::fs::read_dir(&frames)
        .and_then(|entries| entries.map(|e| e.map(|e| e.path())).collect())
        .map_err(|e| io(&frames, e))?;
    stills.sort();
    let into = out.join("frames");
    std::fs::create_dir_all(&into).map_err(|e| io(&into, e))?;
    let summary = "summary.json";
    let files = OUTPUT_FILES
        .iter()
        .filter(|f| **f != summary)
        .chain([&summary]);
    let moves = stills
        .into_iter()
        .map(|still| {
            let name = still.file_name().expect("a listed file").to_owned();
            (still, out.join("frames").join(name))
        })
        .chain(files.map(|f| (staging.join(f), out.join(f))));
    for (from, to) in moves {
        if !from.exists() {
            continue;
        }
        // A symlink or a FIFO the user placed where an output goes is written through (or
        // refused) as any output is; a regular file or nothing is replaced by the staged one.
        let placed = std::fs::symlink_metadata(&to).is_ok_and(|m| !m.is_file());
        if placed {
            let bytes = std::fs::read(&from).map_err(|e| io(&from, e))?;
            write_atomic(&to, &bytes).map_err(output_error)?;
        } else {
            std::fs::rename(&from, &to).map_err(|e| io(&to, e))?;
        }
    }
    Ok(())
}

/// Files written into the output folder besides `frames/`; a temporary one is `.<name>.<suffix>`.
const OUTPUT_FILES: [&str; 5] = [
    "markers_sim.csv",
    "object_sim.csv",
    "metrics.csv",
    "summary.json",
    "replay.gif",
];

/// A replay never writes into a folder that holds an earlier replay's files: the files the new one
/// does not rewrite (stills at other instants, a GIF under `--no-gif`) would pass for its own.
fn refuse_earlier_output(out: &Path) -> anyhow::Result<()> {
    // Regular files only: a symlink or a FIFO placed where an output goes is the user's set-up
    // (written through, or refused, when the file is written).
    let regular = |path: &Path| std::fs::symlink_metadata(path).is_ok_and(|m| m.is_file());
    let mut found: Vec<String> = OUTPUT_FILES
        .iter()
        .filter(|file| regular(&out.join(file)))
        .map(|file| file.to_string())
        .collect();
    if let Ok(entries) = std::fs::read_dir(out.join("frames")) {
        let mut stills: Vec<String> = entries
            .flatten()
            .filter(|entry| regular(&entry.path()))
            .map(|entry| entry.file_name().to_string_lossy().into_owned())
            .filter(|name| !name.starts_with('.'))
            .map(|name| format!("frames/{name}"))
            .collect();
        stills.sort();
        found.extend(stills);
    }
    if found.is_empty() {
        return Ok(());
    }
    const NAMED: usize = 4;
    let more = found.len().saturating_sub(NAMED);
    found.truncate(NAMED);
    Err(input_error(format!(
        "--out {}: holds an earlier replay's files ({}{}); expected a new or empty folder: \
         remove them or choose another --out",
        out.display(),
        found.join(", "),
        if more > 0 {
            format!(" and {more} more")
        } else {
            String::new()
        }
    )))
}

/// Creates `out` and removes temporary files an interrupted earlier run left behind.
fn prepare_output(out: &Path) -> anyhow::Result<()> {
    if out.exists() && !out.is_dir() {
        return Err(input_error(format!(
            "--out {}: is a file; expected a folder for the replay's files",
            out.display()
        )));
    }
    let frames = out.join("frames");
    std::fs::create_dir_all(out).map_err(|err| {
        input_error(format!(
            "{}: cannot create the output folder: {err}",
            out.display()
        ))
    })?;
    let is_output_temporary = |name: &str| {
        OUTPUT_FILES
            .iter()
            .any(|file| name.starts_with(&format!(".{file}.")))
    };
    let is_still_temporary = |name: &str| name.starts_with('.') && name.contains(".tmp");
    // The staging folder of a replay killed outright (a signal or an error removes its own).
    if let Ok(entries) = std::fs::read_dir(out) {
        for entry in entries.flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            if name.starts_with(STAGING_PREFIX) && entry.path().is_dir() {
                std::fs::remove_dir_all(entry.path()).map_err(|err| {
                    input_error(format!(
                        "{}: cannot remove this leftover staging folder: {err}",
                        entry.path().display()
                    ))
                })?;
            }
        }
    }
    for (dir, is_temporary) in [
        (out, &is_output_temporary as &dyn Fn(&str) -> bool),
        (frames.as_path(), &is_still_temporary),
    ] {
        if !dir.exists() {
            continue;
        }
        let entries = std::fs::read_dir(dir)
            .map_err(|err| input_error(format!("{}: {err}", dir.display())))?;
        for entry in entries.flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            if is_temporary(&name) {
                let path = entry.path();
                std::fs::remove_file(&path).map_err(|err| {
                    input_error(format!(
                        "{}: cannot remove this leftover temporary file: {err}",
                        path.display()
                    ))
                })?;
            }
        }
    }
    Ok(())
}

/// Upper bound of `--frames-every`: one GIF frame per hour of recording.
const MAX_FRAMES_EVERY: usize = 3600 * RECORDING_RATE_HZ as usize;

/// Upper bound of `--png-every` (s): one still per hour of simulated time.
const MAX_PNG_EVERY_S: f64 = 3600.0;

fn check_options(args: &SimulateArgs) -> anyhow::Result<()> {
    if !(1..=MAX_FRAMES_EVERY).contains(&args.frames_every) {
        return Err(input_error(format!(
            "--frames-every {}: expected a whole number of frames in [1, {MAX_FRAMES_EVERY}] \
             (an hour of recording)",
            args.frames_every
        )));
    }
    let png_range = 1.0 / RECORDING_RATE_HZ..=MAX_PNG_EVERY_S;
    if !png_range.contains(&args.png_every) {
        return Err(input_error(format!(
            "--png-every {:?}: expected a number of seconds in [1/{RECORDING_RATE_HZ} (one \
             recorded frame), {MAX_PNG_EVERY_S}]",
            args.png_every
        )));
    }
    if let Some(seconds) = args.seconds {
        if !(seconds.is_finite() && seconds > 0.0) {
            return Err(input_error(format!(
                "--seconds {seconds}: expected a positive number of seconds"
            )));
        }
    }
    Ok(())
}

/// The scene config (file or built-in reference preset) with the grid options applied.
fn scene_config(args: &SimulateArgs) -> anyhow::Result<(SceneConfig, String)> {
    let (mut config, source) = match &args.params {
        Some(path) => (
            SceneConfig::load(path).map_err(input_error)?,
            path.display().to_string(),
        ),
        None => (
            SceneConfig::preset("reference").map_err(input_error)?,
            "built-in reference preset (configs/scenes/study.toml)".to_string(),
        ),
    };
    let grid = match (args.grid, args.between) {
        (Some(grid), _) => Some((grid, "--grid")),
        (None, Some(p)) => {
            let side = |base: usize, per: usize| p.checked_mul(per)?.checked_add(base);
            let grid = side(6, 5).zip(side(7, 6)).ok_or_else(|| {
                input_error(format!(
                    "--between {p}: expected a small number of particles"
                ))
            })?;
            Some(([grid.0, grid.1], "--between"))
        }
        (None, None) => None,
    };
    if let Some((grid, option)) = grid {
        config.package.grid = grid;
        config.validate(option).map_err(input_error)?;
    }
    Ok((config, source))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_option_parses_rows_and_columns() {
        assert_eq!(parse_grid("11x13"), Ok([11, 13]));
        assert_eq!(parse_grid("21X25"), Ok([21, 25]));
        for bad in ["11", "11x", "x13", "1x13", "ax b", "11x13x2"] {
            let err = parse_grid(bad).unwrap_err();
            assert!(err.contains(bad) && err.contains("ROWSxCOLS"), "{err}");
        }
    }

    #[test]
    fn leftover_temporary_files_are_removed_and_outputs_kept() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        std::fs::create_dir_all(out.join("frames")).unwrap();
        let leftovers = [
            ".summary.json.AbC123",
            ".replay.gif.4242.0.tmp",
            "frames/.000_t-2.000s.png.4242.3.tmp.png",
        ];
        let kept = ["metrics.csv", "frames/000_t-2.000s.png", ".hidden-notes"];
        for name in leftovers.iter().chain(&kept) {
            std::fs::write(out.join(name), "x").unwrap();
        }
        prepare_output(&out).unwrap();
        for name in leftovers {
            assert!(!out.join(name).exists(), "{name}");
        }
        for name in kept {
            assert!(out.join(name).exists(), "{name}");
        }
    }
}
