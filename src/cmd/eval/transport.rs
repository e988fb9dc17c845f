//! `rlpkg eval runs/<transport run>` and `rlpkg eval --policy <file.onnx> --config <file.toml>`:
//! the trained policy (the run's checkpoint, or the exported file through tract), the scripted
//! baseline (the recorded high-velocity path, time-scaled), the profile baseline (the time-optimal,
//! jerk-limited motion along the episode's path under scaled tool limits, the tilt a smooth blend
//! over the path), the open-loop commands of `rlpkg optimize` runs and the recorded baselines over
//! the same seeded, randomised episodes, side by side.

use std::path::{Path, PathBuf};

use anyhow::Context;

use rlpkg_agents::export::OnnxPolicy;
use rlpkg_agents::TrainedPolicy;
use rlpkg_env::transport::{
    load_paths, load_scene, recorded_timings, run_traced_episodes, CommandLibrary, EpisodeTable,
    KnotCurve, MotionLimits, OutcomeSummary, PathProfile, TiltSchedule, TracePoint,
    TransportConfig, TransportPath,
};
use rlpkg_env::Transport;
use rlpkg_vec_env::{EnvError, VecEnv};
use serde::Serialize;

use super::EvalArgs;
use crate::error::input_error;
use crate::render::plot::write_transport_plot;

/// What `rlpkg eval` prints for a transport policy.
#[derive(Serialize)]
struct TransportReport {
    /// The run folder or the ONNX file evaluated.
    run: String,
    /// The checkpoint's update and environment steps (none for an exported file).
    update: Option<usize>,
    global_step: Option<u64>,
    seed: u64,
    /// Randomised packages the episodes start from, how many of them the scene's solver could not
    /// carry (not sealed or frozen after settling) or the grasp check refused and were replaced by
    /// the unrandomised one, and how many of those the grasp check refused.
    settled_packages: usize,
    replaced_packages: usize,
    weak_grasps: usize,
    /// Recorded baselines: velocity level, and for each path the recording whose timing it plays.
    recorded: Vec<RecordedBaseline>,
    /// `--profile`: the motion limits that scale 1 of the profile baseline stands for.
    #[serde(skip_serializing_if = "Option::is_none")]
    profile: Option<ProfileBaseline>,
    /// `--optimized`: the `rlpkg optimize` results whose commands have rows.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    optimized: Vec<OptimizedCommand>,
    rows: Vec<OutcomeSummary>,
    /// `--trajectories`: the policy and the recording itself on each recording's own conditions.
    trajectories: Vec<OutcomeSummary>,
    /// Plots written (PNG).
    plots: Vec<String>,
}

/// The recordings one recorded baseline takes its timing from.
#[derive(Serialize)]
struct RecordedBaseline {
    velocity: String,
    /// `path id -> recording id` for each configured path.
    timings: Vec<(String, String)>,
}

/// The limits of the profile baseline's rows (`profile xS`: every limit times S).
#[derive(Serialize)]
struct ProfileBaseline {
    /// The tool's own limits of `[transport.limits]`, with jerks that reach its accelerations in
    /// [`rlpkg_env::transport::JERK_RAMP_S`].
    base_limits: MotionLimits,
    scales: Vec<f64>,
}

/// The best open-loop command of an `rlpkg optimize` output folder (its `summary.json`), or
/// the commands of a library (one per target tilt, for the nominal package).
#[derive(Serialize)]
struct OptimizedCommand {
    /// The row's driver name: `optimized <folder name>`.
    driver: String,
    folder: PathBuf,
    /// `[conditions]` of the optimisation: the seed of its packages and how many (K).
    seed: u64,
    packages: u64,
    /// A library's target tilts (degrees); empty for one command.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    target_tilts_deg: Vec<f64>,
    /// Its risk (cost) on its own packages (a library's: the mean over its commands).
    best_cost: f64,
    #[serde(skip)]
    library: CommandLibrary,
}

