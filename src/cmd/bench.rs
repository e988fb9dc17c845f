//! `rlpkg bench ...`: benchmarks that print throughput figures.

use std::io::Write;

use clap::{Args, Subcommand};

use crate::error::input_error;

/// The benchmarks.
#[derive(Subcommand)]
pub enum BenchCommand {
    /// Simulator throughput: particle-substeps/s, real-time factor and peak memory per grid and batch size.
    Sim(SimBenchArgs),
    /// PPO update throughput (samples/s per burn backend) and environment steps/s.
    Ppo(crate::cmd::train::PpoBenchArgs),
}

/// Arguments of `rlpkg bench sim`.
#[derive(Args)]
pub struct SimBenchArgs {
    /// Package grids per layer, comma-separated ROWSxCOLS (Table 2 sizes by default).
    #[arg(long, default_value = "11x13,16x19,21x25,26x31")]
    grid: String,
    /// Batch sizes, comma-separated.
    #[arg(long, default_value = "1,64,1024")]
    envs: String,
    /// Wall-clock seconds per measurement.
    #[arg(long, default_value_t = 3.0)]
    seconds: f64,
    /// Scenes, comma-separated: a preset (`reference` or `physical`) or a path to a scene TOML.
    /// Several scenes are measured one after the other in the same run, side by side.
    #[arg(long, default_value = "reference")]
    scene: String,
    /// Workloads, comma-separated: `motionless` (identical packages held still), `replay` (the
    /// recordings of --data replayed, cycled over the batch, random object masses, no rest
    /// period), `command` (a smooth pseudo-random twist command per tool every 1/20 s).
    #[arg(long, default_value = "motionless,replay,command")]
    workload: String,
    /// Dataset whose recordings the `replay` workload replays.
    #[arg(long, value_name = "DIR", default_value = "data/deformable-sim-real")]
    data: std::path::PathBuf,
    /// Seed of the random object masses and twist commands.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Print the results as JSON on stdout (the table then goes to stderr).
    #[arg(long)]
    json: bool,
}

/// Upper bound of `--seconds` (a measurement longer than 10 minutes adds nothing).
const MAX_SECONDS: f64 = 600.0;

fn parse_list<T>(
    option: &str,
    text: &str,
    parse: impl Fn(&str) -> Option<T>,
) -> anyhow::Result<Vec<T>> {
    text.split(',')
        .map(|item| {
            parse(item.trim())
                .ok_or_else(|| input_error(format!("--{option}: cannot read `{item}`")))
        })
        .collect()
}

