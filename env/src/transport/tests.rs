//! Tests of the transport environment on a coarse grid with few steps.

use super::*;

/// A small `[transport]` table: coarse grid, the embedded physical scene, two settled variants.
fn test_table() -> String {
    let data = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/deformable-sim-real");
    format!(
        r#"
[transport]
scene = "physical"
grid = [11, 13]
recordings = "{data}"
paths = ["HHMHL", "HHHHM", "HHHHH"]
control_hz = 20.0
time_limit_s = 12.0
settled_variants = 2
settle_s = 0.5

[transport.limits]
max_path_speed_m_s = 0.945
max_path_accel_m_s2 = 5.2
max_tilt_offset_deg = 20.0
max_angular_speed_rad_s = 3.1
max_angular_accel_rad_s2 = 30.0
tracking_gain = 0.5

[transport.success]
position_m = 0.02
orientation_deg = 5.0
tool_speed_m_s = 0.05
object_speed_m_s = 0.05

[transport.failure]
max_object_distance_m = 0.4

[transport.reward]
progress = 10.0
time = 0.5
object_motion = 20.0
seal = 4.0
seal_threshold = 0.5
jerk = 0.01
angular_jerk = 0.002
failure = 30.0
success = 15.0

[transport.randomization]
target_tilt_deg = [30.0, 60.0]
goal_jitter_m = 0.03
start_jitter_m = 0.02

[transport.randomization.package]
object_mass_kg = [0.287, 0.595]
object_offset_m = 0.02
object_tilt_deg = 0.0
package_yaw_deg = [-10.0, 10.0]
param_scale = {{ k_tri_e = [0.8, 1.25] }}
"#
    )
}

fn config(text: &str) -> TransportConfig {
    TransportConfig::from_toml_str(text, "test.toml").unwrap()
}

fn env(text: &str, num_envs: usize) -> Transport {
    Transport::new(config(text), num_envs, "test.toml").unwrap()
}

fn column(t: &Transport, out: &StepBuffers, env: usize, name: &str, final_row: bool) -> f32 {
    let k = t
        .spec()
        .observation
        .names
        .iter()
        .position(|n| n == name)
        .unwrap();
    let dim = t.spec().observation.dim();
    let rows = if final_row { &out.final_obs } else { &out.obs };
    rows[env * dim + k]
}

fn info(t: &Transport, env: usize, name: &str) -> f32 {
    let k = t.info_names().iter().position(|n| n == name).unwrap();
    t.info()[env * t.info_names().len() + k]
}

#[test]
fn a_tilted_object_needs_a_scene_that_turns_the_disc_during_the_rest() {
    let text = test_table().replace("object_tilt_deg = 0.0", "object_tilt_deg = 20.0");
    let error = Transport::new(config(&text), 1, "test.toml").err().unwrap();
    let message = error.to_string();
    assert!(
        message.contains("test.toml")
            && message.contains("object_tilt_deg")
            && message.contains("hold_orientation"),
        "{message}"
    );
}

#[test]
fn fixed_length_arrays_with_a_wrong_length_name_the_key() {
    let text = test_table();
    for (from, to, key, found) in [
        ("grid = [11, 13]", "grid = [11, 13, 2]", "grid", 3),
        (
            "target_tilt_deg = [30.0, 60.0]",
            "target_tilt_deg = [30.0, 45.0, 60.0]",
            "randomization.target_tilt_deg",
            3,
        ),
        (
            "object_mass_kg = [0.287, 0.595]",
            "object_mass_kg = [0.287]",
            "randomization.package.object_mass_kg",
            1,
        ),
        (
            "package_yaw_deg = [-10.0, 10.0]",
            "package_yaw_deg = [-10.0, 0.0, 10.0]",
            "randomization.package.package_yaw_deg",
            3,
        ),
        (
            "k_tri_e = [0.8, 1.25]",
            "k_tri_e = [0.8, 1.0, 1.25]",
            "randomization.package.param_scale.k_tri_e",
            3,
        ),
    ] {
        assert!(text.contains(from), "{from}");
        let table: toml::Table = toml::from_str(&text.replace(from, to)).unwrap();
        let err = TransportConfig::from_table(table["transport"].as_table().unwrap(), "t.toml")
            .unwrap_err()
            .to_string();
        let expected = format!(
            "t.toml: key `transport.{key}`: invalid length {found}, expected an array of length 2"
        );
        assert!(err.starts_with(&expected), "{to}: {err}");
    }
}

