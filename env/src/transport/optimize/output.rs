//! The files of `rlpkg optimize` and their reader: `trajectory.csv` (the best command's tool
//! motion on the first package, in the robot-file format of `rlpkg data import`), `commands.csv`
//! (its actions every control interval), `costs.csv` (cost per iteration) and `summary.json` of
//! one optimisation; the `summary.json` of a library (one command per target tilt); `mpc.json` of
//! receding-horizon control. [`OptimizedCommand::read`] reads a `summary.json` back for `rlpkg
//! eval --optimized`.

use std::path::{Path, PathBuf};

use serde::Serialize;

use super::config::OptimizeConfig;
use super::curve::{CommandLibrary, KnotCurve};
use crate::transport::OutcomeSummary;

/// One iteration's costs (risk over the packages).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct IterationCosts {
    pub iteration: usize,
    /// The distribution's mean (the first candidate).
    pub mean_candidate: f64,
    /// The iteration's lowest.
    pub best: f64,
    /// Mean over the elites.
    pub elite_mean: f64,
    /// The lowest so far.
    pub best_so_far: f64,
}

/// What one optimisation found (`summary.json` beside the config).
#[derive(Debug, Clone, Serialize)]
pub struct OptimizeSummary {
    /// The nominal package's target tilt (degrees) of a library's command.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub target_tilt_deg: Option<f64>,
    /// The risk of the initial command (iteration 0's mean).
    pub start_cost: f64,
    /// The risk of the best command found.
    pub best_cost: f64,
    /// The best command's cost on each package.
    pub best_package_costs: Vec<f64>,
    /// The best command's knots: path speed (m/s), then tilt offsets about x and z (rad).
    pub best_knots: Vec<f64>,
    /// Simulated time the best command's episode on the first package took (s).
    pub episode_time_s: f64,
    pub iterations: Vec<IterationCosts>,
}

/// The tool at one control step of a rollout (world frame, SI).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToolSample {
    /// Time since the episode's start (s).
    pub time_s: f64,
    /// Tool-point position (m).
    pub position: [f64; 3],
    /// Orientation (x, y, z, w).
    pub orientation: [f64; 4],
    /// Linear velocity (m/s).
    pub velocity: [f64; 3],
    /// Angular velocity (rad/s).
    pub angular_velocity: [f64; 3],
}
/// What one optimisation found, and how long it took.
#[derive(Debug, Clone)]
pub struct OpenLoopResult {
    pub summary: OptimizeSummary,
    pub curve: KnotCurve,
    /// The best command's tool motion on the first package.
    pub trace: Vec<ToolSample>,
    pub control_interval_s: f64,
    /// Wall time to settle the packages (s).
    pub setup_s: f64,
    /// Wall time of the iterations (s).
    pub optimise_s: f64,
}

/// The files of one optimisation, in the order they are moved into place (`summary.json` last:
/// a folder with it holds the others).
pub const OUTPUT_FILES: [&str; 5] = [
    "trajectory.csv",
    "commands.csv",
    "costs.csv",
    "costs.png",
    "summary.json",
];

impl OpenLoopResult {
    /// `trajectory.csv`: the tool's motion as a robot trajectory file (time, position,
    /// orientation, velocity, angular velocity, and acceleration by central differences of the
    /// velocity).
    pub fn trajectory_csv(&self) -> String {
        let (trace, dt) = (&self.trace, self.control_interval_s);
        let mut text = rlpkg_mocap::robot::ROBOT_HEADER.join(",") + "\n";
        let n = trace.len();
        for (k, s) in trace.iter().enumerate() {
            let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
            let span = (b - a).max(1) as f64 * dt;
            let acc: [f64; 3] =
                std::array::from_fn(|i| (trace[b].velocity[i] - trace[a].velocity[i]) / span);
            let values: Vec<String> = [s.time_s]
                .iter()
                .chain(&s.position)
                .chain(&s.orientation)
                .chain(&s.velocity)
                .chain(&s.angular_velocity)
                .chain(&acc)
                .map(|v| format!("{v:.9}"))
                .collect();
            text += &values.join(",");
            text += "\n";
        }
        text
    }

    /// `commands.csv`: the best command's actions at every control step of its episode.
    pub fn commands_csv(&self) -> String {
        let mut commands =
            String::from("time_s,path_speed_m_s,tilt_offset_x_rad,tilt_offset_z_rad\n");
        for sample in &self.trace[..self.trace.len() - 1] {
            let [v, x, z] = self.curve.actions(&self.summary.best_knots, sample.time_s);
            commands += &format!("{:.4},{v:.9},{x:.9},{z:.9}\n", sample.time_s);
        }
        commands
    }

