//! The replay of one recording through the batched rollout of `rlpkg-replay`, with a recorder
//! that writes the CSV rows and draws the pictures at every stop.

use std::path::Path;
use std::sync::Arc;

use anyhow::Context;
use glam::{DVec3, Vec3};
use indicatif::{ProgressBar, ProgressStyle};
use rlpkg_mocap::Trajectory;
use rlpkg_replay::{
    rollout_scheduled, Candidate, FrameClock, FrameObservation, Observer, ReplayError, Schedule,
    Target,
};
use rlpkg_sim::{marker_grid_points, Model, SceneConfig, Simulator, SurfaceEmbedding};

use super::outcome::Outcome;
use super::schedule::{schedule, ScheduleOptions, Stop, RECORDING_RATE_HZ};
use crate::error::input_error;
use crate::render::{self, Bounds, Disc, Frame, GifWriter, View};

/// Picture sizes: PNG stills, and the smaller GIF frames that keep the animation a few MB.
const PNG_SIZE: (u32, u32) = (1280, 720);
const GIF_SIZE: (u32, u32) = (640, 360);

/// The recording prepared for replay, the model it is replayed in, and the schedule of stops.
pub struct Replay {
    /// The model of the scene.
    pub model: Arc<Model>,
    target: Target,
    /// The rest period before the recording starts (s).
    pub rest_s: f64,
    options: ScheduleOptions,
    stops: Vec<Stop>,
}

fn f32x3(p: [f64; 3]) -> [f32; 3] {
    p.map(|c| c as f32)
}

impl Replay {
    /// Prepares `recording` (read from the folder `dir`) for a replay in the scene `config`.
    pub fn new(
        recording: &Trajectory,
        dir: &Path,
        config: &SceneConfig,
        options: ScheduleOptions,
    ) -> anyhow::Result<Self> {
        if recording.tool.t.is_empty() {
            return Err(input_error(format!(
                "{}: no frames; expected at least one row after the header",
                dir.join("tool.csv").display()
            )));
        }
        let stops = schedule(&recording.tool.t, config, &options);
        // The same placement and tool drive as the calibration uses, so a replay shows what it
        // fits; compared are the scheduled frames (the recording's frames share the tool's times).
        let frames = stops.iter().filter(|stop| stop.frame.is_some()).count();
        let last_time = recording.tool.t[frames - 1];
        let target = Target::new(
            recording,
            Some(last_time),
            config.disc.hold_at_recorded_start,
        )
        .map_err(|err| input_error(format!("{}: {err}", dir.display())))?;
        let model = Arc::new(Model::new(config).map_err(input_error)?);
        Ok(Self {
            model,
            target,
            rest_s: f64::from(config.cups.rest_time_s),
            options,
            stops,
        })
    }

    /// Substeps from the start of the rest period to the last stop.
    pub fn total_substeps(&self) -> u64 {
        self.stops.last().map_or(0, |s| s.substep)
    }

    /// Recording time replayed (s).
    pub fn replayed_s(&self) -> f64 {
        self.stops.last().map_or(0.0, |s| s.t.max(0.0))
    }

