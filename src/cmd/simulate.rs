//! `rlpkg simulate`: replays a recorded tool trajectory in the simulator with the reference scene
//! placement (`reference-model.md` §1: package at the row-0 markers, cups around the initial cup
//! point, disc at the object's x/z and the markers' mean y, a rest period first) and writes the
//! simulated marker sites and disc pose as CSV, per-frame errors against the recording, PNG stills
//! and an animated GIF.
//!
//! Files under `--out` (one CSV row per recorded frame, t = recording time, metres):
//! * `markers_sim.csv`: `frame, t`, then `m<i>_x, m<i>_y, m<i>_z` for every row-0 marker of
//!   `meta.toml` (in its order) embedded in the upper sheet, then `g<m>_x, g<m>_y, g<m>_z` for the
//!   42 points of the nominal 6 x 7 marker grid (row-major; the reference's loss points).
//! * `object_sim.csv`: `t, px, py, pz, qx, qy, qz, qw` (disc centre and orientation).
//! * `metrics.csv`: `frame, t, chamfer_m, object_error_m`: the symmetric mean nearest-neighbour
//!   distance between the 42 grid points and that frame's recorded markers, and the distance between
//!   the simulated and recorded disc centres.
//! * `summary.json`: settings, wall time, means and maxima, and the reference's per-second sums.
//! * `frames/NNN_t<time>s.png` stills and `replay.gif` (rest period included, t < 0).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use glam::{DVec3, Vec3};
use indicatif::{ProgressBar, ProgressStyle};
use rlpkg_mocap::{load_trajectory, Trajectory};
use rlpkg_replay::loss::chamfer_distance;
use rlpkg_replay::Target;
use rlpkg_sim::{Model, SceneConfig, Simulator, SurfaceEmbedding};

use crate::error::input_error;
use crate::files::write_atomic;
use crate::render::{self, Bounds, Disc, Frame, GifWriter, View};

/// Pitch of the real 6 x 7 marker grid (2 inches).
const MARKER_PITCH_M: f32 = 0.0508;
/// Rate of the recorded data (Hz).
const RECORDING_RATE_HZ: f64 = 240.0;
/// Picture sizes: PNG stills, and the smaller GIF frames that keep the animation a few MB.
const PNG_SIZE: (u32, u32) = (1280, 720);
const GIF_SIZE: (u32, u32) = (640, 360);

/// Arguments of `rlpkg simulate`.
#[derive(Args, Debug)]
pub struct SimulateArgs {
    /// Trajectory folder with tool.csv, object.csv, markers.csv and meta.toml
    /// (e.g. data/deformable-sim-real/HHMMM).
    pub trajectory: PathBuf,
    /// Scene config TOML [default: the built-in reference preset, configs/scenes/study.toml].
    #[arg(long, value_name = "FILE")]
    pub params: Option<PathBuf>,
    /// Package vertices per layer, ROWSxCOLS (rows along the short side), e.g. 11x13.
    #[arg(long, value_name = "RxC", value_parser = parse_grid, conflicts_with = "between")]
    pub grid: Option<[usize; 2]>,
    /// The reference marker grid with P particles between neighbouring markers: (6+5P)x(7+6P).
    #[arg(long, value_name = "P")]
    pub between: Option<usize>,
    /// Output folder [default: runs/simulate-<trajectory id>].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// One GIF frame every N recorded frames (240 Hz); 24 gives 10 frames per simulated second.
    #[arg(long, value_name = "N", default_value_t = 24)]
    pub frames_every: usize,
    /// One PNG still every S seconds of simulated time (plus the first and the last instant).
    #[arg(long, value_name = "S", default_value_t = 1.0)]
    pub png_every: f64,
    /// Do not write the animated GIF.
    #[arg(long)]
    pub no_gif: bool,
    /// Replay only the first S seconds of the recording (after the rest period).
    #[arg(long, value_name = "S")]
    pub seconds: Option<f64>,
}

fn parse_grid(text: &str) -> Result<[usize; 2], String> {
    let expected =
        || format!("`{text}`: expected ROWSxCOLS with two integers of at least 2, e.g. 11x13");
    let (rows, cols) = text.split_once(['x', 'X']).ok_or_else(expected)?;
    let rows: usize = rows.trim().parse().map_err(|_| expected())?;
    let cols: usize = cols.trim().parse().map_err(|_| expected())?;
    if rows < 2 || cols < 2 {
        return Err(expected());
    }
    Ok([rows, cols])
}