/// Reads the best command of the `rlpkg optimize` output `folder`, or its library's commands;
/// a missing or malformed `summary.json` is an input error naming the file and key.
fn load_optimized(folder: &Path) -> anyhow::Result<OptimizedCommand> {
    let file = folder.join("summary.json");
    let text = std::fs::read_to_string(&file).map_err(|e| {
        input_error(format!(
            "--optimized {}: cannot read {}: {e}; expected an `rlpkg optimize` output folder",
            folder.display(),
            file.display()
        ))
    })?;
    let summary: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| input_error(format!("{}: {e}; expected JSON", file.display())))?;
    let get = |key: &str| summary.pointer(&format!("/{}", key.replace('.', "/")));
    let bad = |key: &str, expected: &str| {
        let found = get(key).map_or("missing".into(), |v| v.to_string());
        input_error(format!(
            "{}: `{key}` is {found}; expected {expected}",
            file.display()
        ))
    };
    let count = get("config.knots.count")
        .and_then(serde_json::Value::as_u64)
        .filter(|&n| (2..=1000).contains(&n))
        .ok_or_else(|| bad("config.knots.count", "an integer in [2, 1000]"))?;
    let horizon_s = get("config.knots.horizon_s")
        .and_then(serde_json::Value::as_f64)
        .filter(|h| h.is_finite() && *h > 0.0)
        .ok_or_else(|| bad("config.knots.horizon_s", "a time > 0 s"))?;
    let curve = KnotCurve {
        knots: count as usize,
        horizon_s,
    };
    let knots_at = |key: &str| {
        get(key)
            .and_then(serde_json::Value::as_array)
            .map(|values| {
                values
                    .iter()
                    .filter_map(serde_json::Value::as_f64)
                    .collect::<Vec<_>>()
            })
            .filter(|k: &Vec<f64>| k.len() == curve.dimension() && k.iter().all(|v| v.is_finite()))
            .ok_or_else(|| {
                bad(
                    key,
                    &format!(
                        "{} finite numbers (3 x config.knots.count)",
                        curve.dimension()
                    ),
                )
            })
    };
    let number = |key: &str, expected: &str| {
        get(key)
            .and_then(serde_json::Value::as_f64)
            .filter(|v| v.is_finite())
            .ok_or_else(|| bad(key, expected))
    };
    let (commands, target_tilts_deg, best_cost) = match get("library")
        .and_then(serde_json::Value::as_array)
    {
        Some(entries) if !entries.is_empty() => {
            let (mut commands, mut tilts) = (Vec::new(), Vec::new());
            let mut cost = 0.0;
            for i in 0..entries.len() {
                let tilt = number(&format!("library.{i}.target_tilt_deg"), "a tilt in degrees")?;
                let knots = knots_at(&format!("library.{i}.best_knots"))?;
                commands.push((tilt.to_radians(), knots));
                tilts.push(tilt);
                cost += number(&format!("library.{i}.best_cost"), "a number")?;
            }
            (commands, tilts, cost / entries.len() as f64)
        }
        Some(_) => return Err(bad("library", "at least one command")),
        None => (
            vec![(0.0, knots_at("best_knots")?)],
            Vec::new(),
            number("best_cost", "a number")?,
        ),
    };
    let integer = |key: &str, expected: &str| {
        get(key)
            .and_then(serde_json::Value::as_u64)
            .ok_or_else(|| bad(key, expected))
    };
    let name = folder.file_name().map_or_else(
        || folder.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    Ok(OptimizedCommand {
        driver: format!("optimized {name}"),
        folder: folder.to_path_buf(),
        seed: integer("config.conditions.seed", "an integer >= 0")?,
        packages: integer("config.conditions.packages", "an integer >= 1")?,
        target_tilts_deg,
        best_cost,
        library: CommandLibrary { curve, commands },
    })
}

/// Deterministic actions for `n` rows of observations.
type Act<'a> = dyn Fn(&[f32], usize) -> anyhow::Result<Vec<f32>> + 'a;

