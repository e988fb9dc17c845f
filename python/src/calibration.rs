//! `rlpkg._native.CalibrationObjective`: the objective of `rlpkg calibrate` (`SimObjective` of
//! `rlpkg-calib`) for a calibration configuration, evaluating a batch of parameter vectors in
//! one batched rollout from Python; `rlpkg._native.sample_posterior`: the sampled posterior of
//! `rlpkg calibrate` with its batches evaluated by a Python callable.

use std::path::{Path, PathBuf};

use pyo3::exceptions::{PyKeyError, PyKeyboardInterrupt, PyRuntimeError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rlpkg_calib::config::CalibrateConfig;
use rlpkg_calib::driver::BatchObjective;
use rlpkg_calib::fingerprint::ObjectiveRecord;
use rlpkg_calib::objective::SimObjective;
use rlpkg_calib::sampled_posterior::{
    prepare_folder, sample_posterior as sample, sample_posterior_through, BatchEvaluator,
    CandidateRow, SampledPosterior, SampledPosteriorError, SimBatches, POSTERIOR_METRICS,
};
use rlpkg_mocap::{Dataset, Trajectory};
use rlpkg_replay::loss::LossWeights;
use rlpkg_replay::{LikelihoodSettings, Target};
use rlpkg_sim::SceneConfig;

use crate::{describe, value_error};

/// The key of a log row's `objective` column (the candidate's log-likelihood).
const LOG_LIKELIHOOD: &str = "log_likelihood";

/// The objective of a calibration configuration: its scene, parameters, trajectories and loss.
/// Each evaluation builds the `SimObjective` from these (its observer is not `Send`), so the
/// rollout runs without the GIL.
#[pyclass(module = "rlpkg._native", frozen)]
pub struct CalibrationObjective {
    scene: SceneConfig,
    names: Vec<String>,
    bounds: Vec<(f64, f64)>,
    log_scale: Vec<bool>,
    targets: Vec<Target>,
    loss: LossWeights,
    likelihood: LikelihoodSettings,
    trajectories: Vec<String>,
}

/// A calibration configuration loaded as `rlpkg calibrate` loads it: the configuration with
/// the overrides applied, its trajectory ids, their recordings and the scene.
struct Loaded {
    config: CalibrateConfig,
    ids: Vec<String>,
    recorded: Vec<Trajectory>,
    scene: SceneConfig,
}

impl Loaded {
    fn new(
        path: &Path,
        trajectories: Option<Vec<String>>,
        max_seconds: Option<f64>,
    ) -> PyResult<Self> {
        let mut config = CalibrateConfig::load(path).map_err(value_error)?;
        if let Some(ids) = trajectories {
            // Refused as the configuration's `trajectories = []` is: None keeps the file's ids.
            if ids.is_empty() {
                return Err(value_error(
                    "trajectories: []; expected at least one trajectory id (or None for the \
                     configuration's)",
                ));
            }
            rlpkg_calib::config::check_unique_ids("trajectories", &ids).map_err(value_error)?;
            config.trajectories = Some(ids);
        }
        if max_seconds.is_some() {
            config.sim.max_seconds = max_seconds;
        }
        let dataset = Dataset::open(&config.data).map_err(value_error)?;
        let ids = config.trajectory_ids(&dataset).map_err(value_error)?;
        let recorded = ids
            .iter()
            .map(|id| dataset.load(id).map_err(value_error))
            .collect::<PyResult<Vec<_>>>()?;
        let scene = config.scene(path).map_err(value_error)?;
        Ok(Self {
            config,
            ids,
            recorded,
            scene,
        })
    }

    /// The objective `rlpkg calibrate` simulates (one replay per candidate).
    fn objective(&self) -> PyResult<SimObjective> {
        let names: Vec<String> = self.config.params.iter().map(|p| p.name.clone()).collect();
        SimObjective::new(
            &self.scene,
            names,
            &self.recorded,
            self.config.loss,
            self.config.sim.max_seconds,
        )
        .map_err(value_error)
    }
}

#[pymethods]
impl CalibrationObjective {
    /// The objective of the calibration configuration at `config` (paths in it relative to the
    /// working folder, as for `rlpkg calibrate`); `trajectories` and `max_seconds` override the
    /// configuration's as `--trajectories` and `--max-seconds` do.
    #[new]
    #[pyo3(signature = (config, trajectories=None, max_seconds=None))]
    fn new(
        py: Python<'_>,
        config: PathBuf,
        trajectories: Option<Vec<String>>,
        max_seconds: Option<f64>,
    ) -> PyResult<Self> {
        if let Some(s) = max_seconds {
            if !(s > 0.0 && s.is_finite()) {
                return Err(value_error(format!(
                    "max_seconds={s}: expected a duration > 0 s"
                )));
            }
        }
        py.detach(|| {
            let loaded = Loaded::new(&config, trajectories, max_seconds)?;
            let objective = loaded.objective()?;
            let cfg = &loaded.config;
            Ok(Self {
                targets: objective.targets().to_vec(),
                names: cfg.params.iter().map(|p| p.name.clone()).collect(),
                bounds: cfg.params.iter().map(|p| (p.lower, p.upper)).collect(),
                log_scale: cfg.params.iter().map(|p| p.log).collect(),
                loss: cfg.loss,
                likelihood: cfg.likelihood,
                trajectories: loaded.ids,
                scene: loaded.scene,
            })
        })
    }

    /// The calibrated parameters' names, in the order of a parameter vector.
    #[getter]
    fn names(&self) -> Vec<String> {
        self.names.clone()
    }

    /// `(lower, upper)` of each parameter, from the configuration's `[[param]]` tables.
    #[getter]
    fn bounds(&self) -> Vec<(f64, f64)> {
        self.bounds.clone()
    }

    /// Whether each parameter is searched on a log scale (`log = true` of its `[[param]]`).
    #[getter]
    fn log_scale(&self) -> Vec<bool> {
        self.log_scale.clone()
    }

    /// The trajectory ids the objective replays.
    #[getter]
    fn trajectories(&self) -> Vec<String> {
        self.trajectories.clone()
    }

    /// The scene's own values of the parameters.
    fn base_values(&self) -> PyResult<Vec<f64>> {
        Ok(self.objective()?.base_values())
    }

    /// Evaluates every parameter vector of `batch` in one batched rollout; returns one dict per
    /// vector: `loss` (weighted, mean over trajectories; NaN or infinite when a rollout
    /// diverged), `chamfer_m`, `object_mse_m2`, as `evaluations.csv` of `rlpkg calibrate`.
    fn evaluate<'py>(
        &self,
        py: Python<'py>,
        batch: Vec<Vec<f64>>,
    ) -> PyResult<Vec<Bound<'py, PyDict>>> {
        self.check_batch(&batch)?;
        if batch.is_empty() {
            return Ok(Vec::new());
        }
        let results = py.detach(|| {
            self.objective()?
                .evaluate(&batch)
                .map_err(|e| value_error(format!("evaluation failed: {e}")))
        })?;
        results
            .iter()
            .map(|r| {
                let d = PyDict::new(py);
                d.set_item("loss", r.loss)?;
                d.set_item("chamfer_m", r.chamfer_m)?;
                d.set_item("object_mse_m2", r.object_mse_m2)?;
                Ok(d)
            })
            .collect()
    }

    /// The rows a sampled posterior (`[smc]`) logs in `evaluations.csv` for the parameter
    /// vectors of `batch` on the recordings' first `horizon` seconds (`None`: all of them), one
    /// batched rollout scored with the configuration's `[likelihood]`: one dict per vector with
    /// `log_likelihood` (the log's `objective`; `-inf` when a rollout diverged) and the metric
    /// columns (`loss`, `chamfer_m`, `object_mse_m2`, `site_mse_m2`, `horizon_s`).
    #[pyo3(signature = (batch, horizon=None))]
    fn log_likelihoods<'py>(
        &self,
        py: Python<'py>,
        batch: Vec<Vec<f64>>,
        horizon: Option<f64>,
    ) -> PyResult<Vec<Bound<'py, PyDict>>> {
        self.check_batch(&batch)?;
        if let Some(h) = horizon {
            if !(h > 0.0 && h.is_finite()) {
                return Err(value_error(format!(
                    "horizon={h}: expected a duration > 0 s or None"
                )));
            }
        }
        if batch.is_empty() {
            return Ok(Vec::new());
        }
        let rows = py.detach(|| {
            let mut objective = self.objective()?.with_replicas(&self.likelihood);
            SimBatches::new(&mut objective, &self.likelihood)
                .evaluate(horizon, &batch)
                .map_err(|e| value_error(format!("evaluation failed: {e}")))
        })?;
        rows.iter().map(|row| row_dict(py, row)).collect()
    }
}

