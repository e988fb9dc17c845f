//! Vectorised environments over struct-of-arrays buffers.
//!
//! Every environment steps `E` copies in lockstep. Observations, rewards and episode flags live in
//! flat buffers ([`StepBuffers`]) so that a trainer can hand them to a network without copying.
//! Finished copies reset themselves; the observation they ended on is kept in
//! [`StepBuffers::final_obs`] so a trainer can bootstrap the value of a truncated episode.

mod cartpole;
mod pendulum;
mod spec;
pub mod transport;

pub use cartpole::CartPole;
pub use pendulum::Pendulum;
pub use spec::{EnvSpec, Space, SpaceKind};
pub use transport::{Transport, TransportConfig};

use rand_chacha::ChaCha8Rng;

/// Errors raised by environments: wrong buffer sizes, actions outside the action space, unknown ids.
#[derive(Debug, thiserror::Error)]
pub enum EnvError {
    /// The action buffer does not hold `num_envs x action_dim` values.
    #[error("expected {expected} action values (num_envs x action_dim), got {got}")]
    ActionLength {
        /// Values expected.
        expected: usize,
        /// Values received.
        got: usize,
    },
    /// A discrete action is not an integer index in `0..n`.
    #[error("environment {env}: action {value} is not a valid index in 0..{n}")]
    InvalidDiscreteAction {
        /// Index of the environment copy.
        env: usize,
        /// The offending value.
        value: f32,
        /// Number of discrete actions.
        n: usize,
    },
    /// The environment needs settings that [`make`] cannot give it (use [`make_with`]).
    #[error("environment `{0}` needs the [transport] table of its training configuration")]
    NeedsSettings(String),
    /// The environment id is not one this crate provides.
    #[error("unknown environment id `{0}` (expected one of: {known})", known = ALL_IDS.join(", "))]
    UnknownId(String),
    /// A saved state does not fit this environment.
    #[error("saved environment state does not fit {env}: {reason}")]
    StateMismatch {
        /// Environment id.
        env: String,
        /// What does not fit.
        reason: String,
    },
    /// `num_envs` must be at least one.
    #[error("num_envs must be >= 1, got {0}")]
    NoEnvs(usize),
    /// A configuration value is outside its allowed range.
    #[error("{file}: key `{key}` = {value}: expected {expected}")]
    Config {
        /// The configuration file.
        file: String,
        /// Dotted key, e.g. `transport.control_hz`.
        key: String,
        /// The value found.
        value: String,
        /// The allowed range or values.
        expected: String,
    },
    /// A configuration could not be parsed (syntax, unknown or missing key, wrong type), or a
    /// file it names could not be used.
    #[error("{file}: {message}")]
    ConfigParse {
        /// The configuration file.
        file: String,
        /// What is wrong (names the key).
        message: String,
    },
    /// The simulator rejected a call (a fault of the environment, not of the input).
    #[error("simulator: {0}")]
    Simulator(String),
    /// An action value is not a finite number.
    #[error("environment {env}: action {index} is {value}, expected a finite number")]
    NonFiniteAction {
        /// Index of the environment copy.
        env: usize,
        /// Index within the action.
        index: usize,
        /// The offending value.
        value: f32,
    },
}

/// The environment ids [`make`] accepts (they need no settings).
pub const KNOWN_IDS: &[&str] = &[cartpole::ID, pendulum::ID];

