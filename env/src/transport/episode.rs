//! Episodes: the settled package variants a reset builds, the conditions drawn for each episode,
//! the start of an episode from a variant's snapshot, and what happens to a copy whose episode
//! ended (restarted, or retired in evaluation mode).

use std::sync::Arc;

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rlpkg_sim::{
    CupLoad, EnvObservation, EnvSnapshot, EpisodeSpec, Model, Placement, SceneConfig, Simulator,
    ToolTrajectory,
};
use serde::{Deserialize, Serialize};

use super::geometry::v3;
use super::geometry::vec3_as_array;
use super::reward::SUCCESS_COLUMN;
use super::sensors::cup_vacuum_pa;
use super::{saturate_utilisation, sim_error, Transport, TransportPath};
use crate::{env_rng, EnvError, StepBuffers, VecEnv};
use rlpkg_vec_env::ResetCopies;

/// What was drawn for one copy's current episode.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeConditions {
    /// Recording whose path the episode follows.
    pub path_id: String,
    /// Settled variant the episode started from.
    pub variant: usize,
    /// Tool tilt at the place pose (rad).
    pub target_tilt_rad: f64,
    /// Offset of the place position from the recorded one (m).
    pub goal_jitter_m: [f64; 3],
    /// Offset of the pick position from the recorded one (m).
    pub start_offset_m: [f64; 3],
    /// Object mass (kg).
    pub object_mass_kg: f32,
    /// Yaw of the package under the tool (rad).
    pub package_yaw_rad: f32,
}

/// A settled package state episodes start from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(super) struct Variant {
    pub(super) snapshot: EnvSnapshot,
    /// Tool position at pick (m).
    #[serde(with = "vec3_as_array")]
    pub(super) tool_start: DVec3,
}

/// One copy's current episode beyond the simulator state: what was drawn for it, where the
/// reference is along the path, and what the last step left for the next one's rates.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub(super) struct Episode {
    /// Index of the path followed.
    pub(super) path: usize,
    /// Index of the settled variant started from.
    pub(super) variant: usize,
    /// Added to the path's points: the variant's tool start minus the path's first point.
    #[serde(with = "vec3_as_array")]
    pub(super) start_offset: DVec3,
    /// Place position offset, blended in along the path.
    #[serde(with = "vec3_as_array")]
    pub(super) goal_jitter: DVec3,
    /// Tool tilt at the place pose (rad).
    pub(super) target_tilt: f64,
    /// Arc length of the reference along the path (m).
    pub(super) progress: f64,
    /// Speed of the reference along the path (m/s).
    pub(super) path_speed: f64,
    /// Arc length the last command advanced the reference by (m).
    pub(super) last_advance: f64,
    /// The last action after clamping to its bounds.
    pub(super) previous_action: [f64; 3],
    /// The tool's linear acceleration over the last step (m/s²).
    #[serde(with = "vec3_as_array")]
    pub(super) previous_accel: DVec3,
    /// The tool's angular acceleration over the last step (rad/s²).
    #[serde(with = "vec3_as_array")]
    pub(super) previous_angular_accel: DVec3,
    /// The object's position in the tool frame after the last step (m).
    #[serde(with = "vec3_as_array")]
    pub(super) previous_object_in_tool: DVec3,
    /// Simulator time of the episode start (s).
    pub(super) start_time: f64,
    /// Control steps taken.
    pub(super) steps: usize,
    /// Time along the episode's motion profile (s; `[transport.profile_rate]` only).
    #[serde(default)]
    pub(super) profile_clock: f64,
}

/// Uniform draw in `[lo, hi]` (`lo` when the range is empty).
fn uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    if lo < hi {
        rng.random_range(lo..=hi)
    } else {
        lo
    }
}

/// A uniform point in the ball of radius `r` (3-D) or, with `horizontal`, the disc (x, z).
fn uniform_offset(rng: &mut ChaCha8Rng, r: f64, horizontal: bool) -> DVec3 {
    if r <= 0.0 {
        return DVec3::ZERO;
    }
    loop {
        let p = DVec3::new(
            uniform(rng, -1.0, 1.0),
            if horizontal {
                0.0
            } else {
                uniform(rng, -1.0, 1.0)
            },
            uniform(rng, -1.0, 1.0),
        );
        if p.length_squared() <= 1.0 {
            return p * r;
        }
    }
}

/// A settled variant for a training episode under failure replay: with probability `share`
/// drawn in proportion to the variants' `failures` (uniformly while none has failed), else
/// uniformly.
fn replayed_variant(rng: &mut ChaCha8Rng, share: f64, failures: &[f64]) -> usize {
    let total: f64 = failures.iter().sum();
    if rng.random::<f64>() >= share || total <= 0.0 {
        return rng.random_range(0..failures.len());
    }
    let mut left = rng.random::<f64>() * total;
    for (k, &rate) in failures.iter().enumerate() {
        if left < rate {
            return k;
        }
        left -= rate;
    }
    // Rounding left a remainder: the last variant that has failed.
    failures.iter().rposition(|&rate| rate > 0.0).unwrap_or(0)
}

