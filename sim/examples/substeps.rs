//! Steps a batch for a fixed number of substeps, for profilers (a fixed amount of work, unlike
//! `rlpkg bench sim`, which runs for a wall-clock budget): the `command` workload of
//! [`rlpkg_sim::bench`], identical packages each carried by its own smooth twist command.
//!
//! `cargo run --release -p rlpkg-sim --example substeps -- SCENE.toml ROWSxCOLS ENVS SUBSTEPS`

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
    println!("{} substeps, {frozen} environments frozen", sim.substep());
    Ok(())
}
