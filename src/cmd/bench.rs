//! `rlpkg bench ...`: benchmarks that print throughput figures.

use clap::{Args, Subcommand};
use rlpkg_agents::config::check_memory;

use crate::error::input_error;
use crate::tasks::Task;

/// The benchmarks.
#[derive(Subcommand)]
pub enum BenchCommand {
    /// Simulator throughput: particle-substeps/s, real-time factor and peak memory per grid and batch size.
    Sim(SimBenchArgs),
    /// PPO update throughput (samples/s per burn backend) and environment steps/s.
    Ppo(PpoBenchArgs),
}

/// Arguments of `rlpkg bench sim`.
#[derive(Args)]
pub struct SimBenchArgs {
    /// Package grids per layer, comma-separated ROWSxCOLS (Table 2 sizes by default).
    #[arg(
        long,
        default_value = "11x13,16x19,21x25,26x31",
        allow_hyphen_values = true
    )]
    grid: String,
    /// Batch sizes, comma-separated.
    #[arg(long, default_value = "1,64,1024", allow_hyphen_values = true)]
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

/// The comma-separated items of `--<option> text`; an item `parse` refuses is named with what
/// `expected` says.
fn parse_list<T>(
    option: &str,
    text: &str,
    expected: &str,
    parse: impl Fn(&str) -> Option<T>,
) -> anyhow::Result<Vec<T>> {
    text.split(',')
        .map(|item| {
            parse(item.trim()).ok_or_else(|| {
                input_error(format!(
                    "--{option} {text}: cannot read `{item}`; expected {expected}"
                ))
            })
        })
        .collect()
}

fn run_sim(args: SimBenchArgs) -> anyhow::Result<()> {
    let grids = parse_list(
        "grid",
        &args.grid,
        "ROWSxCOLS items, e.g. 11x13,21x25",
        |s| {
            let (r, c) = s.split_once('x')?;
            Some([r.parse::<usize>().ok()?, c.parse::<usize>().ok()?])
        },
    )?;
    let envs = parse_list(
        "envs",
        &args.envs,
        "whole numbers of environments >= 1, e.g. 1,8,64",
        |s| s.parse::<usize>().ok().filter(|&n| n > 0),
    )?;
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
                check_memory(&format!("--grid {}x{} --envs {n}", grid[0], grid[1]), bytes)
                    .map_err(input_error)?;
            }
        }
    }
    let workloads = parse_list(
        "workload",
        &args.workload,
        "motionless, replay or command",
        |s| {
            ["motionless", "replay", "command"]
                .contains(&s)
                .then(|| s.to_string())
        },
    )?;
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
    if args.json {
        eprint!("{table}");
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        print!("{table}");
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
        BenchCommand::Ppo(args) => run_ppo(args),
    }
}

/// Arguments of `rlpkg bench ppo`.
#[derive(Args)]
pub struct PpoBenchArgs {
    /// burn backends to measure: flex, ndarray, or both (comma-separated).
    #[arg(long, default_value = "flex,ndarray", value_delimiter = ',')]
    pub backend: Vec<String>,
    /// Samples per minibatch.
    #[arg(long, default_value_t = 4096)]
    pub minibatch: usize,
    /// Timed minibatches per backend (at most 10000).
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u64).range(1..=10_000))]
    pub minibatches: u64,
    /// Observation width.
    #[arg(long, default_value_t = 48)]
    pub obs_dim: usize,
    /// Action width.
    #[arg(long, default_value_t = 6)]
    pub action_dim: usize,
    /// Hidden widths of actor and critic (comma-separated).
    #[arg(long, default_value = "256,256", value_delimiter = ',')]
    pub hidden: Vec<usize>,
    /// Lockstep steps of the environment benchmark (0 skips it; at most 10 million).
    #[arg(long, default_value_t = 20000, value_parser = clap::value_parser!(u64).range(0..=10_000_000))]
    pub env_steps: u64,
    /// Copies in the environment benchmark (1 to 65536).
    #[arg(long, default_value_t = 64,
          value_parser = clap::value_parser!(u64).range(1..=65_536))]
    pub num_envs: u64,
    /// Print the results as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Bytes of the PPO benchmark: actor and critic with gradients and Adam moments (x6), and one
