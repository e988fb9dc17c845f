//! The block-descent integrator ([`crate::config::Solver::BlockDescent`]): one implicit Euler step
//! per substep, solved by Vertex Block Descent (Chen et al., SIGGRAPH 2024).
//!
//! Per substep: the cups move kinematically to their pose at the end of the step; every package
//! vertex starts from its inertial prediction `y = x + h·v + h²·g`; then `iterations` sweeps, each
//! visiting the package vertices in index order (Gauss-Seidel: a vertex sees its neighbours'
//! latest positions) and taking one Newton step on its 3x3 block
//! `(m/h²·I + ΣK)·Δx = m/h²·(y − x) + Σf` (force laws and stiffness blocks in
//! [`crate::implicit`]), then one Newton step of the disc's 6x6 block (translation and rotation,
//! inertia plus every contact on it, with the particles as they are now): the disc and the film
//! are solved together within the step, not one step apart. Velocities are the step's
//! displacement over `h`. The environments of a block are SIMD lanes, so the sweeps need no graph
//! colouring: within one environment the order is plainly sequential.
//!
//! Contacts with the disc use Warp's frozen contact data: the closest point on the disc (body
//! frame) and the normal (world) are found once per substep from the positions at its start.

use crate::forces::{self, ContactMaterial};
use crate::implicit::{
    bending_element, contact_vertex, spring_vertex, triangle_vertex, LaneCorners, Membrane, Sym3,
};
use crate::math::{Lanes, Quat, Real, V3};
use crate::model::Model;

use super::{gather_elements, get3, set3, Block, StepConstants, E8, ELEMENT_LANES, L};

/// A 6x6 symmetric system of one lane block: the disc's translation and rotation.
struct Disc6<const W: usize> {
    h: [[L<W>; 6]; 6],
    g: [L<W>; 6],
}

impl<const W: usize> Disc6<W> {
    fn new() -> Self {
        Disc6 {
            h: [[L::splat(0.0); 6]; 6],
            g: [L::splat(0.0); 6],
        }
    }

    /// Adds a force `f` acting at arm `r` from the centre, with stiffness `k` (with respect to the
    /// point's position), in lanes where `gap < 0` (see [`point_terms`]). Other lanes are left
    /// bit for bit as they were.
    #[inline(always)]
    fn add_point(&mut self, gap: L<W>, f: V3<L<W>>, k: &Sym3<L<W>>, r: V3<L<W>>) {
        let (g, h) = point_terms(f, k, r);
        self.add_terms(gap, |a| g[a], |n| h[n]);
    }

    /// Adds the terms of one point (entry `a` of its generalised force `g(a)`, entry `n` of its
    /// Hessian's upper triangle `h(n)`, as [`point_terms`] returns them) in lanes where `gap < 0`.
    #[inline(always)]
    fn add_terms(&mut self, gap: L<W>, g: impl Fn(usize) -> L<W>, h: impl Fn(usize) -> L<W>) {
        let zero = L::splat(0.0);
        for a in 0..6 {
            self.g[a] = L::select_lt(gap, zero, self.g[a] + g(a), self.g[a]);
        }
        let mut n = 0;
        for a in 0..6 {
            for b in a..6 {
                self.h[a][b] = L::select_lt(gap, zero, self.h[a][b] + h(n), self.h[a][b]);
                n += 1;
            }
        }
    }

    /// Solves for the Newton step (LDLᵀ, upper triangle used).
    #[inline(always)]
    fn solve(&self) -> [L<W>; 6] {
        let mut a = self.h;
        for r in 0..6 {
            for c in 0..r {
                a[r][c] = a[c][r];
            }
        }
        let mut d = [L::<W>::splat(0.0); 6];
        let mut lo = [[L::<W>::splat(0.0); 6]; 6];
        for j in 0..6 {
            let mut dj = a[j][j];
            for k in 0..j {
                dj -= lo[j][k] * lo[j][k] * d[k];
            }
            d[j] = dj;
            for i in j + 1..6 {
                let mut s = a[i][j];
                for k in 0..j {
                    s -= lo[i][k] * lo[j][k] * d[k];
                }
                lo[i][j] = s / dj;
            }
        }
        let mut y = self.g;
        for i in 0..6 {
            for k in 0..i {
                let t = lo[i][k] * y[k];
                y[i] -= t;
            }
        }
        for i in 0..6 {
            y[i] = y[i] / d[i];
        }
        for i in (0..6).rev() {
            for k in i + 1..6 {
                let t = lo[k][i] * y[k];
                y[i] -= t;
            }
        }
        y
    }
}