/// Runs the command.
pub fn run(args: SimulateArgs) -> anyhow::Result<()> {
    check_options(&args)?;
    let dir = &args.trajectory;
    if !dir.is_dir() {
        return Err(input_error(format!(
            "{}: trajectory folder not found (expected a folder with tool.csv, object.csv, markers.csv and meta.toml)",
            dir.display()
        )));
    }
    let recording = load_trajectory(dir).map_err(input_error)?;
    let (config, config_source) = scene_config(&args)?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("runs/simulate-{}", recording.id)));
    let mut replay = Replay::new(&recording, &config, &args)?;
    // From here on a signal stops the replay between two pictures; the unfinished GIF removes
    // its temporary file when dropped, and nothing else is open for writing then.
    let _cooperation = crate::interrupt::Cooperation::start();
    prepare_output(&out)?;
    println!(
        "simulate {}: {} package + {} cup particles, dt = 1/{} s, {:.2} s rest + {:.3} s replay ({} substeps)",
        recording.id,
        replay.model.num_package,
        replay.model.num_cup,
        config.integrator.substep_rate_hz,
        replay.rest_s,
        replay.replayed_s(),
        replay.total_substeps(),
    );
    let started = Instant::now();
    let outcome = replay.run(&recording, &args, &out)?;
    let wall_s = started.elapsed().as_secs_f64();
    let summary = outcome.summary(&recording, &replay, &config_source, wall_s, &out);
    write_atomic(
        &out.join("summary.json"),
        serde_json::to_string_pretty(&summary)?.as_bytes(),
    )
    .map_err(input_error)?;
    outcome.print(&replay, wall_s, &out);
    if let Some(event) = outcome.health {
        anyhow::bail!(
            "the simulation became unhealthy ({:?}) at recording time t = {:.4} s; the files in {} stop there",
            event.reason,
            event.time - replay.rest_s,
            out.display()
        );
    }
    Ok(())
}

/// Files written into the output folder besides `frames/`; a temporary one is `.<name>.<suffix>`.
const OUTPUT_FILES: [&str; 5] = [
    "markers_sim.csv",
    "object_sim.csv",
    "metrics.csv",
    "summary.json",
    "replay.gif",
];

/// Creates `out/frames` and removes temporary files an interrupted earlier run left behind.
fn prepare_output(out: &Path) -> anyhow::Result<()> {
    if out.exists() && !out.is_dir() {
        return Err(input_error(format!(
            "--out {}: is a file; expected a folder for the replay's files",
            out.display()
        )));
    }
    let frames = out.join("frames");
    std::fs::create_dir_all(&frames).map_err(|err| {
        input_error(format!(
            "{}: cannot create the output folder: {err}",
            frames.display()
        ))
    })?;
    let is_output_temporary = |name: &str| {
        OUTPUT_FILES
            .iter()
            .any(|file| name.starts_with(&format!(".{file}.")))
    };
    let is_still_temporary = |name: &str| name.starts_with('.') && name.contains(".tmp");
    for (dir, is_temporary) in [
        (out, &is_output_temporary as &dyn Fn(&str) -> bool),
        (frames.as_path(), &is_still_temporary),
    ] {
        let entries = std::fs::read_dir(dir)
            .map_err(|err| input_error(format!("{}: {err}", dir.display())))?;
        for entry in entries.flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            if is_temporary(&name) {
                let path = entry.path();
                std::fs::remove_file(&path).map_err(|err| {
                    input_error(format!(
                        "{}: cannot remove this leftover temporary file: {err}",
                        path.display()
                    ))
                })?;
            }
        }
    }
    Ok(())
}

/// Writing a picture failed: the output folder's fault (exit 2) unless drawing itself failed.
fn output_error(err: render::RenderError) -> anyhow::Error {
    match err {
        render::RenderError::Write { .. } => input_error(err),
        other => anyhow::Error::new(other),
    }
}

fn check_options(args: &SimulateArgs) -> anyhow::Result<()> {
    if args.frames_every == 0 {
        return Err(input_error(
            "--frames-every 0: expected a whole number of frames of at least 1",
        ));
    }
    if !(args.png_every.is_finite() && args.png_every > 0.0) {
        return Err(input_error(format!(
            "--png-every {}: expected a positive number of seconds",
            args.png_every
        )));
    }
    if let Some(seconds) = args.seconds {
        if !(seconds.is_finite() && seconds > 0.0) {
            return Err(input_error(format!(
                "--seconds {seconds}: expected a positive number of seconds"
            )));
        }
    }
    Ok(())
}

