//! The calibration objective on the batched simulator: named parameters on top of a scene,
//! evaluated by one batched rollout of every candidate on every training trajectory
//! ([`rlpkg_replay::rollout`], where the replay set-up lives so that `simulate`, `eval --params`
//! and the transport task share it without depending on calibration).

use std::sync::Arc;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rlpkg_mocap::Trajectory;
use rlpkg_replay::loss::{squared_distance, LossKind, LossWeights};
use rlpkg_replay::{
    get_param, mean_loss, rollout, set_param, Candidate, LikelihoodSettings, Phase, ReplayError,
    Target,
};
use rlpkg_sim::{Model, SceneConfig};

use crate::driver::{BatchObjective, CalibratedParams, CandidateResult};

pub use rlpkg_replay::{load_scene, FrameObservation, Observer, RolloutOutcome};

/// Mean loss and metrics of one candidate over its trajectories; non-finite if any diverged.
pub fn summarise(outcomes: &[RolloutOutcome], weights: &LossWeights) -> CandidateResult {
    let n = outcomes.len() as f64;
    let mean = |f: &dyn Fn(&RolloutOutcome) -> f64| outcomes.iter().map(f).sum::<f64>() / n;
    CandidateResult {
        loss: mean_loss(outcomes, weights),
        chamfer_m: mean(&|o| o.loss.mean_chamfer()),
        object_mse_m2: mean(&|o| o.loss.mean_object_sq()),
    }
}

/// The calibration objective: named parameters on top of a scene's base parameters, evaluated on a
/// fixed set of recorded trajectories.
pub struct SimObjective {
    model: Arc<Model>,
    base: Candidate,
    names: Vec<String>,
    targets: Vec<Target>,
    weights: LossWeights,
    observer: Box<dyn Observer>,
    /// Replays per candidate and their jitter ([`rlpkg_replay::likelihood`], "Replicas").
    replicas: usize,
    replica_jitter: f64,
    /// The targets of [`SimObjective::rollouts_within`]'s shorter starts, by their end (s).
    starts: Vec<(f64, Vec<Target>)>,
}

impl SimObjective {
    /// Builds the model of `scene` and prepares the trajectories.
    pub fn new(
        scene: &SceneConfig,
        names: Vec<String>,
        trajectories: &[Trajectory],
        weights: LossWeights,
        max_seconds: Option<f64>,
    ) -> Result<Self, ReplayError> {
        let targets = trajectories
            .iter()
            .map(|t| Target::new(t, max_seconds, scene.disc.hold_at_recorded_start))
            .collect::<Result<Vec<_>, _>>()?;
        Self::from_targets(scene, names, targets, weights)
    }

    /// Builds the model of `scene` for already prepared targets. With the labelled loss, the
    /// targets' first-frame tracks are tied to the sites the scene's own parameters simulate at
    /// that frame ([`Target::tie_sites`]), unless their sites are known already.
    pub fn from_targets(
        scene: &SceneConfig,
        names: Vec<String>,
        mut targets: Vec<Target>,
        weights: LossWeights,
    ) -> Result<Self, ReplayError> {
        let base = Candidate::of_scene(scene);
        for name in &names {
            get_param(&base, name)?;
        }
        let model = Arc::new(Model::new(scene)?);
        if weights.kind == LossKind::Labelled {
            tie_sites(&model, &mut targets, base)?;
        }
        Ok(Self {
            model,
            base,
            names,
            targets,
            weights,
            observer: Box::new(()),
            replicas: 1,
            replica_jitter: 0.0,
            starts: Vec::new(),
        })
    }

    /// Replays every candidate of [`SimObjective::rollouts`] as `settings.replicas` replicas
    /// ([`rlpkg_replay::likelihood`], "Replicas"): its outcomes are then each replica's on every
    /// target in turn, as [`rlpkg_replay::Likelihood`] expects.
    pub fn with_replicas(mut self, settings: &LikelihoodSettings) -> Self {
        self.replicas = settings.replicas.max(1);
        self.replica_jitter = settings.replica_jitter;
        self
    }

