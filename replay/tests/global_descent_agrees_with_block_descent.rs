//! The global-descent solver at 300 substeps per second against block descent at 1200 on a
//! replay of a real recording: the calibrated real-film scene
//! (configs/scenes/calibrated-coarse-real-film.toml) and the same scene on global descent
//! (configs/scenes/global-coarse-real-film.toml) replay the first 2 s of a held-out recording;
//! at every recorded frame the simulated markers of the two are compared.

use std::path::Path;
use std::sync::Arc;

use rlpkg_mocap::dataset::{Dataset, Split};
use rlpkg_replay::Target;
use rlpkg_sim::{Model, SceneConfig, Simulator, Solver};

/// Root-mean-square distance between two point sets of equal length (m).
fn rms(a: &[[f32; 3]], b: &[[f64; 3]]) -> f64 {
    let sum: f64 = a
        .iter()
        .zip(b)
        .map(|(p, q)| (0..3).map(|k| (p[k] as f64 - q[k]).powi(2)).sum::<f64>())
        .sum();
    (sum / a.len() as f64).sqrt()
}

#[test]
fn global_descent_at_300_hz_replays_a_recording_like_block_descent_at_1200_hz() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let scene = |name: &str| SceneConfig::load(&root.join("configs/scenes").join(name)).unwrap();
    let descent = scene("calibrated-coarse-real-film.toml");
    let global = scene("global-coarse-real-film.toml");
    assert_eq!(descent.integrator.solver, Solver::BlockDescent);
    assert_eq!(global.integrator.solver, Solver::GlobalDescent);
    assert_eq!(descent.params, global.params);
    let data = Dataset::open(&root.join("data/deformable-sim-real")).unwrap();
    let id = &data.ids(Some(Split::Test))[0];
    let target = Target::new(
        &data.load(id).unwrap(),
        Some(2.0),
        descent.disc.hold_at_recorded_start,
    )
    .unwrap();
    let sim_of = |c: &SceneConfig| {
        let spec = target.episode_spec(c.params, None);
        Simulator::new(Arc::new(Model::new(c).unwrap()), vec![spec]).unwrap()
    };
    let (mut a, mut b) = (sim_of(&descent), sim_of(&global));
    let (ea, eb) = (
        a.embed(0, &target.initial_markers),
        b.embed(0, &target.initial_markers),
    );
    let rest = descent.cups.rest_time_s as f64;
    let (mut between, mut to_recording_a, mut to_recording_b) = (0.0, 0.0, 0.0);
    for (k, &t) in target.times.iter().enumerate() {
        for sim in [&mut a, &mut b] {
            let substep = ((rest + t) / sim.dt() as f64).round() as u64;
            sim.step(substep - sim.substep());
        }
        let (pa, pb) = (a.surface_points(0, &ea), b.surface_points(0, &eb));
        let pa64: Vec<[f64; 3]> = pa.iter().map(|p| p.map(f64::from)).collect();
        between += rms(&pb, &pa64).powi(2);
        to_recording_a += rms(&pa, &target.markers[k]).powi(2);
        to_recording_b += rms(&pb, &target.markers[k]).powi(2);
    }
    let frames = target.times.len() as f64;
    let (between, to_a, to_b) = [between, to_recording_a, to_recording_b]
        .map(|s| (s / frames).sqrt())
        .into();
    eprintln!(
        "{id}, {frames} frames: global vs block descent {:.2} mm RMS; to the recording {:.2} mm (block descent), {:.2} mm (global descent)",
        between * 1e3,
        to_a * 1e3,
        to_b * 1e3
    );
    for sim in [&a, &b] {
        assert!(sim.health_events().is_empty(), "{:?}", sim.health_events());
    }
    // Agreement: the two solvers' markers within 5 mm RMS over the replay (the coarse grid's
    // cell is 25 mm), and global descent no further from the recording than block descent plus 2 mm.
    assert!(between < 5e-3, "markers differ by {between} m RMS");
    assert!(to_b < to_a + 2e-3, "{to_b} m vs {to_a} m to the recording");
}
