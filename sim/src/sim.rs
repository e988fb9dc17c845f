//! [`Simulator`]: a batch of environments (model + per-environment data + batched state) and the
//! calls to step it and read it back.

use std::sync::Arc;

use rayon::prelude::*;

use serde::{Deserialize, Serialize};

use crate::block::{advance_block, get3, Block, LaneSnapshot, StepConstants};
use crate::config::{Params, ToolLimits};
use crate::embed::SurfaceEmbedding;
use crate::error::SimError;
use crate::model::Model;
use crate::state::{CupLoad, DiscState, EnvObservation, EpisodeSpec, HealthEvent, SealEvent};
use crate::tool::{plan, ToolCommand, ToolCommandReport, ToolDrive, ToolState};
use crate::trajectory::ToolTrajectory;

/// Environments per block in batches (8 f32 lanes = one AVX2 register).
pub const LANES: usize = 8;

/// Blocks of the batch. A batch of one environment uses 1-lane blocks so no lane is wasted; the
/// arithmetic per lane is the same, so results are bit-identical either way.
enum Blocks {
    Wide(Vec<Block<LANES>>),
    Single(Vec<Block<1>>),
}

/// Runs `$body` with `$b` bound to the block holding environment `$env` and `$l` to its lane.
/// Panics with a clear message if there is no such environment (an index is the caller's
/// logic, never user input; the lane would otherwise read padding data).
macro_rules! with_lane {
    ($self:expr, $env:expr, |$b:ident, $l:ident| $body:expr) => {{
        let env: usize = $env;
        assert!(
            env < $self.specs.len(),
            "environment {env} out of range (batch of {})",
            $self.specs.len()
        );
        match &$self.blocks {
            Blocks::Wide(blocks) => {
                let $b = &blocks[$env / LANES];
                let $l = $env % LANES;
                $body
            }
            Blocks::Single(blocks) => {
                let $b = &blocks[$env];
                let $l = 0;
                $body
            }
        }
    }};
}

/// Runs `$body` with `$b` bound mutably to the block holding environment `$env` (checked).
macro_rules! with_block_mut {
    ($self:expr, $env:expr, |$b:ident| $body:expr) => {{
        let env: usize = $env;
        $self.check_env(env)?;
        match &mut $self.blocks {
            Blocks::Wide(blocks) => {
                let $b = &mut blocks[env / LANES];
                $body
            }
            Blocks::Single(blocks) => {
                let $b = &mut blocks[env];
                $body
            }
        }
    }};
}

/// One environment's full state: its spec, particles, disc, cups and seals, tool and clock.
/// Restored into any environment of a batch built on the same model, it continues bit for bit as
/// the original would; it serialises with serde (e.g. for exact resume of training).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EnvSnapshot {
    /// The environment's spec (placement, parameters, masses, trajectory).
    pub spec: EpisodeSpec,
    /// Particles, cups and disc of the model it was taken from (checked on restore).
    shape: [usize; 3],
    /// Substep length of the model it was taken from (checked on restore).
    dt: f32,
    lane: LaneSnapshot,
}

impl EnvSnapshot {
    /// The environment's own time when the snapshot was taken (substeps since its episode began).
    pub fn substep(&self) -> u64 {
        self.lane.clock
    }
}

/// A batch of environments stepped in lockstep.
pub struct Simulator {
    model: Arc<Model>,
    specs: Vec<EpisodeSpec>,
    blocks: Blocks,
    constants: StepConstants,
    limits: ToolLimits,
    substep: u64,
    events: Vec<HealthEvent>,
    seal_events: Vec<SealEvent>,
}

fn lane_envs<const W: usize>(block: usize, num_envs: usize) -> ([usize; W], [bool; W]) {
    let mut envs = [0; W];
    let mut real = [false; W];
    for l in 0..W {
        let e = block * W + l;
        // Padding lanes repeat the block's first environment; their results are never read.
        envs[l] = if e < num_envs { e } else { block * W };
        real[l] = e < num_envs;
    }
    (envs, real)
}

/// Lays environments out in blocks: 1-lane blocks for a single environment, else LANES-wide.
fn build_blocks(model: &Model, specs: &[EpisodeSpec]) -> Blocks {
    let n = specs.len();
    if n == 1 {
        Blocks::Single(vec![Block::new(model, specs, [0], [true])])
    } else {
        Blocks::Wide(
            (0..n.div_ceil(LANES))
                .into_par_iter()
                .map(|b| {
                    let (envs, real) = lane_envs::<LANES>(b, n);
                    Block::new(model, specs, envs, real)
                })
                .collect(),
        )
    }
}

/// Checks one environment's spec.
fn validate_spec(env: usize, spec: &EpisodeSpec) -> Result<(), SimError> {
    let fail = |message: String| Err(SimError::Env { env, message });
    if let Err(e) = spec
        .params
        .validate(&format!("environment {env} parameters"))
    {
        return fail(e.to_string());
    }
    let pl = &spec.placement;
    let values = pl
        .package_origin
        .iter()
        .chain(&pl.cup_point)
        .chain(&pl.disc_position)
        .chain(pl.disc_hold.iter().flatten())
        .chain(&pl.disc_orientation)
        .chain([&pl.package_yaw_rad]);
    if values.clone().any(|c| !c.is_finite()) {
        return fail("placement has a non-finite coordinate".into());
    }
    if pl.disc_orientation.iter().map(|c| c * c).sum::<f32>() < 1e-6 {
        return fail("disc orientation is a zero quaternion".into());
    }
    if !(spec.object_mass_kg.is_finite() && spec.object_mass_kg > 0.0) {
        return fail(format!(
            "object mass {} kg: expected a positive number",
            spec.object_mass_kg
        ));
    }
    if let Some(scale) = spec.disc_mass_scale {
        if !(scale.is_finite() && (1e-3..=1e4).contains(&scale)) {
            return fail(format!(
                "disc mass scale {scale}: expected a number in [0.001, 10000]"
            ));
        }
    }
    Ok(())
}