/// The generator of settled variant `k` for `seed` (independent of the copies' streams).
fn variant_rng(seed: u64, k: usize) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(1 << 32 | k as u64);
    rng
}

/// The index of the path whose recorded final tilt is nearest `tilt` (the first of equals).
fn nearest_path(paths: &[TransportPath], tilt: f64) -> Option<usize> {
    paths
        .iter()
        .enumerate()
        .min_by(|a, b| {
            let da = (a.1.recorded_final_tilt_rad - tilt).abs();
            let db = (b.1.recorded_final_tilt_rad - tilt).abs();
            da.total_cmp(&db)
        })
        .map(|(i, _)| i)
}

/// Moves the package, the cups and the object of `placement` by `offset` (m).
fn shift(placement: &mut Placement, offset: [f32; 3]) {
    let points = [
        &mut placement.package_origin,
        &mut placement.cup_point,
        &mut placement.disc_position,
    ];
    for point in points.into_iter().chain(placement.disc_hold.as_mut()) {
        for (c, d) in point.iter_mut().zip(offset) {
            *c += d;
        }
    }
}

/// The package at pick on `path`, the tool held at its start pose.
pub(super) fn base_spec(scene: &SceneConfig, path: &TransportPath) -> EpisodeSpec {
    let q = path.start_orientation;
    EpisodeSpec {
        placement: path.placement,
        params: scene.params,
        object_mass_kg: path.object_mass_kg,
        disc_mass_scale: None,
        vacuum_kpa: None,
        trajectory: Arc::new(ToolTrajectory::hold(
            path.points[0].to_array(),
            [q.x, q.y, q.z, q.w],
        )),
    }
}

/// How a settled package ended its settling.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Settled {
    /// Every cup still holds a healthy (not frozen) package.
    pub sealed: bool,
    /// The lowest vacuum over the package's cups as a fraction of the supply vacuum, under the
    /// sensors' leak model (what the cell's vacuum switch reads at the pick).
    pub grasp_vacuum_ratio: f64,
}

impl Settled {
    /// Whether the package is sealed and passes the grasp check `min_vacuum_ratio` (if any).
    pub fn grasped(&self, min_vacuum_ratio: Option<f64>) -> bool {
        self.sealed && min_vacuum_ratio.is_none_or(|min| self.grasp_vacuum_ratio >= min)
    }
}

/// Simulates `specs` through the rest period and `settle_s`; returns their snapshots and how
/// each ended its settling.
fn settle(
    model: &Arc<Model>,
    specs: Vec<EpisodeSpec>,
    settle_s: f64,
) -> Result<(Vec<EnvSnapshot>, Vec<Settled>), EnvError> {
    let mut sim = Simulator::new(model.clone(), specs).map_err(sim_error)?;
    let seconds = model.config.cups.rest_time_s as f64 + settle_s;
    sim.step((seconds / sim.dt() as f64).round() as u64);
    let mut states = vec![EnvObservation::default(); sim.num_envs()];
    sim.read_states(&mut states).map_err(sim_error)?;
    let cups = model.num_cups();
    let mut loads = vec![CupLoad::default(); sim.num_envs() * cups];
    sim.read_cup_loads(&mut loads).map_err(sim_error)?;
    saturate_utilisation(&mut loads);
    let settled = states
        .iter()
        .zip(loads.chunks(cups))
        .map(|(s, loads)| Settled {
            sealed: !s.frozen && s.cups_attached == cups as u32,
            grasp_vacuum_ratio: loads
                .iter()
                // Supply 1: the ratio.
                .map(|l| {
                    cup_vacuum_pa(
                        1.0,
                        l.attached,
                        l.sealed_fraction as f64,
                        l.utilisation as f64,
                    )
                })
                .fold(f64::INFINITY, f64::min),
        })
        .collect();
    Ok((
        (0..sim.num_envs()).map(|k| sim.snapshot(k)).collect(),
        settled,
    ))
}