    /// `values` as replica `replica` replays them: replica 0 as they are, replica `r > 0` with each
    /// value scaled by `1 + jitter · u`, `u` uniform in `[−1, 1]` from a stream fixed by `r`.
    pub fn replica_values(&self, values: &[f64], replica: usize) -> Vec<f64> {
        if replica == 0 {
            return values.to_vec();
        }
        let mut rng = ChaCha8Rng::seed_from_u64(replica as u64);
        values
            .iter()
            .map(|v| v * (1.0 + self.replica_jitter * rng.random_range(-1.0..=1.0)))
            .collect()
    }

    /// Reports progress (and frames) of every rollout to `observer`.
    pub fn with_observer(mut self, observer: Box<dyn Observer>) -> Self {
        self.observer = observer;
        self
    }

    /// The longest prepared recording's duration (s of trajectory time).
    pub fn duration(&self) -> f64 {
        self.targets
            .iter()
            .map(Target::duration)
            .fold(0.0, f64::max)
    }

    /// The scene's values of the calibrated parameters (a good first point to evaluate).
    pub fn base_values(&self) -> Vec<f64> {
        self.names
            .iter()
            .map(|n| get_param(&self.base, n).expect("checked in new"))
            .collect()
    }

    /// The prepared trajectories.
    pub fn targets(&self) -> &[Target] {
        &self.targets
    }

    /// The base candidate with the calibrated parameters replaced by `values`.
    pub fn candidate_for(&self, values: &[f64]) -> Candidate {
        let mut p = self.base;
        for (name, &v) in self.names.iter().zip(values) {
            set_param(&mut p, name, v).expect("checked in new");
        }
        p
    }

    /// The scene with calibrated parameters applied (to write as `calibrated.toml`).
    pub fn calibrated_scene(&self, best: &CalibratedParams) -> Result<SceneConfig, ReplayError> {
        let mut candidate = self.base;
        for (name, &v) in &best.params {
            set_param(&mut candidate, name, v)?;
        }
        let mut scene = self.model.config.clone();
        candidate.apply_to(&mut scene);
        Ok(scene)
    }
}

/// Ties the untied targets' tracks to the sites `base` simulates at each track's first frame
/// ([`Target::tie_sites`]): one rollout of `base` on those targets.
fn tie_sites(
    model: &Arc<Model>,
    targets: &mut [Target],
    base: Candidate,
) -> Result<(), ReplayError> {
    struct Sites(Vec<Vec<Vec<[f64; 3]>>>);
    impl Observer for Sites {
        fn frame(&mut self, o: &FrameObservation) {
            self.0[o.target].push(o.simulated_points.to_vec());
        }
    }
    let untied: Vec<usize> = (0..targets.len())
        .filter(|&t| targets[t].labelled_share() == 0.0)
        .collect();
    if untied.is_empty() {
        return Ok(());
    }
    let cut: Vec<Target> = untied.iter().map(|&t| targets[t].clone()).collect();
    let mut observer = Sites(vec![Vec::new(); cut.len()]);
    rollout(model, &cut, &[base], &mut observer)?;
    for (i, &t) in untied.iter().enumerate() {
        // A rollout that diverged ties what it reached.
        targets[t].tie_sites(&observer.0[i]);
    }
    Ok(())
}

impl SimObjective {
    /// The loss weights.
    pub fn weights(&self) -> &LossWeights {
        &self.weights
    }

    /// Simulates every candidate (values in the space's order) on every target in one batched
    /// rollout; outcomes `[candidate][target]`, or `[candidate][replica · targets + target]` with
    /// replicas ([`SimObjective::with_replicas`]).
    pub fn rollouts(
        &mut self,
        candidates: &[Vec<f64>],
    ) -> Result<Vec<Vec<RolloutOutcome>>, ReplayError> {
        self.rollouts_of(None, candidates)
    }