impl CalibrationObjective {
    /// Every vector of `batch` has one finite value per parameter.
    fn check_batch(&self, batch: &[Vec<f64>]) -> PyResult<()> {
        for (i, values) in batch.iter().enumerate() {
            if values.len() != self.names.len() {
                return Err(value_error(format!(
                    "batch[{i}]: {} values; expected one per parameter {:?}",
                    values.len(),
                    self.names
                )));
            }
            if let Some(k) = values.iter().position(|v| !v.is_finite()) {
                return Err(value_error(format!(
                    "batch[{i}][{k}] ({}) = {}: expected a finite number",
                    self.names[k], values[k]
                )));
            }
        }
        Ok(())
    }

    fn objective(&self) -> PyResult<SimObjective> {
        SimObjective::from_targets(
            &self.scene,
            self.names.clone(),
            self.targets.clone(),
            self.loss,
        )
        .map_err(value_error)
    }
}

/// A log row as a dict: `log_likelihood` and the [`POSTERIOR_METRICS`] by name.
fn row_dict<'py>(py: Python<'py>, row: &CandidateRow) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item(LOG_LIKELIHOOD, row.log_likelihood)?;
    for (name, value) in POSTERIOR_METRICS.iter().zip(&row.metrics) {
        d.set_item(*name, *value)?;
    }
    Ok(d)
}