impl Simulator {
    /// Builds the batch: one environment per spec, all at rest at time 0.
    pub fn new(model: Arc<Model>, specs: Vec<EpisodeSpec>) -> Result<Self, SimError> {
        if specs.is_empty() {
            return Err(SimError::Env {
                env: 0,
                message: "a batch needs at least one environment".into(),
            });
        }
        for (env, spec) in specs.iter().enumerate() {
            validate_spec(env, spec)?;
        }
        let blocks = build_blocks(&model, &specs);
        let mut sim = Simulator {
            constants: StepConstants::new(&model),
            limits: model.config.tool_limits.clone(),
            model,
            specs,
            blocks,
            substep: 0,
            events: Vec::new(),
            seal_events: Vec::new(),
        };
        sim.collect_events();
        Ok(sim)
    }

    /// Puts every environment back to its initial state (time 0, health flags cleared), keeping
    /// the current parameters and trajectories.
    pub fn reset(&mut self) {
        self.blocks = build_blocks(&self.model, &self.specs);
        self.substep = 0;
        self.events.clear();
        self.seal_events.clear();
        self.collect_events();
    }

    /// Restarts environment `env` from `spec` (time 0 of its own clock, cups sealed anew, any
    /// freeze lifted) while the others keep their state; their results are bit-identical to a
    /// run without this reset.
    pub fn reset_env(&mut self, env: usize, spec: EpisodeSpec) -> Result<(), SimError> {
        self.check_env(env)?;
        validate_spec(env, &spec)?;
        let model = self.model.clone();
        with_block_mut!(self, env, |b| b.reset_env(env, &model, &spec));
        self.specs[env] = spec;
        self.collect_events();
        Ok(())
    }

    /// A copy of environment `env`'s full state.
    pub fn snapshot(&self, env: usize) -> EnvSnapshot {
        let lane = with_lane!(self, env, |b, l| b.take_lane(l));
        EnvSnapshot {
            spec: self.specs[env].clone(),
            shape: self.shape(),
            dt: self.constants.dt,
            lane,
        }
    }

    fn shape(&self) -> [usize; 3] {
        [
            self.model.num_particles(),
            self.model.num_cup,
            self.model.num_cups(),
        ]
    }

    /// Puts `snapshot` into environment `env` (any environment of a batch on the same model):
    /// from here on `env` continues exactly as the snapshot's environment would have.
    pub fn restore(&mut self, env: usize, snapshot: &EnvSnapshot) -> Result<(), SimError> {
        self.check_env(env)?;
        let lane = &snapshot.lane;
        let consistent = snapshot.shape == self.shape()
            && snapshot.dt.to_bits() == self.constants.dt.to_bits()
            && [
                lane.x.len(),
                lane.v.len(),
                lane.x0.len(),
                lane.contact_point.len(),
                lane.contact_normal.len(),
            ]
            .iter()
            .all(|&n| n == self.model.num_particles())
            && lane.cup_offsets.len() == self.model.num_cup
            && lane.springs.len() == self.model.num_cup
            && lane.cups.len() == self.model.num_cups()
            && lane
                .springs
                .iter()
                .all(|s| (s.0 as usize) < self.model.num_package);
        if !consistent {
            return Err(SimError::Env {
                env,
                message: format!(
                    "snapshot of a different model ({} particles, {} cup particles, {} cups, \
                     dt {} s; this batch has {:?} and dt {} s)",
                    snapshot.shape[0],
                    snapshot.shape[1],
                    snapshot.shape[2],
                    snapshot.dt,
                    self.shape(),
                    self.constants.dt
                ),
            });
        }
        validate_spec(env, &snapshot.spec)?;
        let model = self.model.clone();
        with_block_mut!(self, env, |b| b.restore_env(
            env,
            &model,
            &snapshot.spec,
            lane
        ));
        self.specs[env] = snapshot.spec.clone();
        Ok(())
    }

    /// Commands the tool of `env` for the next `duration_s` seconds (one control interval; see
    /// [`ToolCommand`]), starting from its pose and twist now. The robot's limits
    /// ([`Simulator::tool_limits`]) are enforced; the report says what they changed.
    pub fn command_tool(
        &mut self,
        env: usize,
        command: ToolCommand,
        duration_s: f64,
    ) -> Result<ToolCommandReport, SimError> {
        self.check_env(env)?;
        let values: Vec<f32> = match command {
            ToolCommand::Twist { linear, angular } => linear.into_iter().chain(angular).collect(),
            ToolCommand::Pose {
                position,
                orientation,
            } => position.into_iter().chain(orientation).collect(),
        };
        if values.iter().any(|c| !c.is_finite()) || !(duration_s.is_finite() && duration_s > 0.0) {
            return Err(SimError::Env {
                env,
                message: format!(
                    "tool command {command:?} over {duration_s} s: expected finite values and a positive duration"
                ),
            });
        }
        if let ToolCommand::Pose { orientation, .. } = command {
            if orientation.iter().map(|c| c * c).sum::<f32>() < 1e-6 {
                return Err(SimError::Env {
                    env,
                    message: "tool command orientation is a zero quaternion".into(),
                });
            }
        }
        let (t0, now) = self.tool_now(env);
        let (segment, report) = plan(t0, now, command, duration_s, &self.limits);
        let drive = ToolDrive::Commanded(segment);
        with_block_mut!(self, env, |b| b.set_drive(env, &drive));
        Ok(report)
    }

