//! The reset and step loops of environments whose copies are independent and cheap to step one
//! at a time (CartPole, Pendulum): each environment says how one copy resets, steps and is
//! observed, and the loops apply the autoreset mode ([`crate::AutoresetMode`]) the same way for all.

use crate::{env_rng, Autoreset, EnvError, ResetCopies, StepBuffers};

/// One copy's dynamics, as the shared loops use them.
pub(crate) trait ClassicCopies {
    /// Observation width.
    const OBS_DIM: usize;
    /// The autoreset bookkeeping.
    fn autoreset(&mut self) -> &mut Autoreset;
    /// Replaces copy `env`'s random stream.
    fn reseed(&mut self, env: usize, rng: rand_chacha::ChaCha8Rng);
    /// Starts a new episode in copy `env` (drawn from its stream).
    fn reset_copy(&mut self, env: usize);
    /// Steps copy `env` with its (checked) action: reward, terminated, truncated.
    fn step_copy(&mut self, env: usize, action: &[f32]) -> (f32, bool, bool);
    /// Writes copy `env`'s observation into `row`.
    fn write_obs(&self, env: usize, row: &mut [f32]);
}

/// Restarts the copies `copies` chooses; rows of the others are left as they are.
pub(crate) fn reset<E: ClassicCopies>(
    env: &mut E,
    num_envs: usize,
    copies: ResetCopies,
    out: &mut StepBuffers,
) -> Result<(), EnvError> {
    copies.check(num_envs)?;
    for i in (0..num_envs).filter(|&i| copies.includes(i)) {
        if let Some(seed) = copies.seed_of(i) {
            env.reseed(i, env_rng(seed, 0));
        }
        env.reset_copy(i);
        env.autoreset().restarted(i);
        restart_row(env, i, out);
    }
    Ok(())
}

/// Steps every copy with its row of `actions` (`action_dim` values each, already checked).
pub(crate) fn step<E: ClassicCopies>(
    env: &mut E,
    actions: &[f32],
    action_dim: usize,
    out: &mut StepBuffers,
) -> Result<(), EnvError> {
    env.autoreset().check_step()?;
    for (i, action) in actions.chunks_exact(action_dim).enumerate() {
        if env.autoreset().restarts_now(i) {
            env.reset_copy(i);
            env.autoreset().restarted(i);
            restart_row(env, i, out);
            continue;
        }
        let (reward, terminated, truncated) = env.step_copy(i, action);
        let row = i * E::OBS_DIM..(i + 1) * E::OBS_DIM;
        env.write_obs(i, &mut out.final_obs[row.clone()]);
        if (terminated || truncated) && env.autoreset().episode_ended(i) {
            env.reset_copy(i);
        }
        env.write_obs(i, &mut out.obs[row]);
        out.rewards[i] = reward;
        out.terminated[i] = terminated;
        out.truncated[i] = truncated;
    }
    Ok(())
}

/// Copy `env`'s row right after it started an episode: its first observation, reward 0, no flag.
fn restart_row<E: ClassicCopies>(env: &E, i: usize, out: &mut StepBuffers) {
    let row = i * E::OBS_DIM..(i + 1) * E::OBS_DIM;
    env.write_obs(i, &mut out.obs[row.clone()]);
    out.final_obs[row.clone()].copy_from_slice(&out.obs[row]);
    out.rewards[i] = 0.0;
    out.terminated[i] = false;
    out.truncated[i] = false;
}

#[cfg(test)]
mod tests {
    use crate::{
        AutoresetMode, CartPole, EnvError, Pendulum, ResetCopies, Seeding, StepBuffers, VecEnv,
    };

    type Make = fn(usize) -> Box<dyn VecEnv>;
    const ENVS: [Make; 2] = [
        |n| Box::new(CartPole::new(n)),
        |n| Box::new(Pendulum::new(n)),
    ];

    fn started(make: Make, n: usize, mode: AutoresetMode) -> (Box<dyn VecEnv>, StepBuffers) {
        let mut env = make(n);
        env.set_autoreset_mode(mode).unwrap();
        let mut out = env.buffers();
        env.reset(11, &mut out).unwrap();
        (env, out)
    }

    fn row(values: &[f32], env: usize, dim: usize) -> &[f32] {
        &values[env * dim..(env + 1) * dim]
    }