    /// As [`SimObjective::rollouts`] on the recordings' first `seconds` only ([`Target::within`],
    /// made once and kept; the sites stay tied as on the whole recordings), reported to this objective's observer (which may stop it). `None` when a
    /// recording has no frame that early.
    pub fn rollouts_within(
        &mut self,
        seconds: f64,
        candidates: &[Vec<f64>],
    ) -> Option<Result<Vec<Vec<RolloutOutcome>>, ReplayError>> {
        if !self.starts.iter().any(|(s, _)| *s == seconds) {
            let short = self
                .targets
                .iter()
                .map(|t| t.within(seconds))
                .collect::<Option<Vec<_>>>()?;
            self.starts.push((seconds, short));
        }
        Some(self.rollouts_of(Some(seconds), candidates))
    }

    /// The targets [`SimObjective::rollouts_within`]`(seconds, ..)` rolled out on, once it has.
    pub fn targets_within(&self, seconds: f64) -> Option<&[Target]> {
        self.starts
            .iter()
            .find(|(start, _)| *start == seconds)
            .map(|(_, targets)| targets.as_slice())
    }

    fn rollouts_of(
        &mut self,
        seconds: Option<f64>,
        candidates: &[Vec<f64>],
    ) -> Result<Vec<Vec<RolloutOutcome>>, ReplayError> {
        let r = self.replicas;
        let batch: Vec<Candidate> = candidates
            .iter()
            .flat_map(|c| (0..r).map(move |k| (c, k)))
            .map(|(c, k)| self.candidate_for(&self.replica_values(c, k)))
            .collect();
        let targets = match seconds {
            None => &self.targets[..],
            Some(s) => {
                &self
                    .starts
                    .iter()
                    .find(|(start, _)| *start == s)
                    .expect("made by rollouts_within")
                    .1
            }
        };
        let outcomes = rollout(&self.model, targets, &batch, self.observer.as_mut())?;
        // Each candidate's replicas, one after the other.
        Ok(outcomes
            .chunks(r)
            .map(|replicas| replicas.concat())
            .collect())
    }

    /// As [`SimObjective::rollouts`] of the candidates themselves (no replicas), reporting to
    /// `observer` instead of the objective's own: the Fisher analysis differentiates one replay.
    pub fn rollouts_observed(
        &self,
        candidates: &[Vec<f64>],
        observer: &mut dyn Observer,
    ) -> Result<Vec<Vec<RolloutOutcome>>, ReplayError> {
        let batch: Vec<Candidate> = candidates.iter().map(|c| self.candidate_for(c)).collect();
        rollout(&self.model, &self.targets, &batch, observer)
    }
}

/// How far the replays of one nudged parameter set move from those of the unnudged one
/// ([`SimObjective::spread`]): over every compared frame of every trajectory, the largest distance
/// between a simulated marker site and the same site of the unnudged replay.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Spread {
    /// The nudged parameter, or `all` when every one is nudged at once.
    pub parameter: String,
    /// Median over frames of the worst site's distance (m).
    pub median_m: f64,
    /// 90th percentile over frames of the worst site's distance (m).
    pub p90_m: f64,
    /// Largest worst-site distance of any frame (m).
    pub max_m: f64,
    /// Largest distance between the two discs' centres in any frame (m).
    pub disc_max_m: f64,
    /// Per phase of the motion present in the recordings ([`Phase::ALL`] order): the 90th
    /// percentile over that phase's frames of the worst site's distance (m).
    pub phase_p90_m: Vec<(Phase, f64)>,
}

/// The value at quantile `q` of sorted `values` (nearest rank); NaN when empty.
fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// The label of the candidate that nudges every parameter in [`SimObjective::spread`].
pub const ALL_PARAMETERS: &str = "all";

