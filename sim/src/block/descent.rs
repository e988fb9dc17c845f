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
    bending_element, contact_vertex, spring_vertex, triangle_vertex, Membrane, Sym3,
};
use crate::math::{Lanes, Quat, Real, V3};
use crate::model::Model;

use super::{Block, StepConstants, L};

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
    /// point's position), in lanes where `gap < 0`: generalised force `[f, r × f]`, Hessian
    /// `JᵀKJ` with `J = [I, −[r]×]`. Other lanes are left bit for bit as they were.
    #[inline(always)]
    fn add_point(&mut self, gap: L<W>, f: V3<L<W>>, k: &Sym3<L<W>>, r: V3<L<W>>) {
        let zero = L::splat(0.0);
        let t = r.cross(f);
        for (a, v) in [f.x, f.y, f.z, t.x, t.y, t.z].into_iter().enumerate() {
            self.g[a] = L::select_lt(gap, zero, self.g[a] + v, self.g[a]);
        }
        // Columns of J: the point's displacement per unit of each coordinate.
        let one = L::splat(1.0);
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
        for a in 0..6 {
            for b in a..6 {
                let v = cols[a].dot(kc[b]);
                self.h[a][b] = L::select_lt(gap, zero, self.h[a][b] + v, self.h[a][b]);
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
                let vi = (xi - self.x_start[i]) * inv_h;
                let mut force = (self.inertia_target[i] - xi) * inertial;
                let mut stiff = Sym3::diagonal(inertial);
                for &(tri, corner) in model.adjacency.triangles_of(i) {
                    let tri = &model.package_triangles[tri as usize];
                    let [a, b, c] = [
                        tri.idx[0] as usize,
                        tri.idx[1] as usize,
                        tri.idx[2] as usize,
                    ];
                    let dm = tri.rest.dm;
                    let (f, kk) = triangle_vertex(
                        [self.x[a], self.x[b], self.x[c]],
                        [
                            (self.x[a] - self.x_start[a]) * inv_h,
                            (self.x[b] - self.x_start[b]) * inv_h,
                            (self.x[c] - self.x_start[c]) * inv_h,
                        ],
                        corner as usize,
                        [
                            [L::splat(dm[0][0]), L::splat(dm[0][1])],
                            [L::splat(dm[1][0]), L::splat(dm[1][1])],
                        ],
                        (
                            L::splat(1.0 / tri.rest.inv_rest_area()),
                            L::splat(tri.rest.inv_rest_area()),
                        ),
                        membrane,
                        inv_h,
                    );
                    force += f;
                    stiff.add_assign(kk);
                }
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
                        super::set3(&mut anchor, l, super::get3(&self.x[c], l));
                        super::set3(&mut anchor_v, l, super::get3(&self.v[c], l));
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
            for idx in 0..self.disc_candidates.len() {
                let i = self.disc_candidates[idx] as usize;
                let (gap, f, kk, arm) =
                    self.disc_contact(i, com, q, disc_v, disc_w, rad, reach2, inv_h);
                sys.add_point(gap, -f, &kk, arm);
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
            let v1 = (self.x[i] - self.x_start[i]) * inv_h;
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
                super::set3(&mut xj, l, super::get3(&self.x[j], l));
                super::set3(&mut vj, l, super::get3(&self.v[j], l));
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
                    (self.x[id[0]] - self.x_start[id[0]]) * inv_h,
                    (self.x[id[1]] - self.x_start[id[1]]) * inv_h,
                    (self.x[id[2]] - self.x_start[id[2]]) * inv_h,
                    (self.x[id[3]] - self.x_start[id[3]]) * inv_h,
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
        let x = self.x[i];
        let v = if i < self.x_start.len() {
            (x - self.x_start[i]) * inv_h
        } else {
            self.v[i]
        };
        let normal = self.contact_normal[i];
        let arm = q.rotate(self.contact_point[i]);
        let bx = com + arm;
        let rel = x - com;
        let dist2 = rel.dot(rel);
        let gap = normal.dot(x - bx) - rad;
        // Beyond the disc's bounding sphere a frozen contact plane would reach too far.
        let gap = L::select_lt(reach2, dist2, L::splat(1.0), gap);
        let surface_v = disc_v + disc_w.cross(arm);
        let (f, kk) = contact_vertex(gap, normal, v - surface_v, self.params.disc_contact, inv_h);
        (gap, f, kk, arm)
    }
}