    /// The environment's own time and its tool's state now.
    fn tool_now(&self, env: usize) -> (f64, ToolState) {
        let k = &self.constants;
        with_lane!(self, env, |b, l| (
            b.clock[l] as f64 * k.dt64,
            b.tool_state(l, k, 0.0)
        ))
    }

    /// The robot limits applied to tool commands (the scene's `tool_limits`).
    pub fn tool_limits(&self) -> &ToolLimits {
        &self.limits
    }

    /// The tool of `env` now: pose and twist.
    pub fn tool_state(&self, env: usize) -> ToolState {
        self.tool_now(env).1
    }

    /// Seals the cups of `env` anew on the film as it is now (the loading test of the seal
    /// model decides which cups hold), e.g. after [`Simulator::set_particle_positions`].
    pub fn attach_cups(&mut self, env: usize) -> Result<(), SimError> {
        self.check_env(env)?;
        let (time, tool) = self.tool_now(env);
        let model = self.model.clone();
        with_block_mut!(self, env, |b| {
            for l in 0..b.envs.len() {
                if b.envs[l] == env {
                    b.attach_cups_lane(l, &model, time, tool.orientation);
                }
            }
        });
        self.collect_events();
        Ok(())
    }

    /// Moves the block events (health, seal) into the simulator's logs, in time order.
    fn collect_events(&mut self) {
        fn drain<const W: usize>(
            blocks: &mut [Block<W>],
            health: &mut Vec<HealthEvent>,
            seal: &mut Vec<SealEvent>,
        ) {
            for b in blocks {
                health.append(&mut b.events);
                seal.append(&mut b.seal_events);
            }
        }
        let (mut health, mut seal) = (Vec::new(), Vec::new());
        match &mut self.blocks {
            Blocks::Wide(blocks) => drain(blocks, &mut health, &mut seal),
            Blocks::Single(blocks) => drain(blocks, &mut health, &mut seal),
        }
        health.sort_by(|a, b| a.time.total_cmp(&b.time).then(a.env.cmp(&b.env)));
        // Stable: within one environment and instant, the order the block found them in.
        seal.sort_by(|a, b| a.env.cmp(&b.env).then(a.time.total_cmp(&b.time)));
        self.events.append(&mut health);
        self.seal_events.append(&mut seal);
    }

    /// The shared model.
    pub fn model(&self) -> &Arc<Model> {
        &self.model
    }

    /// Number of environments.
    pub fn num_envs(&self) -> usize {
        self.specs.len()
    }

    /// Substep length (s).
    pub fn dt(&self) -> f32 {
        self.constants.dt
    }

    /// Substeps this simulator has stepped since it was built or [`Simulator::reset`] (every
    /// environment's own clock starts there too, unless it was reset or restored since).
    pub fn substep(&self) -> u64 {
        self.substep
    }

    /// Simulated time (s) of [`Simulator::substep`], counted from the start of the rest period.
    pub fn time(&self) -> f64 {
        self.substep as f64 * self.constants.dt64
    }

    /// Substeps environment `env` has taken since its episode began (its own clock; it stops
    /// while the environment is frozen or retired).
    pub fn env_substep(&self, env: usize) -> u64 {
        with_lane!(self, env, |b, l| b.clock[l])
    }

    /// Environment `env`'s own time (s) since its episode began.
    pub fn env_time(&self, env: usize) -> f64 {
        self.env_substep(env) as f64 * self.constants.dt64
    }

    /// Advances every active environment by `substeps` substeps of its own clock (in parallel
    /// over blocks of environments; frozen and retired environments stay as they are and cost
    /// nothing once their whole block is).
    pub fn step(&mut self, substeps: u64) {
        let (model, k) = (&*self.model, &self.constants);
        match &mut self.blocks {
            Blocks::Wide(blocks) => blocks
                .par_iter_mut()
                .for_each(|b| advance_block(b, model, k, substeps, false)),
            Blocks::Single(blocks) => blocks
                .iter_mut()
                .for_each(|b| advance_block(b, model, k, substeps, true)),
        }
        self.substep += substeps;
        self.collect_events();
    }

    /// Stops stepping `env` (e.g. its recording has ended): its state stays as it is, it counts as
    /// frozen, and no health event is recorded. A block whose environments are all frozen or
    /// retired costs nothing, so retiring finished environments makes ragged batches cheap.
    /// [`Simulator::reset`] brings it back.
    pub fn retire(&mut self, env: usize) -> Result<(), SimError> {
        self.check_env(env)?;
        match &mut self.blocks {
            Blocks::Wide(blocks) => blocks[env / LANES].retire(env),
            Blocks::Single(blocks) => blocks[env].retire(env),
        }
        Ok(())
    }

    /// Replaces one environment's material parameters (takes effect at the next substep).
    pub fn set_params(&mut self, env: usize, params: Params) -> Result<(), SimError> {
        self.check_env(env)?;
        params
            .validate(&format!("environment {env} parameters"))
            .map_err(|e| SimError::Env {
                env,
                message: e.to_string(),
            })?;
        self.specs[env].params = params;
        let (model, spec) = (&*self.model, &self.specs[env]);
        match &mut self.blocks {
            Blocks::Wide(blocks) => blocks[env / LANES].set_params(env, model, spec),
            Blocks::Single(blocks) => blocks[env].set_params(env, model, spec),
        }
        Ok(())
    }

    /// Replaces one environment's tool trajectory (its time base is unchanged: trajectory time 0
    /// is at the end of the rest period). The cup offsets keep their initial values.
    pub fn set_trajectory(
        &mut self,
        env: usize,
        trajectory: Arc<ToolTrajectory>,
    ) -> Result<(), SimError> {
        self.check_env(env)?;
        match &mut self.blocks {
            Blocks::Wide(blocks) => blocks[env / LANES].set_trajectory(env, &trajectory),
            Blocks::Single(blocks) => blocks[env].set_trajectory(env, &trajectory),
        }
        self.specs[env].trajectory = trajectory;
        Ok(())
    }

