//! A block of W environments in lockstep, and the semi-implicit Euler integrator that advances it.
//!
//! # Layout
//! Every per-particle quantity is stored `[particle][component][lane]` (`Vec<V3<Lanes<W>>>`): the
//! W environments of a block sit side by side in the innermost dimension. All environments share
//! the topology, so an element's particle indices are the same in every lane: loading a triangle's
//! vertices reads three contiguous W-wide vectors per component, and every force law (written once
//! in `forces.rs`) runs as straight-line W-lane arithmetic that compiles to packed SIMD (W = 8 is one
//! AVX2 register of f32). There are no scatter conflicts across lanes and no cross-lane reductions,
//! so each lane computes exactly what it would compute alone. Blocks are independent and run in
//! parallel (rayon), each for the whole requested number of substeps, which keeps a block's ~0.5 MB
//! working set hot in cache. Partial blocks are padded with copies of a real environment whose
//! results are discarded.
//!
//! Lane-dependent shortcuts (skipping contacts when every lane is far away) only ever skip work
//! whose lanes would be left bit-for-bit unchanged: contact forces are applied by a per-lane select,
//! never by adding a zero.

mod assembly;
mod descent;
mod health;
mod seal;
mod snapshot;

use std::sync::Arc;

use crate::config::{DriveMode, Solver};
use crate::forces::ContactMaterial;
use crate::implicit::Sym3;
use crate::math::{Lanes, Quat, Real, V3};
use crate::model::Model;
use crate::state::{EpisodeSpec, HealthEvent, SealEvent};
use crate::tool::{ToolDrive, ToolState};
use crate::trajectory::ToolTrajectory;

use assembly::{contact_and_bending_forces, membrane_forces};
pub(crate) use seal::SealConstants;
pub(crate) use snapshot::LaneSnapshot;

type L<const W: usize> = Lanes<W>;

/// Elements processed together by the single-environment paths (SIMD across elements).
const ELEMENT_LANES: usize = 8;
type E8 = Lanes<ELEMENT_LANES>;

/// Lane 0's positions `x` and velocities `v` at the `N` vertices of `count` elements (`vertices(e)`
/// of element `e`), element `e` in lane `e`. Lanes past `count` repeat the last element; callers
/// do not add them.
#[inline(always)]
fn gather_elements<const W: usize, const N: usize>(
    count: usize,
    vertices: impl Fn(usize) -> [u32; N],
    x: &[V3<L<W>>],
    v: &[V3<L<W>>],
) -> ([V3<E8>; N], [V3<E8>; N]) {
    let mut xs = [V3::<E8>::zero(); N];
    let mut vs = [V3::<E8>::zero(); N];
    for e in 0..ELEMENT_LANES {
        for (k, &j) in vertices(e.min(count - 1)).iter().enumerate() {
            set3(&mut xs[k], e, get3(&x[j as usize], 0));
            set3(&mut vs[k], e, get3(&v[j as usize], 0));
        }
    }
    (xs, vs)
}

/// Per-lane material parameters, masses and contact materials.
#[derive(Clone, Copy)]
pub(crate) struct LaneParams<const W: usize> {
    tri: [L<W>; 3],
    edge: [L<W>; 2],
    cup_tri: [L<W>; 3],
    spring: [L<W>; 2],
    disc_contact: ContactMaterial<L<W>>,
    disc_ground: ContactMaterial<L<W>>,
    inv_mass_package: L<W>,
    inv_mass_cup: L<W>,
    disc_mass: L<W>,
    disc_inertia: V3<L<W>>,
    gravity: L<W>,
}

/// Attachment spring of one cup particle (one element of its cup's lip): per-lane package
/// vertex, rest length, whether it is sealed (1) or let go (0), and its filtered pull along the
/// cup axis (N).
#[derive(Clone, Copy)]
pub(crate) struct LaneSpring<const W: usize> {
    pub(crate) target: [u32; W],
    pub(crate) rest: L<W>,
    pub(crate) sealed: L<W>,
    pub(crate) tension: L<W>,
}

/// Seal state of one cup in every lane.
#[derive(Clone, Copy)]
pub(crate) struct LaneCup<const W: usize> {
    /// 1 while the cup holds the film, 0 once it let go (or never sealed).
    pub(crate) attached: L<W>,
    /// Lip elements (springs) still sealed.
    pub(crate) sealed_count: L<W>,
    /// Filtered force of the film on the cup (N, world).
    pub(crate) load: V3<L<W>>,
}

/// The disc of every lane.
#[derive(Clone, Copy)]
pub(crate) struct LaneDisc<const W: usize> {
    pub(crate) com: V3<L<W>>,
    pub(crate) q: Quat<L<W>>,
    pub(crate) v: V3<L<W>>,
    pub(crate) w: V3<L<W>>,
}

