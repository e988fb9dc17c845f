//! [`Simulator`]: a batch of environments (the shared [`Model`], one [`EpisodeSpec`] per
//! environment, their batched state in blocks of [`LANES`], see `block`) and the calls to step it
//! and control it (here), read it back (`readout`) and snapshot it ([`EnvSnapshot`]).

use std::sync::Arc;

use rayon::prelude::*;

use crate::config::{Params, ToolLimits};
use crate::constants::StepConstants;
use crate::episode::{EpisodeSpec, HealthEvent, SealEvent};
use crate::error::SimError;
use crate::model::Model;
use crate::tool::{plan, ToolCommand, ToolCommandReport, ToolDrive, ToolState};
use crate::trajectory::ToolTrajectory;

use crate::solvers::{Simd, AVX512_LANES};
use block::EnvBlock;

/// Environments per block in batches on CPUs without AVX-512 (8 f32 lanes = one AVX2 register),
/// and in batches too small to fill two blocks of [`AVX512_LANES`].
pub const LANES: usize = 8;

/// Blocks of the batch. A batch of one environment uses 1-lane blocks so no lane is wasted; where
/// the CPU has AVX-512, a batch of at least two 16-lane blocks uses 16-lane blocks (one register
/// per value). The arithmetic per lane is the same, so results are bit-identical either way.
enum Blocks {
    Wide(Vec<EnvBlock<LANES>>),
    Wide16(Vec<EnvBlock<AVX512_LANES>>),
    Single(Vec<EnvBlock<1>>),
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
            Blocks::Wide16(blocks) => {
                let lanes = $crate::solvers::AVX512_LANES;
                let $b = &blocks[$env / lanes];
                let $l = $env % lanes;
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
            Blocks::Wide16(blocks) => {
                let $b = &mut blocks[env / $crate::solvers::AVX512_LANES];
                $body
            }
            Blocks::Single(blocks) => {
                let $b = &mut blocks[env];
                $body
            }
        }
    }};
}

mod block;
#[cfg(test)]
mod control_tests;
mod readout;
mod snapshot;
#[cfg(test)]
mod tests;

pub use snapshot::EnvSnapshot;