/// A log row from what `map_batches` returned for candidate `candidate` of a batch, or why it
/// is not one.
fn row_from_python(candidate: usize, row: &Bound<'_, PyAny>) -> Result<CandidateRow, String> {
    let value = |key: &str| -> Result<f64, String> {
        let problem = match row.get_item(key) {
            Ok(v) => match v.extract::<f64>() {
                Ok(number) => return Ok(number),
                Err(_) => format!("{key} = {}", describe(&v)),
            },
            Err(e) if e.is_instance_of::<PyKeyError>(row.py()) => format!("no {key} key"),
            Err(e) => format!("{} has no {key} ({e})", describe(row)),
        };
        Err(format!(
            "row {candidate}: {problem}; expected a dict of numbers with the keys \
             {LOG_LIKELIHOOD}, {} (as Objective.log_likelihoods gives them)",
            POSTERIOR_METRICS.join(", ")
        ))
    };
    Ok(CandidateRow {
        log_likelihood: value(LOG_LIKELIHOOD)?,
        metrics: POSTERIOR_METRICS
            .iter()
            .map(|name| value(name))
            .collect::<Result<_, _>>()?,
    })
}

/// Why `map_batches` failed a batch.
enum BatchFailure {
    /// It raised this (the cause of the sampler's RuntimeError).
    Raised(PyErr),
    /// It returned rows that do not fit the batch (a ValueError, as the sampler's own check).
    Unfit,
}

/// The sampler's batches evaluated by the Python callable
/// `map_batches(config, horizon, candidates)`, called with the GIL held; its first failure is
/// kept, to decide the error the sampler's becomes.
struct PythonBatches {
    map_batches: Py<PyAny>,
    config: String,
    failure: Option<BatchFailure>,
}

impl BatchEvaluator for PythonBatches {
    fn evaluate(
        &mut self,
        horizon: Option<f64>,
        candidates: &[Vec<f64>],
    ) -> Result<Vec<CandidateRow>, String> {
        let rows = Python::attach(|py| -> Result<Vec<CandidateRow>, (String, BatchFailure)> {
            let raised = |e: PyErr| (e.to_string(), BatchFailure::Raised(e));
            // Ctrl-C stops the sampler between batches.
            py.check_signals().map_err(raised)?;
            let rows = self
                .map_batches
                .bind(py)
                .call1((self.config.as_str(), horizon, candidates.to_vec()))
                .map_err(raised)?;
            let unfit = |message: String| (message, BatchFailure::Unfit);
            rows.try_iter()
                .map_err(|_| unfit(format!("returned {}, not a list of rows", describe(&rows))))?
                .enumerate()
                .map(|(candidate, row)| {
                    row_from_python(candidate, &row.map_err(raised)?).map_err(unfit)
                })
                .collect()
        });
        rows.map_err(|(message, failure)| {
            self.failure.get_or_insert(failure);
            format!("map_batches: {message}")
        })
    }
}

