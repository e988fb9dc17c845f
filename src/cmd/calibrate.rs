//! `rlpkg calibrate <config.toml>`: fits simulator parameters to recorded trajectories with batched
//! Gaussian-process Bayesian optimisation (crate `rlpkg-calib`).
//!
//! Every batch of candidates is simulated on every training trajectory in one batched rollout.
//! Rerunning with the same output folder resumes from its `evaluations.csv` when it fits the same
//! objective (recorded in `objective.toml`: data, time window, loss, bounds, seed, scene); `--fresh`
//! starts over. The output folder is locked while the command runs (`<out>/.lock`): a second
//! calibration into it is refused.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;

use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use rlpkg_calib::config::{check_unique_ids, CalibrateConfig};
use rlpkg_calib::driver::{self, CalibratedParams, Plan};
use rlpkg_calib::fingerprint::{self, ObjectiveRecord};
use rlpkg_calib::objective::{Observer, SimObjective};
use rlpkg_calib::posterior_files;
use rlpkg_mocap::Trajectory;
use rlpkg_replay::{set_param, Candidate};
use rlpkg_sim::SceneConfig;

use crate::error::input_error;
use crate::files::{
    check_not_input, check_output, lock_folder, remove_staging_leftovers, Input, Staging,
};

/// Progress-bar ticks per batch.
const TICKS_PER_BATCH: u64 = 1000;

/// Arguments of `rlpkg calibrate`.
#[derive(Args, Debug)]
pub struct CalibrateArgs {
    /// Calibration config (TOML), e.g. configs/calibrate.toml.
    pub config: PathBuf,
    /// Output folder [default: the config's `out_dir`].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Batches after the initial design [default: the config's `optimiser.iterations`].
    #[arg(long, value_name = "N")]
    pub iterations: Option<usize>,
    /// Fit only these trajectory ids, comma-separated [default: the config's list or the train split].
    #[arg(long, value_delimiter = ',', value_name = "IDS")]
    pub trajectories: Vec<String>,
    /// Compare only the first S seconds of each trajectory [default: the config's `sim.max_seconds`].
    #[arg(long, value_name = "S")]
    pub max_seconds: Option<f64>,
    /// Start over: delete the output folder's previous evaluations instead of resuming.
    #[arg(long)]
    pub fresh: bool,
    /// Also write the calibrated scene here (e.g. configs/scenes/calibrated-study.toml).
    #[arg(long, value_name = "FILE")]
    pub write_params: Option<PathBuf>,
}

