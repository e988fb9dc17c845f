//! `rlpkg eval --params <scene.toml>`: how well simulator parameters reproduce recorded trajectories.
//!
//! Prints the paper's Table 1 (package Chamfer distance and object squared error per frame: mean,
//! max, std over every compared frame of every trajectory; one row per split) and writes, under
//! `--out` (default `runs/eval-<params file stem>`): `summary.json`, per trajectory the simulated vs
//! recorded scene at four instants (`<id>_t<seconds>.png`, the paper's Fig. 9), the per-marker error
//! over the package (`<id>_marker_error.png`, Fig. 10) and the loss over time (`<id>_loss.png`).
//! `--sweep-grid` adds Table 2 (grid, particles, real-time factor, CD, MSE) and `--perturb 10,20`
//! the sensitivity table (every calibrated value scaled up by that percentage, as the study did).
//! A posterior (`summary.json` or `samples.csv` of `rlpkg posterior`) instead gives the
//! posterior-predictive Table 1 ([`super::predictive`]).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use rlpkg_mocap::{Dataset, Split, Trajectory};
use rlpkg_replay::evaluate::{perturbed, real_time_factor, SiteErrors};
use rlpkg_replay::loss::{table1_text, LossWeights, Table1Row, TrajectoryLoss};
use rlpkg_replay::{
    mean_loss, rollout, Candidate, FrameObservation, Observer, RolloutOutcome, Target,
};
use rlpkg_sim::{Model, SceneConfig};
use serde::Serialize;

use super::predictive::PredictiveArgs;
use crate::error::{input_error, output_error};
use crate::files::write_atomic;
use crate::render::plot::{write_loss_plot, write_marker_error_plot};
use crate::render::{self, Bounds, Disc, Frame, View};

/// Picture size of the scene stills.
const STILL_SIZE: (u32, u32) = (1280, 720);
/// Instants pictured per trajectory, as fractions of its compared frames.
const STILL_FRACTIONS: [f64; 4] = [0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0];
/// Grids of the sweep: particles between markers (Table 2: 11x13, 16x19, 21x25, 26x31).
const SWEEP_BETWEEN: [usize; 4] = [1, 2, 3, 4];

/// Everything `--json` prints and `summary.json` holds.
#[derive(Serialize)]
struct Summary {
    params: PathBuf,
    grid: [usize; 2],
    dt_s: f64,
    table1: Vec<Table1Row>,
    trajectories: Vec<TrajectorySummary>,
    wall_s: f64,
    real_time_factor: f64,
    sweep_grid: Vec<SweepRow>,
    perturb: Vec<PerturbRow>,
}

#[derive(Serialize)]
struct TrajectorySummary {
    id: String,
    split: String,
    frames: usize,
    chamfer_mean_m: f64,
    object_mse_mean_m2: f64,
    loss: f64,
    diverged_at_s: Option<f64>,
}

#[derive(Serialize)]
struct SweepRow {
    grid: [usize; 2],
    particles: usize,
    real_time_factor: f64,
    wall_s: f64,
    chamfer_mean_m: f64,
    object_mse_mean_m2: f64,
}

#[derive(Serialize)]
struct PerturbRow {
    percent: f64,
    loss: f64,
    chamfer_mean_m: f64,
    object_mse_mean_m2: f64,
}

/// Posterior draws replayed by default for a posterior `--params`.
const DEFAULT_DRAWS: usize = 16;

/// Upper bound of the number of `--perturb` percentages.
const MAX_PERTURBATIONS: usize = 20;