/// The scene config (file or built-in reference preset) with the grid options applied.
fn scene_config(args: &SimulateArgs) -> anyhow::Result<(SceneConfig, String)> {
    let (mut config, source) = match &args.params {
        Some(path) => (
            SceneConfig::load(path).map_err(input_error)?,
            path.display().to_string(),
        ),
        None => (
            SceneConfig::preset("reference").map_err(input_error)?,
            "built-in reference preset (configs/scenes/study.toml)".to_string(),
        ),
    };
    let grid = match (args.grid, args.between) {
        (Some(grid), _) => Some((grid, "--grid")),
        (None, Some(p)) => {
            let side = |base: usize, per: usize| p.checked_mul(per)?.checked_add(base);
            let grid = side(6, 5).zip(side(7, 6)).ok_or_else(|| {
                input_error(format!(
                    "--between {p}: expected a small number of particles"
                ))
            })?;
            Some(([grid.0, grid.1], "--between"))
        }
        (None, None) => None,
    };
    if let Some((grid, option)) = grid {
        config.package.grid = grid;
        config.validate(option).map_err(input_error)?;
    }
    Ok((config, source))
}

/// One instant at which the replay stops to record or draw.
#[derive(Clone, Copy, Debug)]
struct Stop {
    /// Substep count from the start of the rest period.
    substep: u64,
    /// Time relative to the start of the recording (negative during the rest period).
    t: f64,
    /// The recorded frame compared at this instant, if any.
    frame: Option<usize>,
    gif: bool,
    png: bool,
}

/// The simulator set up for one recording, and the schedule of stops.
struct Replay {
    model: Arc<Model>,
    sim: Simulator,
    rest_s: f64,
    stops: Vec<Stop>,
    marker_sites: SurfaceEmbedding,
    grid_sites: SurfaceEmbedding,
    triangles: Vec<[u32; 3]>,
    scene_bounds: Bounds,
    close_up_bounds: Bounds,
}

fn f32x3(p: [f64; 3]) -> [f32; 3] {
    p.map(|c| c as f32)
}

impl Replay {
    fn new(
        recording: &Trajectory,
        config: &SceneConfig,
        args: &SimulateArgs,
    ) -> anyhow::Result<Self> {
        if recording.tool.t.is_empty() {
            return Err(input_error(format!(
                "{}: no frames; expected at least one row after the header",
                args.trajectory.join("tool.csv").display()
            )));
        }
        // The same placement and tool drive as the calibration uses, so a replay shows what it fits.
        let target = Target::new(recording, None, config.disc.hold_at_recorded_start)
            .map_err(|err| input_error(format!("{}: {err}", args.trajectory.display())))?;
        let spec = target.episode_spec(config.params, None);
        let placement = target.placement;
        let initial_markers = target.initial_markers;
        let model = Arc::new(Model::new(config).map_err(input_error)?);
        let sim = Simulator::new(model.clone(), vec![spec]).map_err(input_error)?;

        let marker_sites = sim.embed(0, &initial_markers);
        // The reference's 42 loss points: the nominal 6 x 7 marker grid on the upper sheet; embedding
        // them works for any grid (on the reference grids they land exactly on vertices).
        let origin = placement.package_origin;
        let nominal: Vec<[f32; 3]> = (0..42)
            .map(|m| {
                let (row, col) = (m / 7, m % 7);
                [
                    origin[0] + col as f32 * MARKER_PITCH_M,
                    origin[1],
                    origin[2] + row as f32 * MARKER_PITCH_M,
                ]
            })
            .collect();
        let grid_sites = sim.embed(0, &nominal);
        let triangles = model.package_triangles.iter().map(|t| t.idx).collect();

        let rest_s = f64::from(config.cups.rest_time_s);
        let stops = schedule(
            &recording.tool.t,
            config.integrator.substep_rate_hz,
            rest_s,
            args,
        );
        let last_frame = stops.iter().filter_map(|s| s.frame).max().unwrap_or(0);
        let (scene_bounds, close_up_bounds) = picture_bounds(recording, &sim, last_frame);
        Ok(Self {
            model,
            sim,
            rest_s,
            stops,
            marker_sites,
            grid_sites,
            triangles,
            scene_bounds,
            close_up_bounds,
        })
    }

