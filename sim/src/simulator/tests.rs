//! Tests of the batched simulator: conservation, settling, batching and threading invariance,
//! health checks, resets and retirement.

use std::sync::Arc;

use super::*;
use crate::{Placement, SceneConfig, ToolSample};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Package corner at (0, 0.3, 0), cups `cup_height` above the mid-plane at the centre, disc at
/// the centre, tool held still (or following `tool`).
fn spec(config: &SceneConfig, cup_height: f32, tool: Option<ToolTrajectory>) -> EpisodeSpec {
    let size = config.package.size_m;
    let centre = [size[1] / 2.0, 0.3, size[0] / 2.0];
    let cup_point = [centre[0], centre[1] + cup_height, centre[2]];
    let hold = ToolTrajectory::hold(
        [cup_point[0] as f64, 0.45, cup_point[2] as f64],
        [0.0, 0.0, 0.0, 1.0],
    );
    EpisodeSpec {
        placement: Placement::new([0.0, 0.3, 0.0], cup_point, centre),
        params: config.params,
        object_mass_kg: 0.57,
        disc_mass_scale: None,
        vacuum_kpa: None,
        trajectory: Arc::new(tool.unwrap_or(hold)),
    }
}

fn coarse(preset: &str, grid: [usize; 2]) -> SceneConfig {
    let mut c = SceneConfig::preset(preset).unwrap();
    c.package.grid = grid;
    c
}

fn perturbed(config: &SceneConfig, rng: &mut ChaCha8Rng) -> EpisodeSpec {
    let mut s = spec(config, rng.random_range(0.002..0.02), None);
    let p = &mut s.params;
    p.k_tri_e *= rng.random_range(0.5..2.0);
    p.k_tri_a *= rng.random_range(0.5..2.0);
    p.k_edge_e *= rng.random_range(0.5..2.0);
    p.k_con_e *= rng.random_range(0.5..2.0);
    p.mu_con *= rng.random_range(0.5..1.5);
    s.object_mass_kg = rng.random_range(0.28..0.57);
    s.placement.disc_position[0] += rng.random_range(-0.02..0.02);
    s
}

fn snapshot(sim: &Simulator, env: usize) -> Vec<u32> {
    let d = sim.disc(env);
    sim.particle_positions(env)
        .iter()
        .chain(&sim.particle_velocities(env))
        .flatten()
        .chain(
            d.position
                .iter()
                .chain(&d.orientation)
                .chain(&d.velocity)
                .chain(&d.angular_velocity),
        )
        .map(|c| c.to_bits())
        .collect()
}

#[test]
fn momentum_is_conserved_without_gravity_or_contact() {
    let mut c = coarse("reference", [6, 7]);
    c.integrator.gravity_m_s2 = 0.0;
    c.params.k_spr_e = 0.0;
    c.params.k_spr_d = 0.0;
    let model = Arc::new(Model::new(&c).unwrap());
    let mut s = spec(&c, 0.5, None); // cups far above: no cup contact either
    s.placement.disc_position = [5.0, 5.0, 5.0];
    let mut sim = Simulator::new(model.clone(), vec![s]).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut vel = vec![[0.0f32; 3]; model.num_particles()];
    for v in vel.iter_mut().take(model.num_package) {
        *v = [
            rng.random_range(-0.2..0.2),
            rng.random_range(-0.2..0.2),
            rng.random_range(-0.2..0.2),
        ];
    }
    sim.set_particle_velocities(0, &vel).unwrap();
    let momentum = |sim: &Simulator| {
        let mut p = [0.0f64; 3];
        for v in &sim.particle_velocities(0)[..model.num_package] {
            for k in 0..3 {
                p[k] += model.package_particle_mass as f64 * v[k] as f64;
            }
        }
        p
    };
    let before = momentum(&sim);
    let positions_before = sim.particle_positions(0);
    sim.step(300);
    let after = momentum(&sim);
    // The internal forces did work: the shape changed.
    let moved = positions_before
        .iter()
        .zip(sim.particle_positions(0))
        .any(|(a, b)| (a[1] - b[1]).abs() > 1e-4);
    assert!(moved);
    for k in 0..3 {
        assert!(
            (before[k] - after[k]).abs() < 1e-3 * 0.8,
            "component {k}: {} vs {}",
            before[k],
            after[k]
        );
    }
}

