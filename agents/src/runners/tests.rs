//! Runner tests: checkpoints, determinism across thread counts, resume, and learning CartPole.

use std::path::Path;

use rlpkg_vec_env::{CartPole, VecEnv};

use super::*;
use crate::config::tests::{classic_env, CARTPOLE_TEST};
use crate::config::{config_hash, read_config_text, TrainConfig};
use crate::AgentError;

fn config(text: &str) -> TrainConfig {
    TrainConfig::parse(text, Path::new("test.toml")).unwrap()
}

fn trainer(text: &str) -> Trainer {
    let config = config(text);
    let env = classic_env(&config.run.env, config.run.num_envs);
    Trainer::new(config, text.to_string(), env).unwrap()
}

/// The configuration of the run in `dir`, with its text.
fn run_config(dir: &Path) -> Result<(TrainConfig, String), AgentError> {
    let path = run_config_path(dir)?;
    let text = read_config_text(&path)?;
    Ok((TrainConfig::parse(&text, &path)?, text))
}

/// The trainer of the classic-control run in `dir`, continued from its latest checkpoint.
fn resume(dir: &Path) -> Result<Trainer, AgentError> {
    let (config, text) = run_config(dir)?;
    let env = classic_env(&config.run.env, config.run.num_envs);
    let mut trainer = Trainer::new(config, text, env)?;
    trainer.load_checkpoint(dir)?;
    Ok(trainer)
}

/// The policy of the latest checkpoint in `dir`, read without an environment.
fn checkpointed_policy(dir: &Path) -> TrainedPolicy {
    let (config, text) = run_config(dir).unwrap();
    let spec = classic_env(&config.run.env, 1).spec().clone();
    TrainedPolicy::load(dir, &config, &config_hash(&text), &spec).unwrap()
}

/// `episodes` deterministic episodes of the latest checkpoint in `dir` from `seed`.
fn evaluate(dir: &Path, episodes: usize, seed: u64) -> EvalSummary {
    let policy = checkpointed_policy(dir);
    let mut env = classic_env(&policy.spec.id, episodes);
    policy.evaluate(env.as_mut(), seed).unwrap()
}

#[test]
fn checkpoint_round_trip_is_bit_identical() {
    let dir = tempfile::tempdir().unwrap();
    let mut original = trainer(CARTPOLE_TEST);
    original.create_run_dir(dir.path()).unwrap();
    original.train(dir.path(), Some(2), false).unwrap();
    let restored = resume(dir.path()).unwrap();
    let (a, b) = (
        original.ppo.model.flat_parameters(),
        restored.ppo.model.flat_parameters(),
    );
    assert_eq!(a.len(), b.len());
    assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
    assert_eq!((restored.update, restored.global_step), (2, 512));
    assert_eq!(restored.obs_stats, original.obs_stats);
    assert_eq!(restored.reward_norm, original.reward_norm);
    assert_eq!(restored.buffers, original.buffers);
    assert_eq!(
        restored.ppo.learning_rate.to_bits(),
        original.ppo.learning_rate.to_bits()
    );
    assert_eq!(
        latest_checkpoint(dir.path()).unwrap().file_name().unwrap(),
        "update_000002"
    );
}

#[test]
fn a_stopped_run_checkpoints_the_update_it_stopped_after() {
    // checkpoint_every = 2: update 3 is checkpointed only because training stops after it.
    let dir = tempfile::tempdir().unwrap();
    let mut t = trainer(CARTPOLE_TEST);
    t.create_run_dir(dir.path()).unwrap();
    let asked = std::cell::Cell::new(0);
    let stop = || {
        asked.set(asked.get() + 1);
        asked.get() == 3
    };
    let summary = t.train_until(dir.path(), None, false, &stop).unwrap();
    assert!(summary.stopped);
    assert_eq!((summary.updates, asked.get()), (3, 3));
    assert_eq!(
        latest_checkpoint(dir.path()).unwrap().file_name().unwrap(),
        "update_000003"
    );
    let resumed = resume(dir.path()).unwrap();
    assert_eq!((resumed.update, resumed.global_step), (3, 768));
    assert!(!t.train(dir.path(), None, false).unwrap().stopped);
}