    /// Replays the recording through [`rollout_scheduled`], recording CSV rows, errors and
    /// pictures (the GIF unless `no_gif`) into `out` at every stop.
    pub fn run(&self, recording: &Trajectory, no_gif: bool, out: &Path) -> anyhow::Result<Outcome> {
        let frame_seconds = self.options.frames_every as f32 / RECORDING_RATE_HZ as f32;
        let gif = if no_gif {
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
        let schedule = Schedule {
            clock: FrameClock::SubstepRate,
            extra_stops: self
                .stops
                .iter()
                .filter(|stop| stop.frame.is_none())
                .map(|stop| stop.substep)
                .collect(),
        };
        let mut recorder = Recorder::new(self, recording, out, gif, progress);
        let candidate = Candidate::of_scene(&self.model.config);
        let result = rollout_scheduled(
            &self.model,
            std::slice::from_ref(&self.target),
            &[candidate],
            &schedule,
            &mut recorder,
        );
        recorder.progress.finish_and_clear();
        let outcome = match result {
            Ok(outcomes) => {
                let mut outcome = recorder.outcome;
                outcome.health = outcomes[0][0].diverged;
                outcome.seal_failure = outcomes[0][0].seal_failure;
                outcome
            }
            Err(ReplayError::Stopped) => {
                if let Some(err) = recorder.error {
                    return Err(err);
                }
                if recorder.outcome.non_finite.is_some() {
                    crate::interrupt::check()?;
                    let outcome = std::mem::replace(&mut recorder.outcome, Outcome::new(0));
                    return self.finish_files(outcome, recorder.gif.take(), out);
                }
                crate::interrupt::check()?;
                return Err(ReplayError::Stopped.into());
            }
            Err(err) => return Err(input_error(err)),
        };
        crate::interrupt::check()?;
        self.finish_files(outcome, recorder.gif, out)
    }

    /// Closes the GIF and writes the CSVs of `outcome`.
    fn finish_files(
        &self,
        mut outcome: Outcome,
        gif: Option<GifWriter>,
        out: &Path,
    ) -> anyhow::Result<Outcome> {
        if let Some(writer) = gif {
            let frames = writer.frames();
            outcome.gif = Some((writer.finish().map_err(output_error)?, frames));
        }
        outcome.write_csvs(out)?;
        Ok(outcome)
    }
}

/// What the replay needs to draw, set up from the simulator at rest.
struct Pictures {
    /// The nominal marker grid embedded in the upper sheet.
    grid_sites: SurfaceEmbedding,
    png_view: View,
    gif_view: View,
}

/// Watches the rollout: writes a CSV row at every compared frame and draws the scheduled pictures.
struct Recorder<'a> {
    recording: &'a Trajectory,
    model: &'a Model,
    placement_origin: [f32; 3],
    out: &'a Path,
    /// The rest period's picture stops in time order, and the next one due.
    rest_stops: Vec<Stop>,
    next_rest_stop: usize,
    /// The stop of each compared frame, by frame.
    frame_stops: Vec<Stop>,
    triangles: Vec<[u32; 3]>,
    pictures: Option<Pictures>,
    gif: Option<GifWriter>,
    progress: ProgressBar,
    outcome: Outcome,
    /// The first error of writing a picture; it stops the rollout.
    error: Option<anyhow::Error>,
}

impl<'a> Recorder<'a> {
    fn new(
        replay: &'a Replay,
        recording: &'a Trajectory,
        out: &'a Path,
        gif: Option<GifWriter>,
        progress: ProgressBar,
    ) -> Self {
        let (frame_stops, rest_stops) = replay.stops.iter().partition(|stop| stop.frame.is_some());
        Self {
            recording,
            model: &replay.model,
            placement_origin: replay.target.placement.package_origin,
            out,
            rest_stops,
            next_rest_stop: 0,
            frame_stops,
            triangles: replay
                .model
                .package_triangles
                .iter()
                .map(|t| t.idx)
                .collect(),
            pictures: None,
            gif,
            progress,
            outcome: Outcome::new(replay.target.sites().len()),
            error: None,
        }
    }

    /// Draws the pictures `stop` asks for (a PNG still, a GIF frame) from environment 0.
    fn draw(
        &mut self,
        stop: &Stop,
        simulator: &Simulator,
        positions: &[[f32; 3]],
        grid_sites: &[[f32; 3]],
    ) -> anyhow::Result<()> {
        if !(stop.gif || stop.png) {
            return Ok(());
        }
        let pictures = self.pictures.as_ref().expect("set up at the start");
        let recording = self.recording;
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
        let num_package = self.model.num_package;
        let disc = simulator.disc(0);
        let frame = Frame {
            title: &title,
            time: stop.t as f32,
            package: &positions[..num_package],
            triangles: &self.triangles,
            cups: &positions[num_package..],
            disc: Some(Disc {
                center: disc.position,
                rotation: disc.orientation,
                radius: self.model.disc.radius,
                thickness: 2.0 * self.model.disc.half_height,
            }),
            recorded_markers: &recorded_markers,
            simulated_markers: grid_sites,
            recorded_object: stop.frame.map(|k| f32x3(recording.object.position[k])),
        };
        if stop.png {
            // The index keeps the files in time order when listed by name.
            let name = format!("{:03}_t{:+.3}s.png", self.outcome.stills.len(), stop.t);
            let path = self.out.join("frames").join(name);
            render::write_png(&path, &frame, &pictures.png_view).map_err(output_error)?;
            self.outcome.stills.push(path);
        }
        if let (true, Some(writer)) = (stop.gif, self.gif.as_mut()) {
            writer
                .add(&frame, &pictures.gif_view)
                .map_err(output_error)?;
        }
        Ok(())
    }

