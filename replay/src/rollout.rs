//! Batched rollouts of recorded trajectories.
//!
//! One batched rollout evaluates a whole candidate batch on every trajectory: environment
//! `c · T + t` simulates candidate `c` on trajectory `t`, all in lockstep, so the simulator's lanes
//! and threads are filled and the result is deterministic (each environment is bit-identical
//! whatever the batch).
//!
//! Simulated points for the loss: the recorded row-0 markers embedded in the upper sheet, and any
//! lower-layer markers the dataset places in the lower sheet (barycentric, nearest triangle at
//! rest), evaluated on the deformed sheets; not the study's 42 nominal grid vertices, which sit
//! up to 1.5 cm off the real markers (§12, item 5). Recorded frame
//! `k` (trajectory time `t_k`) is compared with the state at the substep nearest to
//! `rest + t_k` ([`FrameClock`]); a [`Schedule`] can add stops between the frames (pictures).

use std::sync::Arc;

use rlpkg_sim::config::PARAM_NAMES;
use rlpkg_sim::{
    DiscState, HealthEvent, Model, NoSealReason, Params, SceneConfig, SealEventKind, Sheet,
    Simulator, SurfaceEmbedding,
};

use crate::error::ReplayError;
use crate::loss::{FrameComparison, LossWeights, TrajectoryLoss};
use crate::target::Target;

/// The name of the disc's mass scale as a calibrated parameter (the scene's `disc.mass_scale`).
pub const DISC_MASS_SCALE: &str = "disc_mass_scale";

/// Simulator parameter names that can be set by name: the material parameters of
/// [`rlpkg_sim::config::PARAM_NAMES`] (the paper's names and Warp's friction `k_con_f`), then
/// [`DISC_MASS_SCALE`] (simulated disc kg per recorded kg).
pub const PARAMETER_NAMES: [&str; PARAM_NAMES.len() + 1] = {
    let mut names = [DISC_MASS_SCALE; PARAM_NAMES.len() + 1];
    let mut k = 0;
    while k < PARAM_NAMES.len() {
        names[k] = PARAM_NAMES[k];
        k += 1;
    }
    names
};

/// What one calibration candidate sets in every environment it is simulated in: the material
/// parameters and the disc's mass scale (simulated disc kg per recorded kg, the scene's
/// `disc.mass_scale`). The reference's package particles weigh far more than the scaled disc, so
/// how deep the disc sags the film is a quantity worth fitting.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// Material parameters.
    pub params: Params,
    /// Simulated disc mass per recorded kg (the scene's `disc.mass_scale`).
    pub disc_mass_scale: f32,
}

impl Candidate {
    /// The scene's own parameters and disc mass scale.
    pub fn of_scene(scene: &SceneConfig) -> Self {
        Self {
            params: scene.params,
            disc_mass_scale: scene.disc.mass_scale,
        }
    }

    /// Writes this candidate's values into `scene`.
    pub fn apply_to(&self, scene: &mut SceneConfig) {
        scene.params = self.params;
        scene.disc.mass_scale = self.disc_mass_scale;
    }
}

/// The slot of the parameter called `name` (see [`PARAMETER_NAMES`]).
fn slot<'a>(candidate: &'a mut Candidate, name: &str) -> Result<&'a mut f32, ReplayError> {
    if name == DISC_MASS_SCALE {
        return Ok(&mut candidate.disc_mass_scale);
    }
    candidate
        .params
        .get_mut(name)
        .ok_or_else(|| ReplayError::UnknownParameter(name.to_string()))
}

/// Sets the parameter called `name` (see [`PARAMETER_NAMES`]).
pub fn set_param(candidate: &mut Candidate, name: &str, value: f64) -> Result<(), ReplayError> {
    *slot(candidate, name)? = value as f32;
    Ok(())
}

/// The value of the parameter called `name`.
pub fn get_param(candidate: &Candidate, name: &str) -> Result<f64, ReplayError> {
    let mut copy = *candidate;
    Ok(*slot(&mut copy, name)? as f64)
}

