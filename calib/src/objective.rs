//! The calibration objective on the batched simulator: named parameters on top of a scene,
//! evaluated by one batched rollout of every candidate on every training trajectory
//! ([`rlpkg_replay::rollout`], where the replay set-up lives so that `simulate`, `eval --params`
//! and the transport task share it without depending on calibration).

use std::sync::Arc;

use rlpkg_mocap::Trajectory;
use rlpkg_replay::loss::{LossKind, LossWeights};
use rlpkg_replay::{get_param, mean_loss, rollout, set_param, Candidate, ReplayError, Target};
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
        })
    }

    /// Reports progress (and frames) of every rollout to `observer`.
    pub fn with_observer(mut self, observer: Box<dyn Observer>) -> Self {
        self.observer = observer;
        self
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
    /// rollout; outcomes `[candidate][target]`.
    pub fn rollouts(
        &mut self,
        candidates: &[Vec<f64>],
    ) -> Result<Vec<Vec<RolloutOutcome>>, ReplayError> {
        let batch: Vec<Candidate> = candidates.iter().map(|c| self.candidate_for(c)).collect();
        rollout(&self.model, &self.targets, &batch, self.observer.as_mut())
    }

    /// As [`SimObjective::rollouts`], reporting to `observer` instead of the objective's own.
    pub fn rollouts_observed(
        &self,
        candidates: &[Vec<f64>],
        observer: &mut dyn Observer,
    ) -> Result<Vec<Vec<RolloutOutcome>>, ReplayError> {
        let batch: Vec<Candidate> = candidates.iter().map(|c| self.candidate_for(c)).collect();
        rollout(&self.model, &self.targets, &batch, observer)
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
        let sites = (0..target.initial_markers.len())
            .map(Some)
            .collect::<Vec<_>>();
        let tracks = (0..target.initial_markers.len() as u32).collect::<Vec<_>>();
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
}
