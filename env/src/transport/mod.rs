//! `Transport-v0`: carry a package with a moving object inside from a pick pose to a place pose
//! with a target tilt, fast and without a seal failure, on the batched package simulator.
//!
//! # Episode
//! Each copy starts from a settled, sealed package at the pick pose: `reset(seed)` settles
//! `settled_variants` randomised packages once (the scene's rest period plus `settle_s`) and
//! snapshots them; every episode restores one of those snapshots into its copy of the simulator
//! ([`rlpkg_sim::Simulator::restore`]) instead of re-simulating the rest. The tool then follows a
//! recorded path (the recording whose final tilt is nearest the episode's target tilt, shifted to
//! start where the variant's tool is and bent towards a jittered place position) at the speed the
//! policy commands, tilting from the pick orientation to the target tilt as the recording did,
//! plus the policy's tilt offsets.
//!
//! # Action (3 values, every control interval `1 / control_hz`)
//! `path_speed` (m/s, [0, `max_path_speed_m_s`]; its change is limited to `max_path_accel_m_s2`,
//! and it is capped so the tool can still stop at the place pose), `tilt_offset_x` and
//! `tilt_offset_z` (rad, ±`max_tilt_offset_deg`: rotation of the tool about world x and z away
//! from the path's nominal orientation; the bound shrinks to zero over the path's last
//! `tilt_offset_fade_m` when that is set). Values outside the bounds are clamped to them. A
//! tracking controller turns the reference pose into a twist command
//! ([`rlpkg_sim::ToolCommand::Twist`]) within the robot limits (`[transport.limits]`, which
//! replace the scene's `[tool_limits]`).
//!
//! With `[transport.profile_rate]` the first action is `profile_rate` instead (unit 1, [0,
//! `max_rate`], its change limited to `max_rate_change_per_s`): the clock rate at which the
//! reference plays a time-optimal, jerk-limited motion profile planned at the episode's start
//! ([`ProfileRateAction`]); the nominal tilt then follows the minimum-jerk schedule, and the
//! actor reads the profile's clock and its last rate where it would read the episode time and
//! its last path speed. A robot running such a policy plans the same profile
//! ([`plan_path_profile`] under the limits of the run's config).
//!
//! # Observations
//! The actor sees [`ACTOR_OBSERVATIONS`] and, with `observation = "privileged"` (the default), the
//! simulator's exact values and each cup's utilisation; with `observation = "sensors"`, only what
//! a real cell measures, noisy and delayed (`sensors`: vacuum pressure per cup, wrist
//! force-torque, tool pose and twist). The critic additionally sees privileged simulator state
//! ([`critic_only_observations`]). Every name comes with its unit.
//!
//! # Reward, termination
//! See [`RewardTerms`]; each term is also reported per step in [`crate::VecEnv::info`] (names in
//! [`crate::VecEnv::info_names`]). Terminated on success (at the place pose within
//! `[transport.success]`, object settled) or failure (a cup detached, the package dropped, or the
//! simulator froze the copy as unhealthy); truncated at `time_limit_s`.
//!
//! # Modules
//! - `config`: the `[transport]` table and the scene it names;
//! - `recordings`: the recorded paths and timings, from the motion-capture dataset;
//! - `path`: one recorded path, resampled in arc length;
//! - `episode`: settled variants, the draws of an episode, reset and episode ends;
//! - `control`: action to reference to the tool's twist command, and the scripted, recorded and
//!   motion-profile baselines' actions;
//! - `profile`: the time-optimal, jerk-limited motion profile along a path (the profile baseline);
//! - `observe`: observation names, the spec and the observation rows;
//! - `sensors`: the cell's sensors (vacuum leak model, wrist wrench, noise, delay lines);
//! - `reward`: failure, success, reward terms and the info row of a step;
//! - `snapshot`: the saved state for checkpoints (serde; the flat layout is read too);
//! - `outcome`: episode outcomes, traces, their summaries and the per-episode table;
//! - `run_error`: what stops an evaluation or an optimisation, and the stop request's check;
//! - `governor`: the vacuum governor, a closed-loop baseline on the task's own plan;
//! - `optimize`: the cross-entropy method over an open-loop command's knots (`rlpkg optimize`),
//!   its config and its files, and receding-horizon control (`rlpkg optimize --mpc`);
//! - `evaluation`: a policy beside the baselines over the same seeded episodes (`rlpkg eval`);
//! - `geometry`: vector and rotation helpers.