/// minibatch's data and activations with their gradients.
fn ppo_bench_memory_bytes(args: &PpoBenchArgs) -> f64 {
    let network = |out: usize| {
        let mut widths = vec![args.obs_dim];
        widths.extend_from_slice(&args.hidden);
        widths.push(out);
        widths
            .windows(2)
            .map(|w| (w[0] as f64 + 1.0) * w[1] as f64)
            .sum::<f64>()
    };
    let parameters = network(args.action_dim) + network(1);
    let widths = 2 * args.hidden.iter().sum::<usize>() + args.obs_dim + args.action_dim;
    let per_row = 4 * widths + 2 * (args.obs_dim + args.action_dim + 6);
    4.0 * (6.0 * parameters + args.minibatch as f64 * per_row as f64)
}

/// `rlpkg bench ppo`: PPO update throughput (forward + backward + global clip + Adam) per backend,
/// and CartPole / Pendulum steps per second.
fn run_ppo(args: PpoBenchArgs) -> anyhow::Result<()> {
    use rlpkg_agents::bench::{
        env_throughput, matmul_throughput, ppo_update_throughput, PpoBenchConfig,
    };
    if args.minibatch == 0 || args.obs_dim == 0 || args.action_dim == 0 {
        return Err(input_error(
            "--minibatch, --obs-dim and --action-dim: expected at least 1",
        ));
    }
    if args.hidden.is_empty() || args.hidden.contains(&0) {
        return Err(input_error(
            "--hidden: expected widths of at least 1, e.g. 256,256",
        ));
    }
    check_memory(
        &format!(
            "--minibatch {} --hidden {:?} --obs-dim {} --action-dim {}",
            args.minibatch, args.hidden, args.obs_dim, args.action_dim
        ),
        ppo_bench_memory_bytes(&args),
    )
    .map_err(input_error)?;
    let (minibatches, env_steps) = (args.minibatches as usize, args.env_steps as usize);
    if env_steps > 0 {
        check_memory(
            &format!("--num-envs {}", args.num_envs),
            rlpkg_agents::runners::evaluation_memory_bytes(args.num_envs as usize, 4, 0),
        )
        .map_err(input_error)?;
    }
    let mut updates = Vec::new();
    let mut matmuls = Vec::new();
    for name in &args.backend {
        let backend = rlpkg_agents::Backend::parse(name)
            .ok_or_else(|| input_error(format!("--backend {name}: expected flex or ndarray")))?;
        let result = ppo_update_throughput(&PpoBenchConfig {
            obs_dim: args.obs_dim,
            action_dim: args.action_dim,
            hidden: args.hidden.clone(),
            minibatch: args.minibatch,
            minibatches,
            backend,
        });
        let shares = &result.shares;
        eprintln!(
            "ppo update [{}] {}-{:?}-{} ({} parameters), minibatch {}: {:.0} samples/s ({:.1} ms/minibatch; forward {:.0} %, backward {:.0} %, optimiser {:.0} %, batching {:.0} %; {:.0} samples per CPU second)",
            result.backend,
            args.obs_dim,
            args.hidden,
            args.action_dim,
            result.parameters,
            args.minibatch,
            result.samples_per_second,
            result.ms_per_minibatch,
            100.0 * shares.forward,
            100.0 * shares.backward,
            100.0 * shares.optimiser,
            100.0 * shares.batch,
            result.samples_per_cpu_second.unwrap_or(f64::NAN),
        );
        updates.push(result);
        // The layer products of the update: the forward x W of the first two layers and the
        // weight gradient x^T dz of the second.
        let (m, h0) = (args.minibatch, args.hidden[0]);
        let h1 = args.hidden.get(1).copied().unwrap_or(h0);
        for (shape, transposed) in [
            ([m, args.obs_dim, h0], false),
            ([m, h0, h1], false),
            ([h0, m, h1], true),
        ] {
            let result = matmul_throughput(backend, shape, transposed, 5);
            eprintln!(
                "matmul [{}] {}x{}{} x {}x{}: {:.1} GFLOP/s",
                result.backend,
                shape[0],
                shape[1],
                if transposed { " (transposed view)" } else { "" },
                shape[1],
                shape[2],
                result.gflops
            );
            matmuls.push(result);
        }
    }
    let mut envs = Vec::new();
    if env_steps > 0 {
        for task in Task::without_settings() {
            let mut env = task.build(args.num_envs as usize)?;
            let result = env_throughput(env.as_mut(), env_steps)?;
            eprintln!(
                "env {} x{}: {:.3e} steps/s",
                result.env_id, result.num_envs, result.steps_per_second
            );
            envs.push(result);
        }
    }
    if args.json {
        let json = serde_json::json!({ "ppo_update": updates, "matmul": matmuls, "env": envs });
        println!("{}", serde_json::to_string_pretty(&json)?);
    }
    Ok(())
}
