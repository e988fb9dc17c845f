//! Tests of the simulator as a control plant: per-environment episodes, snapshots, tool
//! commands, the suction seal and randomisation.

use std::sync::Arc;

use glam::DQuat;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::test_support::{env_bits as bits, held_spec as spec, varied};

use crate::{
    CupLoad, EnvObservation, EpisodeSpec, HealthReason, Model, NoSealReason, Randomization,
    SceneConfig, SealEventKind, Simulator, ToolCommand,
};

/// The physical scene on a coarse grid, cups held `cup_height` above the package centre, the
/// tool at the cup point (so it turns about the cups' centre), a 0.5 kg disc.
fn scene(grid: [usize; 2]) -> SceneConfig {
    let mut c = SceneConfig::preset("physical").unwrap();
    c.package.grid = grid;
    c
}

fn seconds(sim: &Simulator, s: f64) -> u64 {
    (s / sim.dt() as f64).round() as u64
}

#[test]
fn resetting_one_env_leaves_the_others_bit_identical() {
    let c = scene([6, 7]);
    let model = Arc::new(Model::new(&c).unwrap());
    let specs = varied(&c, 11, 1);
    let mut plain = Simulator::new(model.clone(), specs.clone()).unwrap();
    let mut reset = Simulator::new(model.clone(), specs.clone()).unwrap();
    plain.step(90);
    reset.step(90);
    let fresh = varied(&c, 12, 2).pop().unwrap();
    reset.reset_env(3, fresh.clone()).unwrap();
    assert_eq!(reset.env_substep(3), 0);
    plain.step(70);
    reset.step(70);
    for env in (0..11).filter(|&e| e != 3) {
        assert_eq!(bits(&plain, env), bits(&reset, env), "env {env}");
        assert_eq!(reset.env_substep(env), 160);
    }
    // The reset environment runs its new episode exactly as a fresh one would, on its own clock.
    let mut alone = Simulator::new(model, vec![fresh]).unwrap();
    alone.step(70);
    assert_eq!(bits(&alone, 0), bits(&reset, 3));
    assert_eq!(reset.env_substep(3), 70);
    assert_ne!(bits(&plain, 3), bits(&reset, 3));
}

#[test]
fn a_snapshot_restored_into_another_lane_continues_bit_identically() {
    let mut c = scene([6, 7]);
    c.seal.enabled = true;
    let model = Arc::new(Model::new(&c).unwrap());
    let mut a = Simulator::new(model.clone(), varied(&c, 9, 3)).unwrap();
    let mut b = Simulator::new(model.clone(), varied(&c, 9, 4)).unwrap();
    a.step(130);
    b.step(40);
    // A command in flight is part of the state too.
    let command = ToolCommand::Twist {
        linear: [0.0, 0.3, 0.1],
        angular: [0.0, 0.0, 0.5],
    };
    a.command_tool(2, command, 1e-3).unwrap();
    a.step(20);
    let snap = a.snapshot(2);
    let text = serde_json::to_string(&snap).unwrap();
    let back: crate::EnvSnapshot = serde_json::from_str(&text).unwrap();
    assert_eq!(format!("{back:?}"), format!("{snap:?}"));
    b.restore(5, &back).unwrap();
    a.step(150);
    b.step(150);
    assert_eq!(bits(&a, 2), bits(&b, 5));
    assert_eq!(a.env_substep(2), b.env_substep(5));
    // A snapshot of another model is refused.
    let other = Arc::new(Model::new(&scene([7, 8])).unwrap());
    let mut wrong = Simulator::new(other, vec![spec(&scene([7, 8]), 0.01)]).unwrap();
    assert!(wrong.restore(0, &snap).is_err());
}

/// The cups' mean position.
fn cup_centre(sim: &Simulator, env: usize) -> [f32; 3] {
    let cups = sim.cup_positions(env);
    std::array::from_fn(|k| cups.iter().map(|p| p[k]).sum::<f32>() / cups.len() as f32)
}