fn run_sim(args: SimBenchArgs) -> anyhow::Result<()> {
    let grids = parse_list("grid", &args.grid, |s| {
        let (r, c) = s.split_once('x')?;
        Some([r.parse::<usize>().ok()?, c.parse::<usize>().ok()?])
    })?;
    let envs = parse_list("envs", &args.envs, |s| {
        s.parse::<usize>().ok().filter(|&n| n > 0)
    })?;
    if !(args.seconds.is_finite() && args.seconds >= 0.0) {
        return Err(input_error(format!(
            "--seconds {}: expected a non-negative number",
            args.seconds
        )));
    }
    if args.seconds > MAX_SECONDS {
        return Err(input_error(format!(
            "--seconds {}: expected at most {MAX_SECONDS} s per measurement",
            args.seconds
        )));
    }
    let scenes = args
        .scene
        .split(',')
        .map(|name| {
            let name = name.trim();
            match name {
                "reference" | "physical" => rlpkg_sim::SceneConfig::preset(name),
                path => rlpkg_sim::SceneConfig::load(std::path::Path::new(path)),
            }
            .map(|scene| (name.to_string(), scene))
            .map_err(input_error)
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    for (_, scene) in &scenes {
        for grid in &grids {
            // One environment's simulator, measured, scales the memory of the largest batch.
            let one = rlpkg_sim::bench::bench_simulator(scene, *grid, 1)
                .map_err(|err| input_error(format!("--grid {}x{}: {err}", grid[0], grid[1])))?
                .state_bytes();
            for &n in &envs {
                // Batches are stored in blocks of 8 environments (a lone environment in a 1-lane block).
                let bytes = (n as f64 / 8.0).ceil() * 8.0 * one as f64;
                rlpkg_agents::config::check_memory(
                    &format!("--grid {}x{} --envs {n}", grid[0], grid[1]),
                    bytes,
                )
                .map_err(input_error)?;
            }
        }
    }
    let workloads = parse_list("workload", &args.workload, |s| {
        ["motionless", "replay", "command"]
            .contains(&s)
            .then(|| s.to_string())
    })
    .map_err(|err| input_error(format!("{err}; expected motionless, replay or command")))?;
    let mut rows = Vec::new();
    let mut table = String::new();
    for (name, scene) in &scenes {
        let targets = if workloads.iter().any(|w| w == "replay") {
            rlpkg_replay::workload::load_targets(&args.data, scene.disc.hold_at_recorded_start)
                .map_err(|err| input_error(format!("--data {}: {err}", args.data.display())))?
        } else {
            Vec::new()
        };
        let mut scene_rows = Vec::new();
        for grid in &grids {
            for &n in &envs {
                for workload in &workloads {
                    let what = format!(
                        "--scene {name} --grid {}x{} --envs {n} --workload {workload}",
                        grid[0], grid[1]
                    );
                    let row = measure_workload(workload, scene, *grid, n, &args, &targets)
                        .map_err(|err| input_error(format!("{what}: {err}")))?;
                    eprintln!(
                        "{name}: {workload} grid {}x{} envs {n}: {:.2} M particle-substeps/s, {:.3} simulated s per wall s",
                        grid[0],
                        grid[1],
                        row.particle_substeps_per_s / 1e6,
                        row.simulated_s_per_wall_s
                    );
                    scene_rows.push(row);
                }
            }
        }
        table += &format!(
            "scene {name}\n{}",
            rlpkg_sim::bench::format_table(&scene_rows)
        );
        rows.extend(scene_rows.into_iter().map(|row| SceneRow {
            scene: name.clone(),
            row,
        }));
    }
    let mut stdout = std::io::stdout().lock();
    if args.json {
        eprint!("{table}");
        writeln!(stdout, "{}", serde_json::to_string_pretty(&rows)?)?;
    } else {
        write!(stdout, "{table}")?;
    }
    Ok(())
}

/// A measurement and the scene it was taken on.
#[derive(serde::Serialize)]
struct SceneRow {
    scene: String,
    #[serde(flatten)]
    row: rlpkg_sim::bench::BenchRow,
}

/// One measurement of `workload` (one of the names `run_sim` accepts).
fn measure_workload(
    workload: &str,
    scene: &rlpkg_sim::SceneConfig,
    grid: [usize; 2],
    envs: usize,
    args: &SimBenchArgs,
    targets: &[rlpkg_replay::Target],
) -> anyhow::Result<rlpkg_sim::bench::BenchRow> {
    use rlpkg_sim::bench;
    Ok(match workload {
        "motionless" => bench::run(scene, grid, envs, args.seconds)?,
        "command" => bench::run_commanded(scene, grid, envs, args.seconds, args.seed)?,
        _ => {
            bench::reset_peak_rss();
            let mut sim =
                rlpkg_replay::workload::replay_simulator(scene, grid, envs, targets, args.seed)?;
            bench::measure("replay", &mut sim, args.seconds, None)?
        }
    })
}

/// Runs a benchmark subcommand.
pub fn run(command: BenchCommand) -> anyhow::Result<()> {
    match command {
        BenchCommand::Sim(args) => run_sim(args),
        BenchCommand::Ppo(args) => crate::cmd::train::run_bench(args),
    }
}