#[test]
fn resume_continues_exactly_like_an_uninterrupted_run() {
    let (straight_dir, split_dir) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let mut straight = trainer(CARTPOLE_TEST);
    straight.create_run_dir(straight_dir.path()).unwrap();
    let mut straight_logs = Vec::new();
    for _ in 0..4 {
        straight_logs.push(straight.run_update().unwrap());
    }

    let mut first_half = trainer(CARTPOLE_TEST);
    first_half.create_run_dir(split_dir.path()).unwrap();
    first_half.train(split_dir.path(), Some(2), false).unwrap();
    drop(first_half);
    let mut resumed = resume(split_dir.path()).unwrap();
    let resumed_logs: Vec<UpdateLog> = (0..2).map(|_| resumed.run_update().unwrap()).collect();

    assert_eq!(resumed_logs, straight_logs[2..]);
    let (a, b) = (
        straight.ppo.model.flat_parameters(),
        resumed.ppo.model.flat_parameters(),
    );
    assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
}

#[test]
fn same_seed_same_first_updates_on_one_and_two_threads() {
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut t = trainer(CARTPOLE_TEST);
            let logs: Vec<UpdateLog> = (0..2).map(|_| t.run_update().unwrap()).collect();
            (logs, t.ppo.model.flat_parameters())
        })
    };
    let (logs_1, params_1) = run(1);
    let (logs_2, params_2) = run(2);
    assert_eq!(logs_1, logs_2);
    assert!(params_1
        .iter()
        .zip(&params_2)
        .all(|(x, y)| x.to_bits() == y.to_bits()));
    // A different seed gives a different run.
    let mut other = trainer(&CARTPOLE_TEST.replace("seed = 1", "seed = 2"));
    let other_log = other.run_update().unwrap();
    assert_ne!(other_log.stats, logs_1[0].stats);
}

#[test]
fn burn_policy_and_policy_graph_act_alike() {
    for text in [
        CARTPOLE_TEST.to_string(),
        CARTPOLE_TEST
            .replace("CartPole-v1", "Pendulum-v1")
            .replace("\"clip\"", "\"tanh_scale\""),
    ] {
        let mut t = trainer(&text);
        t.run_update().unwrap();
        let policy = TrainedPolicy::from_trainer(&t);
        let graph = policy.policy_graph();
        let dim = t.spec().observation.dim();
        let obs: Vec<f32> = (0..64 * dim)
            .map(|k| ((k * 37 % 101) as f32 / 50.0) - 1.0)
            .collect();
        let (burn_actions, graph_actions) = (policy.act(&obs, 64), graph.act(&obs, 64));
        assert_eq!(burn_actions.len(), 64 * t.spec().action.dim());
        for (a, b) in burn_actions.iter().zip(&graph_actions) {
            assert!((a - b).abs() < 1e-5, "{a} vs {b}");
        }
        graph.validate().unwrap();
    }
}

#[test]
fn a_policy_read_from_its_checkpoint_is_the_trainers() {
    for text in [
        CARTPOLE_TEST.to_string(),
        CARTPOLE_TEST
            .replace("CartPole-v1", "Pendulum-v1")
            .replace("\"clip\"", "\"tanh_scale\""),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let mut t = trainer(&text);
        t.create_run_dir(dir.path()).unwrap();
        t.train(dir.path(), Some(2), false).unwrap();
        let (trained, read) = (
            TrainedPolicy::from_trainer(&t),
            checkpointed_policy(dir.path()),
        );
        assert_eq!(
            trained.model.flat_parameters(),
            read.model.flat_parameters()
        );
        assert_eq!(trained.policy_graph(), read.policy_graph());
        assert_eq!((read.update, read.global_step), (2, 512));
        let id = &read.spec.id;
        let (a, b) = (
            trained.evaluate(classic_env(id, 3).as_mut(), 4).unwrap(),
            read.evaluate(classic_env(id, 3).as_mut(), 4).unwrap(),
        );
        assert_eq!(
            (a.mean_return, a.mean_length, a.update),
            (b.mean_return, b.mean_length, b.update)
        );
    }
}