/// The unrandomised package `base` on `path` settled for `settle_s` after the rest period: it
/// checks that the scene's cups seal (and pass the grasp check `min_vacuum_ratio`, if any), and
/// stands in for a randomised variant whose cups do not.
pub(super) fn settle_unrandomised(
    model: &Arc<Model>,
    base: EpisodeSpec,
    path: &TransportPath,
    settle_s: f64,
    min_vacuum_ratio: Option<f64>,
) -> Result<Variant, EnvError> {
    let (mut settled, how) = settle(model, vec![base], settle_s)?;
    let how = how[0];
    if !how.sealed {
        return Err(EnvError::ConfigParse {
            file: "[transport]".into(),
            message: format!(
                "the package of recording {} does not stay sealed by all cups in this scene \
                 after the rest period (seal settings too weak for its mass?)",
                path.id
            ),
        });
    }
    if !how.grasped(min_vacuum_ratio) {
        return Err(EnvError::ConfigParse {
            file: "[transport]".into(),
            message: format!(
                "grasp_min_vacuum_ratio = {}: the unrandomised package of recording {} holds \
                 only {:.3} of the supply vacuum at its weakest cup after the rest period; \
                 expected a ratio the scene's own package passes",
                min_vacuum_ratio.unwrap_or_default(),
                path.id,
                how.grasp_vacuum_ratio
            ),
        });
    }
    Ok(Variant {
        snapshot: settled.remove(0),
        tool_start: path.points[0],
    })
}

impl Transport {
    /// [`VecEnv::reset`] that reports a failure to settle the packages or to restore them instead
    /// of panicking.
    pub fn try_reset(&mut self, seed: u64, out: &mut StepBuffers) -> Result<(), EnvError> {
        self.restart_copies(ResetCopies::all(seed), out)
    }

    /// [`VecEnv::reset_copies`]: the settled variants are drawn again (and the sensors reseeded)
    /// from the batch's seed when every copy is reseeded, else kept (settled from the batch's
    /// seed, or 0, if there are none yet); each chosen copy then starts an episode.
    pub(super) fn restart_copies(
        &mut self,
        copies: ResetCopies,
        out: &mut StepBuffers,
    ) -> Result<(), EnvError> {
        copies.check(self.num_envs())?;
        match (copies.is_all(), copies.batch_seed()) {
            (true, Some(seed)) => {
                self.settle_variants(seed)?;
                if let Some(sensors) = &mut self.sensors {
                    sensors.reseed(seed);
                }
            }
            (_, seed) if self.variants.is_empty() => self.settle_variants(seed.unwrap_or(0))?,
            _ => {}
        }
        let chosen: Vec<usize> = (0..self.num_envs())
            .filter(|&env| copies.includes(env))
            .collect();
        for &env in &chosen {
            self.retired[env] = false;
            self.autoreset.restarted(env);
            if let Some(seed) = copies.seed_of(env) {
                self.rngs[env] = env_rng(seed, 0);
            }
            self.start_episode(env)?;
        }
        self.read_simulator()?;
        for &env in &chosen {
            self.start_sensors(env);
        }
        let width = self.info_names.len();
        for &env in &chosen {
            out.rewards[env] = 0.0;
            out.terminated[env] = false;
            out.truncated[env] = false;
            self.info[env * width..(env + 1) * width].fill(0.0);
            self.observe_into(env, out, false);
            self.observe_into(env, out, true);
        }
        Ok(())
    }

    /// How many randomised packages of the last reset did not stay sealed (or failed the grasp
    /// check) and were replaced by the unrandomised one.
    pub fn replaced_variants(&self) -> usize {
        self.replaced_variants
    }

    /// How many of the [`Transport::replaced_variants`] stayed sealed but failed the grasp check
    /// (`grasp_min_vacuum_ratio`).
    pub fn weak_grasps(&self) -> usize {
        self.weak_grasps
    }

    /// Each randomised package of the last reset: the lowest vacuum over its cups after settling,
    /// as a fraction of the supply vacuum (what the grasp check compares).
    pub fn grasp_vacuum_ratios(&self) -> &[f64] {
        &self.grasp_vacuum_ratios
    }

    /// What was drawn for copy `env`'s current episode (after [`VecEnv::reset`]).
    pub fn conditions(&self, env: usize) -> EpisodeConditions {
        let episode = &self.episodes[env];
        let spec = self.sim.spec(env);
        EpisodeConditions {
            path_id: self.paths[episode.path].id.clone(),
            variant: episode.variant,
            target_tilt_rad: episode.target_tilt,
            goal_jitter_m: episode.goal_jitter.to_array(),
            start_offset_m: (self.variants[episode.variant].tool_start - self.paths[0].points[0])
                .to_array(),
            object_mass_kg: spec.object_mass_kg,
            package_yaw_rad: spec.placement.package_yaw_rad,
        }
    }