/// A batch of environments stepped in lockstep.
pub struct Simulator {
    model: Arc<Model>,
    specs: Vec<EpisodeSpec>,
    blocks: Blocks,
    constants: StepConstants,
    limits: ToolLimits,
    substep: u64,
    /// The instruction set the solvers use (the CPU's widest, or lower in tests).
    simd: Simd,
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

/// The blocks of `n` environments, `W` lanes each.
fn wide_blocks<const W: usize>(model: &Model, specs: &[EpisodeSpec]) -> Vec<EnvBlock<W>> {
    let n = specs.len();
    (0..n.div_ceil(W))
        .into_par_iter()
        .map(|b| {
            let (envs, real) = lane_envs::<W>(b, n);
            EnvBlock::new(model, specs, envs, real)
        })
        .collect()
}

/// Lays environments out in blocks (see [`Blocks`]) for the instruction set `simd`.
fn build_blocks(model: &Model, specs: &[EpisodeSpec], simd: Simd) -> Blocks {
    let n = specs.len();
    if n == 1 {
        Blocks::Single(vec![EnvBlock::new(model, specs, [0], [true])])
    } else if simd == Simd::Avx512 && n >= 2 * AVX512_LANES {
        Blocks::Wide16(wide_blocks(model, specs))
    } else {
        Blocks::Wide(wide_blocks(model, specs))
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
    if let Some(vacuum) = spec.vacuum_kpa {
        if !(vacuum.is_finite() && vacuum > 0.0 && vacuum <= 101.325) {
            return fail(format!(
                "vacuum {vacuum} kPa: expected a number in (0, 101.325] kPa below ambient"
            ));
        }
    }
    Ok(())
}

impl Simulator {
    /// Builds the batch: one environment per spec, all at rest at time 0.
    pub fn new(model: Arc<Model>, specs: Vec<EpisodeSpec>) -> Result<Self, SimError> {
        Self::with_simd(model, specs, Simd::detect())
    }

    /// [`Simulator::new`] with the solvers limited to the instruction set `simd` (tests compare
    /// the bits of every one the CPU has).
    pub(crate) fn with_simd(
        model: Arc<Model>,
        specs: Vec<EpisodeSpec>,
        simd: Simd,
    ) -> Result<Self, SimError> {
        let simd = simd.min(Simd::detect());
        if specs.is_empty() {
            return Err(SimError::Env {
                env: 0,
                message: "a batch needs at least one environment".into(),
            });
        }
        for (env, spec) in specs.iter().enumerate() {
            validate_spec(env, spec)?;
        }
        let blocks = build_blocks(&model, &specs, simd);
        let mut sim = Simulator {
            constants: StepConstants::new(&model),
            limits: model.config.tool_limits.clone(),
            model,
            specs,
            blocks,
            substep: 0,
            simd,
            events: Vec::new(),
            seal_events: Vec::new(),
        };
        sim.collect_events();
        Ok(sim)
    }

    /// Puts every environment back to its initial state (time 0, health flags cleared), keeping
    /// the current parameters and trajectories.
    pub fn reset(&mut self) {
        self.blocks = build_blocks(&self.model, &self.specs, self.simd);
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
            b.state.clock[l] as f64 * k.dt64,
            b.tool_state(l, k, 0.0)
        ))
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
            blocks: &mut [EnvBlock<W>],
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
            Blocks::Wide16(blocks) => drain(blocks, &mut health, &mut seal),
            Blocks::Single(blocks) => drain(blocks, &mut health, &mut seal),
        }
        health.sort_by(|a, b| a.time.total_cmp(&b.time).then(a.env.cmp(&b.env)));
        // Stable: within one environment and instant, the order the block found them in.
        seal.sort_by(|a, b| a.env.cmp(&b.env).then(a.time.total_cmp(&b.time)));
        self.events.append(&mut health);
        self.seal_events.append(&mut seal);
    }

    /// Advances every active environment by `substeps` substeps of its own clock (in parallel
    /// over blocks of environments; frozen and retired environments stay as they are and cost
    /// nothing once their whole block is).
    pub fn step(&mut self, substeps: u64) {
        let (model, k, simd) = (&*self.model, &self.constants, self.simd);
        match &mut self.blocks {
            Blocks::Wide(blocks) => blocks
                .par_iter_mut()
                .for_each(|b| b.advance(model, k, substeps, false, simd)),
            Blocks::Wide16(blocks) => blocks
                .par_iter_mut()
                .for_each(|b| b.advance(model, k, substeps, false, simd)),
            Blocks::Single(blocks) => blocks
                .iter_mut()
                .for_each(|b| b.advance(model, k, substeps, true, simd)),
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
            Blocks::Wide16(blocks) => blocks[env / AVX512_LANES].retire(env),
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
            Blocks::Wide16(blocks) => blocks[env / AVX512_LANES].set_params(env, model, spec),
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
            Blocks::Wide16(blocks) => blocks[env / AVX512_LANES].set_trajectory(env, &trajectory),
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
        fn write<const W: usize>(b: &mut EnvBlock<W>, env: usize, velocities: &[[f32; 3]]) {
            for l in 0..W {
                if b.envs[l] == env {
                    for (v, u) in b.state.v.iter_mut().zip(velocities) {
                        v.x.0[l] = u[0];
                        v.y.0[l] = u[1];
                        v.z.0[l] = u[2];
                    }
                }
            }
        }
        match &mut self.blocks {
            Blocks::Wide(blocks) => write(&mut blocks[env / LANES], env, velocities),
            Blocks::Wide16(blocks) => write(&mut blocks[env / AVX512_LANES], env, velocities),
            Blocks::Single(blocks) => write(&mut blocks[env], env, velocities),
        }
        Ok(())
    }
}