    #[test]
    fn each_mode_around_an_episode_end() {
        for make in ENVS {
            let (mut same, mut a) = started(make, 2, AutoresetMode::SameStep);
            let (mut next, mut b) = started(make, 2, AutoresetMode::NextStep);
            let (mut off, mut c) = started(make, 2, AutoresetMode::Disabled);
            let dim = same.spec().observation.dim();
            let actions = [1.0, 0.0];
            // Up to the step the first episode of copy 0 ends, the three modes agree, except that
            // next-step and disabled copies show the terminal observation.
            let mut steps = 0;
            loop {
                steps += 1;
                same.step(&actions, &mut a).unwrap();
                next.step(&actions, &mut b).unwrap();
                off.step(&actions, &mut c).unwrap();
                for out in [&b, &c] {
                    assert_eq!(out.rewards, a.rewards);
                    assert_eq!(
                        (&out.terminated, &out.truncated),
                        (&a.terminated, &a.truncated)
                    );
                    assert_eq!(out.final_obs, a.final_obs);
                }
                if a.done(0) {
                    break;
                }
                assert_eq!((&b.obs, &c.obs), (&a.obs, &a.obs));
                assert!(!a.done(1) && steps < 500);
            }
            assert_eq!(row(&b.obs, 0, dim), row(&a.final_obs, 0, dim));
            assert_eq!(row(&c.obs, 0, dim), row(&a.final_obs, 0, dim));
            assert_ne!(row(&a.obs, 0, dim), row(&a.final_obs, 0, dim));
            let restart = row(&a.obs, 0, dim).to_vec();
            // Next step: copy 0 starts the episode same-step started a step earlier (its action
            // ignored), with reward 0 and no flag; copy 1 is stepped as ever.
            let mut lagged = same.save_state();
            same.step(&actions, &mut a).unwrap();
            next.step(&[0.0, 0.0], &mut b).unwrap();
            assert_eq!(row(&b.obs, 0, dim), &restart[..]);
            assert_eq!(row(&b.final_obs, 0, dim), &restart[..]);
            assert_eq!((b.rewards[0], b.done(0)), (0.0, false));
            for step in 0..5 {
                // From here on, copy 0 of next-step is copy 0 of same-step one step late.
                let state_then = lagged.clone();
                let mut replay = make(2);
                replay.load_state(&state_then).unwrap();
                let mut out = replay.buffers();
                replay.step(&actions, &mut out).unwrap();
                next.step(&actions, &mut b).unwrap();
                assert_eq!(row(&b.obs, 0, dim), row(&out.obs, 0, dim), "step {step}");
                assert_eq!(b.rewards[0], out.rewards[0], "step {step}");
                lagged = replay.save_state();
            }
            // Disabled: stepping the finished copy is an error until it is reset by mask.
            assert!(matches!(
                off.step(&actions, &mut c),
                Err(EnvError::FinishedCopy { env: 0 })
            ));
            let before = c.clone();
            let mask = [true, false];
            let copies = ResetCopies {
                mask: Some(&mask),
                seeding: Seeding::Continue,
            };
            off.reset_copies(copies, &mut c).unwrap();
            assert_eq!(row(&c.obs, 0, dim), &restart[..]);
            assert_eq!(row(&c.obs, 1, dim), row(&before.obs, 1, dim));
            assert_eq!((c.rewards[0], c.done(0)), (0.0, false));
            // Copy 1 may have ended in the same step (Pendulum's copies truncate together).
            match off.step(&actions, &mut c) {
                Err(EnvError::FinishedCopy { env: 1 }) => assert!(before.done(1)),
                other => assert!(other.is_ok() && !before.done(1)),
            }
        }
    }

    #[test]
    fn copies_are_seeded_one_by_one_and_a_mask_restarts_only_its_copies() {
        for make in ENVS {
            let (mut env, mut out) = started(make, 3, AutoresetMode::SameStep);
            let dim = env.spec().observation.dim();
            let seeds = [5, 40, 9];
            let copies = ResetCopies {
                mask: None,
                seeding: Seeding::PerCopy(&seeds),
            };
            env.reset_copies(copies, &mut out).unwrap();
            for (i, &seed) in seeds.iter().enumerate() {
                let mut one = make(1);
                let mut single = one.buffers();
                one.reset(seed, &mut single).unwrap();
                assert_eq!(row(&out.obs, i, dim), &single.obs[..]);
            }
            // A mask restarts copy 1 from seed 4 + 1; copies 0 and 2 run on as if nothing
            // happened.
            let (mut reference, mut expected) = started(make, 3, AutoresetMode::SameStep);
            let (mut masked, mut got) = started(make, 3, AutoresetMode::SameStep);
            let actions = [1.0, 0.0, 1.0];
            for _ in 0..3 {
                reference.step(&actions, &mut expected).unwrap();
                masked.step(&actions, &mut got).unwrap();
            }
            let before = got.clone();
            let mask = [false, true, false];
            let copies = ResetCopies {
                mask: Some(&mask),
                seeding: Seeding::Base(4),
            };
            masked.reset_copies(copies, &mut got).unwrap();
            let mut fresh = make(3);
            let mut fresh_out = fresh.buffers();
            fresh.reset(4, &mut fresh_out).unwrap();
            assert_eq!(row(&got.obs, 1, dim), row(&fresh_out.obs, 1, dim));
            for i in [0, 2] {
                assert_eq!(row(&got.obs, i, dim), row(&before.obs, i, dim));
                assert_eq!(got.rewards[i], before.rewards[i]);
            }
            for _ in 0..5 {
                reference.step(&actions, &mut expected).unwrap();
                masked.step(&actions, &mut got).unwrap();
                for i in [0, 2] {
                    assert_eq!(row(&got.obs, i, dim), row(&expected.obs, i, dim));
                }
            }
            let short = [true];
            let wrong = ResetCopies {
                mask: Some(&short),
                seeding: Seeding::Continue,
            };
            assert!(matches!(
                masked.reset_copies(wrong, &mut got),
                Err(EnvError::BatchLength { .. })
            ));
        }
    }
}
