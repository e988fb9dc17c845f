//! The calibration objective on the batched simulator.
//!
//! One batched rollout evaluates a whole candidate batch on every training trajectory: environment
//! `c · T + t` simulates candidate `c` on trajectory `t`, all in lockstep, so the simulator's lanes
//! and threads are filled and the result is deterministic (each environment is bit-identical
//! whatever the batch).
//!
//! Scene per trajectory, as the study (reference-model §1, §4): the package corner at the row-0
//! markers, the cups around the recorded initial cup point, the disc at the t = 0 object position
//! with the markers' mean height, a rest period, then the recorded tool motion.
//!
//! Simulated points for the loss: the recorded row-0 markers embedded in the upper sheet
//! (barycentric, nearest triangle at rest), evaluated on the deformed sheet; not the study's 42
//! nominal grid vertices, which sit up to 1.5 cm off the real markers (§12, item 5). Recorded frame
//! `k` (trajectory time `t_k`) is compared with the state at the substep nearest to
//! `rest + t_k`.

use std::sync::Arc;

use rlpkg_mocap::Trajectory;
use rlpkg_sim::{
    DiscState, EnvSpec, HealthEvent, Model, Params, Placement, SceneConfig, SimError, Simulator,
    SurfaceEmbedding, ToolSample, ToolTrajectory,
};

use crate::driver::{BatchObjective, CalibratedParams, CandidateResult};
use crate::loss::{LossWeights, TrajectoryLoss};

/// Errors of the objective.
#[derive(Debug, thiserror::Error)]
pub enum ObjectiveError {
    /// The simulator rejected the scene or an environment.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// A recorded trajectory cannot be replayed.
    #[error("trajectory {id}: {message}")]
    Trajectory {
        /// Trajectory id.
        id: String,
        /// What is wrong.
        message: String,
    },
    /// An unknown parameter name.
    #[error("unknown simulator parameter `{0}`")]
    UnknownParameter(String),
}

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

/// The slot of the parameter called `name` (see [`crate::config::PARAMETER_NAMES`]).
fn slot<'a>(candidate: &'a mut Candidate, name: &str) -> Result<&'a mut f32, ObjectiveError> {
    let params = &mut candidate.params;
    Ok(match name {
        "k_tri_e" => &mut params.k_tri_e,
        "k_tri_a" => &mut params.k_tri_a,
        "k_tri_d" => &mut params.k_tri_d,
        "k_edge_e" => &mut params.k_edge_e,
        "k_edge_d" => &mut params.k_edge_d,
        "k_cup_e" => &mut params.k_cup_e,
        "k_cup_a" => &mut params.k_cup_a,
        "k_cup_d" => &mut params.k_cup_d,
        "k_spr_e" => &mut params.k_spr_e,
        "k_spr_d" => &mut params.k_spr_d,
        "k_con_e" => &mut params.k_con_e,
        "k_con_d" => &mut params.k_con_d,
        "k_con_f" => &mut params.k_con_f,
        "mu_con" => &mut params.mu_con,
        "disc_mass_scale" => &mut candidate.disc_mass_scale,
        other => return Err(ObjectiveError::UnknownParameter(other.to_string())),
    })
}

/// Sets the parameter called `name` (see [`crate::config::PARAMETER_NAMES`]).
pub fn set_param(candidate: &mut Candidate, name: &str, value: f64) -> Result<(), ObjectiveError> {
    *slot(candidate, name)? = value as f32;
    Ok(())
}

/// The value of the parameter called `name`.
pub fn get_param(candidate: &Candidate, name: &str) -> Result<f64, ObjectiveError> {
    let mut copy = *candidate;
    Ok(*slot(&mut copy, name)? as f64)
}

/// Loads a simulator preset (`reference`, `physical`, or a scene TOML file), sets the grid to the
/// 6 x 7 marker grid with `between` particles between markers, and optionally the time step.
pub fn load_scene(
    preset: &str,
    between: Option<usize>,
    dt: Option<f64>,
) -> Result<SceneConfig, SimError> {
    let mut scene = match preset {
        "reference" | "physical" => SceneConfig::preset(preset)?,
        path => SceneConfig::load(std::path::Path::new(path))?,
    };
    if let Some(p) = between {
        scene.package.grid = [6 + 5 * p, 7 + 6 * p];
    }
    if let Some(dt) = dt {
        scene.integrator.substep_rate_hz = 1.0 / dt;
    }
    scene.validate(preset)?;
    Ok(scene)
}

