//! The suction seal of every cup (see [`crate::config::SealConfig`] for the model): loading at
//! attach time, filtered loads every substep, and peeling, pull-off and sliding. Its constants
//! and load law are [`crate::constants::SealConstants`].

use glam::{DQuat, DVec3};
use nalgebra::{Matrix3, SymmetricEigen, Vector3};

use crate::constants::StepConstants;
use crate::episode::{CupLoad, NoSealReason, SealEvent, SealEventKind};
use crate::math::{get3, Lanes, Quat, Real, V3};
use crate::model::Model;

use super::EnvBlock;

type L<const W: usize> = Lanes<W>;

impl<const W: usize> EnvBlock<W> {
    /// The cup axis of every lane under tool orientation `tq`.
    fn cup_axes(&self, tq: Quat<L<W>>) -> V3<L<W>> {
        tq.rotate(self.setup.cup_axis_local)
    }

    /// Filters the cup and lip loads of this substep and, with the seal model on, lets go of
    /// the lip elements and cups beyond their limits (from the end of the rest period on: the
    /// rest settles a package built flat, and its transient is not part of a pick). `tq` is the
    /// tool orientation of each lane and `t` its time at the start of the substep.
    pub(super) fn update_seals(
        &mut self,
        model: &Model,
        k: &StepConstants,
        tq: Quat<L<W>>,
        t: &[f64; W],
    ) {
        let seal = &k.seal;
        let alpha = L::<W>::splat(seal.filter);
        let axis = self.cup_axes(tq);
        let half = L::<W>::splat(0.5);
        let active = self.state.active;
        let cup_size = model.cup_size;
        let state = &mut self.state;
        for (c, cup) in state.cups.iter_mut().enumerate() {
            let mut sum = V3::<L<W>>::zero();
            for s in c * cup_size..(c + 1) * cup_size {
                let f = state.spring_force[s];
                let spring = &mut state.springs[s];
                let tension = spring.tension + (f.dot(axis) - spring.tension) * alpha;
                spring.tension = L::select_lt(half, active, tension, spring.tension);
                sum += f;
            }
            let load = cup.load + (sum - cup.load) * alpha;
            cup.load = V3::select_lt(half, active, load, cup.load);
        }
        if !seal.enabled {
            return;
        }
        for l in 0..W {
            // The rest period settles a package built flat: its transient is not a pick.
            if self.state.active.0[l] < 0.5 || t[l] < k.rest_time {
                continue;
            }
            let lane_axis = get3(&axis, l);
            let seal = k.seal.with_vacuum(self.setup.params.vacuum_kpa[l]);
            let mut lost_any = false;
            for c in 0..self.state.cups.len() {
                if self.state.cups[c].attached.0[l] < 0.5 {
                    continue;
                }
                // Peeling: lip elements pulled beyond their strength let go one by one.
                let mut sealed = self.state.cups[c].sealed_count.0[l];
                for s in c * cup_size..(c + 1) * cup_size {
                    let spring = &mut self.state.springs[s];
                    if spring.sealed.0[l] > 0.5 && spring.tension.0[l] > seal.element_strength {
                        spring.sealed.0[l] = 0.0;
                        sealed -= 1.0;
                    }
                }
                self.state.cups[c].sealed_count.0[l] = sealed;
                let fraction = sealed / cup_size as f32;
                let force = get3(&self.state.cups[c].load, l);
                let load = seal.cup_load(true, fraction, force, lane_axis);
                let failure = if fraction < seal.min_sealed_fraction {
                    Some(SealEventKind::Peeled)
                } else if load.normal_n > load.capacity_n {
                    Some(SealEventKind::PulledOff)
                } else if load.shear_n > seal.friction * (load.capacity_n - load.normal_n) {
                    Some(SealEventKind::Slid)
                } else {
                    None
                };
                if let Some(kind) = failure {
                    self.detach_cup(l, c, cup_size);
                    lost_any = true;
                    self.push_seal_event(l, Some(c), kind, t[l], load);
                }
            }
            if lost_any && self.attached_cups(l) == 0 {
                self.push_seal_event(l, None, SealEventKind::Dropped, t[l], CupLoad::default());
            }
        }
    }