/// Quantities fixed for a whole batch, derived from the model's config.
pub(crate) struct StepConstants {
    pub(crate) dt: f32,
    pub(crate) dt64: f64,
    pub(crate) rest_time: f64,
    pub(crate) drive: DriveMode,
    pub(crate) kp: f32,
    pub(crate) kff: f32,
    pub(crate) check_every: u64,
    pub(crate) max_speed: f32,
    pub(crate) max_displacement: f32,
    pub(crate) ground: ContactMaterial<f32>,
    pub(crate) angular_damping: f32,
    pub(crate) max_particle_speed: f32,
    pub(crate) contact_refresh: u64,
    pub(crate) seal: SealConstants,
    pub(crate) solver: Solver,
    pub(crate) iterations: u32,
    pub(crate) chebyshev_rho: f32,
    /// Reach of the disc's centre beyond the package's particles before it counts as outside (m).
    pub(crate) object_outside_margin: f32,
    pub(crate) object_outside: bool,
}

impl StepConstants {
    pub(crate) fn new(model: &Model) -> Self {
        let c = &model.config;
        StepConstants {
            dt: c.dt(),
            dt64: 1.0 / c.integrator.substep_rate_hz,
            rest_time: c.cups.rest_time_s as f64,
            drive: c.cups.drive,
            kp: c.cups.servo_kp,
            kff: c.cups.servo_kff,
            check_every: c.health.check_every as u64,
            max_speed: c.health.max_speed_m_s,
            max_displacement: c.health.max_displacement_m,
            ground: ContactMaterial {
                ke: c.contact.soft_ke,
                kd: c.contact.soft_kd,
                kf: c.contact.soft_kf,
                mu: c.contact.soft_mu,
            },
            angular_damping: c.integrator.angular_damping,
            max_particle_speed: c.integrator.max_particle_speed_m_s,
            contact_refresh: c.disc.contact_refresh_substeps as u64,
            seal: SealConstants::new(model),
            solver: c.integrator.solver,
            iterations: c.integrator.iterations,
            chebyshev_rho: c.integrator.chebyshev_rho,
            object_outside_margin: model.particle_radius + c.disc.radius_m,
            object_outside: c.health.object_outside,
        }
    }
}

/// W environments stepped together.
pub(crate) struct Block<const W: usize> {
    /// Environment index of each lane (padding lanes repeat a real one).
    pub(crate) envs: [usize; W],
    /// Whether a lane is a real environment (not padding).
    pub(crate) real: [bool; W],
    pub(crate) x: Vec<V3<L<W>>>,
    pub(crate) v: Vec<V3<L<W>>>,
    f: Vec<V3<L<W>>>,
    f2: Vec<V3<L<W>>>,
    x0: Vec<V3<L<W>>>,
    cup_offsets: Vec<V3<L<W>>>,
    pub(crate) springs: Vec<LaneSpring<W>>,
    /// Per spring: its force on the cup particle this substep (scratch for the seal model).
    spring_force: Vec<V3<L<W>>>,
    pub(crate) cups: Vec<LaneCup<W>>,
    /// Per lane: the cups' axis (from the cup face towards the film) in the tool frame.
    cup_axis_local: V3<L<W>>,
    pub(crate) disc: LaneDisc<W>,
    disc_x0: V3<L<W>>,
    /// Per lane: where the disc is held during the rest (`None`: free), see `Placement::disc_hold`.
    disc_hold: [Option<[f32; 3]>; W],
    /// Per lane: the orientation a held disc is turned to during the rest (`None`: the disc is
    /// free), see `Placement::disc_orientation`.
    disc_turn: [Option<[f32; 4]>; W],
    /// Per particle: frozen contact point on the disc (body frame) and normal (world).
    contact_point: Vec<V3<L<W>>>,
    contact_normal: Vec<V3<L<W>>>,
    params: LaneParams<W>,
    pub(crate) tools: Vec<ToolDrive>,
    /// Per lane: substeps since the start of its episode (its own clock).
    pub(crate) clock: [u64; W],
    /// 1.0 for lanes still simulated, 0.0 for frozen ones.
    pub(crate) active: L<W>,
    pub(crate) events: Vec<HealthEvent>,
    pub(crate) seal_events: Vec<SealEvent>,
    /// Block descent only (empty otherwise): package positions at the start of the substep and
    /// their inertial predictions.
    x_start: Vec<V3<L<W>>>,
    inertia_target: Vec<V3<L<W>>>,
    /// Block descent only: the step velocity `(x − x_start) / h` of each package vertex's current
    /// iterate, kept with `x` (every element around a vertex reads it).
    x_rate: Vec<V3<L<W>>>,
    /// Block descent only: attachment springs per package vertex (rows of `[spring; W]`, one
    /// spring index per lane or `u32::MAX`), and the particles near the disc this substep.
    spring_slot_starts: Vec<u32>,
    spring_slots: Vec<[u32; W]>,
    disc_candidates: Vec<u32>,
    /// Block descent only: whether each package particle is among `disc_candidates`.
    near_disc: Vec<bool>,
    /// Block descent with Chebyshev acceleration only: package positions before the current sweep
    /// and before the previous one.
    x_before: Vec<V3<L<W>>>,
    x_older: Vec<V3<L<W>>>,
    /// Block descent only: bending force and stiffness per package vertex at a sweep's start.
    bend_force: Vec<V3<L<W>>>,
    bend_stiffness: Vec<Sym3<L<W>>>,
}