/// Mean y of the lower and upper sheet particles within `radius` (xz) of the disc axis.
fn sheets_around_disc(sim: &Simulator, env: usize, radius: f32) -> (f32, f32) {
    let m = sim.model();
    let d = sim.disc(env).position;
    let x = sim.particle_positions(env);
    let mean = |range: std::ops::Range<usize>| {
        let ys: Vec<f32> = x[range]
            .iter()
            .filter(|p| (p[0] - d[0]).hypot(p[2] - d[2]) < radius)
            .map(|p| p[1])
            .collect();
        ys.iter().sum::<f32>() / ys.len() as f32
    };
    (mean(0..m.layer_size), mean(m.layer_size..m.num_package))
}

fn lift(start: [f64; 3], speed: f64, duration: f64) -> ToolTrajectory {
    let q = [0.0, 0.0, 0.0, 1.0];
    let end = [start[0], start[1] + speed * duration, start[2]];
    let v = [0.0, speed, 0.0];
    ToolTrajectory::new(vec![
        ToolSample {
            t: 0.0,
            position: start,
            orientation: q,
            velocity: v,
        },
        ToolSample {
            t: duration,
            position: end,
            orientation: q,
            velocity: v,
        },
    ])
    .unwrap()
}

#[test]
fn hanging_package_settles_with_disc_inside_then_lifts_without_tunnelling() {
    let mut c = coarse("reference", [11, 13]);
    c.cups.rest_time_s = 1.2;
    let model = Arc::new(Model::new(&c).unwrap());
    let mut s = spec(&c, 0.01, None);
    let tool0 = s.trajectory.pose_at(0.0).position.map(|x| x as f64);
    s.trajectory = Arc::new(lift(tool0, 1.0, 0.2));
    let mut sim = Simulator::new(model, vec![s]).unwrap();
    let tenth = (0.1 / sim.dt() as f64).round() as u64;
    let mut peak = 0.0f64;
    for _ in 0..12 {
        sim.step(tenth);
        peak = peak.max(sim.kinetic_energy(0));
    }
    let settled = sim.kinetic_energy(0);
    assert!(
        settled < 1e-3 && settled < 1e-3 * peak,
        "kinetic energy {settled} J (peak {peak} J)"
    );
    let (lower, upper) = sheets_around_disc(&sim, 0, 0.05);
    let y0 = sim.disc(0).position[1];
    assert!(
        lower < y0 && y0 < upper,
        "disc at {y0} not between sheets {lower} and {upper}"
    );
    assert!(sim.health_events().is_empty());
    // Fast lift: 1 m/s for 0.2 s. The disc must stay between the sheets all the way.
    for _ in 0..8 {
        sim.step(tenth / 2);
        let (lower, upper) = sheets_around_disc(&sim, 0, 0.05);
        let y = sim.disc(0).position[1];
        assert!(
            lower < y && y < upper,
            "t = {}: disc at {y} not between sheets {lower} and {upper}",
            sim.time()
        );
    }
    assert!(
        sim.disc(0).position[1] > y0 + 0.1,
        "disc was not lifted: {} from {y0}",
        sim.disc(0).position[1]
    );
}