#[test]
fn bad_run_folders_are_reported() {
    let dir = tempfile::tempdir().unwrap();
    let err = resume(dir.path()).err().unwrap();
    assert!(
        err.is_input_error() && err.to_string().contains("not a run folder"),
        "{err}"
    );
    let mut t = trainer(CARTPOLE_TEST);
    t.create_run_dir(dir.path()).unwrap();
    assert!(t
        .create_run_dir(dir.path())
        .unwrap_err()
        .to_string()
        .contains("already holds a run"));
    let err = resume(dir.path()).err().unwrap();
    assert!(err.to_string().contains("no checkpoint"), "{err}");
    t.train(dir.path(), Some(1), false).unwrap();
    std::fs::write(
        dir.path().join("config.toml"),
        CARTPOLE_TEST.replace("seed = 1", "seed = 5"),
    )
    .unwrap();
    let err = resume(dir.path()).err().unwrap();
    assert!(
        err.to_string().contains("differs from the configuration"),
        "{err}"
    );
    assert!(
        err.to_string()
            .contains("is `seed = 5`, trained with `seed = 1`"),
        "{err}"
    );
}

#[test]
fn first_differing_line_names_the_line_and_both_texts() {
    use super::checkpoint::first_differing_line;
    assert_eq!(
        first_differing_line("a = 1\nb = 2\n", "a = 1\nb = 3\n"),
        ": line 2 is `b = 3`, trained with `b = 2`"
    );
    assert_eq!(
        first_differing_line("a = 1\n", "a = 1\nc = 4\n"),
        ": line 2 is `c = 4`, trained with the end of the file"
    );
    assert!(first_differing_line("a = 1\n", "a = 1").contains("line endings"));
}

#[test]
fn short_cartpole_training_beats_random_play() {
    // Random play lasts ~22 steps on average; this run reaches well above that in seconds.
    let text = CARTPOLE_TEST
        .replace("num_envs = 4", "num_envs = 8")
        .replace("total_steps = 2048", "total_steps = 40960")
        .replace("rollout_steps = 64", "rollout_steps = 128")
        .replace("epochs = 2", "epochs = 4")
        .replace("learning_rate = 2.5e-3", "learning_rate = 1e-3")
        .replace("rewards = true", "rewards = false");
    let dir = tempfile::tempdir().unwrap();
    let mut t = trainer(&text);
    t.create_run_dir(dir.path()).unwrap();
    t.train(dir.path(), None, false).unwrap();
    let eval = evaluate(dir.path(), 20, 1000);
    assert!(
        eval.mean_return > 100.0,
        "deterministic mean return {}",
        eval.mean_return
    );
}

#[test]
fn shipped_cartpole_config_reaches_475() {
    // `configs/train/cartpole.toml` as shipped (seed 1, 500k steps; ~20 s alone on 2 cores), then
    // 100 greedy episodes. Runs are bit-exact, so this is one fixed trajectory: any change to
    // the trainer's arithmetic re-rolls it (seeds 1-25 all reached 500.0 when this was written).
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../configs/train/cartpole.toml"
    );
    let text = std::fs::read_to_string(path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut t = trainer(&text);
    t.create_run_dir(dir.path()).unwrap();
    let summary = t.train(dir.path(), None, false).unwrap();
    assert_eq!(summary.global_step, 499_712);
    let eval = evaluate(dir.path(), 100, 0);
    assert!(
        eval.mean_return >= 475.0,
        "deterministic mean return {} +- {} (min {})",
        eval.mean_return,
        eval.std_return,
        eval.min_return
    );
}

#[test]
fn update_timing_splits_rollout_environment_and_update_phases() {
    let mut t = trainer(CARTPOLE_TEST);
    t.run_update().unwrap();
    let timing = t.timing;
    assert!(timing.rollout > 0.0 && timing.update > 0.0, "{timing:?}");
    assert!(
        timing.env_step > 0.0 && timing.env_step < timing.rollout,
        "{timing:?}"
    );
    let phases = timing.phases;
    assert!(
        phases.forward > 0.0 && phases.backward > 0.0 && phases.optimiser > 0.0,
        "{phases:?}"
    );
    assert!(phases.total() <= timing.update, "{timing:?}");
}

