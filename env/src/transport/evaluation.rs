//! An evaluation of a transport policy beside the baselines over the same seeded, randomised
//! episodes: the scripted baseline (the recorded high-velocity path, time-scaled), the profile
//! baseline (the time-optimal, jerk-limited motion along the episode's path under scaled tool
//! limits, the tilt a smooth blend over the path), the open-loop commands of `rlpkg optimize`
//! outputs and the recorded baselines (a recording's timing along the episode's path); optionally
//! the policy on the recordings' own conditions. [`evaluate_policy`] returns the report, the
//! per-episode table and the traces and snapshots its plots and animation are drawn from; it
//! writes nothing.

use std::path::Path;
use std::sync::Arc;

use rlpkg_mocap::{Dataset, Split};
use serde::Serialize;

use super::governor::VacuumGovernor;
use super::optimize::output::OptimizedCommand;
use super::run_error::{check, RunError};
use super::{
    load_paths, load_scene, recorded_timings, run_traced_episodes, spec_of, EpisodeTable,
    MotionLimits, OutcomeSummary, PathProfile, TiltSchedule, TracePoint, Transport,
    TransportConfig, TransportPath,
};
use crate::VecEnv;

/// The evaluated policy's actions for `n` rows of actor observations, its errors as [`RunError`]s.
type Act<'a> = dyn Fn(&[f32], usize) -> Result<Vec<f32>, RunError> + 'a;

/// Deterministic actions of the evaluated policy for `n` rows of actor observations.
pub type PolicyActions<'a> =
    dyn Fn(&[f32], usize) -> Result<Vec<f32>, Box<dyn std::error::Error + Send + Sync>> + 'a;

/// Which recordings of the run's dataset the policy is also evaluated on, each on its own
/// conditions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RecordingSet {
    /// Every recording of the dataset.
    All,
    /// The recordings of one split.
    Split(Split),
}

/// What an evaluation runs besides the policy.
#[derive(Debug, Clone)]
pub struct EvaluationSettings {
    /// Randomised episodes per driver (one environment copy each).
    pub episodes: usize,
    /// Seed of the episodes' draws.
    pub seed: u64,
    /// Time scales of the scripted baseline (the recorded high-velocity path, S times as fast).
    pub scripted: Vec<f64>,
    /// Scales of the tool's motion limits of the profile baseline.
    pub profile: Vec<f64>,
    /// Open-loop commands of `rlpkg optimize` outputs, each played from every episode's start.
    pub optimized: Vec<OptimizedCommand>,
    /// Vacuum governors of the task's own plan ([`VacuumGovernor`]; `0:0` is the plan at rate 1).
    pub governors: Vec<VacuumGovernor>,
    /// Velocity levels (`low`, `medium`, `high`) of the recorded baselines.
    pub recorded: Vec<String>,
    /// Recordings on whose own conditions the policy is also evaluated.
    pub trajectories: Option<RecordingSet>,
}

/// The report of an evaluation (`summary.json` of `rlpkg eval` holds it).
#[derive(Debug, Clone, Serialize)]
pub struct EvaluationReport {
    /// Seed of the episodes.
    pub seed: u64,
    /// Randomised packages the episodes start from, how many of them the scene's solver could not
    /// carry (not sealed or frozen after settling) or the grasp check refused and were replaced by
    /// the unrandomised one, and how many of those the grasp check refused.
    pub settled_packages: usize,
    pub replaced_packages: usize,
    pub weak_grasps: usize,
    /// Recorded baselines: velocity level, and for each path the recording whose timing it plays.
    pub recorded: Vec<RecordedBaseline>,
    /// The motion limits that scale 1 of the profile baseline stands for.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub profile: Option<ProfileBaseline>,
    /// The `rlpkg optimize` results whose commands have rows.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub optimized: Vec<OptimizedCommand>,
    /// One row per driver: the policy, then the scripted, profile, optimized and recorded
    /// baselines.
    pub rows: Vec<OutcomeSummary>,
    /// The policy and the recording itself on each recording's own conditions.
    pub trajectories: Vec<OutcomeSummary>,
}

/// The recordings one recorded baseline takes its timing from.
#[derive(Debug, Clone, Serialize)]
pub struct RecordedBaseline {
    /// Velocity level (`low`, `medium`, `high`).
    pub velocity: String,
    /// `path id -> recording id` for each configured path.
    pub timings: Vec<(String, String)>,
}

