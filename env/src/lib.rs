//! `Transport-v0`, the package transport task ([`transport`]), as a vectorised environment
//! ([`rlpkg_vec_env::VecEnv`]) on the batched package simulator, and the registry of every task
//! rlpkg builds ([`tasks`]).
//!
//! The environment interface lives in `rlpkg-vec-env`; the parts of it the task uses are
//! re-exported here.

pub mod tasks;
pub mod transport;

pub use rlpkg_vec_env::{EnvError, EnvSpec, EnvState, Space, SpaceKind, StepBuffers, VecEnv};
pub use tasks::Task;
pub use transport::{Transport, TransportConfig};

use rlpkg_vec_env::{check_action_len, env_rng, rng_from_words, rng_to_words, RNG_WORDS};
