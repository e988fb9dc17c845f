//! What each lane's episode prescribes: material parameters, start positions, the cups' place on
//! the tool, the disc's hold during the rest, and what drives the tool.

use crate::episode::EpisodeSpec;
use crate::forces::ContactMaterial;
use crate::math::{get3, set3, Lanes, Quat, Real, V3};
use crate::model::Model;
use crate::tool::ToolDrive;

type L<const W: usize> = Lanes<W>;

/// Per-lane material parameters, masses and contact materials.
#[derive(Clone, Copy)]
pub(crate) struct LaneParams<const W: usize> {
    /// Package membrane (k_mu, k_lambda, k_damp).
    pub(crate) tri: [L<W>; 3],
    /// Package bending (ke, kd).
    pub(crate) edge: [L<W>; 2],
    /// Cup membrane (k_mu, k_lambda, k_damp).
    pub(crate) cup_tri: [L<W>; 3],
    /// Attachment springs (ke, kd).
    pub(crate) spring: [L<W>; 2],
    pub(crate) disc_contact: ContactMaterial<L<W>>,
    pub(crate) disc_ground: ContactMaterial<L<W>>,
    pub(crate) inv_mass_package: L<W>,
    pub(crate) inv_mass_cup: L<W>,
    pub(crate) disc_mass: L<W>,
    /// Principal moments of the disc (body frame).
    pub(crate) disc_inertia: V3<L<W>>,
    /// Gravity along world y.
    pub(crate) gravity: L<W>,
    /// The lane's own supply vacuum (kPa), `None` for the scene's.
    pub(crate) vacuum_kpa: [Option<f32>; W],
}

impl<const W: usize> LaneParams<W> {
    fn zero() -> Self {
        let zero = L::<W>::splat(0.0);
        let zero_contact = ContactMaterial {
            ke: zero,
            kd: zero,
            kf: zero,
            mu: zero,
        };
        LaneParams {
            tri: [zero; 3],
            edge: [zero; 2],
            cup_tri: [zero; 3],
            spring: [zero; 2],
            disc_contact: zero_contact,
            disc_ground: zero_contact,
            inv_mass_package: zero,
            inv_mass_cup: zero,
            disc_mass: zero,
            disc_inertia: V3::zero(),
            gravity: zero,
            vacuum_kpa: [None; W],
        }
    }

    /// Sets lane `l` from `spec`'s parameters and masses.
    pub(crate) fn set_lane(&mut self, l: usize, model: &Model, spec: &EpisodeSpec) {
        let params = &spec.params;
        let c = &model.config.contact;
        self.tri[0].0[l] = params.k_tri_e;
        self.tri[1].0[l] = params.k_tri_a;
        self.tri[2].0[l] = params.k_tri_d;
        self.edge[0].0[l] = params.k_edge_e;
        self.edge[1].0[l] = params.k_edge_d;
        self.cup_tri[0].0[l] = params.k_cup_e;
        self.cup_tri[1].0[l] = params.k_cup_a;
        self.cup_tri[2].0[l] = params.k_cup_d;
        self.spring[0].0[l] = params.k_spr_e;
        self.spring[1].0[l] = params.k_spr_d;
        // Warp averages the model-wide soft contact material with the shape's (reference preset).
        let avg = |model_value: f32, shape: f32| {
            if c.average_disc_with_soft {
                0.5 * (model_value + shape)
            } else {
                shape
            }
        };
        self.disc_contact.ke.0[l] = avg(c.soft_ke, params.k_con_e);
        self.disc_contact.kd.0[l] = avg(c.soft_kd, params.k_con_d);
        self.disc_contact.kf.0[l] = avg(c.soft_kf, params.k_con_f);
        self.disc_contact.mu.0[l] = avg(c.soft_mu, params.mu_con);
        // Rigid contacts average the two shapes' materials (disc and ground).
        self.disc_ground.ke.0[l] = 0.5 * (params.k_con_e + c.ground_ke);
        self.disc_ground.kd.0[l] = 0.5 * (params.k_con_d + c.ground_kd);
        self.disc_ground.kf.0[l] = 0.5 * (params.k_con_f + c.ground_kf);
        self.disc_ground.mu.0[l] = 0.5 * (params.mu_con + c.ground_mu);
        self.inv_mass_package.0[l] = 1.0 / model.package_particle_mass;
        self.inv_mass_cup.0[l] = 1.0 / model.cup_particle_mass;
        let disc = model.disc_mass_with_scale(spec.object_mass_kg, spec.disc_mass_scale);
        self.disc_mass.0[l] = disc.mass;
        set3(&mut self.disc_inertia, l, disc.inertia);
        self.gravity.0[l] = model.config.integrator.gravity_m_s2;
        self.vacuum_kpa[l] = spec.vacuum_kpa;
    }
}

