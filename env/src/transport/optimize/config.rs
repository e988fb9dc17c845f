//! The config of `rlpkg optimize` (TOML): the packages an open-loop command is optimised for,
//! how their costs combine, the cross-entropy method, the knots of the command, and the settings
//! of receding-horizon control; with the task it names and the search space it spans.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::cem::CemSettings;
use super::curve::KnotCurve;
use crate::transport::run_error::RunError;
use crate::transport::TransportConfig;

/// The optimisation config.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct OptimizeConfig {
    /// Training config whose `[transport]` table sets the task (scene, paths, limits, reward).
    pub transport: PathBuf,
    /// Output folder.
    pub out_dir: PathBuf,
    /// Which packages the command is optimised for.
    pub conditions: Conditions,
    /// How a command's costs over the packages combine.
    #[serde(default)]
    pub risk: Risk,
    /// The cross-entropy method.
    pub cem: CemTable,
    /// The decision variables.
    pub knots: Knots,
    /// Receding-horizon control (`--mpc`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mpc: Option<MpcTable>,
}

/// `[conditions]`: the first `packages` episodes a reset from `seed` draws (what `rlpkg eval
/// --seed <seed>` runs as its first episodes).
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Conditions {
    /// Seed of the episodes' draws (path, mass, object offset and tilt, target tilt, ...).
    pub seed: u64,
    /// K: 1 optimises for one package condition, more for all K at once.
    pub packages: usize,
    /// A library instead: one command per target tilt (degrees), each for the nominal package
    /// (every randomised quantity at the middle of its range; needs `packages = 1`). An
    /// episode of `rlpkg eval --optimized` plays the command of the tilt nearest its own.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub nominal_target_tilts_deg: Vec<f64>,
}

/// `[mpc]`: each control step optimises the command over the next `horizon_s` (knots evenly
/// spaced over it, counted from now) with `iterations` CEM iterations of `[cem]`'s population,
/// then applies the best candidate's first action.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MpcTable {
    /// Planning horizon (s).
    pub horizon_s: f64,
    /// Knots per action over the horizon.
    pub knots: usize,
    /// CEM iterations per control step.
    pub iterations: usize,
}

/// `[risk]`: a command's cost over K packages is `(1 - weight) x mean + weight x quantile`.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Risk {
    /// Quantile level in [0, 1].
    pub quantile: f64,
    /// Weight of the quantile in [0, 1].
    pub weight: f64,
}

impl Default for Risk {
    fn default() -> Self {
        Self {
            quantile: 0.9,
            weight: 0.0,
        }
    }
}

/// `[cem]`.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CemTable {
    /// Candidates per iteration (the distribution's mean first); each is rolled out on every
    /// package, so one iteration is one batch of population x packages copies.
    pub population: usize,
    /// Lowest-cost candidates the distribution is refitted to.
    pub elites: usize,
    /// Iterations.
    pub iterations: usize,
    /// Weight of the elites in each update, in (0, 1].
    pub smoothing: f64,
    /// Seed of the samples.
    pub seed: u64,
}

/// `[knots]`: each action is a smooth curve in time through `count` knots evenly spaced over
/// `horizon_s`, held after it.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Knots {
    /// Knots per action.
    pub count: usize,
    /// Time of the last knot (s).
    pub horizon_s: f64,
    /// Path speed of every knot at the start (m/s).
    pub initial_speed_m_s: f64,
    /// Initial spread of the path speed knots (m/s).
    pub speed_std_m_s: f64,
    /// Initial spread of the tilt offset knots (degrees).
    pub tilt_std_deg: f64,
}

/// Largest population x packages: one batch of copies.
const MAX_COPIES: usize = 4096;

