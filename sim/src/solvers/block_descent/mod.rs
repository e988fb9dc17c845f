//! The block-descent solver ([`crate::config::Solver::BlockDescent`]): one implicit Euler step
//! per substep, solved by Vertex Block Descent (Chen et al., SIGGRAPH 2024).
//!
//! Per substep: the cups move kinematically to their pose at the end of the step; every package
//! vertex starts from its inertial prediction `y = x + h·v + h²·g`; then `iterations` sweeps, each
//! visiting the package vertices in index order (Gauss-Seidel: a vertex sees its neighbours'
//! latest positions) and taking one Newton step on its 3x3 block
//! `(m/h²·I + ΣK)·Δx = m/h²·(y − x) + Σf` (force laws and stiffness blocks in [`vertex`], the
//! film's elements around a vertex in [`elements`]), then one Newton step of the disc's 6x6 block
//! ([`disc`]: translation and rotation, inertia plus every contact on it, with the particles as
//! they are now): the disc and the film are solved together within the step, not one step apart.
//! Optionally the sweeps are over-relaxed (Chebyshev). Velocities are the step's displacement
//! over `h`. The environments of a block are SIMD lanes, so the sweeps need no graph colouring:
//! within one environment the order is plainly sequential.
//!
//! Contacts with the disc use Warp's frozen contact data: the closest point on the disc (body
//! frame) and the normal (world) are found once per substep from the positions at its start.

mod disc;
mod elements;
#[cfg(test)]
mod tests;
mod vertex;

use crate::forces::{self, ContactMaterial};
use crate::math::{get3, lane_vec, set3, LaneVec, Lanes, Quat, Real, Sym3, V3};
use crate::model::Model;
use crate::state::{LaneParams, State};

use super::{keep, Integrator, Substep};
use disc::{rotation_between, turned, world_inertia_times, Disc6};
use vertex::{contact_vertex, spring_vertex, Membrane};

type L<const W: usize> = Lanes<W>;

/// The block-descent solver of a block: its settings and its per-substep buffers.
pub(crate) struct BlockDescent<const W: usize> {
    /// Sweeps per substep.
    iterations: u32,
    /// Chebyshev acceleration's spectral radius estimate (0: off).
    chebyshev_rho: f32,
    /// Package positions at the start of the substep and their inertial predictions.
    x_start: LaneVec<V3<L<W>>>,
    inertia_target: LaneVec<V3<L<W>>>,
    /// The step velocity `(x − x_start) / h` of each package vertex's current iterate, kept with
    /// `x` (every element around a vertex reads it).
    x_rate: LaneVec<V3<L<W>>>,
    /// Attachment springs per package vertex (`spring_slot_starts[i]..spring_slot_starts[i + 1]`
    /// of `spring_slots`), the counts per vertex and lane that index them, and the particles near
    /// the disc this substep.
    spring_slot_starts: Vec<u32>,
    spring_slots: LaneVec<SpringSlot<W>>,
    spring_counts: Vec<[u32; W]>,
    disc_candidates: Vec<u32>,
    /// Whether each package particle is among `disc_candidates`.
    near_disc: Vec<bool>,
    /// With Chebyshev acceleration only: package positions before the current sweep and before
    /// the previous one.
    x_before: LaneVec<V3<L<W>>>,
    x_older: LaneVec<V3<L<W>>>,
    /// Bending force and stiffness per package vertex at a sweep's start.
    bend_force: LaneVec<V3<L<W>>>,
    bend_stiffness: LaneVec<Sym3<L<W>>>,
}

/// One attachment spring slot of a package vertex, per lane: the cup particle it pulls towards
/// (position, velocity), its rest length and whether it is sealed (1) or not (0); lanes without
/// a spring in this slot pull with nothing.
#[derive(Clone, Copy)]
struct SpringSlot<const W: usize> {
    anchor: V3<L<W>>,
    anchor_v: V3<L<W>>,
    rest: L<W>,
    on: L<W>,
}

impl<const W: usize> SpringSlot<W> {
    /// A slot without springs.
    fn none() -> Self {
        SpringSlot {
            anchor: V3::zero(),
            anchor_v: V3::zero(),
            rest: L::splat(1.0),
            on: L::splat(0.0),
        }
    }
}