impl SimObjective {
    /// The simulator's own sensitivity at `values`: each parameter alone, then all of them, scaled
    /// by `1 + nudge` (a change far below what recordings can tell apart, e.g. 1e-6) and replayed
    /// in one batch beside `values` itself; one [`Spread`] per nudged set. A smooth simulator moves
    /// its replays by about `nudge` times their motion; a spread near the markers' noise means the
    /// loss is rough at the scale the likelihood resolves, and no optimiser can tell the truth's
    /// neighbourhood from afar. A replay that diverged counts its frames until then.
    pub fn spread(&self, values: &[f64], nudge: f64) -> Result<Vec<Spread>, ReplayError> {
        let mut sets = vec![values.to_vec()];
        let mut labels = Vec::new();
        for (i, name) in self.names.iter().enumerate() {
            let mut v = values.to_vec();
            v[i] *= 1.0 + nudge;
            sets.push(v);
            labels.push(name.clone());
        }
        sets.push(values.iter().map(|v| v * (1.0 + nudge)).collect());
        labels.push(ALL_PARAMETERS.to_string());

        /// The unnudged replay's sites and disc centre in the frame being observed.
        type Unnudged = (Vec<[f64; 3]>, [f64; 3]);
        /// Per nudged set: the worst site's distance and the phase of each frame, and the discs'
        /// largest distance.
        struct Distances {
            phases: Vec<Vec<Phase>>,
            unnudged: Vec<Option<Unnudged>>,
            worst: Vec<Vec<(Phase, f64)>>,
            disc: Vec<f64>,
        }
        impl Observer for Distances {
            fn frame(&mut self, o: &FrameObservation) {
                let disc = o.disc.position.map(f64::from);
                // Candidates are observed in order within a frame: the unnudged one first.
                if o.candidate == 0 {
                    self.unnudged[o.target] = Some((o.simulated_points.to_vec(), disc));
                    return;
                }
                let Some((points, base_disc)) = &self.unnudged[o.target] else {
                    return;
                };
                let worst = o
                    .simulated_points
                    .iter()
                    .zip(points)
                    .map(|(a, b)| squared_distance(a, b).sqrt())
                    .fold(0.0, f64::max);
                let set = o.candidate - 1;
                self.worst[set].push((self.phases[o.target][o.frame], worst));
                self.disc[set] = self.disc[set].max(squared_distance(&disc, base_disc).sqrt());
            }
        }
        let mut distances = Distances {
            phases: self.targets.iter().map(|t| t.phases.clone()).collect(),
            unnudged: vec![None; self.targets.len()],
            worst: vec![Vec::new(); labels.len()],
            disc: vec![0.0; labels.len()],
        };
        self.rollouts_observed(&sets, &mut distances)?;
        Ok(labels
            .into_iter()
            .zip(distances.worst)
            .zip(distances.disc)
            .map(|((parameter, frames), disc_max_m)| {
                let sorted = |phase: Option<Phase>| {
                    let mut d: Vec<f64> = frames
                        .iter()
                        .filter(|(p, _)| phase.is_none_or(|phase| *p == phase))
                        .map(|(_, d)| *d)
                        .collect();
                    d.sort_by(f64::total_cmp);
                    d
                };
                let all = sorted(None);
                Spread {
                    parameter,
                    median_m: quantile(&all, 0.5),
                    p90_m: quantile(&all, 0.9),
                    max_m: quantile(&all, 1.0),
                    disc_max_m,
                    phase_p90_m: Phase::ALL
                        .into_iter()
                        .filter(|&phase| frames.iter().any(|(p, _)| *p == phase))
                        .map(|phase| (phase, quantile(&sorted(Some(phase)), 0.9)))
                        .collect(),
                }
            })
            .collect())
    }
}