/// A force `f` with stiffness `k` (with respect to the point's position) acting at arm `r` from
/// the disc's centre: the generalised force `[f, r × f]` and the upper triangle of the Hessian
/// `JᵀKJ`, `J = [I, −[r]×]`, row by row.
#[inline(always)]
fn point_terms<T: Real>(f: V3<T>, k: &Sym3<T>, r: V3<T>) -> ([T; 6], [T; 21]) {
    let zero = T::splat(0.0);
    let t = r.cross(f);
    // Columns of J: the point's displacement per unit of each coordinate.
    let one = T::splat(1.0);
    let ex = V3::new(one, zero, zero);
    let ey = V3::new(zero, one, zero);
    let ez = V3::new(zero, zero, one);
    let cols = [ex, ey, ez, ex.cross(r), ey.cross(r), ez.cross(r)];
    let kc = [
        k.mul_vec(cols[0]),
        k.mul_vec(cols[1]),
        k.mul_vec(cols[2]),
        k.mul_vec(cols[3]),
        k.mul_vec(cols[4]),
        k.mul_vec(cols[5]),
    ];
    let mut h = [zero; 21];
    let mut n = 0;
    for a in 0..6 {
        for b in a..6 {
            h[n] = cols[a].dot(kc[b]);
            n += 1;
        }
    }
    ([f.x, f.y, f.z, t.x, t.y, t.z], h)
}

/// Contact of a particle at `x` moving with `v` with the disc at pose (`com`, `q`) moving with
/// (`disc_v`, `disc_w`), through the frozen contact `normal` (world) and `point` (body frame):
/// gap (negative when touching), force on the particle, stiffness, arm from the centre to the
/// contact point.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn disc_contact_at<T: Real>(
    x: V3<T>,
    v: V3<T>,
    normal: V3<T>,
    point: V3<T>,
    (com, q): (V3<T>, Quat<T>),
    (disc_v, disc_w): (V3<T>, V3<T>),
    (rad, reach2): (T, T),
    material: ContactMaterial<T>,
    inv_h: T,
) -> (T, V3<T>, Sym3<T>, V3<T>) {
    let arm = q.rotate(point);
    let bx = com + arm;
    let rel = x - com;
    let dist2 = rel.dot(rel);
    let gap = normal.dot(x - bx) - rad;
    // Beyond the disc's bounding sphere a frozen contact plane would reach too far.
    let gap = T::select_lt(reach2, dist2, T::splat(1.0), gap);
    let surface_v = disc_v + disc_w.cross(arm);
    let (f, kk) = contact_vertex(gap, normal, v - surface_v, material, inv_h);
    (gap, f, kk, arm)
}

/// The rotation vector taking `from` to `to` (both unit quaternions), short way round.
#[inline(always)]
fn rotation_between<const W: usize>(to: Quat<L<W>>, from: Quat<L<W>>) -> V3<L<W>> {
    let conj = Quat {
        v: -from.v,
        w: from.w,
    };
    let d = to.compose(conj);
    d.v * (d.w.sign() * L::splat(2.0))
}

/// `q` turned by the small rotation vector `theta` (first order, renormalised).
#[inline(always)]
fn turned<const W: usize>(q: Quat<L<W>>, theta: V3<L<W>>) -> Quat<L<W>> {
    let zero = L::splat(0.0);
    let spin = Quat { v: theta, w: zero }.compose(q);
    let half = L::splat(0.5);
    Quat {
        v: q.v + spin.v * half,
        w: q.w + spin.w * half,
    }
    .normalize()
}

/// `R·diag(i)·Rᵀ·u` for the rotation `q`.
#[inline(always)]
fn world_inertia_times<const W: usize>(q: Quat<L<W>>, i: V3<L<W>>, u: V3<L<W>>) -> V3<L<W>> {
    let b = q.rotate_inv(u);
    q.rotate(V3::new(b.x * i.x, b.y * i.y, b.z * i.z))
}

