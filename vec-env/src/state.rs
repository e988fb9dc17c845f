//! Saved environment state ([`EnvState`]) and the per-copy random streams, as plain numbers.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::EnvError;

/// A snapshot of a vectorised environment as plain numbers: real-valued state and integer
/// counters (step counters and random-stream positions), in an order each environment defines.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct EnvState {
    /// Real-valued state (positions, velocities, ...).
    pub reals: Vec<f64>,
    /// Integer state (elapsed steps, random streams as [`rng_to_words`]).
    pub counters: Vec<u64>,
    /// Serialised state that is neither (e.g. simulator snapshots); empty for simple environments.
    pub bytes: Vec<u8>,
}

/// Number of words [`rng_to_words`] produces.
pub const RNG_WORDS: usize = 7;

/// A ChaCha8 stream as plain words: seed (4), stream (1), word position (2).
pub fn rng_to_words(rng: &ChaCha8Rng) -> [u64; RNG_WORDS] {
    let seed = rng.get_seed();
    let word = |k: usize| u64::from_le_bytes(seed[8 * k..8 * k + 8].try_into().expect("8 bytes"));
    let pos = rng.get_word_pos();
    [
        word(0),
        word(1),
        word(2),
        word(3),
        rng.get_stream(),
        pos as u64,
        (pos >> 64) as u64,
    ]
}

/// The ChaCha8 stream written by [`rng_to_words`], at the same position.
pub fn rng_from_words(words: &[u64; RNG_WORDS]) -> ChaCha8Rng {
    let mut seed = [0u8; 32];
    for k in 0..4 {
        seed[8 * k..8 * k + 8].copy_from_slice(&words[k].to_le_bytes());
    }
    let mut rng = ChaCha8Rng::from_seed(seed);
    rng.set_stream(words[4]);
    rng.set_word_pos(words[5] as u128 | ((words[6] as u128) << 64));
    rng
}

/// The random stream of copy `env` for a reset with `seed`.
pub fn env_rng(seed: u64, env: usize) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed.wrapping_add(env as u64))
}

/// Packs per-copy real columns, step counters and random streams into an [`EnvState`].
pub(crate) fn pack_state(columns: &[&[f64]], steps: &[usize], rngs: &[ChaCha8Rng]) -> EnvState {
    EnvState {
        reals: columns.iter().flat_map(|c| c.iter().copied()).collect(),
        counters: steps
            .iter()
            .map(|&s| s as u64)
            .chain(rngs.iter().flat_map(rng_to_words))
            .collect(),
        bytes: Vec::new(),
    }
}

/// Unpacks an [`EnvState`] written by [`pack_state`] into the same columns, counters and streams.
pub(crate) fn unpack_state(
    id: &str,
    state: &EnvState,
    columns: &mut [&mut Vec<f64>],
    steps: &mut [usize],
    rngs: &mut [ChaCha8Rng],
) -> Result<(), EnvError> {
    let n = steps.len();
    if state.reals.len() != columns.len() * n || state.counters.len() != n * (1 + RNG_WORDS) {
        return Err(EnvError::StateMismatch {
            env: id.to_string(),
            reason: format!(
                "expected {} reals and {} counters for {n} copies, got {} and {}",
                columns.len() * n,
                n * (1 + RNG_WORDS),
                state.reals.len(),
                state.counters.len()
            ),
        });
    }
    for (c, column) in columns.iter_mut().enumerate() {
        column.copy_from_slice(&state.reals[c * n..(c + 1) * n]);
    }
    for (i, step) in steps.iter_mut().enumerate() {
        *step = state.counters[i] as usize;
    }
    for (i, rng) in rngs.iter_mut().enumerate() {
        let words = &state.counters[n + i * RNG_WORDS..n + (i + 1) * RNG_WORDS];
        *rng = rng_from_words(words.try_into().expect("RNG_WORDS words"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{CartPole, Pendulum, VecEnv};

    #[test]
    fn saved_state_continues_bit_identically() {
        let make: [fn(usize) -> Box<dyn VecEnv>; 2] = [
            |n| Box::new(CartPole::new(n)),
            |n| Box::new(Pendulum::new(n)),
        ];
        for make in make {
            let mut env = make(3);
            let id = env.spec().id.clone();
            let mut out = env.buffers();
            env.reset(9, &mut out).unwrap();
            let actions = vec![1.0; 3];
            for _ in 0..30 {
                env.step(&actions, &mut out).unwrap();
            }
            let saved = env.save_state();
            let mut copy = make(3);
            copy.load_state(&saved).unwrap();
            let mut copy_out = out.clone();
            for _ in 0..300 {
                env.step(&actions, &mut out).unwrap();
                copy.step(&actions, &mut copy_out).unwrap();
                assert_eq!(out, copy_out, "{id}");
            }
            let mut wrong_size = make(2);
            assert!(wrong_size.load_state(&saved).is_err());
        }
    }

    #[test]
    fn rng_words_round_trip() {
        use rand::Rng;
        let mut rng = env_rng(5, 2);
        let _: [u64; 3] = [rng.random(), rng.random(), rng.random()];
        let mut copy = rng_from_words(&rng_to_words(&rng));
        assert_eq!(rng.random::<u64>(), copy.random::<u64>());
    }
}