/// A recorded trajectory prepared for replay: placement, tool motion and the frames to compare.
#[derive(Debug, Clone)]
pub struct Target {
    /// Trajectory id.
    pub id: String,
    /// Initial placement of package, cups and disc.
    pub placement: Placement,
    /// Recorded object mass (kg), before the scene's scaling.
    pub object_mass_kg: f32,
    /// Recorded tool motion.
    pub tool: Arc<ToolTrajectory>,
    /// Row-0 markers, embedded in the upper sheet for the loss.
    pub initial_markers: Vec<[f32; 3]>,
    /// Trajectory time of each compared frame (s).
    pub times: Vec<f64>,
    /// Markers seen in each compared frame.
    pub markers: Vec<Vec<[f64; 3]>>,
    /// Recorded object position in each compared frame.
    pub object: Vec<[f64; 3]>,
}

impl Target {
    /// Prepares `trajectory`, keeping the frames with `t <= max_seconds` (all when `None`). With
    /// `hold_disc` the disc is held at the recorded start during the rest
    /// (`DiscConfig::hold_at_recorded_start`).
    pub fn new(
        trajectory: &Trajectory,
        max_seconds: Option<f64>,
        hold_disc: bool,
    ) -> Result<Self, ObjectiveError> {
        let fail = |message: String| ObjectiveError::Trajectory {
            id: trajectory.id.clone(),
            message,
        };
        let meta = &trajectory.meta;
        let f32s = |p: &[f64; 3]| p.map(|c| c as f32);
        let initial_markers: Vec<[f32; 3]> =
            meta.initial_marker_positions_m.iter().map(f32s).collect();
        let first_object = trajectory
            .object
            .position
            .first()
            .ok_or_else(|| fail("no object position".into()))?;
        let placement = Placement::from_markers(
            &initial_markers,
            f32s(&meta.initial_suction_cup_position_m),
            f32s(first_object),
        )
        .map_err(|e| fail(e.to_string()))?;
        let placement = if hold_disc {
            placement.holding_disc_at(f32s(first_object))
        } else {
            placement
        };
        let tool = &trajectory.tool;
        let samples = (0..tool.t.len())
            .map(|i| ToolSample {
                t: tool.t[i],
                position: tool.position[i],
                orientation: tool.orientation[i],
                velocity: tool.velocity[i],
            })
            .collect();
        let tool = ToolTrajectory::new(samples).map_err(|e| fail(e.to_string()))?;
        let limit = max_seconds.unwrap_or(f64::INFINITY);
        let frames = (0..trajectory.markers.len())
            .take_while(|&k| trajectory.markers.t(k) <= limit)
            .count()
            .min(trajectory.object.position.len());
        if frames == 0 {
            return Err(fail("no frame to compare".into()));
        }
        Ok(Self {
            id: trajectory.id.clone(),
            placement,
            object_mass_kg: meta.object_total_mass_kg as f32,
            tool: Arc::new(tool),
            initial_markers,
            times: (0..frames).map(|k| trajectory.markers.t(k)).collect(),
            markers: (0..frames)
                .map(|k| trajectory.markers.frame(k).to_vec())
                .collect(),
            object: trajectory.object.position[..frames].to_vec(),
        })
    }

    /// Simulated duration needed (s of trajectory time).
    pub fn duration(&self) -> f64 {
        self.times.last().copied().unwrap_or(0.0)
    }
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
    /// Called at every compared frame of every live environment.
    fn frame(&mut self, _observation: &FrameObservation) {}
    /// Called after every stepping chunk with simulated substeps done and planned.
    fn progress(&mut self, _done: u64, _total: u64) {}
}

impl Observer for () {}

/// The result of one environment of a rollout.
#[derive(Debug, Clone)]
pub struct RolloutOutcome {
    /// Per-frame losses (frames after a divergence are missing).
    pub loss: TrajectoryLoss,
    /// The health event that froze the environment, if it diverged.
    pub diverged: Option<HealthEvent>,
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
) -> Result<Vec<Vec<RolloutOutcome>>, ObjectiveError> {
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
            specs.push(EnvSpec {
                placement: targets[t].placement,
                params: candidate.params,
                object_mass_kg: targets[t].object_mass_kg,
                disc_mass_scale: Some(candidate.disc_mass_scale),
                trajectory: targets[t].tool.clone(),
            });
        }
    }
    let mut sim = Simulator::new(model.clone(), specs)?;
    // Placement depends on the target only: embed once per target.
    let embeddings: Vec<SurfaceEmbedding> = (0..n_targets)
        .map(|t| sim.embed(env_of[t][0], &targets[t].initial_markers))
        .collect();
    let rest = model.config.cups.rest_time_s as f64;
    let dt = sim.dt() as f64;
    // Substep of each compared frame, per target.
    let frame_substeps: Vec<Vec<u64>> = targets
        .iter()
        .map(|t| {
            t.times
                .iter()
                .map(|&tk| ((rest + tk) / dt).round() as u64)
                .collect()
        })
        .collect();
    let mut checkpoints: Vec<u64> = frame_substeps.iter().flatten().copied().collect();
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
                })
                .collect()
        })
        .collect();
    let mut next_frame = vec![0usize; n_targets];
    for &substep in &checkpoints {
        sim.step(substep - sim.substep());
        for (t, target) in targets.iter().enumerate() {
            let k = next_frame[t];
            if k >= frame_substeps[t].len() || frame_substeps[t][k] != substep {
                continue;
            }
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
                per_target[t].loss.push_frame(
                    k,
                    &points,
                    &target.markers[k],
                    &disc_position,
                    &target.object[k],
                );
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
        observer.progress(substep, total);
        if (0..sim.num_envs()).all(|env| sim.is_frozen(env)) {
            break; // every environment finished or diverged
        }
    }
    for event in sim.health_events() {
        let (c, t) = slot_of_env[event.env];
        outcomes[c][t].diverged.get_or_insert(*event);
    }
    Ok(outcomes)
}