/// Runs `rlpkg calibrate`.
pub fn run(args: CalibrateArgs) -> anyhow::Result<()> {
    let mut config = CalibrateConfig::load(&args.config).map_err(input_error)?;
    apply_overrides(&mut config, &args)?;
    if config.out_dir.exists() && !config.out_dir.is_dir() {
        return Err(input_error(format!(
            "{}: is a file; expected a folder for the calibration's files (`out_dir` of {} or --out)",
            config.out_dir.display(),
            args.config.display()
        )));
    }
    check_write_params(&args, &config)?;
    check_out_dir(&args, &config)?;
    let (ids, trajectories) = config.training_trajectories().map_err(input_error)?;
    check_time_window(&args, &config, &trajectories)?;
    let scene = config.scene(&args.config).map_err(input_error)?;
    check_bounds_in_scene(&config, &scene, &args.config)?;
    // One command at a time in the output folder: nothing in it is removed (`--fresh`, leftovers)
    // or written before the lock is held.
    let _lock = lock_folder(&config.out_dir, true)?;
    for path in remove_staging_leftovers(&config.out_dir, STAGING_PREFIX)? {
        eprintln!("removed the leftover staging folder {}", path.display());
    }
    let names: Vec<String> = config.params.iter().map(|p| p.name.clone()).collect();
    let space = config.space();
    if let Some(smc) = config.smc {
        return run_posterior(&args, &config, smc, &ids, &trajectories, &scene);
    }

    let planned = {
        let plan = make_plan(&config, &space, Vec::new());
        plan.planned_batches()
    };
    let bar = ProgressBar::new(planned as u64 * TICKS_PER_BATCH).with_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:30}] batch {msg} (eta {eta})")
            .expect("valid template")
            .progress_chars("=> "),
    );
    let batch_base = Arc::new(AtomicU64::new(0));
    let objective = SimObjective::new(
        &scene,
        names.clone(),
        &trajectories,
        config.loss,
        config.sim.max_seconds,
    )
    .map_err(input_error)?;
    let seed = objective.base_values();
    let inside = space
        .specs()
        .iter()
        .zip(&seed)
        .all(|(s, v)| (s.lower..=s.upper).contains(v));
    // The preset's values go first when they lie inside the bounds: a known reference point.
    let seed_points = if inside { vec![seed] } else { Vec::new() };
    let plan = make_plan(&config, &space, seed_points);
    let mut objective = objective.with_observer(Box::new(BarObserver {
        bar: bar.clone(),
        batch_base: batch_base.clone(),
    }));

    let out_dir = &config.out_dir;
    let record = ObjectiveRecord {
        data: &config.data,
        trajectories: &ids,
        max_seconds: config.sim.max_seconds,
        seed: config.optimiser().seed,
        initial_points: config.optimiser().initial_points,
        batch_size: config.optimiser().batch_size,
        loss: config.loss,
        param: &config.params,
        smc: None,
        likelihood: None,
        scene: &scene,
    }
    .to_text()?;
    let mut recorded = false;
    if !args.fresh {
        recorded = fingerprint::check(out_dir, &record).map_err(input_error)?;
        if !recorded && out_dir.join("evaluations.csv").exists() {
            eprintln!(
                "{} has no {}: resuming its evaluations without checking that they fit this objective",
                out_dir.display(),
                fingerprint::OBJECTIVE_FILE
            );
        }
    }
    // What a calibration stopped at once (a second signal, a kill) left behind.
    let mut leftovers =
        driver::clean_leftovers(out_dir, &driver::OUTPUT_FILES).map_err(driver_error)?;
    if let Some(path) = &args.write_params {
        let dir = path.parent().filter(|d| !d.as_os_str().is_empty());
        if let Some(name) = path.file_name().and_then(|name| name.to_str()) {
            let dir = dir.unwrap_or(Path::new("."));
            leftovers.extend(driver::clean_leftovers(dir, &[name]).map_err(driver_error)?);
        }
    }
    for path in leftovers {
        eprintln!("removed the leftover temporary {}", path.display());
    }
    if args.fresh {
        remove_outputs(out_dir, &driver::OUTPUT_FILES)?;
    }
    println!(
        "calibrating {} parameter(s) on {} trajectory(ies) [{}], grid {}x{}, dt {:.3e} s, {} batch(es) of {}; output in {}",
        names.len(),
        ids.len(),
        ids.join(","),
        scene.package.grid[0],
        scene.package.grid[1],
        scene.dt(),
        planned,
        config.optimiser().batch_size,
        out_dir.display()
    );
    // A folder with a log but no record (written by an earlier version) gets its record once
    // its log has been read back without error, at the end.
    let fresh_start = !recorded && !out_dir.join("evaluations.csv").exists();
    if fresh_start {
        write_record(out_dir, &record)?;
    }
    let started = Instant::now();
    // A signal stops the rollout of the current batch (whose rows are not logged) and the
    // calibration; the log and the other files stay whole, and the next run resumes.
    let _cooperation = crate::interrupt::Cooperation::start();
    let best = driver::run(&plan, &mut objective, |report| {
        batch_base.store(
            (report.batch as u64 + 1) * TICKS_PER_BATCH,
            Ordering::Relaxed,
        );
        bar.set_position((report.batch as u64 + 1) * TICKS_PER_BATCH);
        bar.set_message(format!(
            "{}/{}, best loss {:.5}",
            report.batch + 1,
            report.planned_batches,
            report.best_loss
        ));
        bar.println(format!(
            "batch {:>3}/{}: batch best {:.6}, best {:.6} ({} evaluations)",
            report.batch + 1,
            report.planned_batches,
            report.batch_best_loss,
            report.best_loss,
            report.evaluations
        ));
    });
    let best = match best {
        Ok(best) => best,
        Err(err) => {
            if fresh_start {
                remove_empty_start(out_dir);
            }
            return Err(driver_error(err));
        }
    };
    if !recorded && !fresh_start {
        driver::write_atomically(
            &out_dir.join(fingerprint::OBJECTIVE_FILE),
            record.as_bytes(),
        )
        .map_err(driver_error)?;
    }
    bar.finish_and_clear();
    let wall = started.elapsed().as_secs_f64();

    let calibrated = objective.calibrated_scene(&best)?;
    let text = scene_text(
        &calibrated,
        &best,
        &ids,
        config.sim.max_seconds,
        &args.config,
    )?;
    let staging = Staging::new(out_dir, STAGING_PREFIX)?;
    driver::write_atomically(&staging.path("calibrated.toml"), text.as_bytes())
        .map_err(driver_error)?;
    place_outputs(
        staging,
        &["calibrated.toml"],
        args.write_params.as_deref(),
        &text,
    )?;
    let calibrated_path = out_dir.join("calibrated.toml");
    print_summary(
        &best,
        wall,
        out_dir,
        &calibrated_path,
        args.write_params.as_deref(),
    );
    Ok(())
}