/// Runs `rlpkg eval --params`.
pub fn run(args: &super::EvalArgs) -> anyhow::Result<()> {
    let params_path = args
        .params
        .as_ref()
        .ok_or_else(|| input_error("--params: expected a scene TOML file"))?;
    if let Some(extension @ ("json" | "csv")) = params_path.extension().and_then(|e| e.to_str()) {
        if args.sweep_grid || !args.perturb.is_empty() {
            return Err(input_error(format!(
                "--params {}: a posterior ({extension}) takes neither --sweep-grid nor --perturb; \
                 give a scene TOML file for those",
                params_path.display()
            )));
        }
        return super::predictive::run(&PredictiveArgs {
            posterior: params_path,
            draws: args.draws.unwrap_or(DEFAULT_DRAWS),
            split: args.split.as_deref().unwrap_or("test"),
            data: args.data.as_deref(),
            out: args.out.as_deref(),
            json: args.json,
        });
    }
    if args.draws.is_some() {
        return Err(input_error(format!(
            "--draws: only with a posterior (--params <summary.json or samples.csv>), not with {}",
            params_path.display()
        )));
    }
    let scene = SceneConfig::load(params_path).map_err(input_error)?;
    // Every perturbation must stay in the ranges the scene accepts, before any rollout.
    for &percent in &args.perturb {
        let mut probe = scene.clone();
        perturbed(&Candidate::of_scene(&scene), percent).apply_to(&mut probe);
        probe
            .validate(&params_path.display().to_string())
            .map_err(|err| {
                input_error(format!(
                    "--perturb {percent}: scaling the parameters by {} leaves the range the \
                     scene accepts: {err}",
                    1.0 + percent / 100.0
                ))
            })?;
    }
    // A signal stops the rollouts; the pictures and summary.json are written whole or not at all.
    let _cooperation = crate::interrupt::Cooperation::start();
    // clap's `requires` does not apply to options with a default, so the defaults are set here.
    let split = args.split.as_deref().unwrap_or("test");
    let data = args
        .data
        .clone()
        .unwrap_or_else(|| PathBuf::from("data/deformable-sim-real"));
    let splits: Vec<Split> = match split {
        "train" => vec![Split::Train],
        "test" => vec![Split::Test],
        "all" => vec![Split::Train, Split::Test],
        other => {
            return Err(input_error(format!(
                "--split {other}: expected train, test or all"
            )))
        }
    };
    if args.perturb.len() > MAX_PERTURBATIONS {
        return Err(input_error(format!(
            "--perturb: {} percentages; expected at most {MAX_PERTURBATIONS} (each one simulates \
             every trajectory twice per parameter)",
            args.perturb.len()
        )));
    }
    if let Some(p) = args
        .perturb
        .iter()
        .find(|p| !(p.is_finite() && **p > -100.0))
    {
        return Err(input_error(format!(
            "--perturb {p}: expected percentages > -100"
        )));
    }
    let dataset = Dataset::open(&data).map_err(input_error)?;
    let mut selected: Vec<(Split, Trajectory)> = Vec::new();
    for &split in &splits {
        for id in dataset.ids(Some(split)) {
            selected.push((split, dataset.load(&id).map_err(input_error)?));
        }
    }
    if selected.is_empty() {
        return Err(input_error(format!(
            "{}: no trajectory in split {split}",
            data.display(),
        )));
    }
    let out = args.out.clone().unwrap_or_else(|| {
        let stem = params_path
            .file_stem()
            .map_or("params".into(), |s| s.to_string_lossy().into_owned());
        PathBuf::from(format!("runs/eval-{stem}"))
    });
    if out.exists() && !out.is_dir() {
        return Err(input_error(format!(
            "--out {}: is a file; expected a folder for the pictures and summary.json",
            out.display()
        )));
    }

    let targets = selected
        .iter()
        .map(|(_, t)| Target::new(t, None, scene.disc.hold_at_recorded_start).map_err(input_error))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let model = Arc::new(Model::new(&scene).map_err(input_error)?);
    let weights = LossWeights::default();

    // Main evaluation, with pictures.
    let mut observer = Pictures::new(&targets, model.num_package, "evaluating");
    let started = Instant::now();
    let outcomes = rollout(
        &model,
        &targets,
        &[Candidate::of_scene(&scene)],
        &mut observer,
    )?;
    let wall_s = started.elapsed().as_secs_f64();
    observer.progress.bar.finish_and_clear();
    let outcomes = &outcomes[0];
    let durations: Vec<f64> = targets.iter().map(Target::duration).collect();
    let table1: Vec<Table1Row> = splits
        .iter()
        .map(|&split| {
            let losses: Vec<TrajectoryLoss> = selected
                .iter()
                .zip(outcomes)
                .filter(|((s, _), _)| *s == split)
                .map(|(_, o)| o.loss.clone())
                .collect();
            Table1Row::from_losses(split.name(), &losses)
        })
        .collect();
    let trajectories = selected
        .iter()
        .zip(outcomes)
        .map(|((split, _), o)| TrajectorySummary {
            id: o.loss.id.clone(),
            split: split.name().into(),
            frames: o.loss.frames.len(),
            chamfer_mean_m: o.loss.mean_chamfer(),
            object_mse_mean_m2: o.loss.mean_object_sq(),
            loss: o.loss.total(&weights),
            diverged_at_s: o.diverged.map(|e| e.time),
        })
        .collect();
    // Made only now: a start that fails or is interrupted leaves no folder behind.
    std::fs::create_dir_all(&out).map_err(|err| {
        input_error(format!(
            "{}: cannot create the output folder: {err}",
            out.display()
        ))
    })?;
    observer
        .write_pictures(&out, &model, &targets, outcomes)
        .map_err(crate::error::output_error)?;

    let sweep_grid = if args.sweep_grid {
        sweep(&scene, &targets, &durations)?
    } else {
        Vec::new()
    };
    let perturb = if args.perturb.is_empty() {
        Vec::new()
    } else {
        sensitivity(
            &model,
            &Candidate::of_scene(&scene),
            &targets,
            &args.perturb,
            &weights,
        )?
    };

    let summary = Summary {
        params: params_path.clone(),
        grid: scene.package.grid,
        dt_s: scene.dt() as f64,
        table1,
        trajectories,
        wall_s,
        real_time_factor: real_time_factor(&durations, wall_s),
        sweep_grid,
        perturb,
    };
    let json = serde_json::to_string_pretty(&summary)?;
    write_atomic(&out.join("summary.json"), json.as_bytes()).map_err(output_error)?;
    if args.json {
        println!("{json}");
    } else {
        print_summary(&summary, &out);
    }
    Ok(())
}

