//! `rlpkg optimize <config.toml>`: sampling-based trajectory optimisation (the cross-entropy
//! method) of the transport task's open-loop command for one package condition, or robustly for
//! K of them (crate `rlpkg-env`, module `transport::optimize`).
//!
//! Writes to the output folder: `trajectory.csv` (the best command's tool motion on the first
//! package, in the robot-file format of `rlpkg data import`), `commands.csv` (its actions every
//! control interval), `costs.csv` (cost per iteration), `costs.png` and `summary.json`. The files
//! depend only on the config, whatever the number of threads.

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use rlpkg_env::transport::{
    Cem, CemSettings, KnotCurve, OpenLoopProblem, RiskMeasure, ToolSample, TransportConfig,
};
use serde::{Deserialize, Serialize};

use crate::error::input_error;
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
        if !(k.horizon_s.is_finite() && k.horizon_s > 0.0) {
            return fail("knots.horizon_s", k.horizon_s.to_string(), "> 0 (s)");
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
struct Summary<'a> {
    config: &'a OptimizeConfig,
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
    let curve = KnotCurve {
        knots: config.knots.count,
        horizon_s: config.knots.horizon_s,
    };
    let (speed, tilt) = (
        transport.limits.max_path_speed_m_s,
        transport.limits.max_tilt_offset_deg.to_radians(),
    );
    let block = |v: f64| vec![v; curve.knots];
    let mean = [
        block(config.knots.initial_speed_m_s),
        block(0.0),
        block(0.0),
    ]
    .concat();
    let std = [
        block(config.knots.speed_std_m_s),
        block(config.knots.tilt_std_deg.to_radians()),
        block(config.knots.tilt_std_deg.to_radians()),
    ]
    .concat();
    let lower = [block(0.0), block(-tilt), block(-tilt)].concat();
    let upper = [block(speed), block(tilt), block(tilt)].concat();
    let settings = CemSettings {
        population: config.cem.population,
        elites: config.cem.elites,
        smoothing: config.cem.smoothing,
        seed: config.cem.seed,
    };
    let mut cem = Cem::new(mean, std, lower, upper, settings).map_err(input_error)?;
    let risk = RiskMeasure {
        quantile: config.risk.quantile,
        weight: config.risk.weight,
    };
    let _cooperation = crate::interrupt::Cooperation::start();
    let started = Instant::now();
    let mut problem = OpenLoopProblem::new(
        transport,
        &source,
        config.conditions.seed,
        config.conditions.packages,
        config.cem.population,
        curve,
    )
    .map_err(input_error)?;
    let setup_s = started.elapsed().as_secs_f64();
    let bar = if args.quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(config.cem.iterations as u64).with_style(
            ProgressStyle::with_template(
                "{elapsed_precise} [{bar:30}] iteration {pos}/{len} {msg} (eta {eta})",
            )
            .expect("valid template")
            .progress_chars("=> "),
        )
    };
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
    let dt = problem.control_interval_s();
    write_outputs(
        &out,
        &config,
        &curve,
        &trace,
        dt,
        Summary {
            config: &config,
            start_cost,
            best_cost,
            best_package_costs,
            episode_time_s: trace.last().map_or(0.0, |s| s.time_s),
            best_knots,
            iterations: history,
        },
    )?;
    println!(
        "cost {start_cost:.4} at the start, {best_cost:.4} at the end ({} iterations of {} \
         candidates x {} packages)",
        config.cem.iterations, config.cem.population, config.conditions.packages
    );
    println!(
        "wall time: {setup_s:.1} s to settle the packages, {:.2} s per iteration, {:.1} s in all",
        optimise_s / config.cem.iterations as f64,
        started.elapsed().as_secs_f64()
    );
    println!("wrote {}", out.display());
    Ok(())
}

/// Writes the trajectory, commands, costs, plot and summary into `out`.
fn write_outputs(
    out: &Path,
    config: &OptimizeConfig,
    curve: &KnotCurve,
    trace: &[ToolSample],
    dt: f64,
    summary: Summary,
) -> anyhow::Result<()> {
    std::fs::create_dir_all(out)
        .map_err(|e| input_error(format!("{}: cannot create: {e}", out.display())))?;
    let write = |name: &str, bytes: &[u8]| -> anyhow::Result<()> {
        let path = out.join(name);
        rlpkg_files::write_atomic(&path, bytes)
            .map_err(|e| anyhow::anyhow!("writing {}: {e}", path.display()))
    };
    write("trajectory.csv", robot_csv(trace, dt).as_bytes())?;
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
    let json = serde_json::to_string_pretty(&summary).expect("plain data serialises");
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
