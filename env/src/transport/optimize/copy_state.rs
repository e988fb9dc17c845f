//! What the open-loop optimisation's candidates and receding-horizon control's searches start
//! from: [`CopyState`], the replica of a copy's episode.

use rand_chacha::ChaCha8Rng;
use rlpkg_sim::EnvSnapshot;

use crate::transport::episode::Episode;
use crate::transport::sensors::CopySensors;
use crate::transport::{sim_error, Transport};
use crate::EnvError;

/// One copy's episode at a moment (its draw, random stream, simulator state and sensors), to
/// restore into any copy of a [`Transport`] on the same model.
#[derive(Debug, Clone)]
pub(super) struct CopyState {
    episode: Episode,
    rng: ChaCha8Rng,
    snapshot: EnvSnapshot,
    sensors: Option<CopySensors>,
}

impl CopyState {
    /// Copy `k` of `env` now.
    pub(super) fn capture(env: &Transport, k: usize) -> Self {
        Self {
            episode: env.episodes[k],
            rng: env.rngs[k].clone(),
            snapshot: env.sim.snapshot(k),
            sensors: env.sensors.as_ref().map(|s| s.copies[k].clone()),
        }
    }

    /// Puts this state into copy `copy` of `env` (un-retired; call `read_simulator` after the
    /// last restore of a batch).
    pub(super) fn restore_into(&self, env: &mut Transport, copy: usize) -> Result<(), EnvError> {
        env.sim.restore(copy, &self.snapshot).map_err(sim_error)?;
        env.episodes[copy] = self.episode;
        env.rngs[copy] = self.rng.clone();
        if let (Some(sensors), Some(saved)) = (&mut env.sensors, &self.sensors) {
            sensors.copies[copy] = saved.clone();
        }
        env.retired[copy] = false;
        Ok(())
    }
}
