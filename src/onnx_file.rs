//! An ONNX file of a policy, written only once checked: the encoding is loaded in tract and
//! compared with the policy before anything is written (`rlpkg export`, and `rlpkg train` at the
//! end of a run).

use std::path::{Path, PathBuf};

use anyhow::Context;
use rlpkg_agents::export::check::{check_path, CheckData};
use rlpkg_agents::export::onnx::write_atomically;
use rlpkg_agents::export::runtime::{
    compare_with_reference, measure_latency, random_observations, Latency,
};
use rlpkg_agents::export::{to_onnx_bytes, OnnxPolicy, PolicyGraph, TOLERANCE};
use serde::Serialize;

use crate::error::{export_error, input_error};
use crate::files::check_output;

/// What `rlpkg export` did, printed as text or JSON.
#[derive(Debug, Serialize)]
pub struct ExportSummary {
    /// The ONNX file written.
    pub model: PathBuf,
    /// Its size in bytes.
    pub bytes: u64,
    /// Environment the policy acts in.
    pub env_id: String,
    /// Observations the written file was checked on.
    pub verified_rows: usize,
    /// Largest absolute difference between tract on the file and the reference policy.
    pub max_abs_diff: f32,
    /// Check data written next to the model, if asked.
    pub check_data: Option<PathBuf>,
    /// tract single-observation latency, if asked.
    pub latency_us: Option<LatencySummary>,
    /// Comparison with the trainer's burn policy (when exported from a run folder).
    pub burn: Option<BurnComparison>,
}

/// Latency figures in microseconds.
#[derive(Debug, Serialize)]
pub struct LatencySummary {
    /// Timed runs.
    pub runs: usize,
    /// Median.
    pub median: f64,
    /// 90th percentile.
    pub p90: f64,
}

impl From<Latency> for LatencySummary {
    fn from(l: Latency) -> Self {
        Self {
            runs: l.runs,
            median: l.median_us,
            p90: l.p90_us,
        }
    }
}

/// Options of [`export_policy`] beyond the graph and the output path.
#[derive(Debug, Clone)]
pub struct ExportOptions {
    /// Observations to verify the written file on.
    pub verify_rows: usize,
    /// Write `<model>.check.json` beside the model.
    pub check_data: bool,
    /// Single-observation latency runs, if any.
    pub latency_runs: Option<usize>,
}

/// How the written file compares with the trainer's burn policy.
#[derive(Debug, Serialize)]
pub struct BurnComparison {
    /// Random observations compared.
    pub random_rows: usize,
    /// Max abs action difference, burn vs tract, on them.
    pub random_max_abs_diff: f32,
    /// Observations visited by the burn policy in deterministic episodes.
    pub visited_rows: usize,
    /// Max abs action difference, burn vs tract, on them.
    pub visited_max_abs_diff: f32,
}

/// Encodes `graph`, checks the encoding in tract (see [`check_export`]) and only then writes it
/// to `out` atomically, with the optional check data and latency.
pub fn export_policy(
    graph: &PolicyGraph,
    out: &Path,
    options: &ExportOptions,
) -> anyhow::Result<ExportSummary> {
    check_export(graph, out, options)?.write(out, options)
}

/// An ONNX encoding of a policy that tract loaded and that reproduces the policy, not yet written.
pub struct CheckedExport<'a> {
    graph: &'a PolicyGraph,
    bytes: Vec<u8>,
    policy: OnnxPolicy,
    obs: Vec<f32>,
    max_abs_diff: f32,
}

/// Encodes `graph` for `out` and checks the encoding in tract against [`PolicyGraph::act`] on
/// `verify_rows` random observations (error if the difference exceeds [`TOLERANCE`]). Nothing is
/// written: a policy that fails its check leaves no file.
pub fn check_export<'a>(
    graph: &'a PolicyGraph,
    out: &Path,
    options: &ExportOptions,
) -> anyhow::Result<CheckedExport<'a>> {
    check_out_path(out)?;
    let bytes = to_onnx_bytes(graph).map_err(|e| export_error(e, None))?;
    let policy = OnnxPolicy::from_bytes(&bytes, out).map_err(|e| export_error(e, None))?;
    let rows = options.verify_rows;
    let obs = random_observations(graph, rows, 0);
    let agreement = compare_with_reference(graph, &policy, &obs, rows)?;
    agreement.check(TOLERANCE).with_context(|| {
        format!(
            "{}: the encoded policy does not reproduce the policy (nothing written)",
            out.display()
        )
    })?;
    Ok(CheckedExport {
        graph,
        bytes,
        policy,
        obs,
        max_abs_diff: agreement.max_abs_diff(),
    })
}

impl CheckedExport<'_> {
    /// The encoding, loaded in tract.
    pub fn policy(&self) -> &OnnxPolicy {
        &self.policy
    }

    /// Writes the checked encoding to `out` atomically; optionally writes check data and
    /// measures latency.
    pub fn write(self, out: &Path, options: &ExportOptions) -> anyhow::Result<ExportSummary> {
        write_atomically(out, &self.bytes).map_err(|e| export_error(e, None))?;
        let rows = options.verify_rows;
        let check_data = if options.check_data {
            let path = check_path(out);
            CheckData::from_reference(self.graph, &self.obs, rows, TOLERANCE).write(&path)?;
            Some(path)
        } else {
            None
        };
        let latency_us = match options.latency_runs {
            Some(runs) => Some(measure_latency(&self.policy, &self.obs, runs)?.into()),
            None => None,
        };
        Ok(ExportSummary {
            model: out.to_path_buf(),
            bytes: self.bytes.len() as u64,
            env_id: self.graph.meta.env_id.clone(),
            verified_rows: rows,
            max_abs_diff: self.max_abs_diff,
            check_data,
            latency_us,
            burn: None,
        })
    }
}

/// The output folder must exist and the path must name a file that can be replaced.
pub fn check_out_path(out: &Path) -> anyhow::Result<()> {
    let parent = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if out.file_name().is_none() || out.is_dir() {
        return Err(input_error(format!(
            "--out {}: expected a file path, e.g. policy.onnx",
            out.display()
        )));
    }
    if !parent.is_dir() {
        return Err(input_error(format!(
            "--out {}: folder {} does not exist",
            out.display(),
            parent.display()
        )));
    }
    check_output("--out", out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::exit_code;
    use rlpkg_agents::export::random::pendulum_like;

    fn options() -> ExportOptions {
        ExportOptions {
            verify_rows: 200,
            check_data: true,
            latency_runs: Some(20),
        }
    }

    #[test]
    fn export_writes_verifies_and_saves_check_data() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("pendulum.onnx");
        let summary = export_policy(&pendulum_like(1), &out, &options()).unwrap();
        assert_eq!(summary.bytes, std::fs::metadata(&out).unwrap().len());
        assert!(summary.max_abs_diff <= TOLERANCE);
        assert_eq!(summary.verified_rows, 200);
        let check = CheckData::read(summary.check_data.as_ref().unwrap()).unwrap();
        assert_eq!(check.rows, 200);
        assert_eq!(summary.latency_us.unwrap().runs, 20);
    }

    #[test]
    fn bad_output_paths_are_input_errors() {
        let dir = tempfile::tempdir().unwrap();
        for out in [
            dir.path().join("missing/policy.onnx"),
            dir.path().to_path_buf(),
        ] {
            let err = export_policy(&pendulum_like(2), &out, &options()).unwrap_err();
            assert_eq!(exit_code(&err), 2, "{err:#}");
            assert!(format!("{err:#}").contains("--out"), "{err:#}");
        }
    }
}
