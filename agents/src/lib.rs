//! PPO in burn, laid out like RSL-RL: [`modules`] (actor-critic, distributions, normalisers),
//! [`storage`] (rollouts and GAE), [`algorithms`] (the PPO update), [`runners`] (training loop,
//! checkpoints, evaluation); plus [`export`] (ONNX) and [`bench`] (throughput figures).
//!
//! The learner knows no task: it trains on the environment it is handed (any
//! [`rlpkg_vec_env::VecEnv`]) and reads everything else from its spec.

pub mod algorithms;
mod backend;
pub mod bench;
pub mod config;
mod error;
pub mod export;
pub mod modules;
pub mod runners;
pub mod storage;

pub use backend::Backend;
pub use config::TrainConfig;
pub use error::AgentError;
pub use runners::{EvalSummary, TrainSummary, TrainedPolicy, Trainer};