/// The policy a transport evaluation drives with.
struct Driver<'a> {
    /// What is evaluated (run folder or ONNX file), as printed.
    name: String,
    /// The checkpoint's update and environment steps (a run folder).
    checkpoint: Option<(usize, u64)>,
    /// Deterministic actions for `n` rows of observations.
    act: Box<Act<'a>>,
    /// Where plots, the animation and `summary.json` go.
    out: PathBuf,
}

/// Evaluates `policy` (read from `run`, trained on the task `transport` describes; `source` is the
/// run's configuration file) beside the baselines (see [`evaluate`]); writes to `run/eval/`.
pub fn run(
    run: &Path,
    policy: &TrainedPolicy,
    transport: &TransportConfig,
    source: &str,
    episodes: usize,
    args: &EvalArgs,
) -> anyhow::Result<()> {
    policy
        .check_evaluation_memory(episodes)
        .map_err(input_error)?;
    let driver = Driver {
        name: run.display().to_string(),
        checkpoint: Some((policy.update, policy.global_step)),
        act: Box::new(|obs, n| Ok(policy.act(obs, n))),
        out: run.join("eval"),
    };
    evaluate(&driver, transport, source, episodes, args)
}

/// Evaluates the exported file `policy` (at `path`) on the task `transport` describes (`source`
/// is its configuration file) beside the baselines, exactly as [`run`] does a run's checkpoint;
/// writes to `<file stem>-eval/` beside the file.
pub fn run_onnx(
    path: &Path,
    policy: &OnnxPolicy,
    transport: &TransportConfig,
    source: &str,
    episodes: usize,
    args: &EvalArgs,
) -> anyhow::Result<()> {
    let stem = path
        .file_stem()
        .map_or("policy".into(), |s| s.to_string_lossy().into_owned());
    let driver = Driver {
        name: path.display().to_string(),
        checkpoint: None,
        act: Box::new(|obs, n| Ok(policy.act(obs, n)?)),
        out: path.with_file_name(format!("{stem}-eval")),
    };
    evaluate(&driver, transport, source, episodes, args)
}