fn print_summary(s: &Summary, out: &Path) {
    println!(
        "{} on a {}x{} grid, dt {:.3e} s: {:.1} s wall, real-time factor {:.3} (recorded s per wall s, all trajectories)",
        s.params.display(),
        s.grid[0],
        s.grid[1],
        s.dt_s,
        s.wall_s,
        s.real_time_factor
    );
    println!("Table 1 (per frame; CD in m, object MSE in m^2):");
    print!("{}", table1_text(&s.table1));
    for t in &s.trajectories {
        let diverged = t
            .diverged_at_s
            .map_or(String::new(), |time| format!("  DIVERGED at {time:.3} s"));
        println!(
            "  {:<6} {:<5} frames {:>5}  CD {:.5} m  MSE {:.3e} m^2  loss {:.5}{diverged}",
            t.id, t.split, t.frames, t.chamfer_mean_m, t.object_mse_mean_m2, t.loss
        );
    }
    if !s.sweep_grid.is_empty() {
        println!("Table 2 (grid sweep):");
        println!("  grid   particles  real-time factor  wall s   CD mean m   MSE mean m^2");
        for r in &s.sweep_grid {
            println!(
                "  {:>2}x{:<3} {:>9}  {:>16.4}  {:>6.1}   {:>9.5}   {:>12.3e}",
                r.grid[0],
                r.grid[1],
                r.particles,
                r.real_time_factor,
                r.wall_s,
                r.chamfer_mean_m,
                r.object_mse_mean_m2
            );
        }
    }
    if !s.perturb.is_empty() {
        println!("Sensitivity (every calibrated value scaled by 1 + p/100):");
        println!("      p %     loss       CD mean m   MSE mean m^2");
        for r in &s.perturb {
            // Shortest exact form: a 1e-5 % probe of the loss's roughness reads as itself.
            println!(
                "  {:>7}  {:>9.5}  {:>9.5}   {:>12.3e}",
                r.percent.to_string(),
                r.loss,
                r.chamfer_mean_m,
                r.object_mse_mean_m2
            );
        }
    }
    println!("wrote {}/summary.json and pictures", out.display());
}

