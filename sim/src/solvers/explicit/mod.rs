//! Warp 1.6's semi-implicit (symplectic) Euler ([`crate::config::Solver::SemiImplicitEuler`]):
//! per substep the cups are driven to the tool, every force term is evaluated once at the current
//! state ([`assembly`]), then the disc (Warp `integrate_bodies`) and the particles (Warp
//! `integrate_particles`) are integrated. Stable only for small substeps (bending sets the limit).
//!
//! Contacts with the disc use Warp's frozen contact data: the closest point on the disc (body
//! frame) and the normal (world) are regenerated every `disc.contact_refresh_substeps` of each
//! lane's own clock and kept in the state in between.

mod assembly;

use crate::config::DriveMode;
use crate::math::{lane_vec, LaneVec, Lanes, Quat, Real, V3};
use crate::model::Model;
use crate::state::{LaneDisc, State, ToolLanes};

use super::{keep, Integrator, Substep};
use assembly::{
    contact_and_bending_forces, contact_and_bending_forces_simd, membrane_forces,
    membrane_forces_simd,
};

type L<const W: usize> = Lanes<W>;

/// The explicit solver of a block: its settings and its two force buffers (one per half of the
/// force evaluation, summed per particle in a fixed order).
pub(crate) struct SemiImplicitEuler<const W: usize> {
    /// How the cups follow the tool.
    drive: DriveMode,
    /// Servo gain on the position error (1/s) and feed-forward weight of the tool's velocity.
    kp: f32,
    kff: f32,
    /// Substeps between regenerations of the frozen disc contact data.
    contact_refresh: u64,
    /// Forces of the membrane half and of the contact half of the evaluation.
    f: LaneVec<V3<L<W>>>,
    f2: LaneVec<V3<L<W>>>,
}

impl<const W: usize> Integrator<W> for SemiImplicitEuler<W> {
    fn new(model: &Model) -> Self {
        let c = &model.config;
        let n = model.num_particles();
        SemiImplicitEuler {
            drive: c.cups.drive,
            kp: c.cups.servo_kp,
            kff: c.cups.servo_kff,
            contact_refresh: c.disc.contact_refresh_substeps as u64,
            f: lane_vec(V3::zero(), n),
            f2: lane_vec(V3::zero(), n),
        }
    }

    fn bytes(&self) -> usize {
        (self.f.capacity() + self.f2.capacity()) * std::mem::size_of::<V3<L<W>>>()
    }

    #[inline(always)]
    fn substep(&mut self, step: &Substep<'_, W>, state: &mut State<W>) {
        let (model, k, setup) = (step.model, step.k, step.setup);
        let zero = L::<W>::splat(0.0);
        let half = L::<W>::splat(0.5);
        let dt = L::<W>::splat(k.dt);
        let active = state.active;
        let cup_start = model.cup_start();
        let n = model.num_particles();
        let p = setup.params;

        // 1. Drive the cups (before forces, like the reference's `actuate_suction_cup`).
        let ToolLanes {
            position: tp,
            orientation: tq,
            velocity: tv,
        } = step.tool;
        match self.drive {
            DriveMode::Servo => {
                let (kp, kff) = (L::splat(self.kp), L::splat(self.kff));
                for (c, off) in setup.cup_offsets.iter().enumerate() {
                    let i = cup_start + c;
                    let target = tq.rotate(*off) + tp;
                    let vel = (target - state.x[i]) * kp + tv * kff;
                    state.v[i] = keep(active, vel, state.v[i]);
                }
            }
            DriveMode::Kinematic => {
                let next = setup.tool_lanes(&step.t1, k.rest_time);
                let (np, nq) = (next.position, next.orientation);
                for (c, off) in setup.cup_offsets.iter().enumerate() {
                    let i = cup_start + c;
                    let target = tq.rotate(*off) + tp;
                    let next = nq.rotate(*off) + np;
                    state.x[i] = keep(active, target, state.x[i]);
                    state.v[i] = keep(active, (next - target) / dt, state.v[i]);
                }
            }
        }

        // 2-6. Forces, in two independent halves summed per particle in a fixed order; a
        // single-environment batch computes the halves on two threads (same arithmetic).
        let disc = state.disc;
        let refresh = state
            .clock
            .map(|c| c.is_multiple_of(self.contact_refresh) as u8 as f32);
        let refresh = refresh.iter().any(|&r| r > 0.0).then_some(Lanes(refresh));
        let (x, v) = (&state.x[..], &state.v[..]);
        let (springs, f, f2) = (&state.springs[..], &mut self.f[..], &mut self.f2[..]);
        let spring_force = &mut state.spring_force[..];
        let (cp, cn) = (&mut state.contact_point[..], &mut state.contact_normal[..]);
        // One environment: the two halves on two threads, each compiled for AVX2 (closures run
        // by rayon leave the substep's AVX2-compiled code). Otherwise direct calls, inlined into
        // it.
        let (disc_f, disc_t) = if step.parallel {
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
        let (com1, v1) = setup.held_disc(&step.t1, k.rest_time, com1, v1);
        let (q1, w1, _) = setup.held_turn(&step.t1, k.rest_time, q1, w1);
        state.disc = LaneDisc {
            com: keep(active, com1, disc.com),
            q: Quat {
                v: keep(active, q1.v, disc.q.v),
                w: L::select_lt(half, active, q1.w, disc.q.w),
            },
            v: keep(active, v1, disc.v),
            w: keep(active, w1, disc.w),
        };

        // 8. Integrate particles (Warp `integrate_particles`), one loop per kind of particle:
        // with the branch inside one loop, LLVM if-converted it into 128-bit pieces and
        // per-lane selects (30 % slower).
        let max_speed = L::<W>::splat(k.max_particle_speed);
        let package = 0..cup_start;
        self.integrate_free(state, package, p.inv_mass_package, gravity, dt, max_speed);
        if self.drive == DriveMode::Kinematic {
            // The cups move at the velocity set in step 1.
            for i in cup_start..n {
                state.x[i] = keep(active, state.x[i] + state.v[i] * dt, state.x[i]);
            }
        } else {
            self.integrate_free(state, cup_start..n, p.inv_mass_cup, gravity, dt, max_speed);
        }
    }
}

impl<const W: usize> SemiImplicitEuler<W> {
    /// Advances particles `range` of the active lanes of `state` under their forces (inverse
    /// mass `inv_m`), the speed clamped to `max_speed`.
    #[inline(always)]
    fn integrate_free(
        &self,
        state: &mut State<W>,
        range: std::ops::Range<usize>,
        inv_m: L<W>,
        gravity: V3<L<W>>,
        dt: L<W>,
        max_speed: L<W>,
    ) {
        let half = L::<W>::splat(0.5);
        let active = state.active;
        for i in range {
            let v1 = state.v[i] + ((self.f[i] + self.f2[i]) * inv_m + gravity) * dt;
            let speed = v1.length();
            let v1 = V3::select_lt(max_speed, speed, v1 * (max_speed / speed), v1);
            state.v[i] = V3::select_lt(half, active, v1, state.v[i]);
            state.x[i] = V3::select_lt(half, active, state.x[i] + v1 * dt, state.x[i]);
            // Keeps LLVM from vectorising this loop across particles (gathering one lane of
            // eight particles per vector: 15-25 % slower than one particle's W lanes at a time).
            std::sync::atomic::compiler_fence(std::sync::atomic::Ordering::SeqCst);
        }
    }
}