#[inline(always)]
pub(crate) fn set3<const W: usize>(v: &mut V3<L<W>>, l: usize, a: [f32; 3]) {
    v.x.0[l] = a[0];
    v.y.0[l] = a[1];
    v.z.0[l] = a[2];
}
#[inline(always)]
pub(crate) fn get3<const W: usize>(v: &V3<L<W>>, l: usize) -> [f32; 3] {
    [v.x.0[l], v.y.0[l], v.z.0[l]]
}

fn lane_params_set<const W: usize>(
    p: &mut LaneParams<W>,
    l: usize,
    model: &Model,
    spec: &EpisodeSpec,
) {
    let params = &spec.params;
    let c = &model.config.contact;
    p.tri[0].0[l] = params.k_tri_e;
    p.tri[1].0[l] = params.k_tri_a;
    p.tri[2].0[l] = params.k_tri_d;
    p.edge[0].0[l] = params.k_edge_e;
    p.edge[1].0[l] = params.k_edge_d;
    p.cup_tri[0].0[l] = params.k_cup_e;
    p.cup_tri[1].0[l] = params.k_cup_a;
    p.cup_tri[2].0[l] = params.k_cup_d;
    p.spring[0].0[l] = params.k_spr_e;
    p.spring[1].0[l] = params.k_spr_d;
    // Warp averages the model-wide soft contact material with the shape's (reference preset).
    let avg = |model_value: f32, shape: f32| {
        if c.average_disc_with_soft {
            0.5 * (model_value + shape)
        } else {
            shape
        }
    };
    p.disc_contact.ke.0[l] = avg(c.soft_ke, params.k_con_e);
    p.disc_contact.kd.0[l] = avg(c.soft_kd, params.k_con_d);
    p.disc_contact.kf.0[l] = avg(c.soft_kf, params.k_con_f);
    p.disc_contact.mu.0[l] = avg(c.soft_mu, params.mu_con);
    // Rigid contacts average the two shapes' materials (disc and ground).
    p.disc_ground.ke.0[l] = 0.5 * (params.k_con_e + c.ground_ke);
    p.disc_ground.kd.0[l] = 0.5 * (params.k_con_d + c.ground_kd);
    p.disc_ground.kf.0[l] = 0.5 * (params.k_con_f + c.ground_kf);
    p.disc_ground.mu.0[l] = 0.5 * (params.mu_con + c.ground_mu);
    p.inv_mass_package.0[l] = 1.0 / model.package_particle_mass;
    p.inv_mass_cup.0[l] = 1.0 / model.cup_particle_mass;
    let disc = model.disc_mass_with_scale(spec.object_mass_kg, spec.disc_mass_scale);
    p.disc_mass.0[l] = disc.mass;
    set3(&mut p.disc_inertia, l, disc.inertia);
    p.gravity.0[l] = model.config.integrator.gravity_m_s2;
}

