//! The evaluation log: one CSV row per objective evaluation, appended as soon as a batch is done, and
//! read back to resume an interrupted calibration.
//!
//! Columns: `batch`, `candidate`, one column per parameter (search order), `objective`, then the
//! caller's metric columns (e.g. `loss`, `chamfer_m`, `object_mse_m2`). Each batch is written with a
//! single `write` and flushed, so an interrupted run loses at most the batch in flight.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Errors of the evaluation log.
#[derive(Debug, thiserror::Error)]
pub enum LogError {
    /// The file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The log file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The header does not match the current parameters and metrics.
    #[error("{path}: header is `{found}`, expected `{expected}` (was the log written with other parameters?)")]
    Header {
        /// The log file.
        path: PathBuf,
        /// Header found.
        found: String,
        /// Header expected.
        expected: String,
    },
    /// A row disagrees with how its values are computed (e.g. an edited objective).
    #[error("{path}: batch {batch} candidate {candidate}: {message}")]
    Inconsistent {
        /// The log file.
        path: PathBuf,
        /// Batch of the row.
        batch: usize,
        /// Candidate of the row.
        candidate: usize,
        /// What disagrees.
        message: String,
    },
    /// A row is malformed.
    #[error("{path}, line {line}: {message}")]
    Row {
        /// The log file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What was expected.
        message: String,
    },
}

/// One logged evaluation.
#[derive(Debug, Clone, PartialEq)]
pub struct LoggedEvaluation {
    /// Batch index (0-based).
    pub batch: usize,
    /// Candidate index within the batch.
    pub candidate: usize,
    /// Parameter values, in search order.
    pub params: Vec<f64>,
    /// The objective told to the optimiser.
    pub objective: f64,
    /// Metric values, in the order of the metric names.
    pub metrics: Vec<f64>,
}

/// An append-only CSV log of evaluations.
#[derive(Debug)]
pub struct EvaluationLog {
    path: PathBuf,
    header: Vec<String>,
}

impl EvaluationLog {
    /// Opens (or creates with its header) the log at `path` and returns it with the rows already in
    /// it. Rows the log could not have written are errors: a parameter outside its `bounds` (one
    /// `(lower, upper)` per parameter), or a row out of sequence (every batch numbers its candidates
    /// 0, 1, ... and follows the previous batch, so a duplicated row is out of sequence too).
    pub fn open(
        path: &Path,
        param_names: &[&str],
        metric_names: &[&str],
        bounds: &[(f64, f64)],
    ) -> Result<(Self, Vec<LoggedEvaluation>), LogError> {
        let mut header: Vec<String> = vec!["batch".into(), "candidate".into()];
        header.extend(param_names.iter().map(|s| s.to_string()));
        header.push("objective".into());
        header.extend(metric_names.iter().map(|s| s.to_string()));
        let log = Self {
            path: path.to_path_buf(),
            header,
        };
        let rows = if path.exists() {
            log.read(param_names.len(), metric_names.len(), bounds)?
        } else {
            log.append_text(&format!("{}\n", log.header.join(",")))?;
            Vec::new()
        };
        Ok((log, rows))
    }