/// Evaluates `driver`'s policy, the scripted baseline at each time scale of `args.scripted`, the
/// profile baseline at each limit scale of `args.profile` and the recorded baseline of each
/// velocity level in `args.recorded` over `episodes` randomised episodes from `args.seed` (and
/// `args.trajectories`' recordings) of the task `transport` describes; prints the table (or JSON), writes plots, an animation and `summary.json` to
/// `driver.out`.
fn evaluate(
    driver: &Driver,
    transport: &TransportConfig,
    source: &str,
    episodes: usize,
    args: &EvalArgs,
) -> anyhow::Result<()> {
    let (seed, scales, json) = (args.seed, &args.scripted, args.json);
    let recorded: Vec<&str> = match args.recorded.as_slice() {
        [none] if none == "none" => Vec::new(),
        levels => levels.iter().map(String::as_str).collect(),
    };
    if let Some(bad) = recorded
        .iter()
        .find(|v| !["low", "medium", "high"].contains(v))
    {
        return Err(input_error(format!(
            "--recorded {bad}: expected velocity levels low, medium, high (comma-separated) or none"
        )));
    }
    if let Some(bad) = scales
        .iter()
        .find(|s| !(s.is_finite() && **s > 0.0 && **s <= 10.0))
    {
        return Err(input_error(format!(
            "--scripted {bad}: expected time scales in (0, 10]"
        )));
    }
    if let Some(bad) = args
        .profile
        .iter()
        .find(|s| !(s.is_finite() && **s > 0.0 && **s <= 10.0))
    {
        return Err(input_error(format!(
            "--profile {bad}: expected scales of the tool's motion limits in (0, 10]"
        )));
    }
    let optimized = args
        .optimized
        .iter()
        .map(|folder| load_optimized(folder))
        .collect::<anyhow::Result<Vec<_>>>()?;
    // A signal stops the episodes at the next control step; the plots, the GIF and summary.json
    // are written whole or not at all.
    let _cooperation = crate::interrupt::Cooperation::start();
    let act = &driver.act;
    let make = || Transport::new(transport.clone(), episodes, source);
    // The baselines drive with path speeds, whatever the policy's first action is.
    let baseline = |config: TransportConfig, copies: usize| {
        Transport::new(config, copies, source).map(|mut env| {
            env.drive_path_speed();
            env
        })
    };
    let held_out = match args.trajectories.as_deref() {
        Some(split) => Some(held_out_configs(transport, split, source)?),
        None => None,
    };
    let mut rows = Vec::new();
    // Episode 0 of the policy and of each recorded baseline, plotted together.
    let mut first_episode: Vec<(String, Vec<TracePoint>)> = Vec::new();
    let mut env = make().map_err(input_error)?;
    let (outcomes, mut traces) =
        run_traced_episodes::<anyhow::Error>(&mut env, seed, &[0], |_, obs| {
            crate::interrupt::check()?;
            act(obs, episodes)
        })?;
    rows.push(OutcomeSummary::of("policy", &outcomes));
    let mut episode_table = EpisodeTable::default();
    episode_table.add("policy", &env, &outcomes);
    let (settled_packages, replaced_packages, weak_grasps) = (
        transport.settled_variants,
        env.replaced_variants(),
        env.weak_grasps(),
    );
    first_episode.push(("policy".into(), traces.remove(0)));
    for &scale in scales {
        let mut env = baseline(transport.clone(), episodes).map_err(input_error)?;
        let (outcomes, _) = run_traced_episodes::<anyhow::Error>(&mut env, seed, &[], |env, _| {
            crate::interrupt::check()?;
            Ok(env.scripted_actions(scale))
        })?;
        let driver = format!("scripted x{scale}");
        rows.push(OutcomeSummary::of(&driver, &outcomes));
        episode_table.add(&driver, &env, &outcomes);
    }
    let base_limits = MotionLimits::of_tool(&transport.limits);
    for &scale in &args.profile {
        let limits = base_limits.scaled(scale);
        let mut env = baseline(transport.clone(), episodes).map_err(input_error)?;
        env.set_tilt_schedule(TiltSchedule::MinimumJerk);
        // Planned once per episode, right after the reset that draws it.
        let mut plans: Option<Vec<PathProfile>> = None;
        let (outcomes, _) = run_traced_episodes::<anyhow::Error>(&mut env, seed, &[], |env, _| {
            crate::interrupt::check()?;
            if plans.is_none() {
                plans = Some(env.plan_profiles(&limits)?);
            }
            Ok(env.profile_actions(plans.as_deref().unwrap_or_default()))
        })?;
        let driver = format!("profile x{scale}");
        rows.push(OutcomeSummary::of(&driver, &outcomes));
        episode_table.add(&driver, &env, &outcomes);
    }
    for command in &optimized {
        let mut env = baseline(transport.clone(), episodes).map_err(input_error)?;
        let (outcomes, _) = run_traced_episodes::<anyhow::Error>(&mut env, seed, &[], |env, _| {
            crate::interrupt::check()?;
            Ok(env.open_loop_actions(&command.library))
        })?;
        rows.push(OutcomeSummary::of(&command.driver, &outcomes));
        episode_table.add(&command.driver, &env, &outcomes);
    }
    let mut baselines = Vec::new();
    for velocity in recorded {
        let timings = recorded_timings(transport, velocity, source).map_err(input_error)?;
        // The same episodes, with time to finish the slowest recording (the low-velocity ones
        // take 19-22 s): the time limit does not change what an episode draws.
        let mut long = transport.clone();
        long.time_limit_s = long.time_limit_s.max(longest_timing_s(&timings) * 1.25);
        let mut env = baseline(long, episodes).map_err(input_error)?;
        let (outcomes, mut traces) =
            run_traced_episodes::<anyhow::Error>(&mut env, seed, &[0], |env, _| {
                crate::interrupt::check()?;
                Ok(env.timed_actions(&timings, 1.0))
            })?;
        let driver = format!("recorded {velocity}");
        rows.push(OutcomeSummary::of(&driver, &outcomes));
        episode_table.add(&driver, &env, &outcomes);
        first_episode.push((format!("recorded {velocity}"), traces.remove(0)));
        baselines.push(RecordedBaseline {
            velocity: velocity.to_string(),
            timings: transport
                .paths
                .iter()
                .cloned()
                .zip(timings.iter().map(|t| t.id.clone()))
                .collect(),
        });
    }
    let out = driver.out.clone();
    std::fs::create_dir_all(&out)
        .map_err(|e| input_error(format!("{}: cannot create: {e}", out.display())))?;
    let mut plots = Vec::new();
    let plot = out.join("episode-0.png");
    write_transport_plot(
        &plot,
        &format!("randomised episode 0 (seed {seed})"),
        &first_episode,
    )?;
    plots.push(plot.display().to_string());
    let medium = recorded_timings(transport, "medium", source).map_err(input_error)?;
    let (animation, still) = (out.join("episode-0.gif"), out.join("episode-0-end.png"));
    render_beside_medium((&animation, &still), transport, source, &medium, seed, act)?;
    plots.extend([&animation, &still].map(|p| p.display().to_string()));
    let mut trajectory_rows = Vec::new();
    for (id, held) in held_out.into_iter().flatten() {
        let mut drivers = Vec::new();
        let mut env = Transport::new(held.clone(), 1, source).map_err(input_error)?;
        let (outcomes, mut traces) =
            run_traced_episodes::<anyhow::Error>(&mut env, seed, &[0], |_, obs| {
                crate::interrupt::check()?;
                act(obs, 1)
            })?;
        trajectory_rows.push(OutcomeSummary::of(&format!("{id} policy"), &outcomes));
        drivers.push(("policy".to_string(), traces.remove(0)));
        env.drive_path_speed();
        let (outcomes, mut traces) =
            run_traced_episodes::<anyhow::Error>(&mut env, seed, &[0], |env, _| {
                crate::interrupt::check()?;
                Ok(env.scripted_actions(1.0))
            })?;
        trajectory_rows.push(OutcomeSummary::of(&format!("{id} recorded"), &outcomes));
        drivers.push((format!("recording {id}"), traces.remove(0)));
        let plot = out.join(format!("{id}.png"));
        write_transport_plot(&plot, &format!("{id}: its mass, tilt and poses"), &drivers)?;
        plots.push(plot.display().to_string());
    }
    let report = TransportReport {
        run: driver.name.clone(),
        update: driver.checkpoint.map(|c| c.0),
        global_step: driver.checkpoint.map(|c| c.1),
        seed,
        settled_packages,
        replaced_packages,
        weak_grasps,
        recorded: baselines,
        profile: (!args.profile.is_empty()).then(|| ProfileBaseline {
            base_limits,
            scales: args.profile.clone(),
        }),
        optimized,
        rows,
        trajectories: trajectory_rows,
        plots,
    };
    let trained = match driver.checkpoint {
        Some((update, steps)) => format!("update {update}, {steps} steps"),
        None => "exported policy, through tract".to_string(),
    };
    let mut text = format!(
        "{} ({trained}): {} randomised episodes from seed {} per driver; \
         scripted xS = the recorded high-velocity path played S times as fast\n",
        report.run, episodes, seed
    );
    text += &replaced_packages_line(
        report.settled_packages,
        report.replaced_packages,
        report.weak_grasps,
    );
    text.push('\n');
    if let Some(p) = &report.profile {
        let l = &p.base_limits;
        text += &format!(
            "profile xS = the time-optimal, jerk-limited motion along the episode's path, the tilt \
             a minimum-jerk blend over the path, with S x the tool's limits: {:.3} m/s, {:.3} m/s^2, {:.3} m/s^3, {:.3} rad/s, {:.3} rad/s^2, \
             {:.3} rad/s^3\n",
            l.speed_m_s,
            l.accel_m_s2,
            l.jerk_m_s3,
            l.angular_speed_rad_s,
            l.angular_accel_rad_s2,
            l.angular_jerk_rad_s3
        );
    }
    for o in &report.optimized {
        text += &match o.target_tilts_deg.as_slice() {
            [] => format!(
                "{} = the best open-loop command of {} (optimised over {} package(s) of seed {}, risk {:.3}), played from each episode's start\n",
                o.driver,
                o.folder.display(),
                o.packages,
                o.seed,
                o.best_cost
            ),
            tilts => format!(
                "{} = the open-loop commands of {} optimised for the nominal package at target tilts {tilts:?} degrees (mean cost {:.3}), each episode playing the one nearest its tilt\n",
                o.driver,
                o.folder.display(),
                o.best_cost
            ),
        };
    }
    for b in &report.recorded {
        let pairs: Vec<String> = b
            .timings
            .iter()
            .map(|(path, timing)| format!("{path} with {timing}'s timing"))
            .collect();
        text += &format!("recorded {}: {}\n", b.velocity, pairs.join(", "));
    }
    text += &OutcomeSummary::table(&report.rows);
    if !report.trajectories.is_empty() {
        text += "recordings' own conditions (mass, placement tilt, pick and place poses; no \
                 randomisation): the policy and the recording's own timing along its path\n";
        text += &OutcomeSummary::table(&report.trajectories);
    }
    let summary = out.join("summary.json");
    let report_json = serde_json::to_string_pretty(&report)?;
    crate::files::write_atomic(&summary, report_json.as_bytes())?;
    let per_episode = out.join("episodes.csv");
    crate::files::write_atomic(&per_episode, episode_table.csv().as_bytes())?;
    text += &format!(
        "plots: {}\nsummary: {}\nper episode: {}\n",
        report.plots.join(", "),
        summary.display(),
        per_episode.display()
    );
    if json {
        println!("{report_json}");
        eprint!("{text}");
    } else {
        print!("{text}");
    }
    Ok(())
}