/// Lane `e` of `v`, in every lane of the block's vectors (used with one-lane blocks).
#[inline(always)]
fn lane_vector<const W: usize>(v: &V3<E8>, e: usize) -> V3<L<W>> {
    V3::new(L::splat(v.x.0[e]), L::splat(v.y.0[e]), L::splat(v.z.0[e]))
}

/// Lane `e` of `m`, in every lane of the block's matrices (used with one-lane blocks).
#[inline(always)]
fn lane_matrix<const W: usize>(m: &Sym3<E8>, e: usize) -> Sym3<L<W>> {
    Sym3 {
        m: [
            L::splat(m.m[0].0[e]),
            L::splat(m.m[1].0[e]),
            L::splat(m.m[2].0[e]),
            L::splat(m.m[3].0[e]),
            L::splat(m.m[4].0[e]),
            L::splat(m.m[5].0[e]),
        ],
    }
}

impl<const W: usize> Block<W> {
    /// Rebuilds, for each package vertex, the attachment springs pulling on it in each lane (a
    /// lane's cup particles attach to vertices of its own choosing).
    fn index_springs(&mut self, num_package: usize) {
        let mut counts = vec![[0u32; W]; num_package];
        for spring in &self.springs {
            for l in 0..W {
                counts[spring.target[l] as usize][l] += 1;
            }
        }
        self.spring_slot_starts.clear();
        self.spring_slot_starts.push(0);
        for c in &counts {
            let most = c.iter().copied().max().unwrap_or(0);
            let last = *self.spring_slot_starts.last().unwrap_or(&0);
            self.spring_slot_starts.push(last + most);
        }
        let total = *self.spring_slot_starts.last().unwrap_or(&0) as usize;
        self.spring_slots.clear();
        self.spring_slots.resize(total, [u32::MAX; W]);
        let mut filled = vec![[0u32; W]; num_package];
        for (s, spring) in self.springs.iter().enumerate() {
            for l in 0..W {
                let j = spring.target[l] as usize;
                let slot = self.spring_slot_starts[j] + filled[j][l];
                self.spring_slots[slot as usize][l] = s as u32;
                filled[j][l] += 1;
            }
        }
    }

    /// One substep of the block-descent integrator (see the module documentation).
    #[inline(always)]
    pub(super) fn substep_descent(&mut self, model: &Model, k: &StepConstants) {
        let zero = L::<W>::splat(0.0);
        let half = L::<W>::splat(0.5);
        let h = L::<W>::splat(k.dt);
        let inv_h = L::<W>::splat(1.0 / k.dt);
        let active = self.active;
        let keep = |new: V3<L<W>>, old: V3<L<W>>| V3::select_lt(half, active, new, old);
        let cup_start = model.cup_start();
        let num_package = model.num_package;
        let p = self.params;
        let gravity = V3::new(zero, p.gravity, zero);

        // 1. The cups move to their pose at the end of the step.
        let t = self.lane_times(k, 0.0);
        let t1 = self.lane_times(k, k.dt64);
        let (tp, tq, _) = self.tool_lanes(&t, k.rest_time);
        let (np, nq, _) = self.tool_lanes(&t1, k.rest_time);
        for (c, off) in self.cup_offsets.iter().enumerate() {
            let i = cup_start + c;
            let start = tq.rotate(*off) + tp;
            let end = nq.rotate(*off) + np;
            self.x[i] = keep(end, self.x[i]);
            self.v[i] = keep((end - start) * inv_h, self.v[i]);
        }

        // 2. Inertial predictions of the film and the disc.
        let h2 = h * h;
        for i in 0..num_package {
            self.x_start[i] = self.x[i];
            let y = self.x[i] + self.v[i] * h + gravity * h2;
            self.inertia_target[i] = y;
            self.x[i] = keep(y, self.x[i]);
            self.x_rate[i] = (self.x[i] - self.x_start[i]) * inv_h;
        }
        let disc_start = self.disc;
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
        let (held_com, _) = self.held_disc(&t1, k.rest_time, disc_target, disc_start.v);
        let held = Lanes::<W>(std::array::from_fn(|l| {
            (self.disc_hold[l].is_some() && t1[l] <= k.rest_time) as u8 as f32
        }));
        let mut com = V3::select_lt(half, held, held_com, disc_target);
        let (held_q, _, turning) = self.held_turn(&t1, k.rest_time, q_target, w_target);
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
            let rel = self.x_start_or_x(i, num_package) - disc_start.com;
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
            self.contact_point[i] = local - n_local * d;
            self.contact_normal[i] = disc_start.q.rotate(n_local);
        }
        self.index_springs(num_package);

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

