//! CartPole-v1 with Gymnasium's dynamics (Euler kinematics), constants, termination, 500-step
//! truncation and reset distribution. State is kept in f64 like Gymnasium; observations are f32.

use rand::Rng;
use rand_chacha::ChaCha8Rng;

use crate::classic::{self, ClassicCopies};
use crate::state::{pack_state, unpack_state};
use crate::{
    check_action_len, env_rng, Autoreset, AutoresetMode, EnvError, EnvSpec, EnvState, ResetCopies,
    Space, StepBuffers, VecEnv,
};

/// Gymnasium id.
pub const ID: &str = "CartPole-v1";
const GRAVITY: f64 = 9.8;
const MASS_CART: f64 = 1.0;
const MASS_POLE: f64 = 0.1;
const TOTAL_MASS: f64 = MASS_CART + MASS_POLE;
/// Half the pole's length, as in Gymnasium.
const HALF_LENGTH: f64 = 0.5;
const POLE_MASS_LENGTH: f64 = MASS_POLE * HALF_LENGTH;
const FORCE_MAG: f64 = 10.0;
const TAU: f64 = 0.02;
const THETA_THRESHOLD: f64 = 12.0 * 2.0 * std::f64::consts::PI / 360.0;
const X_THRESHOLD: f64 = 2.4;
const MAX_EPISODE_STEPS: usize = 500;
const OBS_DIM: usize = 4;

/// `E` cart-poles: push the cart left (action 0) or right (action 1) by 10 N, reward 1 per step.
pub struct CartPole {
    spec: EnvSpec,
    x: Vec<f64>,
    x_dot: Vec<f64>,
    theta: Vec<f64>,
    theta_dot: Vec<f64>,
    elapsed_steps: Vec<usize>,
    rngs: Vec<ChaCha8Rng>,
    autoreset: Autoreset,
}

impl CartPole {
    /// `num_envs` copies; call [`VecEnv::reset`] before stepping.
    pub fn new(num_envs: usize) -> Self {
        let theta_limit = (THETA_THRESHOLD * 2.0) as f32;
        let spec = EnvSpec {
            id: ID.to_string(),
            observation: Space::continuous(&[
                (
                    "cart_position",
                    "m",
                    -(X_THRESHOLD as f32) * 2.0,
                    X_THRESHOLD as f32 * 2.0,
                ),
                ("cart_velocity", "m/s", f32::MIN, f32::MAX),
                ("pole_angle", "rad", -theta_limit, theta_limit),
                ("pole_angular_velocity", "rad/s", f32::MIN, f32::MAX),
            ]),
            action: Space::discrete("push_direction", 2),
            critic_observation: None,
            max_episode_steps: MAX_EPISODE_STEPS,
        };
        Self {
            spec,
            x: vec![0.0; num_envs],
            x_dot: vec![0.0; num_envs],
            theta: vec![0.0; num_envs],
            theta_dot: vec![0.0; num_envs],
            elapsed_steps: vec![0; num_envs],
            rngs: (0..num_envs).map(|env| env_rng(0, env)).collect(),
            autoreset: Autoreset::new(num_envs),
        }
    }
}

impl VecEnv for CartPole {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn num_envs(&self) -> usize {
        self.x.len()
    }

    fn save_state(&self) -> EnvState {
        let columns: [&[f64]; 4] = [&self.x, &self.x_dot, &self.theta, &self.theta_dot];
        pack_state(&columns, &self.elapsed_steps, &self.rngs)
    }

    fn load_state(&mut self, state: &EnvState) -> Result<(), EnvError> {
        let mut columns = [
            &mut self.x,
            &mut self.x_dot,
            &mut self.theta,
            &mut self.theta_dot,
        ];
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
        if let Some(env) = actions.iter().position(|&a| a != 0.0 && a != 1.0) {
            return Err(EnvError::InvalidDiscreteAction {
                env,
                value: actions[env],
                n: 2,
            });
        }
        classic::step(self, actions, 1, out)
    }
}

