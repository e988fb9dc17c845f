//! `rlpkg._native`: the Rust core of the `rlpkg` Python package. [`VecEnvCore`] holds one
//! vectorised environment (CartPole-v1, Pendulum-v1 or Transport-v0) with its own rayon thread
//! pool; the Python side (`python/python/rlpkg`) wraps it in Gymnasium's `VectorEnv` and `Env`.
//!
//! Every array handed to Python is a fresh copy of the step's buffers (numpy owns it), and the
//! step itself runs without the GIL, so other Python threads run while the environment steps.
//! [`profile::ProfileReference`] is the reference a profile-rate policy drives on a robot.

use std::path::{Path, PathBuf};
use std::sync::Mutex;

mod calibration;
mod profile;

use numpy::{
    PyArray1, PyArrayMethods, PyReadonlyArray1, PyReadonlyArrayDyn, PyUntypedArray,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyRuntimeError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{IntoPyDict, PyBool, PyDict};
use rlpkg_env::tasks::{Task, IDS};
use rlpkg_vec_env::digest::rollout_digest;
use rlpkg_vec_env::{
    AutoresetMode, EnvError, ResetCopies, Seeding, SpaceKind, StepBuffers, VecEnv,
};

fn value_error(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// `value` for an error message: its repr (cut at 80 characters) and its type, e.g. `'1' (a
/// str)`, as `rlpkg._checks.describe` gives it on the Python side.
fn describe(value: &Bound<'_, PyAny>) -> String {
    let mut text = value.repr().map_or_else(|_| "?".into(), |r| r.to_string());
    if text.chars().count() > 80 {
        text = text.chars().take(77).collect::<String>() + "...";
    }
    let kind = value
        .get_type()
        .name()
        .map_or_else(|_| "?".into(), |n| n.to_string());
    let article = match kind.starts_with(['a', 'e', 'i', 'o', 'u']) {
        true => "an",
        false => "a",
    };
    format!("{text} ({article} {kind})")
}

/// `value` as a real number for the argument `name` (a Python or NumPy real; not a bool, which
/// is no quantity), else a TypeError saying what was `expected`. Arguments take `&Bound<PyAny>`
/// and this, rather than `f64`, for an error that names them.
fn real(name: &str, value: &Bound<'_, PyAny>, expected: &str) -> PyResult<f64> {
    if !value.is_instance_of::<PyBool>() {
        if let Ok(number) = value.extract::<f64>() {
            return Ok(number);
        }
    }
    Err(PyTypeError::new_err(format!(
        "{name}: expected {expected}, got {}",
        describe(value)
    )))
}

/// `value` as a float64 array for the argument `name`: any array-like of real numbers (a NumPy
/// array of another dtype, nested lists), converted by NumPy; else a TypeError (a ValueError
/// when NumPy makes no array of it, e.g. of ragged lists) saying what was `expected`.
fn real_array<'py>(
    name: &str,
    value: &Bound<'py, PyAny>,
    expected: &str,
) -> PyResult<PyReadonlyArrayDyn<'py, f64>> {
    let py = value.py();
    let array = numpy::get_array_module(py)?
        .call_method1("asarray", (value,))
        .map_err(|e| {
            value_error(format!(
                "{name}: expected {expected}, got {} ({e})",
                describe(value)
            ))
        })?;
    let dtype = array.getattr("dtype")?;
    let kind: String = dtype.getattr("kind")?.extract()?;
    // Integers and floats of any width; not bools, strings or objects.
    if !matches!(kind.as_str(), "i" | "u" | "f") {
        let got = match value.is_instance_of::<PyUntypedArray>() {
            true => format!("an array of dtype {dtype}"),
            false => format!("{}, an array of dtype {dtype} to NumPy", describe(value)),
        };
        return Err(PyTypeError::new_err(format!(
            "{name}: expected {expected}, got {got}"
        )));
    }
    let no_copy = [("copy", false)].into_py_dict(py)?;
    array
        .call_method("astype", ("float64",), Some(&no_copy))?
        .extract()
}

/// The size of the thread pool: `num_threads`, else `RAYON_NUM_THREADS`, else `OMP_NUM_THREADS`,
/// else the number of cores.
fn pool_size(num_threads: Option<usize>) -> PyResult<usize> {
    if let Some(n) = num_threads {
        return match n {
            0 => Err(value_error("num_threads must be >= 1, got 0")),
            n => Ok(n),
        };
    }
    for var in ["RAYON_NUM_THREADS", "OMP_NUM_THREADS"] {
        if let Some(n) = std::env::var(var).ok().and_then(|v| v.trim().parse().ok()) {
            if n >= 1 {
                return Ok(n);
            }
        }
    }
    Ok(std::thread::available_parallelism().map_or(1, |n| n.get()))
}