/// What an [`Observer`] sees at each compared frame of each environment.
pub struct FrameObservation<'a> {
    /// Candidate index.
    pub candidate: usize,
    /// Target (trajectory) index.
    pub target: usize,
    /// Compared frame index.
    pub frame: usize,
    /// Simulated marker sites (the embedded row-0 markers).
    pub simulated_points: &'a [[f64; 3]],
    /// The disc.
    pub disc: &'a DiscState,
    /// The simulator (for full particle positions, cups...).
    pub simulator: &'a Simulator,
    /// Environment index in the simulator.
    pub env: usize,
}

/// Hooks into a rollout: per-frame observations (pictures, per-marker errors) and progress.
pub trait Observer {
    /// Called once with the simulator at rest, before the first substep.
    fn start(&mut self, _simulator: &Simulator) {}
    /// Called at every extra stop of the [`Schedule`] while an environment is live, before the
    /// frames compared at the same substep.
    fn instant(&mut self, _substep: u64, _simulator: &Simulator) {}
    /// Called at every compared frame of every live environment.
    fn frame(&mut self, _observation: &FrameObservation) {}
    /// Called after every stepping chunk with simulated substeps done and planned.
    fn progress(&mut self, _done: u64, _total: u64) {}
    /// Asked after every stepping chunk: `true` ends the rollout with [`ReplayError::Stopped`]
    /// (e.g. the user pressed Ctrl-C).
    fn stop(&mut self) -> bool {
        false
    }
    /// Called once with the simulator where the rollout ended (every frame compared, or every
    /// environment diverged); not when the rollout was stopped.
    fn finish(&mut self, _simulator: &Simulator) {}
}

impl Observer for () {}

/// How a recorded time maps to the substep it is compared at, counted from the start of the rest
/// period: the nearest substep to `rest + t`, computed one of two ways that can differ by one
/// substep when `rest + t` falls half-way between two substeps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum FrameClock {
    /// `(rest + t) / dt` with the simulator's single-precision substep length `dt`: the
    /// calibration's and the evaluations' clock.
    #[default]
    SubstepLength,
    /// `(rest + t) · rate` with the scene's substep rate in double precision: `rlpkg simulate`'s
    /// clock.
    SubstepRate,
}

impl FrameClock {
    /// The substep at trajectory time `t` (s; negative during the rest period) in `scene`.
    pub fn substep_at(self, scene: &SceneConfig, t: f64) -> u64 {
        let rest = f64::from(scene.cups.rest_time_s);
        let substeps = match self {
            Self::SubstepLength => (rest + t) / f64::from(scene.dt()),
            Self::SubstepRate => (rest + t) * scene.integrator.substep_rate_hz,
        };
        substeps.round().max(0.0) as u64
    }
}

/// Substeps between two looks at [`Observer::stop`] within a long stretch of simulation: a
/// small fraction of a second of work even for large batches on fine grids.
const STOP_CHECK_SUBSTEPS: u64 = 256;

/// When a rollout stops: the clock of the compared frames and extra stops between them.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Schedule {
    /// How the compared frames' times map to substeps.
    pub clock: FrameClock,
    /// Substeps (from the start of the rest period) at which [`Observer::instant`] is called, e.g.
    /// pictures during the rest period; the simulator steps in chunks between every stop.
    pub extra_stops: Vec<u64>,
}

/// The result of one environment of a rollout.
#[derive(Debug, Clone)]
pub struct RolloutOutcome {
    /// Per-frame losses (frames after a divergence are missing).
    pub loss: TrajectoryLoss,
    /// The health event that froze the environment, if it diverged.
    pub diverged: Option<HealthEvent>,
    /// The first cup whose seal failed (did not seal, peeled, pulled off or slid), if any.
    pub seal_failure: Option<SealFailure>,
}

/// The first cup of an environment whose suction seal failed, from the simulator's seal events.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SealFailure {
    /// Cup index (the scene's `cups.angles_deg` order).
    pub cup: usize,
    /// How it failed.
    pub kind: SealEventKind,
    /// Recording time (s): the environment's time minus the scene's rest period.
    pub t: f64,
}

impl SealFailure {
    /// The failure mode in words: `not sealed (gap 25.0 mm)`, `peeled`, `pulled off`, `slid`.
    pub fn mode(&self) -> String {
        seal_mode(&self.kind)
    }
}

