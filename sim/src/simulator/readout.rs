//! Reading a batch back: per-environment getters, and the batched readers that fill a caller's
//! buffers every control step without allocating ([`Simulator::read_states`],
//! [`Simulator::read_cup_loads`], [`Simulator::read_points`]).

use std::sync::Arc;

use crate::config::ToolLimits;
use crate::embed::{Sheet, SurfaceEmbedding};
use crate::episode::{CupLoad, DiscState, EnvObservation, EpisodeSpec, HealthEvent, SealEvent};
use crate::error::SimError;
use crate::math::get3;
use crate::model::Model;
use crate::tool::ToolState;

use super::{Blocks, Simulator, LANES};

impl Simulator {
    /// Positions of every particle of `env` (package particles, then cup particles).
    pub fn particle_positions(&self, env: usize) -> Vec<[f32; 3]> {
        with_lane!(self, env, |b, l| b
            .state
            .x
            .iter()
            .map(|p| get3(p, l))
            .collect())
    }

    /// Velocities of every particle of `env`.
    pub fn particle_velocities(&self, env: usize) -> Vec<[f32; 3]> {
        with_lane!(self, env, |b, l| b
            .state
            .v
            .iter()
            .map(|p| get3(p, l))
            .collect())
    }

    /// Positions of the cup particles of `env` (cup-major, ring-major within a cup).
    pub fn cup_positions(&self, env: usize) -> Vec<[f32; 3]> {
        let start = self.model.cup_start();
        with_lane!(self, env, |b, l| b.state.x[start..]
            .iter()
            .map(|p| get3(p, l))
            .collect())
    }

    /// The disc of `env`.
    pub fn disc(&self, env: usize) -> DiscState {
        with_lane!(self, env, |b, l| {
            let d = &b.state.disc;
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
        with_lane!(self, env, |b, l| b.state.active.0[l] < 0.5)
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
                let d = &b.state.disc;
                let v = get3(&d.q.v, l);
                let disc = DiscState {
                    position: get3(&d.com, l),
                    orientation: [v[0], v[1], v[2], d.q.w.0[l]],
                    velocity: get3(&d.v, l),
                    angular_velocity: get3(&d.w, l),
                };
                EnvObservation {
                    time: b.state.clock[l] as f64 * k.dt64,
                    tool_position: tool.position.map(|c| c as f32),
                    tool_orientation: tool.orientation.map(|c| c as f32),
                    tool_velocity: tool.velocity.map(|c| c as f32),
                    tool_angular_velocity: tool.angular_velocity.map(|c| c as f32),
                    disc,
                    disc_in_tool: relative_to_tool(&disc, &tool),
                    cups_attached: b.attached_cups(l),
                    frozen: b.state.active.0[l] < 0.5,
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

    /// Writes the force every cup's springs exert on the tool in every environment into `out` (N,
    /// world frame, after the seal model's low-pass filter; what a wrist force sensor reads):
    /// environment-major, one row of [`Simulator::num_cups`] entries per environment.
    pub fn read_cup_forces(&self, out: &mut [[f32; 3]]) -> Result<(), SimError> {
        let cups = self.num_cups();
        self.check_len("read_cup_forces", out.len(), self.num_envs() * cups)?;
        for (env, row) in out.chunks_mut(cups).enumerate() {
            with_lane!(self, env, |b, l| b.read_cup_forces(l, row));
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
                    *slot = p.evaluate_with(|i| get3(&b.state.x[i], l));
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
        self.embed_in_sheet(env, Sheet::Upper, world_points)
    }

    /// [`Simulator::embed`] into either sheet.
    pub fn embed_in_sheet(
        &self,
        env: usize,
        sheet: Sheet,
        world_points: &[[f32; 3]],
    ) -> SurfaceEmbedding {
        let o = self.specs[env].placement.package_origin;
        let rel: Vec<[f32; 3]> = world_points
            .iter()
            .map(|p| [p[0] - o[0], p[1] - o[1], p[2] - o[2]])
            .collect();
        self.model.embed_in_sheet(sheet, &rel)
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
            Blocks::Wide16(blocks) => blocks.iter().map(|b| b.bytes()).sum(),
            Blocks::Single(blocks) => blocks.iter().map(|b| b.bytes()).sum(),
        }
    }

    /// Environments per block (1, [`LANES`] or 16, see `Blocks`).
    #[cfg(test)]
    pub(crate) fn lanes_per_block(&self) -> usize {
        match &self.blocks {
            Blocks::Wide(_) => LANES,
            Blocks::Wide16(_) => crate::solvers::AVX512_LANES,
            Blocks::Single(_) => 1,
        }
    }

    /// Substeps environment `env` has taken since its episode began (its own clock; it stops
    /// while the environment is frozen or retired).
    pub fn env_substep(&self, env: usize) -> u64 {
        with_lane!(self, env, |b, l| b.state.clock[l])
    }

    /// Environment `env`'s own time (s) since its episode began.
    pub fn env_time(&self, env: usize) -> f64 {
        self.env_substep(env) as f64 * self.constants.dt64
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

    /// The spec an environment was built from (with any parameter/trajectory replacements).
    pub fn spec(&self, env: usize) -> &EpisodeSpec {
        &self.specs[env]
    }

    /// The robot limits applied to tool commands (the scene's `tool_limits`).
    pub fn tool_limits(&self) -> &ToolLimits {
        &self.limits
    }

    /// The tool of `env` now: pose and twist.
    pub fn tool_state(&self, env: usize) -> ToolState {
        self.tool_now(env).1
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
