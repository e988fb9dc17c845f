// TEMPORARY harness (deleted before hand-over): the same code path as `rlpkg calibrate`.
use rlpkg_calib::config::CalibrateConfig;
use rlpkg_calib::driver::{self, Plan};
use rlpkg_calib::objective::{load_scene, SimObjective};
use std::time::Instant;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let config = CalibrateConfig::load(std::path::Path::new(&args[1])).unwrap();
    let ids: Vec<String> = args[2].split(',').map(String::from).collect();
    let max_s: f64 = args[3].parse().unwrap();
    let iterations: usize = args[4].parse().unwrap();
    let out: std::path::PathBuf = args[5].clone().into();
    let ds = rlpkg_mocap::Dataset::open(&config.data).unwrap();
    let trajs: Vec<_> = ids.iter().map(|id| ds.load(id).unwrap()).collect();
    let scene = load_scene(&config.sim.preset, Some(config.sim.between), config.sim.dt).unwrap();
    let names: Vec<String> = config.params.iter().map(|p| p.name.clone()).collect();
    let mut obj = SimObjective::new(&scene, names, &trajs, config.loss, Some(max_s)).unwrap();
    let plan = Plan { space: config.space(), settings: config.bo_settings(), seed_points: vec![obj.base_values()], iterations, out_dir: out };
    let t0 = Instant::now();
    let best = driver::run(&plan, &mut obj, |r| println!("batch {}/{} best {:.6} batch best {:.6} at {:.1}s", r.batch + 1, r.planned_batches, r.best_loss, r.batch_best_loss, t0.elapsed().as_secs_f64())).unwrap();
    println!("{best:#?}\nwall {:.1}s", t0.elapsed().as_secs_f64());
}
