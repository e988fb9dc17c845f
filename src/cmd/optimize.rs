//! `rlpkg optimize <config.toml>`: sampling-based trajectory optimisation (the cross-entropy
//! method) of the transport task's open-loop command for one package condition, robustly for K
//! of them, or for the nominal package at each of a list of target tilts (a library of
//! commands); with `--mpc`, receding-horizon control of the K packages instead (crate
//! `rlpkg-env`, modules `transport::optimize` and `transport::mpc`).
//!
//! Writes to the output folder: `trajectory.csv` (the best command's tool motion on the first
//! package, in the robot-file format of `rlpkg data import`), `commands.csv` (its actions every
//! control interval), `costs.csv` (cost per iteration), `costs.png` and `summary.json`; a library
//! writes those into `tilt-<degrees>/` per tilt and a `summary.json` listing them; `--mpc` writes
//! `mpc.json`. The files depend only on the config, whatever the number of threads.

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use rlpkg_env::transport::{
    run_traced_episodes, Cem, CemSettings, HorizonSearch, KnotCurve, OpenLoopProblem,
    OutcomeSummary, RecedingHorizon, RiskMeasure, ToolSample, TransportConfig,
};
use rlpkg_env::Transport;
use serde::{Deserialize, Serialize};

use crate::error::{input_error, output_error};
use crate::render::plot::write_cost_plot;

/// Arguments of `rlpkg optimize`.
#[derive(Args, Debug)]
pub struct OptimizeArgs {
    /// Optimisation config (TOML), e.g. configs/optimize/transport.toml.
    pub config: PathBuf,
    /// Output folder [default: the config's `out_dir`].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// Receding-horizon control of the `[conditions]` packages instead (settings in `[mpc]`):
    /// every control step re-optimises the command over the horizon from the episode's state.
    #[arg(long)]
    pub mpc: bool,
}

/// The optimisation config.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct OptimizeConfig {
    /// Training config whose `[transport]` table sets the task (scene, paths, limits, reward).
    pub transport: PathBuf,
    /// Output folder.
    pub out_dir: PathBuf,
    /// Which packages the command is optimised for.
    pub conditions: Conditions,
    /// How a command's costs over the packages combine.
    #[serde(default)]
    pub risk: Risk,
    /// The cross-entropy method.
    pub cem: CemTable,
    /// The decision variables.
    pub knots: Knots,
    /// Receding-horizon control (`--mpc`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mpc: Option<MpcTable>,
}

/// `[conditions]`: the first `packages` episodes a reset from `seed` draws (what `rlpkg eval
/// --seed <seed>` runs as its first episodes).
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Conditions {
    /// Seed of the episodes' draws (path, mass, object offset and tilt, target tilt, ...).
    pub seed: u64,
    /// K: 1 optimises for one package condition, more for all K at once.
    pub packages: usize,
    /// A library instead: one command per target tilt (degrees), each for the nominal package
    /// (every randomised quantity at the middle of its range; needs `packages = 1`). An
    /// episode of `rlpkg eval --optimized` plays the command of the tilt nearest its own.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub nominal_target_tilts_deg: Vec<f64>,
}

/// `[mpc]`: each control step optimises the command over the next `horizon_s` (knots evenly
/// spaced over it, counted from now) with `iterations` CEM iterations of `[cem]`'s population,
/// then applies the best candidate's first action.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MpcTable {
    /// Planning horizon (s).
    pub horizon_s: f64,
    /// Knots per action over the horizon.
    pub knots: usize,
    /// CEM iterations per control step.
    pub iterations: usize,
}

/// `[risk]`: a command's cost over K packages is `(1 - weight) x mean + weight x quantile`.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Risk {
    /// Quantile level in [0, 1].
    pub quantile: f64,
    /// Weight of the quantile in [0, 1].
    pub weight: f64,
}

impl Default for Risk {
    fn default() -> Self {
        Self {
            quantile: 0.9,
            weight: 0.0,
        }
    }
}