/// The limits of the profile baseline's rows (`profile xS`: every limit times S).
#[derive(Debug, Clone, Serialize)]
pub struct ProfileBaseline {
    /// The tool's own limits of `[transport.limits]`, with jerks that reach its accelerations in
    /// [`super::JERK_RAMP_S`].
    pub base_limits: MotionLimits,
    pub scales: Vec<f64>,
}

/// Package, cups and disc of copy 0 at one control step.
#[derive(Debug, Clone)]
pub struct Snapshot {
    /// Time since the episode's start (s).
    pub time_s: f32,
    /// Package particles, then cup particles.
    pub positions: Vec<[f32; 3]>,
    pub disc: rlpkg_sim::DiscState,
}

/// The randomised episode 0 driven by the policy and by the medium-velocity recording's timing:
/// same package, same time axis, every control step until each ends.
#[derive(Debug, Clone)]
pub struct EpisodeFilm {
    pub by_policy: Vec<Snapshot>,
    pub by_recording: Vec<Snapshot>,
    /// The medium-velocity recording whose timing the episode's path played.
    pub recording_id: String,
    /// The simulator's model (particle counts, triangles, disc).
    pub model: Arc<rlpkg_sim::Model>,
}

/// The policy and one recording on the recording's own conditions.
#[derive(Debug, Clone)]
pub struct RecordingComparison {
    /// The recording's id.
    pub id: String,
    /// The traces of `policy` and `recording <id>`.
    pub traces: Vec<(String, Vec<TracePoint>)>,
}

/// Everything an evaluation found.
#[derive(Debug, Clone)]
pub struct TransportEvaluation {
    pub report: EvaluationReport,
    /// One row per driver and episode (`episodes.csv`).
    pub episodes: EpisodeTable,
    /// Episode 0 of the policy and of each recorded baseline.
    pub first_episode: Vec<(String, Vec<TracePoint>)>,
    pub film: EpisodeFilm,
    /// One per recording of [`EvaluationSettings::trajectories`].
    pub recordings: Vec<RecordingComparison>,
}

