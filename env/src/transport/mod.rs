//! `Transport-v0`: carry a package with a moving object inside from a pick pose to a place pose
//! with a target tilt, fast and without a seal failure, on the batched package simulator.
//!
//! # Episode
//! Each copy starts from a settled, sealed package at the pick pose: `reset(seed)` settles
//! `settled_variants` randomised packages once (the scene's rest period plus `settle_s`) and
//! snapshots them; every episode restores one of those snapshots into its simulator lane
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
//! from the path's nominal orientation). Values outside the bounds are clamped to them. A
//! tracking controller turns the reference pose into a twist command
//! ([`rlpkg_sim::ToolCommand::Twist`]) within the robot limits (`[transport.limits]`, which
//! replace the scene's `[tool_limits]`).
//!
//! # Observations
//! The actor sees what a real cell measures ([`ACTOR_OBSERVATIONS`]); the critic additionally sees
//! privileged simulator state ([`critic_only_observations`]). Every name comes with its unit.
//!
//! # Reward, termination
//! See [`RewardTerms`]; each term is also reported per step in [`crate::VecEnv::info`] (names in
//! [`crate::VecEnv::info_names`]). Terminated on success (at the place pose within
//! `[transport.success]`, object settled) or failure (a cup detached, the package dropped, or the
//! simulator froze the copy as unhealthy); truncated at `time_limit_s`.

mod config;
mod evaluate;
mod path;
mod reward;

use std::path::Path;
use std::sync::Arc;

use glam::{DQuat, DVec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rlpkg_sim::{
    CupLoad, EnvObservation, EnvSnapshot, EpisodeSpec, HealthEvent, Model, SceneConfig, SealEvent,
    SealEventKind, Simulator, ToolCommand, ToolLimits, ToolTrajectory,
};

pub use config::{
    FailureLimits, RewardWeights, SuccessTolerances, TransportConfig, TransportLimits,
    TransportRandomization, RECORDED_PEAK_ACCEL_M_S2, RECORDED_PEAK_ANGULAR_SPEED_RAD_S,
    RECORDED_PEAK_SPEED_M_S,
};
pub use evaluate::{
    run_episodes, run_traced_episodes, Ending, EpisodeOutcome, OutcomeSummary, TracePoint,
};
pub use path::TransportPath;
pub use reward::{RewardTerms, StepOutcome, REWARD_TERM_NAMES};

use crate::{
    check_action_len, env_rng, rng_from_words, rng_to_words, EnvError, EnvSpec, EnvState, Space,
    SpaceKind, StepBuffers, VecEnv, RNG_WORDS,
};

/// The id [`crate::make_with`] knows this environment by.
pub const ID: &str = "Transport-v0";

/// The actor's observations (name, unit) before the per-cup utilisations
/// (`cup<k>_utilisation`, unit `1`): quantities a real cell measures (robot state, its own
/// commands and goal, vacuum sensors).
pub const ACTOR_OBSERVATIONS: [(&str, &str); 19] = [
    ("goal_dx", "m"),
    ("goal_dy", "m"),
    ("goal_dz", "m"),
    ("goal_rotation_x", "rad"),
    ("goal_rotation_y", "rad"),
    ("goal_rotation_z", "rad"),
    ("tool_velocity_x", "m/s"),
    ("tool_velocity_y", "m/s"),
    ("tool_velocity_z", "m/s"),
    ("tool_angular_velocity_x", "rad/s"),
    ("tool_angular_velocity_y", "rad/s"),
    ("tool_angular_velocity_z", "rad/s"),
    ("path_progress", "1"),
    ("path_speed", "m/s"),
    ("episode_time", "s"),
    ("target_tilt", "rad"),
    ("previous_path_speed_command", "m/s"),
    ("previous_tilt_offset_x", "rad"),
    ("previous_tilt_offset_z", "rad"),
];

/// Words that mark a privileged quantity (one a real cell does not measure): the actor's
/// observation names contain none of them, every critic-only name contains one.
pub const PRIVILEGED_MARKERS: [&str; 4] = ["object", "load", "material", "mass"];

/// The critic's observations beyond the actor's (name, unit) for `num_cups` cups and the
/// randomised material parameters `materials`: the object relative to the tool (tool frame),
/// its mass, every cup's normal and shear load, and each material parameter's log scale.
pub fn critic_only_observations(num_cups: usize, materials: &[String]) -> Vec<(String, String)> {
    let mut out: Vec<(String, String)> = [
        ("object_in_tool_x", "m"),
        ("object_in_tool_y", "m"),
        ("object_in_tool_z", "m"),
        ("object_in_tool_qx", "1"),
        ("object_in_tool_qy", "1"),
        ("object_in_tool_qz", "1"),
        ("object_in_tool_qw", "1"),
        ("object_in_tool_vx", "m/s"),
        ("object_in_tool_vy", "m/s"),
        ("object_in_tool_vz", "m/s"),
        ("object_in_tool_wx", "rad/s"),
        ("object_in_tool_wy", "rad/s"),
        ("object_in_tool_wz", "rad/s"),
        ("object_mass", "kg"),
    ]
    .iter()
    .map(|(n, u)| (n.to_string(), u.to_string()))
    .collect();
    for k in 0..num_cups {
        out.push((format!("cup{k}_normal_load"), "N".into()));
        out.push((format!("cup{k}_shear_load"), "N".into()));
    }
    for name in materials {
        out.push((format!("material_log_scale_{name}"), "1".into()));
    }
    out
}

/// Why an episode failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Failure {
    /// A cup peeled, was pulled off or slid off (a seal event).
    CupDetached,
    /// No cup holds the package, or the object is further from the tool than allowed.
    Dropped,
    /// The simulator froze the copy (non-finite, exploding, object outside the package).
    Unhealthy,
}