/// The tool of every lane at one instant: position, orientation, velocity (world).
#[derive(Clone, Copy)]
pub(crate) struct ToolLanes<const W: usize> {
    pub(crate) position: V3<L<W>>,
    pub(crate) orientation: Quat<L<W>>,
    pub(crate) velocity: V3<L<W>>,
}

/// What each lane's episode prescribes (set when the episode starts; the tool drive also by
/// commands).
pub(crate) struct LaneSetup<const W: usize> {
    pub(crate) params: LaneParams<W>,
    /// Per particle: its position at the start of the episode (health checks measure from it).
    pub(crate) x0: Vec<V3<L<W>>>,
    /// Per cup particle: its offset from the tool (tool frame, or world with
    /// `cups.offsets_in_tool_frame` off).
    pub(crate) cup_offsets: Vec<V3<L<W>>>,
    /// Per lane: the cups' axis (from the cup face towards the film) in the tool frame.
    pub(crate) cup_axis_local: V3<L<W>>,
    /// Per lane: the disc centre at the start of the episode.
    pub(crate) disc_x0: V3<L<W>>,
    /// Per lane: where the disc is held during the rest (`None`: free), see `Placement::disc_hold`.
    pub(crate) disc_hold: [Option<[f32; 3]>; W],
    /// Per lane: the orientation a held disc is turned to during the rest (`None`: the disc is
    /// free), see `Placement::disc_orientation`.
    pub(crate) disc_turn: [Option<[f32; 4]>; W],
    /// Per lane: what drives the tool.
    pub(crate) tools: Vec<ToolDrive>,
}

impl<const W: usize> LaneSetup<W> {
    /// Zeroed data sized for `model`, the lanes' tools driven by `tools`.
    pub(crate) fn new(model: &Model, tools: Vec<ToolDrive>) -> Self {
        let zero3 = V3::<L<W>>::zero();
        LaneSetup {
            params: LaneParams::zero(),
            x0: vec![zero3; model.num_particles()],
            cup_offsets: vec![zero3; model.num_cup],
            cup_axis_local: zero3,
            disc_x0: zero3,
            disc_hold: [None; W],
            disc_turn: [None; W],
            tools,
        }
    }

    /// Bytes held by the arrays.
    pub(crate) fn bytes(&self) -> usize {
        (self.x0.capacity() + self.cup_offsets.capacity()) * std::mem::size_of::<V3<L<W>>>()
    }

    /// Tool position, orientation and velocity of every lane at its time `t[l]`.
    pub(crate) fn tool_lanes(&self, t: &[f64; W], rest_time: f64) -> ToolLanes<W> {
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
        ToolLanes {
            position: p,
            orientation: q,
            velocity: vel,
        }
    }

    /// The disc centre and velocity at time `t` for lanes whose disc is held during the rest
    /// (`Placement::disc_hold`): a smooth path from the start to the hold point over the first half
    /// of the rest, then still. Other lanes, and every lane after the rest, keep `com`, `v`.
    pub(crate) fn held_disc(
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
    pub(crate) fn held_turn(
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
