//! Tests of the task registry and of the split of training configurations, and short trainings
//! on the transport task.

use std::path::{Path, PathBuf};

use rlpkg_agents::runners::TrainedPolicy;

use super::*;

/// The repository's root folder.
fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The shipped `configs/train/cartpole.toml`.
fn cartpole_text() -> String {
    std::fs::read_to_string(root().join("configs/train/cartpole.toml")).unwrap()
}

/// `configs/train/transport.toml` with the scene and recordings found from the repository.
fn transport_text() -> String {
    let root = root().display().to_string();
    std::fs::read_to_string(format!("{root}/configs/train/transport.toml"))
        .unwrap()
        .replace("scene = \"configs/", &format!("scene = \"{root}/configs/"))
        .replace(
            "recordings = \"data/deformable-sim-real\"",
            &format!("recordings = \"{root}/data/deformable-sim-real\""),
        )
}

fn parse(text: &str) -> Result<Training, AgentError> {
    Training::parse(text.to_string(), Path::new("cfg.toml"))
}

#[test]
fn the_run_env_must_name_a_task() {
    let err = parse(&cartpole_text().replace("env = \"CartPole-v1\"", "env = \"Cartpole\""))
        .err()
        .unwrap();
    let message = err.to_string();
    assert!(matches!(err, AgentError::ConfigValue { .. }), "{message}");
    assert!(
        message.starts_with("cfg.toml:")
            && message.contains("run.env")
            && message.contains("Pendulum-v1"),
        "{message}"
    );
}

#[test]
fn learner_sections_and_task_table_are_split_and_checked() {
    let training = parse(&cartpole_text()).unwrap();
    assert!(matches!(training.task, Task::CartPole));
    assert_eq!(training.config.source, "cfg.toml");
    assert_eq!(training.spec.id, "CartPole-v1");
    // An unknown key in a learner's section names the key and its line.
    let err = parse(&cartpole_text().replace("gamma = 0.99", "gamma = 0.99\ngama = 0.9"))
        .err()
        .unwrap()
        .to_string();
    assert!(err.contains("gama") && err.contains("line "), "{err}");

    let text = transport_text();
    let training = parse(&text).unwrap();
    assert_eq!(training.config.run.env, "Transport-v0");
    assert!(matches!(training.task, Task::Transport { .. }));
    assert!(training.spec.is_asymmetric());
    let err = parse(&text.replace("control_hz = 20.0", "control_hz = 50.0"))
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("cfg.toml") && err.contains("transport.control_hz"),
        "{err}"
    );
    // The classic-control tasks take no [transport] table; the transport task needs one.
    let stray = format!("{}\n[transport]\nscene = \"physical\"\n", cartpole_text());
    let err = parse(&stray).err().unwrap().to_string();
    assert!(err.contains("no [transport] table"), "{err}");
    let missing = text[..text.find("\n[transport]\n").unwrap()].to_string();
    let err = parse(&missing).err().unwrap().to_string();
    assert!(err.contains("[transport]"), "{err}");
}

/// A tiny `Transport-v0` run: two copies on an 11 x 13 grid, 8-step rollouts, one settled variant.
fn tiny_transport_text() -> String {
    transport_text()
        .replace("num_envs = 16", "num_envs = 2")
        .replace("total_steps = 819200", "total_steps = 48")
        .replace("checkpoint_every = 80", "checkpoint_every = 1")
        .replace("rollout_steps = 64", "rollout_steps = 8")
        .replace("minibatches = 4", "minibatches = 2")
        .replace("settled_variants = 16", "settled_variants = 1")
        .replace("settle_s = 0.5", "settle_s = 0.1")
}

#[test]
fn short_transport_training_raises_the_return() {
    // The shipped configuration's first 100 updates (102,400 steps, ~2.5 min on 2 cores): the
    // mean return of the last finished episodes climbs well above the early policy's (the full
    // run logged -14.7 after 10 updates and 4.8 after 100).
    let text = transport_text().replace("total_steps = 819200", "total_steps = 102400");
    assert!(text.contains("total_steps = 102400"));
    let mut t = parse(&text).unwrap().trainer().unwrap();
    for _ in 0..10 {
        t.run_update().unwrap();
    }
    let early = t.recent_mean_return();
    for _ in 10..100 {
        t.run_update().unwrap();
    }
    let later = t.recent_mean_return();
    assert!(later > early + 10.0, "mean return {early} -> {later}");
}

#[test]
fn transport_run_logs_reward_terms_resumes_exactly_and_reads_its_policy_without_an_env() {
    let text = tiny_transport_text();
    let dir = tempfile::tempdir().unwrap();
    let mut first = parse(&text).unwrap().trainer().unwrap();
    assert!(first.spec().is_asymmetric());
    first.create_run_dir(dir.path()).unwrap();
    first.train(dir.path(), Some(1), false).unwrap();
    let training = Training::of_run(dir.path()).unwrap();
    let read = TrainedPolicy::load(
        dir.path(),
        &training.config,
        &training.config_hash(),
        &training.spec,
    )
    .unwrap();
    assert_eq!(
        read.policy_graph(),
        TrainedPolicy::from_trainer(&first).policy_graph()
    );
    let mut resumed = training.trainer().unwrap();
    resumed.load_checkpoint(dir.path()).unwrap();
    let (a, b) = (first.run_update().unwrap(), resumed.run_update().unwrap());
    assert_eq!(a, b);
    // Every reward term is logged, and the critic reads the wider privileged group.
    for term in [
        "progress",
        "time",
        "object_motion",
        "seal",
        "jerk",
        "failure",
        "success",
    ] {
        let name = format!("reward/{term}");
        assert!(
            a.env_info.iter().any(|(n, v)| *n == name && v.is_finite()),
            "{name}"
        );
    }
    let model = &resumed.ppo.model;
    assert_eq!(model.actor_layers()[0].d_in, first.spec().observation.dim());
    assert_eq!(model.critic_layers()[0].d_in, first.spec().critic_obs_dim());
    assert!(first.spec().critic_obs_dim() > first.spec().observation.dim());
}
