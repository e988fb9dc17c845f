//! The 18 recordings succeeded in reality: replayed in the physical scene with its default seal
//! settings, none may lose a cup. The test suite replays the first 1.5 s of each on the scene's own
//! 16 x 19 grid (on 11 x 13 a heavy disc can slip between the coarse sheet's particles, which the
//! health check reports). The closing note of the seal model gives the whole replays, made with
//! `cargo run --release -p rlpkg-replay --example seal_replays`.

use std::path::Path;
use std::sync::Arc;

use rlpkg_mocap::dataset::Dataset;
use rlpkg_replay::Target;
use rlpkg_sim::{CupLoad, EpisodeSpec, Model, SceneConfig, Simulator};

#[test]
fn no_recording_loses_a_cup_in_the_physical_scene() {
    let scene = SceneConfig::preset("physical").unwrap();
    assert!(scene.seal.enabled, "the physical scene models the seal");
    let data = Dataset::open(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../data/deformable-sim-real")
            .as_path(),
    )
    .unwrap();
    let ids = data.ids(None);
    assert_eq!(ids.len(), 18);
    let specs: Vec<EpisodeSpec> = ids
        .iter()
        .map(|id| {
            let target = Target::new(
                &data.load(id).unwrap(),
                None,
                scene.disc.hold_at_recorded_start,
            )
            .unwrap();
            EpisodeSpec {
                placement: target.placement,
                params: scene.params,
                object_mass_kg: target.object_mass_kg,
                disc_mass_scale: None,
                vacuum_kpa: None,
                trajectory: target.tool,
            }
        })
        .collect();
    let mut sim = Simulator::new(Arc::new(Model::new(&scene).unwrap()), specs).unwrap();
    let seconds = scene.cups.rest_time_s as f64 + 1.5;
    let chunk = (0.05 / sim.dt() as f64).round() as u64;
    let mut loads = vec![CupLoad::default(); 18 * sim.num_cups()];
    let mut peak = 0.0f32;
    while sim.time() < seconds {
        sim.step(chunk);
        sim.read_cup_loads(&mut loads).unwrap();
        peak = loads.iter().map(|l| l.utilisation).fold(peak, f32::max);
    }
    assert!(sim.seal_events().is_empty(), "{:?}", sim.seal_events());
    assert!(sim.health_events().is_empty(), "{:?}", sim.health_events());
    // The cups really carry load (the test is not vacuous), with margin to the limit.
    assert!(peak > 0.05 && peak < 1.0, "peak utilisation {peak}");
}