/// `[cem]`.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CemTable {
    /// Candidates per iteration (the distribution's mean first); each is rolled out on every
    /// package, so one iteration is one batch of population x packages copies.
    pub population: usize,
    /// Lowest-cost candidates the distribution is refitted to.
    pub elites: usize,
    /// Iterations.
    pub iterations: usize,
    /// Weight of the elites in each update, in (0, 1].
    pub smoothing: f64,
    /// Seed of the samples.
    pub seed: u64,
}

/// `[knots]`: each action is a smooth curve in time through `count` knots evenly spaced over
/// `horizon_s`, held after it.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Knots {
    /// Knots per action.
    pub count: usize,
    /// Time of the last knot (s).
    pub horizon_s: f64,
    /// Path speed of every knot at the start (m/s).
    pub initial_speed_m_s: f64,
    /// Initial spread of the path speed knots (m/s).
    pub speed_std_m_s: f64,
    /// Initial spread of the tilt offset knots (degrees).
    pub tilt_std_deg: f64,
}

/// Largest population x packages: one batch of copies.
const MAX_COPIES: usize = 4096;

impl OptimizeConfig {
    /// Reads and checks the config at `path`.
    fn load(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| input_error(format!("{}: cannot read: {e}", path.display())))?;
        let config: Self =
            toml::from_str(&text).map_err(|e| input_error(format!("{}: {e}", path.display())))?;
        config.validate(path)?;
        Ok(config)
    }

    fn validate(&self, path: &Path) -> anyhow::Result<()> {
        let fail = |key: &str, value: String, expected: &str| {
            Err(input_error(format!(
                "{}: {key} = {value}: expected {expected}",
                path.display()
            )))
        };
        let (c, k, r) = (&self.cem, &self.knots, &self.risk);
        if self.conditions.packages == 0 {
            return fail("conditions.packages", "0".into(), ">= 1");
        }
        if c.population < 2 {
            return fail("cem.population", c.population.to_string(), ">= 2");
        }
        if c.population.saturating_mul(self.conditions.packages) > MAX_COPIES {
            return fail(
                "cem.population",
                c.population.to_string(),
                &format!("population x conditions.packages <= {MAX_COPIES}"),
            );
        }
        if c.elites == 0 || c.elites > c.population {
            return fail("cem.elites", c.elites.to_string(), "in [1, cem.population]");
        }
        if c.iterations == 0 || c.iterations > 10_000 {
            return fail("cem.iterations", c.iterations.to_string(), "in [1, 10000]");
        }
        if !(c.smoothing > 0.0 && c.smoothing <= 1.0) {
            return fail("cem.smoothing", c.smoothing.to_string(), "in (0, 1]");
        }
        if !(2..=64).contains(&k.count) {
            return fail("knots.count", k.count.to_string(), "in [2, 64]");
        }
        // Ten minutes is beyond any transport; a larger value is a typo, not a plan.
        if !(k.horizon_s.is_finite() && k.horizon_s > 0.0 && k.horizon_s <= 600.0) {
            return fail(
                "knots.horizon_s",
                k.horizon_s.to_string(),
                "in (0, 600] (s)",
            );
        }
        for (key, v) in [
            ("knots.initial_speed_m_s", k.initial_speed_m_s),
            ("knots.speed_std_m_s", k.speed_std_m_s),
            ("knots.tilt_std_deg", k.tilt_std_deg),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return fail(key, v.to_string(), ">= 0");
            }
        }
        for (key, v) in [("risk.quantile", r.quantile), ("risk.weight", r.weight)] {
            if !(0.0..=1.0).contains(&v) {
                return fail(key, v.to_string(), "in [0, 1]");
            }
        }
        let tilts = &self.conditions.nominal_target_tilts_deg;
        if !tilts.is_empty() {
            if self.conditions.packages != 1 {
                return fail(
                    "conditions.packages",
                    self.conditions.packages.to_string(),
                    "1 with conditions.nominal_target_tilts_deg (the nominal package)",
                );
            }
            if tilts.len() > 64
                || tilts
                    .iter()
                    .any(|t| !(t.is_finite() && (0.0..=90.0).contains(t)))
            {
                return fail(
                    "conditions.nominal_target_tilts_deg",
                    format!("{tilts:?}"),
                    "at most 64 tilts in [0, 90] degrees",
                );
            }
        }
        if let Some(m) = &self.mpc {
            if !(m.horizon_s.is_finite() && m.horizon_s > 0.0 && m.horizon_s <= 10.0) {
                return fail("mpc.horizon_s", m.horizon_s.to_string(), "in (0, 10] (s)");
            }
            if !(2..=64).contains(&m.knots) {
                return fail("mpc.knots", m.knots.to_string(), "in [2, 64]");
            }
            if !(1..=1000).contains(&m.iterations) {
                return fail("mpc.iterations", m.iterations.to_string(), "in [1, 1000]");
            }
        }
        Ok(())
    }
}