    fn check_env(&self, env: usize) -> Result<(), SimError> {
        if env < self.num_envs() {
            Ok(())
        } else {
            Err(SimError::Env {
                env,
                message: format!("no such environment (batch of {})", self.num_envs()),
            })
        }
    }

    /// The spec an environment was built from (with any parameter/trajectory replacements).
    pub fn spec(&self, env: usize) -> &EpisodeSpec {
        &self.specs[env]
    }

    /// Overwrites the positions of every particle of `env` (velocities unchanged; cup particles
    /// follow the tool again at the next substep).
    pub fn set_particle_positions(
        &mut self,
        env: usize,
        positions: &[[f32; 3]],
    ) -> Result<(), SimError> {
        self.check_env(env)?;
        if positions.len() != self.model.num_particles()
            || positions.iter().flatten().any(|c| !c.is_finite())
        {
            return Err(SimError::Env {
                env,
                message: format!(
                    "{} positions given, expected {} finite ones",
                    positions.len(),
                    self.model.num_particles()
                ),
            });
        }
        with_block_mut!(self, env, |b| b.set_positions(env, positions));
        Ok(())
    }

    /// Overwrites the velocities of every particle of `env` (e.g. to start from a perturbed state).
    pub fn set_particle_velocities(
        &mut self,
        env: usize,
        velocities: &[[f32; 3]],
    ) -> Result<(), SimError> {
        self.check_env(env)?;
        if velocities.len() != self.model.num_particles() {
            return Err(SimError::Env {
                env,
                message: format!(
                    "{} velocities given, expected {}",
                    velocities.len(),
                    self.model.num_particles()
                ),
            });
        }
        fn write<const W: usize>(b: &mut Block<W>, env: usize, velocities: &[[f32; 3]]) {
            for l in 0..W {
                if b.envs[l] == env {
                    for (v, u) in b.v.iter_mut().zip(velocities) {
                        v.x.0[l] = u[0];
                        v.y.0[l] = u[1];
                        v.z.0[l] = u[2];
                    }
                }
            }
        }
        match &mut self.blocks {
            Blocks::Wide(blocks) => write(&mut blocks[env / LANES], env, velocities),
            Blocks::Single(blocks) => write(&mut blocks[env], env, velocities),
        }
        Ok(())
    }

    /// Positions of every particle of `env` (package particles, then cup particles).
    pub fn particle_positions(&self, env: usize) -> Vec<[f32; 3]> {
        with_lane!(self, env, |b, l| b.x.iter().map(|p| get3(p, l)).collect())
    }

    /// Velocities of every particle of `env`.
    pub fn particle_velocities(&self, env: usize) -> Vec<[f32; 3]> {
        with_lane!(self, env, |b, l| b.v.iter().map(|p| get3(p, l)).collect())
    }

    /// Positions of the cup particles of `env` (cup-major, ring-major within a cup).
    pub fn cup_positions(&self, env: usize) -> Vec<[f32; 3]> {
        let start = self.model.cup_start();
        with_lane!(self, env, |b, l| b.x[start..]
            .iter()
            .map(|p| get3(p, l))
            .collect())
    }

    /// The disc of `env`.
    pub fn disc(&self, env: usize) -> DiscState {
        with_lane!(self, env, |b, l| {
            let d = &b.disc;
            let v = get3(&d.q.v, l);
            DiscState {
                position: get3(&d.com, l),
                orientation: [v[0], v[1], v[2], d.q.w.0[l]],
                velocity: get3(&d.v, l),
                angular_velocity: get3(&d.w, l),
            }
        })
    }

    /// Whether `env` has been frozen by a health check.
    pub fn is_frozen(&self, env: usize) -> bool {
        with_lane!(self, env, |b, l| b.active.0[l] < 0.5)
    }

    /// Every health event not yet drained, in time order.
    pub fn health_events(&self) -> &[HealthEvent] {
        &self.events
    }

    /// Every seal event not yet drained (loading failures, peeling, pull-off, sliding, drops),
    /// ordered by environment, then time; a drop comes after the failure that caused it.
    pub fn seal_events(&self) -> &[SealEvent] {
        &self.seal_events
    }

    /// Moves the health and seal events into the caller's buffers (appended), leaving the logs
    /// empty: an environment loop drains them every control step without allocating.
    pub fn drain_events(&mut self, health: &mut Vec<HealthEvent>, seal: &mut Vec<SealEvent>) {
        health.append(&mut self.events);
        seal.append(&mut self.seal_events);
    }

    /// Number of cups of the model (the length of one environment's row in
    /// [`Simulator::read_cup_loads`]).
    pub fn num_cups(&self) -> usize {
        self.model.num_cups()
    }

    /// Writes the tool, disc and seal summary of every environment into `out` (one entry per
    /// environment, in order).
    pub fn read_states(&self, out: &mut [EnvObservation]) -> Result<(), SimError> {
        self.check_len("read_states", out.len(), self.num_envs())?;
        let k = &self.constants;
        for (env, slot) in out.iter_mut().enumerate() {
            *slot = with_lane!(self, env, |b, l| {
                let tool = b.tool_state(l, k, 0.0);
                let d = &b.disc;
                let v = get3(&d.q.v, l);
                let disc = DiscState {
                    position: get3(&d.com, l),
                    orientation: [v[0], v[1], v[2], d.q.w.0[l]],
                    velocity: get3(&d.v, l),
                    angular_velocity: get3(&d.w, l),
                };
                EnvObservation {
                    time: b.clock[l] as f64 * k.dt64,
                    tool_position: tool.position.map(|c| c as f32),
                    tool_orientation: tool.orientation.map(|c| c as f32),
                    tool_velocity: tool.velocity.map(|c| c as f32),
                    tool_angular_velocity: tool.angular_velocity.map(|c| c as f32),
                    disc,
                    disc_in_tool: relative_to_tool(&disc, &tool),
                    cups_attached: b.attached_cups(l),
                    frozen: b.active.0[l] < 0.5,
                }
            });
        }
        Ok(())
    }

