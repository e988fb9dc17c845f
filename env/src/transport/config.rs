//! The `[transport]` table of a training configuration (`configs/train/transport.toml`): scene, paths
//! from the recordings, control rate, limits, success tolerances, reward weights and domain
//! randomisation. Every key is required unless said otherwise; unknown keys and out-of-range
//! values are rejected with the file, the key and what was expected. [`load_scene`] resolves the
//! scene the table names.

use std::path::Path;
use std::sync::Arc;

use rlpkg_calib::posterior_files::{self, Samples};
use rlpkg_sim::{Randomization, SceneConfig, ToolLimits};
use serde::{Deserialize, Serialize};

use super::path::ToolPeaks;
use super::sensors::{SensorConfig, MAX_DELAY_STEPS, MAX_HISTORY_STEPS};
use crate::EnvError;

/// The whole `[transport]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransportConfig {
    /// Scene file (e.g. `configs/scenes/physical-explicit.toml`) or preset name (`physical`); needs SI masses
    /// and the seal model on.
    pub scene: String,
    /// Package grid `[rows, columns]` (overrides the scene's; coarse grids train faster).
    #[serde(deserialize_with = "rlpkg_toml_input::array")]
    pub grid: [usize; 2],
    /// Folder of the recordings (`data/deformable-sim-real`).
    pub recordings: String,
    /// Recordings whose tool paths the episodes follow; each episode takes the one whose final
    /// tilt is nearest its target tilt.
    pub paths: Vec<String>,
    /// Control rate (Hz): one action per `1 / control_hz` seconds.
    pub control_hz: f64,
    /// Episodes are truncated after this long (s).
    pub time_limit_s: f64,
    /// Settled package states built at each `reset(seed)` (see [`TransportRandomization`]).
    pub settled_variants: usize,
    /// Extra settling after the scene's rest period before the snapshot is taken (s).
    pub settle_s: f64,
    /// The cell's grasp check (optional), as a vacuum switch confirms a pick before the move: a
    /// settled package counts as grasped only if every cup holds at least this fraction of the
    /// supply vacuum under the sensors' leak model ([`super::sensors::cup_vacuum_pa`]: 0.98 for a
    /// sound, unloaded seal, about 0.75 at the failure load); a package below it is replaced by
    /// the unrandomised one, as an unsealed one is. In [0.5, 0.98].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grasp_min_vacuum_ratio: Option<f64>,
    /// Limits of the action and of the robot.
    pub limits: TransportLimits,
    /// When an episode counts as a success.
    pub success: SuccessTolerances,
    /// When an episode counts as a failure besides seal and health events.
    pub failure: FailureLimits,
    /// Reward weights.
    pub reward: RewardWeights,
    /// Domain randomisation.
    pub randomization: TransportRandomization,
    /// What the actor observes (optional; default `"privileged"`).
    #[serde(default, skip_serializing_if = "ObservationMode::is_privileged")]
    pub observation: ObservationMode,
    /// The cell's sensors: required with `observation = "sensors"`, refused otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sensors: Option<SensorConfig>,
    /// With this table the first action is the rate of a motion profile's clock instead of the
    /// path speed (optional; see [`ProfileRateAction`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub profile_rate: Option<ProfileRateAction>,
}

/// `[transport.profile_rate]`: the policy plays a time-optimal, jerk-limited motion profile along
/// each episode's path (planned at the episode's start under the tool's limits times
/// `limits_scale`, the tilt following the minimum-jerk schedule) and its first action is the
/// rate of the profile's clock: 1 plays the plan as planned, 0 holds the reference, 2 plays it
/// twice as fast. The result still goes through the path speed's clamps. Training starts from
/// the profile's careful driving and may speed it up or slow it down per package.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProfileRateAction {
    /// The plan's limits as a multiple of the tool's (`[transport.limits]`), in (0, 3]. Above 1
    /// the plan asks for more than the tool gives and the path speed's clamps shape it, as they
    /// shape the profile baseline's rows above x1.
    pub limits_scale: f64,
    /// Largest rate of the profile's clock, in [1, 4].
    pub max_rate: f64,
    /// Largest change of the rate per second (1/s): the clock speeds up and slows down smoothly.
    pub max_rate_change_per_s: f64,
}

/// What the actor observes (`transport.observation`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ObservationMode {
    /// The simulator's exact tool state and each cup's utilisation (load over capacity), which no
    /// real sensor measures.
    #[default]
    Privileged,
    /// Only what a real cell measures, with noise and delay (`[transport.sensors]`); the critic
    /// keeps the exact, privileged state.
    Sensors,
}

impl ObservationMode {
    /// Whether this is the default, [`ObservationMode::Privileged`].
    pub fn is_privileged(&self) -> bool {
        *self == ObservationMode::Privileged
    }
}

/// Bounds of the action and of the robot carrying the tool (SI).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransportLimits {
    /// Largest speed along the path (m/s); at most 1.5 x the high-velocity recordings' peak
    /// tool speed (0.63 m/s).
    pub max_path_speed_m_s: f64,
    /// Largest change of the path speed per second (m/s²); at most 1.5 x the recordings' peak
    /// tool acceleration (3.47 m/s²).
    pub max_path_accel_m_s2: f64,
    /// Largest tilt of the tool away from the path's nominal orientation, about world x and z
    /// (degrees).
    pub max_tilt_offset_deg: f64,
    /// Distance before the path's end over which the largest tilt offset shrinks linearly to
    /// zero (m; optional, in [0.001, 1]): the tool arrives at the place orientation whatever the
    /// policy asks, and its tilting stops stirring the object once it is there.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tilt_offset_fade_m: Option<f64>,
    /// The robot's largest angular speed (rad/s); at most 1.5 x the recordings' peak (2.07 rad/s).
    pub max_angular_speed_rad_s: f64,
    /// The robot's largest angular acceleration (rad/s²).
    pub max_angular_accel_rad_s2: f64,
    /// Fraction of the predicted pose error the tracking controller removes per control
    /// interval, in (0, 1].
    pub tracking_gain: f64,
}

/// Tolerances at the place pose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SuccessTolerances {
    /// Tool within this distance of the place position (m).
    pub position_m: f64,
    /// Tool orientation within this angle of the place orientation (degrees).
    pub orientation_deg: f64,
    /// Tool slower than this (m/s).
    pub tool_speed_m_s: f64,
    /// Object slower than this relative to the tool (m/s): it has settled.
    pub object_speed_m_s: f64,
}