#[test]
fn commanded_tool_reaches_its_pose_and_limits_are_reported() {
    let c = scene([6, 7]);
    let model = Arc::new(Model::new(&c).unwrap());
    let s = spec(&c, 0.01);
    let mut sim = Simulator::new(model, vec![s.clone(), s]).unwrap();
    sim.step(seconds(&sim, 0.2));
    let start = cup_centre(&sim, 0);
    let tool0 = sim.tool_state(0);
    let goal = [
        tool0.position[0] + 0.06,
        tool0.position[1] + 0.04,
        tool0.position[2],
    ];
    let turn = DQuat::from_rotation_y(0.3);
    let control = 0.05;
    for _ in 0..30 {
        let report = sim
            .command_tool(
                0,
                ToolCommand::Pose {
                    position: goal.map(|c| c as f32),
                    orientation: turn.to_array().map(|c| c as f32),
                },
                control,
            )
            .unwrap();
        assert!(report.accel_applied <= c.tool_limits.max_accel_m_s2 * 1.0001);
        sim.step(seconds(&sim, control));
    }
    // Stop: zero twist over a last interval.
    let stop = ToolCommand::Twist {
        linear: [0.0; 3],
        angular: [0.0; 3],
    };
    sim.command_tool(0, stop, control).unwrap();
    sim.step(seconds(&sim, 0.3));
    let tool = sim.tool_state(0);
    for k in 0..3 {
        assert!(
            (tool.position[k] - goal[k]).abs() < 5e-3,
            "{:?} vs {goal:?}",
            tool.position
        );
    }
    assert!(DQuat::from_array(tool.orientation).angle_between(turn) < 0.01);
    // Kinematic cups moved rigidly with the tool: their centre by the tool's displacement.
    let moved = cup_centre(&sim, 0);
    let tool_shift = [
        tool.position[0] - tool0.position[0],
        tool.position[1] - tool0.position[1],
    ];
    assert!((moved[0] - start[0] - tool_shift[0] as f32).abs() < 1e-4);
    assert!((moved[1] - start[1] - tool_shift[1] as f32).abs() < 1e-4);
    // The other environment held still.
    assert_eq!(sim.tool_state(1).position, tool0.position);
    // An impossible command is clamped and says so.
    let report = sim
        .command_tool(
            1,
            ToolCommand::Twist {
                linear: [50.0, 0.0, 0.0],
                angular: [0.0; 3],
            },
            control,
        )
        .unwrap();
    assert!(report.clamped() && report.accel_applied <= c.tool_limits.max_accel_m_s2 * 1.0001);
    assert!(sim
        .command_tool(
            1,
            ToolCommand::Twist {
                linear: [f32::NAN, 0.0, 0.0],
                angular: [0.0; 3]
            },
            control
        )
        .is_err());
}

/// Package and disc weight (N).
fn weight(config: &SceneConfig, spec: &EpisodeSpec) -> f32 {
    let film = config.package.film_mass_kg.unwrap();
    (film + spec.object_mass_kg) * -config.integrator.gravity_m_s2
}

/// The physical scene's four cups with the seal on and a vacuum giving each cup the holding
/// force `per_cup` (N); a 2 s rest (the package, built flat, settles in it).
fn sealed(per_cup: f32) -> SceneConfig {
    let mut c = scene([11, 13]);
    c.cups.rest_time_s = 2.0;
    c.seal.enabled = true;
    c.seal.vacuum_kpa = per_cup / (std::f32::consts::PI * c.seal.lip_radius_m.powi(2)) / 1e3;
    c
}