/// Names of the per-step values in [`VecEnv::info`], in order: the reward terms
/// (`reward/<term>`), then episode outcomes (1 on the step an episode ends that way, else 0),
/// then state figures.
pub fn info_names() -> Vec<String> {
    REWARD_TERM_NAMES
        .iter()
        .map(|n| format!("reward/{n}"))
        .chain(
            [
                "episode/success",
                "episode/failure_cup_detached",
                "episode/failure_dropped",
                "episode/failure_unhealthy",
                "episode/truncated",
                "state/peak_seal_utilisation",
                "state/object_motion_m",
                "state/path_speed_m_s",
            ]
            .iter()
            .map(|n| n.to_string()),
        )
        .collect()
}

/// What was drawn for one copy's current episode.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeConditions {
    /// Recording whose path the episode follows.
    pub path_id: String,
    /// Settled variant the episode started from.
    pub variant: usize,
    /// Tool tilt at the place pose (rad).
    pub target_tilt_rad: f64,
    /// Offset of the place position from the recorded one (m).
    pub goal_jitter_m: [f64; 3],
    /// Offset of the pick position from the recorded one (m).
    pub start_offset_m: [f64; 3],
    /// Object mass (kg).
    pub object_mass_kg: f32,
    /// Yaw of the package under the tool (rad).
    pub package_yaw_rad: f32,
}

/// A settled package state episodes start from.
#[derive(Debug, Clone)]
struct Variant {
    snapshot: EnvSnapshot,
    /// Tool position at pick (m).
    tool_start: DVec3,
}

/// One copy's episode beyond the simulator state.
#[derive(Debug, Clone, Copy, Default)]
struct Lane {
    path: usize,
    variant: usize,
    /// Added to the path's points: the variant's tool start minus the path's first point.
    start_offset: DVec3,
    /// Place position offset, blended in along the path.
    goal_jitter: DVec3,
    target_tilt: f64,
    /// Arc length of the reference along the path (m).
    progress: f64,
    path_speed: f64,
    /// Arc length the last command advanced the reference by (m).
    last_advance: f64,
    previous_action: [f64; 3],
    previous_accel: DVec3,
    previous_angular_accel: DVec3,
    previous_object_in_tool: DVec3,
    /// Simulator time of the episode start (s).
    start_time: f64,
    steps: usize,
}

/// The reference reaches the place pose when it is this close (m): braking to the end of the
/// path would otherwise approach it forever.
const PATH_END_SNAP_M: f64 = 1e-3;

/// Real numbers per lane in [`Lane::to_reals`].
const LANE_REALS: usize = 23;

impl Lane {
    fn to_reals(self) -> [f64; LANE_REALS] {
        let [a, b, c] = self.start_offset.to_array();
        let [d, e, f] = self.goal_jitter.to_array();
        let [g, h, i] = self.previous_action;
        let [j, k, l] = self.previous_accel.to_array();
        let [m, n, o] = self.previous_angular_accel.to_array();
        let [p, q, r] = self.previous_object_in_tool.to_array();
        [
            a,
            b,
            c,
            d,
            e,
            f,
            self.target_tilt,
            self.progress,
            self.path_speed,
            g,
            h,
            i,
            j,
            k,
            l,
            m,
            n,
            o,
            p,
            q,
            r,
            self.start_time,
            self.last_advance,
        ]
    }

    fn from_reals(r: &[f64], path: usize, variant: usize, steps: usize) -> Self {
        let v = |k: usize| DVec3::new(r[k], r[k + 1], r[k + 2]);
        Lane {
            path,
            variant,
            start_offset: v(0),
            goal_jitter: v(3),
            target_tilt: r[6],
            progress: r[7],
            path_speed: r[8],
            previous_action: [r[9], r[10], r[11]],
            previous_accel: v(12),
            previous_angular_accel: v(15),
            previous_object_in_tool: v(18),
            start_time: r[21],
            last_advance: r[22],
            steps,
        }
    }
}

/// The transport task on `num_envs` simulator lanes.
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
    lanes: Vec<Lane>,
    rngs: Vec<ChaCha8Rng>,
    states: Vec<EnvObservation>,
    loads: Vec<CupLoad>,
    health: Vec<HealthEvent>,
    seal: Vec<SealEvent>,
    info: Vec<f32>,
    substeps_per_step: u64,
    dt: f64,
    /// Evaluation mode: a finished copy is retired instead of restarted.
    retire_finished: bool,
    /// Copies retired since the last reset (evaluation mode).
    retired: Vec<bool>,
}

