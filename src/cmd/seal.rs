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

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::{Args, Subcommand};
use rlpkg_mocap::{Dataset, DetachmentConfig, DetachmentScan, Split};
use rlpkg_replay::seal::{margins, observed_detachment, pick, score, seal_replays, SealCapacity};
use rlpkg_replay::Target;
use rlpkg_sim::SceneConfig;
use serde::Deserialize;

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

/// The seal fit config.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FitConfig {
    /// Imported dataset folder (manifest.toml with the failure flags).
    dataset: PathBuf,
    /// Scene config TOML whose `[seal]` is fitted.
    scene: PathBuf,
    /// Output folder.
    out: PathBuf,
    /// Replay only the first seconds of each take (tests); all when absent.
    max_seconds: Option<f64>,
    grid: GridConfig,
    #[serde(default)]
    detachment: DetachmentConfig,
}

/// The capacities searched: the product of the two axes.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct GridConfig {
    vacuum_kpa: Axis,
    /// The scene's value when absent.
    lip_strength_ratio: Option<Axis>,
}

/// `steps` values evenly spaced from `min` to `max` (`min` alone when `steps` = 1).
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
struct Axis {
    min: f64,
    max: f64,
    steps: usize,
}

/// More capacities than this are a typo, not a search (each is a replay of the whole dataset).
const MAX_STEPS: usize = 1000;

impl Axis {
    fn values(&self) -> Vec<f64> {
        if self.steps == 1 {
            return vec![self.min];
        }
        (0..self.steps)
            .map(|i| self.min + (self.max - self.min) * i as f64 / (self.steps - 1) as f64)
            .collect()
    }

    fn check(&self, file: &Path, key: &str) -> anyhow::Result<()> {
        let bad = |field: &str, value: String, expected: &str| {
            Err(input_error(format!(
                "{}: key `{key}.{field}` = {value}: expected {expected}",
                file.display()
            )))
        };
        if !(self.min.is_finite() && self.min > 0.0) {
            return bad("min", self.min.to_string(), "a positive number");
        }
        if !(self.max.is_finite() && self.max >= self.min) {
            return bad("max", self.max.to_string(), "a number at least `min`");
        }
        if !(1..=MAX_STEPS).contains(&self.steps) {
            return bad(
                "steps",
                self.steps.to_string(),
                &format!("a whole number from 1 to {MAX_STEPS}"),
            );
        }
        Ok(())
    }
}

impl FitConfig {
    fn load(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path)
            .map_err(|err| input_error(format!("{}: {err}", path.display())))?;
        // The TOML error names the line and, for an unknown or missing key, the key.
        let config: FitConfig = toml::from_str(&text).map_err(|err| {
            input_error(format!("{}: {}", path.display(), err.to_string().trim()))
        })?;
        config.check(path)?;
        Ok(config)
    }

    fn check(&self, file: &Path) -> anyhow::Result<()> {
        let bad = |key: &str, value: String, expected: &str| {
            Err(input_error(format!(
                "{}: key `{key}` = {value}: expected {expected}",
                file.display()
            )))
        };
        if let Some(s) = self.max_seconds {
            if !(s.is_finite() && s > 0.0) {
                return bad("max_seconds", s.to_string(), "a positive number of seconds");
            }
        }
        self.grid.vacuum_kpa.check(file, "grid.vacuum_kpa")?;
        if let Some(axis) = &self.grid.lip_strength_ratio {
            axis.check(file, "grid.lip_strength_ratio")?;
        }
        let steps =
            self.grid.vacuum_kpa.steps * self.grid.lip_strength_ratio.map_or(1, |axis| axis.steps);
        if steps > MAX_STEPS {
            return bad(
                "grid",
                format!("{steps} capacities"),
                &format!("at most {MAX_STEPS} (vacuum_kpa.steps x lip_strength_ratio.steps)"),
            );
        }
        let d = &self.detachment;
        for (key, value) in [
            ("detachment.reference_rise_m", d.reference_rise_m),
            ("detachment.threshold_m", d.threshold_m),
            ("detachment.cup_reach_m", d.cup_reach_m),
            ("detachment.top_layer_depth_m", d.top_layer_depth_m),
            ("detachment.max_match_m", d.max_match_m),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return bad(key, value.to_string(), "a positive length in metres");
            }
        }
        if !(d.hold_s.is_finite() && d.hold_s >= 0.0) {
            return bad(
                "detachment.hold_s",
                d.hold_s.to_string(),
                "a duration of at least 0 s",
            );
        }
        if d.markers_per_cup == 0 {
            return bad("detachment.markers_per_cup", "0".into(), "at least 1");
        }
        Ok(())
    }
}

