//! Judging a control step: whether the episode failed or the package was placed, the reward term
//! by term (from plain numbers, so each term can be checked on hand-made states and logged
//! separately), the episode's end and the per-step info row.

use glam::DVec3;
use rlpkg_sim::{EnvObservation, SealEventKind};

use super::config::RewardWeights;
use super::geometry::{quat, rotation_between, v3};
use super::Transport;
use crate::StepBuffers;

/// What one control step did, as the reward sees it.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StepOutcome {
    /// Control interval (s).
    pub dt_s: f64,
    /// Path length travelled in the step as a fraction of the whole path.
    pub progress_fraction: f64,
    /// How far the object moved relative to the tool during the step (m).
    pub object_motion_m: f64,
    /// Largest cup utilisation at the end of the step (1 = the seal's limit).
    pub peak_utilisation: f64,
    /// Change of the tool's linear acceleration from the previous step (m/s²).
    pub accel_change_m_s2: f64,
    /// Change of the tool's angular acceleration from the previous step (rad/s²).
    pub angular_accel_change_rad_s2: f64,
    /// The episode failed in this step.
    pub failed: bool,
    /// The package was placed in this step.
    pub succeeded: bool,
}

/// Reward terms of one step (signed: penalties are negative); their sum is the reward.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RewardTerms {
    /// `progress` x path fraction travelled.
    pub progress: f64,
    /// `-time` x interval.
    pub time: f64,
    /// `-object_motion` x object motion relative to the tool.
    pub object_motion: f64,
    /// `-seal` x max(0, peak utilisation - threshold) x interval.
    pub seal: f64,
    /// `-jerk` x change of linear acceleration `- angular_jerk` x change of angular acceleration.
    pub jerk: f64,
    /// `-failure` on the failing step.
    pub failure: f64,
    /// `success` on the placing step.
    pub success: f64,
}

/// Names of the terms, in [`RewardTerms::values`] order.
pub const REWARD_TERM_NAMES: [&str; 7] = [
    "progress",
    "time",
    "object_motion",
    "seal",
    "jerk",
    "failure",
    "success",
];

impl RewardTerms {
    /// The terms of `outcome` under `weights`.
    pub fn of(weights: &RewardWeights, outcome: &StepOutcome) -> Self {
        let w = weights;
        RewardTerms {
            progress: w.progress * outcome.progress_fraction,
            time: -w.time * outcome.dt_s,
            object_motion: -w.object_motion * outcome.object_motion_m,
            seal: -w.seal * (outcome.peak_utilisation - w.seal_threshold).max(0.0) * outcome.dt_s,
            jerk: -w.jerk * outcome.accel_change_m_s2
                - w.angular_jerk * outcome.angular_accel_change_rad_s2,
            failure: if outcome.failed { -w.failure } else { 0.0 },
            success: if outcome.succeeded { w.success } else { 0.0 },
        }
    }

    /// The terms in [`REWARD_TERM_NAMES`] order.
    pub fn values(&self) -> [f64; 7] {
        [
            self.progress,
            self.time,
            self.object_motion,
            self.seal,
            self.jerk,
            self.failure,
            self.success,
        ]
    }

    /// The reward: the sum of the terms.
    pub fn total(&self) -> f64 {
        self.values().iter().sum()
    }
}

/// Why an episode failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Failure {
    /// A cup peeled, was pulled off or slid off (a seal event).
    CupDetached,
    /// No cup holds the package, or the object is further from the tool than allowed.
    Dropped,
    /// The simulator froze the copy (non-finite, exploding, object outside the package).
    Unhealthy,
}

/// Names of the per-step values in [`crate::VecEnv::info`], in order: the reward terms
/// (`reward/<term>`), then episode outcomes (1 on the step an episode ends that way, else 0),
/// then state figures.
pub fn info_names() -> Vec<String> {
    REWARD_TERM_NAMES
        .iter()
        .map(|n| format!("reward/{n}"))
        .chain(
            [
                "episode/success",
                "episode/failure_cup_detached",
                "episode/failure_dropped",
                "episode/failure_unhealthy",
                "episode/truncated",
                "state/peak_seal_utilisation",
                "state/object_motion_m",
                "state/path_speed_m_s",
            ]
            .iter()
            .map(|n| n.to_string()),
        )
        .collect()
}