impl<const W: usize> BlockDescent<W> {
    /// Rebuilds, for each package vertex, the attachment springs pulling on it in each lane (a
    /// lane's cup particles attach to vertices of its own choosing), with what they read of the
    /// cups (which stay put during the substep's sweeps).
    fn index_springs(&mut self, state: &State<W>, num_package: usize, cup_start: usize) {
        let springs = &state.springs;
        let counts = &mut self.spring_counts;
        counts.clear();
        counts.resize(num_package, [0u32; W]);
        for spring in springs {
            for l in 0..W {
                counts[spring.target[l] as usize][l] += 1;
            }
        }
        self.spring_slot_starts.clear();
        self.spring_slot_starts.push(0);
        for c in counts.iter() {
            let most = c.iter().copied().max().unwrap_or(0);
            let last = *self.spring_slot_starts.last().unwrap_or(&0);
            self.spring_slot_starts.push(last + most);
        }
        let total = *self.spring_slot_starts.last().unwrap_or(&0) as usize;
        self.spring_slots.clear();
        self.spring_slots.resize(total, SpringSlot::none());
        // Now the slots filled so far per vertex and lane.
        counts.fill([0u32; W]);
        for (s, spring) in springs.iter().enumerate() {
            let c = cup_start + s;
            for l in 0..W {
                let j = spring.target[l] as usize;
                let slot =
                    &mut self.spring_slots[(self.spring_slot_starts[j] + counts[j][l]) as usize];
                set3(&mut slot.anchor, l, get3(&state.x[c], l));
                set3(&mut slot.anchor_v, l, get3(&state.v[c], l));
                slot.rest.0[l] = spring.rest.0[l];
                slot.on.0[l] = spring.sealed.0[l];
                counts[j][l] += 1;
            }
        }
    }

    /// Position of particle `i` at the start of the substep (package particles are saved in
    /// `x_start`; cup particles, at `x`, have already moved: their start does not matter for
    /// contact).
    #[inline(always)]
    fn x_start_or_x(&self, x: &[V3<L<W>>], i: usize, num_package: usize) -> V3<L<W>> {
        if i < num_package {
            self.x_start[i]
        } else {
            x[i]
        }
    }
}

/// What the Newton system of every package vertex in one sweep reads besides the state and the
/// solver's buffers.
pub(crate) struct VertexTerms<'a, const W: usize> {
    model: &'a Model,
    p: &'a LaneParams<W>,
    membrane: Membrane<L<W>>,
    /// `m / h²` of a package particle.
    inertial: L<W>,
    inv_h: L<W>,
    ground: ContactMaterial<L<W>>,
    /// Particle radius, and the squared reach of a disc contact.
    rad: L<W>,
    reach2: L<W>,
    /// The disc's current iterate (centre, orientation) and the velocity and spin it implies.
    disc: (V3<L<W>>, Quat<L<W>>),
    disc_velocity: (V3<L<W>>, V3<L<W>>),
}

/// A global step taken before each block-descent sweep, from the residual forces of every
/// package vertex (the `global_descent` solver's; plain block descent takes none, `()`).
pub(crate) trait GlobalStep<const W: usize> {
    /// Prepares the substep's global system once its contacts are known (`state` holds the
    /// package's inertial prediction and the cups at the end of the step).
    fn prepare(&mut self, step: &Substep<'_, W>, state: &State<W>);
    /// The buffer of residual forces per package vertex (`None`: no global step), which
    /// [`GlobalStep::solve`] turns into the global displacement.
    fn residual(&mut self) -> Option<&mut [V3<L<W>>]>;
    /// Replaces the residual forces in the buffer by the displacement of the global step.
    fn solve(&mut self);
}

impl<const W: usize> GlobalStep<W> for () {
    #[inline(always)]
    fn prepare(&mut self, _: &Substep<'_, W>, _: &State<W>) {}
    #[inline(always)]
    fn residual(&mut self) -> Option<&mut [V3<L<W>>]> {
        None
    }
    #[inline(always)]
    fn solve(&mut self) {}
}

impl<const W: usize> BlockDescent<W> {
    /// The Newton system of package vertex `i` at the current iterate: the force (the negative
    /// gradient of the step's incremental potential, inertia included) and its 3x3 stiffness.
    #[inline(always)]
    fn vertex_system(
        &self,
        terms: &VertexTerms<'_, W>,
        state: &State<W>,
        i: usize,
    ) -> (V3<L<W>>, Sym3<L<W>>) {
        let xi = state.x[i];
        let mut force = (self.inertia_target[i] - xi) * terms.inertial;
        let mut stiff = Sym3::diagonal(terms.inertial);
        self.add_membrane(
            terms.model,
            &state.x,
            i,
            terms.membrane,
            terms.inv_h,
            &mut force,
            &mut stiff,
        );
        self.add_vertex_terms(terms, state, i, &mut force, &mut stiff);
        (force, stiff)
    }