/// One take of the dataset with what its markers show.
struct Take {
    id: String,
    split: Split,
    flagged: bool,
    observed: DetachmentScan,
}

/// The files `rlpkg seal fit` writes into its output folder.
const OUTPUT_FILES: [&str; 4] = ["candidates.csv", "takes.csv", "fit.toml", "scene.toml"];

/// The output folder and `--write-params`, checked before any replay: the folder must be one or
/// be creatable (no file in its place or above it), and `--write-params` a writable file that is
/// none of the fit's inputs (config, scene, dataset) nor one of the folder's other files.
fn check_outputs(args: &FitArgs, config: &FitConfig) -> anyhow::Result<()> {
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
    let config = FitConfig::load(&args.config)?;
    check_outputs(&args, &config)?;
    let scene = SceneConfig::load(&config.scene).map_err(input_error)?;
    let dataset = Dataset::open(&config.dataset).map_err(input_error)?;
    // The capacity is where simulated failures agree with the flags, class by class: a dataset
    // without both classes would be "fitted" at the grid's edge after replaying everything.
    let flagged = dataset.entries.iter().filter(|e| e.failure).count();
    if flagged == 0 || flagged == dataset.entries.len() {
        return Err(input_error(format!(
            "{}: {flagged} of {} takes flagged as failures (`failure` in manifest.toml); expected \
             at least one failure take and one that held (the fit compares simulated failures \
             with both)",
            config.dataset.join("manifest.toml").display(),
            dataset.entries.len()
        )));
    }
    let started = Instant::now();
    let mut takes = Vec::new();
    let mut targets = Vec::new();
    for entry in &dataset.entries {
        let trajectory = dataset.load(&entry.id).map_err(input_error)?;
        let target = Target::new(
            &trajectory,
            config.max_seconds,
            scene.disc.hold_at_recorded_start,
        )
        .map_err(input_error)?;
        let mut observed = observed_detachment(&trajectory, &scene, &config.detachment);
        // Detachment after the replayed span is not compared.
        if observed.detachment.is_some_and(|d| d.t > target.duration()) {
            observed.detachment = None;
        }
        takes.push(Take {
            id: entry.id.clone(),
            split: entry.split,
            flagged: entry.failure,
            observed,
        });
        targets.push(target);
    }
    if takes.is_empty() {
        return Err(input_error(format!(
            "{}: no takes; expected an imported dataset",
            config.dataset.display()
        )));
    }
    let vacuum = config.grid.vacuum_kpa.values();
    let ratio = config
        .grid
        .lip_strength_ratio
        .map_or(vec![f64::from(scene.seal.lip_strength_ratio)], |axis| {
            axis.values()
        });
    let mut grid = Vec::new();
    let mut capacities = Vec::new();
    for (i, &v) in vacuum.iter().enumerate() {
        for (j, &r) in ratio.iter().enumerate() {
            grid.push([i, j]);
            capacities.push(SealCapacity {
                vacuum_kpa: v as f32,
                lip_strength_ratio: r as f32,
            });
        }
    }
    let mut checked = scene.clone();
    for capacity in &capacities {
        capacity.apply_to(&mut checked);
        checked
            .validate(&args.config.display().to_string())
            .map_err(input_error)?;
    }
    println!(
        "seal fit: {} takes ({} flagged) x {} capacities ({} vacuum x {} lip strength), scene {}",
        takes.len(),
        takes.iter().filter(|t| t.flagged).count(),
        capacities.len(),
        vacuum.len(),
        ratio.len(),
        config.scene.display()
    );
    // What the markers show comes first: it needs no simulation.
    for take in &takes {
        let drift = max_held_drift_m(&take.observed);
        let seen = take.observed.detachment.map_or("none".to_string(), |d| {
            format!("cup {} at t = {:.3} s", d.cup, d.t)
        });
        println!(
            "observed {:<18} flagged {:<5} detachment {seen} (largest held drift {:.1} mm)",
            take.id,
            take.flagged,
            1e3 * drift
        );
    }
    let replays = seal_replays(&scene, &targets, &capacities).map_err(input_error)?;
    let wall_s = started.elapsed().as_secs_f64();
    let flags: Vec<bool> = takes.iter().map(|t| t.flagged).collect();
    let observed: Vec<Option<f64>> = takes
        .iter()
        .map(|t| t.observed.detachment.map(|d| d.t))
        .collect();
    let scores: Vec<_> = replays
        .iter()
        .map(|r| score(&flags, &observed, r))
        .collect();
    let best = pick(&grid, &scores).expect("at least one capacity");
    let margins = margins(&grid, &scores);

    std::fs::create_dir_all(&config.out).map_err(|err| {
        input_error(format!(
            "{}: cannot create the output folder: {err}",
            config.out.display()
        ))
    })?;
    let mut candidates_csv = String::from(
        "vacuum_kpa,lip_strength_ratio,balanced_agreement,agreement,flagged_failed,flagged_held,unflagged_failed,unflagged_held,diverged,timing_error_s,margin_steps\n",
    );
    for ((capacity, s), margin) in capacities.iter().zip(&scores).zip(&margins) {
        let c = &s.confusion;
        let _ = writeln!(
            candidates_csv,
            "{},{},{:.4},{},{},{},{},{},{},{},{}",
            capacity.vacuum_kpa,
            capacity.lip_strength_ratio,
            c.balanced_agreement(),
            c.agreement(),
            c.flagged_failed,
            c.flagged_held,
            c.unflagged_failed,
            c.unflagged_held,
            c.diverged(),
            s.timing_error_s
                .map_or(String::new(), |e| format!("{e:.4}")),
            margin
        );
    }
    let mut takes_csv = String::from(
        "take,split,flagged,observed_cup,observed_t_s,max_held_drift_mm,sim_cup,sim_mode,sim_t_s,timing_error_s,diverged\n",
    );
    let empty = String::new;
    for (take, replay) in takes.iter().zip(&replays[best]) {
        let seen = take.observed.detachment;
        let drift = max_held_drift_m(&take.observed);
        let failure = replay.failure;
        let error = seen.zip(failure).map(|(s, f)| (f.t - s.t).abs());
        let _ = writeln!(
            takes_csv,
            "{},{},{},{},{},{:.2},{},{},{},{},{}",
            take.id,
            split_name(take.split),
            take.flagged,
            seen.map_or_else(empty, |d| d.cup.to_string()),
            seen.map_or_else(empty, |d| format!("{:.3}", d.t)),
            1e3 * drift,
            failure.map_or_else(empty, |f| f.cup.to_string()),
            failure.map_or_else(empty, |f| f.mode()),
            failure.map_or_else(empty, |f| format!("{:.3}", f.t)),
            error.map_or_else(empty, |e| format!("{e:.3}")),
            replay
                .diverged
                .map_or_else(empty, |e| format!("{:?}", e.reason)),
        );
    }
    let fitted = capacities[best];
    let s = &scores[best];
    let c = &s.confusion;
    let table = format!(
        "                 | cup failed in sim | no cup failed\n\
         flagged failure  | {:>17} | {:>13}\n\
         not flagged      | {:>17} | {:>13}\n",
        c.flagged_failed, c.flagged_held, c.unflagged_failed, c.unflagged_held
    );
    let fit_toml = format!(
        "# Seal capacity fitted by `rlpkg seal fit {}` on {} takes ({} capacities, {:.1} s wall).\n\
         vacuum_kpa = {:?}\nlip_strength_ratio = {:?}\nbalanced_agreement = {:.4}\nagreement = {}\ntakes = {}\n\
         timing_error_s = {}\nmargin_steps = {}\ndiverged = {}\n\n[confusion]\n\
         flagged_failed = {}\nflagged_held = {}\nunflagged_failed = {}\nunflagged_held = {}\n",
        args.config.display(),
        takes.len(),
        capacities.len(),
        wall_s,
        fitted.vacuum_kpa,
        fitted.lip_strength_ratio,
        c.balanced_agreement(),
        c.agreement(),
        takes.len(),
        s.timing_error_s
            .map_or("nan".to_string(), |e| format!("{e:.4}")),
        if margins[best].is_finite() {
            format!("{:.1}", margins[best])
        } else {
            "inf".to_string()
        },
        c.diverged(),
        c.flagged_failed,
        c.flagged_held,
        c.unflagged_failed,
        c.unflagged_held,
    );
    let mut fitted_scene = scene.clone();
    fitted.apply_to(&mut fitted_scene);
    let scene_text = format!(
        "# {} with the seal capacity fitted by `rlpkg seal fit {}`: vacuum_kpa = {}, lip_strength_ratio = {}\n\
         # ({} of {} takes agree with their failure flags, balanced agreement {:.3}). Use with `rlpkg simulate --params <this file>`.\n\n{}",
        config.scene.display(),
        args.config.display(),
        fitted.vacuum_kpa,
        fitted.lip_strength_ratio,
        c.agreement(),
        takes.len(),
        c.balanced_agreement(),
        toml::to_string_pretty(&fitted_scene)?
    );
    for (name, text) in
        OUTPUT_FILES
            .iter()
            .zip([&candidates_csv, &takes_csv, &fit_toml, &scene_text])
    {
        write_atomic(&config.out.join(name), text.as_bytes()).map_err(output_error)?;
    }
    if let Some(path) = &args.write_params {
        write_atomic(path, scene_text.as_bytes()).map_err(output_error)?;
    }

    println!("{takes_csv}");
    println!("{table}");
    println!(
        "fitted vacuum_kpa = {}, lip_strength_ratio = {}: balanced agreement {:.3}, {} of {} takes agree, timing error {}, {} diverged ({:.1} s wall)",
        fitted.vacuum_kpa,
        fitted.lip_strength_ratio,
        c.balanced_agreement(),
        c.agreement(),
        takes.len(),
        s.timing_error_s
            .map_or("n/a".to_string(), |e| format!("{e:.3} s")),
        c.diverged(),
        wall_s
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

fn split_name(split: Split) -> &'static str {
    match split {
        Split::Train => "train",
        Split::Test => "test",
        Split::Excluded => "excluded",
    }
}

/// The largest drift (m) any cup's markers held for the scan's hold time.
fn max_held_drift_m(scan: &DetachmentScan) -> f64 {
    scan.max_held_drift_m.iter().copied().fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axes_span_their_bounds() {
        let axis = Axis {
            min: 10.0,
            max: 40.0,
            steps: 4,
        };
        assert_eq!(axis.values(), vec![10.0, 20.0, 30.0, 40.0]);
        let single = Axis {
            min: 3.0,
            max: 3.0,
            steps: 1,
        };
        assert_eq!(single.values(), vec![3.0]);
    }
}
