//! Actor-critic MLPs with orthogonal initialisation and a Gaussian (state-independent log-std) or
//! categorical head.

use burn::module::{Module, Param};
use burn::nn::{Linear, LinearConfig};
use burn::tensor::activation::{elu, relu, tanh};
use burn::tensor::{Device, Tensor, TensorData};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use super::dense::dense_tanh;
use crate::export::{Activation, DenseLayer};

/// Separate actor and critic MLPs plus the Gaussian head's log-std (absent for discrete actions).
#[derive(Module, Debug)]
pub struct ActorCritic {
    actor: Vec<Linear>,
    critic: Vec<Linear>,
    log_std: Option<Param<Tensor<1>>>,
    #[module(skip)]
    activation: Activation,
}

/// What the actor produces for a batch of observations.
#[derive(Debug, Clone)]
pub struct ActorOutput {
    /// Gaussian means or categorical logits, `[B, A]` / `[B, n]`.
    pub head: Tensor<2>,
}

impl ActorCritic {
    /// Builds both networks with orthogonal weights (gain sqrt(2) for hidden layers, 0.01 for the
    /// actor's output, 1 for the critic's) and zero biases, drawn from `rng`.
    ///
    /// The actor reads `obs_dim` observations, the critic `critic_obs_dim` (the actor's width for
    /// a symmetric actor-critic, another for a critic with privileged observations).
    /// `log_std` is `Some(initial value)` for a Gaussian head with `actor_out` dimensions.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        obs_dim: usize,
        critic_obs_dim: usize,
        actor_out: usize,
        actor_hidden: &[usize],
        critic_hidden: &[usize],
        activation: Activation,
        log_std: Option<f32>,
        rng: &mut ChaCha8Rng,
        device: &Device,
    ) -> Self {
        let actor = mlp(obs_dim, actor_hidden, actor_out, 0.01, rng, device);
        let critic = mlp(critic_obs_dim, critic_hidden, 1, 1.0, rng, device);
        let log_std = log_std.map(|value| {
            Param::from_tensor(Tensor::from_data(
                TensorData::new(vec![value; actor_out], [actor_out]),
                device,
            ))
        });
        Self {
            actor,
            critic,
            log_std,
            activation,
        }
    }

    /// Actor head output for `obs` `[B, obs_dim]`.
    pub fn actor(&self, obs: Tensor<2>) -> Tensor<2> {
        forward(&self.actor, self.activation, obs)
    }

    /// Critic values for the critic's observations `[B, critic_obs_dim]`: `[B]`.
    pub fn value(&self, obs: Tensor<2>) -> Tensor<1> {
        forward(&self.critic, self.activation, obs).squeeze_dim(1)
    }

    /// The Gaussian head's log-std `[A]`, or `None` for a categorical head.
    pub fn log_std(&self) -> Option<Tensor<1>> {
        self.log_std.as_ref().map(|p| p.val())
    }

    /// Hidden-layer activation.
    pub fn activation(&self) -> Activation {
        self.activation
    }

    /// Actor layers as plain numbers (row-major `[d_in, d_out]` weights).
    pub fn actor_layers(&self) -> Vec<DenseLayer> {
        self.actor.iter().map(dense_layer).collect()
    }

    /// Critic layers as plain numbers.
    pub fn critic_layers(&self) -> Vec<DenseLayer> {
        self.critic.iter().map(dense_layer).collect()
    }

    /// Every parameter flattened in a fixed order (for comparing models bit by bit).
    pub fn flat_parameters(&self) -> Vec<f32> {
        let mut out: Vec<f32> = self
            .actor_layers()
            .into_iter()
            .chain(self.critic_layers())
            .flat_map(|l| l.weight.into_iter().chain(l.bias))
            .collect();
        if let Some(log_std) = self.log_std() {
            out.extend(to_host(log_std));
        }
        out
    }
}