/// `rlpkg calibrate` of a config with `[smc]`: samples the posterior on the simulator
/// ([`rlpkg_calib::sampled_posterior`]), resuming the folder's log, and writes the draws, their
/// summary and the best draw's scene.
fn run_posterior(
    args: &CalibrateArgs,
    config: &CalibrateConfig,
    smc: rlpkg_calib::smc::SmcSettings,
    ids: &[String],
    trajectories: &[Trajectory],
    scene: &SceneConfig,
) -> anyhow::Result<()> {
    use rlpkg_calib::sampled_posterior::{posterior_table, sample_posterior, POSTERIOR_FILES};
    let out_dir = &config.out_dir;
    let record = ObjectiveRecord::posterior(config, smc, ids, scene).to_text()?;
    if args.fresh {
        remove_outputs(out_dir, &POSTERIOR_FILES)?;
    } else if !fingerprint::check(out_dir, &record).map_err(input_error)?
        && out_dir.join("evaluations.csv").exists()
    {
        return Err(input_error(format!(
            "{}: has an evaluations.csv but no {}; use --fresh to start over or another --out",
            out_dir.display(),
            fingerprint::OBJECTIVE_FILE
        )));
    }
    for path in driver::clean_leftovers(out_dir, &POSTERIOR_FILES).map_err(driver_error)? {
        eprintln!("removed the leftover temporary {}", path.display());
    }
    write_record(out_dir, &record)?;
    println!(
        "sampling the posterior of {} parameter(s) on {} trajectory(ies) [{}], grid {}x{}, dt {:.3e} s, \
         {}; output in {}",
        config.params.len(),
        ids.len(),
        ids.join(","),
        scene.package.grid[0],
        scene.package.grid[1],
        scene.dt(),
        smc.sampler_text(),
        out_dir.display()
    );
    println!("{}", config.likelihood.replicas_text());
    let names: Vec<String> = config.params.iter().map(|p| p.name.clone()).collect();
    let bar = ProgressBar::new_spinner().with_style(
        ProgressStyle::with_template("{elapsed_precise} {msg}").expect("valid template"),
    );
    let mut objective = SimObjective::new(
        scene,
        names,
        trajectories,
        config.loss,
        config.sim.max_seconds,
    )
    .map_err(input_error)?
    .with_replicas(&config.likelihood)
    .with_observer(Box::new(BarObserver {
        bar: bar.clone(),
        batch_base: Arc::new(AtomicU64::new(0)),
    }));
    for target in objective.targets() {
        let Some(t) = &target.tracking else {
            continue; // synthetic or given identities: nothing was tracked
        };
        let how = if t.recorded_ids {
            "with the recording's ids"
        } else {
            "tracked"
        };
        println!(
            "  {}: {} markers {how} from the first frame ({:.1} % of the points), {} breaks, {} relinked, \
             {} new tracks; {:.1} % of the points tied to a site",
            target.id,
            t.initial_tracks,
            100.0 * t.initial_share(),
            t.breaks,
            t.relinked,
            t.new_tracks,
            100.0 * target.labelled_share()
        );
    }
    let started = Instant::now();
    let _cooperation = crate::interrupt::Cooperation::start();
    let posterior = sample_posterior(
        &mut objective,
        &config.space(),
        &smc,
        &config.likelihood,
        out_dir,
        |batch, evaluations| {
            bar.set_message(format!("batch {batch}, {evaluations} candidates simulated"));
        },
    );
    bar.finish_and_clear();
    let posterior = posterior.map_err(|e| match e {
        rlpkg_calib::sampled_posterior::SampledPosteriorError::Smc(_) => anyhow::Error::new(e),
        other => input_error(other),
    })?;
    let wall = started.elapsed().as_secs_f64();
    let calibrated = objective.calibrated_scene(&posterior.best)?;
    let text = scene_text(
        &calibrated,
        &posterior.best,
        ids,
        config.sim.max_seconds,
        &args.config,
    )?;
    // The files that tell a finished posterior (the scene, the corner plot, the summary that
    // `eval --params` and a transport task read) are staged and moved into place together.
    let staging = Staging::new(out_dir, STAGING_PREFIX)?;
    driver::write_atomically(&staging.path("calibrated.toml"), text.as_bytes())
        .map_err(driver_error)?;
    let space = config.space();
    let unit: Vec<Vec<f64>> = posterior.draws.iter().map(|d| space.to_unit(d)).collect();
    let best_values: Vec<f64> = space
        .names()
        .iter()
        .map(|n| posterior.best.params[*n])
        .collect();
    let best_unit = space.to_unit(&best_values);
    crate::render::plot::write_corner_plot(
        &staging.path("corner.png"),
        &space.names(),
        &unit,
        &best_unit,
    )
    .map_err(crate::error::output_error)?;
    // The calibration the draws came from, so that a transport task or `eval --params` given this
    // folder can rebuild (and check) the scene they are parameters of.
    let summary = posterior_files::summary_json(&args.config, out_dir, &[], &posterior)?;
    driver::write_atomically(
        &staging.path(posterior_files::SUMMARY_FILE),
        summary.as_bytes(),
    )
    .map_err(driver_error)?;
    place_outputs(
        staging,
        &[
            "corner.png",
            "calibrated.toml",
            posterior_files::SUMMARY_FILE,
        ],
        args.write_params.as_deref(),
        &text,
    )?;
    print!("{}", posterior_table(&posterior));
    print!("{}", rlpkg_calib::fisher::fisher_table(&posterior.fisher));
    println!(
        "{} candidates simulated in {} search generations and {} stages, {} more polishing, {wall:.1} s \
         ({:.1} per s); best log-likelihood {:.2}",
        posterior.evaluations,
        posterior.search_generations,
        posterior.stages,
        posterior.polished_evaluations,
        (posterior.evaluations + posterior.polished_evaluations) as f64 / wall.max(1e-9),
        posterior.best_log_likelihood
    );
    println!(
        "wrote {}/{{objective.toml, evaluations.csv, search.csv, stages.csv, samples.csv, posterior.toml, best.toml, fisher.toml, calibrated.toml, corner.png, summary.json}}",
        out_dir.display()
    );
    if let Some(path) = &args.write_params {
        println!("wrote {}", path.display());
    }
    Ok(())
}