    fn push_seal_event(
        &mut self,
        l: usize,
        cup: Option<usize>,
        kind: SealEventKind,
        time: f64,
        load: CupLoad,
    ) {
        if self.real[l] {
            self.seal_events.push(SealEvent {
                env: self.envs[l],
                cup,
                kind,
                time,
                load,
            });
        }
    }

    fn detach_cup(&mut self, l: usize, c: usize, cup_size: usize) {
        let cup = &mut self.state.cups[c];
        cup.attached.0[l] = 0.0;
        cup.sealed_count.0[l] = 0.0;
        for spring in &mut self.state.springs[c * cup_size..(c + 1) * cup_size] {
            spring.sealed.0[l] = 0.0;
        }
    }

    /// Cups of lane `l` still holding the film.
    pub(crate) fn attached_cups(&self, l: usize) -> u32 {
        self.state
            .cups
            .iter()
            .filter(|c| c.attached.0[l] > 0.5)
            .count() as u32
    }

    /// Attaches (seals) the cups of lane `l` to the film as it is now: each cup particle's spring
    /// goes to its nearest upper-sheet particle with its current length as rest length (or the
    /// shortest one, `cups.common_rest_length`), loads start at zero, and with the seal model on
    /// a cup whose film is too far, tilted or folded does not seal (reported at time `time`).
    /// `tool_orientation` is the tool's orientation now.
    pub(crate) fn attach_cups_lane(
        &mut self,
        l: usize,
        model: &Model,
        time: f64,
        tool_orientation: [f64; 4],
    ) {
        let cup_start = model.cup_start();
        let upper = model.layer_size..model.num_package;
        let mut lengths = Vec::with_capacity(model.num_cup);
        for k in 0..model.num_cup {
            let c = get3(&self.state.x[cup_start + k], l);
            let (mut best, mut best_d2) = (upper.start, f32::INFINITY);
            for j in upper.clone() {
                let p = get3(&self.state.x[j], l);
                let d2 = (c[0] - p[0]).powi(2) + (c[1] - p[1]).powi(2) + (c[2] - p[2]).powi(2);
                if d2 < best_d2 {
                    best = j;
                    best_d2 = d2;
                }
            }
            self.state.springs[k].target[l] = best as u32;
            lengths.push(best_d2.sqrt());
        }
        let common = lengths.iter().copied().fold(f32::INFINITY, f32::min);
        for (k, len) in lengths.iter().enumerate() {
            let spring = &mut self.state.springs[k];
            spring.rest.0[l] = if model.config.cups.common_rest_length {
                common
            } else {
                *len
            };
            spring.sealed.0[l] = 1.0;
            spring.tension.0[l] = 0.0;
        }
        let cup_size = model.cup_size;
        for c in 0..model.num_cups() {
            let cup = &mut self.state.cups[c];
            cup.attached.0[l] = 1.0;
            cup.sealed_count.0[l] = cup_size as f32;
            for comp in [&mut cup.load.x, &mut cup.load.y, &mut cup.load.z] {
                comp.0[l] = 0.0;
            }
        }
        if !model.config.seal.enabled {
            return;
        }
        let local = get3(&self.setup.cup_axis_local, l).map(f64::from);
        let axis = DQuat::from_array(tool_orientation) * DVec3::from(local);
        let axis = Vector3::new(axis.x, axis.y, axis.z);
        let mut any = false;
        for c in 0..model.num_cups() {
            match self.loading_check(l, model, c, axis) {
                None => any = true,
                Some(reason) => {
                    self.detach_cup(l, c, cup_size);
                    let load = CupLoad::default();
                    self.push_seal_event(l, Some(c), SealEventKind::NotSealed(reason), time, load);
                }
            }
        }
        if !any {
            self.push_seal_event(l, None, SealEventKind::Dropped, time, CupLoad::default());
        }
    }

