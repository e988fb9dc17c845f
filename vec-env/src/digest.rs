//! A digest of a rollout under a fixed, scripted action sequence: two ways of stepping an
//! environment (e.g. from Rust and through the Python bindings, or on different thread counts)
//! give the same digest exactly when they produce the same observations, rewards and flags.
//!
//! The digest is FNV-1a (64 bit) over 32-bit words: after the reset, every observation's bits;
//! after each step, every observation's bits, every reward's bits and each copy's `terminated`
//! and `truncated` as 0 or 1. A word-wise hash is easy to compute the same way elsewhere.

use crate::{EnvError, Space, SpaceKind, StepBuffers, VecEnv};

const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
const FNV_PRIME: u64 = 0x0100_0000_01b3;

/// FNV-1a over 32-bit words.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WordDigest(u64);

impl Default for WordDigest {
    fn default() -> Self {
        Self(FNV_OFFSET)
    }
}

impl WordDigest {
    /// Mixes in one word.
    pub fn word(&mut self, word: u32) {
        self.0 = (self.0 ^ word as u64).wrapping_mul(FNV_PRIME);
    }

    /// Mixes in the bits of each value.
    pub fn floats(&mut self, values: &[f32]) {
        values.iter().for_each(|v| self.word(v.to_bits()));
    }

    /// Mixes in each flag as 0 or 1.
    pub fn flags(&mut self, flags: &[bool]) {
        flags.iter().for_each(|&f| self.word(f as u32));
    }

    /// The digest so far.
    pub fn value(&self) -> u64 {
        self.0
    }
}

/// The scripted action of copy `env` at step `step` (`out`: one value per action dimension): a
/// discrete index `(31 step + 17 env) mod n`, or for a box, `low + (high - low) k / 10` with
/// `k = (31 step + 17 env + 7 d) mod 11` for dimension `d`, in f32.
pub fn scripted_action(space: &Space, step: usize, env: usize, out: &mut [f32]) {
    let base = 31 * step + 17 * env;
    match space.kind {
        SpaceKind::Discrete { n } => out[0] = (base % n) as f32,
        SpaceKind::Continuous => {
            for (d, value) in out.iter_mut().enumerate() {
                let k = ((base + 7 * d) % 11) as f32;
                *value = space.low[d] + (space.high[d] - space.low[d]) * (k / 10.0);
            }
        }
    }
}

/// Resets `env` with `seed`, steps it `steps` times with [`scripted_action`] and returns the
/// digest of what it produced.
pub fn rollout_digest(env: &mut dyn VecEnv, seed: u64, steps: usize) -> Result<u64, EnvError> {
    let (num_envs, space) = (env.num_envs(), env.spec().action.clone());
    let dim = space.dim();
    let mut out: StepBuffers = env.buffers();
    let mut digest = WordDigest::default();
    env.reset(seed, &mut out)?;
    digest.floats(&out.obs);
    let mut actions = vec![0.0; num_envs * dim];
    for step in 0..steps {
        for (i, row) in actions.chunks_exact_mut(dim).enumerate() {
            scripted_action(&space, step, i, row);
        }
        env.step(&actions, &mut out)?;
        digest.floats(&out.obs);
        digest.floats(&out.rewards);
        digest.flags(&out.terminated);
        digest.flags(&out.truncated);
    }
    Ok(digest.value())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{AutoresetMode, CartPole, Pendulum};

    fn cartpole_digest(mode: AutoresetMode, seed: u64) -> u64 {
        let mut env = CartPole::new(64);
        env.set_autoreset_mode(mode).unwrap();
        rollout_digest(&mut env, seed, 500).unwrap()
    }

    #[test]
    fn the_digest_follows_the_rollout() {
        let same = cartpole_digest(AutoresetMode::SameStep, 3);
        assert_eq!(same, cartpole_digest(AutoresetMode::SameStep, 3));
        assert_ne!(same, cartpole_digest(AutoresetMode::NextStep, 3));
        assert_ne!(same, cartpole_digest(AutoresetMode::SameStep, 4));
        let mut pendulum = Pendulum::new(4);
        let a = rollout_digest(&mut pendulum, 3, 250).unwrap();
        assert_eq!(a, rollout_digest(&mut pendulum, 3, 250).unwrap());
    }

    #[test]
    fn scripted_actions_stay_in_their_space() {
        let pendulum = Pendulum::new(1);
        let cartpole = CartPole::new(1);
        for step in 0..30 {
            for env in 0..5 {
                let mut torque = [0.0];
                scripted_action(&pendulum.spec().action, step, env, &mut torque);
                assert!((-2.0..=2.0).contains(&torque[0]));
                let mut push = [0.0];
                scripted_action(&cartpole.spec().action, step, env, &mut push);
                assert!(push[0] == 0.0 || push[0] == 1.0);
            }
        }
    }
}
