//! `rlpkg optimize`: sampling-based trajectory optimisation of the transport task's open-loop
//! command, the cross-entropy method (CEM) over the knots of smooth curves in time of the three
//! actions (path speed, tilt offsets about x and z), scored by rolling every candidate out in the
//! simulator; and receding-horizon control with the same search (`--mpc`).
//!
//! From the bottom up:
//! - `curve`: the decision variables (knot curves of the three actions) and command libraries;
//! - `cem`: the cross-entropy method's sampling distribution, and the risk over the packages;
//! - `copy_state`: one copy's episode at a moment, replayed in other copies;
//! - `config`: the config of `rlpkg optimize`;
//! - `output`: the files of `rlpkg optimize`, and their reader;
//! - `open_loop`: the candidates' rollouts, and the iterations of `rlpkg optimize`;
//! - `mpc`: receding-horizon control (`rlpkg optimize --mpc`).
//!
//! The module lives beside the task because a candidate's copy is a replica of another copy's
//! episode (its draw, its random stream, its simulator state): that needs the task's own
//! per-copy state, which the public surface does not expose.

pub(super) mod cem;
pub(super) mod config;
mod copy_state;
pub(super) mod curve;
pub(super) mod mpc;
pub(super) mod open_loop;
pub(super) mod output;