impl<const W: usize> Block<W> {
    /// A block holding `specs[envs[l]]` in lane l.
    pub(crate) fn new(
        model: &Model,
        specs: &[EpisodeSpec],
        envs: [usize; W],
        real: [bool; W],
    ) -> Self {
        let n = model.num_particles();
        let zero3 = V3::<L<W>>::zero();
        let zero = L::<W>::splat(0.0);
        let one = L::<W>::splat(1.0);
        let zero_contact = ContactMaterial {
            ke: zero,
            kd: zero,
            kf: zero,
            mu: zero,
        };
        let mut block = Block {
            envs,
            real,
            x: vec![zero3; n],
            v: vec![zero3; n],
            f: vec![zero3; n],
            f2: vec![zero3; n],
            x0: vec![zero3; n],
            cup_offsets: vec![zero3; model.num_cup],
            springs: vec![
                LaneSpring {
                    target: [0; W],
                    rest: zero,
                    sealed: one,
                    tension: zero,
                };
                model.num_cup
            ],
            spring_force: vec![zero3; model.num_cup],
            cups: vec![
                LaneCup {
                    attached: one,
                    sealed_count: L::splat(model.cup_size as f32),
                    load: zero3,
                };
                model.num_cups()
            ],
            cup_axis_local: zero3,
            disc: LaneDisc {
                com: zero3,
                q: Quat {
                    v: zero3,
                    w: L::splat(1.0),
                },
                v: zero3,
                w: zero3,
            },
            disc_x0: zero3,
            disc_hold: [None; W],
            disc_turn: [None; W],
            contact_point: vec![zero3; n],
            contact_normal: vec![zero3; n],
            params: LaneParams {
                tri: [zero; 3],
                edge: [zero; 2],
                cup_tri: [zero; 3],
                spring: [zero; 2],
                disc_contact: zero_contact,
                disc_ground: zero_contact,
                inv_mass_package: zero,
                inv_mass_cup: zero,
                disc_mass: zero,
                disc_inertia: zero3,
                gravity: zero,
            },
            tools: envs
                .iter()
                .map(|&e| ToolDrive::Trajectory(specs[e].trajectory.clone()))
                .collect(),
            clock: [0; W],
            active: one,
            events: Vec::new(),
            seal_events: Vec::new(),
            x_start: Vec::new(),
            inertia_target: Vec::new(),
            x_rate: Vec::new(),
            spring_slot_starts: Vec::new(),
            spring_slots: Vec::new(),
            disc_candidates: Vec::new(),
            near_disc: Vec::new(),
            x_before: Vec::new(),
            x_older: Vec::new(),
            bend_force: Vec::new(),
            bend_stiffness: Vec::new(),
        };
        if model.config.integrator.solver == Solver::BlockDescent {
            block.x_start = vec![zero3; model.num_package];
            block.inertia_target = vec![zero3; model.num_package];
            block.x_rate = vec![zero3; model.num_package];
            block.bend_force = vec![zero3; model.num_package];
            block.bend_stiffness = vec![Sym3::zero(); model.num_package];
            if model.config.integrator.chebyshev_rho > 0.0 {
                block.x_before = vec![zero3; model.num_package];
                block.x_older = vec![zero3; model.num_package];
            }
        }
        for (l, &e) in envs.iter().enumerate() {
            block.init_lane(l, model, &specs[e]);
        }
        block
    }