fn sim_error(e: impl std::fmt::Display) -> EnvError {
    EnvError::Simulator(e.to_string())
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

/// The recorded paths `config.paths` names, from `config.recordings`, with the pick set-up the
/// scene's replay rule gives (`hold_disc`: the scene's `disc.hold_at_recorded_start`).
pub fn load_paths(
    config: &TransportConfig,
    hold_disc: bool,
    source: &str,
) -> Result<Vec<TransportPath>, EnvError> {
    let data_error = |message: String| EnvError::ConfigParse {
        file: source.to_string(),
        message,
    };
    let dataset = rlpkg_mocap::Dataset::open(Path::new(&config.recordings))
        .map_err(|e| data_error(format!("transport.recordings: {e}")))?;
    config
        .paths
        .iter()
        .map(|id| {
            let trajectory = dataset
                .load(id)
                .map_err(|e| data_error(format!("transport.paths: {e}")))?;
            let target = rlpkg_replay::Target::new(&trajectory, Some(0.0), hold_disc)
                .map_err(|e| data_error(format!("transport.paths: {e}")))?;
            TransportPath::from_recording(&trajectory, target.placement)
                .map_err(|e| data_error(format!("transport.paths: {e}")))
        })
        .collect()
}

/// Recording levels in order (`low`, `medium`, `high`), for nearest-level matching.
const LEVELS: [&str; 3] = ["low", "medium", "high"];

/// For each of `config.paths`, the recording of velocity level `velocity` (`low`, `medium` or
/// `high`) whose timing a recorded baseline plays along that path ([`Transport::timed_actions`]):
/// the one with the path's placement tilt level and object mass level, else the nearest tilt
/// level (the dataset has no low-velocity recording at the high tilt), then the nearest mass.
pub fn recorded_timings(
    config: &TransportConfig,
    velocity: &str,
    source: &str,
) -> Result<Vec<TransportPath>, EnvError> {
    let data_error = |message: String| EnvError::ConfigParse {
        file: source.to_string(),
        message,
    };
    let level = |x: &Option<String>| {
        x.as_deref()
            .and_then(|v| LEVELS.iter().position(|l| *l == v))
    };
    let wanted = LEVELS.iter().position(|l| *l == velocity).ok_or_else(|| {
        data_error(format!(
            "velocity level `{velocity}`: expected low, medium or high"
        ))
    })?;
    let dataset = rlpkg_mocap::Dataset::open(Path::new(&config.recordings))
        .map_err(|e| data_error(format!("transport.recordings: {e}")))?;
    config
        .paths
        .iter()
        .map(|id| {
            let entry = |id: &str| dataset.entries.iter().find(|e| e.id == id);
            let path_entry = entry(id)
                .ok_or_else(|| data_error(format!("transport.paths: no recording `{id}`")))?;
            let (tilt, mass) = (level(&path_entry.orientation), level(&path_entry.mass));
            let distance = |a: Option<usize>, b: Option<usize>| match (a, b) {
                (Some(a), Some(b)) => a.abs_diff(b),
                _ => LEVELS.len(),
            };
            let chosen = dataset
                .entries
                .iter()
                .filter(|e| level(&e.velocity) == Some(wanted))
                .min_by_key(|e| {
                    (
                        distance(level(&e.orientation), tilt),
                        distance(level(&e.mass), mass),
                        e.id.clone(),
                    )
                })
                .ok_or_else(|| {
                    data_error(format!(
                        "transport.recordings: no {velocity}-velocity recording"
                    ))
                })?;
            let trajectory = dataset
                .load(&chosen.id)
                .map_err(|e| data_error(format!("transport.recordings: {e}")))?;
            let target = rlpkg_replay::Target::new(&trajectory, Some(0.0), false)
                .map_err(|e| data_error(format!("transport.recordings: {e}")))?;
            TransportPath::from_recording(&trajectory, target.placement)
                .map_err(|e| data_error(format!("transport.recordings: {e}")))
        })
        .collect()
}

/// The material parameters the package randomisation scales, in name order.
fn randomised_materials(config: &TransportConfig) -> Vec<String> {
    config
        .randomization
        .package
        .param_scale
        .keys()
        .cloned()
        .collect()
}

/// Observation groups, action space and episode length for a scene with `num_cups` cups.
fn build_spec(config: &TransportConfig, num_cups: usize) -> EnvSpec {
    let l = &config.limits;
    let tilt = l.max_tilt_offset_deg.to_radians() as f32;
    let mut observation: Vec<(String, String)> = ACTOR_OBSERVATIONS
        .iter()
        .map(|(n, u)| (n.to_string(), u.to_string()))
        .collect();
    observation.extend((0..num_cups).map(|k| (format!("cup{k}_utilisation"), "1".to_string())));
    let critic: Vec<(String, String)> = observation
        .iter()
        .cloned()
        .chain(critic_only_observations(
            num_cups,
            &randomised_materials(config),
        ))
        .collect();
    let space = |rows: &[(String, String)]| Space {
        kind: SpaceKind::Continuous,
        names: rows.iter().map(|r| r.0.clone()).collect(),
        units: rows.iter().map(|r| r.1.clone()).collect(),
        low: vec![f32::MIN; rows.len()],
        high: vec![f32::MAX; rows.len()],
    };
    EnvSpec {
        id: ID.to_string(),
        observation: space(&observation),
        critic_observation: Some(space(&critic)),
        action: Space::continuous(&[
            ("path_speed", "m/s", 0.0, l.max_path_speed_m_s as f32),
            ("tilt_offset_x", "rad", -tilt, tilt),
            ("tilt_offset_z", "rad", -tilt, tilt),
        ]),
        max_episode_steps: (config.time_limit_s * config.control_hz).ceil() as usize,
    }
}

/// The spec of the environment `config` describes, without simulating anything (the scene is
/// loaded for its number of cups).
pub fn spec_of(config: &TransportConfig, source: &str) -> Result<EnvSpec, EnvError> {
    let scene = load_scene(config, source)?;
    let model = Model::new(&scene).map_err(sim_error)?;
    Ok(build_spec(config, model.num_cups()))
}

/// Uniform draw in `[lo, hi]` (`lo` when the range is empty).
fn uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    if lo < hi {
        rng.random_range(lo..=hi)
    } else {
        lo
    }
}

/// A uniform point in the ball of radius `r` (3-D) or, with `horizontal`, the disc (x, z).
fn uniform_offset(rng: &mut ChaCha8Rng, r: f64, horizontal: bool) -> DVec3 {
    if r <= 0.0 {
        return DVec3::ZERO;
    }
    loop {
        let p = DVec3::new(
            uniform(rng, -1.0, 1.0),
            if horizontal {
                0.0
            } else {
                uniform(rng, -1.0, 1.0)
            },
            uniform(rng, -1.0, 1.0),
        );
        if p.length_squared() <= 1.0 {
            return p * r;
        }
    }
}

