//! ONNX export of trained policies and its verification.
//!
//! - [`graph`]: [`PolicyGraph`], the plain-number policy the PPO trainer hands over, with a plain-Rust
//!   reference evaluation [`PolicyGraph::act`].
//! - [`onnx`]: [`PolicyGraph`] -> ONNX model (prost types of `tract_onnx::pb`), written atomically.
//! - [`runtime`]: loading and running ONNX policies in tract, comparing them with the reference,
//!   timing single-observation inference.
//! - [`check`]: observations and expected outputs saved next to a model for external checkers
//!   (`tests/onnx_check.py` with onnxruntime).
//! - [`random`]: seeded random policies shaped like CartPole, Pendulum and transport policies.

pub mod check;
mod error;
pub mod graph;
pub mod onnx;
pub mod random;
pub mod runtime;

pub use error::ExportError;
pub use graph::{
    ActionHead, ActionTransform, Activation, DenseLayer, ObsNormaliser, PolicyGraph, PolicyMeta,
};
pub use onnx::{to_onnx_bytes, write_onnx};
pub use runtime::{compare_with_reference, Agreement, OnnxPolicy};

/// Largest absolute difference the exported graph may show against the reference evaluation.
pub const TOLERANCE: f32 = 1e-5;

#[cfg(test)]
mod tests;