    /// `costs.csv`: the costs of every iteration.
    pub fn costs_csv(&self) -> String {
        let mut costs = String::from("iteration,mean_candidate,best,elite_mean,best_so_far\n");
        for r in &self.summary.iterations {
            costs += &format!(
                "{},{:.9},{:.9},{:.9},{:.9}\n",
                r.iteration, r.mean_candidate, r.best, r.elite_mean, r.best_so_far
            );
        }
        costs
    }

    /// `summary.json`: `config` as written, then the summary.
    pub fn summary_json(&self, config: &OptimizeConfig) -> String {
        #[derive(Serialize)]
        struct WithConfig<'a> {
            config: &'a OptimizeConfig,
            #[serde(flatten)]
            summary: &'a OptimizeSummary,
        }
        serde_json::to_string_pretty(&WithConfig {
            config,
            summary: &self.summary,
        })
        .expect("plain data serialises")
    }

    /// The library entry of this command, optimised for `target_tilt_deg` and written to
    /// `folder` (relative to the library's).
    pub fn library_entry(&self, target_tilt_deg: f64, folder: String) -> LibraryEntry {
        let s = &self.summary;
        LibraryEntry {
            target_tilt_deg,
            folder,
            start_cost: s.start_cost,
            best_cost: s.best_cost,
            best_knots: s.best_knots.clone(),
            episode_time_s: s.episode_time_s,
            wall_s: self.setup_s + self.optimise_s,
        }
    }
}

/// One command of a library (`summary.json` of a library's folder lists them).
#[derive(Debug, Clone, Serialize)]
pub struct LibraryEntry {
    pub target_tilt_deg: f64,
    /// Its folder, relative to the library's.
    pub folder: String,
    pub start_cost: f64,
    pub best_cost: f64,
    pub best_knots: Vec<f64>,
    pub episode_time_s: f64,
    /// Wall time of its optimisation (s).
    pub wall_s: f64,
}

/// `summary.json` of a library: `config` as written, then its commands.
pub fn library_summary_json(config: &OptimizeConfig, library: &[LibraryEntry]) -> String {
    #[derive(Serialize)]
    struct LibrarySummary<'a> {
        config: &'a OptimizeConfig,
        library: &'a [LibraryEntry],
    }
    serde_json::to_string_pretty(&LibrarySummary { config, library })
        .expect("plain data serialises")
}

/// The episodes of the `[conditions]` packages under receding-horizon control, and what planning
/// cost.
#[derive(Debug, Clone)]
pub struct MpcRun {
    /// The K episodes' outcome.
    pub outcome: OutcomeSummary,
    /// Control steps planned (over all episodes of the batch).
    pub control_steps: usize,
    pub control_interval_s: f64,
    /// Wall time of the planning (s).
    pub planning_s: f64,
    /// Wall time per control step of one episode (s): the batch's planning time over the
    /// episode-steps it planned.
    pub wall_per_control_step_s: f64,
}

impl MpcRun {
    /// How many times slower than real time the loop runs (wall per control step over the
    /// control interval).
    pub fn real_time_factor(&self) -> f64 {
        self.wall_per_control_step_s / self.control_interval_s
    }

    /// `mpc.json`: `config` as written, then the run.
    pub fn summary_json(&self, config: &OptimizeConfig) -> String {
        #[derive(Serialize)]
        struct MpcSummary<'a> {
            config: &'a OptimizeConfig,
            outcome: &'a OutcomeSummary,
            control_steps: usize,
            control_interval_s: f64,
            wall_per_control_step_s: f64,
            real_time_factor: f64,
        }
        serde_json::to_string_pretty(&MpcSummary {
            config,
            outcome: &self.outcome,
            control_steps: self.control_steps,
            control_interval_s: self.control_interval_s,
            wall_per_control_step_s: self.wall_per_control_step_s,
            real_time_factor: self.real_time_factor(),
        })
        .expect("plain data serialises")
    }
}

/// Why an `rlpkg optimize` output folder cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum OptimizedReadError {
    /// Its `summary.json` cannot be read.
    #[error("cannot read {}: {source}; expected an `rlpkg optimize` output folder", file.display())]
    Read {
        file: PathBuf,
        source: std::io::Error,
    },
    /// Its `summary.json` is not JSON or lacks a value (the message names the file and key).
    #[error("{0}")]
    Malformed(String),
}

