//! The batched state of a block of W environments (Warp's `State`): what evolves from substep to
//! substep, and what each lane's episode prescribes ([`LaneSetup`]).
//!
//! # Layout
//! Every per-particle quantity is stored `[particle][component][lane]` (`Vec<V3<Lanes<W>>>`): the
//! W environments of a block sit side by side in the innermost dimension. All environments share
//! the topology, so an element's particle indices are the same in every lane: loading a triangle's
//! vertices reads three contiguous W-wide vectors per component, and every force law (written once
//! in [`crate::forces`]) runs as straight-line W-lane arithmetic that compiles to packed SIMD
//! (W = 8 is one AVX2 register of f32). There are no scatter conflicts across lanes and no
//! cross-lane reductions, so each lane computes exactly what it would compute alone.

mod setup;

pub(crate) use setup::{LaneParams, LaneSetup, ToolLanes};

use crate::math::{lane_vec, LaneVec, Lanes, Quat, Real, V3};
use crate::model::Model;

type L<const W: usize> = Lanes<W>;

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

/// The disc of every lane: centre of mass, orientation, velocity, angular velocity (world).
#[derive(Clone, Copy)]
pub(crate) struct LaneDisc<const W: usize> {
    pub(crate) com: V3<L<W>>,
    pub(crate) q: Quat<L<W>>,
    pub(crate) v: V3<L<W>>,
    pub(crate) w: V3<L<W>>,
}

/// What evolves in the W lanes of a block. A solver maps it to the next substep in place.
pub(crate) struct State<const W: usize> {
    /// Particle positions (package, then cups).
    pub(crate) x: LaneVec<V3<L<W>>>,
    /// Particle velocities.
    pub(crate) v: LaneVec<V3<L<W>>>,
    pub(crate) disc: LaneDisc<W>,
    /// Per cup particle: its attachment spring (target vertex, rest length, seal).
    pub(crate) springs: Vec<LaneSpring<W>>,
    /// Per spring: its force on the cup particle in the last substep (what the seal model
    /// filters; written by the solver like Warp's force buffers).
    pub(crate) spring_force: LaneVec<V3<L<W>>>,
    /// Per cup: whether it holds the film and its filtered load.
    pub(crate) cups: Vec<LaneCup<W>>,
    /// Per particle: frozen contact point on the disc (body frame) and normal (world).
    pub(crate) contact_point: LaneVec<V3<L<W>>>,
    pub(crate) contact_normal: LaneVec<V3<L<W>>>,
    /// Per lane: substeps since the start of its episode (its own clock).
    pub(crate) clock: [u64; W],
    /// 1.0 for lanes still simulated, 0.0 for frozen ones.
    pub(crate) active: L<W>,
}

impl<const W: usize> State<W> {
    /// Zeroed arrays sized for `model`, every lane active at time 0 with its cups sealed.
    pub(crate) fn new(model: &Model) -> Self {
        let n = model.num_particles();
        let zero3 = V3::<L<W>>::zero();
        let zero = L::<W>::splat(0.0);
        let one = L::<W>::splat(1.0);
        State {
            x: lane_vec(zero3, n),
            v: lane_vec(zero3, n),
            disc: LaneDisc {
                com: zero3,
                q: Quat {
                    v: zero3,
                    w: L::splat(1.0),
                },
                v: zero3,
                w: zero3,
            },
            springs: vec![
                LaneSpring {
                    target: [0; W],
                    rest: zero,
                    sealed: one,
                    tension: zero,
                };
                model.num_cup
            ],
            spring_force: lane_vec(zero3, model.num_cup),
            cups: vec![
                LaneCup {
                    attached: one,
                    sealed_count: L::splat(model.cup_size as f32),
                    load: zero3,
                };
                model.num_cups()
            ],
            contact_point: lane_vec(zero3, n),
            contact_normal: lane_vec(zero3, n),
            clock: [0; W],
            active: one,
        }
    }

    /// Each lane's own time (s) plus `ahead`, for substeps of `dt64` seconds.
    pub(crate) fn lane_times(&self, dt64: f64, ahead: f64) -> [f64; W] {
        std::array::from_fn(|l| self.clock[l] as f64 * dt64 + ahead)
    }

    /// Bytes held by the arrays.
    pub(crate) fn bytes(&self) -> usize {
        let per_particle = std::mem::size_of::<V3<L<W>>>();
        [&self.x, &self.v, &self.contact_point, &self.contact_normal]
            .iter()
            .map(|a| a.capacity() * per_particle)
            .sum::<usize>()
            + self.spring_force.capacity() * per_particle
            + self.springs.capacity() * std::mem::size_of::<LaneSpring<W>>()
            + self.cups.capacity() * std::mem::size_of::<LaneCup<W>>()
    }
}
