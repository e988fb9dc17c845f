//! Recorded trajectories as simulator set-ups, shared by `rlpkg simulate`, `rlpkg eval --params`,
//! calibration (`rlpkg-calib`), the transport task and the benchmark, none of which needs to depend
//! on another for it.
//!
//! * [`target`]: the scene presets with grid and time-step overrides ([`load_scene`]) and a recording
//!   prepared for replay ([`Target`]: placement, tool motion, the frames to compare);
//! * [`rollout`]: named simulator parameters ([`Candidate`]) and the batched rollout of candidates x
//!   recordings, with per-frame hooks ([`Observer`]) and, for pictures, extra stops and the clock of
//!   the compared frames ([`Schedule`], [`FrameClock`]);
//! * [`loss`]: the comparison with the recording: the package Chamfer distance (the one
//!   implementation in the workspace), the labelled site error, the object error, the paper's
//!   Table 1;
//! * [`package_scene`]: a scene from a take collection's `manifest.json` (geometry from the
//!   manifest, the rest from a base scene);
//! * [`phase`]: the phases of a recorded motion (rest, lift, move, tilt, hold);
//! * [`likelihood`]: the labelled, phase-balanced log-likelihood a posterior samples;
//! * [`seal`]: seal calibration: every recording under a grid of seal capacities against the
//!   recordings' failure flags and the detachment observed in their markers;
//! * [`evaluate`]: per-marker errors, the sensitivity perturbation, the real-time factor;
//! * [`synthetic`]: synthetic recordings made by the simulator from known parameters, with a real
//!   recording's occlusion and marker noise (parameter-recovery checks);
//! * [`workload`]: many different, moving environments from the recordings (randomised masses),
//!   e.g. for `rlpkg bench sim`;
//! * [`error`]: what can go wrong ([`ReplayError`]).

#![warn(missing_docs)]

pub mod error;
pub mod evaluate;
pub mod likelihood;
pub mod loss;
pub mod package_scene;
pub mod phase;
pub mod rollout;
pub mod seal;
pub mod synthetic;
pub mod target;
#[cfg(test)]
mod test_support;
pub mod workload;

pub use error::ReplayError;
pub use likelihood::{Likelihood, LikelihoodSettings};
pub use phase::Phase;
pub use rollout::{
    get_param, mean_loss, rollout, rollout_scheduled, set_param, Candidate, FrameClock,
    FrameObservation, Observer, RolloutOutcome, Schedule, SealFailure, PARAMETER_NAMES,
};
pub use target::{grid_between_markers, load_scene, Target};
