//! The saved state of a [`Transport`] for checkpoints: every copy's episode, random stream and
//! simulator state, and the settled variants, serialised with serde into [`EnvState::bytes`].
//! Checkpoints in the flat layout (numbers in [`EnvState::reals`] and [`EnvState::counters`],
//! snapshots in the bytes) are read as well.

use glam::DVec3;
use rlpkg_sim::EnvSnapshot;
use serde::{Deserialize, Serialize};

use super::episode::{Episode, Variant};
use super::sensors::CopySensors;
use super::{Transport, ID};
use crate::{rng_from_words, rng_to_words, EnvError, EnvState, RNG_WORDS};

/// Everything a [`Transport`] of the same configuration and size needs to continue exactly.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct SavedTransport {
    /// Each copy's episode.
    episodes: Vec<Episode>,
    /// Each copy's random stream, as [`rng_to_words`].
    rngs: Vec<[u64; RNG_WORDS]>,
    /// Each copy's simulator state.
    copies: Vec<EnvSnapshot>,
    /// The settled variants episodes start from.
    variants: Vec<Variant>,
    /// Each copy's sensors (`observation = "sensors"` only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    sensors: Option<Vec<CopySensors>>,
    /// Each variant's failure rate (`[transport.randomization.replay]` only).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    variant_failures: Vec<f64>,
}

/// Numbers per copy in the flat layout's reals.
const FLAT_REALS_PER_COPY: usize = 23;
/// Numbers per copy in the flat layout's counters before the random streams.
const FLAT_COUNTERS_PER_COPY: usize = 3;

impl SavedTransport {
    /// Reads the flat layout for `n` copies: `reals` holds each copy's episode (start offset,
    /// goal jitter, target tilt, progress, path speed, previous action, previous linear and
    /// angular acceleration, previous object position, start time, last advance); `counters`
    /// each copy's path, variant and steps, then each copy's random stream; `bytes` the JSON of
    /// the copies' snapshots followed by the variants' and the variants' tool starts.
    fn from_flat_layout(state: &EnvState, n: usize) -> Result<Self, String> {
        if state.reals.len() != n * FLAT_REALS_PER_COPY
            || state.counters.len() != n * (FLAT_COUNTERS_PER_COPY + RNG_WORDS)
        {
            return Err(format!(
                "expected {} reals and {} counters for {n} copies, got {} and {}",
                n * FLAT_REALS_PER_COPY,
                n * (FLAT_COUNTERS_PER_COPY + RNG_WORDS),
                state.reals.len(),
                state.counters.len()
            ));
        }
        let (mut copies, starts): (Vec<EnvSnapshot>, Vec<[f64; 3]>) =
            serde_json::from_slice(&state.bytes)
                .map_err(|e| format!("simulator snapshots: {e}"))?;
        if copies.len() != n + starts.len() {
            return Err(format!(
                "{} snapshots and {} variants for {n} copies",
                copies.len(),
                starts.len()
            ));
        }
        let variants = copies
            .split_off(n)
            .into_iter()
            .zip(starts)
            .map(|(snapshot, start)| Variant {
                snapshot,
                tool_start: DVec3::from_array(start),
            })
            .collect();
        let (counters, rng_words) = state.counters.split_at(n * FLAT_COUNTERS_PER_COPY);
        let episodes: Vec<Episode> = state
            .reals
            .chunks_exact(FLAT_REALS_PER_COPY)
            .zip(counters.chunks_exact(FLAT_COUNTERS_PER_COPY))
            .map(|(reals, counters)| {
                #[rustfmt::skip]
                let [
                    sx, sy, sz,
                    gx, gy, gz,
                    target_tilt, progress, path_speed,
                    a0, a1, a2,
                    ax, ay, az,
                    wx, wy, wz,
                    ox, oy, oz,
                    start_time, last_advance,
                ]: [f64; FLAT_REALS_PER_COPY] =
                    reals.try_into().map_err(|_| "episode numbers".to_string())?;
                let [path, variant, steps]: [u64; FLAT_COUNTERS_PER_COPY] = counters
                    .try_into()
                    .map_err(|_| "episode counters".to_string())?;
                Ok(Episode {
                    path: path as usize,
                    variant: variant as usize,
                    start_offset: DVec3::new(sx, sy, sz),
                    goal_jitter: DVec3::new(gx, gy, gz),
                    target_tilt,
                    progress,
                    path_speed,
                    last_advance,
                    previous_action: [a0, a1, a2],
                    previous_accel: DVec3::new(ax, ay, az),
                    previous_angular_accel: DVec3::new(wx, wy, wz),
                    previous_object_in_tool: DVec3::new(ox, oy, oz),
                    start_time,
                    steps: steps as usize,
                    // The flat layout predates the profile-rate action.
                    profile_clock: 0.0,
                })
            })
            .collect::<Result<_, String>>()?;
        let rngs: Vec<[u64; RNG_WORDS]> = rng_words
            .chunks_exact(RNG_WORDS)
            .map(|words| words.try_into().map_err(|_| "random streams".to_string()))
            .collect::<Result<_, String>>()?;
        Ok(Self {
            episodes,
            rngs,
            copies,
            variants,
            sensors: None,
            variant_failures: Vec::new(),
        })
    }
}

