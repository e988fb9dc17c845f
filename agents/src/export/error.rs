//! Errors of the ONNX exporter and runtime.

use std::path::PathBuf;

/// Everything that can go wrong while exporting, loading or checking an ONNX policy.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The [`PolicyGraph`](super::PolicyGraph) does not describe a consistent network.
    #[error("invalid policy graph: {0}")]
    InvalidGraph(String),
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file involved.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A file is not a protobuf-encoded ONNX model.
    #[error("{path}: not an ONNX model ({reason})")]
    NotOnnx {
        /// The file involved.
        path: PathBuf,
        /// What the decoder reported.
        reason: String,
    },
    /// A weight (an initializer or a constant of the graph) is NaN or infinite.
    #[error("{path}: value {index} of tensor `{tensor}` is {value}: expected finite weights")]
    NonFinite {
        /// The file involved.
        path: PathBuf,
        /// The initializer or constant.
        tensor: String,
        /// Index of the first non-finite value.
        index: usize,
        /// That value.
        value: f32,
    },
    /// A metadata entry written by `rlpkg export` is missing or malformed.
    #[error("{path}: metadata key `{key}`: expected {expected}")]
    Metadata {
        /// The file involved.
        path: PathBuf,
        /// The metadata key.
        key: String,
        /// What the key should hold.
        expected: String,
    },
    /// tract could not load or run the model.
    #[error("{path}: tract: {reason}")]
    Runtime {
        /// The file involved (`<memory>` for in-memory bytes).
        path: PathBuf,
        /// tract's error chain.
        reason: String,
    },
    /// The caller passed observations of the wrong shape.
    #[error("observations: expected {expected} values ({rows} rows of {obs_dim}), got {got}")]
    ObsShape {
        /// Rows requested.
        rows: usize,
        /// Observation width of the policy.
        obs_dim: usize,
        /// `rows * obs_dim`.
        expected: usize,
        /// Values given.
        got: usize,
    },
    /// Two evaluations of the same policy disagree by more than the tolerance.
    #[error(
        "{what}: max abs difference {max_abs_diff:e} exceeds tolerance {tolerance:e} (row {row})"
    )]
    Mismatch {
        /// Which output disagrees (`action`, `logits`, `value`).
        what: String,
        /// Largest absolute difference found.
        max_abs_diff: f32,
        /// Allowed difference.
        tolerance: f32,
        /// Row where the largest difference occurred.
        row: usize,
    },
    /// The environment named in the policy's metadata could not be built or stepped.
    #[error("environment: {0}")]
    Env(#[from] rlpkg_vec_env::EnvError),
}