mod config;
mod control;
mod episode;
mod evaluation;
mod geometry;
mod governor;
mod observe;
mod optimize;
mod outcome;
mod path;
mod profile;
mod recordings;
mod reward;
mod run_error;
mod sensors;
mod snapshot;
#[cfg(test)]
mod test_support;

use std::sync::Arc;

use rand_chacha::ChaCha8Rng;
use rlpkg_sim::{CupLoad, EnvObservation, HealthEvent, Model, SceneConfig, SealEvent, Simulator};

pub use config::{
    load_scene, DrawRows, FailureLimits, FailureReplay, HeldOutDraws, ObservationMode,
    ProfileRateAction, RewardWeights, SuccessTolerances, TransportConfig, TransportLimits,
    TransportRandomization, LIMIT_HEADROOM,
};
pub use control::TiltSchedule;
pub use episode::{replaced_packages_line, EpisodeConditions};
pub use evaluation::{
    evaluate_policy, EpisodeFilm, EvaluationReport, EvaluationSettings, PolicyActions,
    ProfileBaseline, RecordedBaseline, RecordingComparison, RecordingSet, Snapshot,
    TransportEvaluation,
};
pub use governor::VacuumGovernor;
pub use observe::{
    critic_only_observations, spec_of, ACTOR_OBSERVATIONS, PRIVILEGED_MARKERS, WRIST_OBSERVATIONS,
};
pub use optimize::cem::{Cem, CemSettings, RiskMeasure};
pub use optimize::config::{CemTable, Conditions, Knots, MpcTable, OptimizeConfig, Risk};
pub use optimize::curve::{CommandLibrary, KnotCurve, ACTIONS};
pub use optimize::mpc::{control_packages, HorizonSearch, RecedingHorizon};
pub use optimize::open_loop::{optimise_open_loop, OpenLoopProblem};
pub use optimize::output::{
    library_summary_json, IterationCosts, LibraryEntry, MpcRun, OpenLoopResult, OptimizeSummary,
    OptimizedCommand, OptimizedReadError, ToolSample, OUTPUT_FILES,
};
pub use outcome::{
    run_episodes, run_traced_episodes, Ending, EpisodeOutcome, EpisodeTable, OutcomeSummary,
    TracePoint,
};
pub use path::{ToolPeaks, TransportPath};
pub use profile::{
    minimum_jerk, plan_path_profile, LimitUse, MotionLimits, PathProfile, JERK_RAMP_S, PLAN_STEP_S,
};
pub use recordings::{load_paths, recorded_timings};
pub use reward::{info_names, Failure, RewardTerms, StepOutcome, REWARD_TERM_NAMES};
pub use run_error::RunError;
pub use sensors::{
    cup_vacuum_pa, CupSeal, DelayLine, SensorConfig, SensorNoise, VacuumDynamics, LEAK_LOAD,
    LEAK_OPEN, LEAK_PEELED, LEAK_SEALED, MAX_DELAY_STEPS,
};

use crate::{env_rng, EnvError, EnvSpec, EnvState, StepBuffers, VecEnv};
use episode::{Episode, Variant};
use rlpkg_vec_env::{Autoreset, AutoresetMode, ResetCopies};
use sensors::Sensors;

/// The id the command line's task registry knows this environment by.
pub const ID: &str = "Transport-v0";

/// Largest cup utilisation the task reads: twice the seal's limit. The simulator reports an
/// attached cup loaded past its capacity as infinitely utilised until its next seal update
/// detaches it (and does not check seals during the scene's rest period); the reward, the
/// observations, the vacuum sensors and the evaluation read this value instead, so a failing cup
/// costs a bounded seal penalty and no observation is infinite.
pub const UTILISATION_CEILING: f32 = 2.0;