/// The generator of settled variant `k` for `seed` (independent of the copies' streams).
fn variant_rng(seed: u64, k: usize) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(1 << 32 | k as u64);
    rng
}

fn v3(a: [f32; 3]) -> DVec3 {
    DVec3::new(a[0] as f64, a[1] as f64, a[2] as f64)
}

fn quat(q: [f32; 4]) -> DQuat {
    DQuat::from_xyzw(q[0] as f64, q[1] as f64, q[2] as f64, q[3] as f64).normalize()
}

/// Rotation vector taking `from` to `to` (world frame, shortest way).
fn rotation_between(from: DQuat, to: DQuat) -> DVec3 {
    let mut d = to * from.inverse();
    if d.w < 0.0 {
        d = -d;
    }
    d.to_scaled_axis()
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
        let base = Self::base_spec(&scene, &paths[0]);
        let fallback = {
            let (mut settled, held) = Self::settle(&model, vec![base.clone()], config.settle_s)?;
            if !held[0] {
                return Err(EnvError::ConfigParse {
                    file: "[transport]".into(),
                    message: format!(
                        "the package of recording {} does not stay sealed by all cups in this \
                         scene after the rest period (seal settings too weak for its mass?)",
                        paths[0].id
                    ),
                });
            }
            Variant {
                snapshot: settled.remove(0),
                tool_start: paths[0].points[0],
            }
        };
        let sim = Simulator::new(model.clone(), vec![base; num_envs]).map_err(sim_error)?;
        let num_cups = model.num_cups();
        let materials = randomised_materials(&config);
        let spec = build_spec(&config, num_cups);
        let substeps_per_step = (1.0 / config.control_hz / sim.dt() as f64).round().max(1.0) as u64;
        let dt = substeps_per_step as f64 * sim.dt() as f64;
        let info_names = info_names();
        Ok(Self {
            info: vec![0.0; num_envs * info_names.len()],
            info_names,
            lanes: vec![Lane::default(); num_envs],
            rngs: (0..num_envs).map(|i| env_rng(0, i)).collect(),
            states: vec![EnvObservation::default(); num_envs],
            loads: vec![CupLoad::default(); num_envs * num_cups],
            health: Vec::new(),
            seal: Vec::new(),
            variants: Vec::new(),
            fallback,
            replaced_variants: 0,
            config,
            spec,
            model,
            sim,
            paths,
            materials,
            substeps_per_step,
            dt,
            retire_finished: false,
            retired: vec![false; num_envs],
        })
    }

    /// Evaluation mode (`true`): a copy whose episode ends is not restarted but retired until the
    /// next reset. It then keeps its final observation, gets reward 0 and is neither terminated
    /// nor truncated again, and its simulator lane stops: a block of copies that have all
    /// finished costs nothing, so a batch of one-episode copies runs as fast as its slowest block.
    pub fn set_retire_finished(&mut self, on: bool) {
        self.retire_finished = on;
    }

    /// The simulator the copies run on (particle positions, the disc, ... for pictures).
    pub fn simulator(&self) -> &Simulator {
        &self.sim
    }

    /// Whether copy `env` is retired (evaluation mode, episode over).
    pub fn is_retired(&self, env: usize) -> bool {
        self.retired[env]
    }

    /// Copy `env`'s tool and object now, for plots of an episode.
    pub fn trace_point(&self, env: usize) -> TracePoint {
        let lane = &self.lanes[env];
        let state = &self.states[env];
        let cups = self.model.num_cups();
        let start_axis = self.paths[lane.path].start_orientation * DVec3::Y;
        let axis = quat(state.tool_orientation) * DVec3::Y;
        TracePoint {
            time_s: lane.steps as f64 * self.dt,
            path_speed_m_s: lane.path_speed,
            tool_speed_m_s: v3(state.tool_velocity).length(),
            tool_tilt_deg: axis.dot(start_axis).clamp(-1.0, 1.0).acos().to_degrees(),
            object_in_tool_m: v3(state.disc_in_tool.position).to_array(),
            peak_seal_utilisation: self.loads[env * cups..(env + 1) * cups]
                .iter()
                .map(|c| c.utilisation as f64)
                .fold(0.0, f64::max),
        }
    }

    /// The recorded paths.
    pub fn paths(&self) -> &[TransportPath] {
        &self.paths
    }

    /// The control interval (s): a whole number of simulator substeps.
    pub fn control_interval_s(&self) -> f64 {
        self.dt
    }

    /// What was drawn for copy `env`'s current episode (after [`VecEnv::reset`]).
    pub fn conditions(&self, env: usize) -> EpisodeConditions {
        let lane = &self.lanes[env];
        let spec = self.sim.spec(env);
        EpisodeConditions {
            path_id: self.paths[lane.path].id.clone(),
            variant: lane.variant,
            target_tilt_rad: lane.target_tilt,
            goal_jitter_m: lane.goal_jitter.to_array(),
            start_offset_m: (self.variants[lane.variant].tool_start - self.paths[0].points[0])
                .to_array(),
            object_mass_kg: spec.object_mass_kg,
            package_yaw_rad: spec.placement.package_yaw_rad,
        }
    }

    /// The scripted baseline's actions for every copy now: the recorded path's own progress
    /// over time, played `time_scale` times as fast (1 = as recorded, 2 = twice as fast), as the
    /// path speed that brings the reference to where the recording was at the end of the next
    /// control interval, and no tilt offset (the nominal orientation already follows the recorded
    /// tilt profile).
    pub fn scripted_actions(&self, time_scale: f64) -> Vec<f32> {
        self.timed_actions(&self.paths, time_scale)
    }

    /// As [`Transport::scripted_actions`], with the progress over time of `timings[p]` (another
    /// recording, e.g. the medium-velocity one of the same tilt level; see [`recorded_timings`])
    /// scaled to the length of path `p`: the recorded timing played along the episode's path.
    pub fn timed_actions(&self, timings: &[TransportPath], time_scale: f64) -> Vec<f32> {
        let t = self.dt;
        self.lanes
            .iter()
            .flat_map(|lane| {
                let path = &self.paths[lane.path];
                let timing = &timings[lane.path];
                let stretch = path.length_m / timing.length_m;
                let elapsed = lane.steps as f64 * t;
                let planned = timing.recorded_progress(time_scale * (elapsed + t)) * stretch;
                let ahead = planned - lane.progress;
                [(ahead.max(0.0) / t) as f32, 0.0, 0.0]
            })
            .collect()
    }

    /// The seal events of the last step (every copy), as the simulator reported them.
    pub fn seal_events(&self) -> &[SealEvent] {
        &self.seal
    }

    /// The package at pick on `path`, the tool held at its start pose.
    fn base_spec(scene: &SceneConfig, path: &TransportPath) -> EpisodeSpec {
        let q = path.start_orientation;
        EpisodeSpec {
            placement: path.placement,
            params: scene.params,
            object_mass_kg: path.object_mass_kg,
            disc_mass_scale: None,
            trajectory: Arc::new(ToolTrajectory::hold(
                path.points[0].to_array(),
                [q.x, q.y, q.z, q.w],
            )),
        }
    }

    /// Settles `settled_variants` randomised packages (drawn from `seed`) and snapshots them.
    fn settle_variants(&mut self, seed: u64) -> Result<(), EnvError> {
        let scene = &self.model.config;
        let r = &self.config.randomization;
        let path = &self.paths[0];
        let mut specs = Vec::with_capacity(self.config.settled_variants);
        let mut starts = Vec::with_capacity(self.config.settled_variants);
        for k in 0..self.config.settled_variants {
            let mut rng = variant_rng(seed, k);
            let jitter = uniform_offset(&mut rng, r.start_jitter_m, true);
            let mut spec = Self::base_spec(scene, path);
            spec = r.package.apply(&spec, &mut rng);
            let j = jitter.as_vec3().to_array();
            let pl = &mut spec.placement;
            for (c, d) in pl.package_origin.iter_mut().zip(j) {
                *c += d;
            }
            for (c, d) in pl.cup_point.iter_mut().zip(j) {
                *c += d;
            }
            for (c, d) in pl.disc_position.iter_mut().zip(j) {
                *c += d;
            }
            if let Some(hold) = &mut pl.disc_hold {
                for (c, d) in hold.iter_mut().zip(j) {
                    *c += d;
                }
            }
            let start = path.points[0] + jitter;
            let q = path.start_orientation;
            spec.trajectory =
                Arc::new(ToolTrajectory::hold(start.to_array(), [q.x, q.y, q.z, q.w]));
            specs.push(spec);
            starts.push(start);
        }
        let (snapshots, held) = Self::settle(&self.model, specs, self.config.settle_s)?;
        self.replaced_variants = held.iter().filter(|&&h| !h).count();
        self.variants = snapshots
            .into_iter()
            .zip(starts)
            .zip(held)
            .map(|((snapshot, tool_start), held)| {
                if held {
                    Variant {
                        snapshot,
                        tool_start,
                    }
                } else {
                    self.fallback.clone()
                }
            })
            .collect();
        Ok(())
    }

    /// Simulates `specs` through the rest period and `settle_s`; returns their snapshots and
    /// whether every cup of each still holds a healthy package.
    fn settle(
        model: &Arc<Model>,
        specs: Vec<EpisodeSpec>,
        settle_s: f64,
    ) -> Result<(Vec<EnvSnapshot>, Vec<bool>), EnvError> {
        let mut sim = Simulator::new(model.clone(), specs).map_err(sim_error)?;
        let seconds = model.config.cups.rest_time_s as f64 + settle_s;
        sim.step((seconds / sim.dt() as f64).round() as u64);
        let mut states = vec![EnvObservation::default(); sim.num_envs()];
        sim.read_states(&mut states).map_err(sim_error)?;
        let cups = model.num_cups() as u32;
        let held = states
            .iter()
            .map(|s| !s.frozen && s.cups_attached == cups)
            .collect();
        Ok(((0..sim.num_envs()).map(|k| sim.snapshot(k)).collect(), held))
    }

    /// How many randomised packages of the last reset did not stay sealed and were replaced by
    /// the unrandomised one.
    pub fn replaced_variants(&self) -> usize {
        self.replaced_variants
    }

    /// Starts a new episode in copy `env`: a random settled variant, target tilt, path and goal.
    fn start_episode(&mut self, env: usize) -> Result<(), EnvError> {
        let r = &self.config.randomization;
        let rng = &mut self.rngs[env];
        let variant = rng.random_range(0..self.variants.len());
        let tilt = uniform(rng, r.target_tilt_deg[0], r.target_tilt_deg[1]).to_radians();
        let goal_jitter = uniform_offset(rng, r.goal_jitter_m, false);
        let path = self
            .paths
            .iter()
            .enumerate()
            .min_by(|a, b| {
                let da = (a.1.recorded_final_tilt_rad - tilt).abs();
                let db = (b.1.recorded_final_tilt_rad - tilt).abs();
                da.total_cmp(&db)
            })
            .map(|(i, _)| i)
            .expect("at least one path");
        let tool_start = self.variants[variant].tool_start;
        self.sim
            .restore(env, &self.variants[variant].snapshot)
            .map_err(sim_error)?;
        let state = self.read_state(env)?;
        self.lanes[env] = Lane {
            path,
            variant,
            start_offset: tool_start - self.paths[path].points[0],
            goal_jitter,
            target_tilt: tilt,
            previous_object_in_tool: v3(state.disc_in_tool.position),
            start_time: state.time,
            ..Lane::default()
        };
        Ok(())
    }

    fn read_state(&mut self, env: usize) -> Result<EnvObservation, EnvError> {
        self.sim.read_states(&mut self.states).map_err(sim_error)?;
        Ok(self.states[env])
    }

    /// Reference position of copy `env`'s path at arc length `s`.
    fn reference_position(&self, lane: &Lane, s: f64) -> DVec3 {
        let path = &self.paths[lane.path];
        path.position(s) + lane.start_offset + lane.goal_jitter * (s / path.length_m)
    }

    /// Nominal orientation at arc length `s`: the recorded tilt profile scaled to the target.
    fn nominal_orientation(&self, lane: &Lane, s: f64) -> DQuat {
        let path = &self.paths[lane.path];
        DQuat::from_rotation_x(lane.target_tilt * path.tilt_fraction(s)) * path.start_orientation
    }

    /// Place pose of a lane.
    fn goal(&self, lane: &Lane) -> (DVec3, DQuat) {
        let length = self.paths[lane.path].length_m;
        (
            self.reference_position(lane, length),
            self.nominal_orientation(lane, length),
        )
    }

    /// Turns copy `env`'s action into the reference for the next interval and commands the tool.
    fn command(&mut self, env: usize, action: &[f32]) -> Result<(), EnvError> {
        let l = &self.config.limits;
        let t = self.dt;
        let tilt = l.max_tilt_offset_deg.to_radians();
        let a = [
            (action[0] as f64).clamp(0.0, l.max_path_speed_m_s),
            (action[1] as f64).clamp(-tilt, tilt),
            (action[2] as f64).clamp(-tilt, tilt),
        ];
        let mut lane = self.lanes[env];
        let length = self.paths[lane.path].length_m;
        let remaining = (length - lane.progress).max(0.0);
        let step = l.max_path_accel_m_s2 * t;
        // Never faster than the tool can still brake to rest at the place pose.
        let brake = (2.0 * l.max_path_accel_m_s2 * remaining).sqrt();
        let speed = a[0]
            .clamp(lane.path_speed - step, lane.path_speed + step)
            .clamp(0.0, brake.max(0.0));
        let mut progress = (lane.progress + 0.5 * (lane.path_speed + speed) * t).min(length);
        if length - progress < PATH_END_SNAP_M {
            progress = length;
        }
        let target = self.reference_position(&lane, progress);
        let feedforward = self.paths[lane.path].tangent(progress) * speed;
        let state = self.states[env];
        let (p0, v0) = (v3(state.tool_position), v3(state.tool_velocity));
        let gain = l.tracking_gain;
        let linear = feedforward + gain * (2.0 * (target - p0) / t - v0 - feedforward);
        let orientation = DQuat::from_rotation_x(a[1])
            * DQuat::from_rotation_z(a[2])
            * self.nominal_orientation(&lane, progress);
        let q0 = quat(state.tool_orientation);
        let w0 = v3(state.tool_angular_velocity);
        let angular = gain * (2.0 * rotation_between(q0, orientation) / t - w0);
        self.sim
            .command_tool(
                env,
                ToolCommand::Twist {
                    linear: linear.as_vec3().to_array(),
                    angular: angular.as_vec3().to_array(),
                },
                t,
            )
            .map_err(sim_error)?;
        lane.last_advance = progress - lane.progress;
        lane.progress = progress;
        lane.path_speed = speed;
        lane.previous_action = a;
        self.lanes[env] = lane;
        Ok(())
    }

    /// Writes copy `env`'s actor and critic observations into `obs` / `critic` rows.
    fn observe(&self, env: usize, obs: &mut [f32], critic: &mut [f32]) {
        let lane = &self.lanes[env];
        let state = &self.states[env];
        let cups = self.model.num_cups();
        let loads = &self.loads[env * cups..(env + 1) * cups];
        let (goal_p, goal_q) = self.goal(lane);
        let p = v3(state.tool_position);
        let q = quat(state.tool_orientation);
        let to_goal = goal_p - p;
        let rotation = rotation_between(q, goal_q);
        let v = v3(state.tool_velocity);
        let w = v3(state.tool_angular_velocity);
        let length = self.paths[lane.path].length_m;
        let mut row: Vec<f64> = Vec::with_capacity(critic.len());
        row.extend(to_goal.to_array());
        row.extend(rotation.to_array());
        row.extend(v.to_array());
        row.extend(w.to_array());
        row.extend([
            lane.progress / length,
            lane.path_speed,
            state.time - lane.start_time,
            lane.target_tilt,
        ]);
        row.extend(lane.previous_action);
        row.extend(loads.iter().map(|c| c.utilisation as f64));
        let actor_dim = obs.len();
        let d = &state.disc_in_tool;
        row.extend(d.position.iter().map(|&c| c as f64));
        row.extend(d.orientation.iter().map(|&c| c as f64));
        row.extend(d.velocity.iter().map(|&c| c as f64));
        row.extend(d.angular_velocity.iter().map(|&c| c as f64));
        let spec = self.sim.spec(env);
        row.push(spec.object_mass_kg as f64);
        for c in loads {
            row.extend([c.normal_n as f64, c.shear_n as f64]);
        }
        let base = &self.model.config.params;
        for name in &self.materials {
            let mut now = spec.params;
            let mut reference = *base;
            let ratio = match (now.get_mut(name), reference.get_mut(name)) {
                (Some(a), Some(b)) if *b != 0.0 => (*a / *b) as f64,
                _ => 1.0,
            };
            row.push(ratio.ln());
        }
        for (slot, &x) in obs.iter_mut().zip(&row[..actor_dim]) {
            *slot = x as f32;
        }
        for (slot, &x) in critic.iter_mut().zip(&row) {
            *slot = x as f32;
        }
    }

    /// Fills `out`'s observation rows of copy `env`.
    fn observe_into(&self, env: usize, out: &mut StepBuffers, final_rows: bool) {
        let (a, c) = (self.spec.observation.dim(), self.spec.critic_obs_dim());
        if final_rows {
            self.observe(
                env,
                &mut out.final_obs[env * a..(env + 1) * a],
                &mut out.final_critic_obs[env * c..(env + 1) * c],
            );
        } else {
            self.observe(
                env,
                &mut out.obs[env * a..(env + 1) * a],
                &mut out.critic_obs[env * c..(env + 1) * c],
            );
        }
    }

    /// Whether copy `env` is at the place pose within the tolerances, with the object settled.
    fn placed(&self, env: usize) -> bool {
        let lane = &self.lanes[env];
        let tol = &self.config.success;
        let state = &self.states[env];
        let (goal_p, goal_q) = self.goal(lane);
        lane.progress >= self.paths[lane.path].length_m
            && (goal_p - v3(state.tool_position)).length() <= tol.position_m
            && rotation_between(quat(state.tool_orientation), goal_q).length()
                <= tol.orientation_deg.to_radians()
            && v3(state.tool_velocity).length() <= tol.tool_speed_m_s
            && v3(state.disc_in_tool.velocity).length() <= tol.object_speed_m_s
    }

    fn write_info(&mut self, env: usize, values: &[f64]) {
        let n = self.info_names.len();
        for (slot, &x) in self.info[env * n..(env + 1) * n].iter_mut().zip(values) {
            *slot = x as f32;
        }
    }
}