/// Table 2: the same parameters on the four reference grid sizes, timed.
fn sweep(
    scene: &SceneConfig,
    targets: &[Target],
    durations: &[f64],
) -> anyhow::Result<Vec<SweepRow>> {
    let mut rows = Vec::new();
    for between in SWEEP_BETWEEN {
        let mut s = scene.clone();
        s.package.grid = rlpkg_replay::grid_between_markers(between);
        let model = Arc::new(Model::new(&s).map_err(input_error)?);
        let mut bar = Progress::new(&format!("grid {}x{}", s.package.grid[0], s.package.grid[1]));
        let started = Instant::now();
        let outcomes = rollout(&model, targets, &[Candidate::of_scene(&s)], &mut bar)?;
        let wall_s = started.elapsed().as_secs_f64();
        bar.bar.finish_and_clear();
        let (cd, mse) = pooled_means(&outcomes[0]);
        rows.push(SweepRow {
            grid: s.package.grid,
            particles: model.num_particles(),
            real_time_factor: real_time_factor(durations, wall_s),
            wall_s,
            chamfer_mean_m: cd,
            object_mse_mean_m2: mse,
        });
    }
    Ok(rows)
}

/// The sensitivity table: all perturbations in one batched rollout.
fn sensitivity(
    model: &Arc<Model>,
    base: &Candidate,
    targets: &[Target],
    percents: &[f64],
    weights: &LossWeights,
) -> anyhow::Result<Vec<PerturbRow>> {
    let mut all = vec![0.0];
    all.extend(percents.iter().copied().filter(|p| *p != 0.0));
    let candidates: Vec<Candidate> = all.iter().map(|&p| perturbed(base, p)).collect();
    let mut bar = Progress::new("perturbations");
    let outcomes = rollout(model, targets, &candidates, &mut bar)?;
    bar.bar.finish_and_clear();
    Ok(all
        .iter()
        .zip(&outcomes)
        .map(|(&percent, o)| {
            let (cd, mse) = pooled_means(o);
            PerturbRow {
                percent,
                loss: mean_loss(o, weights),
                chamfer_mean_m: cd,
                object_mse_mean_m2: mse,
            }
        })
        .collect())
}

/// Per-frame means pooled over every frame of every trajectory (as Table 1).
fn pooled_means(outcomes: &[RolloutOutcome]) -> (f64, f64) {
    let losses: Vec<TrajectoryLoss> = outcomes.iter().map(|o| o.loss.clone()).collect();
    let row = Table1Row::from_losses("", &losses);
    (row.chamfer_m.mean, row.object_mse_m2.mean)
}

/// A progress bar over a rollout's substeps.
struct Progress {
    bar: ProgressBar,
}

impl Progress {
    fn new(label: &str) -> Self {
        let bar = ProgressBar::new(1).with_style(
            ProgressStyle::with_template(
                "{msg} {elapsed_precise} [{bar:30}] {percent}% (eta {eta})",
            )
            .expect("valid template")
            .progress_chars("=> "),
        );
        bar.set_message(label.to_string());
        Self { bar }
    }
}

impl Observer for Progress {
    fn progress(&mut self, done: u64, total: u64) {
        self.bar.set_length(total.max(1));
        self.bar.set_position(done);
    }

    fn stop(&mut self) -> bool {
        crate::interrupt::requested()
    }
}

/// One pictured instant of one trajectory.
struct Still {
    frame: usize,
    package: Vec<[f32; 3]>,
    cups: Vec<[f32; 3]>,
    disc: rlpkg_sim::DiscState,
    simulated_markers: Vec<[f32; 3]>,
}

/// Collects what the pictures need during the main rollout.
struct Pictures {
    progress: Progress,
    num_package: usize,
    still_frames: Vec<Vec<usize>>,
    stills: Vec<Vec<Still>>,
    site_errors: Vec<SiteErrors>,
    markers: Vec<Vec<Vec<[f64; 3]>>>,
}