/// Evaluates `policy` (on the task `transport` describes; `source` is its configuration file),
/// beside the baselines of `settings`, over `settings.episodes` randomised episodes from
/// `settings.seed`. `stop` is asked between control steps.
pub fn evaluate_policy(
    transport: &TransportConfig,
    source: &str,
    settings: &EvaluationSettings,
    policy: &PolicyActions,
    stop: &dyn Fn() -> bool,
) -> Result<TransportEvaluation, RunError> {
    let (seed, episodes) = (settings.seed, settings.episodes);
    let act = |obs: &[f32], n: usize| {
        check(stop)?;
        policy(obs, n).map_err(RunError::Policy)
    };
    // The baselines drive with path speeds, whatever the policy's first action is.
    let baseline = |config: TransportConfig, copies: usize| {
        Transport::new(config, copies, source)
            .map(|mut env| {
                env.drive_path_speed();
                env
            })
            .map_err(RunError::input)
    };
    let held_out = match settings.trajectories {
        Some(set) => Some(held_out_configs(transport, set, source)?),
        None => None,
    };
    // Every recorded baseline's timings before anything is simulated: an unknown level is refused
    // at once.
    let recorded_levels = settings
        .recorded
        .iter()
        .map(|velocity| recorded_timings(transport, velocity, source).map(|t| (velocity, t)))
        .collect::<Result<Vec<_>, _>>()
        .map_err(RunError::input)?;
    let governor_columns = if settings.governors.is_empty() {
        Vec::new()
    } else {
        let spec = spec_of(transport, source).map_err(RunError::input)?;
        VacuumGovernor::vacuum_columns(transport, &spec, source)?
    };
    let mut rows = Vec::new();
    let mut first_episode: Vec<(String, Vec<TracePoint>)> = Vec::new();
    let mut env = Transport::new(transport.clone(), episodes, source).map_err(RunError::input)?;
    let (outcomes, mut traces) =
        run_traced_episodes::<RunError>(&mut env, seed, &[0], |_, obs| act(obs, episodes))?;
    rows.push(OutcomeSummary::of("policy", &outcomes));
    let mut table = EpisodeTable::default();
    table.add("policy", &env, &outcomes);
    let (settled_packages, replaced_packages, weak_grasps) = (
        transport.settled_variants,
        env.replaced_variants(),
        env.weak_grasps(),
    );
    first_episode.push(("policy".into(), traces.remove(0)));
    for &scale in &settings.scripted {
        let mut env = baseline(transport.clone(), episodes)?;
        let (outcomes, _) = run_traced_episodes::<RunError>(&mut env, seed, &[], |env, _| {
            check(stop)?;
            Ok(env.scripted_actions(scale))
        })?;
        let driver = format!("scripted x{scale}");
        rows.push(OutcomeSummary::of(&driver, &outcomes));
        table.add(&driver, &env, &outcomes);
    }
    let base_limits = MotionLimits::of_tool(&transport.limits);
    for &scale in &settings.profile {
        let limits = base_limits.scaled(scale);
        let mut env = baseline(transport.clone(), episodes)?;
        env.set_tilt_schedule(TiltSchedule::MinimumJerk);
        // Planned once per episode, right after the reset that draws it.
        let mut plans: Option<Vec<PathProfile>> = None;
        let (outcomes, _) = run_traced_episodes::<RunError>(&mut env, seed, &[], |env, _| {
            check(stop)?;
            if plans.is_none() {
                plans = Some(env.plan_profiles(&limits)?);
            }
            Ok(env.profile_actions(plans.as_deref().unwrap_or_default()))
        })?;
        let driver = format!("profile x{scale}");
        rows.push(OutcomeSummary::of(&driver, &outcomes));
        table.add(&driver, &env, &outcomes);
    }
    for command in &settings.optimized {
        let mut env = baseline(transport.clone(), episodes)?;
        let (outcomes, _) = run_traced_episodes::<RunError>(&mut env, seed, &[], |env, _| {
            check(stop)?;
            Ok(env.open_loop_actions(&command.library))
        })?;
        rows.push(OutcomeSummary::of(&command.driver, &outcomes));
        table.add(&command.driver, &env, &outcomes);
    }
    let max_rate = transport.profile_rate.map_or(1.0, |p| p.max_rate);
    for governor in &settings.governors {
        // The policy's own pipeline (plan, delays, sensors), not the baselines' path speeds.
        let mut env =
            Transport::new(transport.clone(), episodes, source).map_err(RunError::input)?;
        let (outcomes, _) = run_traced_episodes::<RunError>(&mut env, seed, &[], |env, obs| {
            check(stop)?;
            Ok(governor.actions(env, obs, &governor_columns, max_rate))
        })?;
        let driver = governor.label();
        rows.push(OutcomeSummary::of(&driver, &outcomes));
        table.add(&driver, &env, &outcomes);
    }
    let mut recorded = Vec::new();
    for (velocity, timings) in recorded_levels {
        // The same episodes, with time to finish the slowest recording (the low-velocity ones
        // take 19-22 s): the time limit does not change what an episode draws.
        let mut long = transport.clone();
        long.time_limit_s = long.time_limit_s.max(longest_timing_s(&timings) * 1.25);
        let mut env = baseline(long, episodes)?;
        let (outcomes, mut traces) =
            run_traced_episodes::<RunError>(&mut env, seed, &[0], |env, _| {
                check(stop)?;
                Ok(env.timed_actions(&timings, 1.0))
            })?;
        let driver = format!("recorded {velocity}");
        rows.push(OutcomeSummary::of(&driver, &outcomes));
        table.add(&driver, &env, &outcomes);
        first_episode.push((driver, traces.remove(0)));
        recorded.push(RecordedBaseline {
            velocity: velocity.clone(),
            timings: transport
                .paths
                .iter()
                .cloned()
                .zip(timings.iter().map(|t| t.id.clone()))
                .collect(),
        });
    }
    let film = film_beside_medium(transport, source, seed, &act, stop)?;
    let mut recordings = Vec::new();
    let mut trajectories = Vec::new();
    for (id, held) in held_out.into_iter().flatten() {
        let mut traced = Vec::new();
        let mut env = Transport::new(held, 1, source).map_err(RunError::input)?;
        let (outcomes, mut traces) =
            run_traced_episodes::<RunError>(&mut env, seed, &[0], |_, obs| act(obs, 1))?;
        trajectories.push(OutcomeSummary::of(&format!("{id} policy"), &outcomes));
        traced.push(("policy".to_string(), traces.remove(0)));
        env.drive_path_speed();
        let (outcomes, mut traces) =
            run_traced_episodes::<RunError>(&mut env, seed, &[0], |env, _| {
                check(stop)?;
                Ok(env.scripted_actions(1.0))
            })?;
        trajectories.push(OutcomeSummary::of(&format!("{id} recorded"), &outcomes));
        traced.push((format!("recording {id}"), traces.remove(0)));
        recordings.push(RecordingComparison { id, traces: traced });
    }
    Ok(TransportEvaluation {
        report: EvaluationReport {
            seed,
            settled_packages,
            replaced_packages,
            weak_grasps,
            recorded,
            profile: (!settings.profile.is_empty()).then(|| ProfileBaseline {
                base_limits,
                scales: settings.profile.clone(),
            }),
            optimized: settings.optimized.clone(),
            rows,
            trajectories,
        },
        episodes: table,
        first_episode,
        film,
        recordings,
    })
}

