//! Replays every shipped recording in one batch of a scene with the seal model on and prints,
//! per recording, the peak seal utilisation of each cup over the replay and every seal event.
//!
//! ```sh
//! cargo run --release -p rlpkg-replay --example seal_replays -- [scene.toml] [grid RxC] [time scale] [seconds]
//! ```
//! Defaults: `configs/scenes/physical-explicit.toml`, its own grid, time scale 1 (2 plays each recording twice as
//! fast), whole recordings. The scene's seal settings are used as they are.

use std::path::Path;
use std::sync::Arc;

use rlpkg_mocap::dataset::Dataset;
use rlpkg_replay::Target;
use rlpkg_sim::{CupLoad, EpisodeSpec, Model, SceneConfig, Simulator, ToolSample, ToolTrajectory};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let scene_path = args
        .first()
        .map_or("configs/scenes/physical-explicit.toml", |s| s.as_str());
    let mut scene = SceneConfig::load(Path::new(scene_path))?;
    if let Some(grid) = args.get(1) {
        let (r, c) = grid.split_once('x').ok_or("grid: expected RxC")?;
        scene.package.grid = [r.parse()?, c.parse()?];
    }
    let scale: f64 = args.get(2).map_or(Ok(1.0), |s| s.parse())?;
    let seconds: Option<f64> = args.get(3).map(|s| s.parse()).transpose()?;
    let data = Dataset::open(Path::new("data/deformable-sim-real"))?;
    let model = Arc::new(Model::new(&scene)?);
    let mut ids = Vec::new();
    let mut specs = Vec::new();
    let mut durations = Vec::new();
    for id in data.ids(None) {
        let target = Target::new(&data.load(&id)?, None, scene.disc.hold_at_recorded_start)?;
        // Time-scaled: the same path, `scale` times as fast.
        let samples = target
            .tool
            .samples()
            .iter()
            .map(|s| ToolSample {
                t: s.t / scale,
                velocity: s.velocity.map(|v| v * scale),
                ..*s
            })
            .collect();
        let tool = ToolTrajectory::new(samples)?;
        let duration = seconds.unwrap_or(tool.duration()).min(tool.duration());
        durations.push(duration);
        ids.push(id);
        specs.push(EpisodeSpec {
            placement: target.placement,
            params: scene.params,
            object_mass_kg: target.object_mass_kg,
            disc_mass_scale: None,
            vacuum_kpa: None,
            trajectory: Arc::new(tool),
        });
    }
    let mut sim = Simulator::new(model.clone(), specs)?;
    let rest = scene.cups.rest_time_s as f64;
    let cups = sim.num_cups();
    let mut loads = vec![CupLoad::default(); ids.len() * cups];
    let mut peak = vec![0.0f32; ids.len() * cups];
    let chunk = (0.01 / sim.dt() as f64).round() as u64;
    let end = rest + durations.iter().copied().fold(0.0, f64::max);
    let started = std::time::Instant::now();
    while sim.time() < end {
        sim.step(chunk);
        sim.read_cup_loads(&mut loads)?;
        for (env, id_peak) in peak.chunks_mut(cups).enumerate() {
            if sim.env_time(env) < rest || sim.env_time(env) > rest + durations[env] {
                continue;
            }
            for (p, l) in id_peak.iter_mut().zip(&loads[env * cups..]) {
                if l.attached {
                    *p = p.max(l.utilisation);
                }
            }
            if sim.env_time(env) >= rest + durations[env] {
                sim.retire(env)?;
            }
        }
    }
    println!(
        "scene {scene_path}, grid {:?}, time scale {scale}, {:.0} s wall",
        scene.package.grid,
        started.elapsed().as_secs_f64()
    );
    println!("recording | peak utilisation per cup | seal events");
    for (env, id) in ids.iter().enumerate() {
        let events: Vec<String> = sim
            .seal_events()
            .iter()
            .filter(|e| e.env == env)
            .map(|e| {
                format!(
                    "{:?} cup {:?} at {:.3} s (normal {:.2} N, shear {:.2} N, capacity {:.2} N)",
                    e.kind,
                    e.cup,
                    e.time - rest,
                    e.load.normal_n,
                    e.load.shear_n,
                    e.load.capacity_n
                )
            })
            .collect();
        let peaks: Vec<String> = peak[env * cups..(env + 1) * cups]
            .iter()
            .map(|p| format!("{p:.2}"))
            .collect();
        println!("{id} | {} | {}", peaks.join(" "), events.join("; "));
    }
    for e in sim.health_events() {
        println!(
            "health: {} {:?} at {:.3} s",
            ids[e.env],
            e.reason,
            e.time - rest
        );
    }
    Ok(())
}