#[test]
fn configuration_errors_name_the_key_and_the_expected_range() {
    let text = test_table();
    let err = TransportConfig::from_toml_str(
        &text.replace("control_hz = 20.0", "control_hz = 100.0"),
        "t.toml",
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("t.toml") && err.contains("transport.control_hz") && err.contains("[10, 30]"),
        "{err}"
    );
    // Faster than 1.5 x the high-velocity recordings' peak speed (0.945 m/s) is refused.
    let err = TransportConfig::from_toml_str(
        &text.replace("max_path_speed_m_s = 0.945", "max_path_speed_m_s = 1.2"),
        "t.toml",
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("limits.max_path_speed_m_s"), "{err}");
    let err = TransportConfig::from_toml_str(
        &text.replace("goal_jitter_m = 0.03", "goal_jiter_m = 0.03"),
        "t.toml",
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("goal_jiter_m"), "{err}");
    let err = Transport::new(config(&text.replace("\"HHHHM\"", "\"NOPE\"")), 1, "t.toml")
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("transport.paths") && err.contains("NOPE"),
        "{err}"
    );
}

#[test]
fn actor_observes_no_privileged_quantity() {
    let t = env(&test_table(), 1);
    let spec = t.spec();
    let actor = &spec.observation;
    let critic = spec.critic_observation.as_ref().unwrap();
    assert_eq!(actor.names.len(), actor.units.len());
    assert_eq!(critic.names.len(), critic.units.len());
    for name in &actor.names {
        assert!(
            !PRIVILEGED_MARKERS.iter().any(|m| name.contains(m)),
            "actor observation {name} is privileged"
        );
    }
    // The critic sees everything the actor sees, then privileged quantities only.
    assert_eq!(&critic.names[..actor.dim()], &actor.names[..]);
    let extra = &critic.names[actor.dim()..];
    assert!(!extra.is_empty());
    for name in extra {
        assert!(
            PRIVILEGED_MARKERS.iter().any(|m| name.contains(m)),
            "critic-only observation {name} is not marked privileged"
        );
    }
    for required in ["object_in_tool_x", "object_mass", "cup0_normal_load"] {
        assert!(extra.iter().any(|n| n == required), "{required}");
    }
    assert!(actor.names.iter().any(|n| n == "cup3_utilisation"));
    assert!(critic.units.iter().all(|u| !u.is_empty()));
}

#[test]
fn randomised_values_stay_in_range_and_follow_the_seed_on_any_thread_count() {
    let text = test_table();
    let run = |threads: usize, seed: u64| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut t = env(&text, 3);
            let mut out = t.buffers();
            t.try_reset(seed, &mut out).unwrap();
            // Every randomised package of this configuration stays sealed.
            assert_eq!(t.replaced_variants(), 0);
            let conditions: Vec<EpisodeConditions> = (0..3).map(|e| t.conditions(e)).collect();
            (conditions, out)
        })
    };
    let (conditions, out) = run(1, 7);
    for c in &conditions {
        assert!(
            (30f64.to_radians()..=60f64.to_radians()).contains(&c.target_tilt_rad),
            "{c:?}"
        );
        assert!(
            DVec3::from(c.goal_jitter_m).length() <= 0.03 + 1e-12,
            "{c:?}"
        );
        let start = DVec3::from(c.start_offset_m);
        assert!(
            start.length() <= 0.02 + 1e-6 && start.y.abs() < 1e-9,
            "{c:?}"
        );
        assert!((0.287..=0.595).contains(&c.object_mass_kg), "{c:?}");
        assert!(
            c.package_yaw_rad.abs() <= 10f32.to_radians() + 1e-6,
            "{c:?}"
        );
        assert!(c.variant < 2);
        // The path is the recording whose final tilt is nearest the target.
        let nearest = match c.target_tilt_rad.to_degrees() {
            d if d < 39.2 => "HHMHL",
            d if d < 53.9 => "HHHHM",
            _ => "HHHHH",
        };
        if (c.target_tilt_rad.to_degrees() - 39.2).abs() > 0.5
            && (c.target_tilt_rad.to_degrees() - 53.9).abs() > 0.5
        {
            assert_eq!(c.path_id, nearest, "{c:?}");
        }
    }
    assert!(conditions
        .windows(2)
        .any(|w| w[0].target_tilt_rad != w[1].target_tilt_rad));
    let (again, out_again) = run(2, 7);
    assert_eq!(conditions, again);
    assert_eq!(out, out_again, "same seed, two threads: bit-identical");
    let (other, _) = run(1, 8);
    assert_ne!(conditions, other);
}

