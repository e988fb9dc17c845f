//! Real-to-sim calibration for rlpkg.
//!
//! * [`gp`] — an exact Gaussian process (Matérn 5/2, ARD, learned noise) on nalgebra;
//! * [`space`] — named parameters with bounds, log scale, unit-cube mapping;
//! * [`bo`] — batched Bayesian optimisation (EI / confidence bound, Kriging believer), ask/tell;
//! * [`evallog`] — the resumable CSV log of evaluations;
//! * [`driver`] — the calibration loop (ask, evaluate, log, tell) and its output files;
//! * [`posterior`] — an approximate posterior from a calibration's evaluations (BOLFI);
//! * [`recovery`] — parameter recovery: calibrating synthetic recordings of known parameters back;
//! * [`mcmc`] — the affine-invariant ensemble sampler the posterior draws with;
//! * [`objective`] — the batched-simulator objective (candidates x trajectories = environments);
//! * [`config`] — `configs/calibrate/study.toml`;
//!
//! The replay set-up (scene, targets, batched rollouts), the structured loss ([`loss`]) and the
//! evaluation helpers ([`evaluate`]) live in `rlpkg-replay`, which this crate builds on.

pub mod bo;
pub mod config;
pub mod driver;
pub mod evallog;
pub mod gp;
pub mod mcmc;
pub mod objective;
pub mod posterior;
pub mod recovery;
pub mod space;

/// The loss and the evaluation helpers live with the replay set-up; re-exported under their old
/// paths.
pub use rlpkg_replay::{evaluate, loss};
