//! The full state of one lane, copied out and into any lane of any block (of the same model).

use serde::{Deserialize, Serialize};

use crate::episode::{DiscState, EpisodeSpec};
use crate::math::{get3, set3, Lanes, V3};
use crate::model::Model;
use crate::tool::ToolDrive;

use super::EnvBlock;

type L<const W: usize> = Lanes<W>;

/// Everything that evolves in one lane (the material parameters are derived from the spec).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub(crate) struct LaneSnapshot {
    pub(crate) x: Vec<[f32; 3]>,
    pub(crate) v: Vec<[f32; 3]>,
    pub(crate) x0: Vec<[f32; 3]>,
    pub(crate) contact_point: Vec<[f32; 3]>,
    pub(crate) contact_normal: Vec<[f32; 3]>,
    pub(crate) cup_offsets: Vec<[f32; 3]>,
    /// Per spring: target particle, rest length, sealed (1/0), filtered tension.
    pub(crate) springs: Vec<(u32, f32, f32, f32)>,
    /// Per cup: attached (1/0), sealed lip elements, filtered load.
    pub(crate) cups: Vec<(f32, f32, [f32; 3])>,
    pub(crate) cup_axis_local: [f32; 3],
    pub(crate) disc: DiscState,
    pub(crate) disc_x0: [f32; 3],
    pub(crate) disc_hold: Option<[f32; 3]>,
    /// Absent from snapshots written before discs could be turned during the rest.
    #[serde(default)]
    pub(crate) disc_turn: Option<[f32; 4]>,
    pub(crate) tool: ToolDrive,
    pub(crate) clock: u64,
    pub(crate) active: bool,
}

fn column<const W: usize>(values: &[V3<L<W>>], l: usize) -> Vec<[f32; 3]> {
    values.iter().map(|v| get3(v, l)).collect()
}

fn fill<const W: usize>(values: &mut [V3<L<W>>], l: usize, from: &[[f32; 3]]) {
    for (v, p) in values.iter_mut().zip(from) {
        set3(v, l, *p);
    }
}

impl<const W: usize> EnvBlock<W> {
    /// A copy of lane `l`'s state.
    pub(crate) fn take_lane(&self, l: usize) -> LaneSnapshot {
        let (state, setup) = (&self.state, &self.setup);
        let d = &state.disc;
        let qv = get3(&d.q.v, l);
        LaneSnapshot {
            x: column(&state.x, l),
            v: column(&state.v, l),
            x0: column(&setup.x0, l),
            contact_point: column(&state.contact_point, l),
            contact_normal: column(&state.contact_normal, l),
            cup_offsets: column(&setup.cup_offsets, l),
            springs: state
                .springs
                .iter()
                .map(|s| (s.target[l], s.rest.0[l], s.sealed.0[l], s.tension.0[l]))
                .collect(),
            cups: state
                .cups
                .iter()
                .map(|c| (c.attached.0[l], c.sealed_count.0[l], get3(&c.load, l)))
                .collect(),
            cup_axis_local: get3(&setup.cup_axis_local, l),
            disc: DiscState {
                position: get3(&d.com, l),
                orientation: [qv[0], qv[1], qv[2], d.q.w.0[l]],
                velocity: get3(&d.v, l),
                angular_velocity: get3(&d.w, l),
            },
            disc_x0: get3(&setup.disc_x0, l),
            disc_hold: setup.disc_hold[l],
            disc_turn: setup.disc_turn[l],
            tool: setup.tools[l].clone(),
            clock: state.clock[l],
            active: state.active.0[l] > 0.5,
        }
    }

    /// Puts `snap` (taken from a lane of a block of the same model; sizes checked by the caller)
    /// into every lane holding `env`, with the parameters of `spec`.
    pub(crate) fn restore_env(
        &mut self,
        env: usize,
        model: &Model,
        spec: &EpisodeSpec,
        snap: &LaneSnapshot,
    ) {
        for l in (0..W).filter(|&l| self.envs[l] == env).collect::<Vec<_>>() {
            let (state, setup) = (&mut self.state, &mut self.setup);
            fill(&mut state.x, l, &snap.x);
            fill(&mut state.v, l, &snap.v);
            fill(&mut setup.x0, l, &snap.x0);
            fill(&mut state.contact_point, l, &snap.contact_point);
            fill(&mut state.contact_normal, l, &snap.contact_normal);
            fill(&mut setup.cup_offsets, l, &snap.cup_offsets);
            for (s, &(target, rest, sealed, tension)) in state.springs.iter_mut().zip(&snap.springs)
            {
                s.target[l] = target;
                s.rest.0[l] = rest;
                s.sealed.0[l] = sealed;
                s.tension.0[l] = tension;
            }
            for (c, &(attached, count, load)) in state.cups.iter_mut().zip(&snap.cups) {
                c.attached.0[l] = attached;
                c.sealed_count.0[l] = count;
                set3(&mut c.load, l, load);
            }
            set3(&mut setup.cup_axis_local, l, snap.cup_axis_local);
            let d = &snap.disc;
            set3(&mut state.disc.com, l, d.position);
            set3(
                &mut state.disc.q.v,
                l,
                [d.orientation[0], d.orientation[1], d.orientation[2]],
            );
            state.disc.q.w.0[l] = d.orientation[3];
            set3(&mut state.disc.v, l, d.velocity);
            set3(&mut state.disc.w, l, d.angular_velocity);
            set3(&mut setup.disc_x0, l, snap.disc_x0);
            setup.disc_hold[l] = snap.disc_hold;
            setup.disc_turn[l] = snap.disc_turn;
            setup.tools[l] = snap.tool.clone();
            state.clock[l] = snap.clock;
            state.active.0[l] = if snap.active { 1.0 } else { 0.0 };
            setup.params.set_lane(l, model, spec);
        }
    }
}
