//! `rlpkg eval runs/<transport run>` and `rlpkg eval --policy <file.onnx> --config <file.toml>`:
//! the trained policy (the run's checkpoint, or the exported file through tract) beside the
//! baselines over the same seeded, randomised episodes ([`rlpkg_env::transport::evaluate_policy`]);
//! this module reads the options, prints the table (or JSON) and writes the plots, the animation,
//! `summary.json` and `episodes.csv`.

use std::path::{Path, PathBuf};

use anyhow::Context;

use rlpkg_agents::export::OnnxPolicy;
use rlpkg_agents::TrainedPolicy;
use rlpkg_env::transport::{
    evaluate_policy, replaced_packages_line, EpisodeFilm, EvaluationReport, EvaluationSettings,
    OptimizedCommand, OptimizedReadError, OutcomeSummary, PolicyActions, RecordingSet,
    TransportConfig,
};
use serde::Serialize;

use super::EvalArgs;
use crate::error::{input_error, run_error};
use crate::render::plot::write_transport_plot;

/// What `rlpkg eval` prints for a transport policy (`summary.json`).
#[derive(Serialize)]
struct TransportSummary<'a> {
    /// The run folder or the ONNX file evaluated.
    run: String,
    /// The checkpoint's update and environment steps (none for an exported file).
    update: Option<usize>,
    global_step: Option<u64>,
    #[serde(flatten)]
    report: &'a EvaluationReport,
    /// Plots written (PNG).
    plots: Vec<String>,
}

/// The policy a transport evaluation drives with.
struct Driver<'a> {
    /// What is evaluated (run folder or ONNX file), as printed.
    name: String,
    /// The checkpoint's update and environment steps (a run folder).
    checkpoint: Option<(usize, u64)>,
    /// Deterministic actions for `n` rows of observations.
    act: Box<PolicyActions<'a>>,
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

