//! Networks and statistics: the actor-critic, its action distributions and the running
//! normalisers whose statistics are saved with the model.

mod actor_critic;
pub mod dense;
pub mod distributions;
mod normalizer;

pub use actor_critic::{ActorCritic, ActorOutput};
pub use normalizer::{RewardNormalizer, RunningMeanStd};