    /// Lanes holding environment `env` (one, or several in a padded block).
    fn lanes_of(&self, env: usize) -> impl Iterator<Item = usize> + '_ {
        (0..W).filter(move |&l| self.envs[l] == env)
    }

    /// Restarts every lane holding `env` from `spec`: time 0, active, cups sealed anew.
    pub(crate) fn reset_env(&mut self, env: usize, model: &Model, spec: &EpisodeSpec) {
        for l in self.lanes_of(env).collect::<Vec<_>>() {
            self.tools[l] = ToolDrive::Trajectory(spec.trajectory.clone());
            self.clock[l] = 0;
            self.active.0[l] = 1.0;
            self.init_lane(l, model, spec);
        }
    }

    /// The tool of lane `l` now (environment time plus `ahead` seconds).
    pub(crate) fn tool_state(&self, l: usize, k: &StepConstants, ahead: f64) -> ToolState {
        self.tools[l].state_at(self.clock[l] as f64 * k.dt64 + ahead, k.rest_time)
    }

    /// Replaces what drives the tool of every lane holding `env`.
    pub(crate) fn set_drive(&mut self, env: usize, drive: &ToolDrive) {
        for l in self.lanes_of(env).collect::<Vec<_>>() {
            self.tools[l] = drive.clone();
        }
    }

    /// Overwrites the positions of every particle of `env` (velocities unchanged).
    pub(crate) fn set_positions(&mut self, env: usize, positions: &[[f32; 3]]) {
        for l in self.lanes_of(env).collect::<Vec<_>>() {
            for (x, p) in self.x.iter_mut().zip(positions) {
                set3(x, l, *p);
            }
        }
    }

    /// Places environment `spec` in lane `l`: positions, springs, cup offsets, disc, parameters.
    fn init_lane(&mut self, l: usize, model: &Model, spec: &EpisodeSpec) {
        let pl = &spec.placement;
        let cup_start = model.cup_start();
        // The package (and the disc in it) turned by its yaw about the vertical through the cup point.
        let (sin, cos) = pl.package_yaw_rad.sin_cos();
        let yaw = |p: [f32; 3]| {
            if pl.package_yaw_rad == 0.0 {
                return p;
            }
            let (dx, dz) = (p[0] - pl.cup_point[0], p[2] - pl.cup_point[2]);
            [
                pl.cup_point[0] + cos * dx + sin * dz,
                p[1],
                pl.cup_point[2] - sin * dx + cos * dz,
            ]
        };
        for (i, off) in model.rest_offsets.iter().enumerate() {
            let anchor = if i < cup_start {
                pl.package_origin
            } else {
                pl.cup_point
            };
            let p = [anchor[0] + off[0], anchor[1] + off[1], anchor[2] + off[2]];
            let p = if i < cup_start { yaw(p) } else { p };
            set3(&mut self.x[i], l, p);
            set3(&mut self.x0[i], l, p);
            set3(&mut self.v[i], l, [0.0; 3]);
        }
        // Cup offsets from the tool's first pose.
        let tool0 = spec.trajectory.pose_at(f64::NEG_INFINITY);
        let q0 = Quat {
            v: V3::new(
                tool0.orientation[0],
                tool0.orientation[1],
                tool0.orientation[2],
            ),
            w: tool0.orientation[3],
        };
        for k in 0..model.num_cup {
            let c = get3(&self.x[cup_start + k], l);
            let d = V3::new(
                c[0] - tool0.position[0],
                c[1] - tool0.position[1],
                c[2] - tool0.position[2],
            );
            let d = if model.config.cups.offsets_in_tool_frame {
                q0.rotate_inv(d)
            } else {
                d
            };
            set3(&mut self.cup_offsets[k], l, [d.x, d.y, d.z]);
        }
        // The cups are built face down (world −y); their axis turns with the tool from here on.
        let down = V3::new(0.0, -1.0, 0.0);
        let axis = if model.config.cups.offsets_in_tool_frame {
            q0.rotate_inv(down)
        } else {
            down
        };
        set3(&mut self.cup_axis_local, l, [axis.x, axis.y, axis.z]);
        let disc_position = yaw(pl.disc_position);
        set3(&mut self.disc.com, l, disc_position);
        set3(&mut self.disc_x0, l, disc_position);
        self.disc_hold[l] = pl.disc_hold.map(yaw);
        let q = pl.disc_orientation;
        let norm = q.iter().map(|c| c * c).sum::<f32>().sqrt();
        let q = q.map(|c| c / norm);
        // A held disc starts level and is turned to its orientation during the rest (see
        // `DiscConfig::hold_orientation`).
        self.disc_turn[l] = self.disc_hold[l]
            .filter(|_| model.config.disc.hold_orientation)
            .map(|_| q);
        let q = if self.disc_turn[l].is_some() {
            [0.0, 0.0, 0.0, 1.0]
        } else {
            q
        };
        set3(&mut self.disc.q.v, l, [q[0], q[1], q[2]]);
        self.disc.q.w.0[l] = q[3];
        set3(&mut self.disc.v, l, [0.0; 3]);
        set3(&mut self.disc.w, l, [0.0; 3]);
        for i in 0..model.num_particles() {
            set3(&mut self.contact_point[i], l, [0.0; 3]);
            set3(&mut self.contact_normal[i], l, [0.0; 3]);
        }
        lane_params_set(&mut self.params, l, model, spec);
        // Springs: each cup particle to its nearest upper-sheet particle (first minimum wins).
        self.attach_cups_lane(l, model, 0.0, tool0.orientation.map(f64::from));
    }

    /// Bytes held by this block's arrays.
    pub(crate) fn bytes(&self) -> usize {
        let per_particle = std::mem::size_of::<V3<L<W>>>();
        let particle_arrays = [
            &self.x,
            &self.v,
            &self.f,
            &self.f2,
            &self.x0,
            &self.contact_point,
            &self.contact_normal,
            &self.x_start,
            &self.inertia_target,
            &self.x_rate,
            &self.bend_force,
            &self.x_before,
            &self.x_older,
        ];
        particle_arrays
            .iter()
            .map(|a| a.capacity() * per_particle)
            .sum::<usize>()
            + (self.cup_offsets.capacity() + self.spring_force.capacity()) * per_particle
            + self.bend_stiffness.capacity() * std::mem::size_of::<Sym3<L<W>>>()
            + self.springs.capacity() * std::mem::size_of::<LaneSpring<W>>()
            + self.cups.capacity() * std::mem::size_of::<LaneCup<W>>()
            + std::mem::size_of::<Self>()
    }

    /// Stops stepping every lane holding `env`; its state stays as it is.
    pub(crate) fn retire(&mut self, env: usize) {
        for l in 0..W {
            if self.envs[l] == env {
                self.active.0[l] = 0.0;
            }
        }
    }

    /// Replaces the material parameters (and object mass) of every lane holding `env`.
    pub(crate) fn set_params(&mut self, env: usize, model: &Model, spec: &EpisodeSpec) {
        for l in 0..W {
            if self.envs[l] == env {
                lane_params_set(&mut self.params, l, model, spec);
            }
        }
    }

    /// Replaces the tool trajectory of every lane holding `env`.
    pub(crate) fn set_trajectory(&mut self, env: usize, trajectory: &Arc<ToolTrajectory>) {
        self.set_drive(env, &ToolDrive::Trajectory(trajectory.clone()));
    }

    /// Each lane's own time (s) plus `ahead`.
    fn lane_times(&self, k: &StepConstants, ahead: f64) -> [f64; W] {
        std::array::from_fn(|l| self.clock[l] as f64 * k.dt64 + ahead)
    }

    /// Tool position, orientation and velocity of every lane at its time `t[l]`.
    fn tool_lanes(&self, t: &[f64; W], rest_time: f64) -> (V3<L<W>>, Quat<L<W>>, V3<L<W>>) {
        let mut p = V3::<L<W>>::zero();
        let mut q = Quat {
            v: V3::<L<W>>::zero(),
            w: L::splat(1.0),
        };
        let mut vel = V3::<L<W>>::zero();
        for l in 0..W {
            let pose = self.tools[l].state_at(t[l], rest_time).pose();
            set3(&mut p, l, pose.position);
            set3(
                &mut q.v,
                l,
                [
                    pose.orientation[0],
                    pose.orientation[1],
                    pose.orientation[2],
                ],
            );
            q.w.0[l] = pose.orientation[3];
            // No feed-forward velocity during the rest period (the tool is held).
            set3(&mut vel, l, pose.velocity);
        }
        (p, q, vel)
    }

    /// The disc centre and velocity at time `t` for lanes whose disc is held during the rest
    /// (`Placement::disc_hold`): a smooth path from the start to the hold point over the first half
    /// of the rest, then still. Other lanes, and every lane after the rest, keep `com`, `v`.
    fn held_disc(
        &self,
        t: &[f64; W],
        rest_time: f64,
        mut com: V3<L<W>>,
        mut v: V3<L<W>>,
    ) -> (V3<L<W>>, V3<L<W>>) {
        for l in 0..W {
            if t[l] > rest_time {
                continue;
            }
            let (shape, rate) = hold_profile(t[l], rest_time);
            if let Some(target) = self.disc_hold[l] {
                let start = get3(&self.disc_x0, l);
                let at =
                    |c: usize| (start[c] as f64 + (target[c] - start[c]) as f64 * shape) as f32;
                let speed = |c: usize| ((target[c] - start[c]) as f64 * rate) as f32;
                set3(&mut com, l, [at(0), at(1), at(2)]);
                set3(&mut v, l, [speed(0), speed(1), speed(2)]);
            }
        }
        (com, v)
    }

    /// The disc orientation and angular velocity at time `t` for lanes whose disc is held during
    /// the rest: turned from level about the tilt's axis, on the centre's time profile.
    /// Other lanes, and every lane after the rest, keep `q`, `w`; `turning` is 1 where it applied.
    fn held_turn(
        &self,
        t: &[f64; W],
        rest_time: f64,
        mut q: Quat<L<W>>,
        mut w: V3<L<W>>,
    ) -> (Quat<L<W>>, V3<L<W>>, L<W>) {
        let mut turning = L::<W>::splat(0.0);
        for l in 0..W {
            let Some(target) = self.disc_turn[l].filter(|_| t[l] <= rest_time) else {
                continue;
            };
            let (shape, rate) = hold_profile(t[l], rest_time);
            let sin_half = (target[0] as f64)
                .hypot(target[1] as f64)
                .hypot(target[2] as f64);
            let angle = 2.0 * sin_half.atan2(target[3] as f64);
            let axis = |c: usize| {
                if sin_half > 0.0 {
                    target[c] as f64 / sin_half
                } else {
                    0.0
                }
            };
            let (s, c) = (0.5 * angle * shape).sin_cos();
            set3(
                &mut q.v,
                l,
                [
                    (axis(0) * s) as f32,
                    (axis(1) * s) as f32,
                    (axis(2) * s) as f32,
                ],
            );
            q.w.0[l] = c as f32;
            let spin = angle * rate;
            set3(
                &mut w,
                l,
                [
                    (axis(0) * spin) as f32,
                    (axis(1) * spin) as f32,
                    (axis(2) * spin) as f32,
                ],
            );
            turning.0[l] = 1.0;
        }
        (q, w, turning)
    }

    /// Advances every active lane by `substeps` substeps of its own clock.
    #[inline(always)]
    pub(crate) fn advance(
        &mut self,
        model: &Model,
        k: &StepConstants,
        substeps: u64,
        parallel: bool,
    ) {
        for _ in 0..substeps {
            // A block whose environments are all frozen or retired would only copy its state over.
            if (0..W).all(|l| !self.real[l] || self.active.0[l] < 0.5) {
                return;
            }
            match k.solver {
                Solver::SemiImplicitEuler => self.substep(model, k, parallel),
                Solver::BlockDescent => self.substep_descent(model, k),
            }
            let mut due = [false; W];
            for l in 0..W {
                if self.active.0[l] > 0.5 {
                    self.clock[l] += 1;
                    due[l] = self.clock[l].is_multiple_of(k.check_every);
                }
            }
            if due.iter().any(|&d| d) {
                self.check_health(model, k, &due);
            }
        }
    }

    #[inline(always)]
    fn substep(&mut self, model: &Model, k: &StepConstants, parallel: bool) {
        let zero = L::<W>::splat(0.0);
        let half = L::<W>::splat(0.5);
        let dt = L::<W>::splat(k.dt);
        let active = self.active;
        let keep = |new: V3<L<W>>, old: V3<L<W>>| V3::select_lt(half, active, new, old);
        let cup_start = model.cup_start();
        let n = model.num_particles();
        let p = self.params;

        // 1. Drive the cups (before forces, like the reference's `actuate_suction_cup`).
        let t = self.lane_times(k, 0.0);
        let (tp, tq, tv) = self.tool_lanes(&t, k.rest_time);
        match k.drive {
            DriveMode::Servo => {
                let (kp, kff) = (L::splat(k.kp), L::splat(k.kff));
                for (c, off) in self.cup_offsets.iter().enumerate() {
                    let i = cup_start + c;
                    let target = tq.rotate(*off) + tp;
                    let vel = (target - self.x[i]) * kp + tv * kff;
                    self.v[i] = keep(vel, self.v[i]);
                }
            }
            DriveMode::Kinematic => {
                let (np, nq, _) = self.tool_lanes(&self.lane_times(k, k.dt64), k.rest_time);
                for (c, off) in self.cup_offsets.iter().enumerate() {
                    let i = cup_start + c;
                    let target = tq.rotate(*off) + tp;
                    let next = nq.rotate(*off) + np;
                    self.x[i] = keep(target, self.x[i]);
                    self.v[i] = keep((next - target) / dt, self.v[i]);
                }
            }
        }

        // 2-6. Forces, in two independent halves summed per particle in a fixed order; a
        // single-environment batch computes the halves on two threads (same arithmetic).
        let disc = self.disc;
        let refresh = self
            .clock
            .map(|c| c.is_multiple_of(k.contact_refresh) as u8 as f32);
        let refresh = refresh.iter().any(|&r| r > 0.0).then_some(Lanes(refresh));
        let (x, v) = (&self.x[..], &self.v[..]);
        let (springs, f, f2) = (&self.springs[..], &mut self.f[..], &mut self.f2[..]);
        let spring_force = &mut self.spring_force[..];
        let (cp, cn) = (&mut self.contact_point[..], &mut self.contact_normal[..]);
        // One environment: the two halves on two threads, each compiled for AVX2 (closures run
        // by rayon leave `advance_avx2`'s code). Otherwise direct calls, inlined into it.
        let (disc_f, disc_t) = if parallel {
            let membrane = move || membrane_forces_simd(model, x, v, springs, spring_force, &p, f);
            let others = move || {
                contact_and_bending_forces_simd(model, k, refresh, x, v, &disc, &p, cp, cn, f2)
            };
            rayon::join(membrane, others).1
        } else {
            membrane_forces(model, x, v, springs, spring_force, &p, f);
            contact_and_bending_forces(model, k, refresh, x, v, &disc, &p, cp, cn, f2)
        };

        // 7. Integrate the disc (Warp `integrate_bodies`).
        let gravity = V3::new(zero, p.gravity, zero);
        let inv_mass = L::splat(1.0) / p.disc_mass;
        let v1 = disc.v + (disc_f * inv_mass + gravity) * dt;
        let com1 = disc.com + v1 * dt;
        let inertia = p.disc_inertia;
        let wb = disc.q.rotate_inv(disc.w);
        let iw = V3::new(inertia.x * wb.x, inertia.y * wb.y, inertia.z * wb.z);
        let tb = disc.q.rotate_inv(disc_t) - wb.cross(iw);
        let dw = V3::new(tb.x / inertia.x, tb.y / inertia.y, tb.z / inertia.z);
        let w1 = disc.q.rotate(wb + dw * dt);
        let spin = Quat { v: w1, w: zero }.compose(disc.q);
        let hdt = half * dt;
        let q1 = Quat {
            v: disc.q.v + spin.v * hdt,
            w: disc.q.w + spin.w * hdt,
        }
        .normalize();
        let w1 = w1 * (L::splat(1.0) - L::splat(k.angular_damping) * dt);
        let times = self.lane_times(k, k.dt64);
        let (com1, v1) = self.held_disc(&times, k.rest_time, com1, v1);
        let (q1, w1, _) = self.held_turn(&times, k.rest_time, q1, w1);
        self.disc = LaneDisc {
            com: keep(com1, disc.com),
            q: Quat {
                v: keep(q1.v, disc.q.v),
                w: L::select_lt(half, active, q1.w, disc.q.w),
            },
            v: keep(v1, disc.v),
            w: keep(w1, disc.w),
        };

        // 8. Integrate particles (Warp `integrate_particles`), one loop per kind of particle:
        // with the branch inside one loop, LLVM if-converted it into 128-bit pieces and
        // per-lane selects (30 % slower).
        let max_speed = L::<W>::splat(k.max_particle_speed);
        let package = 0..cup_start;
        self.integrate_free(package, p.inv_mass_package, gravity, dt, max_speed, active);
        if k.drive == DriveMode::Kinematic {
            // The cups move at the velocity set in step 1.
            for i in cup_start..n {
                self.x[i] = keep(self.x[i] + self.v[i] * dt, self.x[i]);
            }
        } else {
            self.integrate_free(cup_start..n, p.inv_mass_cup, gravity, dt, max_speed, active);
        }

        // 9. Seal loads and failures (take effect from the next substep).
        self.update_seals(model, k, tq, &t);
    }

    /// Advances particles `range` of the active lanes under their forces (inverse mass
    /// `inv_m`), the speed clamped to `max_speed`.
    #[inline(always)]
    fn integrate_free(
        &mut self,
        range: std::ops::Range<usize>,
        inv_m: L<W>,
        gravity: V3<L<W>>,
        dt: L<W>,
        max_speed: L<W>,
        active: L<W>,
    ) {
        let half = L::<W>::splat(0.5);
        for i in range {
            let v1 = self.v[i] + ((self.f[i] + self.f2[i]) * inv_m + gravity) * dt;
            let speed = v1.length();
            let v1 = V3::select_lt(max_speed, speed, v1 * (max_speed / speed), v1);
            self.v[i] = V3::select_lt(half, active, v1, self.v[i]);
            self.x[i] = V3::select_lt(half, active, self.x[i] + v1 * dt, self.x[i]);
            // Keeps LLVM from vectorising this loop across particles (gathering one lane of
            // eight particles per vector: 15-25 % slower than one particle's W lanes at a time).
            std::sync::atomic::compiler_fence(std::sync::atomic::Ordering::SeqCst);
        }
    }
}

