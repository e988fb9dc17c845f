//! Helpers shared by the end-to-end tests. Each test binary compiles this module and uses a
//! part of it, hence the allowance for unused items.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A CartPole training config of 4 updates with both normalisers (a run in seconds).
pub const TINY_CARTPOLE: &str = r#"
[run]
env = "CartPole-v1"
num_envs = 4
seed = 3
total_steps = 1024
checkpoint_every = 1

[ppo]
rollout_steps = 64
epochs = 1
minibatches = 2
gamma = 0.99
gae_lambda = 0.95
clip_ratio = 0.2
clip_value_loss = true
value_coef = 0.5
entropy_coef = 0.01
max_grad_norm = 0.5
learning_rate = 1e-3
lr_schedule = "linear"
desired_kl = 0.01
normalize_advantages = true
adam_epsilon = 1e-5

[policy]
actor_hidden = [16, 16]
critic_hidden = [16, 16]
activation = "tanh"
init_log_std = 0.0
action_transform = "clip"

[normalization]
observations = true
rewards = true
clip_obs = 10.0
clip_reward = 10.0
epsilon = 1e-8
"#;

/// The repository (the binary crate's folder).
pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Owned command-line arguments.
pub fn args(list: &[&str]) -> Vec<String> {
    list.iter().map(|s| s.to_string()).collect()
}

/// Copies the folder `from` to `to`, recursively.
pub fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), &target).unwrap();
        }
    }
}

/// Replaces `from` by `to` in the file at `path`, which must contain it.
pub fn edit(path: &Path, from: &str, to: &str) {
    let text = std::fs::read_to_string(path).unwrap();
    assert!(text.contains(from), "{} lacks {from}", path.display());
    std::fs::write(path, text.replace(from, to)).unwrap();
}

/// Runs the binary with `args` in `dir`, with `RAYON_NUM_THREADS=threads` when given.
pub fn rlpkg_in(args: &[&str], dir: &Path, threads: Option<&str>) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_rlpkg"));
    command.args(args).current_dir(dir);
    if let Some(threads) = threads {
        command.env("RAYON_NUM_THREADS", threads);
    }
    command.output().expect("rlpkg runs")
}

/// Standard output of a run that must succeed (else the test fails showing both streams).
pub fn ok(output: &Output) -> String {
    assert!(
        output.status.success(),
        "exit {:?}\nstdout: {}\nstderr: {}",
        output.status.code(),
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8(output.stdout.clone()).unwrap()
}

/// The shipped training config `configs/train/<name>` (merged with the files it extends), shrunk
/// for a test: paths made absolute, 2 copies, rollouts of 8 steps in 2 minibatches, `total_steps`
/// steps, episodes of `time_limit_s`, one settled variant settled for 0.1 s.
pub fn tiny_training(name: &str, total_steps: u64, time_limit_s: &str) -> String {
    let root = env!("CARGO_MANIFEST_DIR");
    let path = PathBuf::from(format!("{root}/configs/train/{name}"));
    let text = rlpkg_toml_input::read_composed(&path)
        .unwrap()
        .text
        .replace("scene = \"configs/", &format!("scene = \"{root}/configs/"))
        .replace(
            "recordings = \"data/",
            &format!("recordings = \"{root}/data/"),
        )
        .replace("num_envs = 16", "num_envs = 2")
        .replace(
            "total_steps = 819200",
            &format!("total_steps = {total_steps}"),
        )
        .replace("rollout_steps = 64", "rollout_steps = 8")
        .replace("minibatches = 4", "minibatches = 2")
        .replace(
            "time_limit_s = 12.0",
            &format!("time_limit_s = {time_limit_s}"),
        )
        .replace("settled_variants = 16 ", "settled_variants = 1 ")
        .replace("settled_variants = 128 ", "settled_variants = 1 ")
        .replace("settled_variants = 16\n", "settled_variants = 1\n")
        .replace("settled_variants = 128\n", "settled_variants = 1\n")
        .replace("settle_s = 0.5", "settle_s = 0.1");
    for expected in [
        format!("total_steps = {total_steps}"),
        format!("time_limit_s = {time_limit_s}"),
        "num_envs = 2".to_string(),
        "settled_variants = 1".to_string(),
    ] {
        assert!(
            text.contains(&expected),
            "{name}: no `{expected}` after shrinking"
        );
    }
    text
}