/// Event files of a run folder, in name order (TensorBoard's reading order).
fn event_files(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.to_string_lossy().contains("tfevents"))
        .collect();
    files.sort();
    files
}

#[test]
fn resume_after_a_lost_checkpoint_logs_each_update_once() {
    let dir = tempfile::tempdir().unwrap();
    let mut first = trainer(CARTPOLE_TEST);
    first.create_run_dir(dir.path()).unwrap();
    first.train(dir.path(), Some(3), false).unwrap();
    drop(first);
    // As if killed after update 3 was logged but before its checkpoint was named in `latest`.
    std::fs::write(dir.path().join("checkpoints/latest"), "update_000002").unwrap();
    let logged_before = read_scalars(&event_files(dir.path())[0]).unwrap();
    assert!(logged_before.iter().any(|e| e.step == 768));

    let mut resumed = resume(dir.path()).unwrap();
    assert_eq!(resumed.update, 2);
    resumed.train(dir.path(), Some(4), false).unwrap();
    let files = event_files(dir.path());
    assert_eq!(files.len(), 1, "the resumed run continues the same file");
    let events = read_scalars(&files[0]).unwrap();
    let steps: Vec<i64> = events
        .iter()
        .filter(|e| e.tag == "losses/value_loss")
        .map(|e| e.step)
        .collect();
    assert_eq!(steps, [256, 512, 768, 1024]);
    // The records of the first update 3 were cut, not kept beside the new ones.
    let sps = events.iter().filter(|e| e.tag == "charts/SPS").count();
    assert_eq!(sps, 4);
}

/// CartPole with observation groups: the actor sees `actor_dims` of CartPole's four values, the
/// critic all four plus the fraction of the episode's step limit used (or, with
/// `critic_copies_actor`, exactly the actor's values).
struct GroupedCartPole {
    inner: CartPole,
    spec: rlpkg_vec_env::EnvSpec,
    inner_buffers: rlpkg_vec_env::StepBuffers,
    actor_dims: Vec<usize>,
    critic_copies_actor: bool,
    steps: Vec<usize>,
}

impl GroupedCartPole {
    fn new(num_envs: usize, actor_dims: &[usize], critic_copies_actor: bool) -> Self {
        let inner = CartPole::new(num_envs);
        let full = inner.spec().observation.clone();
        let pick = |dims: &[usize]| rlpkg_vec_env::Space {
            kind: full.kind.clone(),
            names: dims.iter().map(|&d| full.names[d].clone()).collect(),
            units: dims.iter().map(|&d| full.units[d].clone()).collect(),
            low: dims.iter().map(|&d| full.low[d]).collect(),
            high: dims.iter().map(|&d| full.high[d]).collect(),
        };
        let observation = pick(actor_dims);
        let critic = if critic_copies_actor {
            observation.clone()
        } else {
            let mut critic = full.clone();
            critic.names.push("episode_fraction".into());
            critic.units.push("1".into());
            critic.low.push(0.0);
            critic.high.push(1.0);
            critic
        };
        let spec = rlpkg_vec_env::EnvSpec {
            id: "GroupedCartPole".into(),
            observation,
            critic_observation: Some(critic),
            ..inner.spec().clone()
        };
        Self {
            inner_buffers: inner.buffers(),
            inner,
            spec,
            actor_dims: actor_dims.to_vec(),
            critic_copies_actor,
            steps: vec![0; num_envs],
        }
    }

    fn fill(&self, full: &[f32], steps: &[usize], obs: &mut [f32], critic: &mut [f32]) {
        let (a, c) = (self.actor_dims.len(), self.spec.critic_obs_dim());
        for (env, row) in full.chunks_exact(4).enumerate() {
            for (k, &d) in self.actor_dims.iter().enumerate() {
                obs[env * a + k] = row[d];
            }
            let critic_row = &mut critic[env * c..(env + 1) * c];
            if self.critic_copies_actor {
                critic_row.copy_from_slice(&obs[env * a..(env + 1) * a]);
            } else {
                critic_row[..4].copy_from_slice(row);
                critic_row[4] = steps[env] as f32 / self.spec.max_episode_steps as f32;
            }
        }
    }
}

