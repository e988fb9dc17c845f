//! `rlpkg._native.CalibrationObjective`: the objective of `rlpkg calibrate` (`SimObjective` of
//! `rlpkg-calib`) for a calibration configuration, evaluating a batch of parameter vectors in
//! one batched rollout from Python.

use std::path::PathBuf;

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rlpkg_calib::config::CalibrateConfig;
use rlpkg_calib::driver::BatchObjective;
use rlpkg_calib::objective::SimObjective;
use rlpkg_mocap::Dataset;
use rlpkg_replay::loss::LossWeights;
use rlpkg_replay::Target;
use rlpkg_sim::SceneConfig;

fn value_error(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

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
    trajectories: Vec<String>,
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
            let mut cfg = CalibrateConfig::load(&config).map_err(value_error)?;
            if let Some(ids) = trajectories.filter(|ids| !ids.is_empty()) {
                if let Some((_, id)) = rlpkg_calib::config::repeated_id(&ids) {
                    return Err(value_error(format!(
                        "trajectories: {id} is listed twice; expected each trajectory id once"
                    )));
                }
                cfg.trajectories = Some(ids);
            }
            if max_seconds.is_some() {
                cfg.sim.max_seconds = max_seconds;
            }
            let dataset = Dataset::open(&cfg.data).map_err(value_error)?;
            let ids = cfg.trajectory_ids(&dataset).map_err(value_error)?;
            let recorded = ids
                .iter()
                .map(|id| dataset.load(id).map_err(value_error))
                .collect::<PyResult<Vec<_>>>()?;
            let scene = cfg.scene(&config).map_err(value_error)?;
            let names: Vec<String> = cfg.params.iter().map(|p| p.name.clone()).collect();
            let objective = SimObjective::new(
                &scene,
                names.clone(),
                &recorded,
                cfg.loss,
                cfg.sim.max_seconds,
            )
            .map_err(value_error)?;
            Ok(Self {
                targets: objective.targets().to_vec(),
                scene,
                names,
                bounds: cfg.params.iter().map(|p| (p.lower, p.upper)).collect(),
                log_scale: cfg.params.iter().map(|p| p.log).collect(),
                loss: cfg.loss,
                trajectories: ids,
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
}

impl CalibrationObjective {
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