        let rho2 = k.chebyshev_rho * k.chebyshev_rho;
        let mut omega = 1.0f32;
        for iteration in 0..k.iterations {
            if rho2 > 0.0 {
                self.x_before[..num_package].copy_from_slice(&self.x[..num_package]);
            }
            // Disc velocity and spin implied by its current iterate.
            let disc_v = (com - disc_start.com) * inv_h;
            let disc_w = rotation_between(q, disc_start.q) * inv_h;

            self.bending_at_sweep_start(model, inv_h);

            // 4. Gauss-Seidel sweep over the package vertices, forwards and backwards in turn:
            // one direction only drifts an unconverged solve along the vertex order (a falling
            // package slid sideways).
            for n in 0..num_package {
                let i = if iteration % 2 == 0 {
                    n
                } else {
                    num_package - 1 - n
                };
                let xi = self.x[i];
                let vi = self.x_rate[i];
                let mut force = (self.inertia_target[i] - xi) * inertial;
                let mut stiff = Sym3::diagonal(inertial);
                self.add_membrane(model, i, membrane, inv_h, &mut force, &mut stiff);
                // Bending, evaluated at the start of the sweep (it is soft: lagging it costs
                // little convergence and saves three of its four evaluations).
                force += self.bend_force[i];
                stiff.add_assign(self.bend_stiffness[i]);
                let slots =
                    self.spring_slot_starts[i] as usize..self.spring_slot_starts[i + 1] as usize;
                for slot in &self.spring_slots[slots] {
                    let mut anchor = V3::<L<W>>::zero();
                    let mut anchor_v = V3::<L<W>>::zero();
                    let mut rest = L::<W>::splat(1.0);
                    let mut on = zero;
                    for l in 0..W {
                        let s = slot[l];
                        if s == u32::MAX {
                            continue;
                        }
                        let spring = &self.springs[s as usize];
                        let c = cup_start + s as usize;
                        set3(&mut anchor, l, get3(&self.x[c], l));
                        set3(&mut anchor_v, l, get3(&self.v[c], l));
                        rest.0[l] = spring.rest.0[l];
                        on.0[l] = spring.sealed.0[l];
                    }
                    // Lanes without this slot, and lip elements that let go, pull with nothing.
                    let (ke, kd) = (p.spring[0] * on, p.spring[1] * on);
                    let (f, kk) = spring_vertex(xi, anchor, vi, anchor_v, rest, ke, kd, inv_h);
                    force += V3::select_lt(half, on, f, V3::zero());
                    stiff.add_assign(kk.keep_lt(half, on));
                }
                // Contacts only change the lanes that touch (see the module docs of `block`).
                if xi.y.0.iter().any(|&y| y < radius) {
                    let gap = xi.y - rad;
                    let (f, kk) = contact_vertex(gap, up, vi, ground, inv_h);
                    force = V3::select_lt(gap, zero, force + f, force);
                    stiff = Sym3::select_lt(gap, zero, stiff.plus(kk), stiff);
                }
                if self.near_disc[i] {
                    let (gap, f, kk, _) =
                        self.disc_contact(i, com, q, disc_v, disc_w, rad, reach2, inv_h);
                    force = V3::select_lt(gap, zero, force + f, force);
                    stiff = Sym3::select_lt(gap, zero, stiff.plus(kk), stiff);
                }
                let dx = stiff.solve(force);
                self.x[i] = keep(xi + dx, xi);
                self.x_rate[i] = (self.x[i] - self.x_start[i]) * inv_h;
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
                        self.x[i] = keep((self.x[i] - older) * w + older, self.x[i]);
                        self.x_rate[i] = (self.x[i] - self.x_start[i]) * inv_h;
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
                    &mut sys,
                    (com, q),
                    (disc_v, disc_w),
                    (rad, reach2),
                    inv_h,
                );
            } else {
                for idx in 0..self.disc_candidates.len() {
                    let i = self.disc_candidates[idx] as usize;
                    let (gap, f, kk, arm) =
                        self.disc_contact(i, com, q, disc_v, disc_w, rad, reach2, inv_h);
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
            let step = sys.solve();
            let dc = V3::new(step[0], step[1], step[2]);
            let dtheta = V3::new(step[3], step[4], step[5]);
            let moved = V3::select_lt(half, held, com, com + dc);
            com = keep(moved, com);
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
            self.v[i] = keep(v1, self.v[i]);
            self.x[i] = keep(self.x_start[i] + v1 * h, self.x[i]);
        }
        let (_, held_v) = self.held_disc(&t1, k.rest_time, com, (com - disc_start.com) * inv_h);
        let w1 = rotation_between(q, disc_start.q) * inv_h;
        let w1 = w1 * (L::splat(1.0) - L::splat(k.angular_damping) * h);
        let (_, w1, _) = self.held_turn(&t1, k.rest_time, q, w1);
        self.disc.com = keep(com, disc_start.com);
        self.disc.v = keep(held_v, disc_start.v);
        self.disc.q = Quat {
            v: keep(q.v, disc_start.q.v),
            w: L::select_lt(half, active, q.w, disc_start.q.w),
        };
        self.disc.w = keep(w1, disc_start.w);

        // 7. Attachment spring forces for the seal model, then the seal.
        for (s, spring) in self.springs.iter().enumerate() {
            let i = cup_start + s;
            let mut xj = V3::<L<W>>::zero();
            let mut vj = V3::<L<W>>::zero();
            for l in 0..W {
                let j = spring.target[l] as usize;
                set3(&mut xj, l, get3(&self.x[j], l));
                set3(&mut vj, l, get3(&self.v[j], l));
            }
            let f = forces::spring(
                self.x[i],
                xj,
                self.v[i],
                vj,
                spring.rest,
                p.spring[0],
                p.spring[1],
            );
            self.spring_force[s] = V3::select_lt(half, spring.sealed, f, V3::zero());
        }
        self.update_seals(model, k, tq, &t);
    }