#[test]
fn held_disc_reaches_its_hold_point_then_is_released() {
    let mut c = coarse("reference", [11, 13]);
    c.cups.rest_time_s = 0.4;
    let model = Arc::new(Model::new(&c).unwrap());
    let free = spec(&c, 0.01, None);
    let start = free.placement.disc_position;
    let target = [start[0] + 0.02, start[1] - 0.03, start[2] - 0.01];
    let mut held = free.clone();
    held.placement = held.placement.holding_disc_at(target);
    let mut sim = Simulator::new(model, vec![free, held]).unwrap();
    let dt = sim.dt() as f64;
    let steps = |s: f64| (s / dt).round() as u64;
    // Half-way through the travel (a quarter of the rest), the smooth path is half-way too.
    sim.step(steps(0.1));
    let mid = sim.disc(1).position;
    for c in 0..3 {
        let expected = 0.5 * (start[c] + target[c]);
        assert!((mid[c] - expected).abs() < 1e-4, "{mid:?} vs {expected}");
    }
    sim.step(steps(0.3));
    let end = sim.disc(1);
    for c in 0..3 {
        assert!((end.position[c] - target[c]).abs() < 1e-6, "{end:?}");
        assert_eq!(end.velocity[c], 0.0);
    }
    // The free disc of environment 0 went its own way; after the rest the held one moves
    // under the package's forces (it was not at the package's equilibrium).
    assert!((sim.disc(0).position[1] - target[1]).abs() > 1e-3);
    sim.step(steps(0.05));
    let released = sim.disc(1);
    let speed = released.velocity.iter().map(|v| v * v).sum::<f32>().sqrt();
    assert!(speed > 1e-2, "{released:?}");
    assert!(sim.health_events().is_empty());
}

#[test]
fn physical_preset_is_stable_on_coarse_and_fine_grids() {
    for grid in [[11, 13], [26, 31]] {
        let c = coarse("physical", grid);
        let model = Arc::new(Model::new(&c).unwrap());
        let mut sim = Simulator::new(model, vec![spec(&c, 0.01, None)]).unwrap();
        sim.step((0.25 / sim.dt() as f64).round() as u64);
        assert!(
            sim.health_events().is_empty(),
            "{grid:?}: {:?}",
            sim.health_events()
        );
        let (lower, upper) = sheets_around_disc(&sim, 0, 0.05);
        let y = sim.disc(0).position[1];
        assert!(
            lower < y && y < upper,
            "{grid:?}: disc at {y} not between sheets {lower} and {upper}"
        );
    }
}

#[test]
fn env_is_bit_identical_alone_and_in_a_batch_of_1024() {
    let c = coarse("reference", [6, 7]);
    let model = Arc::new(Model::new(&c).unwrap());
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let specs: Vec<EpisodeSpec> = (0..1024).map(|_| perturbed(&c, &mut rng)).collect();
    let mut batch = Simulator::new(model.clone(), specs.clone()).unwrap();
    batch.step(96);
    for env in [0, 5, 517, 1023] {
        let mut alone = Simulator::new(model.clone(), vec![specs[env].clone()]).unwrap();
        alone.step(96);
        assert_eq!(snapshot(&alone, 0), snapshot(&batch, env), "env {env}");
    }
    // Different environments really differ (the comparison above is not vacuous).
    assert_ne!(snapshot(&batch, 0), snapshot(&batch, 5));
}

#[test]
fn results_do_not_depend_on_thread_count() {
    let c = coarse("reference", [6, 7]);
    let model = Arc::new(Model::new(&c).unwrap());
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let specs: Vec<EpisodeSpec> = (0..21).map(|_| perturbed(&c, &mut rng)).collect();
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut sim = Simulator::new(model.clone(), specs.clone()).unwrap();
            sim.step(80);
            (0..21).map(|e| snapshot(&sim, e)).collect::<Vec<_>>()
        })
    };
    assert_eq!(run(1), run(2));
}

#[test]
fn health_check_freezes_a_poisoned_env_and_spares_the_others() {
    let c = coarse("reference", [6, 7]);
    let model = Arc::new(Model::new(&c).unwrap());
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let specs: Vec<EpisodeSpec> = (0..10).map(|_| perturbed(&c, &mut rng)).collect();
    let mut poisoned = specs.clone();
    poisoned[3].params.k_tri_e = 1e10;
    poisoned[3].params.k_spr_e = 1e10;
    let mut clean = Simulator::new(model.clone(), specs).unwrap();
    let mut sick = Simulator::new(model, poisoned).unwrap();
    clean.step(256);
    sick.step(256);
    assert!(clean.health_events().is_empty());
    let events = sick.health_events();
    assert_eq!(events.len(), 1, "{events:?}");
    assert_eq!(events[0].env, 3);
    assert!(events[0].time > 0.0 && events[0].time <= sick.time());
    assert!(sick.is_frozen(3) && !sick.is_frozen(2));
    // Frozen: the state no longer changes.
    let frozen = snapshot(&sick, 3);
    sick.step(64);
    assert_eq!(frozen, snapshot(&sick, 3));
    clean.step(64);
    for env in (0..10).filter(|&e| e != 3) {
        assert_eq!(snapshot(&sick, env), snapshot(&clean, env), "env {env}");
    }
}