#[test]
fn time_out_is_truncated_with_the_true_final_observation() {
    let text = test_table().replace("time_limit_s = 12.0", "time_limit_s = 0.2");
    let mut t = env(&text, 2);
    assert_eq!(t.spec().max_episode_steps, 4);
    let mut out = t.buffers();
    t.try_reset(3, &mut out).unwrap();
    // Standing still at the pick pose: nothing fails, nothing is placed.
    let actions = vec![0.0f32; 6];
    for step in 1..=4 {
        t.step(&actions, &mut out).unwrap();
        for e in 0..2 {
            assert!(!out.terminated[e], "step {step}");
            assert_eq!(out.truncated[e], step == 4, "step {step}");
        }
    }
    let dt = t.control_interval_s() as f32;
    for e in 0..2 {
        // The final row is where the episode ended; the row now holds the next episode's start.
        let ended = column(&t, &out, e, "episode_time", true);
        assert!((ended - 4.0 * dt).abs() < 1e-4, "{ended}");
        assert_eq!(column(&t, &out, e, "episode_time", false), 0.0);
        assert_eq!(info(&t, e, "episode/truncated"), 1.0);
        assert_eq!(info(&t, e, "reward/failure"), 0.0);
        assert_eq!(info(&t, e, "reward/progress"), 0.0);
        // The reward is the sum of the reported terms.
        let terms: f32 = REWARD_TERM_NAMES
            .iter()
            .map(|n| info(&t, e, &format!("reward/{n}")))
            .sum();
        assert!(
            (out.rewards[e] - terms).abs() < 1e-5,
            "{} vs {terms}",
            out.rewards[e]
        );
    }
}

#[test]
fn over_fast_episode_fails_with_a_seal_event_and_is_terminated() {
    // A weak vacuum (7 kPa: 8.8 N per cup) holds the settled package at rest; full speed with the
    // tilt offsets flipping between their bounds then loads a cup beyond its seal.
    let config = config(&test_table().replace("settled_variants = 2", "settled_variants = 1"));
    let mut scene = load_scene(&config, "test.toml").unwrap();
    scene.seal.vacuum_kpa = 7.0;
    let paths = load_paths(&config, scene.disc.hold_at_recorded_start, "test.toml").unwrap();
    let mut t = Transport::with_scene(config, scene, paths, 1).unwrap();
    let mut out = t.buffers();
    t.try_reset(5, &mut out).unwrap();
    let mut failed_at = None;
    for step in 0..60 {
        // Full speed, and the tilt offsets flipping between their bounds every step.
        let tilt = if step % 2 == 0 { 0.35 } else { -0.35 };
        t.step(&[0.945, tilt, -tilt], &mut out).unwrap();
        if out.done(0) {
            failed_at = Some(step);
            break;
        }
    }
    let step = failed_at.expect("the over-fast episode ended");
    assert!(out.terminated[0] && !out.truncated[0], "step {step}");
    assert_eq!(info(&t, 0, "episode/success"), 0.0);
    assert_eq!(info(&t, 0, "episode/failure_cup_detached"), 1.0);
    // The simulator reported the cup's failure: peeled, pulled off or slid, at full load.
    let event = t
        .seal_events()
        .iter()
        .find(|e| e.env == 0 && e.cup.is_some())
        .expect("a seal event of a cup");
    assert!(
        matches!(
            event.kind,
            SealEventKind::Peeled | SealEventKind::PulledOff | SealEventKind::Slid
        ),
        "{event:?}"
    );
    assert!(event.load.utilisation >= 1.0, "{event:?}");
    // At rest the same seal held (the package was settled and sealed), and the path speed had
    // reached its limit: the failure comes from the motion.
    assert!(step >= 3, "failed after {step} steps");
    assert_eq!(info(&t, 0, "state/path_speed_m_s"), 0.945);
    assert_eq!(info(&t, 0, "reward/failure"), -30.0);
    assert!(out.rewards[0] < -20.0, "{}", out.rewards[0]);
}