    /// Adds the membrane force and stiffness of package vertex `i` to `force` and `stiff`, one
    /// triangle at a time in adjacency order.
    #[inline(always)]
    fn add_membrane(
        &self,
        model: &Model,
        i: usize,
        membrane: Membrane<L<W>>,
        inv_h: L<W>,
        force: &mut V3<L<W>>,
        stiff: &mut Sym3<L<W>>,
    ) {
        if W == 1 {
            return self.add_membrane_across_elements(model, i, membrane, inv_h, force, stiff);
        }
        for tri in model.adjacency.triangles_of(i) {
            let [a, b, c] = tri.idx.map(|j| j as usize);
            let (area, inv_area) = tri.rest_area;
            let (f, kk) = triangle_vertex(
                [self.x[a], self.x[b], self.x[c]],
                [self.x_rate[a], self.x_rate[b], self.x_rate[c]],
                tri.corner as usize,
                [
                    [L::splat(tri.dm[0][0]), L::splat(tri.dm[0][1])],
                    [L::splat(tri.dm[1][0]), L::splat(tri.dm[1][1])],
                ],
                (L::splat(area), L::splat(inv_area)),
                membrane,
                inv_h,
            );
            *force += f;
            stiff.add_assign(kk);
        }
    }

    /// [`Self::add_membrane`] for a single-environment block (lane 0 only): the vertex's
    /// triangles side by side in [`ELEMENT_LANES`] lanes, each with the same arithmetic as in
    /// the per-environment path, summed in the same order, so the results are bit-identical.
    #[inline(always)]
    fn add_membrane_across_elements(
        &self,
        model: &Model,
        i: usize,
        membrane: Membrane<L<W>>,
        inv_h: L<W>,
        force: &mut V3<L<W>>,
        stiff: &mut Sym3<L<W>>,
    ) {
        let membrane = Membrane {
            mu: E8::splat(membrane.mu.0[0]),
            lambda: E8::splat(membrane.lambda.0[0]),
            damp: E8::splat(membrane.damp.0[0]),
            alpha: E8::splat(membrane.alpha.0[0]),
        };
        let inv_h = E8::splat(inv_h.0[0]);
        for chunk in model.adjacency.triangles_of(i).chunks(ELEMENT_LANES) {
            let (xs, vs) = gather_elements(chunk.len(), |e| chunk[e].idx, &self.x, &self.x_rate);
            let mut dm = [[E8::splat(0.0); 2]; 2];
            let mut area = E8::splat(1.0);
            let mut inv_area = E8::splat(1.0);
            let mut first = E8::splat(0.0);
            let mut second = E8::splat(0.0);
            for e in 0..ELEMENT_LANES {
                let tri = &chunk[e.min(chunk.len() - 1)];
                for (r, row) in tri.dm.iter().enumerate() {
                    for (c, value) in row.iter().enumerate() {
                        dm[r][c].0[e] = *value;
                    }
                }
                (area.0[e], inv_area.0[e]) = tri.rest_area;
                first.0[e] = (tri.corner == 0) as u8 as f32;
                second.0[e] = (tri.corner == 1) as u8 as f32;
            }
            let corners = LaneCorners { first, second };
            let (f, kk) = triangle_vertex(xs, vs, corners, dm, (area, inv_area), membrane, inv_h);
            for e in 0..chunk.len() {
                *force += lane_vector(&f, e);
                stiff.add_assign(lane_matrix(&kk, e));
            }
        }
    }