/// Duration of the longest recording in `timings` (s).
fn longest_timing_s(timings: &[TransportPath]) -> f64 {
    timings
        .iter()
        .map(|t| t.recorded_duration_s)
        .fold(0.0, f64::max)
}

/// For each recording of `set` of the run's dataset, the run's transport configuration set to
/// that recording's own conditions: its path, object mass and placement tilt, no jitter and no
/// randomisation, and time to finish at its own pace.
fn held_out_configs(
    base: &TransportConfig,
    set: RecordingSet,
    source: &str,
) -> Result<Vec<(String, TransportConfig)>, RunError> {
    let split = match set {
        RecordingSet::All => None,
        RecordingSet::Split(split) => Some(split),
    };
    let dataset = Dataset::open(Path::new(&base.recordings))
        .map_err(|e| RunError::Input(format!("transport.recordings: {e}")))?;
    let scene = load_scene(base, source).map_err(RunError::input)?;
    dataset
        .ids(split)
        .into_iter()
        .map(|id| {
            let mut config = base.clone();
            config.paths = vec![id.clone()];
            let path = load_paths(&config, scene.disc.hold_at_recorded_start, source)
                .map_err(RunError::input)?
                .remove(0);
            let tilt = path.recorded_final_tilt_rad.to_degrees();
            config.time_limit_s = config.time_limit_s.max(path.recorded_duration_s * 1.25);
            config.settled_variants = 1;
            let r = &mut config.randomization;
            r.target_tilt_deg = [tilt, tilt];
            r.goal_jitter_m = 0.0;
            r.start_jitter_m = 0.0;
            let p = &mut r.package;
            p.object_mass_kg = None;
            p.disc_mass_scale = None;
            p.object_offset_m = 0.0;
            p.object_tilt_deg = 0.0;
            p.package_yaw_deg = [0.0, 0.0];
            p.param_scale
                .values_mut()
                .for_each(|range| *range = [1.0, 1.0]);
            Ok((id, config))
        })
        .collect()
}

/// Runs copy 0's first episode (the randomised episode 0 of `seed`) with `act`, capturing every
/// control step until it ends.
fn play(
    env: &mut Transport,
    seed: u64,
    mut act: impl FnMut(&Transport, &[f32]) -> Result<Vec<f32>, RunError>,
) -> Result<Vec<Snapshot>, RunError> {
    let capture = |env: &Transport| Snapshot {
        time_s: env.trace_point(0).time_s as f32,
        positions: env.simulator().particle_positions(0),
        disc: env.simulator().disc(0),
    };
    let mut buffers = env.buffers();
    env.set_retire_finished(true);
    env.try_reset(seed, &mut buffers)?;
    let mut snapshots = vec![capture(env)];
    loop {
        let actions = act(env, &buffers.obs)?;
        env.step(&actions, &mut buffers)?;
        snapshots.push(capture(env));
        if buffers.done(0) {
            return Ok(snapshots);
        }
    }
}

