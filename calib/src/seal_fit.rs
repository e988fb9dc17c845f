//! The seal fit (`rlpkg seal fit CONFIG`): the suction seal's capacity (`[seal]` `vacuum_kpa`,
//! `lip_strength_ratio`) fitted to a dataset's failure flags.
//!
//! Every take (train, test and excluded) is replayed with the scene under each capacity of a grid
//! ([`rlpkg_replay::seal`]); the capacity whose simulated cup failures agree best with the flags,
//! class by class (balanced agreement: failures are rare), wins, ties going to the smaller error
//! against the detachment observed in the markers ([`rlpkg_mocap::detach`]), then to the largest
//! margin.
//!
//! This module owns the fit's config format ([`SealFitConfig`]) and the text of its outputs
//! ([`SealFit::candidates_csv`], [`SealFit::takes_csv`], [`SealFit::fit_toml`],
//! [`SealFit::scene_toml`]); the caller writes them.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use rlpkg_mocap::{Dataset, DetachmentConfig, DetachmentScan, Split};
use rlpkg_replay::seal::{
    margins, observed_detachment, pick, score, seal_replays, CapacityScore, SealCapacity,
    SealReplay,
};
use rlpkg_replay::Target;
use rlpkg_sim::SceneConfig;
use serde::Deserialize;

/// What is wrong with a seal fit's inputs: the config, its scene or its dataset (the message
/// names the file and the key or take).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct SealFitError(String);

/// The seal fit config.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SealFitConfig {
    /// Imported dataset folder (manifest.toml with the failure flags).
    pub dataset: PathBuf,
    /// Scene config TOML whose `[seal]` is fitted.
    pub scene: PathBuf,
    /// Output folder.
    pub out: PathBuf,
    /// Replay only the first seconds of each take (tests); all when absent.
    pub max_seconds: Option<f64>,
    /// The capacities searched.
    pub grid: GridConfig,
    /// How the markers show a detachment.
    #[serde(default)]
    pub detachment: DetachmentConfig,
}

/// The capacities searched: the product of the two axes.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridConfig {
    /// Vacuum gauge pressures (kPa).
    pub vacuum_kpa: Axis,
    /// Lip strength ratios; the scene's value when absent.
    pub lip_strength_ratio: Option<Axis>,
}

/// `steps` values evenly spaced from `min` to `max` (`min` alone when `steps` = 1).
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Axis {
    /// First value.
    pub min: f64,
    /// Last value.
    pub max: f64,
    /// Number of values.
    pub steps: usize,
}

/// More capacities than this are a typo, not a search (each is a replay of the whole dataset).
pub const MAX_STEPS: usize = 1000;

impl Axis {
    /// The axis's values, `min` first.
    pub fn values(&self) -> Vec<f64> {
        if self.steps == 1 {
            return vec![self.min];
        }
        (0..self.steps)
            .map(|i| self.min + (self.max - self.min) * i as f64 / (self.steps - 1) as f64)
            .collect()
    }