/// The transport task on `num_envs` copies of the package simulator.
pub struct Transport {
    config: TransportConfig,
    spec: EnvSpec,
    info_names: Vec<String>,
    model: Arc<Model>,
    sim: Simulator,
    paths: Vec<TransportPath>,
    /// Material parameters the randomisation scales (their log scales are critic inputs).
    materials: Vec<String>,
    variants: Vec<Variant>,
    /// The unrandomised package settled at construction: it checks that the scene's cups seal,
    /// and stands in for a randomised variant whose cups do not.
    fallback: Variant,
    /// Randomised variants of the last reset replaced by `fallback`.
    replaced_variants: usize,
    /// Of those, the ones that stayed sealed but failed the grasp check.
    weak_grasps: usize,
    /// Each randomised variant's lowest cup vacuum over the supply after settling.
    grasp_vacuum_ratios: Vec<f64>,
    /// Each variant's failure rate over its finished training episodes
    /// (`[transport.randomization.replay]`; zeros without it).
    variant_failures: Vec<f64>,
    /// Each copy's current episode.
    episodes: Vec<Episode>,
    rngs: Vec<ChaCha8Rng>,
    states: Vec<EnvObservation>,
    loads: Vec<CupLoad>,
    /// Each cup's force on the tool (N, world; read only for a wrist force-torque sensor).
    cup_forces: Vec<[f32; 3]>,
    /// The cell's sensors (`observation = "sensors"`).
    sensors: Option<Sensors>,
    health: Vec<HealthEvent>,
    seal: Vec<SealEvent>,
    info: Vec<f32>,
    substeps_per_step: u64,
    dt: f64,
    /// Evaluation mode: a finished copy is retired instead of restarted.
    retire_finished: bool,
    /// Copies retired since the last reset (evaluation mode), or since their episode ended
    /// (next-step and disabled autoreset: the simulator does not step them until they restart).
    retired: Vec<bool>,
    /// What a copy whose episode ended does, and which copies wait for their restart.
    autoreset: Autoreset,
    /// How the nominal orientation tilts along the path.
    tilt_schedule: TiltSchedule,
    /// Whether the first action is a motion profile's clock rate (`[transport.profile_rate]`)
    /// rather than the path speed; the baselines drive with path speeds.
    profile_rate: Option<ProfileRateAction>,
    /// Each copy's motion profile for its current episode (with `profile_rate`).
    plans: Vec<Option<PathProfile>>,
}

fn sim_error(e: impl std::fmt::Display) -> EnvError {
    EnvError::Simulator(e.to_string())
}

impl Transport {
    /// `num_envs` copies configured by the `[transport]` table `config` (`source` names its file
    /// in messages). Call [`VecEnv::reset`] before stepping: it settles the package variants.
    pub fn new(config: TransportConfig, num_envs: usize, source: &str) -> Result<Self, EnvError> {
        let scene = load_scene(&config, source)?;
        let paths = load_paths(&config, scene.disc.hold_at_recorded_start, source)?;
        Self::with_scene(config, scene, paths, num_envs)
    }

    /// As [`Transport::new`] with the scene and paths given (e.g. a test's weaker seal).
    pub fn with_scene(
        config: TransportConfig,
        scene: SceneConfig,
        paths: Vec<TransportPath>,
        num_envs: usize,
    ) -> Result<Self, EnvError> {
        if num_envs == 0 {
            return Err(EnvError::NoEnvs(num_envs));
        }
        if paths.is_empty() {
            return Err(EnvError::Simulator("no transport path".into()));
        }
        let model = Arc::new(Model::new(&scene).map_err(sim_error)?);
        let base = episode::base_spec(&scene, &paths[0]);
        let fallback = episode::settle_unrandomised(
            &model,
            base.clone(),
            &paths[0],
            config.settle_s,
            config.grasp_min_vacuum_ratio,
        )?;
        let sim = Simulator::new(model.clone(), vec![base; num_envs]).map_err(sim_error)?;
        let num_cups = model.num_cups();
        let materials = observe::randomised_materials(&config);
        let spec = observe::build_spec(&config, num_cups);
        let substeps_per_step = (1.0 / config.control_hz / sim.dt() as f64).round().max(1.0) as u64;
        let dt = substeps_per_step as f64 * sim.dt() as f64;
        let info_names = info_names();
        let sensors = match (&config.observation, &config.sensors) {
            (ObservationMode::Sensors, Some(c)) => Some(Sensors::new(c.clone(), num_envs, dt)),
            _ => None,
        };
        let wrist = sensors
            .as_ref()
            .is_some_and(|s| s.config.wrist_force_torque);
        Ok(Self {
            cup_forces: vec![[0.0; 3]; if wrist { num_envs * num_cups } else { 0 }],
            sensors,
            info: vec![0.0; num_envs * info_names.len()],
            info_names,
            episodes: vec![Episode::default(); num_envs],
            rngs: (0..num_envs).map(|i| env_rng(0, i)).collect(),
            states: vec![EnvObservation::default(); num_envs],
            loads: vec![CupLoad::default(); num_envs * num_cups],
            health: Vec::new(),
            seal: Vec::new(),
            variants: Vec::new(),
            fallback,
            replaced_variants: 0,
            weak_grasps: 0,
            grasp_vacuum_ratios: Vec::new(),
            variant_failures: Vec::new(),
            spec,
            model,
            sim,
            paths,
            materials,
            substeps_per_step,
            dt,
            retire_finished: false,
            retired: vec![false; num_envs],
            autoreset: Autoreset::new(num_envs),
            // The profile is planned along the minimum-jerk tilt (as the profile baseline's).
            tilt_schedule: match config.profile_rate {
                Some(_) => TiltSchedule::MinimumJerk,
                None => TiltSchedule::Recorded,
            },
            profile_rate: config.profile_rate,
            plans: vec![None; num_envs],
            config,
        })
    }