/// The hidden folder inside the output folder that a calibration's final files are staged in.
const STAGING_PREFIX: &str = ".calibrate-";

/// Writes `--write-params` (when given) and moves the staged `names` into the output folder,
/// unless a signal asked the command to stop: then nothing of the final set is written.
fn place_outputs(
    staging: Staging,
    names: &[&str],
    write_params: Option<&Path>,
    scene: &str,
) -> anyhow::Result<()> {
    crate::interrupt::check()?;
    if let Some(path) = write_params {
        driver::write_atomically(path, scene.as_bytes()).map_err(driver_error)?;
    }
    staging.place(names)
}

/// Creates the output folder and writes the objective `record` into it.
fn write_record(out_dir: &Path, record: &str) -> anyhow::Result<()> {
    std::fs::create_dir_all(out_dir)
        .map_err(|e| input_error(format!("{}: cannot create: {e}", out_dir.display())))?;
    driver::write_atomically(
        &out_dir.join(fingerprint::OBJECTIVE_FILE),
        record.as_bytes(),
    )
    .map_err(driver_error)
}

/// `--fresh`: removes the output folder's `files` that exist.
fn remove_outputs(out_dir: &Path, files: &[&str]) -> anyhow::Result<()> {
    for file in files {
        let path = out_dir.join(file);
        if path.exists() {
            std::fs::remove_file(&path).map_err(|err| {
                input_error(format!(
                    "{}: cannot remove (--fresh): {err}",
                    path.display()
                ))
            })?;
        }
    }
    Ok(())
}