#[test]
fn the_cups_carry_the_package_and_a_weak_vacuum_drops_it() {
    let probe = sealed(1.0);
    let s = spec(&probe, 0.008);
    let w = weight(&probe, &s);
    // Strong enough: at rest the four cups together carry the package's weight, and hold.
    let c = sealed(0.8 * w);
    let mut sim = Simulator::new(Arc::new(Model::new(&c).unwrap()), vec![s.clone()]).unwrap();
    sim.step(seconds(&sim, 3.0));
    assert!(sim.seal_events().is_empty(), "{:?}", sim.seal_events());
    let mut loads = [CupLoad::default(); 4];
    sim.read_cup_loads(&mut loads).unwrap();
    let total: f32 = loads.iter().map(|l| l.normal_n).sum();
    assert!(
        (total - w).abs() < 0.05 * w,
        "{loads:?}: {total} N vs {w} N"
    );
    assert!(loads.iter().all(|l| l.attached && l.utilisation < 1.0));
    // Four cups of 0.15 W cannot: a cup lets go (pulled off, or slid as its clamping force
    // vanishes), the others follow, and the package is dropped.
    let c = sealed(0.15 * w);
    let mut sim = Simulator::new(Arc::new(Model::new(&c).unwrap()), vec![s]).unwrap();
    sim.step(seconds(&sim, 3.0));
    let events = sim.seal_events();
    assert!(!events.is_empty());
    for e in events.iter().filter(|e| e.kind != SealEventKind::Dropped) {
        assert!(
            matches!(e.kind, SealEventKind::PulledOff | SealEventKind::Slid),
            "{e:?}"
        );
        assert!(e.time >= 2.0, "failed during the rest: {e:?}");
        let l = e.load;
        let limit = l.normal_n.max(l.shear_n / 0.5 + l.normal_n);
        assert!(limit >= l.capacity_n, "{e:?}");
    }
}

#[test]
fn each_environment_seals_with_its_own_vacuum() {
    let probe = sealed(1.0);
    let s = spec(&probe, 0.008);
    let w = weight(&probe, &s);
    // The scene's vacuum holds the package (see above); 0.15 / 0.8 of it does not.
    let c = sealed(0.8 * w);
    let scene_kpa = c.seal.vacuum_kpa;
    let with = |vacuum_kpa| EpisodeSpec {
        vacuum_kpa,
        ..s.clone()
    };
    let specs = vec![
        with(None),
        with(Some(scene_kpa * 0.15 / 0.8)),
        with(Some(scene_kpa)),
        with(Some(2.0 * scene_kpa)),
    ];
    let mut sim = Simulator::new(Arc::new(Model::new(&c).unwrap()), specs).unwrap();
    sim.step(seconds(&sim, 3.0));
    let failed: std::collections::BTreeSet<usize> =
        sim.seal_events().iter().map(|e| e.env).collect();
    assert_eq!(
        failed.into_iter().collect::<Vec<_>>(),
        [1],
        "{:?}",
        sim.seal_events()
    );
    let mut states = vec![EnvObservation::default(); 4];
    sim.read_states(&mut states).unwrap();
    assert_eq!(states[1].cups_attached, 0, "{:?}", states[1]);
    // `None` is the scene's vacuum with the very same arithmetic: bit for bit.
    assert_eq!(bits(&sim, 0), bits(&sim, 2));
    let mut loads = vec![CupLoad::default(); 16];
    sim.read_cup_loads(&mut loads).unwrap();
    assert_eq!(&loads[..4], &loads[8..12]);
    // Twice the vacuum, twice the capacity per sealed area, and half the utilisation.
    for k in 0..4 {
        let (scene, double) = (loads[k], loads[12 + k]);
        let per_area = |l: CupLoad| l.capacity_n / l.sealed_fraction;
        assert!(
            (per_area(double) / per_area(scene) - 2.0).abs() < 1e-5,
            "{scene:?} {double:?}"
        );
        assert!(double.attached && double.utilisation < 0.6 * scene.utilisation);
    }
}