impl Pictures {
    fn new(targets: &[Target], num_package: usize, label: &str) -> Self {
        Self {
            progress: Progress::new(label),
            num_package,
            still_frames: targets
                .iter()
                .map(|t| {
                    let last = t.times.len() - 1;
                    STILL_FRACTIONS
                        .iter()
                        .map(|f| (f * last as f64).round() as usize)
                        .collect()
                })
                .collect(),
            stills: targets.iter().map(|_| Vec::new()).collect(),
            site_errors: targets
                .iter()
                .map(|t| SiteErrors::new(t.sites().len()))
                .collect(),
            markers: targets.iter().map(|t| t.markers.clone()).collect(),
        }
    }

    fn write_pictures(
        &self,
        out: &Path,
        model: &Model,
        targets: &[Target],
        outcomes: &[RolloutOutcome],
    ) -> anyhow::Result<()> {
        let triangles: Vec<[u32; 3]> = model.package_triangles.iter().map(|t| t.idx).collect();
        for (t, target) in targets.iter().enumerate() {
            self.write_stills(out, model, &triangles, target, &self.stills[t])?;
            write_marker_error_plot(
                &out.join(format!("{}_marker_error.png", target.id)),
                target,
                &self.site_errors[t].means(),
            )?;
            write_loss_plot(
                &out.join(format!("{}_loss.png", target.id)),
                target,
                &outcomes[t].loss,
            )?;
        }
        Ok(())
    }

    fn write_stills(
        &self,
        out: &Path,
        model: &Model,
        triangles: &[[u32; 3]],
        target: &Target,
        stills: &[Still],
    ) -> anyhow::Result<()> {
        if stills.is_empty() {
            return Ok(()); // diverged before the first compared frame: nothing to draw
        }
        let mut scene = Bounds::empty();
        let mut close_up = Bounds::empty();
        for s in stills {
            s.package.iter().for_each(|&p| close_up.include(p));
            s.cups.iter().for_each(|&p| scene.include(p));
            target.markers[s.frame]
                .iter()
                .for_each(|p| scene.include(p.map(|v| v as f32)));
            scene.include(target.object[s.frame].map(|v| v as f32));
        }
        scene.include(close_up.min);
        scene.include(close_up.max);
        let view = View::new(
            &scene.padded(0.03),
            &close_up.padded(0.02),
            STILL_SIZE.0,
            STILL_SIZE.1,
        );
        for s in stills {
            let recorded: Vec<[f32; 3]> = target.markers[s.frame]
                .iter()
                .map(|p| p.map(|v| v as f32))
                .collect();
            let t = target.times[s.frame];
            let title = format!("{}: simulated vs recorded", target.id);
            let frame = Frame {
                title: &title,
                time: t as f32,
                package: &s.package,
                triangles,
                cups: &s.cups,
                disc: Some(Disc {
                    center: s.disc.position,
                    rotation: s.disc.orientation,
                    radius: model.disc.radius,
                    thickness: 2.0 * model.disc.half_height,
                }),
                recorded_markers: &recorded,
                simulated_markers: &s.simulated_markers,
                recorded_object: Some(target.object[s.frame].map(|v| v as f32)),
            };
            render::write_png(
                &out.join(format!("{}_t{t:05.2}.png", target.id)),
                &frame,
                &view,
            )?;
        }
        Ok(())
    }
}

impl Observer for Pictures {
    fn frame(&mut self, o: &FrameObservation) {
        self.site_errors[o.target].record(o.simulated_points, &self.markers[o.target][o.frame]);
        if self.still_frames[o.target].contains(&o.frame) {
            let positions = o.simulator.particle_positions(o.env);
            self.stills[o.target].push(Still {
                frame: o.frame,
                package: positions[..self.num_package].to_vec(),
                cups: positions[self.num_package..].to_vec(),
                disc: *o.disc,
                simulated_markers: o
                    .simulated_points
                    .iter()
                    .map(|p| p.map(|v| v as f32))
                    .collect(),
            });
        }
    }

    fn progress(&mut self, done: u64, total: u64) {
        self.progress.progress(done, total);
    }

    fn stop(&mut self) -> bool {
        self.progress.stop()
    }
}