/// An environment's own rayon pool of [`pool_size`] threads.
fn thread_pool(num_threads: Option<usize>) -> PyResult<rayon::ThreadPool> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(pool_size(num_threads)?)
        .build()
        .map_err(|e| PyRuntimeError::new_err(e.to_string()))
}

/// `num_envs` copies of environment `id` (`config`: a Transport-v0 configuration file), built by
/// the task registry the CLI builds from.
fn build(id: &str, num_envs: usize, config: Option<&Path>) -> Result<Box<dyn VecEnv>, EnvError> {
    if num_envs == 0 {
        return Err(EnvError::NoEnvs(0));
    }
    Task::from_file(id, config)?.build(num_envs)
}

fn autoreset_mode(name: &str) -> PyResult<AutoresetMode> {
    AutoresetMode::parse(name).ok_or_else(|| {
        value_error(format!(
            "autoreset_mode {name:?}: expected \"next_step\", \"same_step\" or \"disabled\""
        ))
    })
}

/// The environment and its step buffers, behind the core's lock.
struct Inner {
    env: Box<dyn VecEnv>,
    out: StepBuffers,
    /// Whether a reset has started the episodes.
    started: bool,
}

/// One vectorised environment with its own thread pool.
#[pyclass(module = "rlpkg._native")]
struct VecEnvCore {
    inner: Mutex<Inner>,
    pool: rayon::ThreadPool,
    num_envs: usize,
    action_dim: usize,
    obs_dim: usize,
    critic_dim: usize,
}

impl VecEnvCore {
    fn lock(&self) -> PyResult<std::sync::MutexGuard<'_, Inner>> {
        self.inner
            .lock()
            .map_err(|_| PyRuntimeError::new_err("the environment failed in an earlier call"))
    }

    /// Copies of `values` as a numpy array of shape `[num_envs, width]` (1-D for width 0).
    fn rows<'py, T: numpy::Element + Copy>(
        &self,
        py: Python<'py>,
        values: &[T],
        width: Option<usize>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let array = PyArray1::from_slice(py, values);
        Ok(match width {
            Some(w) => array.reshape([self.num_envs, w])?.into_any(),
            None => array.into_any(),
        })
    }

    /// The observation arrays of `out`: `(obs, critic_obs or None)`.
    fn observations<'py>(
        &self,
        py: Python<'py>,
        obs: &[f32],
        critic: &[f32],
    ) -> PyResult<(Bound<'py, PyAny>, Option<Bound<'py, PyAny>>)> {
        let critic = match critic.is_empty() {
            true => None,
            false => Some(self.rows(py, critic, Some(self.critic_dim))?),
        };
        Ok((self.rows(py, obs, Some(self.obs_dim))?, critic))
    }
}

#[pymethods]
impl VecEnvCore {
    /// `num_envs` copies of `id` ("CartPole-v1", "Pendulum-v1", "Transport-v0"); `config`: the
    /// Transport-v0 configuration file; `autoreset_mode`: "next_step", "same_step" or
    /// "disabled"; `num_threads`: the pool's size (else RAYON_NUM_THREADS, OMP_NUM_THREADS, the
    /// cores).
    #[new]
    #[pyo3(signature = (id, num_envs, config=None, autoreset_mode="next_step", num_threads=None))]
    fn new(
        py: Python<'_>,
        id: &str,
        num_envs: usize,
        config: Option<PathBuf>,
        autoreset_mode: &str,
        num_threads: Option<usize>,
    ) -> PyResult<Self> {
        let mode = self::autoreset_mode(autoreset_mode)?;
        let pool = thread_pool(num_threads)?;
        let id = id.to_string();
        let mut env = py
            .detach(|| pool.install(|| build(&id, num_envs, config.as_deref())))
            .map_err(value_error)?;
        env.set_autoreset_mode(mode).map_err(value_error)?;
        let spec = env.spec();
        let (obs_dim, action_dim) = (spec.observation.dim(), spec.action.dim());
        let critic_dim = spec.critic_observation.as_ref().map_or(0, |c| c.dim());
        let out = env.buffers();
        Ok(Self {
            inner: Mutex::new(Inner {
                env,
                out,
                started: false,
            }),
            pool,
            num_envs,
            action_dim,
            obs_dim,
            critic_dim,
        })
    }