/// One iteration's costs (risk over the packages).
#[derive(Debug, Clone, Copy, Serialize)]
struct IterationCosts {
    iteration: usize,
    /// The distribution's mean (the first candidate).
    mean_candidate: f64,
    /// The iteration's lowest.
    best: f64,
    /// Mean over the elites.
    elite_mean: f64,
    /// The lowest so far.
    best_so_far: f64,
}

/// `summary.json`.
#[derive(Debug, Serialize)]
struct Summary {
    /// The nominal package's target tilt (degrees) of a library's command.
    #[serde(skip_serializing_if = "Option::is_none")]
    target_tilt_deg: Option<f64>,
    /// The risk of the initial command (iteration 0's mean).
    start_cost: f64,
    /// The risk of the best command found.
    best_cost: f64,
    /// The best command's cost on each package.
    best_package_costs: Vec<f64>,
    /// The best command's knots: path speed (m/s), then tilt offsets about x and z (rad).
    best_knots: Vec<f64>,
    /// Simulated time the best command's episode on the first package took (s).
    episode_time_s: f64,
    iterations: Vec<IterationCosts>,
}

/// One command of a library (`summary.json` of a library's folder lists them).
#[derive(Debug, Serialize)]
struct LibraryEntry {
    target_tilt_deg: f64,
    /// Its folder, relative to the library's.
    folder: String,
    start_cost: f64,
    best_cost: f64,
    best_knots: Vec<f64>,
    episode_time_s: f64,
    /// Wall time of its optimisation (s).
    wall_s: f64,
}

/// `summary.json` of a library.
#[derive(Debug, Serialize)]
struct LibrarySummary<'a> {
    config: &'a OptimizeConfig,
    library: Vec<LibraryEntry>,
}

/// `mpc.json`.
#[derive(Debug, Serialize)]
struct MpcSummary<'a> {
    config: &'a OptimizeConfig,
    /// The K episodes under receding-horizon control.
    outcome: OutcomeSummary,
    /// Control steps planned (over all episodes of the batch) and their wall time.
    control_steps: usize,
    control_interval_s: f64,
    /// Wall time per control step of one episode (s): the batch's planning time over the
    /// episode-steps it planned.
    wall_per_control_step_s: f64,
    /// How many times slower than real time the loop runs (wall per control step over the
    /// control interval).
    real_time_factor: f64,
}

