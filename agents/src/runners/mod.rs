//! The training loop (rollouts, updates, logging), checkpoints and trained policies.

mod checkpoint;
mod inputs;
mod on_policy;
mod policy;
mod tensorboard;

pub use checkpoint::{
    clean_leftovers, latest_checkpoint, run_config_path, run_file_kind, CONFIG_FILE, POLICY_FILE,
};
pub(crate) use inputs::Fnv;
pub use inputs::{changed_inputs, fingerprint, record_inputs, INPUTS_FILE};
pub use on_policy::{TrainSummary, Trainer, UpdateLog, UpdateTiming};
pub use policy::{evaluation_memory_bytes, EvalSummary, TrainedPolicy};
pub use tensorboard::{read_scalars, EventWriter, EventsPosition, ScalarEvent};

#[cfg(test)]
mod tests;