    /// Evaluation mode (`true`): a copy whose episode ends is not restarted but retired until the
    /// next reset. It then keeps its final observation, gets reward 0 and is neither terminated
    /// nor truncated again, and its simulator environment stops: a block of copies that have all
    /// finished costs nothing, so a batch of one-episode copies runs as fast as its slowest block.
    pub fn set_retire_finished(&mut self, on: bool) {
        self.retire_finished = on;
    }

    /// Makes every action's first value a path speed and the nominal tilt the recorded one,
    /// whatever `[transport.profile_rate]` says: the baselines' actions
    /// ([`Transport::scripted_actions`], [`Transport::profile_actions`], ...) are path speeds.
    /// Call before the reset.
    pub fn drive_path_speed(&mut self) {
        self.profile_rate = None;
        self.plans.fill(None);
        self.tilt_schedule = TiltSchedule::Recorded;
    }

    /// The supply vacuum (Pa below ambient) the cell's gauge reads for copy `env`'s episode;
    /// `None` without sensors.
    pub fn supply_vacuum_pa(&self, env: usize) -> Option<f64> {
        self.sensors.as_ref().map(|s| s.copies[env].supply_pa)
    }

    /// The simulator the copies run on (particle positions, the disc, ... for pictures).
    pub fn simulator(&self) -> &Simulator {
        &self.sim
    }

    /// Whether copy `env` is retired (evaluation mode, episode over).
    pub fn is_retired(&self, env: usize) -> bool {
        self.retired[env]
    }

    /// The recorded paths.
    pub fn paths(&self) -> &[TransportPath] {
        &self.paths
    }

    /// The control interval (s): a whole number of simulator substeps.
    pub fn control_interval_s(&self) -> f64 {
        self.dt
    }

    /// The seal events of the last step (every copy), as the simulator reported them.
    pub fn seal_events(&self) -> &[SealEvent] {
        &self.seal
    }

    /// Reads every copy's state and cup loads from the simulator.
    fn read_simulator(&mut self) -> Result<(), EnvError> {
        self.sim.read_states(&mut self.states).map_err(sim_error)?;
        self.read_loads()
    }

    /// Reads every cup's load (and, for a wrist sensor, its force) from the simulator.
    fn read_loads(&mut self) -> Result<(), EnvError> {
        self.sim
            .read_cup_loads(&mut self.loads)
            .map_err(sim_error)?;
        saturate_utilisation(&mut self.loads);
        if !self.cup_forces.is_empty() {
            self.sim
                .read_cup_forces(&mut self.cup_forces)
                .map_err(sim_error)?;
        }
        Ok(())
    }

    /// Simulates one control interval and collects its health and seal events, states and loads.
    fn advance(&mut self) -> Result<(), EnvError> {
        self.sim.step(self.substeps_per_step);
        self.health.clear();
        self.seal.clear();
        self.sim.drain_events(&mut self.health, &mut self.seal);
        self.read_simulator()
    }
}

/// Caps every cup's utilisation at [`UTILISATION_CEILING`] (a non-finite one included).
pub(super) fn saturate_utilisation(loads: &mut [CupLoad]) {
    for load in loads {
        // `f32::min` returns the ceiling for NaN too.
        load.utilisation = load.utilisation.min(UTILISATION_CEILING);
    }
}

impl VecEnv for Transport {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn num_envs(&self) -> usize {
        self.episodes.len()
    }

    fn reset(&mut self, seed: u64, out: &mut StepBuffers) -> Result<(), EnvError> {
        self.try_reset(seed, out)
    }