    /// The force on package vertex `i` at the current iterate without the membrane's (which
    /// [`Self::membrane_forces`] gives per element): inertia, bending, springs and contacts.
    #[inline(always)]
    fn force_without_membrane(
        &self,
        terms: &VertexTerms<'_, W>,
        state: &State<W>,
        i: usize,
    ) -> V3<L<W>> {
        let mut force = (self.inertia_target[i] - state.x[i]) * terms.inertial;
        self.add_vertex_terms(terms, state, i, &mut force, &mut Sym3::zero());
        force
    }

    /// Adds the terms of package vertex `i` that act on it alone to `force` and `stiff`: bending
    /// (from the sweep's start), the attachment springs and the contacts.
    #[inline(always)]
    fn add_vertex_terms(
        &self,
        terms: &VertexTerms<'_, W>,
        state: &State<W>,
        i: usize,
        force: &mut V3<L<W>>,
        stiff: &mut Sym3<L<W>>,
    ) {
        let VertexTerms {
            model,
            p,
            inv_h,
            ground,
            rad,
            reach2,
            disc: (com, q),
            disc_velocity: (disc_v, disc_w),
            ..
        } = *terms;
        let zero = L::<W>::splat(0.0);
        let half = L::<W>::splat(0.5);
        let up = V3::new(zero, L::splat(1.0), zero);
        let radius = model.particle_radius;
        let xi = state.x[i];
        let vi = self.x_rate[i];
        // Bending, evaluated at the start of the sweep (it is soft: lagging it costs
        // little convergence and saves three of its four evaluations).
        *force += self.bend_force[i];
        stiff.add_assign(self.bend_stiffness[i]);
        let slots = self.spring_slot_starts[i] as usize..self.spring_slot_starts[i + 1] as usize;
        for slot in &self.spring_slots[slots] {
            let SpringSlot {
                anchor,
                anchor_v,
                rest,
                on,
            } = *slot;
            // Lanes without this slot, and lip elements that let go, pull with nothing.
            let (ke, kd) = (p.spring[0] * on, p.spring[1] * on);
            let (f, kk) = spring_vertex(xi, anchor, vi, anchor_v, rest, ke, kd, inv_h);
            *force += V3::select_lt(half, on, f, V3::zero());
            stiff.add_assign(kk.keep_lt(half, on));
        }
        // Contacts only change the lanes that touch (see the module docs of `solvers`).
        if xi.y.0.iter().any(|&y| y < radius) {
            let gap = xi.y - rad;
            let (f, kk) = contact_vertex(gap, up, vi, ground, inv_h);
            *force = V3::select_lt(gap, zero, *force + f, *force);
            *stiff = Sym3::select_lt(gap, zero, stiff.plus(kk), *stiff);
        }
        if self.near_disc[i] {
            let (gap, f, kk, _) = self.disc_contact(
                state,
                p.disc_contact,
                i,
                com,
                q,
                disc_v,
                disc_w,
                rad,
                reach2,
                inv_h,
            );
            *force = V3::select_lt(gap, zero, *force + f, *force);
            *stiff = Sym3::select_lt(gap, zero, stiff.plus(kk), *stiff);
        }
    }
}

impl<const W: usize> Integrator<W> for BlockDescent<W> {
    fn new(model: &Model) -> Self {
        let c = &model.config.integrator;
        let zero3 = V3::<L<W>>::zero();
        let n = model.num_package;
        // Chebyshev's two extra copies only when it is on.
        let chebyshev = if c.chebyshev_rho > 0.0 { n } else { 0 };
        BlockDescent {
            iterations: c.iterations,
            chebyshev_rho: c.chebyshev_rho,
            x_start: lane_vec(zero3, n),
            inertia_target: lane_vec(zero3, n),
            x_rate: lane_vec(zero3, n),
            spring_slot_starts: Vec::new(),
            spring_slots: LaneVec::new(64),
            spring_counts: Vec::new(),
            disc_candidates: Vec::new(),
            near_disc: Vec::new(),
            x_before: lane_vec(zero3, chebyshev),
            x_older: lane_vec(zero3, chebyshev),
            bend_force: lane_vec(zero3, n),
            bend_stiffness: lane_vec(Sym3::zero(), n),
        }
    }