/// The best open-loop command of an `rlpkg optimize` output folder (its `summary.json`), or
/// the commands of a library (one per target tilt, for the nominal package).
#[derive(Debug, Clone, Serialize)]
pub struct OptimizedCommand {
    /// The row's driver name: `optimized <folder name>`.
    pub driver: String,
    pub folder: PathBuf,
    /// `[conditions]` of the optimisation: the seed of its packages and how many (K).
    pub seed: u64,
    pub packages: u64,
    /// A library's target tilts (degrees); empty for one command.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub target_tilts_deg: Vec<f64>,
    /// Its risk (cost) on its own packages (a library's: the mean over its commands).
    pub best_cost: f64,
    #[serde(skip)]
    pub library: CommandLibrary,
}

impl OptimizedCommand {
    /// Reads the best command of the `rlpkg optimize` output `folder`, or its library's
    /// commands.
    pub fn read(folder: &Path) -> Result<Self, OptimizedReadError> {
        let file = folder.join("summary.json");
        let text = std::fs::read_to_string(&file).map_err(|source| OptimizedReadError::Read {
            file: file.clone(),
            source,
        })?;
        let summary: serde_json::Value = serde_json::from_str(&text).map_err(|e| {
            OptimizedReadError::Malformed(format!("{}: {e}; expected JSON", file.display()))
        })?;
        let get = |key: &str| summary.pointer(&format!("/{}", key.replace('.', "/")));
        let bad = |key: &str, expected: &str| {
            let found = get(key).map_or("missing".into(), |v| v.to_string());
            OptimizedReadError::Malformed(format!(
                "{}: `{key}` is {found}; expected {expected}",
                file.display()
            ))
        };
        let count = get("config.knots.count")
            .and_then(serde_json::Value::as_u64)
            .filter(|&n| (2..=1000).contains(&n))
            .ok_or_else(|| bad("config.knots.count", "an integer in [2, 1000]"))?;
        let horizon_s = get("config.knots.horizon_s")
            .and_then(serde_json::Value::as_f64)
            .filter(|h| h.is_finite() && *h > 0.0)
            .ok_or_else(|| bad("config.knots.horizon_s", "a time > 0 s"))?;
        let curve = KnotCurve {
            knots: count as usize,
            horizon_s,
        };
        let knots_at = |key: &str| {
            get(key)
                .and_then(serde_json::Value::as_array)
                .map(|values| {
                    values
                        .iter()
                        .filter_map(serde_json::Value::as_f64)
                        .collect::<Vec<_>>()
                })
                .filter(|k: &Vec<f64>| {
                    k.len() == curve.dimension() && k.iter().all(|v| v.is_finite())
                })
                .ok_or_else(|| {
                    bad(
                        key,
                        &format!(
                            "{} finite numbers (3 x config.knots.count)",
                            curve.dimension()
                        ),
                    )
                })
        };
        let number = |key: &str, expected: &str| {
            get(key)
                .and_then(serde_json::Value::as_f64)
                .filter(|v| v.is_finite())
                .ok_or_else(|| bad(key, expected))
        };
        let (commands, target_tilts_deg, best_cost) =
            match get("library").and_then(serde_json::Value::as_array) {
                Some(entries) if !entries.is_empty() => {
                    let (mut commands, mut tilts) = (Vec::new(), Vec::new());
                    let mut cost = 0.0;
                    for i in 0..entries.len() {
                        let tilt =
                            number(&format!("library.{i}.target_tilt_deg"), "a tilt in degrees")?;
                        let knots = knots_at(&format!("library.{i}.best_knots"))?;
                        commands.push((tilt.to_radians(), knots));
                        tilts.push(tilt);
                        cost += number(&format!("library.{i}.best_cost"), "a number")?;
                    }
                    (commands, tilts, cost / entries.len() as f64)
                }
                Some(_) => return Err(bad("library", "at least one command")),
                None => (
                    vec![(0.0, knots_at("best_knots")?)],
                    Vec::new(),
                    number("best_cost", "a number")?,
                ),
            };
        let integer = |key: &str, expected: &str| {
            get(key)
                .and_then(serde_json::Value::as_u64)
                .ok_or_else(|| bad(key, expected))
        };
        let name = folder.file_name().map_or_else(
            || folder.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        Ok(OptimizedCommand {
            driver: format!("optimized {name}"),
            folder: folder.to_path_buf(),
            seed: integer("config.conditions.seed", "an integer >= 0")?,
            packages: integer("config.conditions.packages", "an integer >= 1")?,
            target_tilts_deg,
            best_cost,
            library: CommandLibrary { curve, commands },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config() -> OptimizeConfig {
        toml::from_str(
            r#"
transport = "configs/train/transport.toml"
out_dir = "runs/optimize"
[conditions]
seed = 7
packages = 2
[cem]
population = 4
elites = 2
iterations = 1
smoothing = 1.0
seed = 0
[knots]
count = 2
horizon_s = 3.0
initial_speed_m_s = 0.3
speed_std_m_s = 0.1
tilt_std_deg = 2.0
"#,
        )
        .unwrap()
    }

    /// A result of 2 knots per action whose best cost is `cost`.
    fn found(cost: f64) -> OpenLoopResult {
        let sample = |time_s: f64| ToolSample {
            time_s,
            position: [time_s, 0.0, 0.0],
            orientation: [0.0, 0.0, 0.0, 1.0],
            velocity: [1.0, 0.0, 0.0],
            angular_velocity: [0.0; 3],
        };
        OpenLoopResult {
            summary: OptimizeSummary {
                target_tilt_deg: None,
                start_cost: cost + 1.0,
                best_cost: cost,
                best_package_costs: vec![cost, cost],
                best_knots: vec![0.3, 0.4, 0.0, 0.01, 0.0, -0.01],
                episode_time_s: 0.1,
                iterations: Vec::new(),
            },
            curve: KnotCurve {
                knots: 2,
                horizon_s: 3.0,
            },
            trace: vec![sample(0.0), sample(0.05), sample(0.1)],
            control_interval_s: 0.05,
            setup_s: 0.0,
            optimise_s: 0.0,
        }
    }

    /// A fresh folder under the system's temporary one.
    fn folder(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("rlpkg-env-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn a_summary_reads_back_as_the_command_it_holds() {
        let dir = folder("one-command");
        let written = found(-2.5);
        std::fs::write(dir.join("summary.json"), written.summary_json(&config())).unwrap();
        let read = OptimizedCommand::read(&dir).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!((read.seed, read.packages, read.best_cost), (7, 2, -2.5));
        assert_eq!(read.library.curve, written.curve);
        assert_eq!(read.library.knots_for(0.3), written.summary.best_knots);
        assert!(read.target_tilts_deg.is_empty());
        assert!(read.driver.starts_with("optimized rlpkg-env-one-command"));
    }

    #[test]
    fn a_library_reads_back_with_its_tilts_and_mean_cost() {
        let dir = folder("library");
        let entries = [
            found(-1.0).library_entry(30.0, "tilt-30".into()),
            found(-3.0).library_entry(60.0, "tilt-60".into()),
        ];
        std::fs::write(
            dir.join("summary.json"),
            library_summary_json(&config(), &entries),
        )
        .unwrap();
        let read = OptimizedCommand::read(&dir).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(read.target_tilts_deg, [30.0, 60.0]);
        assert_eq!(read.best_cost, -2.0);
        assert_eq!(read.library.commands[1].0, 60f64.to_radians());
    }

    #[test]
    fn a_summary_without_knots_names_the_key() {
        let dir = folder("no-knots");
        let mut json: serde_json::Value =
            serde_json::from_str(&found(0.0).summary_json(&config())).unwrap();
        json.as_object_mut().unwrap().remove("best_knots");
        std::fs::write(dir.join("summary.json"), json.to_string()).unwrap();
        let err = OptimizedCommand::read(&dir).unwrap_err();
        assert!(matches!(err, OptimizedReadError::Malformed(_)), "{err}");
        let missing = OptimizedCommand::read(&dir.join("absent")).unwrap_err();
        std::fs::remove_dir_all(&dir).unwrap();
        assert!(err.to_string().contains("`best_knots` is missing"), "{err}");
        assert!(
            matches!(missing, OptimizedReadError::Read { .. }),
            "{missing}"
        );
    }

    #[test]
    fn the_files_hold_one_row_per_control_step_and_iteration() {
        let written = found(0.0);
        // Header, then every sample of the trace; the commands stop at the last step.
        assert_eq!(written.trajectory_csv().lines().count(), 1 + 3);
        assert_eq!(written.commands_csv().lines().count(), 1 + 2);
        assert_eq!(written.costs_csv().lines().count(), 1);
        assert!(written
            .commands_csv()
            .lines()
            .nth(1)
            .unwrap()
            .starts_with("0.0000,0.3"));
    }
}