#[test]
fn saved_state_continues_bit_identically() {
    let text = test_table();
    let mut t = env(&text, 2);
    let mut out = t.buffers();
    t.try_reset(11, &mut out).unwrap();
    let actions = [0.5f32, 0.1, -0.05, 0.3, -0.1, 0.0];
    for _ in 0..3 {
        t.step(&actions, &mut out).unwrap();
    }
    let saved = t.save_state();
    let mut copy = env(&text, 2);
    copy.load_state(&saved).unwrap();
    let mut copy_out = out.clone();
    for _ in 0..4 {
        t.step(&actions, &mut out).unwrap();
        copy.step(&actions, &mut copy_out).unwrap();
        assert_eq!(out, copy_out);
        assert_eq!(t.info(), copy.info());
    }
    let mut wrong_size = env(&text, 3);
    assert!(wrong_size.load_state(&saved).is_err());
}

#[test]
fn scripted_recorded_path_places_the_package_without_a_seal_failure() {
    // One copy replaying its recording's own timing: the high-velocity recordings succeeded on
    // the real robot, so the scripted baseline at time scale 1 must place the package. On the
    // scene's own 16 x 19 grid: on 11 x 13 the heavy disc slips through the coarse sheet when
    // the tool accelerates (the simulator's health check reports it).
    let mut t = env(
        &test_table().replace("grid = [11, 13]", "grid = [16, 19]"),
        1,
    );
    let mut out = t.buffers();
    t.try_reset(2, &mut out).unwrap();
    let recorded = t.paths()[t.lanes[0].path].recorded_duration_s;
    let mut steps = 0;
    while !out.done(0) {
        let actions = t.scripted_actions(1.0);
        t.step(&actions, &mut out).unwrap();
        steps += 1;
    }
    let seconds = steps as f64 * t.control_interval_s();
    assert_eq!(
        info(&t, 0, "episode/success"),
        1.0,
        "ended after {seconds} s: {:?}",
        t.info()
    );
    assert!(out.terminated[0]);
    // Placed about when the recording was (plus the time the object needs to settle).
    assert!(
        seconds > 0.8 * recorded && seconds < recorded + 3.0,
        "{seconds} s against {recorded} s recorded"
    );
}

#[test]
fn run_episodes_reports_every_copy_once_with_its_ending_and_time() {
    // A tool held still for a 1 s time limit: every copy times out after 20 control steps, with the
    // seal loaded (the package hangs from the cups) and the object nearly still.
    let mut t = env(
        &test_table().replace("time_limit_s = 12.0", "time_limit_s = 1.0"),
        3,
    );
    let (outcomes, traces) = run_traced_episodes::<EnvError>(&mut t, 5, &[1], |t, _| {
        Ok(vec![0.0; t.num_envs() * t.spec().action.dim()])
    })
    .unwrap();
    assert_eq!(outcomes.len(), 3);
    // The traced copy: its start and each of its 20 steps; the tool held level and still.
    let trace = &traces[0];
    assert_eq!(trace.len(), 21);
    assert!((trace[20].time_s - 1.0).abs() < 1e-6);
    for p in trace {
        assert_eq!(p.path_speed_m_s, 0.0);
        assert!(p.tool_tilt_deg < 1.0 && p.tool_speed_m_s < 0.05, "{p:?}");
    }
    assert!(trace.iter().any(|p| p.peak_seal_utilisation > 0.0));
    for o in &outcomes {
        assert_eq!(o.ending, Ending::TimedOut, "{o:?}");
        assert!((o.time_s - 1.0).abs() < 1e-6, "{o:?}");
        assert!(
            o.peak_seal_utilisation > 0.0 && o.peak_seal_utilisation < 0.5,
            "{o:?}"
        );
        // The object sways a few centimetres (path length) as the package settles under the cups.
        assert!(o.object_motion_m < 0.1, "{o:?}");
    }
    let summary = OutcomeSummary::of("still", &outcomes);
    assert_eq!(summary.timed_out_pct, 100.0);
    assert_eq!(summary.time_to_place_mean_s, None);
}

