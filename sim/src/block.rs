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

use std::sync::Arc;

use crate::config::DriveMode;
use crate::forces::{self, ContactMaterial};
use crate::math::{Lanes, Quat, Real, V3};
use crate::model::{BendingEdge, Model, Triangle};
use crate::state::{EnvSpec, HealthEvent, HealthReason};
use crate::trajectory::ToolTrajectory;
use crate::Params;

type L<const W: usize> = Lanes<W>;

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

/// Attachment spring of one cup particle: per-lane package vertex and rest length.
#[derive(Clone, Copy)]
pub(crate) struct LaneSpring<const W: usize> {
    target: [u32; W],
    rest: L<W>,
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
    springs: Vec<LaneSpring<W>>,
    pub(crate) disc: LaneDisc<W>,
    disc_x0: V3<L<W>>,
    /// Per lane: where the disc is held during the rest (`None`: free), see `Placement::disc_hold`.
    disc_hold: [Option<[f32; 3]>; W],
    /// Per particle: frozen contact point on the disc (body frame) and normal (world).
    contact_point: Vec<V3<L<W>>>,
    contact_normal: Vec<V3<L<W>>>,
    params: LaneParams<W>,
    tools: Vec<Arc<ToolTrajectory>>,
    /// 1.0 for lanes still simulated, 0.0 for frozen ones.
    pub(crate) active: L<W>,
    pub(crate) events: Vec<HealthEvent>,
}

#[inline(always)]
fn set3<const W: usize>(v: &mut V3<L<W>>, l: usize, a: [f32; 3]) {
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
    params: &Params,
    object_mass: f32,
) {
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
    let disc = model.disc_mass(object_mass);
    p.disc_mass.0[l] = disc.mass;
    set3(&mut p.disc_inertia, l, disc.inertia);
    p.gravity.0[l] = model.config.integrator.gravity_m_s2;
}