    fn total_substeps(&self) -> u64 {
        self.stops.last().map_or(0, |s| s.substep)
    }

    fn replayed_s(&self) -> f64 {
        self.stops.last().map_or(0.0, |s| s.t.max(0.0))
    }

    /// Steps through every stop, recording CSV rows, errors and pictures.
    fn run(
        &mut self,
        recording: &Trajectory,
        args: &SimulateArgs,
        out: &Path,
    ) -> anyhow::Result<Outcome> {
        let mut outcome = Outcome::new(self.marker_sites.points.len());
        let png_view = View::new(
            &self.scene_bounds,
            &self.close_up_bounds,
            PNG_SIZE.0,
            PNG_SIZE.1,
        );
        let gif_view = View::new(
            &self.scene_bounds,
            &self.close_up_bounds,
            GIF_SIZE.0,
            GIF_SIZE.1,
        );
        let frame_seconds = args.frames_every as f32 / RECORDING_RATE_HZ as f32;
        let mut gif = if args.no_gif {
            None
        } else {
            Some(
                GifWriter::create(&out.join("replay.gif"), GIF_SIZE, frame_seconds)
                    .map_err(output_error)?,
            )
        };
        let progress = ProgressBar::new(self.total_substeps()).with_style(
            ProgressStyle::with_template("{bar:40} {percent:>3}% substeps, eta {eta}")
                .context("progress bar template")?,
        );
        let num_package = self.model.num_package;
        let (disc_radius, disc_thickness) =
            (self.model.disc.radius, 2.0 * self.model.disc.half_height);
        for stop in self.stops.clone() {
            crate::interrupt::check()?;
            let ahead = stop.substep.saturating_sub(self.sim.substep());
            self.sim.step(ahead);
            progress.inc(ahead);
            if let Some(event) = self.sim.health_events().first() {
                outcome.health = Some(*event);
                break;
            }
            let positions = self.sim.particle_positions(0);
            let grid_sites = self.grid_sites.evaluate(&positions);
            let disc = self.sim.disc(0);
            if let Some(k) = stop.frame {
                let marker_sites = self.marker_sites.evaluate(&positions);
                outcome.record(k, recording, &marker_sites, &grid_sites, disc);
            }
            if stop.gif || stop.png {
                let recorded_markers: Vec<[f32; 3]> = recording
                    .markers
                    .frame(stop.frame.unwrap_or(0))
                    .iter()
                    .map(|&p| f32x3(p))
                    .collect();
                let title = if stop.t < 0.0 {
                    format!("{} (rest period)", recording.id)
                } else {
                    recording.id.clone()
                };
                let frame = Frame {
                    title: &title,
                    time: stop.t as f32,
                    package: &positions[..num_package],
                    triangles: &self.triangles,
                    cups: &positions[num_package..],
                    disc: Some(Disc {
                        center: disc.position,
                        rotation: disc.orientation,
                        radius: disc_radius,
                        thickness: disc_thickness,
                    }),
                    recorded_markers: &recorded_markers,
                    simulated_markers: &grid_sites,
                    recorded_object: stop.frame.map(|k| f32x3(recording.object.position[k])),
                };
                if stop.png {
                    // The index keeps the files in time order when listed by name.
                    let name = format!("{:03}_t{:+.3}s.png", outcome.stills.len(), stop.t);
                    let path = out.join("frames").join(name);
                    render::write_png(&path, &frame, &png_view).map_err(output_error)?;
                    outcome.stills.push(path);
                }
                if let (true, Some(writer)) = (stop.gif, gif.as_mut()) {
                    writer.add(&frame, &gif_view).map_err(output_error)?;
                }
            }
        }
        progress.finish_and_clear();
        crate::interrupt::check()?;
        if let Some(writer) = gif {
            let frames = writer.frames();
            outcome.gif = Some((writer.finish().map_err(output_error)?, frames));
        }
        outcome.write_csvs(out)?;
        Ok(outcome)
    }
}