#[test]
fn retired_copies_stop_while_the_others_run_on_unchanged() {
    // Copy 0 is driven over-fast on a weak seal and fails; copy 1 is held still. With finished
    // copies retired, copy 0 keeps its final observation and earns nothing from then on, and
    // copy 1 runs exactly as it does when finished copies restart.
    let text = test_table()
        .replace("settled_variants = 2", "settled_variants = 1")
        .replace("time_limit_s = 12.0", "time_limit_s = 2.0");
    let config = config(&text);
    let mut scene = load_scene(&config, "test.toml").unwrap();
    scene.seal.vacuum_kpa = 7.0;
    let paths = load_paths(&config, scene.disc.hold_at_recorded_start, "test.toml").unwrap();
    let make = || Transport::with_scene(config.clone(), scene.clone(), paths.clone(), 2).unwrap();
    let (mut retiring, mut restarting) = (make(), make());
    retiring.set_retire_finished(true);
    let (mut a, mut b) = (retiring.buffers(), restarting.buffers());
    retiring.try_reset(5, &mut a).unwrap();
    restarting.try_reset(5, &mut b).unwrap();
    let dim = retiring.spec().observation.dim();
    let mut failed: Option<(usize, Vec<f32>)> = None;
    for step in 0..40 {
        let tilt = if step % 2 == 0 { 0.35 } else { -0.35 };
        let actions = [0.945, tilt, -tilt, 0.0, 0.0, 0.0];
        retiring.step(&actions, &mut a).unwrap();
        restarting.step(&actions, &mut b).unwrap();
        assert_eq!(a.rewards[1], b.rewards[1], "step {step}");
        assert_eq!(a.done(1), b.done(1), "step {step}");
        if a.done(1) {
            assert_eq!(a.final_obs[dim..], b.final_obs[dim..], "step {step}");
        } else {
            assert_eq!(a.obs[dim..], b.obs[dim..], "step {step}");
        }
        match &failed {
            None if a.done(0) => {
                assert!(a.terminated[0] && b.terminated[0], "step {step}");
                assert!(retiring.is_retired(0) && !restarting.is_retired(0));
                // Its row holds the final observation, not a new episode's first one.
                assert_eq!(a.obs[..dim], a.final_obs[..dim]);
                assert_ne!(a.obs[..dim], b.obs[..dim]);
                failed = Some((step, a.obs[..dim].to_vec()));
            }
            Some((_, final_obs)) => {
                assert!(!a.done(0) && a.rewards[0] == 0.0, "step {step}");
                assert_eq!(&a.obs[..dim], &final_obs[..], "step {step}");
            }
            None => {}
        }
    }
    let (step, _) = failed.expect("copy 0 failed");
    assert!(step < 39, "failed at step {step}");
    // The held copy reached the time limit in both.
    assert!(a.truncated[1] && b.truncated[1]);
    // A reset brings the retired copy back.
    retiring.try_reset(5, &mut a).unwrap();
    assert!(!retiring.is_retired(0));
}

#[test]
fn recorded_timings_match_the_tilt_level_and_play_along_the_path() {
    let config = config(&test_table());
    let pick = |velocity: &str| -> Vec<String> {
        recorded_timings(&config, velocity, "test.toml")
            .unwrap()
            .into_iter()
            .map(|t| t.id)
            .collect()
    };
    // Paths HHMHL, HHHHM, HHHHH: tilt low / medium / high, masses medium / high / high.
    assert_eq!(pick("medium"), ["HHMML", "HHHMM", "HHMMH"]);
    assert_eq!(pick("high"), ["HHMHL", "HHHHM", "HHHHH"]);
    // No low-velocity recording has the high tilt: the nearest (medium) tilt stands in.
    assert_eq!(pick("low"), ["HHMLL", "HHHLM", "HHHLM"]);
    assert!(recorded_timings(&config, "fast", "test.toml").is_err());
    // The paths' own timings are the scripted baseline; a slower recording asks for less speed.
    let mut t = env(&test_table(), 3);
    let mut out = t.buffers();
    t.try_reset(2, &mut out).unwrap();
    let own = recorded_timings(&config, "high", "test.toml").unwrap();
    let low = recorded_timings(&config, "low", "test.toml").unwrap();
    let speed = |a: &[f32]| a.iter().step_by(3).sum::<f32>();
    let (mut slow_total, mut scripted_total) = (0.0, 0.0);
    for _ in 0..10 {
        let scripted = t.scripted_actions(1.0);
        assert_eq!(t.timed_actions(&own, 1.0), scripted);
        slow_total += speed(&t.timed_actions(&low, 1.0));
        scripted_total += speed(&scripted);
        t.step(&scripted, &mut out).unwrap();
    }
    assert!(
        slow_total < 0.7 * scripted_total,
        "{slow_total} vs {scripted_total}"
    );
}