    /// Settles `settled_variants` randomised packages (drawn from `seed`) and snapshots them.
    fn settle_variants(&mut self, seed: u64) -> Result<(), EnvError> {
        let scene = &self.model.config;
        let r = &self.config.randomization;
        let path = &self.paths[0];
        let mut specs = Vec::with_capacity(self.config.settled_variants);
        let mut starts = Vec::with_capacity(self.config.settled_variants);
        for k in 0..self.config.settled_variants {
            let mut rng = variant_rng(seed, k);
            let jitter = uniform_offset(&mut rng, r.start_jitter_m, true);
            let mut spec = base_spec(scene, path);
            spec = r.package.apply(&spec, &mut rng);
            shift(&mut spec.placement, jitter.as_vec3().to_array());
            let start = path.points[0] + jitter;
            let q = path.start_orientation;
            spec.trajectory =
                Arc::new(ToolTrajectory::hold(start.to_array(), [q.x, q.y, q.z, q.w]));
            specs.push(spec);
            starts.push(start);
        }
        let (snapshots, settled) = settle(&self.model, specs, self.config.settle_s)?;
        let min_ratio = self.config.grasp_min_vacuum_ratio;
        let held: Vec<bool> = settled.iter().map(|s| s.grasped(min_ratio)).collect();
        self.replaced_variants = held.iter().filter(|&&h| !h).count();
        self.weak_grasps = settled
            .iter()
            .filter(|s| s.sealed && !s.grasped(min_ratio))
            .count();
        self.grasp_vacuum_ratios = settled.iter().map(|s| s.grasp_vacuum_ratio).collect();
        self.variant_failures = vec![0.0; held.len()];
        self.variants = snapshots
            .into_iter()
            .zip(starts)
            .zip(held)
            .map(|((snapshot, tool_start), held)| {
                if held {
                    Variant {
                        snapshot,
                        tool_start,
                    }
                } else {
                    self.fallback.clone()
                }
            })
            .collect();
        Ok(())
    }

    /// Starts a new episode in copy `env`: a random settled variant, target tilt, path and goal.
    fn start_episode(&mut self, env: usize) -> Result<(), EnvError> {
        if self.variants.is_empty() {
            return Err(EnvError::Simulator("no settled package variant".into()));
        }
        let r = &self.config.randomization;
        let rng = &mut self.rngs[env];
        let variant = match r.replay {
            Some(replay) if !self.retire_finished => {
                replayed_variant(rng, replay.share, &self.variant_failures)
            }
            _ => rng.random_range(0..self.variants.len()),
        };
        let tilt = uniform(rng, r.target_tilt_deg[0], r.target_tilt_deg[1]).to_radians();
        let goal_jitter = uniform_offset(rng, r.goal_jitter_m, false);
        let path = nearest_path(&self.paths, tilt)
            .ok_or_else(|| EnvError::Simulator("no transport path".into()))?;
        let tool_start = self.variants[variant].tool_start;
        self.sim
            .restore(env, &self.variants[variant].snapshot)
            .map_err(sim_error)?;
        self.sim.read_states(&mut self.states).map_err(sim_error)?;
        let state = self.states[env];
        self.episodes[env] = Episode {
            path,
            variant,
            start_offset: tool_start - self.paths[path].points[0],
            goal_jitter,
            target_tilt: tilt,
            previous_object_in_tool: v3(state.disc_in_tool.position),
            start_time: state.time,
            ..Episode::default()
        };
        if self.profile_rate.is_some() {
            // The profile's clock starts at its planned pace.
            self.episodes[env].previous_action[0] = 1.0;
            self.plan_profile(env)?;
        }
        Ok(())
    }

    /// Ends the episodes of the copies `finished` and fills their observation rows: each is
    /// retired in evaluation mode or until its restart (next-step and disabled autoreset), else a
    /// new episode starts in it.
    pub(super) fn finish_episodes(
        &mut self,
        finished: &[usize],
        out: &mut StepBuffers,
    ) -> Result<(), EnvError> {
        self.record_failures(finished);
        let mut restarting = Vec::with_capacity(finished.len());
        for &env in finished {
            if !self.retire_finished && self.autoreset.episode_ended(env) {
                restarting.push(env);
            } else {
                self.sim.retire(env).map_err(sim_error)?;
                self.retired[env] = true;
                self.observe_into(env, out, false);
            }
        }
        self.start_episodes(&restarting, out)
    }

    /// Updates the failure rates of the variants the training episodes of `finished` started
    /// from (in copy order, so the rates do not depend on the thread count).
    fn record_failures(&mut self, finished: &[usize]) {
        let Some(replay) = self.config.randomization.replay else {
            return;
        };
        if self.retire_finished {
            return;
        }
        let width = self.info_names.len();
        for &env in finished {
            let failed = if self.info[env * width + SUCCESS_COLUMN] > 0.5 {
                0.0
            } else {
                1.0
            };
            let rate = &mut self.variant_failures[self.episodes[env].variant];
            *rate = replay.memory * *rate + (1.0 - replay.memory) * failed;
        }
    }