/// Failures besides the seal model's events and health freezes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FailureLimits {
    /// The package counts as dropped when the object is further than this from the tool (m).
    pub max_object_distance_m: f64,
}

/// Reward weights; every term is reported separately (see [`super::RewardTerms`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RewardWeights {
    /// Per path length travelled (a whole path gives this much).
    pub progress: f64,
    /// Per second of episode time (a penalty).
    pub time: f64,
    /// Per metre the object moves relative to the tool (a penalty).
    pub object_motion: f64,
    /// Per second and unit of the largest cup utilisation above `seal_threshold` (a penalty).
    pub seal: f64,
    /// Utilisation below which the seal term is zero.
    pub seal_threshold: f64,
    /// Per m/s² of change of the tool's linear acceleration between control steps (a penalty).
    pub jerk: f64,
    /// Per rad/s² of change of the tool's angular acceleration between control steps (a penalty).
    pub angular_jerk: f64,
    /// Once, when an episode fails (a penalty).
    pub failure: f64,
    /// Once, when the package is placed (a bonus).
    pub success: f64,
}

/// Domain randomisation.
///
/// Quantities of the settled package (object mass, its place and tilt in the package, the
/// package's yaw under the tool, material scales, start jitter) are drawn for each of the
/// `settled_variants` states that `reset(seed)` settles once; every episode restores one of them
/// at random (drawn from the copy's own stream), so the package need not be re-simulated at each
/// reset. The target tilt and the goal jitter are drawn per episode. With `replay`, training
/// draws the packages whose episodes fail more often.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransportRandomization {
    /// Tilt of the tool at the place pose (degrees), uniform.
    #[serde(deserialize_with = "rlpkg_toml_input::array")]
    pub target_tilt_deg: [f64; 2],
    /// Largest offset of the place position (m), uniform in a ball.
    pub goal_jitter_m: f64,
    /// Largest offset of the pick position (m), uniform in a horizontal disc, per variant.
    pub start_jitter_m: f64,
    /// Package quantities per settled variant (the simulator's [`Randomization`]).
    pub package: Randomization,
    /// Replay of the settled packages that fail (optional; see [`FailureReplay`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub replay: Option<FailureReplay>,
    /// Posterior draws kept out of training (optional; see [`HeldOutDraws`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub held_out_draws: Option<HeldOutDraws>,
}

/// `[transport.randomization.held_out_draws]`: every `every`-th draw of the posterior (its rows
/// `every`, `2 every`, ... counted from 1) is held out, so that a policy can be evaluated on
/// materials it never trained on; the held-out rows alternate between test (the first, third,
/// ...) and validation (the second, fourth, ...), so that what is chosen by looking at results
/// is chosen on materials the reported table never sees. `rows` says which part the task draws
/// its packages from.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeldOutDraws {
    /// The period of the held-out rows, in [2, 100].
    pub every: usize,
    /// Which draws the packages take: `"training"` (the rest), `"held_out"` (all held-out
    /// rows), `"validation"` or `"test"` (their halves).
    pub rows: DrawRows,
}

/// Which part of a posterior's draws a task uses ([`HeldOutDraws`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DrawRows {
    /// Every draw but the held-out ones.
    Training,
    /// The held-out draws only.
    HeldOut,
    /// The held-out draws of even rank (the second, fourth, ...): where choices are made.
    Validation,
    /// The held-out draws of odd rank (the first, third, ...): where results are reported.
    Test,
}

impl HeldOutDraws {
    /// Whether the draw in row `index` (from 0) is held out.
    pub fn is_held_out(&self, index: usize) -> bool {
        (index + 1).is_multiple_of(self.every)
    }

    /// Whether the draw in row `index` (from 0) is in the part `rows` names.
    fn is_in(&self, index: usize, rows: DrawRows) -> bool {
        let held_out = self.is_held_out(index);
        // Rank among the held-out rows, from 1.
        let rank = (index + 1) / self.every;
        match rows {
            DrawRows::Training => !held_out,
            DrawRows::HeldOut => held_out,
            DrawRows::Validation => held_out && rank.is_multiple_of(2),
            DrawRows::Test => held_out && !rank.is_multiple_of(2),
        }
    }

    /// The rows of `draws` the task uses.
    pub fn select<T: Clone>(&self, draws: &[T]) -> Vec<T> {
        draws
            .iter()
            .enumerate()
            .filter(|(k, _)| self.is_in(*k, self.rows))
            .map(|(_, row)| row.clone())
            .collect()
    }
}

/// `[transport.randomization.replay]`: during training a share of the episodes starts from a
/// settled package drawn in proportion to its recent failure rate instead of uniformly
/// (prioritised level replay, Jiang et al. 2021), so the rare packages a policy fails on are
/// trained on more often than their share of the randomisation. A package's failure rate is an
/// exponential average over its finished episodes (1 for an episode that ends in anything but
/// success, else 0), from 0 at each reset; evaluation mode
/// ([`crate::Transport::set_retire_finished`]) draws uniformly.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FailureReplay {
    /// Share of the episodes that start from a package drawn by its failure rate, in [0, 1].
    pub share: f64,
    /// Weight of a package's earlier failure rate when one of its episodes ends, in [0, 1).
    pub memory: f64,
}

/// The message of an error in the `[transport]` table, naming the key: a table parsed apart from
/// its file has no line, but the parser keeps the key path (its text ends with `` in `a.b` ``).
fn table_error(err: &toml::de::Error) -> String {
    let text = err.to_string();
    match text.trim_end().rsplit_once("\nin `") {
        Some((message, key)) => format!("key `transport.{}: {message}", key),
        None => format!("[transport]: {}", err.message()),
    }
}

/// A configuration problem: `key` = `value` in `source`, expected `expected`.
fn bad(source: &str, key: &str, value: impl ToString, expected: &str) -> EnvError {
    EnvError::Config {
        file: source.to_string(),
        key: format!("transport.{key}"),
        value: value.to_string(),
        expected: expected.to_string(),
    }
}

fn check(source: &str, key: &str, value: f64, low: f64, high: f64) -> Result<(), EnvError> {
    if value.is_finite() && (low..=high).contains(&value) {
        Ok(())
    } else {
        Err(bad(
            source,
            key,
            value,
            &format!("a number in [{low}, {high}]"),
        ))
    }
}