impl rlpkg_vec_env::VecEnv for GroupedCartPole {
    fn spec(&self) -> &rlpkg_vec_env::EnvSpec {
        &self.spec
    }
    fn num_envs(&self) -> usize {
        self.inner.num_envs()
    }
    fn reset(
        &mut self,
        seed: u64,
        out: &mut rlpkg_vec_env::StepBuffers,
    ) -> Result<(), rlpkg_vec_env::EnvError> {
        self.inner.reset(seed, &mut self.inner_buffers)?;
        self.steps.iter_mut().for_each(|s| *s = 0);
        let inner = &self.inner_buffers;
        self.fill(&inner.obs, &self.steps, &mut out.obs, &mut out.critic_obs);
        out.final_obs.copy_from_slice(&out.obs);
        out.final_critic_obs.copy_from_slice(&out.critic_obs);
        Ok(())
    }
    fn step(
        &mut self,
        actions: &[f32],
        out: &mut rlpkg_vec_env::StepBuffers,
    ) -> Result<(), rlpkg_vec_env::EnvError> {
        self.inner.step(actions, &mut self.inner_buffers)?;
        let inner = &self.inner_buffers;
        let ended: Vec<usize> = self.steps.iter().map(|s| s + 1).collect();
        for (i, s) in self.steps.iter_mut().enumerate() {
            *s = if inner.done(i) { 0 } else { *s + 1 };
        }
        self.fill(&inner.obs, &self.steps, &mut out.obs, &mut out.critic_obs);
        self.fill(
            &inner.final_obs,
            &ended,
            &mut out.final_obs,
            &mut out.final_critic_obs,
        );
        out.rewards.copy_from_slice(&inner.rewards);
        out.terminated.copy_from_slice(&inner.terminated);
        out.truncated.copy_from_slice(&inner.truncated);
        Ok(())
    }
    fn save_state(&self) -> rlpkg_vec_env::EnvState {
        let mut state = self.inner.save_state();
        state.counters.extend(self.steps.iter().map(|&s| s as u64));
        state
    }
    fn load_state(
        &mut self,
        state: &rlpkg_vec_env::EnvState,
    ) -> Result<(), rlpkg_vec_env::EnvError> {
        let n = self.steps.len();
        let split = state.counters.len().saturating_sub(n);
        let inner = rlpkg_vec_env::EnvState {
            reals: state.reals.clone(),
            counters: state.counters[..split].to_vec(),
            bytes: Vec::new(),
        };
        self.inner.load_state(&inner)?;
        for (s, &c) in self.steps.iter_mut().zip(&state.counters[split..]) {
            *s = c as usize;
        }
        Ok(())
    }
}

fn grouped_trainer(actor_dims: &[usize], critic_copies_actor: bool) -> Trainer {
    let config = config(CARTPOLE_TEST);
    let env = GroupedCartPole::new(config.run.num_envs, actor_dims, critic_copies_actor);
    Trainer::new(config, CARTPOLE_TEST.to_string(), Box::new(env)).unwrap()
}

#[test]
fn a_critic_group_equal_to_the_actor_observations_trains_like_the_symmetric_path() {
    // The asymmetric path (own storage, own normaliser, own bootstrap rows) fed the actor's
    // observations must reproduce the symmetric trainer bit for bit.
    let mut symmetric = trainer(CARTPOLE_TEST);
    let mut grouped = grouped_trainer(&[0, 1, 2, 3], true);
    assert!(grouped.spec().is_asymmetric());
    for _ in 0..3 {
        let (a, b) = (
            symmetric.run_update().unwrap(),
            grouped.run_update().unwrap(),
        );
        assert_eq!(a, b);
    }
    let (a, b) = (
        symmetric.ppo.model.flat_parameters(),
        grouped.ppo.model.flat_parameters(),
    );
    assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
}