/// Every stop of the replay in time order: rest-period pictures, then each recorded frame (up to
/// `--seconds`), marking which ones go into the GIF and which become PNG stills.
fn schedule(times: &[f64], substep_rate_hz: f64, rest_s: f64, args: &SimulateArgs) -> Vec<Stop> {
    let rate = substep_rate_hz;
    let limit = args.seconds.unwrap_or(f64::INFINITY);
    let gif_step = args.frames_every as f64 / RECORDING_RATE_HZ;
    let substep_at = |t: f64| ((rest_s + t) * rate).round().max(0.0) as u64;
    let mut stops = Vec::new();
    // Rest period: pictures only, on the same beat as the recorded frames.
    let rest_pictures = (rest_s / gif_step).ceil() as usize;
    for m in 0..rest_pictures {
        let t = -rest_s + m as f64 * gif_step;
        stops.push(Stop {
            substep: substep_at(t),
            t,
            frame: None,
            gif: true,
            png: m == 0,
        });
    }
    let frames = times
        .iter()
        .take_while(|&&t| t <= limit + 1e-9)
        .count()
        .max(1);
    let mut next_png = 0.0;
    for (k, &t) in times.iter().enumerate().take(frames) {
        let png = t + 1e-9 >= next_png || k + 1 == frames;
        if png {
            next_png = (t / args.png_every).floor() * args.png_every + args.png_every;
        }
        stops.push(Stop {
            substep: substep_at(t),
            t,
            frame: Some(k),
            gif: k % args.frames_every == 0 || k + 1 == frames,
            png,
        });
    }
    // Recordings start at t = 0, after the rest period; sorting keeps any other file in time order.
    stops.sort_by_key(|stop| stop.substep);
    stops
}

/// What the views must show: everything the replay can reach (the recording, the package at rest,
/// the cups following the tool), and a close-up box the size of the package for the 3/4 view.
fn picture_bounds(recording: &Trajectory, sim: &Simulator, last_frame: usize) -> (Bounds, Bounds) {
    let positions = sim.particle_positions(0);
    let mut close_up = Bounds::empty();
    positions.iter().for_each(|&p| close_up.include(p));
    let mut scene = close_up;
    for k in 0..=last_frame.min(recording.markers.len().saturating_sub(1)) {
        recording
            .markers
            .frame(k)
            .iter()
            .for_each(|&p| scene.include(f32x3(p)));
    }
    recording.object.position[..=last_frame]
        .iter()
        .for_each(|&p| scene.include(f32x3(p)));
    // The cups move with the tool: shift the resting package by the tool's travel.
    let tool = &recording.tool.position;
    let (low, high) = (close_up.min, close_up.max);
    for p in &tool[..=last_frame] {
        let shift = (DVec3::from(*p) - DVec3::from(tool[0])).as_vec3();
        scene.include(low + shift);
        scene.include(high + shift);
    }
    // Room below the package for it to sag around the disc.
    close_up.include(low - 0.08 * Vec3::Y);
    (scene.padded(0.03), close_up.padded(0.02))
}

/// The package Chamfer distance of the calibration (`rlpkg_replay::loss`, reference-model.md §8.3)
/// between simulated sites and a frame's markers, in metres; NaN when either set is empty.
fn chamfer(simulated: &[[f32; 3]], recorded: &[[f64; 3]]) -> f64 {
    let simulated: Vec<[f64; 3]> = simulated.iter().map(|p| p.map(f64::from)).collect();
    chamfer_distance(&simulated, recorded).unwrap_or(f64::NAN)
}

/// Everything the replay produced.
struct Outcome {
    markers_csv: String,
    object_csv: String,
    metrics_csv: String,
    chamfer: Vec<f64>,
    object_error: Vec<f64>,
    times: Vec<f64>,
    stills: Vec<PathBuf>,
    gif: Option<(PathBuf, usize)>,
    health: Option<rlpkg_sim::HealthEvent>,
}

impl Outcome {
    fn new(marker_sites: usize) -> Self {
        let mut markers_csv = String::from("frame,t");
        for (prefix, count) in [("m", marker_sites), ("g", 42)] {
            for site in 0..count {
                for axis in ["x", "y", "z"] {
                    let _ = write!(markers_csv, ",{prefix}{site}_{axis}");
                }
            }
        }
        markers_csv.push('\n');
        Self {
            markers_csv,
            object_csv: "t,px,py,pz,qx,qy,qz,qw\n".to_string(),
            metrics_csv: "frame,t,chamfer_m,object_error_m\n".to_string(),
            chamfer: Vec::new(),
            object_error: Vec::new(),
            times: Vec::new(),
            stills: Vec::new(),
            gif: None,
            health: None,
        }
    }