#[cfg(test)]
impl ActorCritic {
    /// [`ActorCritic::actor`] through burn's own layer and activation ops.
    pub(crate) fn reference_actor(&self, obs: Tensor<2>) -> Tensor<2> {
        reference_forward(&self.actor, self.activation, obs)
    }

    /// [`ActorCritic::value`] through burn's own layer and activation ops.
    pub(crate) fn reference_value(&self, obs: Tensor<2>) -> Tensor<1> {
        reference_forward(&self.critic, self.activation, obs).squeeze_dim(1)
    }
}

/// A tensor's values on the host.
pub(crate) fn to_host<const D: usize>(tensor: Tensor<D>) -> Vec<f32> {
    tensor
        .try_into_vec_as::<f32>()
        .expect("f32 tensors read back as f32")
}

fn dense_layer(linear: &Linear) -> DenseLayer {
    let [d_in, d_out] = linear.weight.val().dims();
    DenseLayer {
        d_in,
        d_out,
        weight: to_host(linear.weight.val()),
        bias: linear
            .bias
            .as_ref()
            .map(|b| to_host(b.val()))
            .unwrap_or_else(|| vec![0.0; d_out]),
    }
}

fn apply_activation(activation: Activation, x: Tensor<2>) -> Tensor<2> {
    match activation {
        Activation::Tanh => tanh(x),
        Activation::Relu => relu(x),
        Activation::Elu => elu(x, 1.0),
    }
}

fn forward(layers: &[Linear], activation: Activation, mut x: Tensor<2>) -> Tensor<2> {
    let last = layers.len() - 1;
    for (i, layer) in layers.iter().enumerate() {
        x = match (&layer.bias, activation) {
            // Hidden tanh layers are one fused op (see `dense`).
            (Some(bias), Activation::Tanh) if i < last => {
                dense_tanh(x, layer.weight.val(), bias.val())
            }
            _ if i < last => apply_activation(activation, layer.forward(x)),
            _ => layer.forward(x),
        };
    }
    x
}

/// The forward pass from burn's own layer and activation ops: the reference the fused layers
/// are checked against.
#[cfg(test)]
pub(crate) fn reference_forward(
    layers: &[Linear],
    activation: Activation,
    mut x: Tensor<2>,
) -> Tensor<2> {
    let last = layers.len() - 1;
    for (i, layer) in layers.iter().enumerate() {
        x = layer.forward(x);
        if i < last {
            x = apply_activation(activation, x);
        }
    }
    x
}

fn mlp(
    d_in: usize,
    hidden: &[usize],
    d_out: usize,
    output_gain: f32,
    rng: &mut ChaCha8Rng,
    device: &Device,
) -> Vec<Linear> {
    let widths: Vec<usize> = std::iter::once(d_in)
        .chain(hidden.iter().copied())
        .chain(std::iter::once(d_out))
        .collect();
    let last = widths.len() - 2;
    widths
        .windows(2)
        .enumerate()
        .map(|(i, pair)| {
            let gain = if i == last { output_gain } else { 2f32.sqrt() };
            let mut linear = LinearConfig::new(pair[0], pair[1]).init(device);
            let weight = orthogonal(pair[0], pair[1], gain, rng);
            linear.weight = Param::from_tensor(Tensor::from_data(
                TensorData::new(weight, [pair[0], pair[1]]),
                device,
            ));
            linear.bias = Some(Param::from_tensor(Tensor::from_data(
                TensorData::new(vec![0.0f32; pair[1]], [pair[1]]),
                device,
            )));
            linear
        })
        .collect()
}