    /// What the Python side builds its spaces from: a dict of id, observation and action names,
    /// units and bounds, the critic's bounds (when it has its own group), info names, sizes.
    fn spec<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let inner = self.lock()?;
        let (env, spec) = (&inner.env, inner.env.spec());
        let d = PyDict::new(py);
        d.set_item("id", &spec.id)?;
        d.set_item("num_envs", self.num_envs)?;
        d.set_item("num_threads", self.pool.current_num_threads())?;
        d.set_item("autoreset_mode", env.autoreset_mode().name())?;
        d.set_item("max_episode_steps", spec.max_episode_steps)?;
        d.set_item("obs_names", &spec.observation.names)?;
        d.set_item("obs_units", &spec.observation.units)?;
        d.set_item("obs_low", &spec.observation.low)?;
        d.set_item("obs_high", &spec.observation.high)?;
        if let Some(critic) = &spec.critic_observation {
            d.set_item("critic_names", &critic.names)?;
            d.set_item("critic_low", &critic.low)?;
            d.set_item("critic_high", &critic.high)?;
        }
        match spec.action.kind {
            SpaceKind::Discrete { n } => d.set_item("action_n", n)?,
            SpaceKind::Continuous => {
                d.set_item("action_low", &spec.action.low)?;
                d.set_item("action_high", &spec.action.high)?;
            }
        }
        d.set_item("action_names", &spec.action.names)?;
        d.set_item("info_names", env.info_names())?;
        Ok(d)
    }

    /// Restarts copies: all, or those where `mask` is true; seeded from `seed + i`
    /// (`seed`), from `seeds[i]`, or continuing their streams (neither). Returns
    /// `(obs, critic_obs or None)` of every copy (rows left out keep their last values).
    #[pyo3(signature = (seed=None, seeds=None, mask=None))]
    fn reset<'py>(
        &self,
        py: Python<'py>,
        seed: Option<u64>,
        seeds: Option<Vec<u64>>,
        mask: Option<PyReadonlyArray1<'py, bool>>,
    ) -> PyResult<(Bound<'py, PyAny>, Option<Bound<'py, PyAny>>)> {
        let mask: Option<Vec<bool>> = mask.map(|m| m.as_array().to_vec());
        let seeding = match (&seeds, seed) {
            (Some(_), Some(_)) => return Err(value_error("give seed or seeds, not both")),
            (Some(seeds), None) => Seeding::PerCopy(seeds),
            (None, Some(seed)) => Seeding::Base(seed),
            (None, None) => Seeding::Continue,
        };
        let copies = ResetCopies {
            mask: mask.as_deref(),
            seeding,
        };
        let mut guard = self.lock()?;
        if copies.mask.is_some() && !guard.started {
            return Err(value_error(
                "reset_mask before the first reset: reset every copy first",
            ));
        }
        let inner = &mut *guard;
        py.detach(|| {
            self.pool
                .install(|| inner.env.reset_copies(copies, &mut inner.out))
        })
        .map_err(value_error)?;
        inner.started = true;
        self.observations(py, &inner.out.obs, &inner.out.critic_obs)
    }

    /// Steps every copy with `actions` (`num_envs * action_dim` float32 values, row-major;
    /// discrete actions as integral values) without the GIL. Returns fresh arrays: `(obs,
    /// critic_obs, rewards, terminated, truncated, final_obs, final_critic_obs, info)`, the
    /// critic arrays None without a critic group, `info` of shape `[num_envs, len(info_names)]`.
    #[allow(clippy::type_complexity)]
    fn step<'py>(
        &self,
        py: Python<'py>,
        actions: PyReadonlyArray1<'py, f32>,
    ) -> PyResult<Bound<'py, pyo3::types::PyTuple>> {
        let expected = self.num_envs * self.action_dim;
        if actions.len() != expected {
            return Err(value_error(format!(
                "expected {expected} action values (num_envs {} x action_dim {}), got {}",
                self.num_envs,
                self.action_dim,
                actions.len()
            )));
        }
        let actions: Vec<f32> = actions.as_array().to_vec();
        if let Some(k) = actions.iter().position(|a| !a.is_finite()) {
            return Err(value_error(format!(
                "environment {}: action {} is {}, expected a finite number",
                k / self.action_dim,
                k % self.action_dim,
                actions[k]
            )));
        }
        let mut guard = self.lock()?;
        if !guard.started {
            return Err(value_error("step before reset: call reset first"));
        }
        let inner = &mut *guard;
        py.detach(|| {
            self.pool
                .install(|| inner.env.step(&actions, &mut inner.out))
        })
        .map_err(value_error)?;
        let out = &inner.out;
        let (obs, critic) = self.observations(py, &out.obs, &out.critic_obs)?;
        let (final_obs, final_critic) =
            self.observations(py, &out.final_obs, &out.final_critic_obs)?;
        let width = inner.env.info_names().len();
        let info = self.rows(py, inner.env.info(), Some(width))?;
        (
            obs,
            critic,
            self.rows(py, &out.rewards, None)?,
            self.rows(py, &out.terminated, None)?,
            self.rows(py, &out.truncated, None)?,
            final_obs,
            final_critic,
            info,
        )
            .into_pyobject(py)
    }
}

