//! [`EnvSnapshot`]: one environment's full state, taken from any environment of a batch and
//! restored into any environment of a batch on the same model.

use serde::{Deserialize, Serialize};

use crate::episode::EpisodeSpec;
use crate::error::SimError;

use super::block::LaneSnapshot;
use super::{validate_spec, Blocks, Simulator, LANES};

/// One environment's full state: its spec, particles, disc, cups and seals, tool and clock.
/// Restored into any environment of a batch built on the same model, it continues bit for bit as
/// the original would; it serialises with serde (e.g. for exact resume of training).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EnvSnapshot {
    /// The environment's spec (placement, parameters, masses, trajectory).
    pub spec: EpisodeSpec,
    /// Particles, cups and disc of the model it was taken from (checked on restore).
    shape: [usize; 3],
    /// Substep length of the model it was taken from (checked on restore).
    dt: f32,
    lane: LaneSnapshot,
}

impl EnvSnapshot {
    /// The environment's own time when the snapshot was taken (substeps since its episode began).
    pub fn substep(&self) -> u64 {
        self.lane.clock
    }
}

impl Simulator {
    /// A copy of environment `env`'s full state.
    pub fn snapshot(&self, env: usize) -> EnvSnapshot {
        let lane = with_lane!(self, env, |b, l| b.take_lane(l));
        EnvSnapshot {
            spec: self.specs[env].clone(),
            shape: self.shape(),
            dt: self.constants.dt,
            lane,
        }
    }

    fn shape(&self) -> [usize; 3] {
        [
            self.model.num_particles(),
            self.model.num_cup,
            self.model.num_cups(),
        ]
    }

    /// Puts `snapshot` into environment `env` (any environment of a batch on the same model):
    /// from here on `env` continues exactly as the snapshot's environment would have.
    pub fn restore(&mut self, env: usize, snapshot: &EnvSnapshot) -> Result<(), SimError> {
        self.check_env(env)?;
        let lane = &snapshot.lane;
        let consistent = snapshot.shape == self.shape()
            && snapshot.dt.to_bits() == self.constants.dt.to_bits()
            && [
                lane.x.len(),
                lane.v.len(),
                lane.x0.len(),
                lane.contact_point.len(),
                lane.contact_normal.len(),
            ]
            .iter()
            .all(|&n| n == self.model.num_particles())
            && lane.cup_offsets.len() == self.model.num_cup
            && lane.springs.len() == self.model.num_cup
            && lane.cups.len() == self.model.num_cups()
            && lane
                .springs
                .iter()
                .all(|s| (s.0 as usize) < self.model.num_package);
        if !consistent {
            return Err(SimError::Env {
                env,
                message: format!(
                    "snapshot of a different model ({} particles, {} cup particles, {} cups, \
                     dt {} s; this batch has {:?} and dt {} s)",
                    snapshot.shape[0],
                    snapshot.shape[1],
                    snapshot.shape[2],
                    snapshot.dt,
                    self.shape(),
                    self.constants.dt
                ),
            });
        }
        validate_spec(env, &snapshot.spec)?;
        let model = self.model.clone();
        with_block_mut!(self, env, |b| b.restore_env(
            env,
            &model,
            &snapshot.spec,
            lane
        ));
        self.specs[env] = snapshot.spec.clone();
        Ok(())
    }
}