/// Refuses the posterior of `summary` unless the calibration it records simulated the grid and
/// the integrator (solver, substep rate, sweeps) of `config.scene`
/// ([`posterior_files::calibrated_scene`]): its draws are parameters of that film at that step.
/// The scenes may differ otherwise (a calibrated scene is its calibration's preset with the
/// fitted values, and a transport scene may change the seal or the disc's hold).
fn check_posterior_scene(
    config: &TransportConfig,
    summary: &Path,
    source: &str,
) -> Result<(), EnvError> {
    let key = "randomization.package.posterior";
    let calibrated = posterior_files::calibrated_scene(summary)
        .map_err(|e| bad(source, key, summary.display(), &e.to_string()))?;
    let fail = |expected: String| bad(source, key, summary.display(), &expected);
    let scene = load_scene(config, source)?;
    // The draws are film and contact parameters of that grid at that step: the same values on
    // another grid or integrator are another material, and may not even be stable there.
    let differs = if calibrated.package.grid != scene.package.grid {
        Some(format!(
            "grid {:?} (transport: {:?})",
            calibrated.package.grid, scene.package.grid
        ))
    } else if calibrated.integrator != scene.integrator {
        Some(format!(
            "[integrator] {:?} (transport: {:?})",
            calibrated.integrator, scene.integrator
        ))
    } else {
        None
    };
    if let Some(what) = differs {
        return Err(fail(format!(
            "a posterior of a calibration on the grid and integrator of transport.scene {:?}; its \
             calibration simulated {what}",
            config.scene,
        )));
    }
    Ok(())
}

/// How far the robot limits may exceed the recordings' peaks ([`TransportConfig::check_limits`]).
pub const LIMIT_HEADROOM: f64 = 1.5;

impl TransportConfig {
    /// Parses the `[transport]` table; `source` names the file in messages.
    pub fn from_table(table: &toml::Table, source: &str) -> Result<Self, EnvError> {
        let mut config: TransportConfig =
            table
                .clone()
                .try_into()
                .map_err(|e: toml::de::Error| EnvError::ConfigParse {
                    file: source.to_string(),
                    message: table_error(&e),
                })?;
        config.validate(source)?;
        config.load_posterior(source)?;
        Ok(config)
    }

    /// Reads the draws of `randomization.package.posterior` (if set) into
    /// `posterior_draws`: the `samples.csv` of the folder (or of the folder of the
    /// `summary.json` or `samples.csv`) it names, relative paths from the working directory as
    /// `scene` and `recordings`. With a `summary.json` beside it, the calibration it records must
    /// have calibrated this config's `scene` at its step ([`check_posterior_scene`]); a bare
    /// `samples.csv` cannot be checked.
    pub fn load_posterior(&mut self, source: &str) -> Result<(), EnvError> {
        let Some(given) = self.randomization.package.posterior.clone() else {
            return Ok(());
        };
        let key = "randomization.package.posterior";
        let files = posterior_files::locate(&given).map_err(|e| EnvError::ConfigParse {
            file: source.to_string(),
            message: format!("transport.{key}: {e}"),
        })?;
        let samples = Samples::read(&files.samples).map_err(|e| EnvError::ConfigParse {
            file: source.to_string(),
            message: format!("transport.{key}: {e}"),
        })?;
        if let Some(summary) = files.summary {
            check_posterior_scene(self, &summary, source)?;
        }
        let mut draws = samples.to_draws();
        if let Some(split) = &self.randomization.held_out_draws {
            draws.rows = split.select(&draws.rows);
            if draws.rows.is_empty() {
                return Err(bad(
                    source,
                    "randomization.held_out_draws",
                    format!("{{ every = {}, rows = {:?} }}", split.every, split.rows),
                    "a split that leaves the task at least one of the posterior's draws",
                ));
            }
        }
        self.randomization.package.posterior_draws = Some(Arc::new(draws));
        Ok(())
    }

    /// Parses the `[transport]` table of a whole configuration file's text.
    pub fn from_toml_str(text: &str, source: &str) -> Result<Self, EnvError> {
        let table: toml::Table = toml::from_str(text).map_err(|e| EnvError::ConfigParse {
            file: source.to_string(),
            message: e.to_string(),
        })?;
        match table.get("transport") {
            Some(toml::Value::Table(t)) => Self::from_table(t, source),
            _ => Err(bad(source, "", "missing", "a [transport] table")),
        }
    }

    /// The task with the nominal package at one target tilt: every randomised quantity at the
    /// middle of its range (mass, disc mass scale and vacuum the mean of theirs, the scene's
    /// parameters instead of posterior draws, material scales the
    /// geometric mean of their log-uniform bands), the object centred and upright, the package
    /// unturned, no pick or place jitter, one settled variant. What a command for a known place
    /// pose and an unknown package is optimised on.
    pub fn nominal(&self, target_tilt_deg: f64) -> Self {
        let mut nominal = self.clone();
        let r = &mut nominal.randomization;
        let middle = |[lo, hi]: [f32; 2]| [0.5 * (lo + hi); 2];
        r.target_tilt_deg = [target_tilt_deg; 2];
        r.goal_jitter_m = 0.0;
        r.start_jitter_m = 0.0;
        let p = &mut r.package;
        p.object_mass_kg = p.object_mass_kg.map(middle);
        p.disc_mass_scale = p.disc_mass_scale.map(middle);
        p.object_offset_m = 0.0;
        p.object_tilt_deg = 0.0;
        p.package_yaw_deg = [0.0; 2];
        p.vacuum_kpa = p.vacuum_kpa.map(middle);
        // The scene's own parameters (a calibration's best fit) stand for the posterior.
        p.posterior = None;
        p.posterior_draws = None;
        for band in p.param_scale.values_mut() {
            *band = [(band[0] * band[1]).sqrt(); 2];
        }
        nominal.settled_variants = 1;
        nominal
    }