/// The digest of `steps` scripted steps of `num_envs` copies of `id` after `reset(seed)`, stepped
/// in Rust only (`rlpkg_vec_env::digest`): the reference the Python tests compare the package's
/// own stepping with.
#[pyfunction]
#[pyo3(signature = (id, num_envs, steps, seed, config=None, autoreset_mode="same_step", num_threads=None))]
#[allow(clippy::too_many_arguments)] // Python's keyword arguments
fn rust_rollout_digest(
    py: Python<'_>,
    id: &str,
    num_envs: usize,
    steps: usize,
    seed: u64,
    config: Option<PathBuf>,
    autoreset_mode: &str,
    num_threads: Option<usize>,
) -> PyResult<u64> {
    let mode = self::autoreset_mode(autoreset_mode)?;
    let pool = thread_pool(num_threads)?;
    py.detach(|| {
        pool.install(|| {
            let mut env = build(id, num_envs, config.as_deref())?;
            env.set_autoreset_mode(mode)?;
            rollout_digest(env.as_mut(), seed, steps)
        })
    })
    .map_err(value_error)
}

/// Seconds `steps` lockstep steps of `num_envs` copies of `id` take in Rust alone, after
/// `reset(seed)` (not timed), every copy given `actions` (one copy's action, repeated): the
/// reference a Python stepping loop is measured against (`python/benchmarks/step_rate.py`).
#[pyfunction]
#[pyo3(signature = (id, num_envs, steps, seed, actions, config=None, autoreset_mode="next_step", num_threads=None))]
#[allow(clippy::too_many_arguments)]
fn rust_step_seconds(
    py: Python<'_>,
    id: &str,
    num_envs: usize,
    steps: usize,
    seed: u64,
    actions: Vec<f32>,
    config: Option<PathBuf>,
    autoreset_mode: &str,
    num_threads: Option<usize>,
) -> PyResult<f64> {
    let mode = self::autoreset_mode(autoreset_mode)?;
    let pool = thread_pool(num_threads)?;
    py.detach(|| {
        pool.install(|| {
            let mut env = build(id, num_envs, config.as_deref()).map_err(value_error)?;
            env.set_autoreset_mode(mode).map_err(value_error)?;
            let dim = env.spec().action.dim();
            if actions.len() != dim {
                return Err(value_error(format!(
                    "actions: {} values; expected one copy's action ({dim} values)",
                    actions.len()
                )));
            }
            let batch: Vec<f32> = actions
                .iter()
                .copied()
                .cycle()
                .take(dim * num_envs)
                .collect();
            let mut out = env.buffers();
            env.reset(seed, &mut out).map_err(value_error)?;
            let start = std::time::Instant::now();
            for _ in 0..steps {
                env.step(&batch, &mut out).map_err(value_error)?;
            }
            Ok(start.elapsed().as_secs_f64())
        })
    })
}

/// The native module.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<VecEnvCore>()?;
    m.add_class::<calibration::CalibrationObjective>()?;
    m.add_function(wrap_pyfunction!(calibration::sample_posterior, m)?)?;
    m.add_class::<profile::ProfileReference>()?;
    m.add_function(wrap_pyfunction!(rust_rollout_digest, m)?)?;
    m.add_function(wrap_pyfunction!(rust_step_seconds, m)?)?;
    m.add("IDS", IDS.to_vec())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    // Where the package was built from: the repository whose configs/ the defaults name.
    m.add("REPOSITORY", concat!(env!("CARGO_MANIFEST_DIR"), "/.."))?;
    Ok(())
}
