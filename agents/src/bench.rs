//! Throughput figures (benchmarks, not tests): PPO update samples/s and environment steps/s.

use std::time::Instant;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::algorithms::{PhaseTimes, Ppo};
use crate::config::{LrSchedule, PpoConfig};
use crate::export::Activation;
use crate::modules::ActorCritic;
use crate::storage::RolloutStorage;
use crate::{AgentError, Backend};

/// Shape of the PPO update benchmark.
#[derive(Debug, Clone, Serialize)]
pub struct PpoBenchConfig {
    /// Observation width.
    pub obs_dim: usize,
    /// Gaussian action width.
    pub action_dim: usize,
    /// Hidden widths of actor and critic.
    pub hidden: Vec<usize>,
    /// Samples per minibatch.
    pub minibatch: usize,
    /// Minibatches timed (after one warm-up minibatch).
    pub minibatches: usize,
    /// burn backend.
    #[serde(skip)]
    pub backend: Backend,
}

/// Measured PPO update throughput.
#[derive(Debug, Clone, Serialize)]
pub struct PpoBenchResult {
    /// Backend name.
    pub backend: String,
    /// The benchmark's shape.
    pub config: PpoBenchConfig,
    /// Parameters of actor + critic.
    pub parameters: usize,
    /// Samples per second through forward + backward + global clip + Adam.
    pub samples_per_second: f64,
    /// Milliseconds per minibatch.
    pub ms_per_minibatch: f64,
    /// Samples per second of CPU time summed over the process's threads (Linux only): the
    /// throughput the update would have with its cores to itself, whatever else runs.
    pub samples_per_cpu_second: Option<f64>,
    /// Shares of the update's time per phase (they sum to 1 up to the loop's own overhead).
    pub shares: PhaseShares,
}

/// Fractions of the timed update spent in each phase.
#[derive(Debug, Clone, Serialize)]
pub struct PhaseShares {
    /// Gathering minibatch rows into tensors.
    pub batch: f64,
    /// Forward passes, loss and diagnostics read-back.
    pub forward: f64,
    /// Backpropagation.
    pub backward: f64,
    /// Gradient clipping and Adam.
    pub optimiser: f64,
}

/// Times PPO minibatch updates (forward, backward, global grad clip, Adam) on random data.
pub fn ppo_update_throughput(config: &PpoBenchConfig) -> PpoBenchResult {
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let device = config.backend.device().autodiff();
    let model = ActorCritic::new(
        config.obs_dim,
        config.obs_dim,
        config.action_dim,
        &config.hidden,
        &config.hidden,
        Activation::Tanh,
        Some(0.0),
        &mut rng,
        &device,
    );
    let parameters = model.flat_parameters().len();
    let ppo_config = PpoConfig {
        rollout_steps: config.minibatch,
        epochs: 1,
        minibatches: 1,
        gamma: 0.99,
        gae_lambda: 0.95,
        clip_ratio: 0.2,
        clip_value_loss: true,
        value_coef: 0.5,
        entropy_coef: 0.0,
        max_grad_norm: 1.0,
        learning_rate: 3e-4,
        lr_schedule: LrSchedule::Constant,
        desired_kl: 0.01,
        normalize_advantages: true,
        adam_epsilon: 1e-5,
    };
    let mut ppo = Ppo::new(model, &ppo_config, device);
    let mut storage = RolloutStorage::new(config.minibatch, 1, config.obs_dim, config.action_dim);
    let mut fill = |v: &mut Vec<f32>, scale: f32| {
        v.iter_mut()
            .for_each(|x| *x = scale * (rng.random::<f32>() - 0.5))
    };
    fill(&mut storage.obs, 2.0);
    fill(&mut storage.actions, 2.0);
    fill(&mut storage.log_probs, 1.0);
    fill(&mut storage.values, 1.0);
    fill(&mut storage.advantages, 1.0);
    fill(&mut storage.returns, 1.0);
    let mut shuffle_rng = ChaCha8Rng::seed_from_u64(1);
    ppo.update(&storage, &mut shuffle_rng); // warm-up
    let mut phases = PhaseTimes::default();
    let cpu_start = process_cpu_seconds();
    let start = Instant::now();
    for _ in 0..config.minibatches {
        ppo.update(&storage, &mut shuffle_rng);
        phases.add(&ppo.times);
    }
    let seconds = start.elapsed().as_secs_f64();
    let samples = (config.minibatch * config.minibatches) as f64;
    let cpu_seconds = cpu_start
        .zip(process_cpu_seconds())
        .map(|(start, end)| end - start);
    PpoBenchResult {
        backend: config.backend.name().to_string(),
        config: config.clone(),
        parameters,
        samples_per_second: samples / seconds,
        ms_per_minibatch: 1e3 * seconds / config.minibatches as f64,
        samples_per_cpu_second: cpu_seconds.filter(|&c| c > 0.0).map(|c| samples / c),
        shares: PhaseShares {
            batch: phases.batch / seconds,
            forward: phases.forward / seconds,
            backward: phases.backward / seconds,
            optimiser: phases.optimiser / seconds,
        },
    }
}