/// A seal event kind in words (see [`SealFailure::mode`]).
pub fn seal_mode(kind: &SealEventKind) -> String {
    match kind {
        SealEventKind::NotSealed(NoSealReason::Gap(m)) => {
            format!("not sealed: gap {:.1} mm", 1e3 * m)
        }
        SealEventKind::NotSealed(NoSealReason::Tilt(deg)) => {
            format!("not sealed: tilt {deg:.1} deg")
        }
        SealEventKind::NotSealed(NoSealReason::Fold(m)) => {
            format!("not sealed: fold {:.1} mm", 1e3 * m)
        }
        SealEventKind::Peeled => "peeled".to_string(),
        SealEventKind::PulledOff => "pulled off".to_string(),
        SealEventKind::Slid => "slid".to_string(),
        SealEventKind::Dropped => "dropped".to_string(),
    }
}

/// Simulates every candidate on every target in one batch; returns outcomes `[candidate][target]`.
///
/// Environments are laid out target-major with targets sorted by length, so each block of lanes
/// holds candidates of trajectories of similar length; an environment is retired once its last
/// frame is compared, and a block of finished environments costs nothing. The results do not
/// depend on this layout (each environment is bit-identical in any batch).
pub fn rollout(
    model: &Arc<Model>,
    targets: &[Target],
    candidates: &[Candidate],
    observer: &mut dyn Observer,
) -> Result<Vec<Vec<RolloutOutcome>>, ReplayError> {
    rollout_scheduled(model, targets, candidates, &Schedule::default(), observer)
}

