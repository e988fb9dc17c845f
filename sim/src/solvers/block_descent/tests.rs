//! Tests of the block-descent integrator against physics and against the explicit integrator.

use std::sync::Arc;

use glam::DQuat;

use crate::test_support::{env_bits as bits, held_spec as spec, varied};

use crate::{HealthReason, Model, SceneConfig, Simulator, Solver, ToolCommand};

/// The physical scene (SI masses, g = −9.81) on `grid`, integrated by block descent at `rate_hz`.
fn descent(grid: [usize; 2], rate_hz: f64, iterations: u32) -> SceneConfig {
    let mut c = SceneConfig::preset("physical").unwrap();
    c.package.grid = grid;
    c.integrator.solver = Solver::BlockDescent;
    c.integrator.substep_rate_hz = rate_hz;
    c.integrator.iterations = iterations;
    c
}

fn explicit(grid: [usize; 2]) -> SceneConfig {
    let mut c = SceneConfig::preset("physical").unwrap();
    c.package.grid = grid;
    c
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

/// Mean velocity of the package particles.
fn mean_velocity(sim: &Simulator, env: usize) -> [f64; 3] {
    let n = sim.model().num_package;
    let mut m = [0.0; 3];
    for v in &sim.particle_velocities(env)[..n] {
        for k in 0..3 {
            m[k] += v[k] as f64 / n as f64;
        }
    }
    m
}

#[test]
fn a_free_falling_package_keeps_g() {
    let mut c = descent([6, 7], 600.0, 10);
    // Nothing holds it: springs off, no seal.
    c.params.k_spr_e = 0.0;
    c.params.k_spr_d = 0.0;
    c.seal.enabled = false;
    let model = Arc::new(Model::new(&c).unwrap());
    let mut sim = Simulator::new(model, vec![spec(&c, 0.01)]).unwrap();
    let t = 0.25;
    sim.step(steps(&sim, t));
    let v = mean_velocity(&sim, 0);
    let expected = -9.81 * t;
    assert!(
        (v[1] - expected).abs() < 0.005 * expected.abs(),
        "film falls at {} m/s after {t} s, free fall gives {expected}",
        v[1]
    );
    let disc = sim.disc(0).velocity[1] as f64;
    assert!(
        (disc - expected).abs() < 0.005 * expected.abs(),
        "disc {disc}"
    );
    // An unconverged Gauss-Seidel solve drifts along the vertex order; alternating sweeps keep
    // it below 1 % of the fall (measured: 0.1 % along x, 0.5 % along z).
    assert!(
        v[0].abs() < 0.01 * expected.abs() && v[2].abs() < 0.01 * expected.abs(),
        "{v:?}"
    );
}

/// Angular momentum of the package particles about the vertical through their centroid.
fn spin_momentum(sim: &Simulator, env: usize) -> f64 {
    let n = sim.model().num_package;
    let x = &sim.particle_positions(env)[..n];
    let v = &sim.particle_velocities(env)[..n];
    let mut centre = [0.0f64; 3];
    for p in x {
        for k in 0..3 {
            centre[k] += p[k] as f64 / n as f64;
        }
    }
    let vm = mean_velocity(sim, env);
    x.iter()
        .zip(v)
        .map(|(p, u)| {
            let (rx, rz) = (p[0] as f64 - centre[0], p[2] as f64 - centre[2]);
            let (ux, uz) = (u[0] as f64 - vm[0], u[2] as f64 - vm[2]);
            rz * ux - rx * uz
        })
        .sum()
}

/// Spins the package about the vertical at 3 rad/s with nothing else acting on it, and returns
/// the fraction of its angular momentum left after 0.5 s.
fn spin_kept(mut c: SceneConfig) -> f64 {
    c.integrator.gravity_m_s2 = 0.0;
    c.params.k_spr_e = 0.0;
    c.params.k_spr_d = 0.0;
    c.params.k_con_e = 0.0;
    c.params.k_con_f = 0.0;
    c.params.k_con_d = 0.0;
    c.seal.enabled = false;
    let model = Arc::new(Model::new(&c).unwrap());
    let s = spec(&c, 0.01);
    let centre = s.placement.disc_position;
    let mut sim = Simulator::new(model, vec![s]).unwrap();
    let w = 3.0f32;
    let v: Vec<[f32; 3]> = sim
        .particle_positions(0)
        .iter()
        .enumerate()
        .map(|(i, p)| {
            if i >= sim.model().num_package {
                return [0.0; 3];
            }
            let (rx, rz) = (p[0] - centre[0], p[2] - centre[2]);
            // ω × r with ω along +y.
            [w * rz, 0.0, -w * rx]
        })
        .collect();
    sim.set_particle_velocities(0, &v).unwrap();
    let before = spin_momentum(&sim, 0);
    sim.step(steps(&sim, 0.5));
    spin_momentum(&sim, 0) / before
}

#[test]
fn a_rigid_rotation_of_the_package_is_not_damped() {
    let kept = spin_kept(descent([6, 7], 600.0, 10));
    assert!(
        kept > 0.97 && kept < 1.001,
        "block descent kept {kept} of the spin"
    );
    // The explicit model's membrane damping (Warp's, on Ḟ) brakes the same spin: the check
    // above can fail.
    let explicit_kept = spin_kept(explicit([6, 7]));
    assert!(explicit_kept < 0.9, "explicit kept {explicit_kept}");
}

/// Mean and largest distance between the package particles of two simulators (m).
fn shape_distance(a: &Simulator, b: &Simulator) -> (f64, f64) {
    let n = a.model().num_package;
    let (pa, pb) = (a.particle_positions(0), b.particle_positions(0));
    let d: Vec<f64> = pa[..n]
        .iter()
        .zip(&pb[..n])
        .map(|(p, q)| {
            (0..3)
                .map(|k| (p[k] as f64 - q[k] as f64).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .collect();
    (
        d.iter().sum::<f64>() / n as f64,
        d.iter().cloned().fold(0.0, f64::max),
    )
}

#[test]
fn a_hanging_package_settles_to_the_explicit_rest_shape() {
    let grid = [11, 13];
    let run = |c: SceneConfig| {
        let model = Arc::new(Model::new(&c).unwrap());
        let mut sim = Simulator::new(model, vec![spec(&c, 0.01)]).unwrap();
        sim.step(steps(&sim, 3.0));
        sim
    };
    let reference = run(explicit(grid));
    let settled = run(descent(grid, 2400.0, 5));
    let (mean, max) = shape_distance(&settled, &reference);
    // A hanging film settles into one of several wrinkled shapes: the explicit integrator itself
    // moves its markers by 6-9 mm on average (up to 26 mm) when only its step is halved (16x19,
    // HHMMM). Measured here: mean 9.0 mm, max 40 mm, disc heights 6 mm apart.
    assert!(
        mean < 0.015 && max < 0.06,
        "rest shapes differ: mean {mean} m, max {max} m"
    );
    let dy = settled.disc(0).position[1] - reference.disc(0).position[1];
    assert!(dy.abs() < 0.01, "disc heights differ by {dy} m");
    // Both really hang: the package sags below the cups.
    assert!(mean_velocity(&settled, 0)[1].abs() < 0.01);
}

#[test]
fn real_film_stiffness_is_stable_at_the_large_step() {
    // Polyethylene packaging film: E ≈ 200 MPa, 100 µm thick: E·t = 2e4 N/m (10x the
    // physical preset's soft film), the preset's SI masses. At 600 substeps per second and 10
    // iterations the unconverged film lets the disc push through it; 2400 x 5 holds it.
    let mut c = descent([16, 19], 2400.0, 5);
    c.params.k_tri_e = 2.0e4;
    c.params.k_tri_a = 2.0e4;
    let model = Arc::new(Model::new(&c).unwrap());
    let mut sim = Simulator::new(model, vec![spec(&c, 0.01)]).unwrap();
    sim.step(steps(&sim, 2.5));
    assert!(sim.health_events().is_empty(), "{:?}", sim.health_events());
    let speed = max_particle_speed(&sim, 0);
    assert!(speed < 0.05, "still moving at {speed} m/s after 2.5 s held");
}

#[test]
fn real_film_is_stable_at_the_real_film_scenes_step() {
    // configs/scenes/physical-real-film.toml (1200 substeps/s x 10 sweeps, Chebyshev 0.95) at both ends of
    // real packaging film, on its grid and on the coarse grid of the coarse real-film scene: held
    // still, the package settles with the disc inside (the health check reports a disc outside
    // the package).
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../configs/scenes/physical-real-film.toml");
    for grid in [[16, 19], [11, 13]] {
        for film in [1.0e4, 2.0e4] {
            let mut c = SceneConfig::load(&path).unwrap();
            c.package.grid = grid;
            c.params.k_tri_e = film;
            c.params.k_tri_a = film;
            let model = Arc::new(Model::new(&c).unwrap());
            let mut sim = Simulator::new(model, vec![spec(&c, 0.01)]).unwrap();
            sim.step(steps(&sim, 2.5));
            assert!(
                sim.health_events().is_empty(),
                "{grid:?}, {film}: {:?}",
                sim.health_events()
            );
            let speed = max_particle_speed(&sim, 0);
            assert!(
                speed < 0.05,
                "{grid:?}, {film}: still moving at {speed} m/s after 2.5 s held"
            );
        }
    }
}

#[test]
fn the_disc_stays_inside_through_a_fast_lift_and_a_60_degree_tilt() {
    let c = descent([16, 19], 600.0, 10);
    let model = Arc::new(Model::new(&c).unwrap());
    let s = spec(&c, 0.01);
    let mut sim = Simulator::new(model, vec![s]).unwrap();
    sim.step(steps(&sim, 1.2));
    let tool0 = sim.tool_state(0);
    let goal = [
        tool0.position[0] as f32,
        tool0.position[1] as f32 + 0.3,
        tool0.position[2] as f32,
    ];
    let tilt = DQuat::from_rotation_z(60f64.to_radians());
    let control = 0.05;
    let mut peak_speed = 0.0f64;
    for _ in 0..50 {
        sim.command_tool(
            0,
            ToolCommand::Pose {
                position: goal,
                orientation: tilt.to_array().map(|c| c as f32),
            },
            control,
        )
        .unwrap();
        sim.step(steps(&sim, control));
        let v = sim.tool_state(0).velocity;
        peak_speed = peak_speed.max((v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt());
    }
    let tool = sim.tool_state(0);
    assert!((tool.position[1] - goal[1] as f64).abs() < 0.01);
    assert!(DQuat::from_array(tool.orientation).angle_between(tilt) < 0.02);
    // A fast move: the tool reached the recordings' high-velocity speeds.
    assert!(peak_speed > 0.5, "peak tool speed {peak_speed} m/s");
    assert!(
        !sim.health_events()
            .iter()
            .any(|e| e.reason == HealthReason::ObjectOutside),
        "{:?}",
        sim.health_events()
    );
    assert!(sim.health_events().is_empty(), "{:?}", sim.health_events());
}

#[test]
fn a_held_disc_is_turned_to_its_tilt_during_the_rest() {
    let tilt = DQuat::from_rotation_x(20f64.to_radians());
    for mut c in [descent([6, 7], 300.0, 10), explicit([6, 7])] {
        c.disc.hold_orientation = true;
        let model = Arc::new(Model::new(&c).unwrap());
        let mut held = spec(&c, 0.01);
        held.placement = held.placement.holding_disc_at(held.placement.disc_position);
        held.placement.disc_orientation = tilt.to_array().map(|c| c as f32);
        // The same tilt without a hold is the initial orientation.
        let mut started = held.clone();
        started.placement.disc_hold = None;
        let mut sim = Simulator::new(model, vec![held, started]).unwrap();
        let tilt_of = |sim: &Simulator, env: usize| {
            DQuat::from_array(sim.disc(env).orientation.map(f64::from))
                .angle_between(DQuat::IDENTITY)
        };
        assert!(tilt_of(&sim, 0) < 1e-6);
        assert!((tilt_of(&sim, 1) - 20f64.to_radians()).abs() < 1e-6);
        let rest = c.cups.rest_time_s as f64;
        // Halfway along the turn (a quarter of the rest): half the tilt, turning about x at the
        // smoothstep's peak rate, 1.5 x 20 degrees per quarter rest.
        sim.step(steps(&sim, 0.25 * rest));
        assert!((tilt_of(&sim, 0) - 10f64.to_radians()).abs() < 1e-3);
        let w = sim.disc(0).angular_velocity;
        let peak = 1.5 * 20f64.to_radians() / (0.5 * rest);
        assert!(
            (w[0] as f64 - peak).abs() < 0.01 * peak,
            "{w:?}, expected {peak} about x"
        );
        assert!(w[1].abs() < 1e-4 && w[2].abs() < 1e-4, "{w:?}");
        // Held at the tilt until the end of the rest, then free.
        sim.step(steps(&sim, 0.75 * rest) - 1);
        assert!((tilt_of(&sim, 0) - 20f64.to_radians()).abs() < 1e-4);
        assert_eq!(sim.disc(0).angular_velocity, [0.0; 3]);
        sim.step(steps(&sim, 0.2));
        assert!(sim.disc(0).angular_velocity.iter().any(|w| w.abs() > 1e-3));
    }
}

#[test]
fn block_descent_is_bit_identical_alone_in_a_batch_and_on_any_thread_count() {
    let mut c = descent([6, 7], 600.0, 5);
    c.integrator.chebyshev_rho = 0.9;
    let model = Arc::new(Model::new(&c).unwrap());
    let specs = varied(&c, 11, 7);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut sim = Simulator::new(model.clone(), specs.clone()).unwrap();
            sim.step(400);
            (0..specs.len()).map(|e| bits(&sim, e)).collect::<Vec<_>>()
        })
    };
    let batch = run(2);
    assert_eq!(batch, run(1));
    for env in [0, 9] {
        let mut alone = Simulator::new(model.clone(), vec![specs[env].clone()]).unwrap();
        alone.step(400);
        assert_eq!(bits(&alone, 0), batch[env], "env {env}");
    }
    assert_ne!(batch[0], batch[9]);
}