impl Transport {
    /// [`crate::VecEnv::save_state`]: the state as [`SavedTransport`] JSON in the bytes.
    pub(super) fn saved_state(&self) -> EnvState {
        let saved = SavedTransport {
            episodes: self.episodes.clone(),
            rngs: self.rngs.iter().map(rng_to_words).collect(),
            copies: (0..self.episodes.len())
                .map(|env| self.sim.snapshot(env))
                .collect(),
            variants: self.variants.clone(),
            sensors: self.sensors.as_ref().map(|s| s.copies.clone()),
            variant_failures: match self.config.randomization.replay {
                Some(_) => self.variant_failures.clone(),
                None => Vec::new(),
            },
        };
        EnvState {
            reals: Vec::new(),
            counters: Vec::new(),
            bytes: serde_json::to_vec(&saved).expect("plain data serialises"),
        }
    }

    /// [`crate::VecEnv::load_state`]: restores a state [`Transport::saved_state`] wrote, or one
    /// in the flat layout.
    pub(super) fn restore_saved(&mut self, state: &EnvState) -> Result<(), EnvError> {
        let n = self.episodes.len();
        let saved = if state.reals.is_empty() && state.counters.is_empty() {
            serde_json::from_slice(&state.bytes).map_err(|e| format!("saved state: {e}"))
        } else {
            SavedTransport::from_flat_layout(state, n)
        }
        .map_err(mismatch)?;
        self.restore(saved)
    }

    /// Puts `saved` into the simulator and the copies' episodes and streams.
    fn restore(&mut self, saved: SavedTransport) -> Result<(), EnvError> {
        let n = self.episodes.len();
        if saved.episodes.len() != n
            || saved.rngs.len() != n
            || saved.copies.len() != n
            || saved.variants.is_empty()
        {
            return Err(mismatch(format!(
                "{} episodes, {} random streams, {} simulator states and {} variants for {n} \
                 copies",
                saved.episodes.len(),
                saved.rngs.len(),
                saved.copies.len(),
                saved.variants.len()
            )));
        }
        match (&mut self.sensors, saved.sensors) {
            (None, None) => {}
            (Some(sensors), Some(copies)) if copies.len() == n => sensors.copies = copies,
            (ours, theirs) => {
                return Err(mismatch(format!(
                    "sensors: this environment {}, the saved state {}",
                    if ours.is_some() {
                        "has them"
                    } else {
                        "has none"
                    },
                    theirs.map_or("none".to_string(), |c| format!("{} copies", c.len()))
                )))
            }
        }
        for (env, (episode, snapshot)) in saved.episodes.iter().zip(&saved.copies).enumerate() {
            if episode.path >= self.paths.len() || episode.variant >= saved.variants.len() {
                return Err(mismatch(format!(
                    "copy {env}: path {} or variant {} out of range",
                    episode.path, episode.variant
                )));
            }
            self.sim
                .restore(env, snapshot)
                .map_err(|e| mismatch(e.to_string()))?;
        }
        self.episodes = saved.episodes;
        self.rngs = saved.rngs.iter().map(rng_from_words).collect();
        self.variant_failures = match saved.variant_failures.len() == saved.variants.len() {
            true => saved.variant_failures,
            false => vec![0.0; saved.variants.len()],
        };
        self.variants = saved.variants;
        self.retired.fill(false);
        // The plans follow from the episodes (planned the same way at their start).
        if self.profile_rate.is_some() {
            for env in 0..n {
                self.plan_profile(env)?;
            }
        }
        self.read_simulator()
    }
}