impl OptimizeConfig {
    /// Reads and checks the config at `path`.
    pub fn load(path: &Path) -> Result<Self, RunError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| RunError::Input(format!("{}: cannot read: {e}", path.display())))?;
        let config: Self = toml::from_str(&text)
            .map_err(|e| RunError::Input(format!("{}: {e}", path.display())))?;
        config.validate(path)?;
        Ok(config)
    }

    /// Checks every value (`path` is the config's file, for the messages).
    fn validate(&self, path: &Path) -> Result<(), RunError> {
        let fail = |key: &str, value: String, expected: &str| {
            Err(RunError::Input(format!(
                "{}: {key} = {value}: expected {expected}",
                path.display()
            )))
        };
        let (c, k, r) = (&self.cem, &self.knots, &self.risk);
        if self.conditions.packages == 0 {
            return fail("conditions.packages", "0".into(), ">= 1");
        }
        if c.population < 2 {
            return fail("cem.population", c.population.to_string(), ">= 2");
        }
        if c.population.saturating_mul(self.conditions.packages) > MAX_COPIES {
            return fail(
                "cem.population",
                c.population.to_string(),
                &format!("population x conditions.packages <= {MAX_COPIES}"),
            );
        }
        if c.elites == 0 || c.elites > c.population {
            return fail("cem.elites", c.elites.to_string(), "in [1, cem.population]");
        }
        if c.iterations == 0 || c.iterations > 10_000 {
            return fail("cem.iterations", c.iterations.to_string(), "in [1, 10000]");
        }
        if !(c.smoothing > 0.0 && c.smoothing <= 1.0) {
            return fail("cem.smoothing", c.smoothing.to_string(), "in (0, 1]");
        }
        if !(2..=64).contains(&k.count) {
            return fail("knots.count", k.count.to_string(), "in [2, 64]");
        }
        // Ten minutes is beyond any transport; a larger value is a typo, not a plan.
        if !(k.horizon_s.is_finite() && k.horizon_s > 0.0 && k.horizon_s <= 600.0) {
            return fail(
                "knots.horizon_s",
                k.horizon_s.to_string(),
                "in (0, 600] (s)",
            );
        }
        for (key, v) in [
            ("knots.initial_speed_m_s", k.initial_speed_m_s),
            ("knots.speed_std_m_s", k.speed_std_m_s),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return fail(key, v.to_string(), ">= 0");
            }
        }
        // The tilt offset's knots live within +-90 degrees; a wider spread is a typo.
        if !(k.tilt_std_deg.is_finite() && (0.0..=90.0).contains(&k.tilt_std_deg)) {
            return fail(
                "knots.tilt_std_deg",
                k.tilt_std_deg.to_string(),
                "in [0, 90] (degrees)",
            );
        }
        for (key, v) in [("risk.quantile", r.quantile), ("risk.weight", r.weight)] {
            if !(0.0..=1.0).contains(&v) {
                return fail(key, v.to_string(), "in [0, 1]");
            }
        }
        let tilts = &self.conditions.nominal_target_tilts_deg;
        if !tilts.is_empty() {
            if self.conditions.packages != 1 {
                return fail(
                    "conditions.packages",
                    self.conditions.packages.to_string(),
                    "1 with conditions.nominal_target_tilts_deg (the nominal package)",
                );
            }
            if tilts.len() > 64
                || tilts
                    .iter()
                    .any(|t| !(t.is_finite() && (0.0..=90.0).contains(t)))
            {
                return fail(
                    "conditions.nominal_target_tilts_deg",
                    format!("{tilts:?}"),
                    "at most 64 tilts in [0, 90] degrees",
                );
            }
        }
        if let Some(m) = &self.mpc {
            if !(m.horizon_s.is_finite() && m.horizon_s > 0.0 && m.horizon_s <= 10.0) {
                return fail("mpc.horizon_s", m.horizon_s.to_string(), "in (0, 10] (s)");
            }
            if !(2..=64).contains(&m.knots) {
                return fail("mpc.knots", m.knots.to_string(), "in [2, 64]");
            }
            if !(1..=1000).contains(&m.iterations) {
                return fail("mpc.iterations", m.iterations.to_string(), "in [1, 1000]");
            }
        }
        Ok(())
    }

    /// The task of the config's `transport` file (`path` is the config's own file; a relative
    /// `transport` is found as every config's relative paths are, [`rlpkg_toml_input::find_relative`],
    /// and so are the scene and files that file names), and that file's name as the task's source.
    /// The search's starting speed and its spread must be within the task's limit (beyond it, the
    /// first would be clamped without a word and the second would draw mostly clamped knots).
    pub fn load_task(&self, path: &Path) -> Result<(TransportConfig, String), RunError> {
        let file = rlpkg_toml_input::find_relative(&self.transport, path);
        let source = file.display().to_string();
        if !file.is_file() {
            return Err(RunError::Input(format!(
                "{}: transport = {:?}: expected a training config file with a [transport] table                  (found neither from the working folder nor from the config's folder upwards)",
                path.display(),
                self.transport.display().to_string()
            )));
        }
        let transport = crate::tasks::read_transport_config(&file).map_err(RunError::input)?;
        let limit = transport.limits.max_path_speed_m_s;
        for (key, value) in [
            ("knots.initial_speed_m_s", self.knots.initial_speed_m_s),
            ("knots.speed_std_m_s", self.knots.speed_std_m_s),
        ] {
            if value > limit {
                return Err(RunError::Input(format!(
                    "{}: {key} = {value}: expected at most the task's \
                     limits.max_path_speed_m_s = {limit} m/s ({source})",
                    path.display(),
                )));
            }
        }
        Ok((transport, source))
    }

    /// The `[mpc]` table for receding-horizon control of the `[conditions]` packages (`path` is
    /// the config's file, for the messages).
    pub fn mpc_settings(&self, path: &Path) -> Result<&MpcTable, RunError> {
        let Some(settings) = &self.mpc else {
            return Err(RunError::Input(format!(
                "{}: --mpc needs an [mpc] table (horizon_s, knots, iterations)",
                path.display()
            )));
        };
        if !self.conditions.nominal_target_tilts_deg.is_empty() {
            return Err(RunError::Input(format!(
                "{}: --mpc controls the [conditions] packages; expected no \
                 conditions.nominal_target_tilts_deg",
                path.display()
            )));
        }
        Ok(settings)
    }

    /// The decision variables' bounds and the CEM's starting distribution for `curve` under the
    /// task's limits: `(mean, std, lower, upper)`.
    pub fn decision_space(&self, transport: &TransportConfig, curve: &KnotCurve) -> [Vec<f64>; 4] {
        let (speed, tilt) = (
            transport.limits.max_path_speed_m_s,
            transport.limits.max_tilt_offset_deg.to_radians(),
        );
        let block = |v: f64| vec![v; curve.knots];
        let spread = self.knots.tilt_std_deg.to_radians();
        [
            [block(self.knots.initial_speed_m_s), block(0.0), block(0.0)].concat(),
            [
                block(self.knots.speed_std_m_s),
                block(spread),
                block(spread),
            ]
            .concat(),
            [block(0.0), block(-tilt), block(-tilt)].concat(),
            [block(speed), block(tilt), block(tilt)].concat(),
        ]
    }

    /// The CEM settings of `[cem]`.
    pub fn cem_settings(&self) -> CemSettings {
        CemSettings {
            population: self.cem.population,
            elites: self.cem.elites,
            smoothing: self.cem.smoothing,
            seed: self.cem.seed,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_config_finds_its_task_from_any_working_folder() {
        // The test runs in this crate's folder; the config names its task relative to the
        // repository, found from the config's folder upwards as every config's paths are.
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
        let path = root.join("configs/optimize/transport.toml");
        let config = OptimizeConfig::load(&path).unwrap();
        assert!(!config.transport.exists(), "run from the repository root");
        let (task, source) = config.load_task(&path).unwrap();
        assert!(Path::new(&source).is_absolute(), "{source}");
        assert!(Path::new(&task.scene).is_absolute(), "{}", task.scene);
    }
}