/// The posterior's summary (`posterior.toml`) as a dict, with the output folder.
fn summary_dict<'py>(
    py: Python<'py>,
    posterior: &SampledPosterior,
    out_dir: &Path,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("out_dir", out_dir.to_string_lossy())?;
    let parameters = posterior
        .parameters
        .iter()
        .map(|p| {
            let row = PyDict::new(py);
            row.set_item("name", &p.name)?;
            row.set_item("lower_5", p.lower_5)?;
            row.set_item("median", p.median)?;
            row.set_item("upper_95", p.upper_95)?;
            row.set_item("box_share", p.box_share)?;
            row.set_item("best", p.best)?;
            Ok(row)
        })
        .collect::<PyResult<Vec<_>>>()?;
    d.set_item("parameters", parameters)?;
    d.set_item("evaluations", posterior.evaluations)?;
    d.set_item("search_generations", posterior.search_generations)?;
    d.set_item("stages", posterior.stages)?;
    d.set_item("log_evidence", posterior.log_evidence)?;
    d.set_item("likelihood_power", posterior.likelihood_power)?;
    d.set_item("chaos_log_likelihood_sd", posterior.chaos_log_likelihood_sd)?;
    d.set_item("chaos_points", posterior.chaos_points)?;
    d.set_item("best_log_likelihood", posterior.best_log_likelihood)?;
    d.set_item("polished_evaluations", posterior.polished_evaluations)?;
    Ok(d)
}

/// Samples the posterior of the calibration configuration `config` (its `[smc]` table) into
/// `out_dir` (default: its `out_dir`) as `rlpkg calibrate` does, resuming the folder's log
/// unless `fresh`. With `map_batches`, each batch is evaluated by
/// `map_batches(config, horizon, candidates)` (rows as `CalibrationObjective.log_likelihoods`
/// gives them) instead of here; the polish and the Fisher information run here. The sampler runs
/// without the GIL. Returns the summary of `posterior.toml`.
#[pyfunction]
#[pyo3(signature = (config, out_dir=None, map_batches=None, fresh=false))]
pub fn sample_posterior<'py>(
    py: Python<'py>,
    config: PathBuf,
    out_dir: Option<PathBuf>,
    map_batches: Option<Py<PyAny>>,
    fresh: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let mut batches = map_batches.map(|map_batches| PythonBatches {
        map_batches,
        config: config.to_string_lossy().into_owned(),
        failure: None,
    });
    let (sampled, out_dir) = py.detach(|| -> PyResult<_> {
        let loaded = Loaded::new(&config, None, None)?;
        let cfg = &loaded.config;
        let Some(smc) = cfg.smc else {
            return Err(value_error(format!(
                "{}: no [smc] table; a sampled posterior needs one (an [optimiser] configuration \
                 is for rlpkg calibrate or Objective)",
                config.display()
            )));
        };
        let out_dir = out_dir.unwrap_or_else(|| cfg.out_dir.clone());
        let record = ObjectiveRecord::posterior(cfg, smc, &loaded.ids, &loaded.scene)
            .to_text()
            .map_err(value_error)?;
        let preset = Path::new(&cfg.sim.preset);
        let mut inputs = vec![(config.as_path(), "the calibration config")];
        if !matches!(cfg.sim.preset.as_str(), "reference" | "physical") {
            inputs.push((preset, "the config's scene (`sim.preset`)"));
        }
        prepare_folder(&out_dir, &record, fresh, &inputs).map_err(value_error)?;
        let mut objective = loaded.objective()?.with_replicas(&cfg.likelihood);
        let space = cfg.space();
        let sampled = match batches.as_mut() {
            None => sample(
                &mut objective,
                &space,
                &smc,
                &cfg.likelihood,
                &out_dir,
                |_, _| {},
            ),
            Some(batches) => sample_posterior_through(
                &mut objective,
                batches,
                &space,
                &smc,
                &cfg.likelihood,
                &out_dir,
                |_, _| {},
            ),
        };
        Ok((sampled, out_dir))
    })?;
    let error = match sampled {
        Ok(posterior) => return summary_dict(py, &posterior, &out_dir),
        Err(e) => e,
    };
    Err(match batches.and_then(|b| b.failure) {
        Some(BatchFailure::Raised(raised)) if raised.is_instance_of::<PyKeyboardInterrupt>(py) => {
            raised
        }
        Some(BatchFailure::Raised(raised)) => {
            let err = PyRuntimeError::new_err(error.to_string());
            err.set_cause(py, Some(raised));
            err
        }
        Some(BatchFailure::Unfit) => value_error(error),
        None => match error {
            SampledPosteriorError::Smc(_) => PyRuntimeError::new_err(error.to_string()),
            other => value_error(other),
        },
    })
}