/// Runs `rlpkg optimize`.
pub fn run(args: OptimizeArgs) -> anyhow::Result<()> {
    let config = OptimizeConfig::load(&args.config)?;
    // summary.json echoes the config as written; --out only moves the files.
    let out = args.out.clone().unwrap_or_else(|| config.out_dir.clone());
    if out.exists() && !out.is_dir() {
        return Err(input_error(format!(
            "{}: is a file; expected a folder (`out_dir` of {} or --out)",
            out.display(),
            args.config.display()
        )));
    }
    let source = config.transport.display().to_string();
    let text = std::fs::read_to_string(&config.transport).map_err(|e| {
        input_error(format!(
            "{source}: cannot read (`transport` of {}): {e}",
            args.config.display()
        ))
    })?;
    let transport = TransportConfig::from_toml_str(&text, &source).map_err(input_error)?;
    // The search's mean starts here; beyond the task's limit it would be clamped without a word.
    let limit = transport.limits.max_path_speed_m_s;
    if config.knots.initial_speed_m_s > limit {
        return Err(input_error(format!(
            "{}: knots.initial_speed_m_s = {}: expected at most the task's \
             limits.max_path_speed_m_s = {limit} m/s ({source})",
            args.config.display(),
            config.knots.initial_speed_m_s
        )));
    }
    let _cooperation = crate::interrupt::Cooperation::start();
    if args.mpc {
        return run_mpc(&args, &config, transport, &source, &out);
    }
    let tilts = &config.conditions.nominal_target_tilts_deg;
    if tilts.is_empty() {
        let found = optimise(&config, transport, &source, args.quiet, "")?;
        write_outputs(&out, &config, &found)?;
        println!(
            "cost {:.4} at the start, {:.4} at the end ({} iterations of {} candidates x {} \
             packages)",
            found.summary.start_cost,
            found.summary.best_cost,
            config.cem.iterations,
            config.cem.population,
            config.conditions.packages
        );
        println!(
            "wall time: {:.1} s to settle the packages, {:.2} s per iteration, {:.1} s in all",
            found.setup_s,
            found.optimise_s / config.cem.iterations as f64,
            found.setup_s + found.optimise_s
        );
    } else {
        let mut library = Vec::new();
        for &tilt in tilts {
            let label = format!("tilt {tilt} deg: ");
            let mut found = optimise(
                &config,
                transport.nominal(tilt),
                &source,
                args.quiet,
                &label,
            )?;
            found.summary.target_tilt_deg = Some(tilt);
            let folder = format!("tilt-{tilt}");
            write_outputs(&out.join(&folder), &config, &found)?;
            let s = &found.summary;
            println!(
                "{label}cost {:.4} at the start, {:.4} at the end, {:.1} s",
                s.start_cost,
                s.best_cost,
                found.setup_s + found.optimise_s
            );
            library.push(LibraryEntry {
                target_tilt_deg: tilt,
                folder,
                start_cost: s.start_cost,
                best_cost: s.best_cost,
                best_knots: s.best_knots.clone(),
                episode_time_s: s.episode_time_s,
                wall_s: found.setup_s + found.optimise_s,
            });
        }
        let summary = LibrarySummary {
            config: &config,
            library,
        };
        let json = serde_json::to_string_pretty(&summary).expect("plain data serialises");
        write_file(&out.join("summary.json"), json.as_bytes())?;
    }
    println!("wrote {}", out.display());
    Ok(())
}

/// The decision variables' bounds and the CEM's starting distribution for `curve` under the
/// task's limits: `(mean, std, lower, upper)`.
fn decision_space(
    config: &OptimizeConfig,
    transport: &TransportConfig,
    curve: &KnotCurve,
) -> [Vec<f64>; 4] {
    let (speed, tilt) = (
        transport.limits.max_path_speed_m_s,
        transport.limits.max_tilt_offset_deg.to_radians(),
    );
    let block = |v: f64| vec![v; curve.knots];
    let spread = config.knots.tilt_std_deg.to_radians();
    [
        [
            block(config.knots.initial_speed_m_s),
            block(0.0),
            block(0.0),
        ]
        .concat(),
        [
            block(config.knots.speed_std_m_s),
            block(spread),
            block(spread),
        ]
        .concat(),
        [block(0.0), block(-tilt), block(-tilt)].concat(),
        [block(speed), block(tilt), block(tilt)].concat(),
    ]
}

fn cem_settings(config: &OptimizeConfig) -> CemSettings {
    CemSettings {
        population: config.cem.population,
        elites: config.cem.elites,
        smoothing: config.cem.smoothing,
        seed: config.cem.seed,
    }
}