#[test]
fn cups_too_far_or_over_a_fold_do_not_seal_and_the_dropped_package_falls_freely() {
    let mut c = scene([11, 13]);
    c.seal.enabled = true;
    c.cups.rest_time_s = 0.0;
    c.contact.ground_ke = 0.0;
    let model = Arc::new(Model::new(&c).unwrap());
    // 5 cm above the film: beyond max_gap_m (2 cm) for every cup.
    let mut far = Simulator::new(model.clone(), vec![spec(&c, 0.05)]).unwrap();
    let events = far.seal_events().to_vec();
    assert_eq!(events.len(), c.cups.angles_deg.len() + 1, "{events:?}");
    for e in &events[..events.len() - 1] {
        assert!(matches!(e.kind, SealEventKind::NotSealed(NoSealReason::Gap(g)) if g > 0.04));
    }
    assert_eq!(events.last().unwrap().kind, SealEventKind::Dropped);
    // Nothing holds it: the package falls as g says (no air drag in the model).
    let mean_y = |sim: &Simulator| {
        let x = sim.particle_positions(0);
        let n = sim.model().num_package;
        x[..n].iter().map(|p| p[1] as f64).sum::<f64>() / n as f64
    };
    let y0 = mean_y(&far);
    far.step(seconds(&far, 0.2));
    let fall = y0 - mean_y(&far);
    let expected = 0.5 * 9.81 * 0.2f64.powi(2);
    assert!(
        (fall - expected).abs() < 0.01 * expected,
        "fell {fall} m, expected {expected}"
    );

    // Close enough, but the film under the cups is creased into a V: no cup seals on a fold.
    let mut folded = Simulator::new(model.clone(), vec![spec(&c, 0.008)]).unwrap();
    assert!(
        folded.seal_events().is_empty(),
        "{:?}",
        folded.seal_events()
    );
    let mut x = folded.particle_positions(0);
    let centre_x = c.package.size_m[1] / 2.0;
    for p in &mut x[..model.num_package] {
        p[1] -= 0.6 * (p[0] - centre_x).abs();
    }
    folded.set_particle_positions(0, &x).unwrap();
    folded.attach_cups(0).unwrap();
    let reasons: Vec<_> = folded.seal_events().iter().map(|e| e.kind).collect();
    assert!(
        reasons.iter().any(|k| matches!(
            k,
            SealEventKind::NotSealed(NoSealReason::Fold(_) | NoSealReason::Tilt(_))
        )),
        "{reasons:?}"
    );
}

#[test]
fn randomised_specs_stay_in_range_and_repeat_with_the_seed() {
    let c = scene([6, 7]);
    let base = spec(&c, 0.01);
    let r = Randomization {
        object_mass_kg: Some([0.25, 0.75]),
        disc_mass_scale: Some([0.9, 1.1]),
        object_offset_m: 0.03,
        object_tilt_deg: 10.0,
        package_yaw_deg: [-20.0, 20.0],
        param_scale: [
            ("k_tri_e".to_string(), [0.5, 2.0]),
            ("mu_con".to_string(), [0.8, 1.25]),
        ]
        .into_iter()
        .collect(),
        ..Randomization::default()
    };
    r.validate("test").unwrap();
    let draw = |seed| {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..200)
            .map(|_| r.apply(&base, &mut rng))
            .collect::<Vec<_>>()
    };
    let specs = draw(5);
    assert_eq!(specs, draw(5));
    assert_ne!(specs, draw(6));
    for s in &specs {
        assert!((0.25..=0.75).contains(&s.object_mass_kg));
        assert!((0.9..=1.1).contains(&s.disc_mass_scale.unwrap()));
        let dx = s.placement.disc_position[0] - base.placement.disc_position[0];
        let dz = s.placement.disc_position[2] - base.placement.disc_position[2];
        assert!(dx.hypot(dz) <= 0.03 + 1e-6);
        assert!(s.placement.package_yaw_rad.abs() <= 20f32.to_radians() + 1e-6);
        let tilt = 2.0 * s.placement.disc_orientation[3].clamp(-1.0, 1.0).acos();
        assert!(tilt <= 10f32.to_radians() + 1e-5);
        let scale = s.params.k_tri_e / base.params.k_tri_e;
        assert!((0.5 - 1e-6..=2.0 + 1e-6).contains(&scale));
        assert!((0.8 - 1e-6..=1.25 + 1e-6).contains(&(s.params.mu_con / base.params.mu_con)));
    }
    // The draws spread over their ranges.
    let masses: Vec<f32> = specs.iter().map(|s| s.object_mass_kg).collect();
    assert!(masses.iter().any(|&m| m < 0.35) && masses.iter().any(|&m| m > 0.65));
    // Bad names and ranges are refused with the key.
    let mut bad = r.clone();
    bad.param_scale.insert("k_bogus".into(), [1.0, 2.0]);
    assert!(bad
        .validate("r.toml")
        .unwrap_err()
        .to_string()
        .contains("param_scale.k_bogus"));
    let mut bad = r.clone();
    bad.object_mass_kg = Some([0.7, 0.2]);
    assert!(bad
        .validate("r.toml")
        .unwrap_err()
        .to_string()
        .contains("object_mass_kg"));
}

