//! Seeded random [`PolicyGraph`]s shaped like real policies, for tests and latency benchmarks.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::graph::{
    ActionHead, ActionTransform, Activation, DenseLayer, ObsNormaliser, PolicyGraph, PolicyMeta,
};

/// A dense layer with weights uniform in +-1/sqrt(d_in) (PyTorch's default scale) and small biases.
pub fn random_layer(d_in: usize, d_out: usize, rng: &mut impl Rng) -> DenseLayer {
    let scale = 1.0 / (d_in as f32).sqrt();
    DenseLayer {
        d_in,
        d_out,
        weight: (0..d_in * d_out)
            .map(|_| rng.random_range(-scale..scale))
            .collect(),
        bias: (0..d_out).map(|_| rng.random_range(-0.1..0.1)).collect(),
    }
}

/// A stack of random dense layers of the given widths (`widths[0]` is the input width).
pub fn random_mlp(widths: &[usize], rng: &mut impl Rng) -> Vec<DenseLayer> {
    widths
        .windows(2)
        .map(|w| random_layer(w[0], w[1], rng))
        .collect()
}

/// A random normaliser: means in [-2, 2], variances in [0.01, 4], eps 1e-8, clip 5.
pub fn random_normaliser(dim: usize, rng: &mut impl Rng) -> ObsNormaliser {
    ObsNormaliser {
        mean: (0..dim).map(|_| rng.random_range(-2.0..2.0)).collect(),
        var: (0..dim).map(|_| rng.random_range(0.01..4.0)).collect(),
        eps: 1e-8,
        clip: 5.0,
    }
}

/// A CartPole-shaped policy: 4 observations, 64-64 tanh actor with 2 logits (argmax), critic,
/// normaliser.
pub fn cartpole_like(seed: u64) -> PolicyGraph {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    PolicyGraph {
        normaliser: Some(random_normaliser(4, &mut rng)),
        actor: random_mlp(&[4, 64, 64, 2], &mut rng),
        critic: Some(random_mlp(&[4, 64, 64, 1], &mut rng)),
        activation: Activation::Tanh,
        head: ActionHead::Categorical { n: 2 },
        meta: PolicyMeta {
            env_id: "CartPole-v1".into(),
            obs_names: ["cart_x", "cart_v", "pole_angle", "pole_omega"]
                .map(String::from)
                .to_vec(),
            obs_units: ["m", "m/s", "rad", "rad/s"].map(String::from).to_vec(),
            obs_low: vec![-4.8, f32::NEG_INFINITY, -0.418_879, f32::NEG_INFINITY],
            obs_high: vec![4.8, f32::INFINITY, 0.418_879, f32::INFINITY],
            action_names: vec!["push_direction".into()],
            action_units: vec!["index".into()],
            action_low: vec![0.0],
            action_high: vec![1.0],
            rlpkg_version: env!("CARGO_PKG_VERSION").into(),
            config_hash: format!("{seed:016x}"),
        },
    }
}

/// A Pendulum-shaped policy: 3 observations, 64-64 tanh actor with 1 output clipped to +-2 N m,
/// critic, normaliser.
pub fn pendulum_like(seed: u64) -> PolicyGraph {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    PolicyGraph {
        normaliser: Some(random_normaliser(3, &mut rng)),
        actor: random_mlp(&[3, 64, 64, 1], &mut rng),
        critic: Some(random_mlp(&[3, 64, 64, 1], &mut rng)),
        activation: Activation::Tanh,
        head: ActionHead::Gaussian {
            transform: ActionTransform::Clip {
                low: vec![-2.0],
                high: vec![2.0],
            },
        },
        meta: PolicyMeta {
            env_id: "Pendulum-v1".into(),
            obs_names: ["cos_theta", "sin_theta", "theta_dot"]
                .map(String::from)
                .to_vec(),
            obs_units: ["1", "1", "rad/s"].map(String::from).to_vec(),
            obs_low: vec![-1.0, -1.0, -8.0],
            obs_high: vec![1.0, 1.0, 8.0],
            action_names: vec!["torque".into()],
            action_units: vec!["N m".into()],
            action_low: vec![-2.0],
            action_high: vec![2.0],
            rlpkg_version: env!("CARGO_PKG_VERSION").into(),
            config_hash: format!("{seed:016x}"),
        },
    }
}

/// A transport-shaped policy: `obs_dim` observations, 256-256 ELU actor with `action_dim` tanh-scaled
/// outputs in [-1, 1] (no critic, no metadata lists).
pub fn transport_like(obs_dim: usize, action_dim: usize, seed: u64) -> PolicyGraph {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    PolicyGraph {
        normaliser: Some(random_normaliser(obs_dim, &mut rng)),
        actor: random_mlp(&[obs_dim, 256, 256, action_dim], &mut rng),
        critic: None,
        activation: Activation::Elu,
        head: ActionHead::Gaussian {
            transform: ActionTransform::TanhScale {
                low: vec![-1.0; action_dim],
                high: vec![1.0; action_dim],
            },
        },
        meta: PolicyMeta {
            env_id: "Transport-v0".into(),
            rlpkg_version: env!("CARGO_PKG_VERSION").into(),
            ..Default::default()
        },
    }
}