impl ClassicCopies for CartPole {
    const OBS_DIM: usize = OBS_DIM;

    fn autoreset(&mut self) -> &mut Autoreset {
        &mut self.autoreset
    }

    fn reseed(&mut self, env: usize, rng: ChaCha8Rng) {
        self.rngs[env] = rng;
    }

    /// Gymnasium's reset: every state variable uniform in [-0.05, 0.05).
    fn reset_copy(&mut self, env: usize) {
        let rng = &mut self.rngs[env];
        let mut draw = || -0.05 + 0.1 * rng.random::<f64>();
        self.x[env] = draw();
        self.x_dot[env] = draw();
        self.theta[env] = draw();
        self.theta_dot[env] = draw();
        self.elapsed_steps[env] = 0;
    }

    fn step_copy(&mut self, env: usize, action: &[f32]) -> (f32, bool, bool) {
        let force = if action[0] == 1.0 {
            FORCE_MAG
        } else {
            -FORCE_MAG
        };
        let (sin_theta, cos_theta) = self.theta[env].sin_cos();
        let temp = (force
            + POLE_MASS_LENGTH * self.theta_dot[env] * self.theta_dot[env] * sin_theta)
            / TOTAL_MASS;
        let theta_acc = (GRAVITY * sin_theta - cos_theta * temp)
            / (HALF_LENGTH * (4.0 / 3.0 - MASS_POLE * cos_theta * cos_theta / TOTAL_MASS));
        let x_acc = temp - POLE_MASS_LENGTH * theta_acc * cos_theta / TOTAL_MASS;
        self.x[env] += TAU * self.x_dot[env];
        self.x_dot[env] += TAU * x_acc;
        self.theta[env] += TAU * self.theta_dot[env];
        self.theta_dot[env] += TAU * theta_acc;
        self.elapsed_steps[env] += 1;
        let terminated = self.x[env].abs() > X_THRESHOLD || self.theta[env].abs() > THETA_THRESHOLD;
        let truncated = self.elapsed_steps[env] >= MAX_EPISODE_STEPS;
        (1.0, terminated, truncated)
    }