/// As [`rollout`], stopping as `schedule` says.
pub fn rollout_scheduled(
    model: &Arc<Model>,
    targets: &[Target],
    candidates: &[Candidate],
    schedule: &Schedule,
    observer: &mut dyn Observer,
) -> Result<Vec<Vec<RolloutOutcome>>, ReplayError> {
    let n_targets = targets.len();
    let n_candidates = candidates.len();
    let mut by_length: Vec<usize> = (0..n_targets).collect();
    by_length.sort_by(|&a, &b| targets[a].duration().total_cmp(&targets[b].duration()));
    // env_of[t][c]: the environment simulating candidate c on target t.
    let mut env_of = vec![vec![0usize; n_candidates]; n_targets];
    let mut slot_of_env = Vec::with_capacity(n_targets * n_candidates);
    let mut specs = Vec::with_capacity(n_targets * n_candidates);
    for &t in &by_length {
        for (c, candidate) in candidates.iter().enumerate() {
            env_of[t][c] = specs.len();
            slot_of_env.push((c, t));
            specs.push(targets[t].episode_spec(candidate.params, Some(candidate.disc_mass_scale)));
        }
    }
    let mut sim = Simulator::new(model.clone(), specs)?;
    // Placement depends on the target only: embed once per target.
    let embeddings: Vec<SurfaceEmbedding> = (0..n_targets)
        .map(|t| {
            let env = env_of[t][0];
            sim.embed_in_sheet(env, Sheet::Upper, &targets[t].initial_markers)
                .chain(sim.embed_in_sheet(env, Sheet::Lower, &targets[t].lower_markers))
        })
        .collect();
    // Substep of each compared frame, per target.
    let frame_substeps: Vec<Vec<u64>> = targets
        .iter()
        .map(|t| {
            t.times
                .iter()
                .map(|&tk| schedule.clock.substep_at(&model.config, tk))
                .collect()
        })
        .collect();
    let mut extra_stops = schedule.extra_stops.clone();
    extra_stops.sort_unstable();
    extra_stops.dedup();
    let mut checkpoints: Vec<u64> = frame_substeps.iter().flatten().copied().collect();
    checkpoints.extend(&extra_stops);
    checkpoints.sort_unstable();
    checkpoints.dedup();
    let total = checkpoints.last().copied().unwrap_or(0);

    let mut outcomes: Vec<Vec<RolloutOutcome>> = (0..n_candidates)
        .map(|_| {
            targets
                .iter()
                .map(|t| RolloutOutcome {
                    loss: TrajectoryLoss::new(t.id.clone()),
                    diverged: None,
                    seal_failure: None,
                })
                .collect()
        })
        .collect();
    let mut next_frame = vec![0usize; n_targets];
    let mut next_extra_stop = 0;
    observer.start(&sim);
    for &substep in &checkpoints {
        // In chunks, so that a stop request is seen soon even when a frame (or the rest period)
        // spans millions of substeps; stepping in pieces gives the same state as in one go.
        while sim.substep() < substep {
            sim.step((substep - sim.substep()).min(STOP_CHECK_SUBSTEPS));
            if sim.substep() < substep && observer.stop() {
                return Err(ReplayError::Stopped);
            }
        }
        if extra_stops.get(next_extra_stop) == Some(&substep) {
            next_extra_stop += 1;
            if (0..sim.num_envs()).any(|env| !sim.is_frozen(env)) {
                observer.instant(substep, &sim);
            }
        }
        // Frames closer together than one substep share it: all of them are compared there.
        for (t, target) in targets.iter().enumerate() {
            while let Some(&at) = frame_substeps[t].get(next_frame[t]) {
                if at != substep {
                    break;
                }
                let k = next_frame[t];
                next_frame[t] += 1;
                for (c, per_target) in outcomes.iter_mut().enumerate() {
                    let env = env_of[t][c];
                    if sim.is_frozen(env) {
                        continue;
                    }
                    let points: Vec<[f64; 3]> = sim
                        .surface_points(env, &embeddings[t])
                        .iter()
                        .map(|p| p.map(|v| v as f64))
                        .collect();
                    let disc = sim.disc(env);
                    let disc_position = disc.position.map(|v| v as f64);
                    per_target[t].loss.push_frame(&FrameComparison {
                        frame: k,
                        simulated_points: &points,
                        markers: &target.markers[k],
                        marker_sites: &target.marker_sites[k],
                        simulated_object: &disc_position,
                        recorded_object: &target.object[k],
                        phase: target.phases[k],
                    });
                    observer.frame(&FrameObservation {
                        candidate: c,
                        target: t,
                        frame: k,
                        simulated_points: &points,
                        disc: &disc,
                        simulator: &sim,
                        env,
                    });
                    if next_frame[t] == frame_substeps[t].len() {
                        sim.retire(env)?;
                    }
                }
            }
        }
        observer.progress(substep, total);
        if observer.stop() {
            return Err(ReplayError::Stopped);
        }
        if (0..sim.num_envs()).all(|env| sim.is_frozen(env)) {
            break; // every environment finished or diverged
        }
    }
    for event in sim.health_events() {
        let (c, t) = slot_of_env[event.env];
        outcomes[c][t].diverged.get_or_insert(*event);
    }
    let rest = f64::from(model.config.cups.rest_time_s);
    for event in sim.seal_events() {
        let Some(cup) = event.cup else {
            continue; // a drop follows the failure of the last cup
        };
        let (c, t) = slot_of_env[event.env];
        let failure = SealFailure {
            cup,
            kind: event.kind,
            t: event.time - rest,
        };
        let first = &mut outcomes[c][t].seal_failure;
        if first.is_none_or(|earlier| failure.t < earlier.t) {
            *first = Some(failure);
        }
    }
    observer.finish(&sim);
    Ok(outcomes)
}