    /// Bending forces and stiffness blocks of every package vertex at the current positions.
    #[inline(always)]
    fn bending_at_sweep_start(&mut self, model: &Model, inv_h: L<W>) {
        for (f, k) in self
            .bend_force
            .iter_mut()
            .zip(self.bend_stiffness.iter_mut())
        {
            *f = V3::zero();
            *k = Sym3::zero();
        }
        let p = self.params;
        if W == 1 {
            return self.bending_across_elements(model, inv_h);
        }
        for edge in &model.package_edges {
            let id = [
                edge.idx[0] as usize,
                edge.idx[1] as usize,
                edge.idx[2] as usize,
                edge.idx[3] as usize,
            ];
            let (forces, grads, s) = bending_element(
                [self.x[id[0]], self.x[id[1]], self.x[id[2]], self.x[id[3]]],
                [
                    self.x_rate[id[0]],
                    self.x_rate[id[1]],
                    self.x_rate[id[2]],
                    self.x_rate[id[3]],
                ],
                L::splat(edge.rest_angle),
                p.edge[0],
                p.edge[1],
                inv_h,
            );
            for ((j, f), d) in id.into_iter().zip(forces).zip(grads) {
                self.bend_force[j] += f;
                self.bend_stiffness[j].add_assign(Sym3::outer(d, s));
            }
        }
    }

    /// [`Self::bending_at_sweep_start`] for a single-environment block: [`ELEMENT_LANES`] edges
    /// side by side, added in edge order (bit-identical, as [`Self::add_membrane_across_elements`]).
    #[inline(always)]
    fn bending_across_elements(&mut self, model: &Model, inv_h: L<W>) {
        let p = self.params;
        let (ke, kd) = (E8::splat(p.edge[0].0[0]), E8::splat(p.edge[1].0[0]));
        let inv_h = E8::splat(inv_h.0[0]);
        for chunk in model.package_edges.chunks(ELEMENT_LANES) {
            let (xs, vs) = gather_elements(chunk.len(), |e| chunk[e].idx, &self.x, &self.x_rate);
            let rest = Lanes(std::array::from_fn(|e| {
                chunk[e.min(chunk.len() - 1)].rest_angle
            }));
            let (forces, grads, s) = bending_element(xs, vs, rest, ke, kd, inv_h);
            let blocks = [
                Sym3::outer(grads[0], s),
                Sym3::outer(grads[1], s),
                Sym3::outer(grads[2], s),
                Sym3::outer(grads[3], s),
            ];
            for (e, edge) in chunk.iter().enumerate() {
                for (k, &j) in edge.idx.iter().enumerate() {
                    self.bend_force[j as usize] += lane_vector(&forces[k], e);
                    self.bend_stiffness[j as usize].add_assign(lane_matrix(&blocks[k], e));
                }
            }
        }
    }