fn progress_bar(quiet: bool, len: usize, template: &str) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    ProgressBar::new(len as u64).with_style(
        ProgressStyle::with_template(template)
            .expect("valid template")
            .progress_chars("=> "),
    )
}

/// What one optimisation found, and how long it took.
struct Optimised {
    summary: Summary,
    curve: KnotCurve,
    /// The best command's tool motion on the first package.
    trace: Vec<ToolSample>,
    control_interval_s: f64,
    setup_s: f64,
    optimise_s: f64,
}

/// Optimises the open-loop command of `transport`'s task for the `[conditions]` packages.
fn optimise(
    config: &OptimizeConfig,
    transport: TransportConfig,
    source: &str,
    quiet: bool,
    label: &str,
) -> anyhow::Result<Optimised> {
    let curve = KnotCurve {
        knots: config.knots.count,
        horizon_s: config.knots.horizon_s,
    };
    let [mean, std, lower, upper] = decision_space(config, &transport, &curve);
    let mut cem = Cem::new(mean, std, lower, upper, cem_settings(config)).map_err(input_error)?;
    let risk = RiskMeasure {
        quantile: config.risk.quantile,
        weight: config.risk.weight,
    };
    let started = Instant::now();
    let mut problem = OpenLoopProblem::new(
        transport,
        source,
        config.conditions.seed,
        config.conditions.packages,
        config.cem.population,
        curve,
    )
    .map_err(input_error)?;
    let setup_s = started.elapsed().as_secs_f64();
    let bar = progress_bar(
        quiet,
        config.cem.iterations,
        &format!("{label}{{elapsed_precise}} [{{bar:30}}] iteration {{pos}}/{{len}} {{msg}} (eta {{eta}})"),
    );
    let mut history = Vec::new();
    let mut best: Option<(f64, Vec<f64>, Vec<f64>)> = None;
    let mut start_cost = f64::NAN;
    let optimising = Instant::now();
    for iteration in 0..config.cem.iterations {
        let candidates = cem.candidates();
        let package_costs = problem.costs(&candidates)?;
        crate::interrupt::check()?;
        let costs: Vec<f64> = package_costs.iter().map(|c| risk.of(c)).collect();
        if iteration == 0 {
            start_cost = costs[0];
        }
        let top = cem.update(&candidates, &costs);
        if best.as_ref().is_none_or(|b| costs[top] < b.0) {
            best = Some((
                costs[top],
                candidates[top].clone(),
                package_costs[top].clone(),
            ));
        }
        let mut sorted = costs.clone();
        sorted.sort_by(f64::total_cmp);
        let elites = &sorted[..config.cem.elites];
        let row = IterationCosts {
            iteration,
            mean_candidate: costs[0],
            best: costs[top],
            elite_mean: elites.iter().sum::<f64>() / elites.len() as f64,
            best_so_far: best.as_ref().map_or(f64::NAN, |b| b.0),
        };
        bar.set_message(format!("best {:.3}", row.best_so_far));
        bar.inc(1);
        history.push(row);
    }
    bar.finish_and_clear();
    let optimise_s = optimising.elapsed().as_secs_f64();
    let (best_cost, best_knots, best_package_costs) = best.expect("at least one iteration");
    let trace = problem.trace(&best_knots)?;
    Ok(Optimised {
        summary: Summary {
            target_tilt_deg: None,
            start_cost,
            best_cost,
            best_package_costs,
            episode_time_s: trace.last().map_or(0.0, |s| s.time_s),
            best_knots,
            iterations: history,
        },
        curve,
        control_interval_s: problem.control_interval_s(),
        trace,
        setup_s,
        optimise_s,
    })
}