/// Removes what a calibration that stopped before logging its first batch wrote (the objective,
/// the log's header; the folder, when the command made it, goes with its lock): a start that
/// failed or was interrupted leaves the output as it was. Best effort: what cannot be removed is a
/// fresh start's, harmless.
fn remove_empty_start(out_dir: &Path) {
    let log = out_dir.join("evaluations.csv");
    let logged = match std::fs::read_to_string(&log) {
        Ok(text) => text.lines().count() > 1,
        Err(_) => true,
    };
    if logged {
        return;
    }
    let _ = std::fs::remove_file(&log);
    let _ = std::fs::remove_file(out_dir.join(fingerprint::OBJECTIVE_FILE));
}

/// `--write-params` must be a file that can be written (checked before any simulation) and none
/// of the calibration's inputs: its config, its scene, its dataset, or a file of its output folder
/// that the calibration writes and reads back (`calibrated.toml` is the same scene).
fn check_write_params(args: &CalibrateArgs, config: &CalibrateConfig) -> anyhow::Result<()> {
    use rlpkg_calib::sampled_posterior::POSTERIOR_FILES;
    const OPTION: &str = "--write-params";
    let Some(path) = &args.write_params else {
        return Ok(());
    };
    check_output(OPTION, path)?;
    let preset = Path::new(&config.sim.preset);
    let mut inputs = vec![Input::File(&args.config, "the calibration config")];
    if !matches!(config.sim.preset.as_str(), "reference" | "physical") {
        inputs.push(Input::File(preset, "the config's scene (`sim.preset`)"));
    }
    inputs.push(Input::Folder(&config.data, "the config's dataset (`data`)"));
    let mut names: Vec<&str> = driver::OUTPUT_FILES.to_vec();
    names.extend(POSTERIOR_FILES);
    names.extend(["corner.png", posterior_files::SUMMARY_FILE]);
    names.retain(|name| *name != "calibrated.toml");
    let outputs: Vec<PathBuf> = names.iter().map(|name| config.out_dir.join(name)).collect();
    inputs.extend(
        outputs
            .iter()
            .map(|file| Input::File(file, "a file of the calibration's output folder")),
    );
    check_not_input(OPTION, path, &inputs)
}