/// A `[rows, cols]` matrix (row-major) with orthonormal rows or columns (whichever are fewer),
/// scaled by `gain`: Gram-Schmidt on a Gaussian matrix, like `torch.nn.init.orthogonal_`.
pub(crate) fn orthogonal(rows: usize, cols: usize, gain: f32, rng: &mut ChaCha8Rng) -> Vec<f32> {
    // Orthonormalise the `k` shorter vectors, each `m` long.
    let (k, m) = (rows.min(cols), rows.max(cols));
    let mut vectors: Vec<Vec<f64>> = (0..k)
        .map(|_| {
            (0..m)
                .map(|_| rng.sample::<f64, _>(StandardNormal))
                .collect()
        })
        .collect();
    for i in 0..k {
        for j in 0..i {
            let dot: f64 = vectors[i].iter().zip(&vectors[j]).map(|(a, b)| a * b).sum();
            let (head, tail) = vectors.split_at_mut(i);
            for (a, b) in tail[0].iter_mut().zip(&head[j]) {
                *a -= dot * b;
            }
        }
        let norm = vectors[i].iter().map(|a| a * a).sum::<f64>().sqrt();
        vectors[i].iter_mut().for_each(|a| *a /= norm);
    }
    let mut out = vec![0.0f32; rows * cols];
    for r in 0..rows {
        for c in 0..cols {
            // Vectors run along the longer axis.
            let value = if rows >= cols {
                vectors[c][r]
            } else {
                vectors[r][c]
            };
            out[r * cols + c] = gain * value as f32;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn orthogonal_matrices_have_orthonormal_short_axis() {
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        for (rows, cols) in [(5, 3), (3, 5), (4, 4)] {
            let w = orthogonal(rows, cols, 2.0, &mut rng);
            let k = rows.min(cols);
            for i in 0..k {
                for j in 0..k {
                    let dot: f32 = if rows >= cols {
                        (0..rows).map(|r| w[r * cols + i] * w[r * cols + j]).sum()
                    } else {
                        (0..cols).map(|c| w[i * cols + c] * w[j * cols + c]).sum()
                    };
                    let expected = if i == j { 4.0 } else { 0.0 };
                    assert!(
                        (dot - expected).abs() < 1e-5,
                        "{rows}x{cols} ({i},{j}): {dot}"
                    );
                }
            }
        }
    }

    #[test]
    fn networks_have_the_configured_shapes() {
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let device = crate::Backend::DEFAULT.device();
        let model = ActorCritic::new(
            4,
            4,
            2,
            &[8, 6],
            &[5],
            Activation::Tanh,
            None,
            &mut rng,
            &device,
        );
        let widths: Vec<(usize, usize)> = model
            .actor_layers()
            .iter()
            .map(|l| (l.d_in, l.d_out))
            .collect();
        assert_eq!(widths, vec![(4, 8), (8, 6), (6, 2)]);
        assert_eq!(model.critic_layers().len(), 2);
        assert!(model.log_std().is_none());
        let obs = Tensor::from_data(TensorData::new(vec![0.1f32; 12], [3, 4]), &device);
        assert_eq!(model.actor(obs.clone()).dims(), [3, 2]);
        assert_eq!(model.value(obs).dims(), [3]);
        assert!(model.critic_layers()[0].bias.iter().all(|&b| b == 0.0));
    }

    #[test]
    fn critic_may_read_a_wider_observation_than_the_actor() {
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let device = crate::Backend::DEFAULT.device();
        let model = ActorCritic::new(
            3,
            7,
            2,
            &[8],
            &[5],
            Activation::Tanh,
            Some(0.0),
            &mut rng,
            &device,
        );
        assert_eq!(model.actor_layers()[0].d_in, 3);
        assert_eq!(model.critic_layers()[0].d_in, 7);
        let actor_obs = Tensor::from_data(TensorData::new(vec![0.1f32; 6], [2, 3]), &device);
        let critic_obs = Tensor::from_data(TensorData::new(vec![0.1f32; 14], [2, 7]), &device);
        assert_eq!(model.actor(actor_obs).dims(), [2, 2]);
        assert_eq!(model.value(critic_obs).dims(), [2]);
    }
}