    fn reset_copies(&mut self, copies: ResetCopies, out: &mut StepBuffers) -> Result<(), EnvError> {
        self.restart_copies(copies, out)
    }

    /// `settled_variants`, `replaced_variants` and `weak_grasps`: the randomised packages of the
    /// last reset, how many of them were replaced by the unrandomised one (not sealed, frozen,
    /// or failing the grasp check), and how many of those failed only the grasp check.
    fn reset_counts(&self) -> Vec<(String, usize)> {
        vec![
            ("settled_variants".into(), self.variants.len()),
            ("replaced_variants".into(), self.replaced_variants),
            ("weak_grasps".into(), self.weak_grasps),
        ]
    }

    fn autoreset_mode(&self) -> AutoresetMode {
        self.autoreset.mode()
    }

    /// Next-step and disabled autoreset retire a copy whose episode ended (as evaluation mode
    /// does, [`Transport::set_retire_finished`]): the simulator does not step it until it restarts.
    fn set_autoreset_mode(&mut self, mode: AutoresetMode) -> Result<(), EnvError> {
        self.autoreset.set_mode(mode);
        Ok(())
    }

    fn step(&mut self, actions: &[f32], out: &mut StepBuffers) -> Result<(), EnvError> {
        self.check_actions(actions)?;
        self.autoreset.check_step()?;
        // Next-step autoreset: copies retired when their episode ended restart after this step's
        // simulation, which they sit out.
        let restarting: Vec<usize> = (0..self.num_envs())
            .filter(|&env| self.autoreset.restarts_now(env))
            .collect();
        let start_states = self.states.clone();
        match self.sensors.as_mut() {
            Some(sensors) => {
                // The robot executes the action the policy sent `d_act` steps ago.
                let mut delayed = actions.to_vec();
                for (env, row) in delayed.chunks_exact_mut(3).enumerate() {
                    if !self.retired[env] {
                        let applied = sensors.delay_action(env, row);
                        row.copy_from_slice(&applied);
                    }
                }
                self.command_tools(&delayed)?;
            }
            None => self.command_tools(actions)?,
        }
        self.advance()?;
        self.measure();
        let mut finished = Vec::new();
        for (env, start) in start_states.iter().enumerate() {
            if self.retired[env] {
                out.rewards[env] = 0.0;
                out.terminated[env] = false;
                out.truncated[env] = false;
                continue;
            }
            let ended = self.score_step(env, start, out);
            self.observe_into(env, out, true);
            if ended {
                finished.push(env);
            } else {
                self.observe_into(env, out, false);
                self.remember_observation(env);
            }
        }
        self.finish_episodes(&finished, out)?;
        self.restart_waiting(&restarting, out)
    }

    fn save_state(&self) -> EnvState {
        self.saved_state()
    }

    fn load_state(&mut self, state: &EnvState) -> Result<(), EnvError> {
        self.restore_saved(state)
    }

    fn info_names(&self) -> &[String] {
        &self.info_names
    }

    fn info(&self) -> &[f32] {
        &self.info
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utilisation_read_by_the_task_is_capped_at_the_ceiling() {
        let load = |utilisation| CupLoad {
            attached: true,
            utilisation,
            ..CupLoad::default()
        };
        let mut loads = [f32::INFINITY, f32::NAN, 5.0, 0.7, 0.0].map(load);
        saturate_utilisation(&mut loads);
        let read: Vec<f32> = loads.iter().map(|l| l.utilisation).collect();
        assert_eq!(read, [2.0, 2.0, 2.0, 0.7, 0.0]);
        // The seal penalty of a step with a failing cup is then finite: 4 x (2 - 0.5) x 0.05.
        let weights = RewardWeights {
            progress: 0.0,
            time: 0.0,
            object_motion: 0.0,
            seal: 4.0,
            seal_threshold: 0.5,
            jerk: 0.0,
            angular_jerk: 0.0,
            failure: 30.0,
            success: 0.0,
        };
        let outcome = StepOutcome {
            dt_s: 0.05,
            peak_utilisation: read[0] as f64,
            failed: true,
            ..StepOutcome::default()
        };
        let terms = RewardTerms::of(&weights, &outcome);
        assert!((terms.seal + 0.3).abs() < 1e-12, "{terms:?}");
        assert!((terms.total() + 30.3).abs() < 1e-12, "{terms:?}");
    }
}