    fn write_obs(&self, env: usize, row: &mut [f32]) {
        row[0] = self.x[env] as f32;
        row[1] = self.x_dot[env] as f32;
        row[2] = self.theta[env] as f32;
        row[3] = self.theta_dot[env] as f32;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn set_state(env: &mut CartPole, i: usize, state: [f64; 4]) {
        env.x[i] = state[0];
        env.x_dot[i] = state[1];
        env.theta[i] = state[2];
        env.theta_dot[i] = state[3];
    }

    #[test]
    fn one_step_from_rest_matches_hand_computation() {
        // From rest, pushing right: temp = 10/1.1, theta_acc = -600/41, x_acc = 400/41.
        let mut env = CartPole::new(2);
        let mut out = env.buffers();
        env.reset(0, &mut out).unwrap();
        set_state(&mut env, 0, [0.0; 4]);
        set_state(&mut env, 1, [0.0; 4]);
        env.step(&[1.0, 0.0], &mut out).unwrap();
        let expected_right = [0.0, 0.02 * 400.0 / 41.0, 0.0, -0.02 * 600.0 / 41.0];
        for (k, expected) in expected_right.iter().enumerate() {
            assert!((out.obs[k] as f64 - expected).abs() < 1e-7, "{:?}", out.obs);
            assert!(
                (out.obs[4 + k] as f64 + expected).abs() < 1e-7,
                "{:?}",
                out.obs
            );
        }
        assert_eq!(out.rewards, vec![1.0, 1.0]);
        assert_eq!(out.terminated, vec![false, false]);
    }

    #[test]
    fn tilted_pole_with_angular_velocity_matches_hand_computation() {
        // theta = 0.1, theta_dot = 0.5, push left (force = -10):
        let (theta, theta_dot) = (0.1_f64, 0.5_f64);
        let temp = (-10.0 + 0.05 * theta_dot * theta_dot * theta.sin()) / 1.1;
        let theta_acc = (9.8 * theta.sin() - theta.cos() * temp)
            / (0.5 * (4.0 / 3.0 - 0.1 * theta.cos() * theta.cos() / 1.1));
        let x_acc = temp - 0.05 * theta_acc * theta.cos() / 1.1;
        let mut env = CartPole::new(1);
        let mut out = env.buffers();
        env.reset(3, &mut out).unwrap();
        set_state(&mut env, 0, [0.3, -0.2, theta, theta_dot]);
        env.step(&[0.0], &mut out).unwrap();
        let expected = [
            0.3 + 0.02 * -0.2,
            -0.2 + 0.02 * x_acc,
            theta + 0.02 * theta_dot,
            theta_dot + 0.02 * theta_acc,
        ];
        for (k, value) in expected.iter().enumerate() {
            assert!(
                (out.obs[k] as f64 - value).abs() < 1e-7,
                "{k}: {:?} vs {expected:?}",
                out.obs
            );
        }
    }

    #[test]
    fn termination_resets_and_keeps_the_final_observation() {
        let mut env = CartPole::new(2);
        let mut out = env.buffers();
        env.reset(7, &mut out).unwrap();
        // Pole at 0.2 rad falling right at 1 rad/s crosses 12 degrees (0.2094 rad) this step.
        set_state(&mut env, 0, [0.0, 0.0, 0.2, 1.0]);
        env.step(&[1.0, 1.0], &mut out).unwrap();
        assert_eq!(out.terminated, vec![true, false]);
        assert_eq!(out.truncated, vec![false, false]);
        assert_eq!(out.rewards[0], 1.0);
        assert!(
            (out.final_obs[2] - 0.22).abs() < 1e-6,
            "{:?}",
            out.final_obs
        );
        assert!(
            out.obs[..4].iter().all(|v| v.abs() <= 0.05),
            "reset state {:?}",
            out.obs
        );
        assert_eq!(env.elapsed_steps[0], 0);
        assert_eq!(out.final_obs[4..], out.obs[4..]);
    }

    #[test]
    fn time_limit_truncates_at_500_steps() {
        let mut env = CartPole::new(1);
        let mut out = env.buffers();
        env.reset(1, &mut out).unwrap();
        env.elapsed_steps[0] = 498;
        set_state(&mut env, 0, [0.0; 4]);
        env.step(&[1.0], &mut out).unwrap();
        assert!(!out.truncated[0]);
        env.step(&[0.0], &mut out).unwrap();
        assert!(out.truncated[0] && !out.terminated[0]);
        assert_eq!(env.elapsed_steps[0], 0);
    }

    #[test]
    fn reset_is_seeded_per_env_and_rejects_bad_actions() {
        let mut a = CartPole::new(3);
        let mut b = CartPole::new(5);
        let (mut out_a, mut out_b) = (a.buffers(), b.buffers());
        a.reset(11, &mut out_a).unwrap();
        b.reset(11, &mut out_b).unwrap();
        assert_eq!(
            out_a.obs[..],
            out_b.obs[..12],
            "copy i depends only on seed + i"
        );
        assert!(out_a.obs.iter().all(|v| v.abs() <= 0.05));
        b.reset(12, &mut out_b).unwrap();
        assert_ne!(out_a.obs[..], out_b.obs[..12]);
        assert!(matches!(
            a.step(&[1.0, 0.0], &mut out_a),
            Err(EnvError::ActionLength { .. })
        ));
        assert!(matches!(
            a.step(&[1.0, 2.0, 0.0], &mut out_a),
            Err(EnvError::InvalidDiscreteAction { env: 1, .. })
        ));
    }
}