    /// Why cup `c` of lane `l` cannot seal on the film as it is now, if it cannot: the film's
    /// plane under the lip (least squares through the particles its springs reach) must be within
    /// `max_gap` of every lip particle, tilted at most `max_tilt_deg` from the cup face, and the
    /// film may deviate at most `max_fold` from that plane.
    fn loading_check(
        &self,
        l: usize,
        model: &Model,
        c: usize,
        axis: Vector3<f64>,
    ) -> Option<NoSealReason> {
        let seal = &model.config.seal;
        let cup_size = model.cup_size;
        let cup_start = model.cup_start() + c * cup_size;
        let mut targets: Vec<usize> = (c * cup_size..(c + 1) * cup_size)
            .map(|s| self.state.springs[s].target[l] as usize)
            .collect();
        targets.sort_unstable();
        targets.dedup();
        let point = |i: usize| {
            let p = get3(&self.state.x[i], l);
            Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64)
        };
        let centre = targets.iter().map(|&i| point(i)).sum::<Vector3<f64>>() / targets.len() as f64;
        let mut cov = Matrix3::<f64>::zeros();
        for &i in &targets {
            let d = point(i) - centre;
            cov += d * d.transpose();
        }
        // The plane's normal is the direction of least spread (fewer than 3 distinct points
        // leave it undetermined: then the cup face's own axis is used).
        let normal = if targets.len() >= 3 {
            let eig = SymmetricEigen::new(cov);
            let k = eig.eigenvalues.imin();
            eig.eigenvectors.column(k).into_owned()
        } else {
            axis
        };
        let fold = targets
            .iter()
            .map(|&i| (point(i) - centre).dot(&normal).abs())
            .fold(0.0, f64::max);
        let tilt = normal.dot(&axis).abs().min(1.0).acos().to_degrees();
        let gap = (cup_start..cup_start + cup_size)
            .map(|i| (point(i) - centre).dot(&normal).abs())
            .fold(0.0, f64::max);
        if gap > seal.max_gap_m as f64 {
            Some(NoSealReason::Gap(gap as f32))
        } else if tilt > seal.max_tilt_deg as f64 {
            Some(NoSealReason::Tilt(tilt as f32))
        } else if fold > seal.max_fold_m as f64 {
            Some(NoSealReason::Fold(fold as f32))
        } else {
            None
        }
    }

    /// The filtered force of every cup of lane `l` (N, world), written to `out` (one per cup).
    pub(crate) fn read_cup_forces(&self, l: usize, out: &mut [[f32; 3]]) {
        for (cup, slot) in self.state.cups.iter().zip(out.iter_mut()) {
            *slot = get3(&cup.load, l);
        }
    }

    /// The loads of every cup of lane `l`, written to `out` (one entry per cup).
    pub(crate) fn read_cup_loads(&self, l: usize, k: &StepConstants, out: &mut [CupLoad]) {
        let tool = self.tool_state(l, k, 0.0);
        let q = tool.orientation;
        let q = Quat {
            v: V3::new(q[0] as f32, q[1] as f32, q[2] as f32),
            w: q[3] as f32,
        };
        let local = &self.setup.cup_axis_local;
        let axis = q.rotate(V3::new(local.x.0[l], local.y.0[l], local.z.0[l]));
        let axis = [axis.x, axis.y, axis.z];
        let cup_size = self.state.springs.len() / self.state.cups.len();
        let seal = k.seal.with_vacuum(self.setup.params.vacuum_kpa[l]);
        for (cup, slot) in self.state.cups.iter().zip(out.iter_mut()) {
            let attached = cup.attached.0[l] > 0.5;
            let fraction = cup.sealed_count.0[l] / cup_size as f32;
            *slot = seal.cup_load(attached, fraction, get3(&cup.load, l), axis);
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::*;
    use crate::math::Lanes;
    use crate::{EpisodeSpec, Placement, SceneConfig, ToolTrajectory};

    /// A block of the physical scene with the seal on (10 kPa), one lane per vacuum of
    /// `vacuums` (`None`: the scene's), every clock past the rest.
    fn block_of<const W: usize>(vacuums: [Option<f32>; W]) -> (Model, EnvBlock<W>) {
        let mut c = SceneConfig::preset("physical").unwrap();
        c.package.grid = [6, 7];
        c.seal.enabled = true;
        c.seal.vacuum_kpa = 10.0;
        c.seal.lip_radius_m = 0.02;
        c.seal.friction = 0.5;
        c.seal.lip_strength_ratio = 3.0;
        let model = Model::new(&c).unwrap();
        let cup = [0.15, 0.51, 0.127];
        let specs: Vec<EpisodeSpec> = vacuums
            .iter()
            .map(|&vacuum_kpa| EpisodeSpec {
                placement: Placement::new([0.0, 0.5, 0.0], cup, [0.15, 0.5, 0.127]),
                params: c.params,
                object_mass_kg: 0.5,
                disc_mass_scale: None,
                vacuum_kpa,
                trajectory: Arc::new(ToolTrajectory::hold(
                    cup.map(f64::from),
                    [0.0, 0.0, 0.0, 1.0],
                )),
            })
            .collect();
        let envs: [usize; W] = std::array::from_fn(|l| l);
        let mut b = EnvBlock::<W>::new(&model, &specs, envs, [true; W]);
        let past_rest = 2 * (c.cups.rest_time_s as f64 / c.dt() as f64) as u64;
        b.state.clock = [past_rest; W];
        (model, b)
    }

    #[test]
    fn each_lane_holds_with_its_own_vacuum() {
        // The scene's 10 kPa gives V = 12.566 N per cup; lane 0 has half of it, lane 1 twice.
        let (model, mut b) = block_of([Some(5.0), Some(20.0)]);
        let k = StepConstants::new(&model);
        let v = 10e3 * std::f32::consts::PI * 0.02f32.powi(2);
        let n = model.cup_size as f32;
        let level = Quat {
            v: V3::zero(),
            w: Lanes([1.0; 2]),
        };
        // The same pull on both lanes: 0.75 V straight off every cup.
        for _ in 0..(0.1 / k.dt64) as usize {
            for f in b.state.spring_force.iter_mut() {
                *f = V3::new(Lanes([0.0; 2]), Lanes([-0.75 * v / n; 2]), Lanes([0.0; 2]));
            }
            let t = b.state.clock.map(|c| c as f64 * k.dt64);
            b.update_seals(&model, &k, level, &t);
        }
        let failed: Vec<_> = b.seal_events.iter().map(|e| (e.env, e.kind)).collect();
        assert!(
            !failed.is_empty()
                && failed
                    .iter()
                    .all(|&(env, kind)| env == 0 && kind != SealEventKind::Slid),
            "{failed:?}"
        );
        assert_eq!(b.attached_cups(0), 0);
        assert_eq!(b.attached_cups(1), 4);
        let mut loads = [CupLoad::default(); 4];
        b.read_cup_loads(1, &k, &mut loads);
        for load in loads {
            assert!((load.capacity_n - 2.0 * v).abs() < 1e-4 * v, "{load:?}");
            assert!((load.utilisation - 0.375).abs() < 1e-3, "{load:?}");
        }
    }

    /// A one-lane block of the physical scene with the seal on, its clock past the rest.
    fn block() -> (Model, EnvBlock<1>) {
        let mut c = SceneConfig::preset("physical").unwrap();
        c.package.grid = [6, 7];
        c.seal.enabled = true;
        c.seal.vacuum_kpa = 10.0;
        c.seal.lip_radius_m = 0.02;
        c.seal.friction = 0.5;
        c.seal.lip_strength_ratio = 3.0;
        let model = Model::new(&c).unwrap();
        let cup = [0.15, 0.51, 0.127];
        let spec = EpisodeSpec {
            placement: Placement::new([0.0, 0.5, 0.0], cup, [0.15, 0.5, 0.127]),
            params: c.params,
            object_mass_kg: 0.5,
            disc_mass_scale: None,
            vacuum_kpa: None,
            trajectory: Arc::new(ToolTrajectory::hold(
                cup.map(f64::from),
                [0.0, 0.0, 0.0, 1.0],
            )),
        };
        let mut b = EnvBlock::<1>::new(&model, &[spec], [0], [true]);
        b.state.clock[0] = 2 * (c.cups.rest_time_s as f64 / c.dt() as f64) as u64;
        (model, b)
    }

    /// Applies `per_spring(s)` (force of the film on each cup particle) for 0.1 s of substeps
    /// (ten filter time constants).
    fn load(model: &Model, b: &mut EnvBlock<1>, per_spring: impl Fn(usize) -> [f32; 3]) {
        let k = StepConstants::new(model);
        let level = Quat {
            v: V3::zero(),
            w: Lanes([1.0]),
        };
        for _ in 0..(0.1 / k.dt64) as usize {
            for (s, f) in b.state.spring_force.iter_mut().enumerate() {
                let g = per_spring(s);
                *f = V3::new(Lanes([g[0]]), Lanes([g[1]]), Lanes([g[2]]));
            }
            let t = [b.state.clock[0] as f64 * k.dt64];
            b.update_seals(model, &k, level, &t);
        }
    }

    #[test]
    fn seal_law_matches_the_hand_computation() {
        let (model, mut b) = block();
        let n = model.cup_size as f32;
        // V = dp * pi * r^2 = 10 kPa * pi * (0.02 m)^2 = 12.566 N per cup; mu = 0.5; a lip
        // element peels beyond 3 V / 24.
        let v = 10e3 * std::f32::consts::PI * 0.02f32.powi(2);
        let cup_of = |s: usize| s / model.cup_size;
        // Cup 0 pulled straight off (the cup axis is world -y: pulling down is tension) with
        // 0.95 V, cup 1 at 0.5 V normal and 0.2 V shear (friction limit 0.5 (V - 0.5 V) = 0.25 V),
        // cup 2 at 0.5 V with one lip element carrying 0.2 V (> 3 V / 24 = 0.125 V).
        let first = |s: usize| match cup_of(s) {
            0 => [0.0, -0.95 * v / n, 0.0],
            1 => [0.2 * v / n, -0.5 * v / n, 0.0],
            2 if s % model.cup_size == 5 => [0.0, -0.2 * v, 0.0],
            2 => [0.0, -0.3 * v / (n - 1.0), 0.0],
            _ => [0.0; 3],
        };
        load(&model, &mut b, first);
        assert!(b.seal_events.is_empty(), "{:?}", b.seal_events);
        let k = StepConstants::new(&model);
        let mut loads = [CupLoad::default(); 4];
        b.read_cup_loads(0, &k, &mut loads);
        assert!((loads[0].utilisation - 0.95).abs() < 1e-3, "{loads:?}");
        assert!(
            (loads[1].utilisation - 0.2 / 0.25).abs() < 1e-3,
            "{loads:?}"
        );
        // The peeled element took 1/24 of cup 2's area with it.
        assert_eq!(loads[2].sealed_fraction, 23.0 / 24.0);
        assert!((loads[2].capacity_n - v * 23.0 / 24.0).abs() < 1e-4);
        assert!(loads[2].attached && loads[3].attached);
        // Now 1.05 V on cup 0 and 0.3 V shear on cup 1: both let go, at their limits.
        let second = |s: usize| match cup_of(s) {
            0 => [0.0, -1.05 * v / n, 0.0],
            1 => [0.3 * v / n, -0.5 * v / n, 0.0],
            _ => first(s),
        };
        load(&model, &mut b, second);
        let kinds: Vec<_> = b.seal_events.iter().map(|e| (e.cup, e.kind)).collect();
        assert_eq!(
            kinds,
            [
                (Some(0), SealEventKind::PulledOff),
                (Some(1), SealEventKind::Slid)
            ],
            "{:?}",
            b.seal_events
        );
        let pulled = b.seal_events[0].load;
        assert!(
            pulled.normal_n > v && pulled.normal_n < 1.001 * v,
            "{pulled:?}"
        );
        let slid = b.seal_events[1].load;
        assert!(
            slid.shear_n > 0.25 * v && slid.shear_n < 0.2505 * v,
            "{slid:?}"
        );
        // A cup that let go transmits nothing from then on and reads as detached.
        assert_eq!(b.state.springs[0].sealed.0[0], 0.0);
        b.read_cup_loads(0, &k, &mut loads);
        assert!(!loads[0].attached && loads[0].utilisation == 0.0);
        assert_eq!(b.attached_cups(0), 2);
    }
}