/// How the tool and the object moved in one copy's step.
#[derive(Debug, Clone, Copy)]
struct StepMotion {
    /// The tool's linear acceleration over the step (m/s²).
    accel: DVec3,
    /// The tool's angular acceleration over the step (rad/s²).
    angular_accel: DVec3,
    /// The object's position in the tool frame at the end of the step (m).
    object_in_tool: DVec3,
    /// How far the object moved relative to the tool during the step (m).
    object_motion_m: f64,
    /// Largest cup utilisation at the end of the step.
    peak_utilisation: f64,
}

/// Column of `episode/success` in the info row: after the reward terms.
pub(super) const SUCCESS_COLUMN: usize = REWARD_TERM_NAMES.len();

/// The info row of one step, in [`info_names`] order.
fn info_row(
    terms: &RewardTerms,
    failure: Option<Failure>,
    succeeded: bool,
    truncated: bool,
    motion: &StepMotion,
    path_speed: f64,
) -> Vec<f64> {
    let mut info: Vec<f64> = terms.values().to_vec();
    let flag = |b: bool| if b { 1.0 } else { 0.0 };
    info.extend([
        flag(succeeded),
        flag(failure == Some(Failure::CupDetached)),
        flag(failure == Some(Failure::Dropped)),
        flag(failure == Some(Failure::Unhealthy)),
        flag(truncated),
        motion.peak_utilisation,
        motion.object_motion_m,
        path_speed,
    ]);
    info
}

impl Transport {
    /// Judges copy `env`'s step, which began in state `start`: writes its reward, its
    /// terminated / truncated flags and its info row, and carries the step's motion into the
    /// episode. Returns whether the episode ended.
    pub(super) fn score_step(
        &mut self,
        env: usize,
        start: &EnvObservation,
        out: &mut StepBuffers,
    ) -> bool {
        let failure = self.failure(env);
        let succeeded = failure.is_none() && self.placed(env);
        let motion = self.motion(env, start);
        let outcome = self.outcome(env, &motion, failure.is_some(), succeeded);
        let terms = RewardTerms::of(&self.config.reward, &outcome);
        let episode = &mut self.episodes[env];
        episode.previous_accel = motion.accel;
        episode.previous_angular_accel = motion.angular_accel;
        episode.previous_object_in_tool = motion.object_in_tool;
        episode.steps += 1;
        let terminated = failure.is_some() || succeeded;
        let truncated = !terminated && episode.steps >= self.spec.max_episode_steps;
        out.rewards[env] = terms.total() as f32;
        out.terminated[env] = terminated;
        out.truncated[env] = truncated;
        let info = info_row(
            &terms,
            failure,
            succeeded,
            truncated,
            &motion,
            episode.path_speed,
        );
        let n = self.info_names.len();
        for (slot, &x) in self.info[env * n..(env + 1) * n].iter_mut().zip(&info) {
            *slot = x as f32;
        }
        terminated || truncated
    }

    /// Why copy `env`'s episode failed in the last step, if it did: its first seal event, else a
    /// health freeze, else the object beyond the failure distance.
    fn failure(&self, env: usize) -> Option<Failure> {
        let state = &self.states[env];
        let mut failure = None;
        for event in self.seal.iter().filter(|e| e.env == env) {
            failure = failure.or(match event.kind {
                SealEventKind::Dropped => Some(Failure::Dropped),
                _ => Some(Failure::CupDetached),
            });
        }
        if state.frozen || self.health.iter().any(|e| e.env == env) {
            failure = failure.or(Some(Failure::Unhealthy));
        }
        let object = v3(state.disc_in_tool.position);
        if object.length() > self.config.failure.max_object_distance_m {
            failure = failure.or(Some(Failure::Dropped));
        }
        failure
    }

    /// Whether copy `env` is at the place pose within the tolerances, with the object settled.
    fn placed(&self, env: usize) -> bool {
        let episode = &self.episodes[env];
        let tol = &self.config.success;
        let state = &self.states[env];
        let (goal_p, goal_q) = self.goal(episode);
        episode.progress >= self.paths[episode.path].length_m
            && (goal_p - v3(state.tool_position)).length() <= tol.position_m
            && rotation_between(quat(state.tool_orientation), goal_q).length()
                <= tol.orientation_deg.to_radians()
            && v3(state.tool_velocity).length() <= tol.tool_speed_m_s
            && v3(state.disc_in_tool.velocity).length() <= tol.object_speed_m_s
    }

