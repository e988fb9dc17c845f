//! Learning algorithms.

mod grad_clip;
pub mod ppo;

pub use grad_clip::clip_global_grad_norm;
pub use ppo::{PhaseTimes, Ppo, UpdateStats};