    /// Writes the load of every cup of every environment into `out`: environment-major, one
    /// row of [`Simulator::num_cups`] entries per environment.
    pub fn read_cup_loads(&self, out: &mut [CupLoad]) -> Result<(), SimError> {
        let cups = self.num_cups();
        self.check_len("read_cup_loads", out.len(), self.num_envs() * cups)?;
        let k = &self.constants;
        for (env, row) in out.chunks_mut(cups).enumerate() {
            with_lane!(self, env, |b, l| b.read_cup_loads(l, k, row));
        }
        Ok(())
    }

    /// Writes the world positions of `embedding`'s points in every environment into `out`:
    /// environment-major, one row of `embedding.points.len()` entries per environment.
    pub fn read_points(
        &self,
        embedding: &SurfaceEmbedding,
        out: &mut [[f32; 3]],
    ) -> Result<(), SimError> {
        let n = embedding.points.len();
        self.check_len("read_points", out.len(), self.num_envs() * n)?;
        if embedding
            .points
            .iter()
            .flat_map(|p| p.triangle)
            .any(|i| i as usize >= self.model.num_particles())
        {
            return Err(SimError::Env {
                env: 0,
                message: "embedding refers to particles this model does not have".into(),
            });
        }
        for (env, row) in out.chunks_mut(n.max(1)).enumerate().take(self.num_envs()) {
            with_lane!(self, env, |b, l| {
                for (p, slot) in embedding.points.iter().zip(row.iter_mut()) {
                    *slot = p.evaluate_with(|i| get3(&b.x[i], l));
                }
            });
        }
        Ok(())
    }

    fn check_len(&self, what: &str, got: usize, expected: usize) -> Result<(), SimError> {
        if got == expected {
            Ok(())
        } else {
            Err(SimError::Env {
                env: 0,
                message: format!("{what}: buffer of {got} entries, expected {expected}"),
            })
        }
    }

    /// Kinetic energy of the package particles and the disc of `env` (J).
    pub fn kinetic_energy(&self, env: usize) -> f64 {
        let m = self.model.package_particle_mass as f64;
        let package: f64 = self.particle_velocities(env)[..self.model.num_package]
            .iter()
            .map(|v| 0.5 * m * v.iter().map(|c| (*c as f64).powi(2)).sum::<f64>())
            .sum();
        let disc = self.disc(env);
        let spec = &self.specs[env];
        let dm = self
            .model
            .disc_mass_with_scale(spec.object_mass_kg, spec.disc_mass_scale);
        let lin = 0.5
            * dm.mass as f64
            * disc
                .velocity
                .iter()
                .map(|c| (*c as f64).powi(2))
                .sum::<f64>();
        let q = crate::math::Quat {
            v: crate::math::V3::new(
                disc.orientation[0],
                disc.orientation[1],
                disc.orientation[2],
            ),
            w: disc.orientation[3],
        };
        let w = q.rotate_inv(crate::math::V3::new(
            disc.angular_velocity[0],
            disc.angular_velocity[1],
            disc.angular_velocity[2],
        ));
        let rot = 0.5
            * (dm.inertia[0] * w.x * w.x + dm.inertia[1] * w.y * w.y + dm.inertia[2] * w.z * w.z)
                as f64;
        package + lin + rot
    }

    /// Embeds world points of environment `env` (e.g. its markers at t0) into the upper sheet at
    /// rest; the result can be evaluated on any environment built with the same placement.
    pub fn embed(&self, env: usize, world_points: &[[f32; 3]]) -> SurfaceEmbedding {
        let o = self.specs[env].placement.package_origin;
        let rel: Vec<[f32; 3]> = world_points
            .iter()
            .map(|p| [p[0] - o[0], p[1] - o[1], p[2] - o[2]])
            .collect();
        self.model.embed_upper_sheet(&rel)
    }

    /// Current world positions of embedded surface points in environment `env`.
    pub fn surface_points(&self, env: usize, embedding: &SurfaceEmbedding) -> Vec<[f32; 3]> {
        embedding.evaluate(&self.particle_positions(env))
    }

    /// Bytes held by the batched state and per-environment data (counted, not RSS; the shared
    /// model and trajectories are not included).
    pub fn state_bytes(&self) -> usize {
        match &self.blocks {
            Blocks::Wide(blocks) => blocks.iter().map(|b| b.bytes()).sum(),
            Blocks::Single(blocks) => blocks.iter().map(|b| b.bytes()).sum(),
        }
    }
}