    /// Largest utilisation of copy `env`'s cups now.
    pub(super) fn peak_utilisation(&self, env: usize) -> f64 {
        let cups = self.model.num_cups();
        self.loads[env * cups..(env + 1) * cups]
            .iter()
            .map(|c| c.utilisation as f64)
            .fold(0.0, f64::max)
    }

    /// How copy `env`'s tool and object moved since `start`, one control interval earlier.
    fn motion(&self, env: usize, start: &EnvObservation) -> StepMotion {
        let state = &self.states[env];
        let object_in_tool = v3(state.disc_in_tool.position);
        StepMotion {
            accel: (v3(state.tool_velocity) - v3(start.tool_velocity)) / self.dt,
            angular_accel: (v3(state.tool_angular_velocity) - v3(start.tool_angular_velocity))
                / self.dt,
            object_in_tool,
            object_motion_m: (object_in_tool - self.episodes[env].previous_object_in_tool).length(),
            peak_utilisation: self.peak_utilisation(env),
        }
    }

    /// What copy `env`'s step did as the reward sees it (before the episode takes `motion` in).
    fn outcome(
        &self,
        env: usize,
        motion: &StepMotion,
        failed: bool,
        succeeded: bool,
    ) -> StepOutcome {
        let episode = &self.episodes[env];
        let first = episode.steps == 0;
        StepOutcome {
            dt_s: self.dt,
            progress_fraction: episode.last_advance / self.paths[episode.path].length_m,
            object_motion_m: motion.object_motion_m,
            peak_utilisation: motion.peak_utilisation,
            accel_change_m_s2: if first {
                motion.accel.length()
            } else {
                (motion.accel - episode.previous_accel).length()
            },
            angular_accel_change_rad_s2: if first {
                motion.angular_accel.length()
            } else {
                (motion.angular_accel - episode.previous_angular_accel).length()
            },
            failed,
            succeeded,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::test_support::{column, config, env, info, test_table};
    use crate::transport::{load_paths, load_scene};
    use crate::VecEnv;

    fn weights() -> RewardWeights {
        RewardWeights {
            progress: 10.0,
            time: 0.5,
            object_motion: 20.0,
            seal: 4.0,
            seal_threshold: 0.5,
            jerk: 0.01,
            angular_jerk: 0.002,
            failure: 30.0,
            success: 15.0,
        }
    }

    #[test]
    fn each_term_follows_its_weight_on_a_hand_made_step() {
        let outcome = StepOutcome {
            dt_s: 0.05,
            progress_fraction: 0.02,
            object_motion_m: 0.003,
            peak_utilisation: 0.75,
            accel_change_m_s2: 2.0,
            angular_accel_change_rad_s2: 5.0,
            failed: false,
            succeeded: false,
        };
        let t = RewardTerms::of(&weights(), &outcome);
        let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
        assert!(close(t.progress, 0.2), "{t:?}");
        assert!(close(t.time, -0.025), "{t:?}");
        assert!(close(t.object_motion, -0.06), "{t:?}");
        // 4 x (0.75 - 0.5) x 0.05
        assert!(close(t.seal, -0.05), "{t:?}");
        // 0.01 x 2 + 0.002 x 5
        assert!(close(t.jerk, -0.03), "{t:?}");
        assert_eq!((t.failure, t.success), (0.0, 0.0));
        assert!(close(t.total(), 0.2 - 0.025 - 0.06 - 0.05 - 0.03));
    }

    #[test]
    fn seal_term_is_zero_below_the_threshold_and_outcomes_pay_once() {
        let calm = StepOutcome {
            dt_s: 0.05,
            peak_utilisation: 0.3,
            ..StepOutcome::default()
        };
        assert_eq!(RewardTerms::of(&weights(), &calm).seal, 0.0);
        let failed = RewardTerms::of(
            &weights(),
            &StepOutcome {
                failed: true,
                ..calm
            },
        );
        assert_eq!(failed.failure, -30.0);
        let placed = RewardTerms::of(
            &weights(),
            &StepOutcome {
                succeeded: true,
                ..calm
            },
        );
        assert_eq!((placed.success, placed.failure), (15.0, 0.0));
        // Standing still costs time and nothing else.
        assert!((RewardTerms::of(&weights(), &calm).total() + 0.025).abs() < 1e-12);
    }

    #[test]
    fn time_out_is_truncated_with_the_true_final_observation() {
        let text = test_table().replace("time_limit_s = 12.0", "time_limit_s = 0.2");
        let mut t = env(&text, 2);
        assert_eq!(t.spec().max_episode_steps, 4);
        let mut out = t.buffers();
        t.try_reset(3, &mut out).unwrap();
        // Standing still at the pick pose: nothing fails, nothing is placed.
        let actions = vec![0.0f32; 6];
        for step in 1..=4 {
            t.step(&actions, &mut out).unwrap();
            for e in 0..2 {
                assert!(!out.terminated[e], "step {step}");
                assert_eq!(out.truncated[e], step == 4, "step {step}");
            }
        }
        let dt = t.control_interval_s() as f32;
        for e in 0..2 {
            // The final row is where the episode ended; the row now holds the next episode's start.
            let ended = column(&t, &out, e, "episode_time", true);
            assert!((ended - 4.0 * dt).abs() < 1e-4, "{ended}");
            assert_eq!(column(&t, &out, e, "episode_time", false), 0.0);
            assert_eq!(info(&t, e, "episode/truncated"), 1.0);
            assert_eq!(info(&t, e, "reward/failure"), 0.0);
            assert_eq!(info(&t, e, "reward/progress"), 0.0);
            // The reward is the sum of the reported terms.
            let terms: f32 = REWARD_TERM_NAMES
                .iter()
                .map(|n| info(&t, e, &format!("reward/{n}")))
                .sum();
            assert!(
                (out.rewards[e] - terms).abs() < 1e-5,
                "{} vs {terms}",
                out.rewards[e]
            );
        }
    }

    #[test]
    fn over_fast_episode_fails_with_a_seal_event_and_is_terminated() {
        // A weak vacuum (7 kPa: 8.8 N per cup) holds the settled package at rest; full speed with the
        // tilt offsets flipping between their bounds then loads a cup beyond its seal.
        let config = config(&test_table().replace("settled_variants = 2", "settled_variants = 1"));
        let mut scene = load_scene(&config, "test.toml").unwrap();
        scene.seal.vacuum_kpa = 7.0;
        let paths = load_paths(&config, scene.disc.hold_at_recorded_start, "test.toml").unwrap();
        let mut t = Transport::with_scene(config, scene, paths, 1).unwrap();
        let mut out = t.buffers();
        t.try_reset(5, &mut out).unwrap();
        let mut failed_at = None;
        for step in 0..60 {
            // Full speed, and the tilt offsets flipping between their bounds every step.
            let tilt = if step % 2 == 0 { 0.35 } else { -0.35 };
            t.step(&[0.945, tilt, -tilt], &mut out).unwrap();
            if out.done(0) {
                failed_at = Some(step);
                break;
            }
        }
        let step = failed_at.expect("the over-fast episode ended");
        assert!(out.terminated[0] && !out.truncated[0], "step {step}");
        assert_eq!(info(&t, 0, "episode/success"), 0.0);
        assert_eq!(info(&t, 0, "episode/failure_cup_detached"), 1.0);
        // The simulator reported the cup's failure: peeled, pulled off or slid, at full load.
        let event = t
            .seal_events()
            .iter()
            .find(|e| e.env == 0 && e.cup.is_some())
            .expect("a seal event of a cup");
        assert!(
            matches!(
                event.kind,
                SealEventKind::Peeled | SealEventKind::PulledOff | SealEventKind::Slid
            ),
            "{event:?}"
        );
        assert!(event.load.utilisation >= 1.0, "{event:?}");
        // At rest the same seal held (the package was settled and sealed), and the path speed had
        // reached its limit: the failure comes from the motion.
        assert!(step >= 3, "failed after {step} steps");
        assert_eq!(info(&t, 0, "state/path_speed_m_s"), 0.945);
        assert_eq!(info(&t, 0, "reward/failure"), -30.0);
        assert!(out.rewards[0] < -20.0, "{}", out.rewards[0]);
    }
}