#[test]
fn reset_restores_the_initial_state() {
    let c = coarse("reference", [6, 7]);
    let model = Arc::new(Model::new(&c).unwrap());
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let specs: Vec<EpisodeSpec> = (0..3).map(|_| perturbed(&c, &mut rng)).collect();
    let mut sim = Simulator::new(model, specs).unwrap();
    let initial = snapshot(&sim, 2);
    sim.step(40);
    let after_40 = snapshot(&sim, 2);
    assert_ne!(initial, after_40);
    sim.reset();
    assert_eq!(sim.substep(), 0);
    assert_eq!(snapshot(&sim, 2), initial);
    sim.step(40);
    assert_eq!(snapshot(&sim, 2), after_40);
}

#[test]
fn retired_envs_stay_put_and_spare_the_others() {
    let c = coarse("reference", [6, 7]);
    let model = Arc::new(Model::new(&c).unwrap());
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let specs: Vec<EpisodeSpec> = (0..2 * LANES).map(|_| perturbed(&c, &mut rng)).collect();
    let mut all = Simulator::new(model.clone(), specs.clone()).unwrap();
    let mut some = Simulator::new(model, specs).unwrap();
    all.step(30);
    some.step(30);
    // Retire the whole first block and one environment of the second.
    let retired: Vec<usize> = (0..LANES).chain([LANES + 3]).collect();
    let before: Vec<Vec<u32>> = retired.iter().map(|&e| snapshot(&some, e)).collect();
    for &e in &retired {
        some.retire(e).unwrap();
    }
    all.step(50);
    some.step(50);
    for (i, &e) in retired.iter().enumerate() {
        assert!(some.is_frozen(e));
        assert_eq!(snapshot(&some, e), before[i], "retired env {e} moved");
    }
    for e in (LANES..2 * LANES).filter(|e| !retired.contains(e)) {
        assert!(!some.is_frozen(e));
        assert_eq!(snapshot(&some, e), snapshot(&all, e), "env {e} changed");
    }
    assert!(some.health_events().is_empty());
    assert!(some.retire(2 * LANES).is_err());
}

#[test]
fn kinematic_cups_follow_the_tool_exactly() {
    let mut c = coarse("physical", [6, 7]);
    c.cups.rest_time_s = 0.0;
    let model = Arc::new(Model::new(&c).unwrap());
    let mut s = spec(&c, 0.01, None);
    let tool0 = s.trajectory.pose_at(0.0).position.map(|x| x as f64);
    s.trajectory = Arc::new(lift(tool0, 0.5, 1.0));
    let cups0 = Simulator::new(model.clone(), vec![s.clone()])
        .unwrap()
        .cup_positions(0);
    let mut sim = Simulator::new(model, vec![s]).unwrap();
    sim.step(1000);
    let rise = 0.5 * sim.time() as f32;
    for (now, then) in sim.cup_positions(0).iter().zip(&cups0) {
        assert!(
            (now[1] - then[1] - rise).abs() < 1e-4,
            "{} vs {}",
            now[1] - then[1],
            rise
        );
        assert!((now[0] - then[0]).abs() < 1e-6 && (now[2] - then[2]).abs() < 1e-6);
    }
}

#[test]
fn bad_env_inputs_are_rejected() {
    let c = coarse("reference", [6, 7]);
    let model = Arc::new(Model::new(&c).unwrap());
    let mut s = spec(&c, 0.01, None);
    s.object_mass_kg = -1.0;
    let err = Simulator::new(model.clone(), vec![s])
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("environment 0") && err.contains("object mass"),
        "{err}"
    );
    let mut sim = Simulator::new(model, vec![spec(&c, 0.01, None)]).unwrap();
    let mut p = c.params;
    p.mu_con = f32::NAN;
    assert!(sim
        .set_params(0, p)
        .unwrap_err()
        .to_string()
        .contains("mu_con"));
    assert!(sim.set_params(4, c.params).is_err());
}