/// The randomised episode 0 of `seed` driven by the policy (`act`) and by the medium-velocity
/// recording's timing.
fn film_beside_medium(
    transport: &TransportConfig,
    source: &str,
    seed: u64,
    act: &Act,
    stop: &dyn Fn() -> bool,
) -> Result<EpisodeFilm, RunError> {
    let medium = recorded_timings(transport, "medium", source).map_err(RunError::input)?;
    let mut env = Transport::new(transport.clone(), 1, source).map_err(RunError::input)?;
    let by_policy = play(&mut env, seed, |_, obs| act(obs, 1))?;
    let mut slow = transport.clone();
    slow.time_limit_s = slow.time_limit_s.max(longest_timing_s(&medium) * 1.25);
    let mut env = Transport::new(slow, 1, source).map_err(RunError::input)?;
    env.drive_path_speed();
    let by_recording = play(&mut env, seed, |env, _| {
        check(stop)?;
        Ok(env.timed_actions(&medium, 1.0))
    })?;
    let path_id = env.conditions(0).path_id;
    let timing = transport
        .paths
        .iter()
        .position(|p| *p == path_id)
        .unwrap_or(0);
    Ok(EpisodeFilm {
        by_policy,
        by_recording,
        recording_id: medium[timing].id.clone(),
        model: env.simulator().model().clone(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::test_support::{config, test_table};

    /// A constant command for every row: half speed along the path, no tilt offset.
    fn steady(
        _obs: &[f32],
        n: usize,
    ) -> Result<Vec<f32>, Box<dyn std::error::Error + Send + Sync>> {
        Ok([0.5, 0.0, 0.0].repeat(n))
    }

    /// The drivers of the report's rows, in order.
    fn drivers(found: &TransportEvaluation) -> Vec<&str> {
        found
            .report
            .rows
            .iter()
            .map(|r| r.driver.as_str())
            .collect()
    }

    fn settings(recorded: &[&str]) -> EvaluationSettings {
        EvaluationSettings {
            episodes: 1,
            seed: 3,
            scripted: vec![1.25],
            profile: Vec::new(),
            optimized: Vec::new(),
            governors: Vec::new(),
            recorded: recorded.iter().map(|v| v.to_string()).collect(),
            trajectories: None,
        }
    }

    #[test]
    fn the_policy_and_each_baseline_have_a_row_over_the_same_episodes() {
        let transport = config(&test_table());
        let found = evaluate_policy(
            &transport,
            "test.toml",
            &settings(&["high"]),
            &steady,
            &|| false,
        )
        .unwrap();
        assert_eq!(
            drivers(&found),
            ["policy", "scripted x1.25", "recorded high"]
        );
        assert!(found.report.rows.iter().all(|r| r.episodes == 1));
        assert_eq!(
            found.report.recorded[0].timings.len(),
            transport.paths.len()
        );
        // The policy's and the recorded baseline's episode 0, each from its start to its end.
        let traced: Vec<&str> = found
            .first_episode
            .iter()
            .map(|(d, _)| d.as_str())
            .collect();
        assert_eq!(traced, ["policy", "recorded high"]);
        assert!(found.first_episode.iter().all(|(_, t)| t.len() > 1));
        let film = &found.film;
        assert!(film.by_policy.len() > 1 && film.by_recording.len() > 1);
        assert_eq!(
            film.by_policy[0].positions.len(),
            film.model.num_particles()
        );
        // One header, then one line per driver and episode.
        assert_eq!(found.episodes.csv().lines().count(), 1 + 3);
    }

    #[test]
    fn governors_play_the_tasks_own_plan_and_need_its_sensors() {
        let with_plan = |table: String| {
            config(
                &(table
                    + "\n[transport.profile_rate]\nlimits_scale = 1.0\nmax_rate = 1.0\n\
                       max_rate_change_per_s = 4.0\n"),
            )
        };
        let mut settings = settings(&[]);
        settings.scripted.clear();
        settings.governors = vec![VacuumGovernor::PLAN, "0.9:0.7".parse().unwrap()];
        let transport = with_plan(crate::transport::test_support::sensors_table());
        let found =
            evaluate_policy(&transport, "test.toml", &settings, &steady, &|| false).unwrap();
        assert_eq!(drivers(&found), ["policy", "plan x1", "governor 0.9:0.7"]);
        // Without sensors there is nothing to govern on: refused before any episode.
        let transport = with_plan(test_table());
        let err = evaluate_policy(&transport, "test.toml", &settings, &steady, &|| -> bool {
            panic!("no episode may start")
        })
        .unwrap_err();
        assert!(
            matches!(&err, RunError::Input(m) if m.contains("test.toml") && m.contains("sensors")),
            "{err}"
        );
    }

    #[test]
    fn a_stop_request_ends_the_evaluation() {
        let transport = config(&test_table());
        let err = evaluate_policy(&transport, "test.toml", &settings(&[]), &steady, &|| true)
            .unwrap_err();
        assert!(matches!(err, RunError::Stopped), "{err}");
    }

    #[test]
    fn an_unknown_velocity_level_is_the_users_error() {
        let transport = config(&test_table());
        let err = evaluate_policy(
            &transport,
            "test.toml",
            &settings(&["brisk"]),
            &steady,
            &|| false,
        )
        .unwrap_err();
        assert!(matches!(err, RunError::Input(_)), "{err}");
    }
}