/// Every environment id [`make_with`] accepts (`Transport-v0` needs its `[transport]` table).
pub const ALL_IDS: &[&str] = &[cartpole::ID, pendulum::ID, transport::ID];

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
/// Copies are seeded independently (copy `i` from `seed + i`), so results do not depend on how
/// the work is split between threads.
pub trait VecEnv: Send {
    /// Names, units and bounds of observations and actions.
    fn spec(&self) -> &EnvSpec;
    /// Number of copies `E`.
    fn num_envs(&self) -> usize;
    /// Reseeds every copy and starts new episodes; fills `out.obs` (rewards and flags cleared).
    fn reset(&mut self, seed: u64, out: &mut StepBuffers);
    /// Applies `actions` (`[E x action_dim]`; discrete actions as integral values) and fills `out`.
    /// Copies whose episode ends are reset at once; `out.final_obs` keeps where they ended.
    fn step(&mut self, actions: &[f32], out: &mut StepBuffers) -> Result<(), EnvError>;
    /// Everything needed to continue exactly where the environment is (state, step counters,
    /// random streams), for checkpoints.
    fn save_state(&self) -> EnvState;
    /// Restores a state written by [`VecEnv::save_state`] of an environment of the same kind and size.
    fn load_state(&mut self, state: &EnvState) -> Result<(), EnvError>;
    /// Names of the per-step values [`VecEnv::info`] reports (reward terms, outcomes, ...);
    /// empty for environments without any.
    fn info_names(&self) -> &[String] {
        &[]
    }
    /// Per-step values of the last step, `[E x info_names().len()]` row-major.
    fn info(&self) -> &[f32] {
        &[]
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

/// Builds `num_envs` copies of the environment named `id` (e.g. `"CartPole-v1"`).
pub fn make(id: &str, num_envs: usize) -> Result<Box<dyn VecEnv>, EnvError> {
    if num_envs == 0 {
        return Err(EnvError::NoEnvs(num_envs));
    }
    match id {
        cartpole::ID => Ok(Box::new(CartPole::new(num_envs))),
        pendulum::ID => Ok(Box::new(Pendulum::new(num_envs))),
        transport::ID => Err(EnvError::NeedsSettings(id.to_string())),
        other => Err(EnvError::UnknownId(other.to_string())),
    }
}

/// Builds `num_envs` copies of the environment named `id` with its settings table, if it takes
/// one (`Transport-v0` takes the `[transport]` table of a training configuration); `source`
/// names the configuration file in messages.
pub fn make_with(
    id: &str,
    num_envs: usize,
    settings: Option<&toml::Table>,
    source: &str,
) -> Result<Box<dyn VecEnv>, EnvError> {
    match (id, settings) {
        (transport::ID, Some(table)) => {
            if num_envs == 0 {
                return Err(EnvError::NoEnvs(num_envs));
            }
            let config = TransportConfig::from_table(table, source)?;
            Ok(Box::new(Transport::new(config, num_envs, source)?))
        }
        (transport::ID, None) => Err(EnvError::ConfigParse {
            file: source.to_string(),
            message: format!("environment {id} needs a [transport] table"),
        }),
        (other, None) => make(other, num_envs),
        (other, Some(_)) if KNOWN_IDS.contains(&other) => Err(EnvError::ConfigParse {
            file: source.to_string(),
            message: format!("environment {other} takes no [transport] table"),
        }),
        (other, Some(_)) => Err(EnvError::UnknownId(other.to_string())),
    }
}

/// The spec of the environment [`make_with`] would build, without building it.
pub fn spec_with(
    id: &str,
    settings: Option<&toml::Table>,
    source: &str,
) -> Result<EnvSpec, EnvError> {
    match (id, settings) {
        (transport::ID, Some(table)) => {
            transport::spec_of(&TransportConfig::from_table(table, source)?, source)
        }
        _ => Ok(make_with(id, 1, settings, source)?.spec().clone()),
    }
}

/// Checks the action buffer length against `num_envs x action_dim`.
fn check_action_len(actions: &[f32], num_envs: usize, dim: usize) -> Result<(), EnvError> {
    if actions.len() != num_envs * dim {
        return Err(EnvError::ActionLength {
            expected: num_envs * dim,
            got: actions.len(),
        });
    }
    Ok(())
}

/// A snapshot of a vectorised environment as plain numbers: real-valued state and integer
/// counters (step counters and random-stream positions), in an order each environment defines.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct EnvState {
    /// Real-valued state (positions, velocities, ...).
    pub reals: Vec<f64>,
    /// Integer state (elapsed steps, random streams as [`rng_to_words`]).
    pub counters: Vec<u64>,
    /// Serialised state that is neither (e.g. simulator snapshots); empty for simple environments.
    pub bytes: Vec<u8>,
}

/// Number of words [`rng_to_words`] produces.
pub const RNG_WORDS: usize = 7;

/// A ChaCha8 stream as plain words: seed (4), stream (1), word position (2).
pub fn rng_to_words(rng: &rand_chacha::ChaCha8Rng) -> [u64; RNG_WORDS] {
    let seed = rng.get_seed();
    let word = |k: usize| u64::from_le_bytes(seed[8 * k..8 * k + 8].try_into().expect("8 bytes"));
    let pos = rng.get_word_pos();
    [
        word(0),
        word(1),
        word(2),
        word(3),
        rng.get_stream(),
        pos as u64,
        (pos >> 64) as u64,
    ]
}

/// The ChaCha8 stream written by [`rng_to_words`], at the same position.
pub fn rng_from_words(words: &[u64; RNG_WORDS]) -> rand_chacha::ChaCha8Rng {
    use rand::SeedableRng;
    let mut seed = [0u8; 32];
    for k in 0..4 {
        seed[8 * k..8 * k + 8].copy_from_slice(&words[k].to_le_bytes());
    }
    let mut rng = rand_chacha::ChaCha8Rng::from_seed(seed);
    rng.set_stream(words[4]);
    rng.set_word_pos(words[5] as u128 | ((words[6] as u128) << 64));
    rng
}

/// Packs per-copy real columns, step counters and random streams into an [`EnvState`].
fn pack_state(columns: &[&[f64]], steps: &[usize], rngs: &[rand_chacha::ChaCha8Rng]) -> EnvState {
    EnvState {
        reals: columns.iter().flat_map(|c| c.iter().copied()).collect(),
        counters: steps
            .iter()
            .map(|&s| s as u64)
            .chain(rngs.iter().flat_map(rng_to_words))
            .collect(),
        bytes: Vec::new(),
    }
}

/// Unpacks an [`EnvState`] written by [`pack_state`] into the same columns, counters and streams.
fn unpack_state(
    id: &str,
    state: &EnvState,
    columns: &mut [&mut Vec<f64>],
    steps: &mut [usize],
    rngs: &mut [rand_chacha::ChaCha8Rng],
) -> Result<(), EnvError> {
    let n = steps.len();
    if state.reals.len() != columns.len() * n || state.counters.len() != n * (1 + RNG_WORDS) {
        return Err(EnvError::StateMismatch {
            env: id.to_string(),
            reason: format!(
                "expected {} reals and {} counters for {n} copies, got {} and {}",
                columns.len() * n,
                n * (1 + RNG_WORDS),
                state.reals.len(),
                state.counters.len()
            ),
        });
    }
    for (c, column) in columns.iter_mut().enumerate() {
        column.copy_from_slice(&state.reals[c * n..(c + 1) * n]);
    }
    for (i, step) in steps.iter_mut().enumerate() {
        *step = state.counters[i] as usize;
    }
    for (i, rng) in rngs.iter_mut().enumerate() {
        let words = &state.counters[n + i * RNG_WORDS..n + (i + 1) * RNG_WORDS];
        *rng = rng_from_words(words.try_into().expect("RNG_WORDS words"));
    }
    Ok(())
}

/// The random stream of copy `env` for a reset with `seed`.
fn env_rng(seed: u64, env: usize) -> ChaCha8Rng {
    use rand::SeedableRng;
    ChaCha8Rng::seed_from_u64(seed.wrapping_add(env as u64))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn make_knows_both_classic_control_tasks() {
        assert_eq!(make("CartPole-v1", 3).unwrap().num_envs(), 3);
        assert_eq!(make("Pendulum-v1", 2).unwrap().spec().action.dim(), 1);
        let err = make("Transport-v0", 1).err().unwrap().to_string();
        assert!(err.contains("[transport] table"), "{err}");
        let err = make("MountainCar-v0", 1).err().unwrap().to_string();
        assert!(
            err.contains("MountainCar-v0") && err.contains("CartPole-v1"),
            "{err}"
        );
        assert!(make("CartPole-v1", 0).is_err());
    }

    #[test]
    fn saved_state_continues_bit_identically() {
        for id in KNOWN_IDS {
            let mut env = make(id, 3).unwrap();
            let mut out = env.buffers();
            env.reset(9, &mut out);
            let actions = vec![1.0; 3];
            for _ in 0..30 {
                env.step(&actions, &mut out).unwrap();
            }
            let saved = env.save_state();
            let mut copy = make(id, 3).unwrap();
            copy.load_state(&saved).unwrap();
            let mut copy_out = out.clone();
            for _ in 0..300 {
                env.step(&actions, &mut out).unwrap();
                copy.step(&actions, &mut copy_out).unwrap();
                assert_eq!(out, copy_out, "{id}");
            }
            let mut wrong_size = make(id, 2).unwrap();
            assert!(wrong_size.load_state(&saved).is_err());
        }
    }

    #[test]
    fn rng_words_round_trip() {
        use rand::Rng;
        let mut rng = env_rng(5, 2);
        let _: [u64; 3] = [rng.random(), rng.random(), rng.random()];
        let mut copy = rng_from_words(&rng_to_words(&rng));
        assert_eq!(rng.random::<u64>(), copy.random::<u64>());
    }
}
