//! [`Simulator`]: a batch of environments (model + per-environment data + batched state) and the
//! calls to step it and read it back.

use std::sync::Arc;

use rayon::prelude::*;

use crate::block::{advance_block, get3, Block, StepConstants};
use crate::config::Params;
use crate::embed::SurfaceEmbedding;
use crate::error::SimError;
use crate::model::Model;
use crate::state::{DiscState, EnvSpec, HealthEvent};
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
macro_rules! with_lane {
    ($self:expr, $env:expr, |$b:ident, $l:ident| $body:expr) => {
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
    };
}

/// A batch of environments stepped in lockstep.
pub struct Simulator {
    model: Arc<Model>,
    specs: Vec<EnvSpec>,
    blocks: Blocks,
    constants: StepConstants,
    substep: u64,
    events: Vec<HealthEvent>,
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
fn build_blocks(model: &Model, specs: &[EnvSpec]) -> Blocks {
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

impl Simulator {
    /// Builds the batch: one environment per spec, all at rest at time 0.
    pub fn new(model: Arc<Model>, specs: Vec<EnvSpec>) -> Result<Self, SimError> {
        if specs.is_empty() {
            return Err(SimError::Env {
                env: 0,
                message: "a batch needs at least one environment".into(),
            });
        }
        for (env, spec) in specs.iter().enumerate() {
            spec.params
                .validate(&format!("environment {env} parameters"))
                .map_err(|e| SimError::Env {
                    env,
                    message: e.to_string(),
                })?;
            let pl = &spec.placement;
            let values = pl
                .package_origin
                .iter()
                .chain(&pl.cup_point)
                .chain(&pl.disc_position);
            if values.clone().any(|c| !c.is_finite()) {
                return Err(SimError::Env {
                    env,
                    message: "placement has a non-finite coordinate".into(),
                });
            }
            if !(spec.object_mass_kg.is_finite() && spec.object_mass_kg > 0.0) {
                return Err(SimError::Env {
                    env,
                    message: format!(
                        "object mass {} kg: expected a positive number",
                        spec.object_mass_kg
                    ),
                });
            }
        }
        let blocks = build_blocks(&model, &specs);
        Ok(Simulator {
            constants: StepConstants::new(&model),
            model,
            specs,
            blocks,
            substep: 0,
            events: Vec::new(),
        })
    }

    /// Puts every environment back to its initial state (time 0, health flags cleared), keeping
    /// the current parameters and trajectories.
    pub fn reset(&mut self) {
        self.blocks = build_blocks(&self.model, &self.specs);
        self.substep = 0;
        self.events.clear();
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

    /// Substeps taken so far.
    pub fn substep(&self) -> u64 {
        self.substep
    }

    /// Simulated time (s), counted from the start of the rest period.
    pub fn time(&self) -> f64 {
        self.substep as f64 * self.constants.dt64
    }

    /// Advances every environment by `substeps` substeps (in parallel over blocks of
    /// environments; frozen environments stay as they are).
    pub fn step(&mut self, substeps: u64) {
        let (model, k, start) = (&*self.model, &self.constants, self.substep);
        match &mut self.blocks {
            Blocks::Wide(blocks) => blocks
                .par_iter_mut()
                .for_each(|b| advance_block(b, model, k, start, substeps, false)),
            Blocks::Single(blocks) => blocks
                .iter_mut()
                .for_each(|b| advance_block(b, model, k, start, substeps, true)),
        }
        self.substep += substeps;
        let mut fresh: Vec<HealthEvent> = match &mut self.blocks {
            Blocks::Wide(blocks) => blocks
                .iter_mut()
                .flat_map(|b| std::mem::take(&mut b.events))
                .collect(),
            Blocks::Single(blocks) => blocks
                .iter_mut()
                .flat_map(|b| std::mem::take(&mut b.events))
                .collect(),
        };
        fresh.sort_by(|a, b| a.time.total_cmp(&b.time).then(a.env.cmp(&b.env)));
        self.events.extend(fresh);
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
        let (model, mass) = (&*self.model, self.specs[env].object_mass_kg);
        match &mut self.blocks {
            Blocks::Wide(blocks) => blocks[env / LANES].set_params(env, model, &params, mass),
            Blocks::Single(blocks) => blocks[env].set_params(env, model, &params, mass),
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
    pub fn spec(&self, env: usize) -> &EnvSpec {
        &self.specs[env]
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

    /// Every health event so far, in time order.
    pub fn health_events(&self) -> &[HealthEvent] {
        &self.events
    }

    /// Kinetic energy of the package particles and the disc of `env` (J).
    pub fn kinetic_energy(&self, env: usize) -> f64 {
        let m = self.model.package_particle_mass as f64;
        let package: f64 = self.particle_velocities(env)[..self.model.num_package]
            .iter()
            .map(|v| 0.5 * m * v.iter().map(|c| (*c as f64).powi(2)).sum::<f64>())
            .sum();
        let disc = self.disc(env);
        let dm = self.model.disc_mass(self.specs[env].object_mass_kg);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Placement, SceneConfig, ToolSample};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Package corner at (0, 0.3, 0), cups `cup_height` above the mid-plane at the centre, disc at
    /// the centre, tool held still (or following `tool`).
    fn spec(config: &SceneConfig, cup_height: f32, tool: Option<ToolTrajectory>) -> EnvSpec {
        let size = config.package.size_m;
        let centre = [size[1] / 2.0, 0.3, size[0] / 2.0];
        let cup_point = [centre[0], centre[1] + cup_height, centre[2]];
        let hold = ToolTrajectory::hold(
            [cup_point[0] as f64, 0.45, cup_point[2] as f64],
            [0.0, 0.0, 0.0, 1.0],
        );
        EnvSpec {
            placement: Placement {
                package_origin: [0.0, 0.3, 0.0],
                cup_point,
                disc_position: centre,
                disc_hold: None,
            },
            params: config.params,
            object_mass_kg: 0.57,
            trajectory: Arc::new(tool.unwrap_or(hold)),
        }
    }

    fn coarse(preset: &str, grid: [usize; 2]) -> SceneConfig {
        let mut c = SceneConfig::preset(preset).unwrap();
        c.package.grid = grid;
        c
    }

    fn perturbed(config: &SceneConfig, rng: &mut ChaCha8Rng) -> EnvSpec {
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
        let specs: Vec<EnvSpec> = (0..1024).map(|_| perturbed(&c, &mut rng)).collect();
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
        let specs: Vec<EnvSpec> = (0..21).map(|_| perturbed(&c, &mut rng)).collect();
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
        let specs: Vec<EnvSpec> = (0..10).map(|_| perturbed(&c, &mut rng)).collect();
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
        let specs: Vec<EnvSpec> = (0..3).map(|_| perturbed(&c, &mut rng)).collect();
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
        let specs: Vec<EnvSpec> = (0..2 * LANES).map(|_| perturbed(&c, &mut rng)).collect();
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