/// `--mpc`: runs the `[conditions]` packages' episodes under receding-horizon control, prints
/// their outcome and the planning time per control step, writes `mpc.json`.
fn run_mpc(
    args: &OptimizeArgs,
    config: &OptimizeConfig,
    transport: TransportConfig,
    source: &str,
    out: &Path,
) -> anyhow::Result<()> {
    let Some(settings) = &config.mpc else {
        return Err(input_error(format!(
            "{}: --mpc needs an [mpc] table (horizon_s, knots, iterations)",
            args.config.display()
        )));
    };
    if !config.conditions.nominal_target_tilts_deg.is_empty() {
        return Err(input_error(format!(
            "{}: --mpc controls the [conditions] packages; expected no \
             conditions.nominal_target_tilts_deg",
            args.config.display()
        )));
    }
    let curve = KnotCurve {
        knots: settings.knots,
        horizon_s: settings.horizon_s,
    };
    let [initial_mean, std, lower, upper] = decision_space(config, &transport, &curve);
    let packages = config.conditions.packages;
    let time_limit_steps = (transport.time_limit_s * transport.control_hz).ceil() as usize;
    let mut plant = Transport::new(transport, packages, source).map_err(input_error)?;
    // The horizon search's commands are path speeds.
    plant.drive_path_speed();
    let search = HorizonSearch {
        curve,
        iterations: settings.iterations,
        cem: cem_settings(config),
        initial_mean,
        std,
        lower,
        upper,
    };
    let bar = progress_bar(
        args.quiet,
        time_limit_steps,
        "{elapsed_precise} [{bar:30}] control step {pos}/{len} ({msg} running)",
    );
    let mut controller: Option<RecedingHorizon> = None;
    let (mut planning_s, mut episode_steps, mut control_steps) = (0.0, 0usize, 0usize);
    let (outcomes, _) =
        run_traced_episodes::<anyhow::Error>(&mut plant, config.conditions.seed, &[], |env, _| {
            crate::interrupt::check()?;
            // Built after the plant's reset, from its settled packages.
            let mpc = match &mut controller {
                Some(mpc) => mpc,
                None => controller.insert(RecedingHorizon::new(env, search.clone())?),
            };
            let running = (0..packages).filter(|&k| !env.is_retired(k)).count();
            let started = Instant::now();
            let actions = mpc.actions(env)?;
            planning_s += started.elapsed().as_secs_f64();
            episode_steps += running;
            control_steps += 1;
            bar.set_message(running.to_string());
            bar.inc(1);
            Ok(actions)
        })?;
    bar.finish_and_clear();
    let outcome = OutcomeSummary::of("mpc", &outcomes);
    let control_interval_s = plant.control_interval_s();
    let per_step = planning_s / episode_steps.max(1) as f64;
    print!("{}", OutcomeSummary::table(std::slice::from_ref(&outcome)));
    println!(
        "planning: {control_steps} control steps of {packages} episode(s), {planning_s:.1} s; \
         {per_step:.3} s per control step of one episode ({:.0} x the {:.3} s control interval)",
        per_step / control_interval_s,
        control_interval_s
    );
    let summary = MpcSummary {
        config,
        outcome,
        control_steps,
        control_interval_s,
        wall_per_control_step_s: per_step,
        real_time_factor: per_step / control_interval_s,
    };
    std::fs::create_dir_all(out)
        .map_err(|e| input_error(format!("{}: cannot create: {e}", out.display())))?;
    let json = serde_json::to_string_pretty(&summary).expect("plain data serialises");
    write_file(&out.join("mpc.json"), json.as_bytes())?;
    println!("wrote {}", out.join("mpc.json").display());
    Ok(())
}

fn write_file(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    rlpkg_files::write_atomic(path, bytes)
        .map_err(|e| anyhow::anyhow!("writing {}: {e}", path.display()))
}

/// Writes the trajectory, commands, costs, plot and summary into `out`: all of them into a hidden
/// staging folder first, then moved into place (`summary.json` last) unless a signal asked the
/// command to stop, so that a signal, a full disk or an error leaves `out` as it was.
fn write_outputs(out: &Path, config: &OptimizeConfig, found: &Optimised) -> anyhow::Result<()> {
    std::fs::create_dir_all(out)
        .map_err(|e| input_error(format!("{}: cannot create: {e}", out.display())))?;
    let staging = tempfile::Builder::new()
        .prefix(".optimize-")
        .tempdir_in(out)
        .map_err(|e| output_error(anyhow::Error::new(e).context(out.display().to_string())))?;
    write_staged(staging.path(), config, found)?;
    crate::interrupt::check()?;
    for name in OUTPUT_FILES {
        let (from, to) = (staging.path().join(name), out.join(name));
        std::fs::rename(&from, &to).map_err(|e| {
            output_error(anyhow::Error::new(e).context(format!("moving {}", to.display())))
        })?;
    }
    Ok(())
}

