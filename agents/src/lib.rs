//! PPO in burn, laid out like RSL-RL: [`modules`] (actor-critic, distributions, normalisers),
//! [`storage`] (rollouts and GAE), [`algorithms`] (the PPO update), [`runners`] (training loop,
//! checkpoints, evaluation); plus [`export`] (ONNX) and [`bench`] (throughput figures).

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
pub use runners::{evaluate_run, load_policy_graph, EvalSummary, TrainSummary, Trainer};
