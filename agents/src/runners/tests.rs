//! Runner tests: checkpoints, determinism across thread counts, resume, and learning CartPole.

use std::path::Path;

use super::*;
use crate::config::tests::CARTPOLE_TEST;
use crate::config::TrainConfig;

fn config(text: &str) -> TrainConfig {
    TrainConfig::parse(text, Path::new("test.toml")).unwrap()
}

fn trainer(text: &str) -> Trainer {
    Trainer::new(config(text), text.to_string()).unwrap()
}

#[test]
fn checkpoint_round_trip_is_bit_identical() {
    let dir = tempfile::tempdir().unwrap();
    let mut original = trainer(CARTPOLE_TEST);
    original.create_run_dir(dir.path()).unwrap();
    original.train(dir.path(), Some(2), false).unwrap();
    let restored = Trainer::resume(dir.path()).unwrap();
    let (a, b) = (
        original.ppo.model.flat_parameters(),
        restored.ppo.model.flat_parameters(),
    );
    assert_eq!(a.len(), b.len());
    assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
    assert_eq!((restored.update, restored.global_step), (2, 512));
    assert_eq!(restored.obs_stats, original.obs_stats);
    assert_eq!(restored.reward_norm, original.reward_norm);
    assert_eq!(restored.buffers, original.buffers);
    assert_eq!(
        restored.ppo.learning_rate.to_bits(),
        original.ppo.learning_rate.to_bits()
    );
    assert_eq!(
        latest_checkpoint(dir.path()).unwrap().file_name().unwrap(),
        "update_000002"
    );
}

#[test]
fn resume_continues_exactly_like_an_uninterrupted_run() {
    let (straight_dir, split_dir) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let mut straight = trainer(CARTPOLE_TEST);
    straight.create_run_dir(straight_dir.path()).unwrap();
    let mut straight_logs = Vec::new();
    for _ in 0..4 {
        straight_logs.push(straight.run_update().unwrap());
    }

    let mut first_half = trainer(CARTPOLE_TEST);
    first_half.create_run_dir(split_dir.path()).unwrap();
    first_half.train(split_dir.path(), Some(2), false).unwrap();
    drop(first_half);
    let mut resumed = Trainer::resume(split_dir.path()).unwrap();
    let resumed_logs: Vec<UpdateLog> = (0..2).map(|_| resumed.run_update().unwrap()).collect();

    assert_eq!(resumed_logs, straight_logs[2..]);
    let (a, b) = (
        straight.ppo.model.flat_parameters(),
        resumed.ppo.model.flat_parameters(),
    );
    assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
}

#[test]
fn same_seed_same_first_updates_on_one_and_two_threads() {
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut t = trainer(CARTPOLE_TEST);
            let logs: Vec<UpdateLog> = (0..2).map(|_| t.run_update().unwrap()).collect();
            (logs, t.ppo.model.flat_parameters())
        })
    };
    let (logs_1, params_1) = run(1);
    let (logs_2, params_2) = run(2);
    assert_eq!(logs_1, logs_2);
    assert!(params_1
        .iter()
        .zip(&params_2)
        .all(|(x, y)| x.to_bits() == y.to_bits()));
    // A different seed gives a different run.
    let mut other = trainer(&CARTPOLE_TEST.replace("seed = 1", "seed = 2"));
    let other_log = other.run_update().unwrap();
    assert_ne!(other_log.stats, logs_1[0].stats);
}

#[test]
fn burn_policy_and_policy_graph_act_alike() {
    for text in [
        CARTPOLE_TEST.to_string(),
        CARTPOLE_TEST
            .replace("CartPole-v1", "Pendulum-v1")
            .replace("\"clip\"", "\"tanh_scale\""),
    ] {
        let mut t = trainer(&text);
        t.run_update().unwrap();
        let policy = TrainedPolicy::from_trainer(&t);
        let graph = policy.policy_graph();
        let dim = t.spec().observation.dim();
        let obs: Vec<f32> = (0..64 * dim)
            .map(|k| ((k * 37 % 101) as f32 / 50.0) - 1.0)
            .collect();
        let (burn_actions, graph_actions) = (policy.act(&obs, 64), graph.act(&obs, 64));
        assert_eq!(burn_actions.len(), 64 * t.spec().action.dim());
        for (a, b) in burn_actions.iter().zip(&graph_actions) {
            assert!((a - b).abs() < 1e-5, "{a} vs {b}");
        }
        graph.validate().unwrap();
    }
}

