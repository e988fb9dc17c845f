//! Tests of the global-descent solver: real film at its large step, and the lane rules.

use std::sync::Arc;

use crate::test_support::{env_bits as bits, held_spec as spec, varied};

use crate::{EpisodeSpec, Model, SceneConfig, Simulator, Solver};

/// A real-film scene on global descent from `configs/scenes/`, at its substep rate.
fn global_scene(name: &str, substep_rate_hz: f64) -> SceneConfig {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../configs/scenes")
        .join(name);
    let c = SceneConfig::load(&path).unwrap();
    assert_eq!(c.integrator.solver, Solver::GlobalDescent);
    assert_eq!(c.integrator.substep_rate_hz, substep_rate_hz);
    c
}

/// configs/scenes/global-coarse-real-film.toml: the block-descent fit of real film on global
/// descent at 300 substeps per second.
fn real_film_scene() -> SceneConfig {
    global_scene("global-coarse-real-film.toml", 300.0)
}

/// The package 0.5 m above the ground, cups `cup_height` above its centre, a 0.5 kg disc.
fn steps(sim: &Simulator, seconds: f64) -> u64 {
    (seconds / sim.dt() as f64).round() as u64
}

/// Fastest particle's speed (m/s).
fn max_particle_speed(sim: &Simulator, env: usize) -> f32 {
    sim.particle_velocities(env)
        .iter()
        .map(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt())
        .fold(0.0f32, f32::max)
}

/// Real packaging film at both ends of its range (`k_tri_e` = `k_tri_a` = 1e4 and 2e4 N/m) on
/// `base`, each alone and in one batch: held still for 2.5 s the package settles with the disc
/// inside (the health check reports a disc outside the package, a divergence or a runaway speed).
fn assert_real_film_held_settles(base: &SceneConfig) {
    let films = [1.0e4f32, 2.0e4];
    let specs: Vec<EpisodeSpec> = films
        .iter()
        .map(|&film| {
            let mut s = spec(base, 0.01);
            s.params.k_tri_e = film;
            s.params.k_tri_a = film;
            s
        })
        .collect();
    let model = Arc::new(Model::new(base).unwrap());
    let mut sim = Simulator::new(model, specs).unwrap();
    sim.step(steps(&sim, 2.5));
    assert!(sim.health_events().is_empty(), "{:?}", sim.health_events());
    for (env, film) in films.iter().enumerate() {
        let speed = max_particle_speed(&sim, env);
        assert!(
            speed < 0.05,
            "{film} N/m: still moving at {speed} m/s after 2.5 s held"
        );
        // The disc hangs inside, below the cups, not fallen through.
        let disc = sim.disc(env).position;
        assert!(
            disc[1] > 0.3 && disc[1] < 0.51,
            "{film} N/m: disc at {disc:?}"
        );
    }
}

#[test]
fn real_film_held_at_300_substeps_per_second_keeps_the_disc_inside_and_settles() {
    assert_real_film_held_settles(&real_film_scene());
}

#[test]
fn real_film_held_at_200_substeps_per_second_keeps_the_disc_inside_and_settles() {
    // The scene calibrated at 200 substeps/s, with its own bending, contacts and cup springs.
    assert_real_film_held_settles(&global_scene(
        "calibrated-global-coarse-real-film-200hz.toml",
        200.0,
    ));
}

#[test]
fn global_descent_is_bit_identical_alone_in_a_batch_and_on_any_thread_count() {
    let mut c = real_film_scene();
    c.package.grid = [6, 7];
    let model = Arc::new(Model::new(&c).unwrap());
    let specs = varied(&c, 11, 7);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut sim = Simulator::new(model.clone(), specs.clone()).unwrap();
            sim.step(200);
            (0..specs.len()).map(|e| bits(&sim, e)).collect::<Vec<_>>()
        })
    };
    let batch = run(2);
    assert_eq!(batch, run(1));
    for env in [0, 9] {
        let mut alone = Simulator::new(model.clone(), vec![specs[env].clone()]).unwrap();
        alone.step(200);
        assert_eq!(bits(&alone, 0), batch[env], "env {env}");
    }
    assert_ne!(batch[0], batch[9]);
}