#[test]
fn asymmetric_critic_trains_on_its_own_wider_observations() {
    let mut t = grouped_trainer(&[0, 2], false);
    let before = t.ppo.model.flat_parameters();
    let log = t.run_update().unwrap();
    assert!(log.stats.value_loss.is_finite() && log.stats.policy_loss.is_finite());
    let model = &t.ppo.model;
    assert_eq!(model.actor_layers()[0].d_in, 2);
    assert_eq!(model.critic_layers()[0].d_in, 5);
    let after = model.flat_parameters();
    let moved = after
        .iter()
        .zip(&before)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max);
    assert!(moved > 1e-4, "the update barely moved: {moved}");
    // The critic's statistics see the privileged episode fraction (which grows within episodes).
    let stats = t.critic_obs_stats.as_ref().unwrap();
    assert_eq!(stats.mean.len(), 5);
    assert!(stats.mean[4] > 0.0 && stats.count > 0.0, "{stats:?}");
    assert_eq!(t.obs_stats.as_ref().unwrap().mean.len(), 2);
    // The exported graph holds the actor alone and reads the actor's two observations.
    let policy = TrainedPolicy::from_trainer(&t);
    let graph = policy.policy_graph();
    assert!(graph.critic.is_none());
    graph.validate().unwrap();
    let obs = [0.01f32, -0.02, 0.03, 0.0];
    let (burn_actions, graph_actions) = (policy.act(&obs, 2), graph.act(&obs, 2));
    assert_eq!(burn_actions, graph_actions);
}

#[test]
fn asymmetric_resume_continues_exactly_like_an_uninterrupted_run() {
    let dir = tempfile::tempdir().unwrap();
    let mut straight = grouped_trainer(&[0, 2], false);
    let straight_logs: Vec<UpdateLog> = (0..4).map(|_| straight.run_update().unwrap()).collect();

    let mut first_half = grouped_trainer(&[0, 2], false);
    first_half.create_run_dir(dir.path()).unwrap();
    first_half.train(dir.path(), Some(2), false).unwrap();
    drop(first_half);
    let mut resumed = grouped_trainer(&[0, 2], false);
    resumed.load_checkpoint(dir.path()).unwrap();
    let resumed_logs: Vec<UpdateLog> = (0..2).map(|_| resumed.run_update().unwrap()).collect();
    assert_eq!(resumed_logs, straight_logs[2..]);
    assert_eq!(resumed.critic_obs_stats, straight.critic_obs_stats);
    let (a, b) = (
        straight.ppo.model.flat_parameters(),
        resumed.ppo.model.flat_parameters(),
    );
    assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
    // A checkpoint of a symmetric run does not fit the asymmetric trainer.
    let symmetric_dir = tempfile::tempdir().unwrap();
    let mut symmetric = trainer(CARTPOLE_TEST);
    symmetric.create_run_dir(symmetric_dir.path()).unwrap();
    symmetric
        .train(symmetric_dir.path(), Some(1), false)
        .unwrap();
    let mut grouped = grouped_trainer(&[0, 1, 2, 3], false);
    assert!(grouped.load_checkpoint(symmetric_dir.path()).is_err());
}

#[test]
fn the_files_of_a_run_are_known_by_their_place() {
    let run = Path::new("/data/runs/tiny");
    for (file, kind) in [
        ("config.toml", Some("the run's configuration")),
        (
            "checkpoints/update_000004/model.bpk",
            Some("a file of the run's checkpoints"),
        ),
        (
            "checkpoints/latest",
            Some("a file of the run's checkpoints"),
        ),
        (
            "checkpoints/new.onnx",
            Some("a file of the run's checkpoints"),
        ),
        (
            "events.out.tfevents.0000000001.rlpkg.7.0",
            Some("an event file of the run"),
        ),
        (".lock", Some("the run's lock file")),
        ("policy.onnx", None),
        ("pendulum.onnx", None),
        ("sub/config.toml", None),
    ] {
        assert_eq!(run_file_kind(run, &run.join(file)), kind, "{file}");
    }
    assert_eq!(
        run_file_kind(run, Path::new("/data/runs/other/config.toml")),
        None
    );
}