    fn record(
        &mut self,
        k: usize,
        recording: &Trajectory,
        marker_sites: &[[f32; 3]],
        grid_sites: &[[f32; 3]],
        disc: rlpkg_sim::DiscState,
    ) {
        let t = recording.tool.t[k];
        let _ = write!(self.markers_csv, "{k},{t:.6}");
        for p in marker_sites.iter().chain(grid_sites) {
            let _ = write!(self.markers_csv, ",{:.6},{:.6},{:.6}", p[0], p[1], p[2]);
        }
        self.markers_csv.push('\n');
        let (p, q) = (disc.position, disc.orientation);
        let _ = writeln!(
            self.object_csv,
            "{t:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6}",
            p[0], p[1], p[2], q[0], q[1], q[2], q[3]
        );
        let cd = chamfer(grid_sites, recording.markers.frame(k));
        let recorded = recording.object.position[k];
        let error = (0..3)
            .map(|a| (f64::from(p[a]) - recorded[a]).powi(2))
            .sum::<f64>()
            .sqrt();
        let _ = writeln!(self.metrics_csv, "{k},{t:.6},{cd:.6},{error:.6}");
        self.chamfer.push(cd);
        self.object_error.push(error);
        self.times.push(t);
    }

    fn write_csvs(&self, out: &Path) -> anyhow::Result<()> {
        for (name, text) in [
            ("markers_sim.csv", &self.markers_csv),
            ("object_sim.csv", &self.object_csv),
            ("metrics.csv", &self.metrics_csv),
        ] {
            write_atomic(&out.join(name), text.as_bytes()).map_err(input_error)?;
        }
        Ok(())
    }

    fn summary(
        &self,
        recording: &Trajectory,
        replay: &Replay,
        config_source: &str,
        wall_s: f64,
        out: &Path,
    ) -> serde_json::Value {
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        let max = |v: &[f64]| v.iter().copied().fold(f64::NAN, f64::max);
        let duration = self.times.last().copied().unwrap_or(0.0);
        // The reference's normalisation (§8.5): sums over the 240 Hz samples divided by seconds.
        let per_second = |sum: f64| {
            if duration > 0.0 {
                sum / duration
            } else {
                f64::NAN
            }
        };
        let simulated_s = replay.sim.time();
        serde_json::json!({
            "trajectory": recording.id,
            "config": config_source,
            "grid": replay.model.grid,
            "package_particles": replay.model.num_package,
            "cup_particles": replay.model.num_cup,
            "dt_s": replay.sim.dt(),
            "rest_s": replay.rest_s,
            "replayed_s": duration,
            "frames_compared": self.times.len(),
            "substeps": replay.sim.substep(),
            "wall_s": wall_s,
            "realtime_factor": simulated_s / wall_s.max(1e-9),
            "chamfer_mean_m": mean(&self.chamfer),
            "chamfer_max_m": max(&self.chamfer),
            "object_error_mean_m": mean(&self.object_error),
            "object_error_max_m": max(&self.object_error),
            "object_error_final_m": self.object_error.last(),
            "package_particle_loss": per_second(self.chamfer.iter().sum()),
            "internal_object_loss": per_second(self.object_error.iter().map(|e| e * e).sum()),
            "health": self.health.map(|e| format!("{:?} at simulated t = {:.4} s", e.reason, e.time)),
            "files": {
                "markers_sim": out.join("markers_sim.csv"),
                "object_sim": out.join("object_sim.csv"),
                "metrics": out.join("metrics.csv"),
                "stills": self.stills,
                "gif": self.gif.as_ref().map(|g| &g.0),
            },
        })
    }

