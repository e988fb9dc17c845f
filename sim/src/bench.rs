//! Throughput benchmark of the simulator (`rlpkg bench sim`): a batch stepped for a wall-clock
//! budget. Workloads built here: identical packages held still by the cups with the disc inside
//! ([`run`]), and the same packages carried by a smooth pseudo-random twist command per
//! environment every control step ([`run_commanded`]). Any other batch (e.g. replayed
//! recordings, `rlpkg_replay::workload`) is measured with [`measure`].

use std::f64::consts::TAU;
use std::sync::Arc;
use std::time::Instant;

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use serde::Serialize;

use crate::{
    EpisodeSpec, Model, Placement, SceneConfig, SimError, Simulator, ToolCommand, ToolLimits,
    ToolTrajectory,
};

/// Control interval of the command-driven workload (s): 20 Hz, a common policy rate.
pub const CONTROL_INTERVAL_S: f64 = 1.0 / 20.0;

/// One benchmark measurement.
#[derive(Clone, Debug, Serialize)]
pub struct BenchRow {
    /// What the environments do (`motionless`, `replay`, `command`).
    pub workload: String,
    /// Package grid per layer [rows, columns].
    pub grid: [usize; 2],
    /// Particles per environment (package + cups).
    pub particles: usize,
    /// Environments stepped together.
    pub envs: usize,
    /// Substeps measured.
    pub substeps: u64,
    /// Wall time of the measurement (s).
    pub wall_s: f64,
    /// Batch substeps per second (every environment advanced by one substep).
    pub substeps_per_s: f64,
    /// Particle-substeps per second actually simulated: over the environments that advanced (a
    /// frozen or retired one costs nothing and counts nothing).
    pub particle_substeps_per_s: f64,
    /// Simulated seconds per wall second of the batch's clock (one environment's view).
    pub real_time_factor_per_env: f64,
    /// Simulated seconds per wall second actually advanced, summed over the environments' own
    /// clocks (a frozen environment's clock stands still).
    pub simulated_s_per_wall_s: f64,
    /// Environments frozen by a health check (or retired) at the end of the measurement.
    pub frozen_envs: usize,
    /// Tool commands issued, and how many of them the robot limits clamped.
    pub commands: u64,
    /// Commands clamped by the tool limits.
    pub clamped_commands: u64,
    /// Bytes of simulator state allocated (counted).
    pub state_bytes: usize,
    /// Peak resident memory of the process (VmHWM, reset before each row where the kernel allows).
    pub peak_rss_bytes: Option<u64>,
    /// Threads in rayon's pool.
    pub threads: usize,
}

/// Reads VmHWM (peak RSS) from /proc/self/status.
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Resets the peak-RSS counter (Linux `clear_refs` value 5); silently does nothing elsewhere.
pub fn reset_peak_rss() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// A batch of `envs` identical environments on a `grid` package, reference preset otherwise.
pub fn bench_simulator(
    config: &SceneConfig,
    grid: [usize; 2],
    envs: usize,
) -> Result<Simulator, SimError> {
    let mut config = config.clone();
    config.package.grid = grid;
    let model = Arc::new(Model::new(&config)?);
    let size = config.package.size_m;
    let origin = [0.0f32, 0.3, 0.0];
    let centre = [
        origin[0] + size[1] / 2.0,
        origin[1],
        origin[2] + size[0] / 2.0,
    ];
    let cup_point = [centre[0], centre[1] + 0.01, centre[2]];
    let tool = Arc::new(ToolTrajectory::hold(
        [cup_point[0] as f64, 0.45, cup_point[2] as f64],
        [0.0, 0.0, 0.0, 1.0],
    ));
    let spec = EpisodeSpec {
        placement: Placement::new(origin, cup_point, centre),
        params: config.params,
        object_mass_kg: 0.57,
        disc_mass_scale: None,
        vacuum_kpa: None,
        trajectory: tool,
    };
    Simulator::new(model, vec![spec; envs])
}

/// Steps a batch of identical motionless environments for at least `seconds` of wall time (in
/// chunks of 64 substeps, after a warm-up chunk) and reports throughput.
pub fn run(
    config: &SceneConfig,
    grid: [usize; 2],
    envs: usize,
    seconds: f64,
) -> Result<BenchRow, SimError> {
    reset_peak_rss();
    let mut sim = bench_simulator(config, grid, envs)?;
    measure("motionless", &mut sim, seconds, None)
}

