//! Real-to-sim calibration for rlpkg (issue 4).
//!
//! * [`loss`] — the paper's structured loss (Chamfer distance of the package, eq. 2; object squared
//!   error, eq. 3), per frame, and the Table 1 statistics;
//! * [`gp`] — an exact Gaussian process (Matérn 5/2, ARD, learned noise) on nalgebra;
//! * [`space`] — named parameters with bounds, log scale, unit-cube mapping;
//! * [`bo`] — batched Bayesian optimisation (EI / confidence bound, Kriging believer), ask/tell;
//! * [`evallog`] — the resumable CSV log of evaluations;
//! * [`driver`] — the calibration loop (ask, evaluate, log, tell) and its output files;
//! * [`objective`] — the batched-simulator objective (candidates x trajectories = environments);
//! * [`config`] — `configs/calibrate.toml`;
//! * [`evaluate`] — helpers of `rlpkg eval --params` (per-marker errors, perturbations, real-time factor).

pub mod bo;
pub mod config;
pub mod driver;
pub mod evallog;
pub mod evaluate;
pub mod gp;
pub mod loss;
pub mod objective;
pub mod space;