    /// Next-step autoreset: the copies `waiting` (retired since their episode ended in the last
    /// step) start a new episode; their rows hold its first observation, reward 0 and no flag.
    pub(super) fn restart_waiting(
        &mut self,
        waiting: &[usize],
        out: &mut StepBuffers,
    ) -> Result<(), EnvError> {
        self.start_episodes(waiting, out)?;
        let width = self.info_names.len();
        for &env in waiting {
            self.retired[env] = false;
            self.autoreset.restarted(env);
            self.info[env * width..(env + 1) * width].fill(0.0);
            self.observe_into(env, out, true);
        }
        Ok(())
    }

    /// Starts a new episode in each copy of `envs` and fills its observation row.
    fn start_episodes(&mut self, envs: &[usize], out: &mut StepBuffers) -> Result<(), EnvError> {
        for &env in envs {
            self.start_episode(env)?;
        }
        if !envs.is_empty() {
            self.read_loads()?;
            for &env in envs {
                self.start_sensors(env);
                self.observe_into(env, out, false);
            }
        }
        Ok(())
    }
}

/// The line `rlpkg train` and `rlpkg eval` print after a reset: how many of the `settled`
/// randomised packages were `replaced` by the unrandomised one (draws the scene's solver cannot
/// carry at its step, and `weak_grasps` the cell's grasp check refuses).
pub fn replaced_packages_line(settled: usize, replaced: usize, weak_grasps: usize) -> String {
    let mut line = format!(
        "settled packages: {settled}, {replaced} of them replaced by the unrandomised package (not \
         sealed or frozen at the scene's step"
    );
    if weak_grasps > 0 {
        line += &format!(", or {weak_grasps} below the grasp check's vacuum");
    }
    line + ")"
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::test_support::{config, env, test_table};
    use crate::transport::{load_paths, load_scene};
    use rlpkg_vec_env::{AutoresetMode, Seeding};

    /// Two copies on a weak seal: copy 0, driven over-fast, fails within a few steps; copy 1,
    /// held still, reaches the 2 s time limit.
    fn failing_pair() -> impl Fn() -> Transport {
        let text = test_table()
            .replace("settled_variants = 2", "settled_variants = 1")
            .replace("time_limit_s = 12.0", "time_limit_s = 2.0");
        let config = config(&text);
        let mut scene = load_scene(&config, "test.toml").unwrap();
        scene.seal.vacuum_kpa = 7.0;
        let paths = load_paths(&config, scene.disc.hold_at_recorded_start, "test.toml").unwrap();
        move || Transport::with_scene(config.clone(), scene.clone(), paths.clone(), 2).unwrap()
    }

    fn pair_actions(step: usize) -> [f32; 6] {
        let tilt = if step.is_multiple_of(2) { 0.35 } else { -0.35 };
        [0.945, tilt, -tilt, 0.0, 0.0, 0.0]
    }

    #[test]
    fn randomised_values_stay_in_range_and_follow_the_seed_on_any_thread_count() {
        let text = test_table();
        let run = |threads: usize, seed: u64| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let mut t = env(&text, 3);
                let mut out = t.buffers();
                t.try_reset(seed, &mut out).unwrap();
                // Every randomised package of this configuration stays sealed.
                assert_eq!(t.replaced_variants(), 0);
                let conditions: Vec<EpisodeConditions> = (0..3).map(|e| t.conditions(e)).collect();
                (conditions, out)
            })
        };
        let (conditions, out) = run(1, 7);
        for c in &conditions {
            assert!(
                (30f64.to_radians()..=60f64.to_radians()).contains(&c.target_tilt_rad),
                "{c:?}"
            );
            assert!(
                DVec3::from(c.goal_jitter_m).length() <= 0.03 + 1e-12,
                "{c:?}"
            );
            let start = DVec3::from(c.start_offset_m);
            assert!(
                start.length() <= 0.02 + 1e-6 && start.y.abs() < 1e-9,
                "{c:?}"
            );
            assert!((0.287..=0.595).contains(&c.object_mass_kg), "{c:?}");
            assert!(
                c.package_yaw_rad.abs() <= 10f32.to_radians() + 1e-6,
                "{c:?}"
            );
            assert!(c.variant < 2);
            // The path is the recording whose final tilt is nearest the target.
            let nearest = match c.target_tilt_rad.to_degrees() {
                d if d < 39.2 => "HHMHL",
                d if d < 53.9 => "HHHHM",
                _ => "HHHHH",
            };
            if (c.target_tilt_rad.to_degrees() - 39.2).abs() > 0.5
                && (c.target_tilt_rad.to_degrees() - 53.9).abs() > 0.5
            {
                assert_eq!(c.path_id, nearest, "{c:?}");
            }
        }
        assert!(conditions
            .windows(2)
            .any(|w| w[0].target_tilt_rad != w[1].target_tilt_rad));
        let (again, out_again) = run(2, 7);
        assert_eq!(conditions, again);
        assert_eq!(out, out_again, "same seed, two threads: bit-identical");
        let (other, _) = run(1, 8);
        assert_ne!(conditions, other);
    }

    #[test]
    fn the_grasp_check_replaces_exactly_the_packages_whose_cups_read_a_weak_vacuum() {
        // Supply vacuums below the scene's own 20 kPa load the randomised packages' seals more
        // than the unrandomised one's, which must pass the check to stand in for them.
        let text = test_table().replace(
            "package_yaw_deg = [-10.0, 10.0]",
            "package_yaw_deg = [-10.0, 10.0]\nvacuum_kpa = [8.0, 15.0]",
        );
        let with_check = |ratio: f64| {
            text.replace(
                "settle_s = 0.5\n",
                &format!("settle_s = 0.5\ngrasp_min_vacuum_ratio = {ratio}\n"),
            )
        };
        let reset = |text: &str| {
            let mut t = env(text, 2);
            let mut out = t.buffers();
            t.try_reset(7, &mut out).unwrap();
            (t, out)
        };
        let (free, free_out) = reset(&text);
        assert_eq!(free.replaced_variants(), 0);
        let ratios = free.grasp_vacuum_ratios().to_vec();
        // Sealed cups read between the failure load's 0.75 and a sound, unloaded seal's 0.98.
        assert!(
            ratios.len() == 2 && ratios.iter().all(|r| (0.75..0.981).contains(r)),
            "{ratios:?}"
        );
        let (weaker, stronger) = (ratios[0].min(ratios[1]), ratios[0].max(ratios[1]));
        assert!(stronger - weaker > 1e-4, "{ratios:?}");
        // A check both packages pass changes nothing, bit for bit.
        let (loose, loose_out) = reset(&with_check((weaker - 1e-3).max(0.5)));
        assert_eq!((loose.replaced_variants(), loose.weak_grasps()), (0, 0));
        assert_eq!(loose_out, free_out);
        // Between the two: the weaker grasp is replaced, and only it.
        let (strict, _) = reset(&with_check((weaker + stronger) / 2.0));
        assert_eq!((strict.replaced_variants(), strict.weak_grasps()), (1, 1));
        assert_eq!(strict.grasp_vacuum_ratios(), &ratios[..]);
        // A check the scene's own package fails is refused by name.
        let err = Transport::new(config(&with_check(0.98)), 1, "test.toml")
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("grasp_min_vacuum_ratio = 0.98"), "{err}");
    }

    #[test]
    fn retired_copies_stop_while_the_others_run_on_unchanged() {
        // Copy 0 is driven over-fast on a weak seal and fails; copy 1 is held still. With finished
        // copies retired, copy 0 keeps its final observation and earns nothing from then on, and
        // copy 1 runs exactly as it does when finished copies restart.
        let make = failing_pair();
        let (mut retiring, mut restarting) = (make(), make());
        retiring.set_retire_finished(true);
        let (mut a, mut b) = (retiring.buffers(), restarting.buffers());
        retiring.try_reset(5, &mut a).unwrap();
        restarting.try_reset(5, &mut b).unwrap();
        let dim = retiring.spec().observation.dim();
        let mut failed: Option<(usize, Vec<f32>)> = None;
        for step in 0..40 {
            let tilt = if step % 2 == 0 { 0.35 } else { -0.35 };
            let actions = [0.945, tilt, -tilt, 0.0, 0.0, 0.0];
            retiring.step(&actions, &mut a).unwrap();
            restarting.step(&actions, &mut b).unwrap();
            assert_eq!(a.rewards[1], b.rewards[1], "step {step}");
            assert_eq!(a.done(1), b.done(1), "step {step}");
            if a.done(1) {
                assert_eq!(a.final_obs[dim..], b.final_obs[dim..], "step {step}");
            } else {
                assert_eq!(a.obs[dim..], b.obs[dim..], "step {step}");
            }
            match &failed {
                None if a.done(0) => {
                    assert!(a.terminated[0] && b.terminated[0], "step {step}");
                    assert!(retiring.is_retired(0) && !restarting.is_retired(0));
                    // Its row holds the final observation, not a new episode's first one.
                    assert_eq!(a.obs[..dim], a.final_obs[..dim]);
                    assert_ne!(a.obs[..dim], b.obs[..dim]);
                    failed = Some((step, a.obs[..dim].to_vec()));
                }
                Some((_, final_obs)) => {
                    assert!(!a.done(0) && a.rewards[0] == 0.0, "step {step}");
                    assert_eq!(&a.obs[..dim], &final_obs[..], "step {step}");
                }
                None => {}
            }
        }
        let (step, _) = failed.expect("copy 0 failed");
        assert!(step < 39, "failed at step {step}");
        // The held copy reached the time limit in both.
        assert!(a.truncated[1] && b.truncated[1]);
        // A reset brings the retired copy back.
        retiring.try_reset(5, &mut a).unwrap();
        assert!(!retiring.is_retired(0));
    }

    #[test]
    fn next_step_and_disabled_autoreset_around_an_episode_end_on_any_thread_count() {
        let make = failing_pair();
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let started = |mode| {
                    let mut t = make();
                    t.set_autoreset_mode(mode).unwrap();
                    let mut out = t.buffers();
                    t.reset(5, &mut out).unwrap();
                    (t, out)
                };
                let (mut same, mut a) = started(AutoresetMode::SameStep);
                let (mut next, mut b) = started(AutoresetMode::NextStep);
                let (mut off, mut c) = started(AutoresetMode::Disabled);
                let dim = same.spec().observation.dim();
                let mut trace = Vec::new();
                let mut step = 0;
                loop {
                    let actions = pair_actions(step);
                    same.step(&actions, &mut a).unwrap();
                    next.step(&actions, &mut b).unwrap();
                    off.step(&actions, &mut c).unwrap();
                    trace.push(b.clone());
                    for out in [&b, &c] {
                        assert_eq!(out.rewards, a.rewards, "step {step}");
                        assert_eq!(out.terminated, a.terminated, "step {step}");
                        assert_eq!(out.final_obs, a.final_obs, "step {step}");
                    }
                    step += 1;
                    if a.done(0) {
                        break;
                    }
                    assert_eq!((&b.obs, &c.obs), (&a.obs, &a.obs), "step {step}");
                    assert!(step < 39, "copy 0 did not fail");
                }
                // The ending step shows the terminal observation; the restart waits.
                assert!(a.terminated[0] && next.is_retired(0) && !same.is_retired(0));
                assert_eq!(b.obs[..dim], a.final_obs[..dim]);
                assert_eq!(c.obs[..dim], a.final_obs[..dim]);
                let restart = a.obs[..dim].to_vec();
                assert_ne!(&restart[..], &a.final_obs[..dim]);
                // Next step: copy 0 restarts where same-step restarted it (its action ignored,
                // not simulated), reward 0, no flag; copy 1 runs on unchanged.
                let actions = pair_actions(step);
                same.step(&actions, &mut a).unwrap();
                next.step(&actions, &mut b).unwrap();
                trace.push(b.clone());
                assert_eq!(&b.obs[..dim], &restart[..]);
                assert_eq!(&b.final_obs[..dim], &restart[..]);
                assert_eq!((b.rewards[0], b.done(0)), (0.0, false));
                assert!(!next.is_retired(0));
                assert_eq!(b.obs[dim..], a.obs[dim..]);
                assert_eq!(b.rewards[1], a.rewards[1]);
                // The same draws as same-step's restart, a step later.
                assert_eq!(next.conditions(0), same.conditions(0));
                // Disabled: stepping the finished copy fails until it is reset by mask.
                assert!(matches!(
                    off.step(&actions, &mut c),
                    Err(EnvError::FinishedCopy { env: 0 })
                ));
                let before = c.clone();
                let mask = [true, false];
                let copies = ResetCopies {
                    mask: Some(&mask),
                    seeding: Seeding::Continue,
                };
                off.reset_copies(copies, &mut c).unwrap();
                assert_eq!(&c.obs[..dim], &restart[..]);
                assert_eq!(c.obs[dim..], before.obs[dim..]);
                assert_eq!((c.rewards[0], c.done(0)), (0.0, false));
                off.step(&actions, &mut c).unwrap();
                trace
            })
        };
        assert_eq!(run(1), run(2), "next-step: 1 and 2 threads, bit-identical");
    }

    #[test]
    fn copies_are_seeded_one_by_one_and_a_mask_restarts_only_its_copies() {
        let make = failing_pair();
        let (mut per_copy, mut reference) = (make(), make());
        let (mut a, mut b) = (per_copy.buffers(), reference.buffers());
        let seeds = [8, 20];
        let copies = ResetCopies {
            mask: None,
            seeding: Seeding::PerCopy(&seeds),
        };
        per_copy.reset_copies(copies, &mut a).unwrap();
        // Copy 0 as reset(8) draws it; copy 1 from seed 20 = 19 + 1.
        reference.reset(8, &mut b).unwrap();
        assert_eq!(per_copy.conditions(0), reference.conditions(0));
        let dim = reference.spec().observation.dim();
        assert_eq!(a.obs[..dim], b.obs[..dim]);
        // Copy 1 draws its episode as copy 1 of reset(19) does (the settled package variants
        // come from the batch's seed, 8, so only the draws are compared).
        reference.reset(19, &mut b).unwrap();
        let (got, expected) = (per_copy.conditions(1), reference.conditions(1));
        assert_eq!(got.target_tilt_rad, expected.target_tilt_rad);
        assert_eq!(got.goal_jitter_m, expected.goal_jitter_m);
        assert_ne!(got.target_tilt_rad, per_copy.conditions(0).target_tilt_rad);
        // A mask restarts copy 1 only: copy 0's row stays, and it runs on as if nothing happened.
        let (mut masked, mut plain) = (make(), make());
        let (mut m, mut p) = (masked.buffers(), plain.buffers());
        masked.reset(3, &mut m).unwrap();
        plain.reset(3, &mut p).unwrap();
        let hold = [0.0; 6];
        for _ in 0..3 {
            masked.step(&hold, &mut m).unwrap();
            plain.step(&hold, &mut p).unwrap();
        }
        let before = m.clone();
        let mask = [false, true];
        let copies = ResetCopies {
            mask: Some(&mask),
            seeding: Seeding::Base(3),
        };
        masked.reset_copies(copies, &mut m).unwrap();
        assert_eq!(m.obs[..dim], before.obs[..dim]);
        assert_ne!(m.obs[dim..], before.obs[dim..]);
        for _ in 0..3 {
            masked.step(&hold, &mut m).unwrap();
            plain.step(&hold, &mut p).unwrap();
            assert_eq!(m.obs[..dim], p.obs[..dim]);
            assert_eq!(m.rewards[0], p.rewards[0]);
        }
        let wrong = [1, 2, 3];
        let copies = ResetCopies {
            mask: None,
            seeding: Seeding::PerCopy(&wrong),
        };
        assert!(matches!(
            masked.reset_copies(copies, &mut m),
            Err(EnvError::BatchLength { .. })
        ));
    }

    #[test]
    fn failure_replay_draws_the_failing_variants_in_proportion_to_their_failure_rates() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut counts = [0usize; 4];
        for _ in 0..4000 {
            counts[replayed_variant(&mut rng, 1.0, &[0.0, 0.1, 0.3, 0.0])] += 1;
        }
        assert_eq!((counts[0], counts[3]), (0, 0), "{counts:?}");
        assert!((2800..3200).contains(&counts[2]), "{counts:?}");
        // No failure yet, or no share: uniform.
        for (share, failures) in [(1.0, [0.0; 4]), (0.0, [0.0, 0.1, 0.3, 0.0])] {
            let mut counts = [0usize; 4];
            for _ in 0..4000 {
                counts[replayed_variant(&mut rng, share, &failures)] += 1;
            }
            assert!(counts.iter().all(|c| (900..1100).contains(c)), "{counts:?}");
        }
    }

    #[test]
    fn failure_replay_learns_from_training_episodes_only_and_is_saved_with_the_state() {
        // Episodes of 0.2 s that never reach the place pose: each ends timed out, a failure.
        let text = test_table().replace("time_limit_s = 12.0", "time_limit_s = 0.2")
            + "\n[transport.randomization.replay]\nshare = 1.0\nmemory = 0.5\n";
        let hold = [0.0f32; 6];
        let mut t = env(&text, 2);
        let mut out = t.buffers();
        t.try_reset(5, &mut out).unwrap();
        assert_eq!(t.variant_failures, [0.0, 0.0]);
        let started = [t.episodes[0].variant, t.episodes[1].variant];
        for _ in 0..4 {
            t.step(&hold, &mut out).unwrap();
        }
        assert!(
            out.truncated.iter().all(|&x| x),
            "both episodes end at the time limit"
        );
        let mut expected = [0.0; 2];
        for v in started {
            expected[v] = 0.5 * expected[v] + 0.5;
        }
        assert_eq!(t.variant_failures, expected);
        // A saved state carries the rates: the copy draws the same variants from here on.
        let mut copy = env(&text, 2);
        copy.load_state(&t.save_state()).unwrap();
        let mut copy_out = out.clone();
        for _ in 0..8 {
            t.step(&hold, &mut out).unwrap();
            copy.step(&hold, &mut copy_out).unwrap();
            assert_eq!(out, copy_out);
        }
        assert_eq!(t.variant_failures, copy.variant_failures);
        // Evaluation mode neither learns from its episodes nor draws by failure rate.
        let before = t.variant_failures.clone();
        t.set_retire_finished(true);
        for _ in 0..4 {
            t.step(&hold, &mut out).unwrap();
        }
        assert!(out.truncated.iter().any(|&x| x));
        assert_eq!(t.variant_failures, before);
    }
}