/// The output folder must not be where one of the calibration's inputs (its config, its scene)
/// sits under the name of a file the calibration writes: checked before any simulation.
fn check_out_dir(args: &CalibrateArgs, config: &CalibrateConfig) -> anyhow::Result<()> {
    use rlpkg_calib::sampled_posterior::output_over_input;
    let mut inputs = vec![(args.config.as_path(), "the calibration config")];
    if !matches!(config.sim.preset.as_str(), "reference" | "physical") {
        inputs.push((
            Path::new(&config.sim.preset),
            "the config's scene (`sim.preset`)",
        ));
    }
    let Some((output, input, what)) = output_over_input(&config.out_dir, &inputs) else {
        return Ok(());
    };
    let given = match &args.out {
        Some(out) => format!("--out {}", out.display()),
        None => format!(
            "{}: key `out_dir` = {}",
            args.config.display(),
            config.out_dir.display()
        ),
    };
    Err(input_error(format!(
        "{given}: the calibration writes {} there, which is {}, {what}; expected another output \
         folder",
        output.display(),
        input.display()
    )))
}

/// A time window longer than every recording would compare nothing less than the whole of each:
/// a value beyond the longest is a mistake (e.g. milliseconds given as seconds), said before any
/// simulation.
fn check_time_window(
    args: &CalibrateArgs,
    config: &CalibrateConfig,
    trajectories: &[Trajectory],
) -> anyhow::Result<()> {
    let Some(seconds) = config.sim.max_seconds else {
        return Ok(());
    };
    let longest = trajectories
        .iter()
        .filter_map(|t| Some(t.tool.t.last()? - t.tool.t.first()?))
        .fold(0.0, f64::max);
    if seconds <= longest {
        return Ok(());
    }
    let given = match args.max_seconds {
        Some(_) => format!("--max-seconds {seconds:?}"),
        None => format!(
            "{}: key `sim.max_seconds` = {seconds:?}",
            args.config.display()
        ),
    };
    Err(input_error(format!(
        "{given}: expected at most the longest recording's {longest:.4} s; leave it out to \
         compare the whole recordings"
    )))
}

/// The evaluation log and the output files are the user's (exit 2: malformed log, folder that is
/// a file, read-only or full); a failing optimiser or objective is not.
fn driver_error(err: driver::DriverError) -> anyhow::Error {
    match err {
        driver::DriverError::Log(_) | driver::DriverError::Write { .. } => input_error(err),
        other => anyhow::Error::new(other),
    }
}

/// Every `[[param]]` bound must be a value the scene accepts (`params.mu_con` in [0, 100], ...):
/// checked before any rollout, which would otherwise fail on the first candidate beyond it.
fn check_bounds_in_scene(
    config: &CalibrateConfig,
    scene: &SceneConfig,
    file: &Path,
) -> anyhow::Result<()> {
    for (i, spec) in config.params.iter().enumerate() {
        for (end, value) in [("lower", spec.lower), ("upper", spec.upper)] {
            let mut candidate = Candidate::of_scene(scene);
            set_param(&mut candidate, &spec.name, value).map_err(input_error)?;
            let mut probe = scene.clone();
            candidate.apply_to(&mut probe);
            probe.validate(&config.sim.preset).map_err(|err| {
                input_error(format!(
                    "{}: key `param[{i}].{end}` = {value} ({}): the scene does not accept it: {err}",
                    file.display(),
                    spec.name
                ))
            })?;
        }
    }
    Ok(())
}

