//! Steps a batch for a fixed number of substeps, for profilers (a fixed amount of work, unlike
//! `rlpkg bench sim`, which runs for a wall-clock budget): the `command` workload of
//! [`rlpkg_sim::bench`], identical packages each carried by its own smooth twist command.
//!
//! `cargo run --release -p rlpkg-sim --example substeps -- SCENE.toml ROWSxCOLS ENVS SUBSTEPS`
//!
//! It prints a hash of the final state, so that two builds can be compared bit for bit.

use rlpkg_sim::bench::{bench_simulator, TwistCommands, CONTROL_INTERVAL_S};
use rlpkg_sim::SceneConfig;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [scene, grid, envs, substeps] = args.as_slice() else {
        return Err("usage: substeps SCENE.toml ROWSxCOLS ENVS SUBSTEPS".into());
    };
    let config = SceneConfig::load(std::path::Path::new(scene))?;
    let (rows, cols) = grid.split_once('x').ok_or("grid: expected ROWSxCOLS")?;
    let grid = [rows.parse()?, cols.parse()?];
    let mut sim = bench_simulator(&config, grid, envs.parse()?)?;
    let mut commands = TwistCommands::new(&sim, 0);
    let interval = (CONTROL_INTERVAL_S / sim.dt() as f64).round().max(1.0) as u64;
    let mut left: u64 = substeps.parse()?;
    while left > 0 {
        commands.apply(&mut sim)?;
        let n = interval.min(left);
        sim.step(n);
        left -= n;
    }
    let frozen = (0..sim.num_envs()).filter(|&e| sim.is_frozen(e)).count();
    // FNV-1a over every environment's positions and velocities: equal for two builds or machines
    // exactly when their results are bit-identical.
    let mut hash = 0xcbf2_9ce4_8422_2325u64;
    for env in 0..sim.num_envs() {
        let state = sim.particle_positions(env);
        for c in state.iter().chain(&sim.particle_velocities(env)).flatten() {
            hash = (hash ^ u64::from(c.to_bits())).wrapping_mul(0x100_0000_01b3);
        }
    }
    println!(
        "{} substeps, {frozen} environments frozen, state hash {hash:016x}",
        sim.substep()
    );
    Ok(())
}
