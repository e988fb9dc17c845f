//! The calibration configuration (`configs/calibrate/study.toml`), parsed with serde and range-checked.
//!
//! Paths in the file are relative to the working directory (run `rlpkg calibrate` from the repository
//! root). Every error names the file, the key and what was expected.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::bo::{Acquisition, BoSettings};
use crate::smc::SmcSettings;
use crate::space::{ParamSpace, ParamSpec};
use rlpkg_mocap::{Dataset, Split, Trajectory};
use rlpkg_replay::loss::LossWeights;
use rlpkg_replay::LikelihoodSettings;
use rlpkg_sim::SceneConfig;

/// Simulator parameter names that can be calibrated (defined beside the replay set-up).
pub use rlpkg_replay::PARAMETER_NAMES;

/// A configuration error: file, key and what was expected.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file (or one it extends) could not be read; TOML syntax, an unknown key or a wrong
    /// type (the message names the key and line).
    #[error("{file}: {message}")]
    Parse {
        /// The configuration file.
        file: PathBuf,
        /// The TOML error.
        message: String,
    },
    /// A value out of range.
    #[error("{file}: key `{key}` = {value}: expected {expected}")]
    Range {
        /// The configuration file.
        file: PathBuf,
        /// Dotted key.
        key: String,
        /// The value found.
        value: String,
        /// What was expected.
        expected: String,
    },
}

/// The first id of `ids` that repeats an earlier one, with its index: a recording listed twice
/// would count twice in the loss without a word.
pub fn repeated_id(ids: &[String]) -> Option<(usize, &String)> {
    ids.iter()
        .enumerate()
        .find(|(i, id)| ids[..*i].contains(id))
}

/// Refuses `ids` (given as `option`, e.g. `--trajectories`) when one is listed twice.
pub fn check_unique_ids(option: &str, ids: &[String]) -> Result<(), String> {
    match repeated_id(ids) {
        Some((_, id)) => Err(format!(
            "{option}: {id} is listed twice; expected each trajectory id once"
        )),
        None => Ok(()),
    }
}

/// Simulator settings of the calibration.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimSettings {
    /// Simulator preset: `reference`, `physical`, or a scene TOML file (scene constants, time step,
    /// base values of the parameters that are not calibrated).
    pub preset: String,
    /// Particles inserted between neighbouring markers: grid (6 + 5p) x (7 + 6p) per layer.
    #[serde(default = "default_between")]
    pub between: usize,
    /// Time step override (s); the preset's when absent.
    pub dt: Option<f64>,
    /// Compare only the first `max_seconds` of each trajectory (short runs, tests); all when absent.
    pub max_seconds: Option<f64>,
    /// Iterations per substep of the implicit solvers (`integrator.iterations` of the scene); the
    /// preset's when absent. Too few leave the film's solve unconverged and the replays rough
    /// under nudges far below the noise (`rlpkg posterior CONFIG --spread 1e-6` shows it).
    pub iterations: Option<u32>,
    /// Hold the disc at each recording's start during the rest (`disc.hold_at_recorded_start` of
    /// the scene); the preset's setting when absent.
    pub hold_disc: Option<bool>,
    /// Turn the held disc to its recorded orientation during the rest hold (`disc.hold_orientation`
    /// of the scene); the preset's setting when absent.
    pub hold_orientation: Option<bool>,
}

fn default_between() -> usize {
    1
}

/// Optimiser settings.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OptimiserSettings {
    /// Batches of candidates after the initial design.
    pub iterations: usize,
    /// Candidates per batch (each is simulated on every training trajectory at once).
    pub batch_size: usize,
    /// Latin-hypercube points of the initial design (the preset's parameters are evaluated first).
    pub initial_points: usize,
    /// Acquisition function: `{ expected_improvement = { xi = 0.01 } }` or
    /// `{ confidence_bound = { kappa = 2.0 } }`.
    #[serde(default)]
    pub acquisition: Acquisition,
    /// Seed of the initial design and the acquisition search.
    #[serde(default)]
    pub seed: u64,
}