/// The mean weighted loss of one candidate over its trajectories; NaN if any of them diverged.
pub fn mean_loss(outcomes: &[RolloutOutcome], weights: &LossWeights) -> f64 {
    if outcomes.iter().any(|o| o.diverged.is_some()) {
        return f64::NAN;
    }
    outcomes.iter().map(|o| o.loss.total(weights)).sum::<f64>() / outcomes.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::target::load_scene;

    #[test]
    fn parameters_by_name_round_trip() {
        let mut p = Candidate::of_scene(&SceneConfig::preset("reference").unwrap());
        for (i, name) in PARAMETER_NAMES.iter().enumerate() {
            set_param(&mut p, name, 1.5 + i as f64).unwrap();
        }
        for (i, name) in PARAMETER_NAMES.iter().enumerate() {
            assert_eq!(get_param(&p, name).unwrap(), 1.5 + i as f64);
        }
        assert!(set_param(&mut p, "k_foo", 1.0).is_err());
        assert!(get_param(&p, "k_foo").is_err());
    }

    /// A real recorded trajectory of the repository (tool motion and placement), first frames only.
    use crate::test_support::recorded;

    #[test]
    fn batched_ragged_rollout_matches_single_rollouts() {
        // Two trajectories of different lengths x two candidates, one with a held disc: the batch
        // (target-major layout, finished environments retired) must give each pair's result.
        let mut scene = load_scene("reference", Some(0), None).unwrap();
        scene.cups.rest_time_s = 0.1;
        // The disc slips through the 6 x 7 sheet; these tests are about the batching and the fit.
        scene.health.object_outside = false;
        let model = Arc::new(Model::new(&scene).unwrap());
        let targets = vec![
            Target::new(&recorded("HHLHL"), Some(0.15), true).unwrap(),
            Target::new(&recorded("HHHHH"), Some(0.05), false).unwrap(),
        ];
        let base = Candidate::of_scene(&scene);
        let mut stiff = base;
        stiff.params.k_tri_e *= 3.0;
        let candidates = [base, stiff];
        let batch = rollout(&model, &targets, &candidates, &mut ()).unwrap();
        for (c, candidate) in candidates.iter().enumerate() {
            for (t, target) in targets.iter().enumerate() {
                let alone =
                    rollout(&model, std::slice::from_ref(target), &[*candidate], &mut ()).unwrap();
                let (a, b) = (&alone[0][0].loss, &batch[c][t].loss);
                assert_eq!(a.frames.len(), target.times.len());
                assert_eq!(a.frames, b.frames, "candidate {c}, target {t}");
            }
        }
        // The two candidates really differ.
        assert_ne!(
            batch[0][0].loss.mean_chamfer(),
            batch[1][0].loss.mean_chamfer()
        );
    }

    #[test]
    fn frames_closer_together_than_a_substep_are_all_compared() {
        // The recordings have ~240 frames per second; at 100 substeps per second several frames
        // fall on one substep, and each of them must still be compared.
        let root = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../configs/scenes/physical-soft-film.toml"
        );
        let mut scene = load_scene(root, Some(0), Some(0.01)).unwrap();
        scene.cups.rest_time_s = 0.1;
        scene.health.object_outside = false;
        let model = Arc::new(Model::new(&scene).unwrap());
        let target = Target::new(&recorded("HHLHL"), Some(0.3), false).unwrap();
        let frame_interval = (target.times[1] - target.times[0]).abs();
        assert!(frame_interval < 0.01, "frames {frame_interval} s apart");
        let candidate = Candidate::of_scene(&scene);
        let out = rollout(&model, std::slice::from_ref(&target), &[candidate], &mut ()).unwrap();
        assert!(out[0][0].diverged.is_none());
        assert_eq!(out[0][0].loss.frames.len(), target.times.len());
    }

    #[test]
    fn lower_layer_markers_are_sites_on_the_lower_sheet() {
        /// The simulated sites of the first compared frame.
        struct FirstSites(Vec<[f64; 3]>);
        impl Observer for FirstSites {
            fn frame(&mut self, observation: &FrameObservation) {
                if self.0.is_empty() {
                    self.0 = observation.simulated_points.to_vec();
                }
            }
        }
        let mut scene = load_scene("reference", Some(1), None).unwrap();
        scene.cups.rest_time_s = 0.1;
        scene.health.object_outside = false;
        let model = Arc::new(Model::new(&scene).unwrap());
        let mut recording = recorded("HHHHH");
        let upper = recording.meta.initial_marker_positions_m.clone();
        // Under each upper marker, the package's thickness lower.
        let thickness = f64::from(scene.package.thickness_m);
        recording.meta.initial_lower_marker_positions_m = upper
            .iter()
            .map(|p| [p[0], p[1] - thickness, p[2]])
            .collect();
        let target = Target::new(&recording, Some(0.02), false).unwrap();
        assert_eq!(target.sites().len(), 2 * upper.len());
        let mut first = FirstSites(Vec::new());
        let candidate = Candidate::of_scene(&scene);
        rollout(
            &model,
            std::slice::from_ref(&target),
            &[candidate],
            &mut first,
        )
        .unwrap();
        let (top, bottom) = first.0.split_at(upper.len());
        assert_eq!(bottom.len(), upper.len());
        // Each bottom site under its top site: the same place in plan within a few mm once the
        // film has sagged for the rest period, one sheet below the other.
        let plan = |t: &[f64; 3], b: &[f64; 3]| (t[0] - b[0]).hypot(t[2] - b[2]);
        let mean_plan =
            top.iter().zip(bottom).map(|(t, b)| plan(t, b)).sum::<f64>() / top.len() as f64;
        assert!(mean_plan < 5e-3, "mean plan offset {mean_plan} m");
        for (t, b) in top.iter().zip(bottom) {
            assert!(plan(t, b) < 0.012, "{t:?} {b:?}");
            assert!(t[1] - b[1] > 0.5 * thickness, "{t:?} above {b:?}");
        }
    }

    #[test]
    fn an_observer_can_stop_the_rollout() {
        /// Stops once `after` frames were compared.
        struct StopAfter {
            frames: usize,
            after: usize,
        }
        impl Observer for StopAfter {
            fn frame(&mut self, _observation: &FrameObservation) {
                self.frames += 1;
            }
            fn stop(&mut self) -> bool {
                self.frames >= self.after
            }
        }
        let mut scene = load_scene("reference", Some(0), None).unwrap();
        scene.cups.rest_time_s = 0.1;
        scene.health.object_outside = false;
        let model = Arc::new(Model::new(&scene).unwrap());
        let target = Target::new(&recorded("HHHHH"), Some(0.05), false).unwrap();
        let candidate = Candidate::of_scene(&scene);
        let mut observer = StopAfter {
            frames: 0,
            after: 3,
        };
        let stopped = rollout(
            &model,
            std::slice::from_ref(&target),
            &[candidate],
            &mut observer,
        );
        assert!(matches!(stopped, Err(ReplayError::Stopped)));
        assert_eq!(observer.frames, 3, "the rollout goes on no further");
        assert!(target.times.len() > 3);
    }

    #[test]
    fn the_two_clocks_differ_only_half_way_between_substeps() {
        let mut scene = load_scene("reference", None, None).unwrap();
        scene.cups.rest_time_s = 1.0;
        scene.integrator.substep_rate_hz = 300.0;
        // 1.025 s is 307.5 substeps: the double-precision rate rounds up, the single-precision
        // substep length (a little over 1/300 s) gives 307.4999... and rounds down.
        assert_eq!(FrameClock::SubstepRate.substep_at(&scene, 0.025), 308);
        assert_eq!(FrameClock::SubstepLength.substep_at(&scene, 0.025), 307);
        for t in [-1.0, -0.5, 0.0, 0.02, 1.0] {
            let exact = ((1.0 + t) * 300.0_f64).round() as u64;
            assert_eq!(FrameClock::SubstepRate.substep_at(&scene, t), exact);
            assert_eq!(FrameClock::SubstepLength.substep_at(&scene, t), exact);
        }
        // Before the rest period starts there is no substep to go back to.
        assert_eq!(FrameClock::SubstepRate.substep_at(&scene, -2.0), 0);
        assert_eq!(FrameClock::SubstepLength.substep_at(&scene, -2.0), 0);
    }

    #[test]
    fn extra_stops_are_observed_in_order_and_leave_the_results_unchanged() {
        /// Logs every hook as (hook, substep).
        #[derive(Default)]
        struct Log(Vec<(&'static str, u64)>);
        impl Observer for Log {
            fn start(&mut self, simulator: &Simulator) {
                self.0.push(("start", simulator.substep()));
            }
            fn instant(&mut self, substep: u64, simulator: &Simulator) {
                assert_eq!(simulator.substep(), substep);
                self.0.push(("instant", substep));
            }
            fn frame(&mut self, observation: &FrameObservation) {
                self.0.push(("frame", observation.simulator.substep()));
            }
            fn finish(&mut self, simulator: &Simulator) {
                self.0.push(("finish", simulator.substep()));
            }
        }
        let mut scene = load_scene("reference", Some(0), None).unwrap();
        scene.cups.rest_time_s = 0.1;
        scene.health.object_outside = false;
        let model = Arc::new(Model::new(&scene).unwrap());
        let target = Target::new(&recorded("HHLHL"), Some(0.02), false).unwrap();
        let candidate = Candidate::of_scene(&scene);
        let plain = rollout(&model, std::slice::from_ref(&target), &[candidate], &mut ()).unwrap();

        let rest_substeps = FrameClock::SubstepLength.substep_at(&scene, 0.0);
        let schedule = Schedule {
            clock: FrameClock::SubstepLength,
            // Unsorted, repeated, and one stop on a frame's substep.
            extra_stops: vec![rest_substeps / 2, 0, rest_substeps, rest_substeps / 2],
        };
        let mut log = Log::default();
        let scheduled = rollout_scheduled(
            &model,
            std::slice::from_ref(&target),
            &[candidate],
            &schedule,
            &mut log,
        )
        .unwrap();
        assert_eq!(plain[0][0].loss.frames, scheduled[0][0].loss.frames);
        let frames = target.times.len();
        let last = FrameClock::SubstepLength.substep_at(&scene, target.duration());
        let mut expected = vec![
            ("start", 0),
            ("instant", 0),
            ("instant", rest_substeps / 2),
            ("instant", rest_substeps),
        ];
        expected.extend((0..frames).map(|k| {
            let at = FrameClock::SubstepLength.substep_at(&scene, target.times[k]);
            ("frame", at)
        }));
        expected.push(("finish", last));
        assert_eq!(log.0, expected);
    }

    #[test]
    fn seal_failures_are_reported_per_environment() {
        // A vacuum far too weak to carry the package: every cup lets go once the tool lifts; the
        // same scene without the seal model loses none.
        let root = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../configs/scenes/physical-soft-film.toml"
        );
        let mut scene = load_scene(root, Some(0), None).unwrap();
        scene.cups.rest_time_s = 0.1;
        scene.health.object_outside = false;
        scene.seal.vacuum_kpa = 0.01;
        let target = Target::new(&recorded("HHLHL"), Some(0.3), false).unwrap();
        let weak = Candidate::of_scene(&scene);
        let model = Arc::new(Model::new(&scene).unwrap());
        let targets = [target.clone(), target];
        let out = rollout(&model, &targets, &[weak], &mut ()).unwrap();
        let failure = out[0][0].seal_failure.expect("a cup fails");
        assert!(failure.cup < scene.cups.angles_deg.len());
        assert!((0.0..=0.3).contains(&failure.t), "t = {}", failure.t);
        assert!(!failure.mode().is_empty());
        assert_eq!(
            out[0][1].seal_failure,
            Some(failure),
            "same target, same failure"
        );

        scene.seal.enabled = false;
        let model = Arc::new(Model::new(&scene).unwrap());
        let out = rollout(&model, &targets[..1], &[weak], &mut ()).unwrap();
        assert_eq!(out[0][0].seal_failure, None);
    }

    #[test]
    fn candidate_disc_mass_scale_acts_as_the_scenes() {
        // A candidate with a heavier disc on a scene of mass scale 100 must behave as the scene
        // with that mass scale, and differently from the lighter disc.
        let mut scene = load_scene("reference", Some(0), None).unwrap();
        scene.cups.rest_time_s = 0.1;
        // The disc slips through the 6 x 7 sheet; these tests are about the batching and the fit.
        scene.health.object_outside = false;
        let target = Target::new(&recorded("HHLHL"), Some(0.3), false).unwrap();
        let run = |scene: &SceneConfig, candidate: Candidate| {
            let model = Arc::new(Model::new(scene).unwrap());
            let out =
                rollout(&model, std::slice::from_ref(&target), &[candidate], &mut ()).unwrap();
            out[0][0].loss.mean_object_sq()
        };
        let light = Candidate::of_scene(&scene);
        let heavy = Candidate {
            disc_mass_scale: 3.0 * light.disc_mass_scale,
            ..light
        };
        let mut heavy_scene = scene.clone();
        heavy.apply_to(&mut heavy_scene);
        assert_eq!(heavy_scene.disc.mass_scale, 300.0);
        let (by_candidate, by_scene) = (run(&scene, heavy), run(&heavy_scene, heavy));
        assert!(
            (by_candidate - by_scene).abs() <= 1e-6 * by_scene,
            "{by_candidate} vs {by_scene}"
        );
        let light_mse = run(&scene, light);
        assert!(
            (light_mse - by_scene).abs() > 1e-3 * by_scene,
            "{light_mse} vs {by_scene}"
        );
    }
}