/// The evaluation `args` ask for: the scripted baseline at each time scale of `args.scripted`,
/// the profile baseline at each limit scale of `args.profile`, the commands of `args.optimized`
/// and the recorded baseline of each velocity level in `args.recorded` over `episodes`
/// randomised episodes from `args.seed`, and `args.trajectories`' recordings.
fn settings(args: &EvalArgs, episodes: usize) -> anyhow::Result<EvaluationSettings> {
    let recorded: Vec<String> = match args.recorded.as_slice() {
        [none] if none == "none" => Vec::new(),
        levels => levels.to_vec(),
    };
    if let Some(bad) = recorded
        .iter()
        .find(|v| !["low", "medium", "high"].contains(&v.as_str()))
    {
        return Err(input_error(format!(
            "--recorded {bad}: expected velocity levels low, medium, high (comma-separated) or none"
        )));
    }
    if let Some(bad) = args
        .scripted
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
        .map(|folder| {
            OptimizedCommand::read(folder).map_err(|e| match e {
                OptimizedReadError::Read { .. } => {
                    input_error(format!("--optimized {}: {e}", folder.display()))
                }
                OptimizedReadError::Malformed(message) => input_error(message),
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let trajectories = match args.trajectories.as_deref() {
        None => None,
        Some("all") => Some(RecordingSet::All),
        Some(other) => Some(RecordingSet::Split(other.parse().map_err(|e| {
            input_error(format!("--trajectories {other}: {e} (or `all`)"))
        })?)),
    };
    Ok(EvaluationSettings {
        episodes,
        seed: args.seed,
        scripted: args.scripted.clone(),
        profile: args.profile.clone(),
        optimized,
        governors: args.governor.clone(),
        recorded,
        trajectories,
    })
}

/// Evaluates `driver`'s policy beside the baselines `args` ask for on the task `transport`
/// describes; prints the table (or JSON), writes plots, an animation, `summary.json` and
/// `episodes.csv` to `driver.out`.
fn evaluate(
    driver: &Driver,
    transport: &TransportConfig,
    source: &str,
    episodes: usize,
    args: &EvalArgs,
) -> anyhow::Result<()> {
    let settings = settings(args, episodes)?;
    let seed = settings.seed;
    // A signal stops the episodes at the next control step; the plots, the GIF and summary.json
    // are written whole or not at all.
    let _cooperation = crate::interrupt::Cooperation::start();
    let evaluation = evaluate_policy(
        transport,
        source,
        &settings,
        &*driver.act,
        &crate::interrupt::requested,
    )
    .map_err(run_error)?;
    let report = &evaluation.report;
    let out = driver.out.clone();
    std::fs::create_dir_all(&out)
        .map_err(|e| input_error(format!("{}: cannot create: {e}", out.display())))?;
    let mut plots = Vec::new();
    let plot = out.join("episode-0.png");
    write_transport_plot(
        &plot,
        &format!("randomised episode 0 (seed {seed})"),
        &evaluation.first_episode,
    )?;
    plots.push(plot.display().to_string());
    let (animation, still) = (out.join("episode-0.gif"), out.join("episode-0-end.png"));
    render_film((&animation, &still), &evaluation.film)?;
    plots.extend([&animation, &still].map(|p| p.display().to_string()));
    for recording in &evaluation.recordings {
        let id = &recording.id;
        let plot = out.join(format!("{id}.png"));
        write_transport_plot(
            &plot,
            &format!("{id}: its mass, tilt and poses"),
            &recording.traces,
        )?;
        plots.push(plot.display().to_string());
    }
    let summary = TransportSummary {
        run: driver.name.clone(),
        update: driver.checkpoint.map(|c| c.0),
        global_step: driver.checkpoint.map(|c| c.1),
        report,
        plots,
    };
    let trained = match driver.checkpoint {
        Some((update, steps)) => format!("update {update}, {steps} steps"),
        None => "exported policy, through tract".to_string(),
    };
    let mut text = format!(
        "{} ({trained}): {} randomised episodes from seed {} per driver; \
         scripted xS = the recorded high-velocity path played S times as fast\n",
        summary.run, episodes, seed
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
    let summary_file = out.join("summary.json");
    let summary_json = serde_json::to_string_pretty(&summary)?;
    crate::files::write_atomic(&summary_file, summary_json.as_bytes())?;
    let per_episode = out.join("episodes.csv");
    crate::files::write_atomic(&per_episode, evaluation.episodes.csv().as_bytes())?;
    text += &format!(
        "plots: {}\nsummary: {}\nper episode: {}\n",
        summary.plots.join(", "),
        summary_file.display(),
        per_episode.display()
    );
    if args.json {
        println!("{summary_json}");
        eprint!("{text}");
    } else {
        print!("{text}");
    }
    Ok(())
}

/// Animates `film`: the randomised episode 0 driven by the policy beside the same episode driven
/// by the medium-velocity recording's timing, same package, same time axis (GIF at `path`), with
/// a still of the moment the policy's episode ends.
fn render_film((path, still): (&Path, &Path), film: &EpisodeFilm) -> anyhow::Result<()> {
    use crate::render::{write_png_side_by_side, Bounds, Disc, Frame, GifWriter, View};
    let EpisodeFilm {
        by_policy,
        by_recording,
        recording_id,
        model,
    } = film;
    let package = model.num_package;
    let triangles: Vec<[u32; 3]> = model.package_triangles.iter().map(|t| t.idx).collect();
    let (radius, thickness) = (model.disc.radius, 2.0 * model.disc.half_height);
    let mut scene = Bounds::empty();
    by_policy
        .iter()
        .chain(by_recording)
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
    let titles = [
        "policy".to_string(),
        format!("medium-velocity recording {recording_id}'s timing"),
    ];
    let steps = by_policy.len().max(by_recording.len());
    for k in 0..steps {
        crate::interrupt::check()?;
        let snapshots = [by_policy, by_recording].map(|s| &s[k.min(s.len() - 1)]);
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