#[test]
fn bad_run_folders_are_reported() {
    let dir = tempfile::tempdir().unwrap();
    let err = Trainer::resume(dir.path()).err().unwrap();
    assert!(
        err.is_input_error() && err.to_string().contains("not a run folder"),
        "{err}"
    );
    let mut t = trainer(CARTPOLE_TEST);
    t.create_run_dir(dir.path()).unwrap();
    assert!(t
        .create_run_dir(dir.path())
        .unwrap_err()
        .to_string()
        .contains("already holds a run"));
    let err = Trainer::resume(dir.path()).err().unwrap();
    assert!(err.to_string().contains("no checkpoint"), "{err}");
    t.train(dir.path(), Some(1), false).unwrap();
    std::fs::write(
        dir.path().join("config.toml"),
        CARTPOLE_TEST.replace("seed = 1", "seed = 5"),
    )
    .unwrap();
    let err = Trainer::resume(dir.path()).err().unwrap();
    assert!(
        err.to_string().contains("differs from the configuration"),
        "{err}"
    );
}

#[test]
fn short_cartpole_training_beats_random_play() {
    // Random play lasts ~22 steps on average; this run reaches well above that in seconds.
    let text = CARTPOLE_TEST
        .replace("num_envs = 4", "num_envs = 8")
        .replace("total_steps = 2048", "total_steps = 40960")
        .replace("rollout_steps = 64", "rollout_steps = 128")
        .replace("epochs = 2", "epochs = 4")
        .replace("learning_rate = 2.5e-3", "learning_rate = 1e-3")
        .replace("rewards = true", "rewards = false");
    let dir = tempfile::tempdir().unwrap();
    let mut t = trainer(&text);
    t.create_run_dir(dir.path()).unwrap();
    t.train(dir.path(), None, false).unwrap();
    let eval = evaluate_run(dir.path(), 20, 1000).unwrap();
    assert!(
        eval.mean_return > 100.0,
        "deterministic mean return {}",
        eval.mean_return
    );
}

#[test]
fn update_timing_splits_rollout_environment_and_update_phases() {
    let mut t = trainer(CARTPOLE_TEST);
    t.run_update().unwrap();
    let timing = t.timing;
    assert!(timing.rollout > 0.0 && timing.update > 0.0, "{timing:?}");
    assert!(
        timing.env_step > 0.0 && timing.env_step < timing.rollout,
        "{timing:?}"
    );
    let phases = timing.phases;
    assert!(
        phases.forward > 0.0 && phases.backward > 0.0 && phases.optimiser > 0.0,
        "{phases:?}"
    );
    assert!(phases.total() <= timing.update, "{timing:?}");
}

/// Event files of a run folder, in name order (TensorBoard's reading order).
fn event_files(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.to_string_lossy().contains("tfevents"))
        .collect();
    files.sort();
    files
}

#[test]
fn resume_after_a_lost_checkpoint_logs_each_update_once() {
    let dir = tempfile::tempdir().unwrap();
    let mut first = trainer(CARTPOLE_TEST);
    first.create_run_dir(dir.path()).unwrap();
    first.train(dir.path(), Some(3), false).unwrap();
    drop(first);
    // As if killed after update 3 was logged but before its checkpoint was named in `latest`.
    std::fs::write(dir.path().join("checkpoints/latest"), "update_000002").unwrap();
    let logged_before = read_scalars(&event_files(dir.path())[0]).unwrap();
    assert!(logged_before.iter().any(|e| e.step == 768));

    let mut resumed = Trainer::resume(dir.path()).unwrap();
    assert_eq!(resumed.update, 2);
    resumed.train(dir.path(), Some(4), false).unwrap();
    let files = event_files(dir.path());
    assert_eq!(files.len(), 1, "the resumed run continues the same file");
    let events = read_scalars(&files[0]).unwrap();
    let steps: Vec<i64> = events
        .iter()
        .filter(|e| e.tag == "losses/value_loss")
        .map(|e| e.step)
        .collect();
    assert_eq!(steps, [256, 512, 768, 1024]);
    // The records of the first update 3 were cut, not kept beside the new ones.
    let sps = events.iter().filter(|e| e.tag == "charts/SPS").count();
    assert_eq!(sps, 4);
}