/// A saved state that does not fit this environment.
fn mismatch(reason: String) -> EnvError {
    EnvError::StateMismatch {
        env: ID.to_string(),
        reason,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::test_support::{env, history_table, sensors_table, test_table};
    use crate::VecEnv;

    /// `saved` in the flat layout [`SavedTransport::from_flat_layout`] reads.
    fn flat_layout(saved: &SavedTransport) -> EnvState {
        let mut reals = Vec::new();
        let mut counters = Vec::new();
        for e in &saved.episodes {
            reals.extend(e.start_offset.to_array());
            reals.extend(e.goal_jitter.to_array());
            reals.extend([e.target_tilt, e.progress, e.path_speed]);
            reals.extend(e.previous_action);
            reals.extend(e.previous_accel.to_array());
            reals.extend(e.previous_angular_accel.to_array());
            reals.extend(e.previous_object_in_tool.to_array());
            reals.extend([e.start_time, e.last_advance]);
            counters.extend([e.path as u64, e.variant as u64, e.steps as u64]);
        }
        counters.extend(saved.rngs.iter().flatten());
        let snapshots: Vec<&EnvSnapshot> = saved
            .copies
            .iter()
            .chain(saved.variants.iter().map(|v| &v.snapshot))
            .collect();
        let starts: Vec<[f64; 3]> = saved
            .variants
            .iter()
            .map(|v| v.tool_start.to_array())
            .collect();
        EnvState {
            reals,
            counters,
            bytes: serde_json::to_vec(&(snapshots, starts)).unwrap(),
        }
    }

    #[test]
    fn saved_state_continues_bit_identically() {
        for text in [test_table(), sensors_table(), history_table(2)] {
            continues_bit_identically(&text);
        }
        // A state saved without sensors does not fit an environment with them.
        let mut plain = env(&test_table(), 2);
        let mut out = plain.buffers();
        plain.try_reset(1, &mut out).unwrap();
        assert!(env(&sensors_table(), 2)
            .load_state(&plain.save_state())
            .is_err());
    }

    fn continues_bit_identically(text: &str) {
        let mut t = env(text, 2);
        let mut out = t.buffers();
        t.try_reset(11, &mut out).unwrap();
        let actions = [0.5f32, 0.1, -0.05, 0.3, -0.1, 0.0];
        for _ in 0..3 {
            t.step(&actions, &mut out).unwrap();
        }
        let saved = t.save_state();
        let mut copy = env(text, 2);
        copy.load_state(&saved).unwrap();
        let mut copy_out = out.clone();
        for _ in 0..4 {
            t.step(&actions, &mut out).unwrap();
            copy.step(&actions, &mut copy_out).unwrap();
            assert_eq!(out, copy_out);
            assert_eq!(t.info(), copy.info());
        }
        let mut wrong_size = env(text, 3);
        assert!(wrong_size.load_state(&saved).is_err());
    }

    #[test]
    fn a_state_in_the_flat_layout_continues_bit_identically() {
        let text = test_table();
        let mut t = env(&text, 2);
        let mut out = t.buffers();
        t.try_reset(4, &mut out).unwrap();
        let actions = [0.4f32, -0.1, 0.05, 0.6, 0.0, 0.1];
        for _ in 0..3 {
            t.step(&actions, &mut out).unwrap();
        }
        let saved = t.save_state();
        let decoded: SavedTransport = serde_json::from_slice(&saved.bytes).unwrap();
        let flat = flat_layout(&decoded);
        assert_eq!(flat.reals.len(), 2 * FLAT_REALS_PER_COPY);
        let mut copy = env(&text, 2);
        copy.load_state(&flat).unwrap();
        assert_eq!(copy.save_state(), saved);
        let mut copy_out = out.clone();
        for _ in 0..3 {
            t.step(&actions, &mut out).unwrap();
            copy.step(&actions, &mut copy_out).unwrap();
            assert_eq!(out, copy_out);
            assert_eq!(t.info(), copy.info());
        }
        let mut wrong_size = env(&text, 3);
        assert!(wrong_size.load_state(&flat).is_err());
    }
}