#[test]
fn a_randomised_batch_settles_with_every_disc_inside_and_is_yawed_as_asked() {
    let mut c = scene([11, 13]);
    c.seal.enabled = true;
    let model = Arc::new(Model::new(&c).unwrap());
    let mut yawed = spec(&c, 0.008);
    yawed.placement.package_yaw_rad = std::f32::consts::FRAC_PI_2;
    let straight = spec(&c, 0.008);
    let sim = Simulator::new(model.clone(), vec![straight, yawed]).unwrap();
    // A quarter turn about the cup point swaps the package's long side from x to z.
    let extent = |env: usize, k: usize| {
        let x = sim.particle_positions(env);
        let v = x[..model.num_package].iter().map(|p| p[k]);
        v.clone().fold(f32::MIN, f32::max) - v.fold(f32::MAX, f32::min)
    };
    assert!((extent(0, 0) - c.package.size_m[1]).abs() < 1e-4);
    assert!((extent(1, 2) - c.package.size_m[1]).abs() < 1e-4);
    // The physical scene's own 16 x 19 grid: on 11 x 13 a heavy disc can fall through the coarse
    // lower sheet (the simulator then reports it, see the next test).
    let c = sealed_default_grid();
    let model = Arc::new(Model::new(&c).unwrap());
    let mut sim = Simulator::new(model, varied(&c, 9, 8)).unwrap();
    sim.step(seconds(&sim, 1.2));
    assert!(sim.health_events().is_empty(), "{:?}", sim.health_events());
    assert!(sim.seal_events().is_empty(), "{:?}", sim.seal_events());
    let mut states = vec![EnvObservation::default(); 9];
    sim.read_states(&mut states).unwrap();
    for s in &states {
        assert_eq!(s.cups_attached, 4);
        assert!(!s.frozen);
        // The disc hangs below the tool, in the tool frame too (tool level: frames agree).
        assert!(s.disc_in_tool.position[1] < -0.005, "{s:?}");
    }
}

fn sealed_default_grid() -> SceneConfig {
    let mut c = SceneConfig::preset("physical").unwrap();
    c.seal.enabled = true;
    c
}

#[test]
fn an_object_that_leaves_the_package_is_a_health_event() {
    let c = scene([6, 7]);
    let model = Arc::new(Model::new(&c).unwrap());
    let mut outside = spec(&c, 0.01);
    outside.placement.disc_position[1] -= 0.2;
    let mut sim = Simulator::new(model, vec![spec(&c, 0.01), outside]).unwrap();
    sim.step(c.health.check_every as u64);
    let events = sim.health_events();
    assert_eq!(events.len(), 1, "{events:?}");
    assert_eq!(
        (events[0].env, events[0].reason),
        (1, HealthReason::ObjectOutside)
    );
    assert!(sim.is_frozen(1) && !sim.is_frozen(0));
}

#[test]
fn getters_check_buffer_sizes_and_indices() {
    let c = scene([6, 7]);
    let model = Arc::new(Model::new(&c).unwrap());
    let mut sim = Simulator::new(model, vec![spec(&c, 0.01); 10]).unwrap();
    let mut states = vec![EnvObservation::default(); 9];
    assert!(sim.read_states(&mut states).is_err());
    let mut loads = vec![CupLoad::default(); 10 * 4 - 1];
    assert!(sim.read_cup_loads(&mut loads).is_err());
    assert!(sim.reset_env(10, spec(&c, 0.01)).is_err());
    assert!(sim
        .command_tool(
            15,
            ToolCommand::Twist {
                linear: [0.0; 3],
                angular: [0.0; 3]
            },
            0.1
        )
        .is_err());
    let disc = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| sim.disc(15)));
    let message = disc.unwrap_err();
    let message = message.downcast_ref::<String>().unwrap();
    assert!(
        message.contains("environment 15 out of range (batch of 10)"),
        "{message}"
    );
}