    fn bytes(&self) -> usize {
        let per_particle = std::mem::size_of::<V3<L<W>>>();
        [
            &self.x_start,
            &self.inertia_target,
            &self.x_rate,
            &self.bend_force,
            &self.x_before,
            &self.x_older,
        ]
        .iter()
        .map(|a| a.capacity() * per_particle)
        .sum::<usize>()
            + self.bend_stiffness.capacity() * std::mem::size_of::<Sym3<L<W>>>()
            + self.spring_slots.capacity() * std::mem::size_of::<SpringSlot<W>>()
            + self.spring_counts.capacity() * std::mem::size_of::<[u32; W]>()
    }

    /// One substep (see the module documentation).
    #[inline(always)]
    fn substep(&mut self, step: &Substep<'_, W>, state: &mut State<W>) {
        self.substep_with(step, state, &mut ());
    }
}

impl<const W: usize> BlockDescent<W> {
    /// One substep with `global`'s step before each sweep.
    #[inline(always)]
    pub(crate) fn substep_with(
        &mut self,
        step: &Substep<'_, W>,
        state: &mut State<W>,
        global: &mut impl GlobalStep<W>,
    ) {
        let (model, k, setup) = (step.model, step.k, step.setup);
        let zero = L::<W>::splat(0.0);
        let half = L::<W>::splat(0.5);
        let h = L::<W>::splat(k.dt);
        let inv_h = L::<W>::splat(1.0 / k.dt);
        let active = state.active;
        let cup_start = model.cup_start();
        let num_package = model.num_package;
        let p = setup.params;
        let gravity = V3::new(zero, p.gravity, zero);

        // 1. The cups move to their pose at the end of the step.
        let t1 = step.t1;
        let (tp, tq) = (step.tool.position, step.tool.orientation);
        let next = setup.tool_lanes(&t1, k.rest_time);
        let (np, nq) = (next.position, next.orientation);
        for (c, off) in setup.cup_offsets.iter().enumerate() {
            let i = cup_start + c;
            let start = tq.rotate(*off) + tp;
            let end = nq.rotate(*off) + np;
            state.x[i] = keep(active, end, state.x[i]);
            state.v[i] = keep(active, (end - start) * inv_h, state.v[i]);
        }

        // 2. Inertial predictions of the film and the disc.
        let h2 = h * h;
        for i in 0..num_package {
            self.x_start[i] = state.x[i];
            let y = state.x[i] + state.v[i] * h + gravity * h2;
            self.inertia_target[i] = y;
            state.x[i] = keep(active, y, state.x[i]);
            self.x_rate[i] = (state.x[i] - self.x_start[i]) * inv_h;
        }
        let disc_start = state.disc;
        let inertia = p.disc_inertia;
        let disc_target = disc_start.com + disc_start.v * h + gravity * h2;
        // Gyroscopic term explicitly (as the explicit integrator), in the body frame.
        let wb = disc_start.q.rotate_inv(disc_start.w);
        let iw = V3::new(inertia.x * wb.x, inertia.y * wb.y, inertia.z * wb.z);
        let gyro = wb.cross(iw);
        let wb1 = wb - V3::new(gyro.x / inertia.x, gyro.y / inertia.y, gyro.z / inertia.z) * h;
        let w_target = disc_start.q.rotate(wb1);
        let q_target = turned(disc_start.q, w_target * h);
        // Lanes whose disc is held during the rest follow their path exactly.
        let (held_com, _) = setup.held_disc(&t1, k.rest_time, disc_target, disc_start.v);
        let held = Lanes::<W>(std::array::from_fn(|l| {
            (setup.disc_hold[l].is_some() && t1[l] <= k.rest_time) as u8 as f32
        }));
        let mut com = V3::select_lt(half, held, held_com, disc_target);
        let (held_q, _, turning) = setup.held_turn(&t1, k.rest_time, q_target, w_target);
        let mut q = held_q;

        // 3. Contact data with the disc, frozen for the substep.
        let (dr, dh) = (model.disc.radius, model.disc.half_height);
        let radius = model.particle_radius;
        let reach = (dr * dr + dh * dh).sqrt() + radius;
        let reach2 = L::<W>::splat(reach * reach);
        // Candidates: within reach at the start, with a margin for this step's motion.
        let margin = reach + 4.0 * radius;
        let colliding = if model.config.cups.collide_with_disc {
            model.num_particles()
        } else {
            cup_start
        };
        self.disc_candidates.clear();
        self.near_disc.clear();
        self.near_disc.resize(num_package, false);
        for i in 0..colliding {
            let rel = self.x_start_or_x(&state.x, i, num_package) - disc_start.com;
            let dist2 = rel.dot(rel);
            if dist2.0.iter().all(|&d| d > margin * margin) {
                continue;
            }
            self.disc_candidates.push(i as u32);
            if i < num_package {
                self.near_disc[i] = true;
            }
            let local = disc_start.q.rotate_inv(rel);
            let (d, n_local) = forces::cylinder_distance(local, L::splat(dr), L::splat(dh));
            state.contact_point[i] = local - n_local * d;
            state.contact_normal[i] = disc_start.q.rotate(n_local);
        }
        self.index_springs(state, num_package, cup_start);
        global.prepare(step, state);

        let rad = L::<W>::splat(radius);
        let ground = ContactMaterial {
            ke: L::splat(k.ground.ke),
            kd: L::splat(k.ground.kd),
            kf: L::splat(k.ground.kf),
            mu: L::splat(k.ground.mu),
        };
        let up = V3::new(zero, L::splat(1.0), zero);
        let mass = L::<W>::splat(1.0) / p.inv_mass_package;
        let inertial = mass / h2;
        let disc_mass = p.disc_mass;
        let shape_thickness = L::<W>::splat(model.config.disc.shape_thickness_m);
        let membrane = Membrane::new(p.tri);

        let rho2 = self.chebyshev_rho * self.chebyshev_rho;
        let mut omega = 1.0f32;
        for iteration in 0..self.iterations {
            if rho2 > 0.0 {
                self.x_before[..num_package].copy_from_slice(&state.x[..num_package]);
            }
            // Disc velocity and spin implied by its current iterate.
            let disc_v = (com - disc_start.com) * inv_h;
            let disc_w = rotation_between(q, disc_start.q) * inv_h;

            self.bending_at_sweep_start(model, &state.x, p.edge, inv_h);
            let terms = VertexTerms {
                model,
                p: &p,
                membrane,
                inertial,
                inv_h,
                ground,
                rad,
                reach2,
                disc: (com, q),
                disc_velocity: (disc_v, disc_w),
            };

            // A composite solver's global step, from the residual forces at the sweep's start.
            if let Some(residual) = global.residual() {
                self.membrane_forces(model, &state.x, membrane, residual);
                for (i, r) in residual.iter_mut().enumerate() {
                    *r += self.force_without_membrane(&terms, state, i);
                }
            }
            global.solve();
            if let Some(dx) = global.residual() {
                for (i, d) in dx.iter().enumerate() {
                    state.x[i] = keep(active, state.x[i] + *d, state.x[i]);
                    self.x_rate[i] = (state.x[i] - self.x_start[i]) * inv_h;
                }
            }

            // 4. Gauss-Seidel sweep over the package vertices, forwards and backwards in turn:
            // one direction only drifts an unconverged solve along the vertex order (a falling
            // package slid sideways).
            for n in 0..num_package {
                let i = if iteration % 2 == 0 {
                    n
                } else {
                    num_package - 1 - n
                };
                let xi = state.x[i];
                let (force, stiff) = self.vertex_system(&terms, state, i);
                let dx = stiff.solve(force);
                state.x[i] = keep(active, xi + dx, xi);
                self.x_rate[i] = (state.x[i] - self.x_start[i]) * inv_h;
            }

            // Chebyshev acceleration (Wang 2015, as in the VBD paper): over-relax each sweep
            // against the iterate before last.
            if rho2 > 0.0 {
                if iteration >= 1 {
                    omega = if iteration == 1 {
                        2.0 / (2.0 - rho2)
                    } else {
                        4.0 / (4.0 - rho2 * omega)
                    };
                    let w = L::<W>::splat(omega);
                    for i in 0..num_package {
                        let older = self.x_older[i];
                        state.x[i] = keep(active, (state.x[i] - older) * w + older, state.x[i]);
                        self.x_rate[i] = (state.x[i] - self.x_start[i]) * inv_h;
                    }
                }
                std::mem::swap(&mut self.x_older, &mut self.x_before);
            }

            // 5. The disc's Newton step with the film as it is now.
            let mut sys = Disc6::<W>::new();
            let lin = (disc_target - com) * (disc_mass / h2);
            let ang = -world_inertia_times(q, inertia, rotation_between(q, q_target)) / h2;
            for (a, v) in [lin.x, lin.y, lin.z, ang.x, ang.y, ang.z]
                .into_iter()
                .enumerate()
            {
                sys.g[a] = v;
            }
            let lin_k = disc_mass / h2;
            for a in 0..3 {
                sys.h[a][a] = lin_k;
            }
            let one = L::<W>::splat(1.0);
            let axes = [
                V3::new(one, zero, zero),
                V3::new(zero, one, zero),
                V3::new(zero, zero, one),
            ];
            for a in 0..3 {
                let col = world_inertia_times(q, inertia, axes[a]) / h2;
                let col = [col.x, col.y, col.z];
                sys.h[3 + a][3 + a..6].copy_from_slice(&col[a..3]);
            }
            if W == 1 {
                self.add_disc_contacts_across_elements(
                    state,
                    p.disc_contact,
                    &mut sys,
                    (com, q),
                    (disc_v, disc_w),
                    (rad, reach2),
                    inv_h,
                );
            } else {
                for idx in 0..self.disc_candidates.len() {
                    let i = self.disc_candidates[idx] as usize;
                    let (gap, f, kk, arm) = self.disc_contact(
                        state,
                        p.disc_contact,
                        i,
                        com,
                        q,
                        disc_v,
                        disc_w,
                        rad,
                        reach2,
                        inv_h,
                    );
                    sys.add_point(gap, -f, &kk, arm);
                }
            }
            for rp in &model.disc.rim_points {
                let r = q.rotate(V3::splat(*rp));
                let point = com + r;
                if point
                    .y
                    .0
                    .iter()
                    .all(|&y| y >= model.config.disc.shape_thickness_m)
                {
                    continue;
                }
                let vel = disc_v + disc_w.cross(r);
                let gap = point.y - shape_thickness;
                let (f, kk) = contact_vertex(gap, up, vel, p.disc_ground, inv_h);
                sys.add_point(gap, f, &kk, r);
            }
            let newton = sys.solve();
            let dc = V3::new(newton[0], newton[1], newton[2]);
            let dtheta = V3::new(newton[3], newton[4], newton[5]);
            let moved = V3::select_lt(half, held, com, com + dc);
            com = keep(active, moved, com);
            let turned_q = turned(q, dtheta);
            let free = active * (L::splat(1.0) - turning);
            q = Quat {
                v: V3::select_lt(half, free, turned_q.v, q.v),
                w: L::select_lt(half, free, turned_q.w, q.w),
            };
        }

        // 6. Velocities from the step's displacement.
        let max_speed = L::<W>::splat(k.max_particle_speed);
        for i in 0..num_package {
            let v1 = self.x_rate[i];
            let speed = v1.length();
            let v1 = V3::select_lt(max_speed, speed, v1 * (max_speed / speed), v1);
            state.v[i] = keep(active, v1, state.v[i]);
            state.x[i] = keep(active, self.x_start[i] + v1 * h, state.x[i]);
        }
        let (_, held_v) = setup.held_disc(&t1, k.rest_time, com, (com - disc_start.com) * inv_h);
        let w1 = rotation_between(q, disc_start.q) * inv_h;
        let w1 = w1 * (L::splat(1.0) - L::splat(k.angular_damping) * h);
        let (_, w1, _) = setup.held_turn(&t1, k.rest_time, q, w1);
        state.disc.com = keep(active, com, disc_start.com);
        state.disc.v = keep(active, held_v, disc_start.v);
        state.disc.q = Quat {
            v: keep(active, q.v, disc_start.q.v),
            w: L::select_lt(half, active, q.w, disc_start.q.w),
        };
        state.disc.w = keep(active, w1, disc_start.w);

        // 7. Attachment spring forces for the seal model.
        for (s, spring) in state.springs.iter().enumerate() {
            let i = cup_start + s;
            let mut xj = V3::<L<W>>::zero();
            let mut vj = V3::<L<W>>::zero();
            for l in 0..W {
                let j = spring.target[l] as usize;
                set3(&mut xj, l, get3(&state.x[j], l));
                set3(&mut vj, l, get3(&state.v[j], l));
            }
            let f = forces::spring(
                state.x[i],
                xj,
                state.v[i],
                vj,
                spring.rest,
                p.spring[0],
                p.spring[1],
            );
            state.spring_force[s] = V3::select_lt(half, spring.sealed, f, V3::zero());
        }
    }
}