/// Duration of the longest recording in `timings` (s).
fn longest_timing_s(timings: &[TransportPath]) -> f64 {
    timings
        .iter()
        .map(|t| t.recorded_duration_s)
        .fold(0.0, f64::max)
}

/// For each recording of `split` (`test`, `train` or `all`) of the run's dataset, the run's
/// transport configuration set to that recording's own conditions: its path, object mass and
/// placement tilt, no jitter and no randomisation, and time to finish at its own pace.
fn held_out_configs(
    base: &TransportConfig,
    split: &str,
    source: &str,
) -> anyhow::Result<Vec<(String, TransportConfig)>> {
    let split_filter = match split {
        "all" => None,
        other => Some(
            other
                .parse::<rlpkg_mocap::Split>()
                .map_err(|e| input_error(format!("--trajectories {other}: {e} (or `all`)")))?,
        ),
    };
    let dataset = rlpkg_mocap::Dataset::open(Path::new(&base.recordings))
        .map_err(|e| input_error(format!("transport.recordings: {e}")))?;
    let scene = load_scene(base, source).map_err(input_error)?;
    dataset
        .ids(split_filter)
        .into_iter()
        .map(|id| {
            let mut config = base.clone();
            config.paths = vec![id.clone()];
            let path = load_paths(&config, scene.disc.hold_at_recorded_start, source)
                .map_err(input_error)?
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

/// Package, cups and disc of copy 0 at one control step, for the animation.
struct Snapshot {
    time_s: f32,
    /// Package particles, then cup particles.
    positions: Vec<[f32; 3]>,
    disc: rlpkg_sim::DiscState,
}

/// Runs copy 0's first episode (the randomised episode 0 of `seed`) with `act`, capturing every
/// control step until it ends.
fn play<E: From<EnvError>>(
    env: &mut Transport,
    seed: u64,
    mut act: impl FnMut(&Transport, &[f32]) -> Result<Vec<f32>, E>,
) -> Result<Vec<Snapshot>, E> {
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

/// Animates the randomised episode 0 of `seed` driven by the policy beside the same episode
/// driven by the medium-velocity recording's timing (`medium`): same package, same time axis
/// (GIF at `path`), with a still of the moment the policy's episode ends.
fn render_beside_medium(
    (path, still): (&Path, &Path),
    transport: &TransportConfig,
    source: &str,
    medium: &[TransportPath],
    seed: u64,
    act: &Act,
) -> anyhow::Result<()> {
    use crate::render::{write_png_side_by_side, Bounds, Disc, Frame, GifWriter, View};
    let mut env = Transport::new(transport.clone(), 1, source).map_err(input_error)?;
    let by_policy = play::<anyhow::Error>(&mut env, seed, |_, obs| {
        crate::interrupt::check()?;
        act(obs, 1)
    })?;
    let mut slow = transport.clone();
    slow.time_limit_s = slow.time_limit_s.max(longest_timing_s(medium) * 1.25);
    let mut env = Transport::new(slow, 1, source).map_err(input_error)?;
    env.drive_path_speed();
    let by_recording = play::<anyhow::Error>(&mut env, seed, |env, _| {
        crate::interrupt::check()?;
        Ok(env.timed_actions(medium, 1.0))
    })?;
    let model = env.simulator().model().clone();
    let package = model.num_package;
    let triangles: Vec<[u32; 3]> = model.package_triangles.iter().map(|t| t.idx).collect();
    let (radius, thickness) = (model.disc.radius, 2.0 * model.disc.half_height);
    let mut scene = Bounds::empty();
    by_policy
        .iter()
        .chain(&by_recording)
        .flat_map(|s| &s.positions)
        .for_each(|&p| scene.include(p));
    let mut close_up = Bounds::empty();
    by_policy[0].positions[..package]
        .iter()
        .for_each(|&p| close_up.include(p));
    // Room below the package for it to sag around the disc.
    close_up.include(close_up.min - 0.08 * glam::Vec3::Y);
    let (scene, close_up) = (scene.padded(0.03), close_up.padded(0.02));
    const PANEL: (u32, u32) = (640, 360);
    let view = View::new(&scene, &close_up, PANEL.0, PANEL.1);
    let interval = by_policy
        .get(1)
        .map_or(0.05, |s| s.time_s - by_policy[0].time_s);
    let mut gif = GifWriter::create(path, (2 * PANEL.0, PANEL.1), interval)
        .with_context(|| format!("writing {}", path.display()))?;
    let path_id = env.conditions(0).path_id;
    let timing = transport
        .paths
        .iter()
        .position(|p| *p == path_id)
        .unwrap_or(0);
    let titles = [
        "policy".to_string(),
        format!("medium-velocity recording {}'s timing", medium[timing].id),
    ];
    let steps = by_policy.len().max(by_recording.len());
    for k in 0..steps {
        crate::interrupt::check()?;
        let snapshots = [&by_policy, &by_recording].map(|s| &s[k.min(s.len() - 1)]);
        let frames: Vec<Frame> = snapshots
            .iter()
            .zip(&titles)
            .map(|(s, title)| Frame {
                title,
                time: s.time_s,
                package: &s.positions[..package],
                triangles: &triangles,
                cups: &s.positions[package..],
                disc: Some(Disc {
                    center: s.disc.position,
                    rotation: s.disc.orientation,
                    radius,
                    thickness,
                }),
                recorded_markers: &[],
                simulated_markers: &[],
                recorded_object: None,
            })
            .collect();
        let pair = [(&frames[0], &view), (&frames[1], &view)];
        if k + 1 == by_policy.len() {
            write_png_side_by_side(still, &pair)
                .with_context(|| format!("writing {}", still.display()))?;
        }
        gif.add_side_by_side(&pair)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    gif.finish()
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// The line `rlpkg train` and `rlpkg eval` print after a reset: how many of the settled randomised
/// packages were replaced by the unrandomised one (draws the scene's solver cannot carry at its
/// step, and grasps the cell's grasp check refuses).
pub(crate) fn replaced_packages_line(
    settled: usize,
    replaced: usize,
    weak_grasps: usize,
) -> String {
    let mut line = format!(
        "settled packages: {settled}, {replaced} of them replaced by the unrandomised package (not \
         sealed or frozen at the scene's step"
    );
    if weak_grasps > 0 {
        line += &format!(", or {weak_grasps} below the grasp check's vacuum");
    }
    line + ")"
}