/// `disc` expressed relative to the tool: position and orientation in the tool frame, velocity
/// relative to the tool's own velocity at the disc's position, angular velocity relative to the
/// tool's; vectors in the tool frame.
fn relative_to_tool(disc: &DiscState, tool: &ToolState) -> DiscState {
    use glam::{DQuat, DVec3};
    let q = DQuat::from_array(tool.orientation);
    let inv = q.inverse();
    let r = DVec3::from(disc.position.map(f64::from)) - DVec3::from(tool.position);
    let w_tool = DVec3::from(tool.angular_velocity);
    let v_rel =
        DVec3::from(disc.velocity.map(f64::from)) - (DVec3::from(tool.velocity) + w_tool.cross(r));
    let w_rel = DVec3::from(disc.angular_velocity.map(f64::from)) - w_tool;
    let q_rel = inv * DQuat::from_array(disc.orientation.map(f64::from));
    let f = |v: DVec3| v.to_array().map(|c| c as f32);
    DiscState {
        position: f(inv * r),
        orientation: q_rel.to_array().map(|c| c as f32),
        velocity: f(inv * v_rel),
        angular_velocity: f(inv * w_rel),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Placement, SceneConfig, ToolSample};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Package corner at (0, 0.3, 0), cups `cup_height` above the mid-plane at the centre, disc at
    /// the centre, tool held still (or following `tool`).
    fn spec(config: &SceneConfig, cup_height: f32, tool: Option<ToolTrajectory>) -> EpisodeSpec {
        let size = config.package.size_m;
        let centre = [size[1] / 2.0, 0.3, size[0] / 2.0];
        let cup_point = [centre[0], centre[1] + cup_height, centre[2]];
        let hold = ToolTrajectory::hold(
            [cup_point[0] as f64, 0.45, cup_point[2] as f64],
            [0.0, 0.0, 0.0, 1.0],
        );
        EpisodeSpec {
            placement: Placement::new([0.0, 0.3, 0.0], cup_point, centre),
            params: config.params,
            object_mass_kg: 0.57,
            disc_mass_scale: None,
            trajectory: Arc::new(tool.unwrap_or(hold)),
        }
    }

    fn coarse(preset: &str, grid: [usize; 2]) -> SceneConfig {
        let mut c = SceneConfig::preset(preset).unwrap();
        c.package.grid = grid;
        c
    }

    fn perturbed(config: &SceneConfig, rng: &mut ChaCha8Rng) -> EpisodeSpec {
        let mut s = spec(config, rng.random_range(0.002..0.02), None);
        let p = &mut s.params;
        p.k_tri_e *= rng.random_range(0.5..2.0);
        p.k_tri_a *= rng.random_range(0.5..2.0);
        p.k_edge_e *= rng.random_range(0.5..2.0);
        p.k_con_e *= rng.random_range(0.5..2.0);
        p.mu_con *= rng.random_range(0.5..1.5);
        s.object_mass_kg = rng.random_range(0.28..0.57);
        s.placement.disc_position[0] += rng.random_range(-0.02..0.02);
        s
    }

    fn snapshot(sim: &Simulator, env: usize) -> Vec<u32> {
        let d = sim.disc(env);
        sim.particle_positions(env)
            .iter()
            .chain(&sim.particle_velocities(env))
            .flatten()
            .chain(
                d.position
                    .iter()
                    .chain(&d.orientation)
                    .chain(&d.velocity)
                    .chain(&d.angular_velocity),
            )
            .map(|c| c.to_bits())
            .collect()
    }

    #[test]
    fn momentum_is_conserved_without_gravity_or_contact() {
        let mut c = coarse("reference", [6, 7]);
        c.integrator.gravity_m_s2 = 0.0;
        c.params.k_spr_e = 0.0;
        c.params.k_spr_d = 0.0;
        let model = Arc::new(Model::new(&c).unwrap());
        let mut s = spec(&c, 0.5, None); // cups far above: no cup contact either
        s.placement.disc_position = [5.0, 5.0, 5.0];
        let mut sim = Simulator::new(model.clone(), vec![s]).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut vel = vec![[0.0f32; 3]; model.num_particles()];
        for v in vel.iter_mut().take(model.num_package) {
            *v = [
                rng.random_range(-0.2..0.2),
                rng.random_range(-0.2..0.2),
                rng.random_range(-0.2..0.2),
            ];
        }
        sim.set_particle_velocities(0, &vel).unwrap();
        let momentum = |sim: &Simulator| {
            let mut p = [0.0f64; 3];
            for v in &sim.particle_velocities(0)[..model.num_package] {
                for k in 0..3 {
                    p[k] += model.package_particle_mass as f64 * v[k] as f64;
                }
            }
            p
        };
        let before = momentum(&sim);
        let positions_before = sim.particle_positions(0);
        sim.step(300);
        let after = momentum(&sim);
        // The internal forces did work: the shape changed.
        let moved = positions_before
            .iter()
            .zip(sim.particle_positions(0))
            .any(|(a, b)| (a[1] - b[1]).abs() > 1e-4);
        assert!(moved);
        for k in 0..3 {
            assert!(
                (before[k] - after[k]).abs() < 1e-3 * 0.8,
                "component {k}: {} vs {}",
                before[k],
                after[k]
            );
        }
    }

    /// Mean y of the lower and upper sheet particles within `radius` (xz) of the disc axis.
    fn sheets_around_disc(sim: &Simulator, env: usize, radius: f32) -> (f32, f32) {
        let m = sim.model();
        let d = sim.disc(env).position;
        let x = sim.particle_positions(env);
        let mean = |range: std::ops::Range<usize>| {
            let ys: Vec<f32> = x[range]
                .iter()
                .filter(|p| (p[0] - d[0]).hypot(p[2] - d[2]) < radius)
                .map(|p| p[1])
                .collect();
            ys.iter().sum::<f32>() / ys.len() as f32
        };
        (mean(0..m.layer_size), mean(m.layer_size..m.num_package))
    }

    fn lift(start: [f64; 3], speed: f64, duration: f64) -> ToolTrajectory {
        let q = [0.0, 0.0, 0.0, 1.0];
        let end = [start[0], start[1] + speed * duration, start[2]];
        let v = [0.0, speed, 0.0];
        ToolTrajectory::new(vec![
            ToolSample {
                t: 0.0,
                position: start,
                orientation: q,
                velocity: v,
            },
            ToolSample {
                t: duration,
                position: end,
                orientation: q,
                velocity: v,
            },
        ])
        .unwrap()
    }

    #[test]
    fn hanging_package_settles_with_disc_inside_then_lifts_without_tunnelling() {
        let mut c = coarse("reference", [11, 13]);
        c.cups.rest_time_s = 1.2;
        let model = Arc::new(Model::new(&c).unwrap());
        let mut s = spec(&c, 0.01, None);
        let tool0 = s.trajectory.pose_at(0.0).position.map(|x| x as f64);
        s.trajectory = Arc::new(lift(tool0, 1.0, 0.2));
        let mut sim = Simulator::new(model, vec![s]).unwrap();
        let tenth = (0.1 / sim.dt() as f64).round() as u64;
        let mut peak = 0.0f64;
        for _ in 0..12 {
            sim.step(tenth);
            peak = peak.max(sim.kinetic_energy(0));
        }
        let settled = sim.kinetic_energy(0);
        assert!(
            settled < 1e-3 && settled < 1e-3 * peak,
            "kinetic energy {settled} J (peak {peak} J)"
        );
        let (lower, upper) = sheets_around_disc(&sim, 0, 0.05);
        let y0 = sim.disc(0).position[1];
        assert!(
            lower < y0 && y0 < upper,
            "disc at {y0} not between sheets {lower} and {upper}"
        );
        assert!(sim.health_events().is_empty());
        // Fast lift: 1 m/s for 0.2 s. The disc must stay between the sheets all the way.
        for _ in 0..8 {
            sim.step(tenth / 2);
            let (lower, upper) = sheets_around_disc(&sim, 0, 0.05);
            let y = sim.disc(0).position[1];
            assert!(
                lower < y && y < upper,
                "t = {}: disc at {y} not between sheets {lower} and {upper}",
                sim.time()
            );
        }
        assert!(
            sim.disc(0).position[1] > y0 + 0.1,
            "disc was not lifted: {} from {y0}",
            sim.disc(0).position[1]
        );
    }

    #[test]
    fn held_disc_reaches_its_hold_point_then_is_released() {
        let mut c = coarse("reference", [11, 13]);
        c.cups.rest_time_s = 0.4;
        let model = Arc::new(Model::new(&c).unwrap());
        let free = spec(&c, 0.01, None);
        let start = free.placement.disc_position;
        let target = [start[0] + 0.02, start[1] - 0.03, start[2] - 0.01];
        let mut held = free.clone();
        held.placement = held.placement.holding_disc_at(target);
        let mut sim = Simulator::new(model, vec![free, held]).unwrap();
        let dt = sim.dt() as f64;
        let steps = |s: f64| (s / dt).round() as u64;
        // Half-way through the travel (a quarter of the rest), the smooth path is half-way too.
        sim.step(steps(0.1));
        let mid = sim.disc(1).position;
        for c in 0..3 {
            let expected = 0.5 * (start[c] + target[c]);
            assert!((mid[c] - expected).abs() < 1e-4, "{mid:?} vs {expected}");
        }
        sim.step(steps(0.3));
        let end = sim.disc(1);
        for c in 0..3 {
            assert!((end.position[c] - target[c]).abs() < 1e-6, "{end:?}");
            assert_eq!(end.velocity[c], 0.0);
        }
        // The free disc of environment 0 went its own way; after the rest the held one moves
        // under the package's forces (it was not at the package's equilibrium).
        assert!((sim.disc(0).position[1] - target[1]).abs() > 1e-3);
        sim.step(steps(0.05));
        let released = sim.disc(1);
        let speed = released.velocity.iter().map(|v| v * v).sum::<f32>().sqrt();
        assert!(speed > 1e-2, "{released:?}");
        assert!(sim.health_events().is_empty());
    }

    #[test]
    fn physical_preset_is_stable_on_coarse_and_fine_grids() {
        for grid in [[11, 13], [26, 31]] {
            let c = coarse("physical", grid);
            let model = Arc::new(Model::new(&c).unwrap());
            let mut sim = Simulator::new(model, vec![spec(&c, 0.01, None)]).unwrap();
            sim.step((0.25 / sim.dt() as f64).round() as u64);
            assert!(
                sim.health_events().is_empty(),
                "{grid:?}: {:?}",
                sim.health_events()
            );
            let (lower, upper) = sheets_around_disc(&sim, 0, 0.05);
            let y = sim.disc(0).position[1];
            assert!(
                lower < y && y < upper,
                "{grid:?}: disc at {y} not between sheets {lower} and {upper}"
            );
        }
    }

    #[test]
    fn env_is_bit_identical_alone_and_in_a_batch_of_1024() {
        let c = coarse("reference", [6, 7]);
        let model = Arc::new(Model::new(&c).unwrap());
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let specs: Vec<EpisodeSpec> = (0..1024).map(|_| perturbed(&c, &mut rng)).collect();
        let mut batch = Simulator::new(model.clone(), specs.clone()).unwrap();
        batch.step(96);
        for env in [0, 5, 517, 1023] {
            let mut alone = Simulator::new(model.clone(), vec![specs[env].clone()]).unwrap();
            alone.step(96);
            assert_eq!(snapshot(&alone, 0), snapshot(&batch, env), "env {env}");
        }
        // Different environments really differ (the comparison above is not vacuous).
        assert_ne!(snapshot(&batch, 0), snapshot(&batch, 5));
    }

    #[test]
    fn results_do_not_depend_on_thread_count() {
        let c = coarse("reference", [6, 7]);
        let model = Arc::new(Model::new(&c).unwrap());
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let specs: Vec<EpisodeSpec> = (0..21).map(|_| perturbed(&c, &mut rng)).collect();
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let mut sim = Simulator::new(model.clone(), specs.clone()).unwrap();
                sim.step(80);
                (0..21).map(|e| snapshot(&sim, e)).collect::<Vec<_>>()
            })
        };
        assert_eq!(run(1), run(2));
    }

    #[test]
    fn health_check_freezes_a_poisoned_env_and_spares_the_others() {
        let c = coarse("reference", [6, 7]);
        let model = Arc::new(Model::new(&c).unwrap());
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let specs: Vec<EpisodeSpec> = (0..10).map(|_| perturbed(&c, &mut rng)).collect();
        let mut poisoned = specs.clone();
        poisoned[3].params.k_tri_e = 1e10;
        poisoned[3].params.k_spr_e = 1e10;
        let mut clean = Simulator::new(model.clone(), specs).unwrap();
        let mut sick = Simulator::new(model, poisoned).unwrap();
        clean.step(256);
        sick.step(256);
        assert!(clean.health_events().is_empty());
        let events = sick.health_events();
        assert_eq!(events.len(), 1, "{events:?}");
        assert_eq!(events[0].env, 3);
        assert!(events[0].time > 0.0 && events[0].time <= sick.time());
        assert!(sick.is_frozen(3) && !sick.is_frozen(2));
        // Frozen: the state no longer changes.
        let frozen = snapshot(&sick, 3);
        sick.step(64);
        assert_eq!(frozen, snapshot(&sick, 3));
        clean.step(64);
        for env in (0..10).filter(|&e| e != 3) {
            assert_eq!(snapshot(&sick, env), snapshot(&clean, env), "env {env}");
        }
    }

    #[test]
    fn reset_restores_the_initial_state() {
        let c = coarse("reference", [6, 7]);
        let model = Arc::new(Model::new(&c).unwrap());
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let specs: Vec<EpisodeSpec> = (0..3).map(|_| perturbed(&c, &mut rng)).collect();
        let mut sim = Simulator::new(model, specs).unwrap();
        let initial = snapshot(&sim, 2);
        sim.step(40);
        let after_40 = snapshot(&sim, 2);
        assert_ne!(initial, after_40);
        sim.reset();
        assert_eq!(sim.substep(), 0);
        assert_eq!(snapshot(&sim, 2), initial);
        sim.step(40);
        assert_eq!(snapshot(&sim, 2), after_40);
    }

    #[test]
    fn retired_envs_stay_put_and_spare_the_others() {
        let c = coarse("reference", [6, 7]);
        let model = Arc::new(Model::new(&c).unwrap());
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let specs: Vec<EpisodeSpec> = (0..2 * LANES).map(|_| perturbed(&c, &mut rng)).collect();
        let mut all = Simulator::new(model.clone(), specs.clone()).unwrap();
        let mut some = Simulator::new(model, specs).unwrap();
        all.step(30);
        some.step(30);
        // Retire the whole first block and one environment of the second.
        let retired: Vec<usize> = (0..LANES).chain([LANES + 3]).collect();
        let before: Vec<Vec<u32>> = retired.iter().map(|&e| snapshot(&some, e)).collect();
        for &e in &retired {
            some.retire(e).unwrap();
        }
        all.step(50);
        some.step(50);
        for (i, &e) in retired.iter().enumerate() {
            assert!(some.is_frozen(e));
            assert_eq!(snapshot(&some, e), before[i], "retired env {e} moved");
        }
        for e in (LANES..2 * LANES).filter(|e| !retired.contains(e)) {
            assert!(!some.is_frozen(e));
            assert_eq!(snapshot(&some, e), snapshot(&all, e), "env {e} changed");
        }
        assert!(some.health_events().is_empty());
        assert!(some.retire(2 * LANES).is_err());
    }

    #[test]
    fn kinematic_cups_follow_the_tool_exactly() {
        let mut c = coarse("physical", [6, 7]);
        c.cups.rest_time_s = 0.0;
        let model = Arc::new(Model::new(&c).unwrap());
        let mut s = spec(&c, 0.01, None);
        let tool0 = s.trajectory.pose_at(0.0).position.map(|x| x as f64);
        s.trajectory = Arc::new(lift(tool0, 0.5, 1.0));
        let cups0 = Simulator::new(model.clone(), vec![s.clone()])
            .unwrap()
            .cup_positions(0);
        let mut sim = Simulator::new(model, vec![s]).unwrap();
        sim.step(1000);
        let rise = 0.5 * sim.time() as f32;
        for (now, then) in sim.cup_positions(0).iter().zip(&cups0) {
            assert!(
                (now[1] - then[1] - rise).abs() < 1e-4,
                "{} vs {}",
                now[1] - then[1],
                rise
            );
            assert!((now[0] - then[0]).abs() < 1e-6 && (now[2] - then[2]).abs() < 1e-6);
        }
    }

    #[test]
    fn bad_env_inputs_are_rejected() {
        let c = coarse("reference", [6, 7]);
        let model = Arc::new(Model::new(&c).unwrap());
        let mut s = spec(&c, 0.01, None);
        s.object_mass_kg = -1.0;
        let err = Simulator::new(model.clone(), vec![s])
            .err()
            .unwrap()
            .to_string();
        assert!(
            err.contains("environment 0") && err.contains("object mass"),
            "{err}"
        );
        let mut sim = Simulator::new(model, vec![spec(&c, 0.01, None)]).unwrap();
        let mut p = c.params;
        p.mu_con = f32::NAN;
        assert!(sim
            .set_params(0, p)
            .unwrap_err()
            .to_string()
            .contains("mu_con"));
        assert!(sim.set_params(4, c.params).is_err());
    }
}
