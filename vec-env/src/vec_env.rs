//! The [`VecEnv`] trait and the buffers it fills.

use crate::{AutoresetMode, EnvError, EnvSpec, EnvState, ResetCopies, Seeding};

/// Output buffers of [`VecEnv::reset`] and [`VecEnv::step`], one row per environment copy.
#[derive(Debug, Clone, PartialEq)]
pub struct StepBuffers {
    /// Observations after the step (after auto-reset for finished copies), `[E x obs_dim]`.
    pub obs: Vec<f32>,
    /// Reward received by each copy for the step.
    pub rewards: Vec<f32>,
    /// The episode reached a terminal state (no bootstrap).
    pub terminated: Vec<bool>,
    /// The episode was cut by the time limit (bootstrap from `final_obs`).
    pub truncated: Vec<bool>,
    /// For copies with `terminated || truncated`: the observation the episode ended on,
    /// `[E x obs_dim]`; rows of copies still running hold their current observation.
    pub final_obs: Vec<f32>,
    /// The critic's observations `[E x critic_obs_dim]` when the environment has a separate
    /// critic group ([`EnvSpec::critic_observation`]); empty otherwise (the critic then sees `obs`).
    pub critic_obs: Vec<f32>,
    /// The critic's observation each finished episode ended on (as `final_obs`); empty when
    /// the environment has no critic group.
    pub final_critic_obs: Vec<f32>,
}

impl StepBuffers {
    /// Zeroed buffers for `num_envs` copies with `obs_dim` observations each.
    pub fn new(num_envs: usize, obs_dim: usize) -> Self {
        Self {
            obs: vec![0.0; num_envs * obs_dim],
            rewards: vec![0.0; num_envs],
            terminated: vec![false; num_envs],
            truncated: vec![false; num_envs],
            final_obs: vec![0.0; num_envs * obs_dim],
            critic_obs: Vec::new(),
            final_critic_obs: Vec::new(),
        }
    }

    /// Zeroed buffers for an environment whose critic sees its own `critic_obs_dim` observations.
    pub fn with_critic(num_envs: usize, obs_dim: usize, critic_obs_dim: usize) -> Self {
        Self {
            critic_obs: vec![0.0; num_envs * critic_obs_dim],
            final_critic_obs: vec![0.0; num_envs * critic_obs_dim],
            ..Self::new(num_envs, obs_dim)
        }
    }

    /// The critic's observations: [`StepBuffers::critic_obs`], or `obs` when the environment
    /// has no critic group.
    pub fn critic_input(&self) -> &[f32] {
        if self.critic_obs.is_empty() {
            &self.obs
        } else {
            &self.critic_obs
        }
    }

    /// The critic's final observations: [`StepBuffers::final_critic_obs`], or `final_obs`.
    pub fn final_critic_input(&self) -> &[f32] {
        if self.final_critic_obs.is_empty() {
            &self.final_obs
        } else {
            &self.final_critic_obs
        }
    }

    /// Whether copy `env` finished its episode in the last step.
    pub fn done(&self, env: usize) -> bool {
        self.terminated[env] || self.truncated[env]
    }
}

/// A batch of `num_envs` copies of one environment stepped in lockstep.
///
/// Copies are seeded independently (copy `i` from `seed + i`, see [`crate::env_rng`]), so results
/// do not depend on how the work is split between threads.
pub trait VecEnv: Send {
    /// Names, units and bounds of observations and actions.
    fn spec(&self) -> &EnvSpec;
    /// Number of copies `E`.
    fn num_envs(&self) -> usize;
    /// Reseeds every copy and starts new episodes; fills `out.obs` (rewards and flags cleared).
    /// An error when the episodes cannot be started (e.g. the simulator fails while preparing
    /// them).
    fn reset(&mut self, seed: u64, out: &mut StepBuffers) -> Result<(), EnvError>;
    /// Restarts the copies `copies` chooses (all, or those of a mask), reseeded as it says (copy
    /// `i` from `seed + i`, from its own seed, or continuing its stream); their rows of `out`
    /// are filled (reward 0, no flag) and the other rows are left as they are.
    fn reset_copies(&mut self, copies: ResetCopies, out: &mut StepBuffers) -> Result<(), EnvError> {
        match (copies.is_all(), copies.seeding) {
            (true, Seeding::Base(seed)) => self.reset(seed, out),
            _ => Err(EnvError::Unsupported {
                env: self.spec().id.clone(),
                what: "resetting chosen copies or seeding each copy".into(),
            }),
        }
    }
    /// What a copy whose episode ends does ([`AutoresetMode::SameStep`] unless set).
    fn autoreset_mode(&self) -> AutoresetMode {
        AutoresetMode::SameStep
    }
    /// Sets the autoreset mode; reset the environment afterwards.
    fn set_autoreset_mode(&mut self, mode: AutoresetMode) -> Result<(), EnvError> {
        match mode {
            AutoresetMode::SameStep => Ok(()),
            _ => Err(EnvError::Unsupported {
                env: self.spec().id.clone(),
                what: format!("autoreset mode {}", mode.name()),
            }),
        }
    }
    /// Applies `actions` (`[E x action_dim]`; discrete actions as integral values) and fills `out`.
    /// Copies whose episode ends restart as [`VecEnv::autoreset_mode`] says (by default at once,
    /// `out.final_obs` keeping where they ended).
    fn step(&mut self, actions: &[f32], out: &mut StepBuffers) -> Result<(), EnvError>;
    /// Everything needed to continue exactly where the environment is (state, step counters,
    /// random streams), for checkpoints.
    fn save_state(&self) -> EnvState;
    /// Restores a state written by [`VecEnv::save_state`] of an environment of the same kind and size.
    fn load_state(&mut self, state: &EnvState) -> Result<(), EnvError>;
    /// Names of the per-step values [`VecEnv::info`] reports (reward terms, episode outcomes,
    /// ...); empty for environments without any. A name says how a trainer summarises the value
    /// over a rollout ([`crate::info::InfoKind::of`]).
    fn info_names(&self) -> &[String] {
        &[]
    }
    /// Per-step values of the last step, `[E x info_names().len()]` row-major.
    fn info(&self) -> &[f32] {
        &[]
    }
    /// Counts about what the last full reset prepared, by name (e.g. randomised packages it
    /// built and how many of them it could not use), for a trainer to show; empty by default.
    fn reset_counts(&self) -> Vec<(String, usize)> {
        Vec::new()
    }
    /// Empty buffers of the right sizes for this environment (with critic buffers if the spec
    /// has a critic observation group).
    fn buffers(&self) -> StepBuffers {
        let spec = self.spec();
        match &spec.critic_observation {
            Some(critic) => {
                StepBuffers::with_critic(self.num_envs(), spec.observation.dim(), critic.dim())
            }
            None => StepBuffers::new(self.num_envs(), spec.observation.dim()),
        }
    }
}

/// Checks the action buffer length against `num_envs x action_dim`.
pub fn check_action_len(actions: &[f32], num_envs: usize, dim: usize) -> Result<(), EnvError> {
    if actions.len() != num_envs * dim {
        return Err(EnvError::ActionLength {
            expected: num_envs * dim,
            got: actions.len(),
        });
    }
    Ok(())
}