/// Mean loss and metrics of one candidate over its trajectories; non-finite if any diverged.
pub fn summarise(outcomes: &[RolloutOutcome], weights: &LossWeights) -> CandidateResult {
    let n = outcomes.len() as f64;
    let diverged = outcomes.iter().any(|o| o.diverged.is_some());
    let mean = |f: &dyn Fn(&RolloutOutcome) -> f64| outcomes.iter().map(f).sum::<f64>() / n;
    let result = CandidateResult {
        loss: mean(&|o| o.loss.total(weights)),
        chamfer_m: mean(&|o| o.loss.mean_chamfer()),
        object_mse_m2: mean(&|o| o.loss.mean_object_sq()),
    };
    if diverged {
        CandidateResult {
            loss: f64::NAN,
            ..result
        }
    } else {
        result
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
    ) -> Result<Self, ObjectiveError> {
        let targets = trajectories
            .iter()
            .map(|t| Target::new(t, max_seconds, scene.disc.hold_at_recorded_start))
            .collect::<Result<Vec<_>, _>>()?;
        Self::from_targets(scene, names, targets, weights)
    }

    /// Builds the model of `scene` for already prepared targets.
    pub fn from_targets(
        scene: &SceneConfig,
        names: Vec<String>,
        targets: Vec<Target>,
        weights: LossWeights,
    ) -> Result<Self, ObjectiveError> {
        let base = Candidate::of_scene(scene);
        for name in &names {
            get_param(&base, name)?;
        }
        Ok(Self {
            model: Arc::new(Model::new(scene)?),
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
    pub fn calibrated_scene(&self, best: &CalibratedParams) -> Result<SceneConfig, ObjectiveError> {
        let mut candidate = self.base;
        for (name, &v) in &best.params {
            set_param(&mut candidate, name, v)?;
        }
        let mut scene = self.model.config.clone();
        candidate.apply_to(&mut scene);
        Ok(scene)
    }
}

impl BatchObjective for SimObjective {
    fn evaluate(&mut self, candidates: &[Vec<f64>]) -> Result<Vec<CandidateResult>, String> {
        let batch: Vec<Candidate> = candidates.iter().map(|c| self.candidate_for(c)).collect();
        let outcomes = rollout(&self.model, &self.targets, &batch, self.observer.as_mut())
            .map_err(|e| e.to_string())?;
        Ok(outcomes
            .iter()
            .map(|o| summarise(o, &self.weights))
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parameters_by_name_round_trip() {
        let mut p = Candidate::of_scene(&SceneConfig::preset("reference").unwrap());
        for (i, name) in crate::config::PARAMETER_NAMES.iter().enumerate() {
            set_param(&mut p, name, 1.5 + i as f64).unwrap();
        }
        for (i, name) in crate::config::PARAMETER_NAMES.iter().enumerate() {
            assert_eq!(get_param(&p, name).unwrap(), 1.5 + i as f64);
        }
        assert!(set_param(&mut p, "k_foo", 1.0).is_err());
        assert!(get_param(&p, "k_foo").is_err());
    }

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
        Target {
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
    fn batched_ragged_rollout_matches_single_rollouts() {
        // Two trajectories of different lengths x two candidates, one with a held disc: the batch
        // (target-major layout, finished environments retired) must give each pair's result.
        let mut scene = load_scene("reference", Some(0), None).unwrap();
        scene.cups.rest_time_s = 0.1;
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
    fn candidate_disc_mass_scale_acts_as_the_scenes() {
        // A candidate with a heavier disc on a scene of mass scale 100 must behave as the scene
        // with that mass scale, and differently from the lighter disc.
        let mut scene = load_scene("reference", Some(0), None).unwrap();
        scene.cups.rest_time_s = 0.1;
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

    #[test]
    fn scene_grid_and_time_step_overrides() {
        let s = load_scene("reference", Some(1), Some(1e-4)).unwrap();
        assert_eq!(s.package.grid, [11, 13]);
        assert!((s.dt() - 1e-4).abs() < 1e-9);
        assert!(load_scene("nonexistent.toml", None, None).is_err());
    }
}