    /// Keeps the first error.
    fn keep(&mut self, result: anyhow::Result<()>) {
        if let (Err(err), None) = (result, &self.error) {
            self.error = Some(err);
        }
    }
}

impl Observer for Recorder<'_> {
    fn start(&mut self, simulator: &Simulator) {
        // The reference's 42 loss points: the nominal 6 x 7 marker grid on the upper sheet;
        // embedding them works for any grid (on the reference grids they land exactly on vertices).
        let grid_sites = simulator.embed(0, &marker_grid_points(self.placement_origin));
        let last_frame = self.frame_stops.len().saturating_sub(1);
        let (scene, close_up) = picture_bounds(self.recording, simulator, last_frame);
        self.pictures = Some(Pictures {
            grid_sites,
            png_view: View::new(&scene, &close_up, PNG_SIZE.0, PNG_SIZE.1),
            gif_view: View::new(&scene, &close_up, GIF_SIZE.0, GIF_SIZE.1),
        });
    }

    fn instant(&mut self, substep: u64, simulator: &Simulator) {
        while let Some(&stop) = self.rest_stops.get(self.next_rest_stop) {
            if stop.substep != substep {
                break;
            }
            self.next_rest_stop += 1;
            if self.error.is_none() {
                let positions = simulator.particle_positions(0);
                let pictures = self.pictures.as_ref().expect("set up at the start");
                let grid_sites = pictures.grid_sites.evaluate(&positions);
                let drawn = self.draw(&stop, simulator, &positions, &grid_sites);
                self.keep(drawn);
            }
        }
    }

    fn frame(&mut self, observation: &FrameObservation) {
        if self.error.is_some() {
            return;
        }
        let k = observation.frame;
        let simulator = observation.simulator;
        let positions = simulator.particle_positions(observation.env);
        let pictures = self.pictures.as_ref().expect("set up at the start");
        let grid_sites = pictures.grid_sites.evaluate(&positions);
        // The marker sites come as f64 widened from the simulator's f32: narrowing is exact.
        let marker_sites: Vec<[f32; 3]> = observation
            .simulated_points
            .iter()
            .map(|&p| f32x3(p))
            .collect();
        let disc = observation.disc;
        let finite = marker_sites
            .iter()
            .chain(&grid_sites)
            .chain(std::iter::once(&disc.position))
            .flatten()
            .chain(&disc.orientation)
            .all(|v| v.is_finite());
        if !finite {
            // No NaN row is written: the files end at the last finite frame.
            self.outcome.non_finite = Some((k, self.recording.tool.t[k]));
            self.finish(simulator);
            return;
        }
        self.outcome.record(
            k,
            self.recording,
            &marker_sites,
            &grid_sites,
            *observation.disc,
        );
        let stop = self.frame_stops[k];
        let drawn = self.draw(&stop, simulator, &positions, &grid_sites);
        self.keep(drawn);
    }

    fn progress(&mut self, done: u64, _total: u64) {
        self.progress.set_position(done);
    }

    fn stop(&mut self) -> bool {
        self.error.is_some() || self.outcome.non_finite.is_some() || crate::interrupt::requested()
    }

    fn finish(&mut self, simulator: &Simulator) {
        self.outcome.substeps = simulator.substep();
        self.outcome.simulated_s = simulator.time();
        self.outcome.dt_s = simulator.dt();
    }
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

/// Writing a picture failed: the output folder's fault (exit 2) unless drawing itself failed.
fn output_error(err: render::RenderError) -> anyhow::Error {
    match err {
        render::RenderError::Write { .. } => input_error(err),
        other => anyhow::Error::new(other),
    }
}