/// Runs [`Block::advance`] compiled for AVX2 when the CPU has it (same IEEE results, wider SIMD).
pub(crate) fn advance_block<const W: usize>(
    block: &mut Block<W>,
    model: &Model,
    k: &StepConstants,
    substeps: u64,
    parallel: bool,
) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, checked just above.
            unsafe { advance_avx2(block, model, k, substeps, parallel) };
            return;
        }
    }
    block.advance(model, k, substeps, parallel);
}

/// [`membrane_forces`] compiled for AVX2 when the CPU has it.
fn membrane_forces_simd<const W: usize>(
    model: &Model,
    x: &[V3<L<W>>],
    v: &[V3<L<W>>],
    springs: &[LaneSpring<W>],
    spring_force: &mut [V3<L<W>>],
    p: &LaneParams<W>,
    f: &mut [V3<L<W>>],
) {
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn avx2<const W: usize>(
        model: &Model,
        x: &[V3<L<W>>],
        v: &[V3<L<W>>],
        springs: &[LaneSpring<W>],
        spring_force: &mut [V3<L<W>>],
        p: &LaneParams<W>,
        f: &mut [V3<L<W>>],
    ) {
        membrane_forces(model, x, v, springs, spring_force, p, f)
    }
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, checked just above.
            return unsafe { avx2(model, x, v, springs, spring_force, p, f) };
        }
    }
    membrane_forces(model, x, v, springs, spring_force, p, f)
}

