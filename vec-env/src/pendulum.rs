//! Pendulum-v1 with Gymnasium's dynamics, constants, cost, 200-step truncation and reset
//! distribution. State is kept in f64 like Gymnasium; observations are f32.

use std::f64::consts::PI;

use rand::Rng;
use rand_chacha::ChaCha8Rng;

use crate::classic::{self, ClassicCopies};
use crate::state::{pack_state, unpack_state};
use crate::{
    check_action_len, env_rng, Autoreset, AutoresetMode, EnvError, EnvSpec, EnvState, ResetCopies,
    Space, StepBuffers, VecEnv,
};

/// Gymnasium id.
pub const ID: &str = "Pendulum-v1";
const MAX_SPEED: f64 = 8.0;
const MAX_TORQUE: f64 = 2.0;
const DT: f64 = 0.05;
const GRAVITY: f64 = 10.0;
const MASS: f64 = 1.0;
const LENGTH: f64 = 1.0;
const MAX_EPISODE_STEPS: usize = 200;
const OBS_DIM: usize = 3;

/// `E` pendulums to swing up: torque in [-2, 2] N m, reward = -(angle^2 + 0.1 speed^2 + 0.001 torque^2).
pub struct Pendulum {
    spec: EnvSpec,
    theta: Vec<f64>,
    theta_dot: Vec<f64>,
    elapsed_steps: Vec<usize>,
    rngs: Vec<ChaCha8Rng>,
    autoreset: Autoreset,
}

/// Angle wrapped to [-pi, pi) with Python's modulo semantics.
fn angle_normalize(angle: f64) -> f64 {
    (angle + PI).rem_euclid(2.0 * PI) - PI
}

impl Pendulum {
    /// `num_envs` copies; call [`VecEnv::reset`] before stepping.
    pub fn new(num_envs: usize) -> Self {
        let spec = EnvSpec {
            id: ID.to_string(),
            observation: Space::continuous(&[
                ("cos_angle", "1", -1.0, 1.0),
                ("sin_angle", "1", -1.0, 1.0),
                (
                    "angular_velocity",
                    "rad/s",
                    -MAX_SPEED as f32,
                    MAX_SPEED as f32,
                ),
            ]),
            action: Space::continuous(&[("torque", "N m", -MAX_TORQUE as f32, MAX_TORQUE as f32)]),
            critic_observation: None,
            max_episode_steps: MAX_EPISODE_STEPS,
        };
        Self {
            spec,
            theta: vec![0.0; num_envs],
            theta_dot: vec![0.0; num_envs],
            elapsed_steps: vec![0; num_envs],
            rngs: (0..num_envs).map(|env| env_rng(0, env)).collect(),
            autoreset: Autoreset::new(num_envs),
        }
    }
}

impl VecEnv for Pendulum {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn num_envs(&self) -> usize {
        self.theta.len()
    }

    fn save_state(&self) -> EnvState {
        pack_state(
            &[&self.theta, &self.theta_dot],
            &self.elapsed_steps,
            &self.rngs,
        )
    }

    fn load_state(&mut self, state: &EnvState) -> Result<(), EnvError> {
        let mut columns = [&mut self.theta, &mut self.theta_dot];
        unpack_state(
            ID,
            state,
            &mut columns,
            &mut self.elapsed_steps,
            &mut self.rngs,
        )
    }

    fn reset(&mut self, seed: u64, out: &mut StepBuffers) -> Result<(), EnvError> {
        self.reset_copies(ResetCopies::all(seed), out)
    }

    fn reset_copies(&mut self, copies: ResetCopies, out: &mut StepBuffers) -> Result<(), EnvError> {
        classic::reset(self, self.num_envs(), copies, out)
    }

    fn autoreset_mode(&self) -> AutoresetMode {
        self.autoreset.mode()
    }

    fn set_autoreset_mode(&mut self, mode: AutoresetMode) -> Result<(), EnvError> {
        self.autoreset.set_mode(mode);
        Ok(())
    }

    fn step(&mut self, actions: &[f32], out: &mut StepBuffers) -> Result<(), EnvError> {
        check_action_len(actions, self.num_envs(), 1)?;
        classic::step(self, actions, 1, out)
    }
}

impl ClassicCopies for Pendulum {
    const OBS_DIM: usize = OBS_DIM;

    fn autoreset(&mut self) -> &mut Autoreset {
        &mut self.autoreset
    }

    fn reseed(&mut self, env: usize, rng: ChaCha8Rng) {
        self.rngs[env] = rng;
    }

