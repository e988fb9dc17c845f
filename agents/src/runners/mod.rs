//! The training loop (rollouts, updates, logging), checkpoints and trained policies.

mod checkpoint;
mod on_policy;
mod policy;

pub use checkpoint::{latest_checkpoint, CONFIG_FILE};
pub use on_policy::{TrainSummary, Trainer, UpdateLog, UpdateTiming};
pub use policy::{evaluate_run, load_policy_graph, EvalSummary, TrainedPolicy};

#[cfg(test)]
mod tests;