/// The motionless batch of [`bench_simulator`], each tool driven by its own [`TwistSignal`]
/// (seeded from `seed` and the environment index) every [`CONTROL_INTERVAL_S`].
pub fn run_commanded(
    config: &SceneConfig,
    grid: [usize; 2],
    envs: usize,
    seconds: f64,
    seed: u64,
) -> Result<BenchRow, SimError> {
    reset_peak_rss();
    let mut sim = bench_simulator(config, grid, envs)?;
    let mut commands = TwistCommands::new(&sim, seed);
    measure("command", &mut sim, seconds, Some(&mut commands))
}

/// Steps `sim` for at least `seconds` of wall time (in chunks of at most 64 substeps, after a
/// warm-up chunk), issuing `commands` at every control step, and reports throughput. The
/// peak-RSS counter is the caller's to reset before building the batch.
pub fn measure(
    workload: &str,
    sim: &mut Simulator,
    seconds: f64,
    mut commands: Option<&mut TwistCommands>,
) -> Result<BenchRow, SimError> {
    let chunk = 64;
    let interval = (CONTROL_INTERVAL_S / sim.dt() as f64).round().max(1.0) as u64;
    let mut next_command = sim.substep();
    // Steps at most `chunk` substeps, commanding the tools first when a control step is due.
    let mut advance = |sim: &mut Simulator| -> Result<u64, SimError> {
        let mut n = chunk;
        if let Some(commands) = commands.as_deref_mut() {
            if sim.substep() == next_command {
                commands.apply(sim)?;
                next_command += interval;
            }
            n = n.min(next_command - sim.substep());
        }
        sim.step(n);
        Ok(n)
    };
    advance(sim)?;
    let clocks_before: u64 = (0..sim.num_envs()).map(|e| sim.env_substep(e)).sum();
    let start = Instant::now();
    let mut substeps = 0;
    while substeps == 0 || start.elapsed().as_secs_f64() < seconds {
        substeps += advance(sim)?;
    }
    let wall_s = start.elapsed().as_secs_f64();
    let clocks_after: u64 = (0..sim.num_envs()).map(|e| sim.env_substep(e)).sum();
    let envs = sim.num_envs();
    let particles = sim.model().num_particles();
    let substeps_per_s = substeps as f64 / wall_s;
    let rtf = substeps_per_s * sim.dt() as f64;
    let simulated_s = (clocks_after - clocks_before) as f64 * sim.dt() as f64 / wall_s;
    let (issued, clamped) = commands.map_or((0, 0), |c| (c.issued, c.clamped));
    Ok(BenchRow {
        workload: workload.to_string(),
        grid: sim.model().grid,
        particles,
        envs,
        substeps,
        wall_s,
        substeps_per_s,
        // Only live environments advance their clocks: a frozen or retired one costs nothing
        // and must not count as work done.
        particle_substeps_per_s: (clocks_after - clocks_before) as f64 * particles as f64 / wall_s,
        real_time_factor_per_env: rtf,
        simulated_s_per_wall_s: simulated_s,
        frozen_envs: (0..envs).filter(|&e| sim.is_frozen(e)).count(),
        commands: issued,
        clamped_commands: clamped,
        state_bytes: sim.state_bytes(),
        peak_rss_bytes: peak_rss_bytes(),
        threads: rayon::current_num_threads(),
    })
}

/// Frequencies of the twist signal's sines (Hz): slow enough to carry a package, fast enough to
/// keep it swinging.
const SIGNAL_HZ: [f64; 2] = [0.5, 1.5];
/// Time over which the signal ramps up from rest (s), so the first command is within the limits.
const SIGNAL_RAMP_S: f64 = 1.0;

/// A smooth pseudo-random twist over time: per linear and angular component, two sines of random
/// frequency in [`SIGNAL_HZ`], phase and weight, ramped up from zero over [`SIGNAL_RAMP_S`]. Its
/// amplitudes keep the speed within a quarter and the acceleration within half of the tool
/// limits, so no command is clamped; zero-mean sines keep the tool near its start.
#[derive(Clone, Debug, PartialEq)]
pub struct TwistSignal {
    /// Per component (3 linear, then 3 angular): (frequency Hz, phase rad, weight) of each sine.
    sines: [[(f64, f64, f64); 2]; 6],
    /// Amplitude per linear component (m/s) and per angular component (rad/s).
    amplitude: [f64; 2],
}