/// The whole calibration configuration.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrateConfig {
    /// Dataset folder (manifest.toml + one folder per trajectory).
    pub data: PathBuf,
    /// Trajectory ids to fit; the manifest's `train` split when absent.
    pub trajectories: Option<Vec<String>>,
    /// Output folder: evaluation log, best parameters, loss curve.
    pub out_dir: PathBuf,
    /// Simulator settings.
    pub sim: SimSettings,
    /// Bayesian optimisation settings (the paper's method); exactly one of `[optimiser]` and `[smc]`.
    #[serde(default)]
    pub optimiser: Option<OptimiserSettings>,
    /// Sequential Monte Carlo on the simulator ([`crate::smc`]): the posterior instead of a point.
    #[serde(default)]
    pub smc: Option<SmcSettings>,
    /// The likelihood the sampler uses ([`rlpkg_replay::likelihood`]).
    #[serde(default)]
    pub likelihood: LikelihoodSettings,
    /// Loss weights (object 1.0, package 0.2 by default, as the study).
    #[serde(default)]
    pub loss: LossWeights,
    /// Parameters to calibrate, with bounds and scale.
    #[serde(rename = "param")]
    pub params: Vec<ParamSpec>,
}

impl CalibrateConfig {
    /// Reads and validates a configuration file, with the files it extends merged in
    /// ([`rlpkg_toml_input::read_composed`]: `extends = "base.toml"`).
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let composed = rlpkg_toml_input::read_composed(path).map_err(|e| ConfigError::Parse {
            file: e.file().to_path_buf(),
            message: e.message(),
        })?;
        if !composed.is_merged() {
            return Self::parse(&composed.text, path);
        }
        // The merged text's line numbers are none of the files': name the key and the chain.
        Self::parse(&composed.text, path).map_err(|err| match err {
            ConfigError::Parse { file, message } => ConfigError::Parse {
                file,
                message: composed
                    .merged_error::<CalibrateConfig>()
                    .unwrap_or(message),
            },
            other => other,
        })
    }

    /// Parses and validates configuration text; `file` names it in errors.
    pub fn parse(text: &str, file: &Path) -> Result<Self, ConfigError> {
        let config: CalibrateConfig = toml::from_str(text).map_err(|e| ConfigError::Parse {
            file: file.to_path_buf(),
            message: e.to_string(),
        })?;
        config.validate(file)?;
        Ok(config)
    }

    fn validate(&self, file: &Path) -> Result<(), ConfigError> {
        let range = |key: &str, value: String, expected: &str| ConfigError::Range {
            file: file.to_path_buf(),
            key: key.into(),
            value,
            expected: expected.into(),
        };
        if self.sim.between > 8 {
            return Err(range(
                "sim.between",
                self.sim.between.to_string(),
                "an integer in [0, 8]",
            ));
        }
        if let Some(dt) = self.sim.dt {
            if !(dt > 0.0 && dt <= 1e-2) {
                return Err(range(
                    "sim.dt",
                    dt.to_string(),
                    "a time step in (0, 0.01] s",
                ));
            }
        }
        if let Some(n) = self.sim.iterations {
            if !(1..=1000).contains(&n) {
                return Err(range(
                    "sim.iterations",
                    n.to_string(),
                    "an integer in [1, 1000]",
                ));
            }
        }
        if let Some(s) = self.sim.max_seconds {
            if !(s > 0.0 && s.is_finite()) {
                return Err(range("sim.max_seconds", s.to_string(), "a duration > 0 s"));
            }
        }
        let o =
            match (&self.optimiser, &self.smc) {
                (Some(o), None) => o,
                (None, Some(smc)) => {
                    crate::smc::check_settings(self.params.len().max(1), smc)
                        .map_err(|e| range("smc", e.to_string(), "settings in range"))?;
                    let d = self.likelihood.decorrelation_s;
                    if !(0.0..=60.0).contains(&d) {
                        return Err(range(
                            "likelihood.decorrelation_s",
                            d.to_string(),
                            "a time in [0, 60] s",
                        ));
                    }
                    let r = self.likelihood.replicas;
                    if !(1..=64).contains(&r) {
                        return Err(range(
                            "likelihood.replicas",
                            r.to_string(),
                            "an integer in [1, 64]",
                        ));
                    }
                    let j = self.likelihood.replica_jitter;
                    if !(j > 0.0 && j <= 1e-2) {
                        return Err(range(
                            "likelihood.replica_jitter",
                            j.to_string(),
                            "a relative perturbation in (0, 0.01]",
                        ));
                    }
                    return self.validate_common(file);
                }
                (Some(_), Some(_)) => {
                    return Err(range(
                        "optimiser",
                        "[optimiser] and [smc]".into(),
                        "one method: [optimiser] (Bayesian optimisation) or [smc] (posterior)",
                    ))
                }
                (None, None) => return Err(range(
                    "optimiser",
                    "(none)".into(),
                    "an [optimiser] table (Bayesian optimisation) or an [smc] table (posterior)",
                )),
            };
        if !(1..=100_000).contains(&o.iterations) {
            return Err(range(
                "optimiser.iterations",
                o.iterations.to_string(),
                "an integer in [1, 100000]",
            ));
        }
        if !(1..=1024).contains(&o.batch_size) {
            return Err(range(
                "optimiser.batch_size",
                o.batch_size.to_string(),
                "an integer in [1, 1024]",
            ));
        }
        if !(1..=10_000).contains(&o.initial_points) {
            return Err(range(
                "optimiser.initial_points",
                o.initial_points.to_string(),
                "an integer in [1, 10000]",
            ));
        }
        match o.acquisition {
            Acquisition::ExpectedImprovement { xi } if !(0.0..=10.0).contains(&xi) => {
                return Err(range(
                    "optimiser.acquisition.expected_improvement.xi",
                    xi.to_string(),
                    "a margin in [0, 10]",
                ));
            }
            Acquisition::ConfidenceBound { kappa } if !(0.0..=100.0).contains(&kappa) => {
                return Err(range(
                    "optimiser.acquisition.confidence_bound.kappa",
                    kappa.to_string(),
                    "a weight in [0, 100]",
                ));
            }
            _ => {}
        }
        self.validate_common(file)
    }

    /// Checks of the keys both methods share.
    fn validate_common(&self, file: &Path) -> Result<(), ConfigError> {
        let range = |key: &str, value: String, expected: &str| ConfigError::Range {
            file: file.to_path_buf(),
            key: key.into(),
            value,
            expected: expected.into(),
        };
        for (key, w) in [
            ("loss.object", self.loss.object),
            ("loss.package", self.loss.package),
        ] {
            if !(w >= 0.0 && w.is_finite()) {
                return Err(range(key, w.to_string(), "a weight >= 0"));
            }
        }
        if self.loss.object == 0.0 && self.loss.package == 0.0 {
            return Err(range(
                "loss",
                "{ object = 0, package = 0 }".into(),
                "at least one weight > 0 (every candidate would have loss 0)",
            ));
        }
        if let Some(ids) = &self.trajectories {
            if ids.is_empty() {
                return Err(range(
                    "trajectories",
                    "[]".into(),
                    "at least one trajectory id (or omit the key for the train split)",
                ));
            }
            if let Some((i, id)) = repeated_id(ids) {
                return Err(range(
                    &format!("trajectories[{i}]"),
                    format!("{id:?}"),
                    "each trajectory id once",
                ));
            }
        }
        if self.params.is_empty() {
            return Err(range(
                "param",
                "(none)".into(),
                "at least one [[param]] table",
            ));
        }
        for (i, p) in self.params.iter().enumerate() {
            if !PARAMETER_NAMES.contains(&p.name.as_str()) {
                return Err(range(
                    &format!("param[{i}].name"),
                    format!("\"{}\"", p.name),
                    &format!("one of {}", PARAMETER_NAMES.join(", ")),
                ));
            }
        }
        ParamSpace::new(self.params.clone()).map_err(|e| {
            range(
                "param",
                e.to_string(),
                "finite bounds with lower < upper (lower > 0 when log = true), unique names",
            )
        })?;
        Ok(())
    }

    /// The search space of the `[[param]]` tables (validated by [`CalibrateConfig::load`]).
    pub fn space(&self) -> ParamSpace {
        ParamSpace::new(self.params.clone()).expect("validated when loaded")
    }

    /// The scene this config calibrates: its preset with the grid, step and disc-holding
    /// overrides. `source` (the config file) is named in an error.
    pub fn scene(&self, source: &Path) -> Result<SceneConfig, String> {
        let mut scene =
            rlpkg_replay::load_scene(&self.sim.preset, Some(self.sim.between), self.sim.dt)
                .map_err(|e| format!("{e} (sim.preset of {})", source.display()))?;
        if let Some(hold) = self.sim.hold_disc {
            scene.disc.hold_at_recorded_start = hold;
        }
        if let Some(n) = self.sim.iterations {
            scene.integrator.iterations = n;
        }
        if let Some(hold) = self.sim.hold_orientation {
            scene.disc.hold_orientation = hold;
        }
        Ok(scene)
    }

    /// The ids of the trajectories to fit: the config's `trajectories`, else the dataset's train
    /// split; an error when that leaves none.
    pub fn trajectory_ids(&self, dataset: &Dataset) -> Result<Vec<String>, String> {
        let ids = match &self.trajectories {
            Some(ids) => ids.clone(),
            None => dataset.ids(Some(Split::Train)),
        };
        if ids.is_empty() {
            return Err(format!(
                "{}: no trajectory to fit (the manifest has no train split)",
                self.data.display()
            ));
        }
        Ok(ids)
    }

    /// The ids and recordings the calibration fits ([`CalibrateConfig::trajectory_ids`] of its
    /// dataset `data`).
    pub fn training_trajectories(&self) -> Result<(Vec<String>, Vec<Trajectory>), String> {
        let dataset = Dataset::open(&self.data).map_err(|e| e.to_string())?;
        let ids = self.trajectory_ids(&dataset)?;
        let trajectories = ids
            .iter()
            .map(|id| dataset.load(id).map_err(|e| e.to_string()))
            .collect::<Result<Vec<_>, _>>()?;
        Ok((ids, trajectories))
    }

    /// The `[optimiser]` table of a Bayesian-optimisation config (validated: present unless the
    /// config has `[smc]`, which callers check first).
    pub fn optimiser(&self) -> &OptimiserSettings {
        self.optimiser
            .as_ref()
            .expect("a config without [smc] has [optimiser] (validated when loaded)")
    }

    /// The `[optimiser]` table, to override from the command line.
    pub fn optimiser_mut(&mut self) -> &mut OptimiserSettings {
        self.optimiser
            .as_mut()
            .expect("a config without [smc] has [optimiser] (validated when loaded)")
    }

    /// The optimiser settings for [`crate::bo::BayesOpt`].
    pub fn bo_settings(&self) -> BoSettings {
        let o = self.optimiser();
        BoSettings {
            initial_points: o.initial_points,
            batch_size: o.batch_size,
            acquisition: o.acquisition,
            seed: o.seed,
            ..BoSettings::default()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
data = "data/deformable-sim-real"
out_dir = "runs/calibrate"
trajectories = ["HHHHH", "HHLHL"]

[sim]
preset = "configs/scenes/study.toml"
between = 1
max_seconds = 2.0
hold_disc = true
hold_orientation = true

[optimiser]
iterations = 10
batch_size = 4
initial_points = 8
acquisition = { confidence_bound = { kappa = 2.5 } }
seed = 3

[loss]
object = 1.0
package = 0.5

[[param]]
name = "k_tri_e"
lower = 1.0e2
upper = 1.0e7
log = true

[[param]]
name = "mu_con"
lower = 0.0
upper = 2.0
"#;

    fn parse(text: &str) -> Result<CalibrateConfig, ConfigError> {
        CalibrateConfig::parse(text, Path::new("calibrate.toml"))
    }

    #[test]
    fn a_repeated_id_is_refused_naming_the_option() {
        let ids: Vec<String> = ["A", "B", "A"].map(String::from).to_vec();
        assert_eq!(
            check_unique_ids("--trajectories", &ids).unwrap_err(),
            "--trajectories: A is listed twice; expected each trajectory id once"
        );
        assert!(check_unique_ids("--trajectories", &ids[..2]).is_ok());
    }

    #[test]
    fn training_trajectories_are_the_listed_ones_else_the_train_split() {
        let mut config = parse(GOOD).unwrap();
        config.data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/deformable-sim-real");
        let (ids, trajectories) = config.training_trajectories().unwrap();
        assert_eq!(ids, ["HHHHH", "HHLHL"]);
        let loaded: Vec<&str> = trajectories.iter().map(|t| t.id.as_str()).collect();
        assert_eq!(loaded, ids);
        config.trajectories = None;
        let dataset = Dataset::open(&config.data).unwrap();
        let (ids, trajectories) = config.training_trajectories().unwrap();
        assert_eq!(ids, dataset.ids(Some(Split::Train)));
        assert_eq!(trajectories.len(), ids.len());
        config.trajectories = Some(vec!["NOPE".into()]);
        let err = config.training_trajectories().unwrap_err();
        assert!(err.contains("NOPE"), "{err}");
    }

    #[test]
    fn parses_a_full_config() {
        let c = parse(GOOD).unwrap();
        assert_eq!(c.space().names(), vec!["k_tri_e", "mu_con"]);
        assert!(c.params[0].log && !c.params[1].log);
        assert_eq!(
            c.optimiser().acquisition,
            Acquisition::ConfidenceBound { kappa: 2.5 }
        );
        assert_eq!(c.loss.package, 0.5);
        assert_eq!(c.sim.max_seconds, Some(2.0));
        assert_eq!(c.sim.hold_disc, Some(true));
        assert_eq!(c.sim.hold_orientation, Some(true));
        assert_eq!(c.bo_settings().seed, 3);
    }

    #[test]
    fn shipped_configs_are_valid() {
        let configs = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs");
        let first = CalibrateConfig::load(&configs.join("calibrate/study.toml")).unwrap();
        let refine = CalibrateConfig::load(&configs.join("calibrate/study-stage2.toml")).unwrap();
        let whole = CalibrateConfig::load(&configs.join("calibrate/study-stage3.toml")).unwrap();
        // Each stage starts from the previous stage's output.
        assert_eq!(
            Path::new(&refine.sim.preset),
            first.out_dir.join("calibrated.toml")
        );
        assert_eq!(
            Path::new(&whole.sim.preset),
            refine.out_dir.join("calibrated.toml")
        );
        assert_eq!(first.space().names(), refine.space().names());
        // The third stage fits the disc's mass scale and contact on whole trajectories.
        assert_eq!(
            whole.space().names(),
            ["disc_mass_scale", "k_con_e", "k_con_d", "mu_con"]
        );
        assert_eq!(whole.sim.max_seconds, None);
        let shipped =
            rlpkg_sim::SceneConfig::load(&configs.join("scenes/calibrated-study.toml")).unwrap();
        assert!(shipped.disc.hold_at_recorded_start);
        assert_eq!(
            shipped.package.grid,
            rlpkg_replay::grid_between_markers(first.sim.between)
        );
        // The SI scene's second stage refines the first with the disc's orientation held.
        let si = CalibrateConfig::load(&configs.join("calibrate/soft-film.toml")).unwrap();
        let si_refine =
            CalibrateConfig::load(&configs.join("calibrate/soft-film-stage2.toml")).unwrap();
        assert_eq!(
            Path::new(&si_refine.sim.preset),
            si.out_dir.join("calibrated.toml")
        );
        assert_eq!(si.space().names(), si_refine.space().names());
        assert_eq!(si_refine.sim.hold_orientation, Some(true));
        // The stiff-film stage: the same parameters, membrane bounds that include real packaging
        // film (1e4-2e4 N/m), on a scene stepped finely enough to carry it.
        let stiff = CalibrateConfig::load(&configs.join("calibrate/real-film.toml")).unwrap();
        assert_eq!(si.space().names(), stiff.space().names());
        for spec in stiff
            .params
            .iter()
            .filter(|p| ["k_tri_e", "k_tri_a"].contains(&p.name.as_str()))
        {
            assert!(spec.lower <= 1.0e4 && spec.upper >= 2.0e4, "{}", spec.name);
        }
        let scene =
            rlpkg_sim::SceneConfig::load(&configs.join("scenes/physical-real-film.toml")).unwrap();
        assert_eq!(
            Path::new(&stiff.sim.preset),
            Path::new("configs/scenes/physical-real-film.toml")
        );
        assert!(scene.integrator.substep_rate_hz >= 1200.0);
        let fitted =
            rlpkg_sim::SceneConfig::load(&configs.join("scenes/calibrated-real-film.toml"))
                .unwrap();
        assert_eq!(
            fitted.integrator.substep_rate_hz,
            scene.integrator.substep_rate_hz
        );
        assert!(fitted.disc.hold_at_recorded_start && fitted.disc.hold_orientation);
        // The coarse real-film scene: the same parameters on the 11 x 13 grid at the real-film step,
        // starting from the fine fit, with every fitted value inside its bounds.
        let coarse =
            CalibrateConfig::load(&configs.join("calibrate/coarse-real-film.toml")).unwrap();
        assert_eq!(si.space().names(), coarse.space().names());
        assert_eq!(
            Path::new(&coarse.sim.preset),
            Path::new("configs/scenes/calibrated-real-film.toml")
        );
        let coarse_fit =
            rlpkg_sim::SceneConfig::load(&configs.join("scenes/calibrated-coarse-real-film.toml"))
                .unwrap();
        assert_eq!(
            coarse_fit.package.grid,
            rlpkg_replay::grid_between_markers(coarse.sim.between)
        );
        assert_eq!(coarse_fit.package.grid, [11, 13]);
        assert_eq!(
            coarse_fit.integrator.substep_rate_hz,
            scene.integrator.substep_rate_hz
        );
        let fitted_values = rlpkg_replay::Candidate::of_scene(&coarse_fit);
        for spec in &coarse.params {
            let value = rlpkg_replay::get_param(&fitted_values, &spec.name).unwrap();
            assert!(
                value > spec.lower * 1.01 && value < spec.upper / 1.01,
                "{} = {value} at a bound of [{}, {}]",
                spec.name,
                spec.lower,
                spec.upper
            );
        }
    }

    /// A calibration config shipped in `configs/calibrate/`, by its file stem.
    fn shipped(name: &str) -> CalibrateConfig {
        let configs = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs");
        CalibrateConfig::load(&configs.join(format!("calibrate/{name}.toml"))).unwrap()
    }

    #[test]
    fn shipped_global_descent_chain_is_valid() {
        // The real-film chain on global descent: stage 1 from block descent's fit, each later stage
        // from the one before, the same parameters throughout with the membrane's shear stiffness
        // bounded to 1e4-4e4 N/m after the first, and the last at the shipped scene's step.
        let configs = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs");
        let first = shipped("global-coarse-real-film");
        assert_eq!(
            Path::new(&first.sim.preset),
            Path::new("configs/scenes/global-coarse-real-film.toml")
        );
        let mut previous =
            Path::new("configs/scenes/calibrated-global-coarse-real-film.toml").to_path_buf();
        let stages = ["stage2", "stage3", "stage4", "200hz"];
        for stage in stages {
            let c = shipped(&format!("global-coarse-real-film-{stage}"));
            assert_eq!(Path::new(&c.sim.preset), previous, "{stage}");
            assert_eq!(c.space().names(), first.space().names(), "{stage}");
            let membrane = c.params.iter().find(|p| p.name == "k_tri_e").unwrap();
            assert!(
                membrane.lower >= 1.0e4 && membrane.upper <= 4.0e4,
                "{stage}"
            );
            assert_eq!(c.sim.dt.is_some(), stage == "200hz", "{stage}");
            previous = c.out_dir.join("calibrated.toml");
        }
        let last = shipped("global-coarse-real-film-200hz");
        let scene = rlpkg_sim::SceneConfig::load(
            &configs.join("scenes/calibrated-global-coarse-real-film-200hz.toml"),
        )
        .unwrap();
        assert_eq!(scene.integrator.substep_rate_hz, 1.0 / last.sim.dt.unwrap());
        assert_eq!(
            scene.package.grid,
            rlpkg_replay::grid_between_markers(last.sim.between)
        );
    }

    #[test]
    fn shipped_larger_step_configs_search_the_posteriors_box() {
        // The fits at 120 and 100 substeps/s that bound the real film's step: each starts from the
        // shipped 200 Hz scene and searches the box of its posterior's prior, at its own step.
        let prior = shipped("global-coarse-real-film-200hz-local");
        for rate_hz in [120.0, 100.0] {
            let c = shipped(&format!("global-coarse-real-film-{rate_hz}hz"));
            assert_eq!(c.sim.preset, prior.sim.preset, "{rate_hz}");
            assert_eq!(1.0 / c.sim.dt.unwrap(), rate_hz);
            assert_eq!(c.params, prior.params, "{rate_hz}");
            assert_eq!(c.sim.between, prior.sim.between, "{rate_hz}");
        }
    }

    #[test]
    fn the_mixed_packages_v1_posterior_changes_only_the_samplers_reference() {
        let base = shipped("posterior-packages-v1");
        let mixed = shipped("posterior-packages-v1-mixed");
        let (b, m) = (base.smc.unwrap(), mixed.smc.unwrap());
        assert_eq!((b.prior_share, b.chaos_points), (0.0, 1));
        assert_eq!((m.prior_share, m.chaos_points), (0.5, 4));
        let unmixed = crate::smc::SmcSettings {
            prior_share: 0.0,
            chaos_points: 1,
            ..m
        };
        assert_eq!(unmixed, b);
        assert_eq!(mixed.params, base.params);
        assert_eq!(mixed.trajectories, base.trajectories);
        assert_ne!(mixed.out_dir, base.out_dir);
    }

    #[test]
    fn an_smc_config_samples_instead_of_optimising_and_names_one_method() {
        let optimiser = GOOD.find("[optimiser]").unwrap();
        let end = GOOD.find("[loss]").unwrap();
        let smc =
            "[smc]\nparticles = 64\nmoves = 3\nseed = 2\n\n[likelihood]\ndecorrelation_s = 0.2\n\n";
        let text = format!("{}{smc}{}", &GOOD[..optimiser], &GOOD[end..]);
        let c = parse(&text).unwrap();
        let settings = c.smc.unwrap();
        assert_eq!(
            (settings.particles, settings.moves, settings.seed),
            (64, 3, 2)
        );
        assert_eq!(settings.ess_fraction, 0.5);
        assert_eq!(c.likelihood.decorrelation_s, 0.2);
        assert!(c.optimiser.is_none());
        let both = format!("{}{smc}{}", &GOOD[..end], &GOOD[end..]);
        assert!(parse(&both).unwrap_err().to_string().contains("one method"));
        let neither = format!("{}{}", &GOOD[..optimiser], &GOOD[end..]);
        assert!(parse(&neither).unwrap_err().to_string().contains("[smc]"));
        let few = text.replace("particles = 64", "particles = 3");
        assert!(parse(&few)
            .unwrap_err()
            .to_string()
            .contains("particles = 3"));
        let long = text.replace("decorrelation_s = 0.2", "decorrelation_s = 100.0");
        let message = parse(&long).unwrap_err().to_string();
        assert!(message.contains("likelihood.decorrelation_s"), "{message}");
        // One replay per candidate unless asked; replicas and their jitter are range-checked.
        assert_eq!(
            (c.likelihood.replicas, c.likelihood.replica_jitter),
            (1, 1e-6)
        );
        let replicated = text.replace(
            "decorrelation_s = 0.2",
            "decorrelation_s = 0.2\nreplicas = 4",
        );
        assert_eq!(parse(&replicated).unwrap().likelihood.replicas, 4);
        for (bad, key) in [
            ("replicas = 0", "likelihood.replicas"),
            ("replicas = 65", "likelihood.replicas"),
            ("replica_jitter = 0.0", "likelihood.replica_jitter"),
            ("replica_jitter = 0.1", "likelihood.replica_jitter"),
        ] {
            let text = text.replace(
                "decorrelation_s = 0.2",
                &format!("decorrelation_s = 0.2\n{bad}"),
            );
            let message = parse(&text).unwrap_err().to_string();
            assert!(message.contains(key), "{bad}: {message}");
        }
    }

    #[test]
    fn errors_name_file_key_and_expectation() {
        let cases = [
            (
                GOOD.replace("batch_size = 4", "batch_size = 0"),
                "optimiser.batch_size",
            ),
            (
                GOOD.replace("name = \"mu_con\"", "name = \"mu\""),
                "param[1].name",
            ),
            (GOOD.replace("lower = 1.0e2", "lower = 0.0"), "log scale"),
            (GOOD.replace("between = 1", "between = 12"), "sim.between"),
            (
                GOOD.replace(r#"["HHHHH", "HHLHL"]"#, r#"["HHHHH", "HHLHL", "HHHHH"]"#),
                "trajectories[2]",
            ),
            (
                GOOD.replace("between = 1", "between = 1\niterations = 0"),
                "sim.iterations",
            ),
            (GOOD.replace("kappa = 2.5", "kappa = -1.0"), "kappa"),
            (GOOD.replace("seed = 3", "seed = 3\ncolour = 1"), "colour"),
            (
                GOOD.replace("package = 0.5", "package = -0.5"),
                "loss.package",
            ),
        ];
        for (text, key) in cases {
            let msg = parse(&text).unwrap_err().to_string();
            assert!(
                msg.contains("calibrate.toml") && msg.contains(key),
                "{key}: {msg}"
            );
        }
    }

    #[test]
    fn sim_iterations_override_the_presets() {
        let text = GOOD.replace("configs/scenes/study.toml", "reference");
        let own = parse(&text)
            .unwrap()
            .scene(Path::new("calibrate.toml"))
            .unwrap();
        let more = parse(&text.replace("between = 1", "between = 1\niterations = 48"))
            .unwrap()
            .scene(Path::new("calibrate.toml"))
            .unwrap();
        assert_ne!(own.integrator.iterations, 48);
        assert_eq!(more.integrator.iterations, 48);
    }

    #[test]
    fn a_config_extends_another_and_is_checked_merged() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("base.toml"), GOOD).unwrap();
        let stage = "extends = \"base.toml\"\nout_dir = \"runs/stage2\"\n[optimiser]\nseed = 4\n[[param]]\nname = \"mu_con\"\nlower = 0.5\nupper = 1.5\n";
        std::fs::write(dir.path().join("stage2.toml"), stage).unwrap();
        let merged = CalibrateConfig::load(&dir.path().join("stage2.toml")).unwrap();
        let mut expected = parse(GOOD).unwrap();
        expected.out_dir = "runs/stage2".into();
        expected.optimiser.as_mut().unwrap().seed = 4;
        // The parameter list is replaced whole, not merged entry by entry.
        expected.params = vec![ParamSpec {
            lower: 0.5,
            upper: 1.5,
            ..expected.params[1].clone()
        }];
        assert_eq!(merged, expected);
        // A bad value in the chain names the key and both files.
        std::fs::write(
            dir.path().join("bad.toml"),
            "extends = \"base.toml\"\n[sim]\nbetween = \"x\"\n",
        )
        .unwrap();
        let err = CalibrateConfig::load(&dir.path().join("bad.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("key `sim.between`") && err.contains("extending"),
            "{err}"
        );
    }
}