/// CPU time used so far by all threads of this process, from the scheduler's per-thread
/// counters (`/proc/self/task/*/schedstat`, nanoseconds on the CPU); `None` where there are none.
fn process_cpu_seconds() -> Option<f64> {
    let mut nanoseconds = 0u64;
    for task in std::fs::read_dir("/proc/self/task").ok()? {
        let text = std::fs::read_to_string(task.ok()?.path().join("schedstat")).ok()?;
        nanoseconds += text.split_whitespace().next()?.parse::<u64>().ok()?;
    }
    Some(nanoseconds as f64 * 1e-9)
}

/// Measured throughput of one matrix product on the backend (no autodiff).
#[derive(Debug, Clone, Serialize)]
pub struct MatmulBenchResult {
    /// Backend name.
    pub backend: String,
    /// `[m, k] x [k, n]`.
    pub m: usize,
    /// Inner dimension.
    pub k: usize,
    /// Output columns.
    pub n: usize,
    /// The left operand is a transposed view (as in a weight gradient `x^T dz`).
    pub transposed_lhs: bool,
    /// 2 m k n / seconds, in 1e9 per second.
    pub gflops: f64,
}

/// Times `repeats` products of the given shape (after one warm-up) on `backend`.
pub fn matmul_throughput(
    backend: Backend,
    [m, k, n]: [usize; 3],
    transposed_lhs: bool,
    repeats: usize,
) -> MatmulBenchResult {
    use burn::tensor::{Distribution, Tensor};
    let device = backend.device();
    let lhs = |_| {
        if transposed_lhs {
            Tensor::<2>::random([k, m], Distribution::Default, &device).transpose()
        } else {
            Tensor::<2>::random([m, k], Distribution::Default, &device)
        }
    };
    let rhs = Tensor::<2>::random([k, n], Distribution::Default, &device);
    let (a, b) = (lhs(()), rhs.clone());
    let _ = a.matmul(b).into_data();
    let operands: Vec<_> = (0..repeats).map(|_| (lhs(()), rhs.clone())).collect();
    let start = Instant::now();
    for (a, b) in operands {
        // Flex computes eagerly; reading one value keeps a lazy backend honest too.
        let _ = a.matmul(b).slice([0..1, 0..1]).into_data();
    }
    let seconds = start.elapsed().as_secs_f64();
    MatmulBenchResult {
        backend: backend.name().to_string(),
        m,
        k,
        n,
        transposed_lhs,
        gflops: 2.0 * (m * k * n * repeats) as f64 / seconds / 1e9,
    }
}

/// Measured environment throughput.
#[derive(Debug, Clone, Serialize)]
pub struct EnvBenchResult {
    /// Environment id.
    pub env_id: String,
    /// Copies stepped in lockstep.
    pub num_envs: usize,
    /// Environment steps (summed over copies) per second, with random actions.
    pub steps_per_second: f64,
}

/// Steps every copy of `env` with random actions for `steps` lockstep steps.
pub fn env_throughput(
    env: &mut dyn rlpkg_vec_env::VecEnv,
    steps: usize,
) -> Result<EnvBenchResult, AgentError> {
    let num_envs = env.num_envs();
    let spec = env.spec().clone();
    let mut buffers = env.buffers();
    env.reset(0, &mut buffers)?;
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let a = spec.action.dim();
    let actions: Vec<Vec<f32>> = (0..16)
        .map(|_| match spec.action.kind {
            rlpkg_vec_env::SpaceKind::Discrete { n } => (0..num_envs)
                .map(|_| rng.random_range(0..n) as f32)
                .collect(),
            rlpkg_vec_env::SpaceKind::Continuous => (0..num_envs * a)
                .map(|k| {
                    let (low, high) = (spec.action.low[k % a], spec.action.high[k % a]);
                    low + (high - low) * rng.random::<f32>()
                })
                .collect(),
        })
        .collect();
    let start = Instant::now();
    for step in 0..steps {
        env.step(&actions[step % actions.len()], &mut buffers)?;
    }
    Ok(EnvBenchResult {
        env_id: spec.id,
        num_envs,
        steps_per_second: (steps * num_envs) as f64 / start.elapsed().as_secs_f64(),
    })
}