impl TwistSignal {
    /// A signal drawn from `rng` for a tool with `limits`.
    pub fn new(limits: &ToolLimits, rng: &mut impl Rng) -> Self {
        // Largest |d/dt| of ramp x sines per unit amplitude: 1/ramp + 2π·f_max.
        let slope = 1.0 / SIGNAL_RAMP_S + TAU * SIGNAL_HZ[1];
        let per_component = |speed: f32, accel: f32| {
            (0.25 * speed as f64).min(0.5 * accel as f64 / slope) / 3f64.sqrt()
        };
        let sines = std::array::from_fn(|_| {
            let weight = rng.random_range(0.3..0.7);
            [weight, 1.0 - weight].map(|w| {
                let hz = rng.random_range(SIGNAL_HZ[0]..SIGNAL_HZ[1]);
                (hz, rng.random_range(0.0..TAU), w)
            })
        });
        Self {
            sines,
            amplitude: [
                per_component(limits.max_speed_m_s, limits.max_accel_m_s2),
                per_component(
                    limits.max_angular_speed_rad_s,
                    limits.max_angular_accel_rad_s2,
                ),
            ],
        }
    }

    /// The twist at time `t` (s): linear (m/s) and angular (rad/s) velocity.
    pub fn at(&self, t: f64) -> ([f32; 3], [f32; 3]) {
        let ramp = (t / SIGNAL_RAMP_S).clamp(0.0, 1.0);
        let component = |c: usize| {
            let sum: f64 = self.sines[c]
                .iter()
                .map(|&(hz, phase, weight)| weight * (TAU * hz * t + phase).sin())
                .sum();
            (self.amplitude[c / 3] * ramp * sum) as f32
        };
        (
            std::array::from_fn(component),
            std::array::from_fn(|k| component(3 + k)),
        )
    }
}

/// One [`TwistSignal`] per environment, commanded every control step.
#[derive(Clone, Debug)]
pub struct TwistCommands {
    signals: Vec<TwistSignal>,
    /// Commands issued so far.
    pub issued: u64,
    /// Commands the tool limits clamped.
    pub clamped: u64,
}

impl TwistCommands {
    /// Signals for every environment of `sim`; environment `e` draws from its own generator
    /// (seeded from `seed` and `e`), so the batch is the same whatever the thread count.
    pub fn new(sim: &Simulator, seed: u64) -> Self {
        let signals = (0..sim.num_envs())
            .map(|env| {
                let mut rng = StdRng::seed_from_u64(
                    seed ^ (env as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15),
                );
                TwistSignal::new(sim.tool_limits(), &mut rng)
            })
            .collect();
        Self {
            signals,
            issued: 0,
            clamped: 0,
        }
    }

    /// Commands every live environment's tool to reach its signal's twist at the end of the
    /// next control interval.
    pub fn apply(&mut self, sim: &mut Simulator) -> Result<(), SimError> {
        for (env, signal) in self.signals.iter().enumerate() {
            if sim.is_frozen(env) {
                continue;
            }
            let (linear, angular) = signal.at(sim.env_time(env) + CONTROL_INTERVAL_S);
            let report = sim.command_tool(
                env,
                ToolCommand::Twist { linear, angular },
                CONTROL_INTERVAL_S,
            )?;
            self.issued += 1;
            self.clamped += u64::from(report.clamped());
        }
        Ok(())
    }
}