    /// Checks the robot limits against the tool's peaks over the recordings (`peaks`: every
    /// recording of `recordings`, [`crate::transport::load_paths`]): speed, acceleration and
    /// angular speed at most [`LIMIT_HEADROOM`] x their peak. `reference` names the recordings in
    /// messages.
    pub fn check_limits(
        &self,
        peaks: &ToolPeaks,
        reference: &str,
        source: &str,
    ) -> Result<(), EnvError> {
        let l = &self.limits;
        for (key, value, peak, unit) in [
            (
                "limits.max_path_speed_m_s",
                l.max_path_speed_m_s,
                peaks.speed_m_s,
                "m/s",
            ),
            (
                "limits.max_path_accel_m_s2",
                l.max_path_accel_m_s2,
                peaks.accel_m_s2,
                "m/s^2",
            ),
            (
                "limits.max_angular_speed_rad_s",
                l.max_angular_speed_rad_s,
                peaks.angular_speed_rad_s,
                "rad/s",
            ),
        ] {
            let bound = LIMIT_HEADROOM * peak;
            if value > bound {
                return Err(bad(
                    source,
                    key,
                    value,
                    &format!(
                        "at most {LIMIT_HEADROOM} x the peak {peak:.4} {unit} of {reference} = {bound:.4} {unit}"
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Range checks of every key (the robot limits against the recordings: [`Self::check_limits`]).
    pub fn validate(&self, source: &str) -> Result<(), EnvError> {
        let s = source;
        if !(self.grid[0] >= 3 && self.grid[1] >= 3 && self.grid[0] <= 64 && self.grid[1] <= 64) {
            return Err(bad(
                s,
                "grid",
                format!("{:?}", self.grid),
                "[rows, columns] within [3, 64]",
            ));
        }
        if self.paths.is_empty() {
            return Err(bad(s, "paths", "[]", "at least one recording id"));
        }
        check(s, "control_hz", self.control_hz, 10.0, 30.0)?;
        check(s, "time_limit_s", self.time_limit_s, 0.1, 600.0)?;
        if !(1..=1024).contains(&self.settled_variants) {
            return Err(bad(
                s,
                "settled_variants",
                self.settled_variants,
                "an integer in [1, 1024]",
            ));
        }
        check(s, "settle_s", self.settle_s, 0.0, 10.0)?;
        if let Some(ratio) = self.grasp_min_vacuum_ratio {
            check(s, "grasp_min_vacuum_ratio", ratio, 0.5, 0.98)?;
        }
        let l = &self.limits;
        check(
            s,
            "limits.max_path_speed_m_s",
            l.max_path_speed_m_s,
            0.01,
            f64::INFINITY,
        )?;
        check(
            s,
            "limits.max_path_accel_m_s2",
            l.max_path_accel_m_s2,
            0.01,
            f64::INFINITY,
        )?;
        check(
            s,
            "limits.max_tilt_offset_deg",
            l.max_tilt_offset_deg,
            0.0,
            45.0,
        )?;
        if let Some(fade) = l.tilt_offset_fade_m {
            check(s, "limits.tilt_offset_fade_m", fade, 1e-3, 1.0)?;
        }
        check(
            s,
            "limits.max_angular_speed_rad_s",
            l.max_angular_speed_rad_s,
            0.01,
            f64::INFINITY,
        )?;
        check(
            s,
            "limits.max_angular_accel_rad_s2",
            l.max_angular_accel_rad_s2,
            0.01,
            1000.0,
        )?;
        check(s, "limits.tracking_gain", l.tracking_gain, 1e-3, 1.0)?;
        let t = &self.success;
        check(s, "success.position_m", t.position_m, 1e-4, 1.0)?;
        check(s, "success.orientation_deg", t.orientation_deg, 0.01, 90.0)?;
        check(s, "success.tool_speed_m_s", t.tool_speed_m_s, 1e-4, 10.0)?;
        check(
            s,
            "success.object_speed_m_s",
            t.object_speed_m_s,
            1e-4,
            10.0,
        )?;
        check(
            s,
            "failure.max_object_distance_m",
            self.failure.max_object_distance_m,
            0.01,
            10.0,
        )?;
        let w = &self.reward;
        for (key, value) in [
            ("reward.progress", w.progress),
            ("reward.time", w.time),
            ("reward.object_motion", w.object_motion),
            ("reward.seal", w.seal),
            ("reward.jerk", w.jerk),
            ("reward.angular_jerk", w.angular_jerk),
            ("reward.failure", w.failure),
            ("reward.success", w.success),
        ] {
            check(s, key, value, 0.0, 1e6)?;
        }
        check(s, "reward.seal_threshold", w.seal_threshold, 0.0, 1.0)?;
        let r = &self.randomization;
        let [lo, hi] = r.target_tilt_deg;
        if !(lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo <= hi && hi <= 90.0) {
            return Err(bad(
                s,
                "randomization.target_tilt_deg",
                format!("{:?}", r.target_tilt_deg),
                "[low, high] within [0, 90] degrees",
            ));
        }
        check(s, "randomization.goal_jitter_m", r.goal_jitter_m, 0.0, 0.2)?;
        if let Some(replay) = &r.replay {
            check(s, "randomization.replay.share", replay.share, 0.0, 1.0)?;
            if !(replay.memory.is_finite() && (0.0..1.0).contains(&replay.memory)) {
                return Err(bad(
                    s,
                    "randomization.replay.memory",
                    replay.memory,
                    "a number in [0, 1)",
                ));
            }
        }
        if let Some(split) = &r.held_out_draws {
            if !(2..=100).contains(&split.every) {
                return Err(bad(
                    s,
                    "randomization.held_out_draws.every",
                    split.every,
                    "an integer in [2, 100]",
                ));
            }
            if r.package.posterior.is_none() {
                return Err(bad(
                    s,
                    "randomization.held_out_draws",
                    format!("{{ every = {} }}", split.every),
                    "a randomization.package.posterior whose draws it splits",
                ));
            }
        }
        check(
            s,
            "randomization.start_jitter_m",
            r.start_jitter_m,
            0.0,
            0.2,
        )?;
        r.package
            .validate(&format!("{source} [transport.randomization.package]"))
            .map_err(|e| EnvError::ConfigParse {
                file: source.to_string(),
                message: e.to_string(),
            })?;
        if let Some(p) = &self.profile_rate {
            check(s, "profile_rate.limits_scale", p.limits_scale, 1e-3, 3.0)?;
            check(s, "profile_rate.max_rate", p.max_rate, 1.0, 4.0)?;
            check(
                s,
                "profile_rate.max_rate_change_per_s",
                p.max_rate_change_per_s,
                1e-3,
                100.0,
            )?;
        }
        self.validate_sensors(source)
    }

    /// Checks `observation` against `[transport.sensors]` and the sensors' ranges.
    fn validate_sensors(&self, s: &str) -> Result<(), EnvError> {
        let sensors = match (self.observation, &self.sensors) {
            (ObservationMode::Privileged, None) => return Ok(()),
            (ObservationMode::Privileged, Some(_)) => {
                return Err(bad(
                    s,
                    "sensors",
                    "a table",
                    "no [transport.sensors] table unless observation = \"sensors\"",
                ))
            }
            (ObservationMode::Sensors, None) => {
                return Err(bad(
                    s,
                    "sensors",
                    "missing",
                    "a [transport.sensors] table with observation = \"sensors\"",
                ))
            }
            (ObservationMode::Sensors, Some(sensors)) => sensors,
        };
        let [lo, hi] = sensors.supply_vacuum_kpa;
        if !(lo.is_finite() && hi.is_finite() && 1.0 <= lo && lo <= hi && hi <= 90.0) {
            return Err(bad(
                s,
                "sensors.supply_vacuum_kpa",
                format!("{:?}", sensors.supply_vacuum_kpa),
                "[low, high] within [1, 90] kPa below ambient (a cell supplies 20-30)",
            ));
        }
        // With the package's vacuum randomised the supply reading is the vacuum its seal has:
        // a second, different range would describe another cell.
        if let Some([plo, phi]) = self.randomization.package.vacuum_kpa {
            if lo as f32 != plo || hi as f32 != phi {
                return Err(bad(
                    s,
                    "sensors.supply_vacuum_kpa",
                    format!("{:?}", sensors.supply_vacuum_kpa),
                    &format!(
                        "the range of transport.randomization.package.vacuum_kpa, [{plo}, {phi}]: \
                         the sensors then read the vacuum each package's seal has"
                    ),
                ));
            }
        }
        for (key, [lo, hi]) in [
            (
                "sensors.observation_delay_steps",
                sensors.observation_delay_steps,
            ),
            ("sensors.action_delay_steps", sensors.action_delay_steps),
        ] {
            if !(lo <= hi && hi <= MAX_DELAY_STEPS) {
                return Err(bad(
                    s,
                    key,
                    format!("[{lo}, {hi}]"),
                    &format!("[low, high] control steps within [0, {MAX_DELAY_STEPS}]"),
                ));
            }
        }
        if sensors.history_steps > MAX_HISTORY_STEPS {
            return Err(bad(
                s,
                "sensors.history_steps",
                sensors.history_steps.to_string(),
                &format!("earlier control steps within [0, {MAX_HISTORY_STEPS}]"),
            ));
        }
        let n = &sensors.noise;
        for (key, value, high) in [
            ("sensors.noise.vacuum_pa", n.vacuum_pa, 1e4),
            ("sensors.noise.force_n", n.force_n, 100.0),
            ("sensors.noise.torque_n_m", n.torque_n_m, 10.0),
            ("sensors.noise.position_m", n.position_m, 0.1),
            ("sensors.noise.orientation_rad", n.orientation_rad, 0.5),
            ("sensors.noise.velocity_m_s", n.velocity_m_s, 1.0),
            (
                "sensors.noise.angular_velocity_rad_s",
                n.angular_velocity_rad_s,
                5.0,
            ),
        ] {
            check(s, key, value, 0.0, high)?;
        }
        if let Some(v) = &sensors.vacuum {
            for (key, [lo, hi], high) in [
                ("sensors.vacuum.load_leak", v.load_leak, 1.0),
                ("sensors.vacuum.time_constant_s", v.time_constant_s, 1.0),
            ] {
                if !(lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo <= hi && hi <= high) {
                    return Err(bad(
                        s,
                        key,
                        format!("[{lo}, {hi}]"),
                        &format!("[low, high] within [0, {high}]"),
                    ));
                }
            }
            check(
                s,
                "sensors.vacuum.supply_noise_pa",
                v.supply_noise_pa,
                0.0,
                5e3,
            )?;
        }
        Ok(())
    }
}

/// The scene `config.scene` names (file or preset) with the configured grid and the robot limits
/// of `[transport.limits]`; it must have the seal model on.
pub fn load_scene(config: &TransportConfig, source: &str) -> Result<SceneConfig, EnvError> {
    let mut scene = match config.scene.as_str() {
        "physical" | "reference" => SceneConfig::preset(&config.scene),
        path => SceneConfig::load(Path::new(path)),
    }
    .map_err(|e| EnvError::ConfigParse {
        file: source.to_string(),
        message: format!("transport.scene = {:?}: {e}", config.scene),
    })?;
    if !scene.seal.enabled {
        return Err(EnvError::Config {
            file: source.to_string(),
            key: "transport.scene".into(),
            value: config.scene.clone(),
            expected: "a scene with SI masses and the seal model on ([seal] enabled = true), \
                       e.g. configs/scenes/physical-explicit.toml"
                .into(),
        });
    }
    if config.randomization.package.object_tilt_deg > 0.0
        && !(scene.disc.hold_at_recorded_start && scene.disc.hold_orientation)
    {
        return Err(EnvError::Config {
            file: source.to_string(),
            key: "transport.randomization.package.object_tilt_deg".into(),
            value: config.randomization.package.object_tilt_deg.to_string(),
            expected: format!(
                "0 with the scene {:?}: a tilted object needs a scene that turns the disc to its \
                 tilt during the rest ([disc] hold_at_recorded_start = true and hold_orientation \
                 = true); started tilted, its rim cuts through the flat package's film",
                config.scene
            ),
        });
    }
    scene.package.grid = config.grid;
    let l = &config.limits;
    scene.tool_limits = ToolLimits {
        max_speed_m_s: l.max_path_speed_m_s as f32,
        max_accel_m_s2: l.max_path_accel_m_s2 as f32,
        max_angular_speed_rad_s: l.max_angular_speed_rad_s as f32,
        max_angular_accel_rad_s2: l.max_angular_accel_rad_s2 as f32,
    };
    scene.validate(source).map_err(|e| EnvError::ConfigParse {
        file: source.to_string(),
        message: e.to_string(),
    })?;
    Ok(scene)
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use super::*;
    use crate::transport::test_support::{config, sensors_table, test_table};
    use crate::transport::Transport;
    use crate::VecEnv;

    #[test]
    fn a_tilted_object_needs_a_scene_that_turns_the_disc_during_the_rest() {
        let text = test_table().replace("object_tilt_deg = 0.0", "object_tilt_deg = 20.0");
        let error = Transport::new(config(&text), 1, "test.toml").err().unwrap();
        let message = error.to_string();
        assert!(
            message.contains("test.toml")
                && message.contains("object_tilt_deg")
                && message.contains("hold_orientation"),
            "{message}"
        );
    }

    #[test]
    fn the_nominal_package_is_the_middle_of_every_range_at_the_tilt_asked() {
        let nominal = config(&test_table()).nominal(42.0);
        nominal.validate("test.toml").unwrap();
        let mut env = Transport::new(nominal, 2, "test.toml").unwrap();
        let mut buffers = env.buffers();
        env.try_reset(7, &mut buffers).unwrap();
        for copy in 0..2 {
            let c = env.conditions(copy);
            assert!(
                (c.target_tilt_rad.to_degrees() - 42.0).abs() < 1e-9,
                "{c:?}"
            );
            assert!((c.object_mass_kg - 0.441).abs() < 1e-6, "{c:?}");
            assert_eq!(c.package_yaw_rad, 0.0);
            assert_eq!(c.goal_jitter_m, [0.0; 3]);
            assert_eq!(c.start_offset_m, [0.0; 3]);
            assert_eq!(c.variant, 0);
        }
        let scale = env.config.randomization.package.param_scale["k_tri_e"];
        assert_eq!(scale, [1.0; 2]);
    }

    #[test]
    fn fixed_length_arrays_with_a_wrong_length_name_the_key() {
        let text = test_table();
        for (from, to, key, found) in [
            ("grid = [11, 13]", "grid = [11, 13, 2]", "grid", 3),
            (
                "target_tilt_deg = [30.0, 60.0]",
                "target_tilt_deg = [30.0, 45.0, 60.0]",
                "randomization.target_tilt_deg",
                3,
            ),
            (
                "object_mass_kg = [0.287, 0.595]",
                "object_mass_kg = [0.287]",
                "randomization.package.object_mass_kg",
                1,
            ),
            (
                "package_yaw_deg = [-10.0, 10.0]",
                "package_yaw_deg = [-10.0, 0.0, 10.0]",
                "randomization.package.package_yaw_deg",
                3,
            ),
            (
                "k_tri_e = [0.8, 1.25]",
                "k_tri_e = [0.8, 1.0, 1.25]",
                "randomization.package.param_scale.k_tri_e",
                3,
            ),
        ] {
            assert!(text.contains(from), "{from}");
            let table: toml::Table = toml::from_str(&text.replace(from, to)).unwrap();
            let err = TransportConfig::from_table(table["transport"].as_table().unwrap(), "t.toml")
                .unwrap_err()
                .to_string();
            let expected = format!(
                "t.toml: key `transport.{key}`: invalid length {found}, expected an array of length 2"
            );
            assert!(err.starts_with(&expected), "{to}: {err}");
        }
    }

    #[test]
    fn configuration_errors_name_the_key_and_the_expected_range() {
        let text = test_table();
        let err = TransportConfig::from_toml_str(
            &text.replace("control_hz = 20.0", "control_hz = 100.0"),
            "t.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("t.toml")
                && err.contains("transport.control_hz")
                && err.contains("[10, 30]"),
            "{err}"
        );
        // Faster than 1.5 x the recordings' peak speed (0.631 m/s, high velocity) is refused when
        // the paths are loaded; the message names the key, the value, the peak and the bound.
        let err = crate::transport::load_paths(
            &config(&text.replace("max_path_speed_m_s = 0.945", "max_path_speed_m_s = 1.2")),
            true,
            "t.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("limits.max_path_speed_m_s")
                && err.contains("1.2")
                && err.contains("0.6310")
                && err.contains("0.9466")
                && err.contains("recordings of"),
            "{err}"
        );
        for (from, to, key) in [
            (
                "max_path_accel_m_s2 = 5.2",
                "max_path_accel_m_s2 = 5.3",
                "max_path_accel_m_s2",
            ),
            (
                "max_angular_speed_rad_s = 3.1",
                "max_angular_speed_rad_s = 3.2",
                "max_angular_speed_rad_s",
            ),
        ] {
            let err =
                crate::transport::load_paths(&config(&text.replace(from, to)), true, "t.toml")
                    .unwrap_err()
                    .to_string();
            assert!(err.contains(key), "{err}");
        }
        let err = TransportConfig::from_toml_str(
            &text.replace("goal_jitter_m = 0.03", "goal_jiter_m = 0.03"),
            "t.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("goal_jiter_m"), "{err}");
        let rate = "\n[transport.profile_rate]\nlimits_scale = 1.0\nmax_rate = 2.0\nmax_rate_change_per_s = 2.0\n";
        assert!(TransportConfig::from_toml_str(&(text.clone() + rate), "t.toml").is_ok());
        for (from, to, key) in [
            (
                "limits_scale = 1.0",
                "limits_scale = 3.5",
                "profile_rate.limits_scale",
            ),
            ("max_rate = 2.0", "max_rate = 0.5", "profile_rate.max_rate"),
            (
                "max_rate_change_per_s = 2.0",
                "max_rate_change_per_s = -1.0",
                "profile_rate.max_rate_change_per_s",
            ),
            ("max_rate = 2.0", "max_rates = 2.0", "max_rates"),
        ] {
            let err =
                TransportConfig::from_toml_str(&(text.clone() + &rate.replace(from, to)), "t.toml")
                    .unwrap_err()
                    .to_string();
            assert!(err.contains("t.toml") && err.contains(key), "{to}: {err}");
        }
        let replay = "\n[transport.randomization.replay]\nshare = 0.5\nmemory = 0.9\n";
        assert!(TransportConfig::from_toml_str(&(text.clone() + replay), "t.toml").is_ok());
        for (from, to, key) in [
            ("share = 0.5", "share = 1.5", "randomization.replay.share"),
            (
                "memory = 0.9",
                "memory = 1.0",
                "randomization.replay.memory",
            ),
            (
                "memory = 0.9",
                "memory = nan",
                "randomization.replay.memory",
            ),
            ("memory = 0.9", "memori = 0.9", "memori"),
        ] {
            let err = TransportConfig::from_toml_str(
                &(text.clone() + &replay.replace(from, to)),
                "t.toml",
            )
            .unwrap_err()
            .to_string();
            assert!(err.contains("t.toml") && err.contains(key), "{to}: {err}");
        }
        let fade = |value: &str| {
            let line = format!("max_tilt_offset_deg = 20.0\ntilt_offset_fade_m = {value}");
            TransportConfig::from_toml_str(
                &text.replace("max_tilt_offset_deg = 20.0", &line),
                "t.toml",
            )
        };
        assert_eq!(fade("0.15").unwrap().limits.tilt_offset_fade_m, Some(0.15));
        for value in ["0.0", "1.5", "nan"] {
            let err = fade(value).unwrap_err().to_string();
            assert!(err.contains("limits.tilt_offset_fade_m"), "{value}: {err}");
        }
        let grasp = |value: &str| {
            let line = format!("settle_s = 0.5\ngrasp_min_vacuum_ratio = {value}\n");
            TransportConfig::from_toml_str(&text.replace("settle_s = 0.5\n", &line), "t.toml")
        };
        assert_eq!(grasp("0.85").unwrap().grasp_min_vacuum_ratio, Some(0.85));
        for value in ["0.4", "0.99", "nan"] {
            let err = grasp(value).unwrap_err().to_string();
            assert!(err.contains("grasp_min_vacuum_ratio"), "{value}: {err}");
        }
        let err = Transport::new(config(&text.replace("\"HHHHM\"", "\"NOPE\"")), 1, "t.toml")
            .err()
            .unwrap()
            .to_string();
        assert!(
            err.contains("transport.paths") && err.contains("NOPE"),
            "{err}"
        );
    }

    #[test]
    fn the_repository_configs_keep_their_limits_within_their_recordings_peaks() {
        let root = concat!(env!("CARGO_MANIFEST_DIR"), "/..");
        for name in [
            "transport.toml",
            "transport-sensors.toml",
            "transport-posterior.toml",
            "transport-sensors-posterior.toml",
            "transport-sensors-posterior-soft-film.toml",
        ] {
            let path = format!("{root}/configs/train/{name}");
            // A posterior names its calibration config relative to the repository root, which is
            // not the tests' working folder; the posterior loader's own tests read one.
            let text = rlpkg_toml_input::read_composed(Path::new(&path))
                .unwrap()
                .text
                .replace("\"data/", &format!("\"{root}/data/"))
                .replace("posterior = ", "# posterior = ");
            let config = TransportConfig::from_toml_str(&text, &path).unwrap();
            let paths = crate::transport::load_paths(&config, true, &path).unwrap();
            assert_eq!(paths.len(), 3, "{name}");
        }
    }

    #[test]
    fn the_cells_vacuum_response_is_checked_and_names_its_key() {
        let table = sensors_table()
            + "\n[transport.sensors.vacuum]\nload_leak = [0.0, 0.31]\n\
               time_constant_s = [0.01, 0.06]\nsupply_noise_pa = 100.0\n";
        let vacuum = config(&table).sensors.unwrap().vacuum.unwrap();
        assert_eq!(vacuum.load_leak, [0.0, 0.31]);
        for (from, to, key) in [
            (
                "load_leak = [0.0, 0.31]",
                "load_leak = [0.31, 0.0]",
                "load_leak",
            ),
            (
                "load_leak = [0.0, 0.31]",
                "load_leak = [-0.1, 0.31]",
                "load_leak",
            ),
            ("[0.01, 0.06]", "[0.01, 6.0]", "time_constant_s"),
            (
                "supply_noise_pa = 100.0",
                "supply_noise_pa = 1e9",
                "supply_noise_pa",
            ),
        ] {
            let err = TransportConfig::from_toml_str(&table.replace(from, to), "t.toml")
                .unwrap_err()
                .to_string();
            assert!(
                err.contains("t.toml") && err.contains(&format!("sensors.vacuum.{key}")),
                "{to}: {err}"
            );
        }
    }

    #[test]
    fn sensor_settings_are_checked_and_name_their_key() {
        let text = sensors_table();
        let sensors = config(&text).sensors.expect("sensors");
        assert_eq!(sensors.observation_delay_steps, [1, 2]);
        for (from, to, key) in [
            (
                "observation = \"sensors\"",
                "observation = \"sonar\"",
                "transport.observation",
            ),
            (
                "action_delay_steps = [1, 2]",
                "action_delay_steps = [2, 1]",
                "transport.sensors.action_delay_steps",
            ),
            (
                "observation_delay_steps = [1, 2]",
                "observation_delay_steps = [1, 20]",
                "transport.sensors.observation_delay_steps",
            ),
            (
                "supply_vacuum_kpa = [20.0, 30.0]",
                "supply_vacuum_kpa = [30.0, 20.0]",
                "transport.sensors.supply_vacuum_kpa",
            ),
            (
                "vacuum_pa = 200.0",
                "vacuum_pa = -1.0",
                "transport.sensors.noise.vacuum_pa",
            ),
            (
                "observation = \"sensors\"",
                "observation = \"privileged\"",
                "transport.sensors",
            ),
        ] {
            assert!(text.contains(from), "{from}");
            let err = TransportConfig::from_toml_str(&text.replace(from, to), "t.toml")
                .unwrap_err()
                .to_string();
            assert!(err.contains("t.toml") && err.contains(key), "{to}: {err}");
        }
        // Sensors asked for without their table.
        let without = test_table().replace(
            "settle_s = 0.5\n",
            "settle_s = 0.5\nobservation = \"sensors\"\n",
        );
        let err = TransportConfig::from_toml_str(&without, "t.toml")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("transport.sensors") && err.contains("missing"),
            "{err}"
        );
    }

    /// A fresh folder under the system's temporary folder for test `name`.
    fn temp_folder(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("rlpkg-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// A posterior folder in `dir`: `samples` as its samples.csv and a summary.json naming a
    /// calibration config of scene `preset` with the further `[sim]` lines `sim`.
    fn posterior_folder(dir: &Path, samples: &str, preset: &str, sim: &str) -> PathBuf {
        let folder = dir.join("posterior");
        std::fs::create_dir_all(&folder).unwrap();
        let calibration = dir.join("calibrate.toml");
        let config = format!(
            "data = \"data\"\nout_dir = \"out\"\n[sim]\npreset = {preset:?}\n{sim}\n\
             [smc]\nparticles = 8\nmoves = 1\n\
             [[param]]\nname = \"k_tri_e\"\nlower = 1e3\nupper = 1e5\n"
        );
        std::fs::write(&calibration, config).unwrap();
        std::fs::write(folder.join("samples.csv"), samples).unwrap();
        let summary = serde_json::json!({ "config": calibration.display().to_string() });
        std::fs::write(folder.join("summary.json"), summary.to_string()).unwrap();
        folder
    }

    fn with_posterior(path: &Path) -> String {
        test_table().replace(
            "param_scale = { k_tri_e = [0.8, 1.25] }",
            &format!(
                "param_scale = {{ k_tri_e = [0.8, 1.25] }}\nposterior = {:?}",
                path.display().to_string()
            ),
        )
    }

    const SAMPLES: &str = "k_tri_e,k_spr_e,mu_con\n1000,20,0.5\n2000,30,0.6\n";

    #[test]
    fn held_out_draws_are_never_among_the_training_draws() {
        let dir = temp_folder("posterior-held-out");
        let rows: String = (1..=10).map(|k| format!("{},20,0.5\n", 1000 * k)).collect();
        let folder = posterior_folder(
            &dir,
            &format!("k_tri_e,k_spr_e,mu_con\n{rows}"),
            "physical",
            "",
        );
        let split = |rows: &str| {
            let text = with_posterior(&folder).replace(
                "[transport.randomization.package]",
                &format!(
                    "[transport.randomization.held_out_draws]\nevery = 3\nrows = {rows:?}\n\n\
                     [transport.randomization.package]"
                ),
            );
            let config = config(&text);
            let draws = config.randomization.package.posterior_draws.unwrap();
            draws
                .rows
                .iter()
                .map(|r| r[0] as usize / 1000)
                .collect::<Vec<_>>()
        };
        assert_eq!(split("training"), [1, 2, 4, 5, 7, 8, 10]);
        assert_eq!(split("held_out"), [3, 6, 9]);
        assert_eq!(split("test"), [3, 9]);
        assert_eq!(split("validation"), [6]);
        let text = test_table().replace(
            "[transport.randomization.package]",
            "[transport.randomization.held_out_draws]\nevery = 3\nrows = \"training\"\n\n\
             [transport.randomization.package]",
        );
        let err = TransportConfig::from_toml_str(&text, "t.toml")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("randomization.held_out_draws") && err.contains("posterior"),
            "{err}"
        );
    }

    #[test]
    fn a_posterior_of_the_scene_s_calibration_is_loaded_from_its_folder_or_files() {
        let dir = temp_folder("posterior-loads");
        let folder = posterior_folder(&dir, SAMPLES, "physical", "between = 1");
        for given in [
            folder.clone(),
            folder.join("summary.json"),
            folder.join("samples.csv"),
        ] {
            let config = config(&with_posterior(&given));
            let draws = config
                .randomization
                .package
                .posterior_draws
                .clone()
                .unwrap();
            assert_eq!(draws.names, ["k_tri_e", "k_spr_e", "mu_con"]);
            assert_eq!(
                draws.rows,
                [vec![1000.0, 20.0, 0.5], vec![2000.0, 30.0, 0.6]]
            );
            // The critic sees the log of every drawn or scaled parameter over the scene's.
            assert_eq!(
                crate::transport::observe::randomised_materials(&config),
                ["k_spr_e", "k_tri_e", "mu_con"]
            );
            // The nominal task is the scene's own parameters.
            assert!(config
                .nominal(45.0)
                .randomization
                .package
                .posterior_draws
                .is_none());
        }
        // A bare samples.csv (no summary beside it) cannot be checked and is taken as it is.
        let bare = dir.join("bare.csv");
        std::fs::write(&bare, SAMPLES).unwrap();
        let config = config(&with_posterior(&bare));
        assert_eq!(
            config
                .randomization
                .package
                .posterior_draws
                .unwrap()
                .rows
                .len(),
            2
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bad_posteriors_are_refused_naming_the_file_line_and_column() {
        let dir = temp_folder("posterior-bad");
        let samples = dir.join("posterior").join("samples.csv");
        let shown = samples.display().to_string();
        for (text, needles) in [
            (
                "k_tri_e,k_sprung\n1,2\n",
                vec![shown.clone(), "line 1 column 2".into(), "k_sprung".into()],
            ),
            (
                "k_tri_e,mu_con\n1,0.5\n1,x\n",
                vec![shown.clone(), "line 3 column 2".into()],
            ),
            (
                "k_tri_e,mu_con\n-5,0.5\n",
                vec![shown.clone(), "line 2 column 1".into(), "-5".into()],
            ),
        ] {
            posterior_folder(&dir, text, "physical", "between = 1");
            let err = TransportConfig::from_toml_str(&with_posterior(&samples), "t.toml")
                .unwrap_err()
                .to_string();
            assert!(err.contains("t.toml") && err.contains("posterior"), "{err}");
            for needle in needles {
                assert!(err.contains(&needle), "{text:?}: {err}");
            }
        }
        let missing = dir.join("nowhere");
        let err = TransportConfig::from_toml_str(&with_posterior(&missing), "t.toml")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("t.toml")
                && err.contains(&missing.display().to_string())
                && err.contains("not found"),
            "{err}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_posterior_of_another_grid_or_step_is_refused_naming_both() {
        let dir = temp_folder("posterior-scene");
        let refusal = |preset: &str, sim: &str| {
            let folder = posterior_folder(&dir, SAMPLES, preset, sim);
            TransportConfig::from_toml_str(&with_posterior(&folder), "t.toml")
                .unwrap_err()
                .to_string()
        };
        // The test table trains on the physical scene at 11 x 13 (`between = 1`).
        for (sim, differs) in [
            ("between = 2", "grid [16, 19]"),
            ("between = 1\ndt = 0.001", "[integrator]"),
            ("between = 1\niterations = 48", "iterations: 48"),
        ] {
            let err = refusal("physical", sim);
            assert!(
                err.contains("t.toml")
                    && err.contains("summary.json")
                    && err.contains("transport.scene \"physical\"")
                    && err.contains(differs),
                "{err}"
            );
        }
        let err = refusal("configs/scenes/missing.toml", "between = 1");
        assert!(err.contains("configs/scenes/missing.toml"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_sensor_supply_range_contradicting_the_package_vacuum_is_refused() {
        let text = sensors_table().replace(
            "param_scale = { k_tri_e = [0.8, 1.25] }",
            "param_scale = { k_tri_e = [0.8, 1.25] }\nvacuum_kpa = [20.0, 30.0]",
        );
        config(&text);
        let err = TransportConfig::from_toml_str(
            &text.replace(
                "supply_vacuum_kpa = [20.0, 30.0]",
                "supply_vacuum_kpa = [25.0, 30.0]",
            ),
            "t.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("t.toml")
                && err.contains("transport.sensors.supply_vacuum_kpa")
                && err.contains("randomization.package.vacuum_kpa"),
            "{err}"
        );
        let err = TransportConfig::from_toml_str(
            &text.replace(
                "\nvacuum_kpa = [20.0, 30.0]\n",
                "\nvacuum_kpa = [0.0, 30.0]\n",
            ),
            "t.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("t.toml") && err.contains("vacuum_kpa"),
            "{err}"
        );
    }
}