/// Applies the command-line overrides to the configuration, with range checks.
fn apply_overrides(config: &mut CalibrateConfig, args: &CalibrateArgs) -> anyhow::Result<()> {
    if let Some(out) = &args.out {
        config.out_dir = out.clone();
    }
    if let Some(n) = args.iterations {
        if config.smc.is_some() {
            return Err(input_error(format!(
                "--iterations {n}: the config samples a posterior ([smc]), which has no \
                 iterations; set smc.particles or smc.moves instead"
            )));
        }
        if !(1..=100_000).contains(&n) {
            return Err(input_error(format!(
                "--iterations {n}: expected an integer in [1, 100000]"
            )));
        }
        config.optimiser_mut().iterations = n;
    }
    if !args.trajectories.is_empty() {
        check_unique_ids("--trajectories", &args.trajectories).map_err(input_error)?;
        config.trajectories = Some(args.trajectories.clone());
    }
    if let Some(s) = args.max_seconds {
        if !(s > 0.0 && s.is_finite()) {
            return Err(input_error(format!(
                "--max-seconds {s}: expected a duration > 0 s"
            )));
        }
        config.sim.max_seconds = Some(s);
    }
    Ok(())
}

fn make_plan(
    config: &CalibrateConfig,
    space: &rlpkg_calib::space::ParamSpace,
    seed_points: Vec<Vec<f64>>,
) -> Plan {
    Plan {
        space: space.clone(),
        settings: config.bo_settings(),
        seed_points,
        iterations: config.optimiser().iterations,
        out_dir: config.out_dir.clone(),
    }
}

/// Moves the progress bar within a batch as the rollout advances.
struct BarObserver {
    bar: ProgressBar,
    batch_base: Arc<AtomicU64>,
}

impl Observer for BarObserver {
    fn progress(&mut self, done: u64, total: u64) {
        let within = done * TICKS_PER_BATCH / total.max(1);
        self.bar.set_position(
            self.batch_base.load(Ordering::Relaxed) + within.min(TICKS_PER_BATCH - 1),
        );
    }

    fn stop(&mut self) -> bool {
        crate::interrupt::requested()
    }
}

/// The calibrated scene as TOML, with a header saying how it was obtained.
fn scene_text(
    scene: &SceneConfig,
    best: &CalibratedParams,
    ids: &[String],
    max_seconds: Option<f64>,
    config: &Path,
) -> anyhow::Result<String> {
    let body = toml::to_string_pretty(scene)?;
    let span = max_seconds.map_or(String::new(), |s| format!(" (first {s} s of each)"));
    Ok(format!(
        "# Calibrated by `rlpkg calibrate {}` on {} trajectory(ies){span}: {}.\n\
         # Training loss {:.6} (mean per-frame Chamfer distance {:.5} m, object MSE {:.3e} m^2) after {} evaluations.\n\
         # Calibrated: {}. Use with `rlpkg eval --params <this file>` or `rlpkg simulate --params <this file>`.\n\n{}",
        config.display(),
        ids.len(),
        ids.join(", "),
        best.fit.loss,
        best.fit.chamfer_m,
        best.fit.object_mse_m2,
        best.fit.evaluations,
        best.params.keys().cloned().collect::<Vec<_>>().join(", "),
        body
    ))
}

fn print_summary(
    best: &CalibratedParams,
    wall_s: f64,
    out_dir: &Path,
    calibrated: &Path,
    extra: Option<&Path>,
) {
    println!(
        "best parameters after {} evaluations:",
        best.fit.evaluations
    );
    for (name, value) in &best.params {
        println!("  {name:<9} = {value:.6e}");
    }
    println!(
        "training loss {:.6}: mean Chamfer distance {:.5} m, object MSE {:.3e} m^2",
        best.fit.loss, best.fit.chamfer_m, best.fit.object_mse_m2
    );
    println!("wall time {wall_s:.1} s");
    println!(
        "wrote {}/{{objective.toml, evaluations.csv, progress.csv, best.toml}} and {}",
        out_dir.display(),
        calibrated.display()
    );
    if let Some(path) = extra {
        println!("wrote {}", path.display());
    }
}