/// The files [`write_outputs`] writes, in the order they are moved into place.
const OUTPUT_FILES: [&str; 5] = [
    "trajectory.csv",
    "commands.csv",
    "costs.csv",
    "costs.png",
    "summary.json",
];

fn write_staged(out: &Path, config: &OptimizeConfig, found: &Optimised) -> anyhow::Result<()> {
    let Optimised {
        summary,
        curve,
        trace,
        control_interval_s: dt,
        ..
    } = found;
    let write = |name: &str, bytes: &[u8]| -> anyhow::Result<()> {
        let path = out.join(name);
        rlpkg_files::write_atomic(&path, bytes).map_err(|e| {
            output_error(anyhow::Error::new(e).context(format!("writing {}", path.display())))
        })
    };
    write("trajectory.csv", robot_csv(trace, *dt).as_bytes())?;
    let mut commands = String::from("time_s,path_speed_m_s,tilt_offset_x_rad,tilt_offset_z_rad\n");
    for sample in &trace[..trace.len() - 1] {
        let [v, x, z] = curve.actions(&summary.best_knots, sample.time_s);
        commands += &format!("{:.4},{v:.9},{x:.9},{z:.9}\n", sample.time_s);
    }
    write("commands.csv", commands.as_bytes())?;
    let mut costs = String::from("iteration,mean_candidate,best,elite_mean,best_so_far\n");
    for r in &summary.iterations {
        costs += &format!(
            "{},{:.9},{:.9},{:.9},{:.9}\n",
            r.iteration, r.mean_candidate, r.best, r.elite_mean, r.best_so_far
        );
    }
    write("costs.csv", costs.as_bytes())?;
    let line = |f: fn(&IterationCosts) -> f64| -> Vec<(f64, f64)> {
        summary
            .iterations
            .iter()
            .map(|r| (r.iteration as f64, f(r)))
            .collect()
    };
    write_cost_plot(
        &out.join("costs.png"),
        &format!(
            "CEM: {} candidates x {} packages",
            config.cem.population, config.conditions.packages
        ),
        &[
            ("best so far", line(|r| r.best_so_far)),
            ("elite mean", line(|r| r.elite_mean)),
            ("distribution mean", line(|r| r.mean_candidate)),
        ],
    )?;
    #[derive(Serialize)]
    struct WithConfig<'a> {
        config: &'a OptimizeConfig,
        #[serde(flatten)]
        summary: &'a Summary,
    }
    let json = serde_json::to_string_pretty(&WithConfig { config, summary })
        .expect("plain data serialises");
    write("summary.json", json.as_bytes())
}

/// The tool's motion as a robot trajectory file (time, position, orientation, velocity, angular
/// velocity, and acceleration by central differences of the velocity).
fn robot_csv(trace: &[ToolSample], dt: f64) -> String {
    let mut text = rlpkg_mocap::robot::ROBOT_HEADER.join(",") + "\n";
    let n = trace.len();
    for (k, s) in trace.iter().enumerate() {
        let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
        let span = (b - a).max(1) as f64 * dt;
        let acc: [f64; 3] =
            std::array::from_fn(|i| (trace[b].velocity[i] - trace[a].velocity[i]) / span);
        let values: Vec<String> = [s.time_s]
            .iter()
            .chain(&s.position)
            .chain(&s.orientation)
            .chain(&s.velocity)
            .chain(&s.angular_velocity)
            .chain(&acc)
            .map(|v| format!("{v:.9}"))
            .collect();
        text += &values.join(",");
        text += "\n";
    }
    text
}
