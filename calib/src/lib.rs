//! Real-to-sim calibration for rlpkg.
//!
//! * [`gp`] — an exact Gaussian process (Matérn 5/2, ARD, learned noise) on nalgebra;
//! * [`space`] — named parameters with bounds, log scale, unit-cube mapping;
//! * [`bo`] — batched Bayesian optimisation (EI / confidence bound, Kriging believer), ask/tell;
//! * [`evallog`] — the resumable CSV log of evaluations;
//! * [`driver`] — the calibration loop (ask, evaluate, log, tell) and its output files;
//! * [`fisher`] — identifiability at a fit: the Fisher information's eigen-directions;
//! * [`fingerprint`] — the objective a calibration folder fits, checked when it is resumed;
//! * [`posterior`] — an approximate posterior from a calibration's evaluations (BOLFI);
//! * [`validation`] — a posterior's draws replayed on the simulator, kept where they fit;
//! * [`predictive`] — the posterior-predictive Table 1 of a posterior's draws;
//! * [`spread_check`] — how far nudged replays move beside the recordings' marker noise;
//! * [`posterior_files`] — a posterior folder's `samples.csv` and `summary.json`, read and written;
//! * [`recovery`] — parameter recovery: calibrating synthetic recordings of known parameters back;
//! * [`sampled_posterior`] — a calibration that returns the posterior (SMC on the simulator);
//! * [`smc`] — adaptive tempered sequential Monte Carlo: a posterior evaluated by the simulator;
//! * [`cmaes`] — CMA-ES with ask-and-tell: the search for the mode the sampler may start from;
//! * [`polish`] — Levenberg–Marquardt steps from the best draw to the mode;
//! * [`mcmc`] — the affine-invariant ensemble sampler the posterior draws with;
//! * [`objective`] — the batched-simulator objective (candidates x trajectories = environments);
//! * [`config`] — `configs/calibrate/study.toml`;
//! * [`seal_fit`] — the seal's capacity fitted to a dataset's failure flags (`configs/seal/*.toml`);
//!
//! The replay set-up (scene, targets, batched rollouts), the losses, the likelihood and the
//! evaluation helpers live in `rlpkg-replay`, which this crate builds on.

pub mod bo;
pub mod cmaes;
pub mod config;
pub mod driver;
pub mod evallog;
pub mod fingerprint;
pub mod fisher;
pub mod gp;
pub mod mcmc;
pub mod objective;
pub mod polish;
pub mod posterior;
pub mod posterior_files;
pub mod predictive;
pub mod recovery;
pub mod sampled_posterior;
pub mod seal_fit;
pub mod smc;
pub mod space;
pub mod spread_check;
pub mod validation;
