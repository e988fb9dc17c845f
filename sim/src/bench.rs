//! Throughput benchmark of the simulator (`rlpkg bench sim`): a package held still by the cups
//! with the disc inside, stepped for a wall-clock budget.

use std::sync::Arc;
use std::time::Instant;

use serde::Serialize;

use crate::{EnvSpec, Model, Placement, SceneConfig, SimError, Simulator, ToolTrajectory};

/// One benchmark measurement.
#[derive(Clone, Debug, Serialize)]
pub struct BenchRow {
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
    /// Particle-substeps per second over the whole batch.
    pub particle_substeps_per_s: f64,
    /// Simulated seconds per wall second, per environment.
    pub real_time_factor_per_env: f64,
    /// Simulated seconds per wall second summed over environments.
    pub real_time_factor_total: f64,
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
fn reset_peak_rss() {
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
    let spec = EnvSpec {
        placement: Placement::new(origin, cup_point, centre),
        params: config.params,
        object_mass_kg: 0.57,
        disc_mass_scale: None,
        trajectory: tool,
    };
    Simulator::new(model, vec![spec; envs])
}

/// Steps a batch for at least `seconds` of wall time (in chunks of 64 substeps, after a warm-up
/// chunk) and reports throughput.
pub fn run(
    config: &SceneConfig,
    grid: [usize; 2],
    envs: usize,
    seconds: f64,
) -> Result<BenchRow, SimError> {
    reset_peak_rss();
    let mut sim = bench_simulator(config, grid, envs)?;
    let chunk = 64;
    sim.step(chunk);
    let start = Instant::now();
    let mut substeps = 0;
    while substeps == 0 || start.elapsed().as_secs_f64() < seconds {
        sim.step(chunk);
        substeps += chunk;
    }
    let wall_s = start.elapsed().as_secs_f64();
    let particles = sim.model().num_particles();
    let substeps_per_s = substeps as f64 / wall_s;
    let rtf = substeps_per_s * sim.dt() as f64;
    Ok(BenchRow {
        grid,
        particles,
        envs,
        substeps,
        wall_s,
        substeps_per_s,
        particle_substeps_per_s: substeps_per_s * (particles * envs) as f64,
        real_time_factor_per_env: rtf,
        real_time_factor_total: rtf * envs as f64,
        state_bytes: sim.state_bytes(),
        peak_rss_bytes: peak_rss_bytes(),
        threads: rayon::current_num_threads(),
    })
}

/// The rows as a plain-text table.
pub fn format_table(rows: &[BenchRow]) -> String {
    let mut out = format!(
        "{:>7} {:>9} {:>6} {:>10} {:>14} {:>10} {:>10} {:>10} {:>10}\n",
        "grid",
        "particles",
        "envs",
        "substeps/s",
        "particle-ss/s",
        "RTF/env",
        "RTF total",
        "state MB",
        "peak MB"
    );
    for r in rows {
        out += &format!(
            "{:>7} {:>9} {:>6} {:>10.0} {:>12.2} M {:>10.4} {:>10.3} {:>10.1} {:>10}\n",
            format!("{}x{}", r.grid[0], r.grid[1]),
            r.particles,
            r.envs,
            r.substeps_per_s,
            r.particle_substeps_per_s / 1e6,
            r.real_time_factor_per_env,
            r.real_time_factor_total,
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
        assert!(format_table(&[row]).contains("6x7"));
    }
}
