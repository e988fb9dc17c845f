//! Helpers shared by the end-to-end bad-input tables.

use std::path::{Path, PathBuf};

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