impl BatchObjective for SimObjective {
    fn evaluate(&mut self, candidates: &[Vec<f64>]) -> Result<Vec<CandidateResult>, String> {
        let outcomes = self.rollouts(candidates).map_err(|e| e.to_string())?;
        Ok(outcomes
            .iter()
            .map(|o| summarise(o, &self.weights))
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A real recorded trajectory of the repository (tool motion and placement), first frames only.
    fn recorded(id: &str) -> Trajectory {
        let root =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/deformable-sim-real");
        rlpkg_mocap::Dataset::open(&root).unwrap().load(id).unwrap()
    }

    /// Records what the simulator does with `candidate` as if it were motion capture: the marker
    /// sites (embedded row-0 markers) as the markers of each frame and the disc as the object.
    /// The placement stays the recording's.
    fn synthetic_target(
        model: &Arc<Model>,
        base: &Trajectory,
        candidate: Candidate,
        seconds: f64,
    ) -> Target {
        struct Recorder {
            markers: Vec<Vec<[f64; 3]>>,
            object: Vec<[f64; 3]>,
        }
        impl Observer for Recorder {
            fn frame(&mut self, o: &FrameObservation) {
                self.markers.push(o.simulated_points.to_vec());
                self.object.push(o.disc.position.map(|v| v as f64));
            }
        }
        let target = Target::new(base, Some(seconds), false).unwrap();
        let mut rec = Recorder {
            markers: Vec::new(),
            object: Vec::new(),
        };
        let out = rollout(model, std::slice::from_ref(&target), &[candidate], &mut rec).unwrap();
        assert!(out[0][0].diverged.is_none());
        assert_eq!(rec.markers.len(), target.times.len());
        let sites = (0..target.sites().len()).map(Some).collect::<Vec<_>>();
        let tracks = (0..target.sites().len() as u32).collect::<Vec<_>>();
        Target {
            marker_tracks: vec![tracks; rec.markers.len()],
            marker_sites: vec![sites; rec.markers.len()],
            markers: rec.markers,
            object: rec.object,
            ..target
        }
    }

    #[test]
    fn calibration_recovers_parameters_of_simulated_data() {
        // Coarse 6 x 7 grid, short rest, 0.2 s of the recorded HHHHH tool motion.
        let mut scene = load_scene("reference", Some(0), None).unwrap();
        scene.cups.rest_time_s = 0.1;
        // The disc slips through the 6 x 7 sheet; these tests are about the batching and the fit.
        scene.health.object_outside = false;
        let model = Arc::new(Model::new(&scene).unwrap());
        let mut truth = Candidate::of_scene(&scene);
        truth.params.k_tri_e = 2.0e4;
        let data = synthetic_target(&model, &recorded("HHHHH"), truth, 0.2);

        let names = vec!["k_tri_e".to_string()];
        let mut objective =
            SimObjective::from_targets(&scene, names, vec![data], LossWeights::default()).unwrap();
        // At the true value the simulator reproduces its own recording exactly.
        let at_truth = objective.evaluate(&[vec![2.0e4]]).unwrap()[0];
        assert!(at_truth.loss < 1e-9, "loss at the true value {at_truth:?}");

        let dir = tempfile::tempdir().unwrap();
        let plan = crate::driver::Plan {
            space: crate::space::ParamSpace::new(vec![crate::space::ParamSpec {
                name: "k_tri_e".into(),
                lower: 1.0e3,
                upper: 1.0e6,
                log: true,
            }])
            .unwrap(),
            settings: crate::bo::BoSettings {
                initial_points: 4,
                batch_size: 4,
                random_candidates: 200,
                seed: 1,
                ..crate::bo::BoSettings::default()
            },
            seed_points: vec![objective.base_values()],
            iterations: 3,
            out_dir: dir.path().to_path_buf(),
        };
        let best = crate::driver::run(&plan, &mut objective, |_| {}).unwrap();
        let found = best.params["k_tri_e"];
        assert!(
            (found / 2.0e4).log10().abs() < 0.1,
            "recovered k_tri_e = {found} (true 2e4), {best:?}"
        );
    }

    #[test]
    fn replicas_replay_each_candidate_with_its_values_jittered_after_the_first() {
        let mut scene = load_scene("reference", Some(0), None).unwrap();
        scene.cups.rest_time_s = 0.1;
        scene.health.object_outside = false;
        let target = Target::new(&recorded("HHLHL"), Some(0.3), false).unwrap();
        let names = vec!["k_tri_e".to_string(), "k_spr_e".to_string()];
        let weights = LossWeights::default();
        let mut one =
            SimObjective::from_targets(&scene, names.clone(), vec![target.clone()], weights)
                .unwrap();
        let settings = LikelihoodSettings {
            replicas: 3,
            replica_jitter: 1e-3,
            ..LikelihoodSettings::default()
        };
        let mut three = SimObjective::from_targets(&scene, names, vec![target], weights)
            .unwrap()
            .with_replicas(&settings);
        let values = one.base_values();
        assert_eq!(three.replica_values(&values, 0), values);
        let jittered = three.replica_values(&values, 1);
        assert_ne!(jittered, values);
        assert_eq!(jittered, three.replica_values(&values, 1), "a fixed stream");
        assert!(jittered
            .iter()
            .zip(&values)
            .all(|(j, v)| (j / v - 1.0).abs() <= 1e-3));
        let single = one.rollouts(std::slice::from_ref(&values)).unwrap();
        let replicated = three.rollouts(&[values.clone(), values]).unwrap();
        assert_eq!(replicated.len(), 2);
        assert_eq!(replicated[0].len(), 3);
        // Replica 0 is the candidate's own replay; the others moved.
        let chamfer = |o: &RolloutOutcome| o.loss.mean_chamfer();
        assert!(chamfer(&single[0][0]).is_finite());
        assert_eq!(chamfer(&replicated[0][0]), chamfer(&single[0][0]));
        assert_ne!(chamfer(&replicated[0][1]), chamfer(&single[0][0]));
        assert_eq!(chamfer(&replicated[1][2]), chamfer(&replicated[0][2]));
    }

    #[test]
    fn spread_is_zero_without_a_nudge_and_grows_with_it() {
        // The reference scene on the coarse grid over 0.2 s of HHHHH, its own parameters.
        let mut scene = load_scene("reference", Some(0), None).unwrap();
        scene.cups.rest_time_s = 0.1;
        scene.health.object_outside = false;
        let target = Target::new(&recorded("HHHHH"), Some(0.2), false).unwrap();
        let names = vec!["k_tri_e".to_string(), "k_edge_e".to_string()];
        let objective =
            SimObjective::from_targets(&scene, names, vec![target], LossWeights::default())
                .unwrap();
        let at = objective.base_values();

        // Each environment is bit-identical in any batch: an unchanged set does not move at all.
        let still = objective.spread(&at, 0.0).unwrap();
        assert_eq!(
            still
                .iter()
                .map(|s| s.parameter.as_str())
                .collect::<Vec<_>>(),
            ["k_tri_e", "k_edge_e", ALL_PARAMETERS]
        );
        for s in &still {
            assert_eq!((s.max_m, s.disc_max_m), (0.0, 0.0), "{s:?}");
        }
        // This explicit scene is smooth: a hundredfold nudge moves the sites about a hundredfold.
        let small = objective.spread(&at, 1e-4).unwrap();
        let large = objective.spread(&at, 1e-2).unwrap();
        for (s, l) in small.iter().zip(&large) {
            assert!(s.max_m > 0.0 && s.max_m < 1e-4, "{s:?}");
            let ratio = l.max_m / s.max_m;
            assert!((20.0..500.0).contains(&ratio), "{s:?} {l:?}");
            assert!(s.median_m <= s.p90_m && s.p90_m <= s.max_m);
            // Every phase's frames are a subset of all frames.
            assert!(!s.phase_p90_m.is_empty());
            assert!(
                s.phase_p90_m.iter().all(|(_, p90)| *p90 <= s.max_m),
                "{s:?}"
            );
        }
    }
}