/// The rows as a plain-text table.
pub fn format_table(rows: &[BenchRow]) -> String {
    let mut out = format!(
        "{:<10} {:>7} {:>9} {:>6} {:>10} {:>14} {:>10} {:>11} {:>6} {:>10} {:>10}\n",
        "workload",
        "grid",
        "particles",
        "envs",
        "substeps/s",
        "particle-ss/s",
        "RTF/env",
        "sim-s/wall",
        "frozen",
        "state MB",
        "peak MB"
    );
    for r in rows {
        out += &format!(
            "{:<10} {:>7} {:>9} {:>6} {:>10.0} {:>12.2} M {:>10.4} {:>11.3} {:>6} {:>10.1} {:>10}\n",
            r.workload,
            format!("{}x{}", r.grid[0], r.grid[1]),
            r.particles,
            r.envs,
            r.substeps_per_s,
            r.particle_substeps_per_s / 1e6,
            r.real_time_factor_per_env,
            r.simulated_s_per_wall_s,
            r.frozen_envs,
            r.state_bytes as f64 / 1e6,
            r.peak_rss_bytes
                .map_or("n/a".to_string(), |b| format!("{:.1}", b as f64 / 1e6)),
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bench_row_is_consistent() {
        let config = SceneConfig::preset("reference").unwrap();
        let row = run(&config, [6, 7], 3, 0.0).unwrap();
        assert_eq!(row.particles, 84 + 96);
        assert!(row.substeps >= 64);
        let expected = row.substeps_per_s * (row.particles * row.envs) as f64;
        assert!((row.particle_substeps_per_s - expected).abs() <= 1e-6 * expected);
        assert_eq!(row.workload, "motionless");
        // Nothing froze: every environment's clock advanced by every substep.
        assert_eq!(row.frozen_envs, 0);
        let total = row.real_time_factor_per_env * row.envs as f64;
        assert!((row.simulated_s_per_wall_s - total).abs() <= 1e-9 * total);
        assert_eq!((row.commands, row.clamped_commands), (0, 0));
        let table = format_table(&[row]);
        let line = table.lines().nth(1).unwrap();
        assert!(
            line.starts_with("motionless") && line.contains("6x7"),
            "{table}"
        );
    }

    #[test]
    fn twist_signal_stays_within_a_quarter_of_the_speed_and_half_the_acceleration_limits() {
        let limits = ToolLimits::default();
        for seed in 0..20 {
            let signal = TwistSignal::new(&limits, &mut StdRng::seed_from_u64(seed));
            let norm = |v: [f32; 3]| v.iter().map(|c| (*c as f64).powi(2)).sum::<f64>().sqrt();
            let dt = 1e-3;
            assert_eq!(signal.at(0.0), ([0.0; 3], [0.0; 3]), "starts from rest");
            for i in 0..10_000 {
                let t = i as f64 * dt;
                let (v0, w0) = signal.at(t);
                let (v1, w1) = signal.at(t + dt);
                assert!(norm(v0) <= 0.25 * limits.max_speed_m_s as f64 + 1e-6);
                assert!(norm(w0) <= 0.25 * limits.max_angular_speed_rad_s as f64 + 1e-6);
                let accel = norm(std::array::from_fn(|k| v1[k] - v0[k])) / dt;
                let angular = norm(std::array::from_fn(|k| w1[k] - w0[k])) / dt;
                assert!(
                    accel <= 0.5 * limits.max_accel_m_s2 as f64 + 1e-3,
                    "{accel}"
                );
                assert!(angular <= 0.5 * limits.max_angular_accel_rad_s2 as f64 + 1e-3);
            }
        }
    }

    #[test]
    fn twist_commands_move_each_tool_its_own_way_reproducibly_and_unclamped() {
        let mut config = SceneConfig::preset("reference").unwrap();
        config.package.grid = [11, 13];
        let run = |seed: u64| {
            let mut sim = bench_simulator(&config, [11, 13], 3).unwrap();
            let mut commands = TwistCommands::new(&sim, seed);
            let interval = (CONTROL_INTERVAL_S / sim.dt() as f64).round() as u64;
            for _ in 0..16 {
                commands.apply(&mut sim).unwrap();
                sim.step(interval);
            }
            assert!(sim.health_events().is_empty(), "{:?}", sim.health_events());
            assert_eq!((commands.issued, commands.clamped), (48, 0));
            (0..3).map(|e| sim.tool_state(e)).collect::<Vec<_>>()
        };
        let start = bench_simulator(&config, [11, 13], 1).unwrap().tool_state(0);
        let tools = run(5);
        for tool in &tools {
            let moved = (0..3).map(|k| (tool.position[k] - start.position[k]).powi(2));
            assert!(moved.sum::<f64>().sqrt() > 0.01, "{tool:?}");
        }
        assert_ne!(tools[0].position, tools[1].position);
        assert_eq!(tools, run(5));
        assert_ne!(tools, run(6));
    }

    #[test]
    fn frozen_environments_count_no_work() {
        let config = SceneConfig::preset("reference").unwrap();
        let mut sim = bench_simulator(&config, [6, 7], 4).unwrap();
        for env in 1..4 {
            sim.retire(env).unwrap();
        }
        let row = measure("motionless", &mut sim, 0.0, None).unwrap();
        assert_eq!(row.frozen_envs, 3);
        // One live environment: the batch's clock, once.
        let one = row.substeps_per_s * row.particles as f64;
        assert!(
            (row.particle_substeps_per_s - one).abs() <= 1e-6 * one,
            "{row:?}"
        );
        let rtf = row.real_time_factor_per_env;
        assert!(
            (row.simulated_s_per_wall_s - rtf).abs() <= 1e-9 * rtf,
            "{row:?}"
        );
    }
}