/// [`contact_and_bending_forces`] compiled for AVX2 when the CPU has it.
#[allow(clippy::too_many_arguments)]
fn contact_and_bending_forces_simd<const W: usize>(
    model: &Model,
    k: &StepConstants,
    refresh: Option<L<W>>,
    x: &[V3<L<W>>],
    v: &[V3<L<W>>],
    disc: &LaneDisc<W>,
    p: &LaneParams<W>,
    contact_point: &mut [V3<L<W>>],
    contact_normal: &mut [V3<L<W>>],
    f: &mut [V3<L<W>>],
) -> (V3<L<W>>, V3<L<W>>) {
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[allow(clippy::too_many_arguments)]
    unsafe fn avx2<const W: usize>(
        model: &Model,
        k: &StepConstants,
        refresh: Option<L<W>>,
        x: &[V3<L<W>>],
        v: &[V3<L<W>>],
        disc: &LaneDisc<W>,
        p: &LaneParams<W>,
        cp: &mut [V3<L<W>>],
        cn: &mut [V3<L<W>>],
        f: &mut [V3<L<W>>],
    ) -> (V3<L<W>>, V3<L<W>>) {
        contact_and_bending_forces(model, k, refresh, x, v, disc, p, cp, cn, f)
    }
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, checked just above.
            return unsafe {
                avx2(
                    model,
                    k,
                    refresh,
                    x,
                    v,
                    disc,
                    p,
                    contact_point,
                    contact_normal,
                    f,
                )
            };
        }
    }
    contact_and_bending_forces(
        model,
        k,
        refresh,
        x,
        v,
        disc,
        p,
        contact_point,
        contact_normal,
        f,
    )
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn advance_avx2<const W: usize>(
    block: &mut Block<W>,
    model: &Model,
    k: &StepConstants,
    substeps: u64,
    parallel: bool,
) {
    block.advance(model, k, substeps, parallel);
}

/// Progress along a rest-period hold at time `t` (s) and its rate (1/s): a smoothstep over the
/// first half of the rest (zero velocity at both ends), then still at 1.
fn hold_profile(t: f64, rest_time: f64) -> (f64, f64) {
    let travel = 0.5 * rest_time;
    let u = (t / travel).min(1.0);
    let rate = if u < 1.0 {
        6.0 * u * (1.0 - u) / travel
    } else {
        0.0
    };
    (u * u * (3.0 - 2.0 * u), rate)
}