impl VecEnv for Transport {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn num_envs(&self) -> usize {
        self.lanes.len()
    }

    fn reset(&mut self, seed: u64, out: &mut StepBuffers) -> Result<(), EnvError> {
        self.try_reset(seed, out)
    }

    fn step(&mut self, actions: &[f32], out: &mut StepBuffers) -> Result<(), EnvError> {
        let n = self.num_envs();
        check_action_len(actions, n, 3)?;
        if self.variants.is_empty() {
            return Err(EnvError::Simulator("step before reset".into()));
        }
        if let Some(k) = actions.iter().position(|a| !a.is_finite()) {
            return Err(EnvError::NonFiniteAction {
                env: k / 3,
                index: k % 3,
                value: actions[k],
            });
        }
        let start_states = self.states.clone();
        for env in 0..n {
            if !self.retired[env] {
                self.command(env, &actions[env * 3..env * 3 + 3])?;
            }
        }
        self.sim.step(self.substeps_per_step);
        self.health.clear();
        self.seal.clear();
        self.sim.drain_events(&mut self.health, &mut self.seal);
        self.sim.read_states(&mut self.states).map_err(sim_error)?;
        self.sim
            .read_cup_loads(&mut self.loads)
            .map_err(sim_error)?;
        let cups = self.model.num_cups();
        let mut finished = Vec::new();
        for (env, start) in start_states.iter().enumerate() {
            if self.retired[env] {
                out.rewards[env] = 0.0;
                out.terminated[env] = false;
                out.truncated[env] = false;
                continue;
            }
            let state = self.states[env];
            let mut failure = None;
            for event in self.seal.iter().filter(|e| e.env == env) {
                failure = failure.or(match event.kind {
                    SealEventKind::Dropped => Some(Failure::Dropped),
                    _ => Some(Failure::CupDetached),
                });
            }
            if state.frozen || self.health.iter().any(|e| e.env == env) {
                failure = failure.or(Some(Failure::Unhealthy));
            }
            let object = v3(state.disc_in_tool.position);
            if object.length() > self.config.failure.max_object_distance_m {
                failure = failure.or(Some(Failure::Dropped));
            }
            let succeeded = failure.is_none() && self.placed(env);
            let mut lane = self.lanes[env];
            let accel = (v3(state.tool_velocity) - v3(start.tool_velocity)) / self.dt;
            let angular_accel =
                (v3(state.tool_angular_velocity) - v3(start.tool_angular_velocity)) / self.dt;
            let length = self.paths[lane.path].length_m;
            let peak_utilisation = self.loads[env * cups..(env + 1) * cups]
                .iter()
                .map(|c| c.utilisation as f64)
                .fold(0.0, f64::max);
            let object_motion = (object - lane.previous_object_in_tool).length();
            let outcome = StepOutcome {
                dt_s: self.dt,
                progress_fraction: lane.last_advance / length,
                object_motion_m: object_motion,
                peak_utilisation,
                accel_change_m_s2: if lane.steps == 0 {
                    accel.length()
                } else {
                    (accel - lane.previous_accel).length()
                },
                angular_accel_change_rad_s2: if lane.steps == 0 {
                    angular_accel.length()
                } else {
                    (angular_accel - lane.previous_angular_accel).length()
                },
                failed: failure.is_some(),
                succeeded,
            };
            let terms = RewardTerms::of(&self.config.reward, &outcome);
            lane.previous_accel = accel;
            lane.previous_angular_accel = angular_accel;
            lane.previous_object_in_tool = object;
            lane.steps += 1;
            self.lanes[env] = lane;
            let terminated = failure.is_some() || succeeded;
            let truncated = !terminated && lane.steps >= self.spec.max_episode_steps;
            out.rewards[env] = terms.total() as f32;
            out.terminated[env] = terminated;
            out.truncated[env] = truncated;
            let mut info: Vec<f64> = terms.values().to_vec();
            let flag = |b: bool| if b { 1.0 } else { 0.0 };
            info.extend([
                flag(succeeded),
                flag(failure == Some(Failure::CupDetached)),
                flag(failure == Some(Failure::Dropped)),
                flag(failure == Some(Failure::Unhealthy)),
                flag(truncated),
                peak_utilisation,
                object_motion,
                lane.path_speed,
            ]);
            self.write_info(env, &info);
            self.observe_into(env, out, true);
            if terminated || truncated {
                finished.push(env);
            } else {
                self.observe_into(env, out, false);
            }
        }
        if self.retire_finished {
            for &env in &finished {
                self.sim.retire(env).map_err(sim_error)?;
                self.retired[env] = true;
                self.observe_into(env, out, false);
            }
            return Ok(());
        }
        for &env in &finished {
            self.start_episode(env)?;
        }
        if !finished.is_empty() {
            self.sim
                .read_cup_loads(&mut self.loads)
                .map_err(sim_error)?;
            for &env in &finished {
                self.observe_into(env, out, false);
            }
        }
        Ok(())
    }