    /// The log file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn io(&self, source: std::io::Error) -> LogError {
        LogError::Io {
            path: self.path.clone(),
            source,
        }
    }

    fn read(
        &self,
        n_params: usize,
        n_metrics: usize,
        bounds: &[(f64, f64)],
    ) -> Result<Vec<LoggedEvaluation>, LogError> {
        let text = std::fs::read_to_string(&self.path).map_err(|e| self.io(e))?;
        let mut lines = text.lines();
        let found = lines.next().unwrap_or("");
        let expected = self.header.join(",");
        if found.trim() != expected {
            return Err(LogError::Header {
                path: self.path.clone(),
                found: found.into(),
                expected,
            });
        }
        let mut rows = Vec::new();
        for (i, line) in lines.enumerate() {
            let line_no = i + 2;
            if line.trim().is_empty() {
                continue;
            }
            let cells: Vec<&str> = line.split(',').collect();
            if cells.len() != self.header.len() {
                return Err(LogError::Row {
                    path: self.path.clone(),
                    line: line_no,
                    message: format!("{} cells, expected {}", cells.len(), self.header.len()),
                });
            }
            let bad = |col: usize| LogError::Row {
                path: self.path.clone(),
                line: line_no,
                message: format!(
                    "column `{}`: `{}` is not a number",
                    self.header[col], cells[col]
                ),
            };
            let index = |col: usize| cells[col].trim().parse::<usize>().map_err(|_| bad(col));
            let number = |col: usize| cells[col].trim().parse::<f64>().map_err(|_| bad(col));
            let params: Vec<f64> = (2..2 + n_params).map(number).collect::<Result<_, _>>()?;
            let metrics = (3 + n_params..3 + n_params + n_metrics)
                .map(number)
                .collect::<Result<_, _>>()?;
            let row_error = |message: String| LogError::Row {
                path: self.path.clone(),
                line: line_no,
                message,
            };
            for (col, (&value, &(lower, upper))) in params.iter().zip(bounds).enumerate() {
                // Values come from the unit cube; allow the rounding of the log-scale map.
                let slack = 1e-9 * upper.abs().max(lower.abs());
                if !(value >= lower - slack && value <= upper + slack) {
                    return Err(row_error(format!(
                        "column `{}` = {value} is outside its bounds [{lower}, {upper}]; \
                         this log was not written with these bounds",
                        self.header[2 + col]
                    )));
                }
            }
            let (batch, candidate) = (index(0)?, index(1)?);
            let expected = match rows.last() {
                None => vec![(0, 0)],
                Some(LoggedEvaluation {
                    batch: b,
                    candidate: c,
                    ..
                }) => vec![(*b, c + 1), (b + 1, 0)],
            };
            if !expected.contains(&(batch, candidate)) {
                let wanted: Vec<String> = expected
                    .iter()
                    .map(|(b, c)| format!("batch {b} candidate {c}"))
                    .collect();
                return Err(row_error(format!(
                    "batch {batch} candidate {candidate} is out of sequence (duplicated or \
                     missing rows); expected {}",
                    wanted.join(" or ")
                )));
            }
            rows.push(LoggedEvaluation {
                batch,
                candidate,
                params,
                objective: number(2 + n_params)?,
                metrics,
            });
        }
        Ok(rows)
    }

    /// Appends a batch of evaluations (one write, then flush).
    pub fn append(&self, rows: &[LoggedEvaluation]) -> Result<(), LogError> {
        let mut text = String::new();
        for r in rows {
            let mut cells = vec![r.batch.to_string(), r.candidate.to_string()];
            // `{:e}`-free Display of f64 round-trips exactly through `parse`.
            cells.extend(r.params.iter().map(|v| v.to_string()));
            cells.push(r.objective.to_string());
            cells.extend(r.metrics.iter().map(|v| v.to_string()));
            text.push_str(&cells.join(","));
            text.push('\n');
        }
        self.append_text(&text)
    }

    fn append_text(&self, text: &str) -> Result<(), LogError> {
        let mut file: File = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&self.path)
            .map_err(|e| self.io(e))?;
        file.write_all(text.as_bytes()).map_err(|e| self.io(e))?;
        file.flush().map_err(|e| self.io(e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const WIDE: [(f64, f64); 2] = [(0.0, 1e6), (0.0, 1.0)];

    fn row(batch: usize, candidate: usize, objective: f64) -> LoggedEvaluation {
        LoggedEvaluation {
            batch,
            candidate,
            params: vec![1.0e5 / 3.0, 0.1 + 0.2],
            objective,
            metrics: vec![0.0331, f64::NAN],
        }
    }

    #[test]
    fn round_trips_rows_exactly() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("evaluations.csv");
        let (log, rows) =
            EvaluationLog::open(&path, &["k_tri_e", "mu_con"], &["cd", "mse"], &WIDE).unwrap();
        assert!(rows.is_empty());
        log.append(&[row(0, 0, -3.25), row(0, 1, f64::INFINITY)])
            .unwrap();
        log.append(&[row(1, 0, 1e-17)]).unwrap();
        let (_, back) =
            EvaluationLog::open(&path, &["k_tri_e", "mu_con"], &["cd", "mse"], &WIDE).unwrap();
        assert_eq!(back.len(), 3);
        assert_eq!(back[0].params, row(0, 0, 0.0).params);
        assert_eq!(back[1].objective, f64::INFINITY);
        assert_eq!(back[2].objective, 1e-17);
        assert_eq!((back[2].batch, back[2].candidate), (1, 0));
        assert!(back[0].metrics[1].is_nan());
    }

    #[test]
    fn rejects_another_parameter_set_and_bad_rows() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("evaluations.csv");
        EvaluationLog::open(&path, &["a"], &[], &WIDE).unwrap();
        let err = EvaluationLog::open(&path, &["b"], &[], &WIDE).unwrap_err();
        assert!(matches!(err, LogError::Header { .. }), "{err}");

        std::fs::write(
            &path,
            "batch,candidate,a,objective\n0,0,1.0,2.0\n0,1,x,2.0\n",
        )
        .unwrap();
        let err = EvaluationLog::open(&path, &["a"], &[], &WIDE).unwrap_err();
        let msg = err.to_string();
        assert!(msg.contains("line 3") && msg.contains("`a`"), "{msg}");
    }

    #[test]
    fn rejects_rows_outside_the_bounds_and_out_of_sequence() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("evaluations.csv");
        let header = "batch,candidate,a,objective\n";
        let cases = [
            (
                "0,0,0.5,1\n0,1,2.5,1\n",
                "line 3",
                "outside its bounds [0, 1]",
            ),
            (
                "0,0,0.5,1\n0,0,0.5,1\n",
                "line 3",
                "batch 0 candidate 0 is out of sequence",
            ),
            (
                "0,0,0.5,1\n1,0,0.5,1\n1,0,0.5,1\n",
                "line 4",
                "out of sequence",
            ),
            (
                "0,0,0.5,1\n2,0,0.5,1\n",
                "line 3",
                "expected batch 0 candidate 1 or batch 1",
            ),
            ("1,0,0.5,1\n", "line 2", "expected batch 0 candidate 0"),
        ];
        for (rows, line, message) in cases {
            std::fs::write(&path, format!("{header}{rows}")).unwrap();
            let err = EvaluationLog::open(&path, &["a"], &[], &[(0.0, 1.0)])
                .unwrap_err()
                .to_string();
            assert!(err.contains(line) && err.contains(message), "{err}");
        }
        std::fs::write(
            &path,
            format!("{header}0,0,1.0000000000000002,1\n0,1,0,1\n1,0,1,1\n"),
        )
        .unwrap();
        let (_, rows) = EvaluationLog::open(&path, &["a"], &[], &[(0.0, 1.0)]).unwrap();
        assert_eq!(
            rows.len(),
            3,
            "rounding at a bound and a new batch are accepted"
        );
    }
}