    fn print(&self, replay: &Replay, wall_s: f64, out: &Path) {
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        println!(
            "replayed {} frames ({:.3} s) in {:.1} s wall: {:.3}x real time",
            self.times.len(),
            self.times.last().copied().unwrap_or(0.0),
            wall_s,
            replay.sim.time() / wall_s.max(1e-9)
        );
        println!(
            "chamfer distance mean {:.2} mm, object error mean {:.2} mm, final {:.2} mm",
            1e3 * mean(&self.chamfer),
            1e3 * mean(&self.object_error),
            1e3 * self.object_error.last().copied().unwrap_or(f64::NAN)
        );
        println!(
            "wrote {}/{{markers_sim,object_sim,metrics}}.csv and summary.json",
            out.display()
        );
        println!(
            "      {} PNG stills in {}",
            self.stills.len(),
            out.join("frames").display()
        );
        if let Some((path, frames)) = &self.gif {
            println!("      {} ({frames} frames)", path.display());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_option_parses_rows_and_columns() {
        assert_eq!(parse_grid("11x13"), Ok([11, 13]));
        assert_eq!(parse_grid("21X25"), Ok([21, 25]));
        for bad in ["11", "11x", "x13", "1x13", "ax b", "11x13x2"] {
            let err = parse_grid(bad).unwrap_err();
            assert!(err.contains(bad) && err.contains("ROWSxCOLS"), "{err}");
        }
    }

    #[test]
    fn schedule_stops_at_rest_pictures_then_every_recorded_frame() {
        let times: Vec<f64> = (0..100).map(|k| k as f64 / 240.0).collect();
        let args = SimulateArgs {
            trajectory: PathBuf::new(),
            params: None,
            grid: None,
            between: None,
            out: None,
            frames_every: 24,
            png_every: 0.2,
            no_gif: false,
            seconds: Some(0.3),
        };
        let stops = schedule(&times, 30720.0, 2.0, &args);
        let (rest, recorded): (Vec<Stop>, Vec<Stop>) =
            stops.iter().partition(|stop| stop.frame.is_none());
        // 2 s of rest at one picture per 0.1 s, the first one also a still.
        assert_eq!(rest.len(), 20);
        assert_eq!(rest[0].substep, 0);
        assert!(rest.iter().all(|stop| stop.gif && stop.t < 0.0));
        assert_eq!(rest.iter().filter(|stop| stop.png).count(), 1);
        // Frames 0..=72 (t <= 0.3 s), 128 substeps apart after the 61 440 rest substeps.
        assert_eq!(recorded.len(), 73);
        for (k, stop) in recorded.iter().enumerate() {
            assert_eq!(stop.frame, Some(k));
            assert_eq!(stop.substep, 61_440 + 128 * k as u64);
        }
        let gif: Vec<usize> = recorded
            .iter()
            .filter(|s| s.gif)
            .filter_map(|s| s.frame)
            .collect();
        assert_eq!(gif, [0, 24, 48, 72]);
        let png: Vec<usize> = recorded
            .iter()
            .filter(|s| s.png)
            .filter_map(|s| s.frame)
            .collect();
        assert_eq!(png, [0, 48, 72]);
        assert!(stops.windows(2).all(|w| w[0].substep < w[1].substep));
    }

    #[test]
    fn leftover_temporary_files_are_removed_and_outputs_kept() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        std::fs::create_dir_all(out.join("frames")).unwrap();
        let leftovers = [
            ".summary.json.AbC123",
            ".replay.gif.4242.0.tmp",
            "frames/.000_t-2.000s.png.4242.3.tmp.png",
        ];
        let kept = ["metrics.csv", "frames/000_t-2.000s.png", ".hidden-notes"];
        for name in leftovers.iter().chain(&kept) {
            std::fs::write(out.join(name), "x").unwrap();
        }
        prepare_output(&out).unwrap();
        for name in leftovers {
            assert!(!out.join(name).exists(), "{name}");
        }
        for name in kept {
            assert!(out.join(name).exists(), "{name}");
        }
    }

    #[test]
    fn chamfer_is_the_symmetric_mean_nearest_distance() {
        let simulated = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
        let recorded = [[0.0, 0.1, 0.0]];
        // sim -> rec: (0.1 + sqrt(1.01)) / 2; rec -> sim: 0.1.
        let expected = 0.5 * ((0.1 + 1.01f64.sqrt()) / 2.0 + 0.1);
        assert!((chamfer(&simulated, &recorded) - expected).abs() < 1e-7);
        assert_eq!(
            chamfer(&simulated, &[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]),
            0.0
        );
        assert!(chamfer(&[], &recorded).is_nan());
        assert!(chamfer(&simulated, &[]).is_nan());
        // The very function the calibration's loss uses, on the same points.
        let simulated_f64 = simulated.map(|p| p.map(f64::from));
        assert_eq!(
            chamfer(&simulated, &recorded),
            chamfer_distance(&simulated_f64, &recorded).unwrap()
        );
    }
}
