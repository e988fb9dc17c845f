//! Observations and the outputs the reference evaluation expects for them, saved next to an ONNX
//! file (`policy.onnx` -> `policy.check.json`) so an independent runtime (onnxruntime in
//! `tests/onnx_check.py`) can verify the file.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::graph::{ActionHead, PolicyGraph};
use super::onnx::write_atomically;
use super::ExportError;

/// Row-major observations and expected outputs; JSON numbers are shortest round-trip f32s.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CheckData {
    /// Number of observations.
    pub rows: usize,
    /// Observation width.
    pub obs_dim: usize,
    /// Action width (1 for categorical heads).
    pub action_dim: usize,
    /// `[rows, obs_dim]` observations.
    pub obs: Vec<f32>,
    /// `[rows, action_dim]` expected actions (categorical: the index).
    pub action: Vec<f32>,
    /// `[rows, n_actions]` expected logits, for categorical heads.
    pub logits: Option<Vec<f32>>,
    /// `[rows, 1]` expected values, when the critic is exported.
    pub value: Option<Vec<f32>>,
    /// Largest absolute difference allowed.
    pub tolerance: f32,
}

impl CheckData {
    /// The reference outputs of `graph` for `rows` observations `obs`.
    pub fn from_reference(graph: &PolicyGraph, obs: &[f32], rows: usize, tolerance: f32) -> Self {
        let logits = match graph.head {
            ActionHead::Categorical { .. } => Some(graph.actor_output(obs, rows)),
            ActionHead::Gaussian { .. } => None,
        };
        Self {
            rows,
            obs_dim: graph.obs_dim(),
            action_dim: graph.action_dim(),
            obs: obs[..rows * graph.obs_dim()].to_vec(),
            action: graph.act(obs, rows),
            logits,
            value: graph.value(obs, rows),
            tolerance,
        }
    }

    /// Writes the data as JSON at `path`, atomically.
    pub fn write(&self, path: &Path) -> Result<(), ExportError> {
        let json = serde_json::to_vec(self).map_err(|e| ExportError::Io {
            path: path.into(),
            source: std::io::Error::other(e),
        })?;
        write_atomically(path, &json)
    }

    /// Reads check data written by [`CheckData::write`].
    pub fn read(path: &Path) -> Result<Self, ExportError> {
        let bytes = std::fs::read(path).map_err(|source| ExportError::Io {
            path: path.into(),
            source,
        })?;
        serde_json::from_slice(&bytes).map_err(|e| ExportError::Io {
            path: path.into(),
            source: std::io::Error::new(std::io::ErrorKind::InvalidData, e),
        })
    }
}

/// Where the check data of the model at `model` goes: `policy.onnx` -> `policy.check.json`.
pub fn check_path(model: &Path) -> PathBuf {
    model.with_extension("check.json")
}