impl<const W: usize> Block<W> {
    /// A block holding `specs[envs[l]]` in lane l.
    pub(crate) fn new(model: &Model, specs: &[EnvSpec], envs: [usize; W], real: [bool; W]) -> Self {
        let n = model.num_particles();
        let zero3 = V3::<L<W>>::zero();
        let zero = L::<W>::splat(0.0);
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
                    rest: zero
                };
                model.num_cup
            ],
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
            tools: envs.iter().map(|&e| specs[e].trajectory.clone()).collect(),
            active: L::splat(1.0),
            events: Vec::new(),
        };
        for (l, &e) in envs.iter().enumerate() {
            block.init_lane(l, model, &specs[e]);
        }
        block
    }

    /// Places environment `spec` in lane `l`: positions, springs, cup offsets, disc, parameters.
    fn init_lane(&mut self, l: usize, model: &Model, spec: &EnvSpec) {
        let pl = &spec.placement;
        let cup_start = model.cup_start();
        for (i, off) in model.rest_offsets.iter().enumerate() {
            let anchor = if i < cup_start {
                pl.package_origin
            } else {
                pl.cup_point
            };
            let p = [anchor[0] + off[0], anchor[1] + off[1], anchor[2] + off[2]];
            set3(&mut self.x[i], l, p);
            set3(&mut self.x0[i], l, p);
            set3(&mut self.v[i], l, [0.0; 3]);
        }
        // Springs: each cup particle to its nearest upper-sheet particle (first minimum wins).
        let upper = model.layer_size..model.num_package;
        let mut lengths = Vec::with_capacity(model.num_cup);
        for k in 0..model.num_cup {
            let c = get3(&self.x[cup_start + k], l);
            let (mut best, mut best_d2) = (upper.start, f32::INFINITY);
            for j in upper.clone() {
                let p = get3(&self.x[j], l);
                let d2 = (c[0] - p[0]).powi(2) + (c[1] - p[1]).powi(2) + (c[2] - p[2]).powi(2);
                if d2 < best_d2 {
                    best = j;
                    best_d2 = d2;
                }
            }
            self.springs[k].target[l] = best as u32;
            lengths.push(best_d2.sqrt());
        }
        let common = lengths.iter().copied().fold(f32::INFINITY, f32::min);
        for (k, len) in lengths.iter().enumerate() {
            self.springs[k].rest.0[l] = if model.config.cups.common_rest_length {
                common
            } else {
                *len
            };
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
        set3(&mut self.disc.com, l, pl.disc_position);
        set3(&mut self.disc_x0, l, pl.disc_position);
        self.disc_hold[l] = pl.disc_hold;
        set3(&mut self.disc.q.v, l, [0.0; 3]);
        self.disc.q.w.0[l] = 1.0;
        set3(&mut self.disc.v, l, [0.0; 3]);
        set3(&mut self.disc.w, l, [0.0; 3]);
        lane_params_set(
            &mut self.params,
            l,
            model,
            &spec.params,
            spec.object_mass_kg,
        );
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
        ];
        particle_arrays
            .iter()
            .map(|a| a.capacity() * per_particle)
            .sum::<usize>()
            + self.cup_offsets.capacity() * per_particle
            + self.springs.capacity() * std::mem::size_of::<LaneSpring<W>>()
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

    /// Replaces the material parameters of every lane holding `env`.
    pub(crate) fn set_params(
        &mut self,
        env: usize,
        model: &Model,
        params: &Params,
        object_mass: f32,
    ) {
        for l in 0..W {
            if self.envs[l] == env {
                lane_params_set(&mut self.params, l, model, params, object_mass);
            }
        }
    }

    /// Replaces the tool trajectory of every lane holding `env`.
    pub(crate) fn set_trajectory(&mut self, env: usize, trajectory: &Arc<ToolTrajectory>) {
        for l in 0..W {
            if self.envs[l] == env {
                self.tools[l] = trajectory.clone();
            }
        }
    }

    /// Tool position, orientation and velocity of every lane at rollout time `t`.
    fn tool_lanes(&self, t: f64, rest_time: f64) -> (V3<L<W>>, Quat<L<W>>, V3<L<W>>) {
        let mut p = V3::<L<W>>::zero();
        let mut q = Quat {
            v: V3::<L<W>>::zero(),
            w: L::splat(1.0),
        };
        let mut vel = V3::<L<W>>::zero();
        for l in 0..W {
            let pose = self.tools[l].pose_at(t - rest_time);
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
        t: f64,
        rest_time: f64,
        mut com: V3<L<W>>,
        mut v: V3<L<W>>,
    ) -> (V3<L<W>>, V3<L<W>>) {
        if t > rest_time {
            return (com, v);
        }
        let travel = 0.5 * rest_time;
        let u = (t / travel).min(1.0);
        // Smoothstep: zero velocity at both ends of the path.
        let shape = u * u * (3.0 - 2.0 * u);
        let rate = if u < 1.0 {
            6.0 * u * (1.0 - u) / travel
        } else {
            0.0
        };
        for l in 0..W {
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

    /// Advances `substeps` substeps starting at global substep `start`.
    #[inline(always)]
    pub(crate) fn advance(
        &mut self,
        model: &Model,
        k: &StepConstants,
        start: u64,
        substeps: u64,
        parallel: bool,
    ) {
        // A block whose environments are all frozen or retired would only copy its state over.
        if (0..W).all(|l| !self.real[l] || self.active.0[l] < 0.5) {
            return;
        }
        for s in start..start + substeps {
            self.substep(model, k, s, parallel);
            if (s + 1).is_multiple_of(k.check_every) {
                self.check_health(k, (s + 1) as f64 * k.dt64);
            }
        }
    }

    #[inline(always)]
    fn substep(&mut self, model: &Model, k: &StepConstants, s: u64, parallel: bool) {
        let zero = L::<W>::splat(0.0);
        let half = L::<W>::splat(0.5);
        let dt = L::<W>::splat(k.dt);
        let active = self.active;
        let keep = |new: V3<L<W>>, old: V3<L<W>>| V3::select_lt(half, active, new, old);
        let cup_start = model.cup_start();
        let n = model.num_particles();
        let p = self.params;

        // 1. Drive the cups (before forces, like the reference's `actuate_suction_cup`).
        let t = s as f64 * k.dt64;
        let (tp, tq, tv) = self.tool_lanes(t, k.rest_time);
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
                let (np, nq, _) = self.tool_lanes(t + k.dt64, k.rest_time);
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
        let (x, v) = (&self.x[..], &self.v[..]);
        let (springs, f, f2) = (&self.springs[..], &mut self.f[..], &mut self.f2[..]);
        let (cp, cn) = (&mut self.contact_point[..], &mut self.contact_normal[..]);
        let mut membrane = move || membrane_forces(model, x, v, springs, &p, f);
        let mut others =
            move || contact_and_bending_forces(model, k, s, x, v, &disc, &p, cp, cn, f2);
        let ((), (disc_f, disc_t)) = if parallel {
            rayon::join(membrane, others)
        } else {
            (membrane(), others())
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
        let (com1, v1) = self.held_disc(t + k.dt64, k.rest_time, com1, v1);
        self.disc = LaneDisc {
            com: keep(com1, disc.com),
            q: Quat {
                v: keep(q1.v, disc.q.v),
                w: L::select_lt(half, active, q1.w, disc.q.w),
            },
            v: keep(v1, disc.v),
            w: keep(w1, disc.w),
        };

        // 8. Integrate particles (Warp `integrate_particles`).
        let max_speed = L::<W>::splat(k.max_particle_speed);
        let kinematic = k.drive == DriveMode::Kinematic;
        for i in 0..n {
            let is_cup = i >= cup_start;
            let vi = self.v[i];
            let v1 = if is_cup && kinematic {
                vi
            } else {
                let inv_m = if is_cup {
                    p.inv_mass_cup
                } else {
                    p.inv_mass_package
                };
                let v1 = vi + ((self.f[i] + self.f2[i]) * inv_m + gravity) * dt;
                let speed = v1.length();
                V3::select_lt(max_speed, speed, v1 * (max_speed / speed), v1)
            };
            let x1 = self.x[i] + v1 * dt;
            self.v[i] = keep(v1, vi);
            self.x[i] = keep(x1, self.x[i]);
        }
    }

    /// Flags and freezes lanes with non-finite or exploding state.
    fn check_health(&mut self, k: &StepConstants, time: f64) {
        let max_v2 = k.max_speed * k.max_speed;
        let max_d2 = k.max_displacement * k.max_displacement;
        let mut reason: [Option<HealthReason>; W] = [None; W];
        let mut inspect = |x: &V3<L<W>>, v: &V3<L<W>>, x0: &V3<L<W>>| {
            for (l, r) in reason.iter_mut().enumerate() {
                let (p, u, p0) = (get3(x, l), get3(v, l), get3(x0, l));
                let found = if p.iter().chain(&u).any(|c| !c.is_finite()) {
                    Some(HealthReason::NonFinite)
                } else if u.iter().map(|c| c * c).sum::<f32>() > max_v2 {
                    Some(HealthReason::TooFast)
                } else if (0..3).map(|c| (p[c] - p0[c]).powi(2)).sum::<f32>() > max_d2 {
                    Some(HealthReason::TooFar)
                } else {
                    None
                };
                if r.is_none() {
                    *r = found;
                }
            }
        };
        for i in 0..self.x.len() {
            inspect(&self.x[i], &self.v[i], &self.x0[i]);
        }
        inspect(&self.disc.com, &self.disc.v, &self.disc_x0);
        for l in 0..W {
            let quat_ok = self.disc.q.w.0[l].is_finite()
                && get3(&self.disc.q.v, l).iter().all(|c| c.is_finite());
            let r = reason[l].or(if quat_ok {
                None
            } else {
                Some(HealthReason::NonFinite)
            });
            if let (Some(reason), true) = (r, self.active.0[l] > 0.5) {
                self.active.0[l] = 0.0;
                if self.real[l] {
                    self.events.push(HealthEvent {
                        env: self.envs[l],
                        reason,
                        time,
                    });
                }
            }
        }
    }
}

/// Runs [`Block::advance`] compiled for AVX2 when the CPU has it (same IEEE results, wider SIMD).
pub(crate) fn advance_block<const W: usize>(
    block: &mut Block<W>,
    model: &Model,
    k: &StepConstants,
    start: u64,
    substeps: u64,
    parallel: bool,
) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, checked just above.
            unsafe { advance_avx2(block, model, k, start, substeps, parallel) };
            return;
        }
    }
    block.advance(model, k, start, substeps, parallel);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn advance_avx2<const W: usize>(
    block: &mut Block<W>,
    model: &Model,
    k: &StepConstants,
    start: u64,
    substeps: u64,
    parallel: bool,
) {
    block.advance(model, k, start, substeps, parallel);
}

/// Attachment springs, membrane triangles and part of the bending, accumulated into `f`
/// (cleared first).
#[inline(always)]
fn membrane_forces<const W: usize>(
    model: &Model,
    x: &[V3<L<W>>],
    v: &[V3<L<W>>],
    springs: &[LaneSpring<W>],
    p: &LaneParams<W>,
    f: &mut [V3<L<W>>],
) {
    let cup_start = model.cup_start();
    for fi in f.iter_mut() {
        *fi = V3::zero();
    }

    // 2. Attachment springs (per-lane package vertex: gather/scatter by lane).
    for (c, spring) in springs.iter().enumerate() {
        let i = cup_start + c;
        let mut xj = V3::<L<W>>::zero();
        let mut vj = V3::<L<W>>::zero();
        for l in 0..W {
            let j = spring.target[l] as usize;
            set3(&mut xj, l, get3(&x[j], l));
            set3(&mut vj, l, get3(&v[j], l));
        }
        let fi = forces::spring(x[i], xj, v[i], vj, spring.rest, p.spring[0], p.spring[1]);
        f[i] += fi;
        for l in 0..W {
            let j = spring.target[l] as usize;
            let g = get3(&fi, l);
            f[j].x.0[l] -= g[0];
            f[j].y.0[l] -= g[1];
            f[j].z.0[l] -= g[2];
        }
    }

    // 3. Membrane triangles.
    for (tris, mat) in [
        (&model.package_triangles[..], p.tri),
        (&model.cup_triangles[..], p.cup_tri),
    ] {
        triangle_forces(tris, mat, x, v, f);
    }

    // 4. Bending, first part of the package edges.
    let split = bending_split(model);
    bending_forces(&model.package_edges[..split], p.edge, x, v, f);
}
/// Bending of `edges` with material `mat` (ke, kd), accumulated into `f`.
#[inline(always)]
fn bending_forces<const W: usize>(
    edges: &[BendingEdge],
    mat: [L<W>; 2],
    x: &[V3<L<W>>],
    v: &[V3<L<W>>],
    f: &mut [V3<L<W>>],
) {
    if W == 1 {
        return bending_across_elements(edges, [mat[0].0[0], mat[1].0[0]], x, v, f);
    }
    for e in edges {
        let id = e.idx.map(|i| i as usize);
        let rest = L::splat(e.rest_angle);
        let fs = forces::bending(id.map(|i| x[i]), id.map(|i| v[i]), rest, mat[0], mat[1]);
        for (q, fq) in id.iter().zip(fs) {
            f[*q] += fq;
        }
    }
}

/// Membrane triangles with material `mat` (k_mu, k_lambda, k_damp), accumulated into `f`.
#[inline(always)]
fn triangle_forces<const W: usize>(
    tris: &[Triangle],
    mat: [L<W>; 3],
    x: &[V3<L<W>>],
    v: &[V3<L<W>>],
    f: &mut [V3<L<W>>],
) {
    if W == 1 {
        return triangles_across_elements(tris, mat.map(|m| m.0[0]), x, v, f);
    }
    for tri in tris {
        let [a, b, c] = tri.idx.map(|i| i as usize);
        let dm = tri.rest.dm.map(|row| row.map(L::splat));
        let inv_area = L::splat(tri.rest.inv_rest_area());
        let fs = forces::triangle(
            [x[a], x[b], x[c]],
            [v[a], v[b], v[c]],
            dm,
            inv_area,
            mat[0],
            mat[1],
            mat[2],
        );
        f[a] += fs[0];
        f[b] += fs[1];
        f[c] += fs[2];
    }
}

/// Elements processed together by the single-environment path.
const ELEMENT_LANES: usize = 8;
type E8 = Lanes<ELEMENT_LANES>;

/// Single-environment blocks (lane 0 only): triangles [`ELEMENT_LANES`] at a time, SIMD across
/// elements. Each element's arithmetic is the same as in the per-environment path and the forces
/// are added in the same element order, so results are bit-identical.
#[inline(always)]
fn triangles_across_elements<const W: usize>(
    tris: &[Triangle],
    mat: [f32; 3],
    x: &[V3<L<W>>],
    v: &[V3<L<W>>],
    f: &mut [V3<L<W>>],
) {
    let mat = mat.map(E8::splat);
    for chunk in tris.chunks(ELEMENT_LANES) {
        let mut xs = [V3::<E8>::zero(); 3];
        let mut vs = [V3::<E8>::zero(); 3];
        let mut dm = [[E8::splat(0.0); 2]; 2];
        let mut inv_area = E8::splat(1.0);
        for e in 0..ELEMENT_LANES {
            // Short chunks repeat their last element; those lanes are not added below.
            let tri = &chunk[e.min(chunk.len() - 1)];
            for (corner, &i) in tri.idx.iter().enumerate() {
                set3(&mut xs[corner], e, get3(&x[i as usize], 0));
                set3(&mut vs[corner], e, get3(&v[i as usize], 0));
            }
            for (r, row) in tri.rest.dm.iter().enumerate() {
                for (c, value) in row.iter().enumerate() {
                    dm[r][c].0[e] = *value;
                }
            }
            inv_area.0[e] = tri.rest.inv_rest_area();
        }
        let fs = forces::triangle(xs, vs, dm, inv_area, mat[0], mat[1], mat[2]);
        for (e, tri) in chunk.iter().enumerate() {
            for (corner, &i) in tri.idx.iter().enumerate() {
                add_lane(&mut f[i as usize], get3(&fs[corner], e));
            }
        }
    }
}

/// Single-environment blocks: bending elements [`ELEMENT_LANES`] at a time (see
/// [`triangles_across_elements`]).
#[inline(always)]
fn bending_across_elements<const W: usize>(
    edges: &[BendingEdge],
    mat: [f32; 2],
    x: &[V3<L<W>>],
    v: &[V3<L<W>>],
    f: &mut [V3<L<W>>],
) {
    let mat = mat.map(E8::splat);
    for chunk in edges.chunks(ELEMENT_LANES) {
        let mut xs = [V3::<E8>::zero(); 4];
        let mut vs = [V3::<E8>::zero(); 4];
        let mut rest = E8::splat(0.0);
        for e in 0..ELEMENT_LANES {
            let edge = &chunk[e.min(chunk.len() - 1)];
            for (corner, &i) in edge.idx.iter().enumerate() {
                set3(&mut xs[corner], e, get3(&x[i as usize], 0));
                set3(&mut vs[corner], e, get3(&v[i as usize], 0));
            }
            rest.0[e] = edge.rest_angle;
        }
        let fs = forces::bending(xs, vs, rest, mat[0], mat[1]);
        for (e, edge) in chunk.iter().enumerate() {
            for (corner, &i) in edge.idx.iter().enumerate() {
                add_lane(&mut f[i as usize], get3(&fs[corner], e));
            }
        }
    }
}

/// `f += g` on lane 0, component by component (the same additions as `V3 += V3`).
#[inline(always)]
fn add_lane<const W: usize>(f: &mut V3<L<W>>, g: [f32; 3]) {
    f.x.0[0] += g[0];
    f.y.0[0] += g[1];
    f.z.0[0] += g[2];
}

/// Package bending edges before this index go with the membrane half of the force evaluation,
/// the rest with the contact half (balances the two threads of a single-environment batch).
fn bending_split(model: &Model) -> usize {
    model.package_edges.len() * 3 / 8
}

/// The rest of the bending, ground and disc contacts, accumulated into `f` (cleared first). Returns the force
/// and torque on the disc.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn contact_and_bending_forces<const W: usize>(
    model: &Model,
    k: &StepConstants,
    s: u64,
    x: &[V3<L<W>>],
    v: &[V3<L<W>>],
    disc: &LaneDisc<W>,
    p: &LaneParams<W>,
    contact_point: &mut [V3<L<W>>],
    contact_normal: &mut [V3<L<W>>],
    f: &mut [V3<L<W>>],
) -> (V3<L<W>>, V3<L<W>>) {
    let zero = L::<W>::splat(0.0);
    let n = model.num_particles();
    let cup_start = model.cup_start();
    let disc = *disc;
    for fi in f.iter_mut() {
        *fi = V3::zero();
    }
    // 4. Bending (the remaining package edges, then the cups).
    let split = bending_split(model);
    bending_forces(&model.package_edges[split..], p.edge, x, v, f);
    let cup_edge = [
        L::splat(model.config.cups.edge_ke),
        L::splat(model.config.cups.edge_kd),
    ];
    bending_forces(&model.cup_edges, cup_edge, x, v, f);

    // 5. Particle-ground contact.
    let radius = model.particle_radius;
    let rad = L::<W>::splat(radius);
    let ground = ContactMaterial {
        ke: L::splat(k.ground.ke),
        kd: L::splat(k.ground.kd),
        kf: L::splat(k.ground.kf),
        mu: L::splat(k.ground.mu),
    };
    for i in 0..n {
        if x[i].y.0.iter().all(|&y| y >= radius) {
            continue;
        }
        let fg = forces::particle_ground(x[i], v[i], rad, ground);
        f[i] = V3::select_lt(x[i].y - rad, zero, f[i] + fg, f[i]);
    }

    // 6. Disc: ground contact at its rim points, then particle contacts.
    let mut disc_f = V3::<L<W>>::zero();
    let mut disc_t = V3::<L<W>>::zero();
    let shape_thickness = L::splat(model.config.disc.shape_thickness_m);
    for rp in &model.disc.rim_points {
        let r = disc.q.rotate(V3::splat(*rp));
        let point = disc.com + r;
        if point
            .y
            .0
            .iter()
            .all(|&y| y >= model.config.disc.shape_thickness_m)
        {
            continue;
        }
        let vel = disc.v + disc.w.cross(r);
        let fr = forces::rigid_ground(point, vel, shape_thickness, p.disc_ground);
        let touching = point.y - shape_thickness;
        disc_f = V3::select_lt(touching, zero, disc_f + fr, disc_f);
        disc_t = V3::select_lt(touching, zero, disc_t + r.cross(fr), disc_t);
    }
    let (dr, dh) = (model.disc.radius, model.disc.half_height);
    if s.is_multiple_of(k.contact_refresh) {
        // Warp's `collide()`: closest point (body frame) and normal (world), frozen until
        // the next refresh.
        let (disc_r, disc_h) = (L::splat(dr), L::splat(dh));
        for i in 0..n {
            let local = disc.q.rotate_inv(x[i] - disc.com);
            let (d, n_local) = forces::cylinder_distance(local, disc_r, disc_h);
            contact_point[i] = local - n_local * d;
            contact_normal[i] = disc.q.rotate(n_local);
        }
    }
    // Only particles that can touch the disc (bounding sphere) are evaluated; beyond it a
    // frozen contact plane could only produce a spurious long-range force.
    let reach = (dr * dr + dh * dh).sqrt() + radius;
    let reach2 = reach * reach;
    let colliding = if model.config.cups.collide_with_disc {
        n
    } else {
        cup_start
    };
    for i in 0..colliding {
        let rel = x[i] - disc.com;
        let dist2 = rel.dot(rel);
        if dist2.0.iter().all(|&d| d > reach2) {
            continue;
        }
        let normal = contact_normal[i];
        let bx = disc.com + disc.q.rotate(contact_point[i]);
        let (fp, arm) = forces::particle_disc(
            x[i],
            v[i],
            rad,
            normal,
            bx,
            disc.com,
            disc.v,
            disc.w,
            p.disc_contact,
        );
        let gap = normal.dot(x[i] - bx) - rad;
        let near = L::select_lt(L::splat(reach2), dist2, zero, L::splat(1.0));
        let gap = L::select_lt(zero, near, gap, L::splat(1.0));
        f[i] = V3::select_lt(zero, gap, f[i], f[i] + fp);
        disc_f = V3::select_lt(zero, gap, disc_f, disc_f - fp);
        disc_t = V3::select_lt(zero, gap, disc_t, disc_t - arm.cross(fp));
    }
    (disc_f, disc_t)
}