    fn save_state(&self) -> EnvState {
        let mut reals = Vec::with_capacity(self.lanes.len() * LANE_REALS);
        let mut counters = Vec::new();
        for lane in &self.lanes {
            reals.extend(lane.to_reals());
            counters.extend([lane.path as u64, lane.variant as u64, lane.steps as u64]);
        }
        for rng in &self.rngs {
            counters.extend(rng_to_words(rng));
        }
        let snapshots: Vec<EnvSnapshot> = (0..self.lanes.len())
            .map(|env| self.sim.snapshot(env))
            .chain(self.variants.iter().map(|v| v.snapshot.clone()))
            .collect();
        let starts: Vec<[f64; 3]> = self
            .variants
            .iter()
            .map(|v| v.tool_start.to_array())
            .collect();
        let bytes = serde_json::to_vec(&(snapshots, starts)).expect("snapshots serialise");
        EnvState {
            reals,
            counters,
            bytes,
        }
    }

    fn load_state(&mut self, state: &EnvState) -> Result<(), EnvError> {
        let n = self.lanes.len();
        let mismatch = |reason: String| EnvError::StateMismatch {
            env: ID.to_string(),
            reason,
        };
        if state.reals.len() != n * LANE_REALS || state.counters.len() != n * (3 + RNG_WORDS) {
            return Err(mismatch(format!(
                "expected {} reals and {} counters for {n} copies, got {} and {}",
                n * LANE_REALS,
                n * (3 + RNG_WORDS),
                state.reals.len(),
                state.counters.len()
            )));
        }
        let (snapshots, starts): (Vec<EnvSnapshot>, Vec<[f64; 3]>) =
            serde_json::from_slice(&state.bytes)
                .map_err(|e| mismatch(format!("simulator snapshots: {e}")))?;
        if snapshots.len() != n + starts.len() || starts.is_empty() {
            return Err(mismatch(format!(
                "{} snapshots and {} variants for {n} copies",
                snapshots.len(),
                starts.len()
            )));
        }
        let variants = snapshots[n..]
            .iter()
            .zip(&starts)
            .map(|(s, t)| Variant {
                snapshot: s.clone(),
                tool_start: DVec3::from(*t),
            })
            .collect::<Vec<_>>();
        for (env, snapshot) in snapshots.iter().enumerate().take(n) {
            let c = &state.counters[env * 3..env * 3 + 3];
            let (path, variant) = (c[0] as usize, c[1] as usize);
            if path >= self.paths.len() || variant >= variants.len() {
                return Err(mismatch(format!(
                    "copy {env}: path {path} or variant {variant} out of range"
                )));
            }
            self.sim
                .restore(env, snapshot)
                .map_err(|e| mismatch(e.to_string()))?;
            self.lanes[env] = Lane::from_reals(
                &state.reals[env * LANE_REALS..(env + 1) * LANE_REALS],
                path,
                variant,
                c[2] as usize,
            );
        }
        for (i, rng) in self.rngs.iter_mut().enumerate() {
            let words = &state.counters[n * 3 + i * RNG_WORDS..n * 3 + (i + 1) * RNG_WORDS];
            *rng = rng_from_words(words.try_into().expect("RNG_WORDS words"));
        }
        self.variants = variants;
        self.retired.fill(false);
        self.sim.read_states(&mut self.states).map_err(sim_error)?;
        self.sim
            .read_cup_loads(&mut self.loads)
            .map_err(sim_error)?;
        Ok(())
    }

    fn info_names(&self) -> &[String] {
        &self.info_names
    }

    fn info(&self) -> &[f32] {
        &self.info
    }
}

impl Transport {
    /// [`VecEnv::reset`] that reports a failure to settle the packages instead of panicking.
    pub fn try_reset(&mut self, seed: u64, out: &mut StepBuffers) -> Result<(), EnvError> {
        self.settle_variants(seed)?;
        self.retired.fill(false);
        for env in 0..self.num_envs() {
            self.rngs[env] = env_rng(seed, env);
            self.start_episode(env)?;
        }
        self.sim.read_states(&mut self.states).map_err(sim_error)?;
        self.sim
            .read_cup_loads(&mut self.loads)
            .map_err(sim_error)?;
        out.rewards.iter_mut().for_each(|r| *r = 0.0);
        out.terminated.iter_mut().for_each(|t| *t = false);
        out.truncated.iter_mut().for_each(|t| *t = false);
        self.info.iter_mut().for_each(|x| *x = 0.0);
        for env in 0..self.num_envs() {
            self.observe_into(env, out, false);
            self.observe_into(env, out, true);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