    /// The film's contacts on the disc for a single-environment block: [`ELEMENT_LANES`]
    /// candidates side by side, added to `sys` in candidate order (bit-identical, as
    /// [`Self::add_membrane_across_elements`]).
    #[inline(always)]
    fn add_disc_contacts_across_elements(
        &self,
        sys: &mut Disc6<W>,
        (com, q): (V3<L<W>>, Quat<L<W>>),
        (disc_v, disc_w): (V3<L<W>>, V3<L<W>>),
        (rad, reach2): (L<W>, L<W>),
        inv_h: L<W>,
    ) {
        let wide = |v: V3<L<W>>| {
            V3::new(
                E8::splat(v.x.0[0]),
                E8::splat(v.y.0[0]),
                E8::splat(v.z.0[0]),
            )
        };
        let pose = (
            wide(com),
            Quat {
                v: wide(q.v),
                w: E8::splat(q.w.0[0]),
            },
        );
        let motion = (wide(disc_v), wide(disc_w));
        let sizes = (E8::splat(rad.0[0]), E8::splat(reach2.0[0]));
        let m = self.params.disc_contact;
        let material = ContactMaterial {
            ke: E8::splat(m.ke.0[0]),
            kd: E8::splat(m.kd.0[0]),
            kf: E8::splat(m.kf.0[0]),
            mu: E8::splat(m.mu.0[0]),
        };
        let inv_h = E8::splat(inv_h.0[0]);
        for chunk in self.disc_candidates.chunks(ELEMENT_LANES) {
            let mut x = V3::<E8>::zero();
            let mut v = V3::<E8>::zero();
            let mut normal = V3::<E8>::zero();
            let mut point = V3::<E8>::zero();
            for e in 0..ELEMENT_LANES {
                // Short chunks repeat their last candidate; those lanes are not added below.
                let i = chunk[e.min(chunk.len() - 1)] as usize;
                set3(&mut x, e, get3(&self.x[i], 0));
                set3(&mut v, e, get3(&self.particle_rate(i), 0));
                set3(&mut normal, e, get3(&self.contact_normal[i], 0));
                set3(&mut point, e, get3(&self.contact_point[i], 0));
            }
            let (gap, f, kk, arm) =
                disc_contact_at(x, v, normal, point, pose, motion, sizes, material, inv_h);
            let (g, h) = point_terms(-f, &kk, arm);
            for e in 0..chunk.len() {
                let lane = |a: E8| L::<W>::splat(a.0[e]);
                sys.add_terms(lane(gap), |a| lane(g[a]), |n| lane(h[n]));
            }
        }
    }

    /// Position of particle `i` at the start of the substep (package particles are saved in
    /// `x_start`; cup particles have already moved, their start does not matter for contact).
    #[inline(always)]
    fn x_start_or_x(&self, i: usize, num_package: usize) -> V3<L<W>> {
        if i < num_package {
            self.x_start[i]
        } else {
            self.x[i]
        }
    }

    /// Contact of particle `i` with the disc at pose (`com`, `q`) moving with (`disc_v`,
    /// `disc_w`): gap (negative when touching), force on the particle, stiffness, arm from the
    /// centre to the contact point.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn disc_contact(
        &self,
        i: usize,
        com: V3<L<W>>,
        q: Quat<L<W>>,
        disc_v: V3<L<W>>,
        disc_w: V3<L<W>>,
        rad: L<W>,
        reach2: L<W>,
        inv_h: L<W>,
    ) -> (L<W>, V3<L<W>>, Sym3<L<W>>, V3<L<W>>) {
        disc_contact_at(
            self.x[i],
            self.particle_rate(i),
            self.contact_normal[i],
            self.contact_point[i],
            (com, q),
            (disc_v, disc_w),
            (rad, reach2),
            self.params.disc_contact,
            inv_h,
        )
    }

    /// The step velocity of particle `i`'s current iterate (package particles) or its velocity
    /// (cup particles, which move kinematically).
    #[inline(always)]
    fn particle_rate(&self, i: usize) -> V3<L<W>> {
        if i < self.x_rate.len() {
            self.x_rate[i]
        } else {
            self.v[i]
        }
    }
}