    /// Gymnasium's reset: angle uniform in [-pi, pi), angular velocity uniform in [-1, 1).
    fn reset_copy(&mut self, env: usize) {
        let rng = &mut self.rngs[env];
        self.theta[env] = -PI + 2.0 * PI * rng.random::<f64>();
        self.theta_dot[env] = -1.0 + 2.0 * rng.random::<f64>();
        self.elapsed_steps[env] = 0;
    }

    fn step_copy(&mut self, env: usize, action: &[f32]) -> (f32, bool, bool) {
        let torque = (action[0] as f64).clamp(-MAX_TORQUE, MAX_TORQUE);
        let (theta, theta_dot) = (self.theta[env], self.theta_dot[env]);
        let cost =
            angle_normalize(theta).powi(2) + 0.1 * theta_dot * theta_dot + 0.001 * torque * torque;
        let new_theta_dot = (theta_dot
            + (3.0 * GRAVITY / (2.0 * LENGTH) * theta.sin()
                + 3.0 / (MASS * LENGTH * LENGTH) * torque)
                * DT)
            .clamp(-MAX_SPEED, MAX_SPEED);
        self.theta[env] = theta + new_theta_dot * DT;
        self.theta_dot[env] = new_theta_dot;
        self.elapsed_steps[env] += 1;
        let truncated = self.elapsed_steps[env] >= MAX_EPISODE_STEPS;
        (-cost as f32, false, truncated)
    }

    fn write_obs(&self, env: usize, row: &mut [f32]) {
        row[0] = self.theta[env].cos() as f32;
        row[1] = self.theta[env].sin() as f32;
        row[2] = self.theta_dot[env] as f32;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_computed_steps() {
        let mut env = Pendulum::new(3);
        let mut out = env.buffers();
        env.reset(0, &mut out).unwrap();
        // Upright at rest, torque 2: theta_dot = 3 * 2 * 0.05 = 0.3, theta = 0.015, cost 0.004.
        env.theta[0] = 0.0;
        env.theta_dot[0] = 0.0;
        // Horizontal, spinning at 1 rad/s, torque -1: theta_dot = 1 + (15 - 3) * 0.05 = 1.6.
        env.theta[1] = PI / 2.0;
        env.theta_dot[1] = 1.0;
        // Torque 5 is clipped to 2; speed 7.9 plus the push is clipped to 8.
        env.theta[2] = PI / 2.0 + 0.25 + 2.0 * PI;
        env.theta_dot[2] = 7.9;
        env.step(&[2.0, -1.0, 5.0], &mut out).unwrap();
        let close = |a: f32, b: f64| (a as f64 - b).abs() < 1e-6;
        assert!(
            close(out.obs[2], 0.3) && close(out.obs[1], 0.015_f64.sin()),
            "{:?}",
            out.obs
        );
        assert!(close(out.rewards[0], -0.004));
        assert!(close(out.obs[5], 1.6) && close(out.obs[3], (PI / 2.0 + 0.08).cos()));
        assert!(close(out.rewards[1], -(PI * PI / 4.0 + 0.1 + 0.001)));
        assert!(close(out.obs[8], 8.0));
        // 5pi/2 + 0.25 wraps to pi/2 + 0.25.
        let wrapped = PI / 2.0 + 0.25;
        assert!(close(
            out.rewards[2],
            -(wrapped * wrapped + 0.1 * 7.9 * 7.9 + 0.004)
        ));
        assert_eq!(out.terminated, vec![false; 3]);
    }

    #[test]
    fn truncates_after_200_steps_and_resets_within_bounds() {
        let mut env = Pendulum::new(2);
        let mut out = env.buffers();
        env.reset(5, &mut out).unwrap();
        for step in 1..=200 {
            env.step(&[0.5, -0.5], &mut out).unwrap();
            assert_eq!(out.truncated[0], step == 200);
        }
        assert_eq!(env.elapsed_steps, vec![0, 0]);
        assert!(env.theta.iter().all(|t| (-PI..PI).contains(t)));
        assert!(env.theta_dot.iter().all(|t| (-1.0..1.0).contains(t)));
        assert_ne!(out.final_obs, out.obs);
    }

    #[test]
    fn angle_normalize_matches_python_modulo() {
        assert!((angle_normalize(3.0 * PI / 2.0) + PI / 2.0).abs() < 1e-12);
        assert!((angle_normalize(-3.0 * PI / 2.0) - PI / 2.0).abs() < 1e-12);
        assert!((angle_normalize(0.3) - 0.3).abs() < 1e-12);
    }
}
