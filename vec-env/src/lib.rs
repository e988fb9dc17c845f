//! The vectorised environment interface, Gymnasium-like, over struct-of-arrays buffers.
//!
//! Every environment steps `E` copies in lockstep ([`VecEnv`]). Observations, rewards and episode
//! flags live in flat buffers ([`StepBuffers`]) so that a trainer can hand them to a network
//! without copying. Finished copies reset themselves in the step their episode ends; the
//! observation they ended on is kept in [`StepBuffers::final_obs`] so a trainer can bootstrap the
//! value of a truncated episode ([`AutoresetMode`] chooses Gymnasium's other behaviours: restart
//! in the next step, or only when the caller resets chosen copies).
//!
//! [`EnvSpec`] names every observation and action with its unit and bounds; [`EnvState`] holds a
//! whole environment as plain numbers for checkpoints; [`info`] says how a trainer reads the
//! per-step values an environment reports beside the reward. [`CartPole`] and [`Pendulum`] are the
//! classic-control reference environments (Gymnasium's `CartPole-v1` and `Pendulum-v1`).

mod autoreset;
pub mod cartpole;
mod classic;
pub mod digest;
mod error;
pub mod info;
pub mod pendulum;
mod spec;
mod state;
mod vec_env;

pub use autoreset::{Autoreset, AutoresetMode, ResetCopies, Seeding};
pub use cartpole::CartPole;
pub use error::EnvError;
pub use pendulum::Pendulum;
pub use spec::{EnvSpec, Space, SpaceKind};
pub use state::{env_rng, rng_from_words, rng_to_words, EnvState, RNG_WORDS};
pub use vec_env::{check_action_len, StepBuffers, VecEnv};