    fn check(&self, file: &Path, key: &str) -> Result<(), SealFitError> {
        let bad = |field: &str, value: String, expected: &str| {
            Err(SealFitError(format!(
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
        // One step would test `min` alone and silently drop `max`.
        if self.steps == 1 && self.max != self.min {
            return bad(
                "steps",
                "1".into(),
                "at least 2 for a range with max > min (or max = min for one value)",
            );
        }
        Ok(())
    }
}

impl SealFitConfig {
    /// Reads, parses and range-checks the config at `path`.
    pub fn load(path: &Path) -> Result<Self, SealFitError> {
        let text = std::fs::read_to_string(path)
            .map_err(|err| SealFitError(format!("{}: {err}", path.display())))?;
        Self::parse(&text, path)
    }

    /// Parses and range-checks config text; `file` names it in errors.
    pub fn parse(text: &str, file: &Path) -> Result<Self, SealFitError> {
        // The TOML error names the line and, for an unknown or missing key, the key.
        let config: SealFitConfig = toml::from_str(text).map_err(|err| {
            SealFitError(format!("{}: {}", file.display(), err.to_string().trim()))
        })?;
        config.check(file)?;
        Ok(config)
    }

    fn check(&self, file: &Path) -> Result<(), SealFitError> {
        let bad = |key: &str, value: String, expected: &str| {
            Err(SealFitError(format!(
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
#[derive(Debug, Clone)]
pub struct ObservedTake {
    /// Take id.
    pub id: String,
    /// Its split.
    pub split: Split,
    /// Flagged as a failure in the manifest.
    pub flagged: bool,
    /// The detachment its markers show within the replayed span.
    pub observed: DetachmentScan,
}

impl ObservedTake {
    /// The largest drift (m) any cup's markers held for the scan's hold time.
    pub fn max_held_drift_m(&self) -> f64 {
        self.observed
            .max_held_drift_m
            .iter()
            .copied()
            .fold(0.0, f64::max)
    }
}

/// A fit set up: the scene, the takes with what their markers show, the capacities of the grid;
/// nothing replayed yet ([`SealFitPlan::run`]).
pub struct SealFitPlan {
    /// The scene whose `[seal]` is fitted.
    pub scene: SceneConfig,
    /// The takes, in the manifest's order.
    pub takes: Vec<ObservedTake>,
    /// The capacities, lip strength ratio varying fastest.
    pub capacities: Vec<SealCapacity>,
    /// Values along the vacuum axis.
    pub vacuum_steps: usize,
    /// Values along the lip strength axis.
    pub lip_strength_steps: usize,
    targets: Vec<Target>,
    /// Each capacity's index along the two axes.
    grid: Vec<[usize; 2]>,
    started: Instant,
}

impl SealFitPlan {
    /// Loads `config`'s scene and dataset (`config_file` names the config in messages), reads
    /// every take's detachment from its markers and checks every capacity in the scene.
    pub fn new(config: &SealFitConfig, config_file: &Path) -> Result<Self, SealFitError> {
        let input = |err: &dyn std::fmt::Display| SealFitError(err.to_string());
        let scene = SceneConfig::load(&config.scene).map_err(|e| input(&e))?;
        let dataset = Dataset::open(&config.dataset).map_err(|e| input(&e))?;
        // The capacity is where simulated failures agree with the flags, class by class: a
        // dataset without both classes would be "fitted" at the grid's edge after replaying
        // everything.
        let flagged = dataset.entries.iter().filter(|e| e.failure).count();
        if flagged == 0 || flagged == dataset.entries.len() {
            return Err(SealFitError(format!(
                "{}: {flagged} of {} takes flagged as failures (`failure` in manifest.toml); \
                 expected at least one failure take and one that held (the fit compares \
                 simulated failures with both)",
                config.dataset.join("manifest.toml").display(),
                dataset.entries.len()
            )));
        }
        let started = Instant::now();
        let mut takes = Vec::new();
        let mut targets = Vec::new();
        for entry in &dataset.entries {
            let trajectory = dataset.load(&entry.id).map_err(|e| input(&e))?;
            let target = Target::new(
                &trajectory,
                config.max_seconds,
                scene.disc.hold_at_recorded_start,
            )
            .map_err(|e| input(&e))?;
            let mut observed = observed_detachment(&trajectory, &scene, &config.detachment);
            // Detachment after the replayed span is not compared.
            if observed.detachment.is_some_and(|d| d.t > target.duration()) {
                observed.detachment = None;
            }
            takes.push(ObservedTake {
                id: entry.id.clone(),
                split: entry.split,
                flagged: entry.failure,
                observed,
            });
            targets.push(target);
        }
        if takes.is_empty() {
            return Err(SealFitError(format!(
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
                .validate(&config_file.display().to_string())
                .map_err(|e| input(&e))?;
        }
        Ok(Self {
            scene,
            takes,
            capacities,
            vacuum_steps: vacuum.len(),
            lip_strength_steps: ratio.len(),
            targets,
            grid,
            started,
        })
    }

    /// Replays every take under every capacity (in parallel) and picks the best capacity.
    pub fn run(self) -> Result<SealFit, SealFitError> {
        let replays = seal_replays(&self.scene, &self.targets, &self.capacities)
            .map_err(|e| SealFitError(e.to_string()))?;
        let wall_s = self.started.elapsed().as_secs_f64();
        let flags: Vec<bool> = self.takes.iter().map(|t| t.flagged).collect();
        let observed: Vec<Option<f64>> = self
            .takes
            .iter()
            .map(|t| t.observed.detachment.map(|d| d.t))
            .collect();
        let scores: Vec<CapacityScore> = replays
            .iter()
            .map(|r| score(&flags, &observed, r))
            .collect();
        let best = pick(&self.grid, &scores).expect("at least one capacity");
        let margins = margins(&self.grid, &scores);
        Ok(SealFit {
            best_replays: replays[best].clone(),
            scene: self.scene,
            takes: self.takes,
            capacities: self.capacities,
            scores,
            margins,
            best,
            wall_s,
        })
    }
}

/// A fitted seal: every capacity's score and the best one's replays.
pub struct SealFit {
    /// The scene as loaded (its own `[seal]`).
    pub scene: SceneConfig,
    /// The takes, in the manifest's order.
    pub takes: Vec<ObservedTake>,
    /// Every capacity of the grid.
    pub capacities: Vec<SealCapacity>,
    /// Each capacity's score.
    pub scores: Vec<CapacityScore>,
    /// Each capacity's margin in grid steps ([`margins`]).
    pub margins: Vec<f64>,
    /// Index of the fitted capacity.
    pub best: usize,
    /// Per take, its replay under the fitted capacity.
    pub best_replays: Vec<SealReplay>,
    /// Wall time of reading the takes and replaying them (s).
    pub wall_s: f64,
}

impl SealFit {
    /// The fitted capacity.
    pub fn fitted(&self) -> SealCapacity {
        self.capacities[self.best]
    }

    /// The fitted capacity's score.
    pub fn fitted_score(&self) -> &CapacityScore {
        &self.scores[self.best]
    }

    /// `candidates.csv`: every capacity's balanced and raw agreement, confusion cells, timing
    /// error and margin.
    pub fn candidates_csv(&self) -> String {
        let mut csv = String::from(
            "vacuum_kpa,lip_strength_ratio,balanced_agreement,agreement,flagged_failed,flagged_held,unflagged_failed,unflagged_held,diverged,timing_error_s,margin_steps\n",
        );
        for ((capacity, s), margin) in self.capacities.iter().zip(&self.scores).zip(&self.margins) {
            let c = &s.confusion;
            let _ = writeln!(
                csv,
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
        csv
    }

    /// `takes.csv`: per take under the fitted capacity, its flag, observed detachment, simulated
    /// failure and timing error.
    pub fn takes_csv(&self) -> String {
        let mut csv = String::from(
            "take,split,flagged,observed_cup,observed_t_s,max_held_drift_mm,sim_cup,sim_mode,sim_t_s,timing_error_s,diverged\n",
        );
        let empty = String::new;
        for (take, replay) in self.takes.iter().zip(&self.best_replays) {
            let seen = take.observed.detachment;
            let failure = replay.failure;
            let error = seen.zip(failure).map(|(s, f)| (f.t - s.t).abs());
            let _ = writeln!(
                csv,
                "{},{},{},{},{},{:.2},{},{},{},{},{}",
                take.id,
                take.split.name(),
                take.flagged,
                seen.map_or_else(empty, |d| d.cup.to_string()),
                seen.map_or_else(empty, |d| format!("{:.3}", d.t)),
                1e3 * take.max_held_drift_m(),
                failure.map_or_else(empty, |f| f.cup.to_string()),
                failure.map_or_else(empty, |f| f.mode()),
                failure.map_or_else(empty, |f| format!("{:.3}", f.t)),
                error.map_or_else(empty, |e| format!("{e:.3}")),
                replay
                    .diverged
                    .map_or_else(empty, |e| format!("{:?}", e.reason)),
            );
        }
        csv
    }

    /// The fitted capacity's 2 x 2 table of flags against simulated failures.
    pub fn confusion_table(&self) -> String {
        let c = &self.fitted_score().confusion;
        format!(
            "                 | cup failed in sim | no cup failed\n\
             flagged failure  | {:>17} | {:>13}\n\
             not flagged      | {:>17} | {:>13}\n",
            c.flagged_failed, c.flagged_held, c.unflagged_failed, c.unflagged_held
        )
    }

    /// `fit.toml`: the fitted values, confusion table and timing error; `config_file` is the
    /// config named in its header.
    pub fn fit_toml(&self, config_file: &Path) -> String {
        let fitted = self.fitted();
        let s = self.fitted_score();
        let c = &s.confusion;
        let margin = self.margins[self.best];
        format!(
            "# Seal capacity fitted by `rlpkg seal fit {}` on {} takes ({} capacities, {:.1} s wall).\n\
             vacuum_kpa = {:?}\nlip_strength_ratio = {:?}\nbalanced_agreement = {:.4}\nagreement = {}\ntakes = {}\n\
             timing_error_s = {}\nmargin_steps = {}\ndiverged = {}\n\n[confusion]\n\
             flagged_failed = {}\nflagged_held = {}\nunflagged_failed = {}\nunflagged_held = {}\n",
            config_file.display(),
            self.takes.len(),
            self.capacities.len(),
            self.wall_s,
            fitted.vacuum_kpa,
            fitted.lip_strength_ratio,
            c.balanced_agreement(),
            c.agreement(),
            self.takes.len(),
            s.timing_error_s
                .map_or("nan".to_string(), |e| format!("{e:.4}")),
            if margin.is_finite() {
                format!("{margin:.1}")
            } else {
                "inf".to_string()
            },
            c.diverged(),
            c.flagged_failed,
            c.flagged_held,
            c.unflagged_failed,
            c.unflagged_held,
        )
    }

    /// `scene.toml`: the scene (loaded from `scene_file`) with the fitted `[seal]`, headed by how
    /// it was fitted (`config_file`).
    pub fn scene_toml(
        &self,
        scene_file: &Path,
        config_file: &Path,
    ) -> Result<String, toml::ser::Error> {
        let fitted = self.fitted();
        let c = &self.fitted_score().confusion;
        let mut fitted_scene = self.scene.clone();
        fitted.apply_to(&mut fitted_scene);
        Ok(format!(
            "# {} with the seal capacity fitted by `rlpkg seal fit {}`: vacuum_kpa = {}, lip_strength_ratio = {}\n\
             # ({} of {} takes agree with their failure flags, balanced agreement {:.3}). Use with `rlpkg simulate --params <this file>`.\n\n{}",
            scene_file.display(),
            config_file.display(),
            fitted.vacuum_kpa,
            fitted.lip_strength_ratio,
            c.agreement(),
            self.takes.len(),
            c.balanced_agreement(),
            toml::to_string_pretty(&fitted_scene)?
        ))
    }
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

    const GOOD: &str = "dataset = \"d\"\nscene = \"s.toml\"\nout = \"o\"\n\n[grid]\n\
                        vacuum_kpa = { min = 5.0, max = 30.0, steps = 3 }\n";

    fn parse(text: &str) -> Result<SealFitConfig, SealFitError> {
        SealFitConfig::parse(text, Path::new("seal.toml"))
    }

    #[test]
    fn configs_are_range_checked_naming_the_key() {
        let config = parse(GOOD).unwrap();
        assert_eq!(config.grid.vacuum_kpa.values(), vec![5.0, 17.5, 30.0]);
        assert!(config.grid.lip_strength_ratio.is_none());
        for (text, key) in [
            (
                GOOD.replace("steps = 3", "steps = 0"),
                "grid.vacuum_kpa.steps",
            ),
            (
                GOOD.replace("max = 30.0", "max = 1.0"),
                "grid.vacuum_kpa.max",
            ),
            (
                GOOD.to_string() + "lip_strength_ratio = { min = 1.0, max = 2.0, steps = 400 }\n",
                "`grid` = 1200 capacities",
            ),
            (
                GOOD.to_string() + "\n[detachment]\nhold_s = -1.0\n",
                "detachment.hold_s",
            ),
            (GOOD.replace("out = \"o\"\n", ""), "`out`"),
        ] {
            let err = parse(&text).unwrap_err().to_string();
            assert!(
                err.starts_with("seal.toml: ") && err.contains(key),
                "{key}: {err}"
            );
        }
    }

    #[test]
    fn a_dataset_without_both_classes_is_refused_before_any_replay() {
        // The study's recordings carry no failure flag: nothing to compare simulated failures with.
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let config = parse(GOOD).map(|c| SealFitConfig {
            dataset: root.join("data/deformable-sim-real"),
            scene: root.join("configs/scenes/physical-soft-film.toml"),
            ..c
        });
        let err = SealFitPlan::new(&config.unwrap(), Path::new("seal.toml"))
            .err()
            .expect("refused")
            .to_string();
        assert!(
            err.contains("manifest.toml: 0 of") && err.contains("flagged as failures"),
            "{err}"
        );
    }
}
