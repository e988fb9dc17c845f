//! [`PolicyGraph`]: the plain-number hand-off between the PPO trainer and the ONNX exporter.
//!
//! The trainer fills it from a trained actor-critic; the exporter turns it into an ONNX graph; and
//! [`PolicyGraph::act`] evaluates it in plain Rust `f32`, the ground truth that both burn and every
//! ONNX runtime are compared against.

use super::ExportError;

/// Plain-number description of a deterministic policy: what the environment receives for an observation.
#[derive(Debug, Clone, PartialEq)]
pub struct PolicyGraph {
    /// Observation normaliser, applied first.
    pub normaliser: Option<ObsNormaliser>,
    /// Actor layers: hidden layers use `activation`; the last layer is linear.
    pub actor: Vec<DenseLayer>,
    /// Critic layers (same activation rule), exported as output `value` when present.
    pub critic: Option<Vec<DenseLayer>>,
    /// Activation between hidden layers.
    pub activation: Activation,
    /// How the last actor layer's output becomes an action.
    pub head: ActionHead,
    /// Names, units, bounds and provenance written into the ONNX metadata.
    pub meta: PolicyMeta,
}

/// y = x W + b, W row-major [d_in, d_out] (burn's Linear layout; ONNX Gemm transB = 0).
#[derive(Debug, Clone, PartialEq)]
pub struct DenseLayer {
    /// Input width.
    pub d_in: usize,
    /// Output width.
    pub d_out: usize,
    /// Row-major `[d_in, d_out]` weights.
    pub weight: Vec<f32>,
    /// `[d_out]` bias.
    pub bias: Vec<f32>,
}

/// Activation applied after every hidden layer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Activation {
    /// Hyperbolic tangent.
    Tanh,
    /// max(x, 0).
    Relu,
    /// x for x > 0, exp(x) - 1 otherwise (alpha = 1).
    Elu,
}

/// normalised = clamp((obs - mean) / sqrt(var + eps), -clip, clip), computed in f32 exactly in this order.
#[derive(Debug, Clone, PartialEq)]
pub struct ObsNormaliser {
    /// Running mean per observation dimension.
    pub mean: Vec<f32>,
    /// Running variance per observation dimension.
    pub var: Vec<f32>,
    /// Added to the variance before the square root.
    pub eps: f32,
    /// Normalised observations are clamped to `[-clip, clip]`.
    pub clip: f32,
}

/// How the actor's last-layer output becomes the action the environment receives.
#[derive(Debug, Clone, PartialEq)]
pub enum ActionHead {
    /// Argmax of the logits (outputs `action` as int64 index and `logits`).
    Categorical {
        /// Number of discrete actions (the last layer's width).
        n: usize,
    },
    /// Gaussian mean, then the trainer's transform to the environment's bounds.
    Gaussian {
        /// Map from the Gaussian mean to the environment's action bounds.
        transform: ActionTransform,
    },
}

/// Map from a Gaussian policy's mean to the environment's action bounds.
#[derive(Debug, Clone, PartialEq)]
pub enum ActionTransform {
    /// action = clamp(mean, low, high) per dimension
    Clip {
        /// Lower bound per action dimension.
        low: Vec<f32>,
        /// Upper bound per action dimension.
        high: Vec<f32>,
    },
    /// action = low + (tanh(mean) + 1) / 2 * (high - low)
    TanhScale {
        /// Lower bound per action dimension.
        low: Vec<f32>,
        /// Upper bound per action dimension.
        high: Vec<f32>,
    },
}

/// Names, units, bounds and provenance of a policy, written into the ONNX `metadata_props`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PolicyMeta {
    /// Environment identifier, e.g. `CartPole-v1`.
    pub env_id: String,
    /// One name per observation dimension.
    pub obs_names: Vec<String>,
    /// SI unit per observation dimension.
    pub obs_units: Vec<String>,
    /// Lower bound per observation dimension (may be infinite).
    pub obs_low: Vec<f32>,
    /// Upper bound per observation dimension (may be infinite).
    pub obs_high: Vec<f32>,
    /// One name per action dimension.
    pub action_names: Vec<String>,
    /// SI unit per action dimension.
    pub action_units: Vec<String>,
    /// Lower bound per action dimension.
    pub action_low: Vec<f32>,
    /// Upper bound per action dimension.
    pub action_high: Vec<f32>,
    /// `rlpkg` version that trained the policy.
    pub rlpkg_version: String,
    /// Hash of the training configuration.
    pub config_hash: String,
}

impl PolicyMeta {
    /// Names, units and bounds of `spec`'s observations and actions, with provenance.
    pub fn from_spec(
        spec: &rlpkg_vec_env::EnvSpec,
        rlpkg_version: &str,
        config_hash: &str,
    ) -> Self {
        Self {
            env_id: spec.id.clone(),
            obs_names: spec.observation.names.clone(),
            obs_units: spec.observation.units.clone(),
            obs_low: spec.observation.low.clone(),
            obs_high: spec.observation.high.clone(),
            action_names: spec.action.names.clone(),
            action_units: spec.action.units.clone(),
            action_low: spec.action.low.clone(),
            action_high: spec.action.high.clone(),
            rlpkg_version: rlpkg_version.into(),
            config_hash: config_hash.into(),
        }
    }
}

impl Activation {
    /// Applies the activation to one value.
    pub fn apply(self, x: f32) -> f32 {
        match self {
            Activation::Tanh => x.tanh(),
            Activation::Relu => x.max(0.0),
            Activation::Elu => {
                if x > 0.0 {
                    x
                } else {
                    x.exp_m1()
                }
            }
        }
    }
}

impl DenseLayer {
    /// `y = x W + b` for `n` rows of `x` (row-major `[n, d_in]`), giving `[n, d_out]`.
    pub fn forward(&self, x: &[f32], n: usize) -> Vec<f32> {
        let mut y = Vec::with_capacity(n * self.d_out);
        for row in x.chunks_exact(self.d_in).take(n) {
            let start = y.len();
            y.extend_from_slice(&self.bias);
            let out = &mut y[start..];
            for (xi, w_row) in row.iter().zip(self.weight.chunks_exact(self.d_out)) {
                for (o, w) in out.iter_mut().zip(w_row) {
                    *o += xi * w;
                }
            }
        }
        y
    }
}

impl ObsNormaliser {
    /// The divisor `sqrt(var + eps)` per dimension; the ONNX graph divides by these same constants.
    pub fn std(&self) -> Vec<f32> {
        self.var.iter().map(|v| (v + self.eps).sqrt()).collect()
    }

    /// Normalises `n` rows of observations.
    pub fn apply(&self, obs: &[f32], n: usize) -> Vec<f32> {
        let std = self.std();
        let dim = self.mean.len();
        obs.chunks_exact(dim)
            .take(n)
            .flat_map(|row| {
                row.iter()
                    .zip(&self.mean)
                    .zip(&std)
                    .map(|((x, m), s)| ((x - m) / s).clamp(-self.clip, self.clip))
            })
            .collect()
    }
}

/// Runs a stack of dense layers: `activation` after every layer but the last.
pub fn mlp_forward(layers: &[DenseLayer], activation: Activation, x: &[f32], n: usize) -> Vec<f32> {
    let mut h = x.to_vec();
    for (i, layer) in layers.iter().enumerate() {
        h = layer.forward(&h, n);
        if i + 1 < layers.len() {
            h.iter_mut().for_each(|v| *v = activation.apply(*v));
        }
    }
    h
}

impl PolicyGraph {
    /// Observation width (the first actor layer's input).
    pub fn obs_dim(&self) -> usize {
        self.actor.first().map_or(0, |l| l.d_in)
    }

    /// Action width: 1 for a categorical head (the index), the last layer's width for a Gaussian one.
    pub fn action_dim(&self) -> usize {
        match self.head {
            ActionHead::Categorical { .. } => 1,
            ActionHead::Gaussian { .. } => self.actor.last().map_or(0, |l| l.d_out),
        }
    }

    /// Normalised observations as the first layer sees them.
    fn normalised(&self, obs: &[f32], n: usize) -> Vec<f32> {
        match &self.normaliser {
            Some(norm) => norm.apply(obs, n),
            None => obs[..n * self.obs_dim()].to_vec(),
        }
    }

    /// The actor's last-layer output (logits or Gaussian mean), `[n, d_out]`.
    pub fn actor_output(&self, obs: &[f32], n: usize) -> Vec<f32> {
        mlp_forward(&self.actor, self.activation, &self.normalised(obs, n), n)
    }

    /// The critic's value estimate `[n]`, when there is a critic.
    pub fn value(&self, obs: &[f32], n: usize) -> Option<Vec<f32>> {
        let critic = self.critic.as_ref()?;
        Some(mlp_forward(
            critic,
            self.activation,
            &self.normalised(obs, n),
            n,
        ))
    }

    /// Reference evaluation in plain Rust f32 (the ground truth both burn and ONNX are compared against).
    ///
    /// `obs` is row-major `[n, obs_dim]`; returns `[n x action_dim]` (categorical: index as f32).
    pub fn act(&self, obs: &[f32], n: usize) -> Vec<f32> {
        let out = self.actor_output(obs, n);
        match &self.head {
            ActionHead::Categorical { n: n_actions } => out
                .chunks_exact(*n_actions)
                .map(|logits| argmax(logits) as f32)
                .collect(),
            ActionHead::Gaussian { transform } => {
                let dim = self.action_dim();
                out.chunks_exact(dim)
                    .flat_map(|mean| mean.iter().enumerate().map(|(j, &m)| transform.apply(j, m)))
                    .collect()
            }
        }
    }
}

impl ActionTransform {
    /// Maps the Gaussian mean of action dimension `j` to the environment's bounds.
    pub fn apply(&self, j: usize, mean: f32) -> f32 {
        match self {
            ActionTransform::Clip { low, high } => mean.max(low[j]).min(high[j]),
            ActionTransform::TanhScale { low, high } => {
                low[j] + (mean.tanh() + 1.0) / 2.0 * (high[j] - low[j])
            }
        }
    }
}

/// Index of the largest value; the first one on ties (ONNX ArgMax with `select_last_index = 0`).
pub fn argmax(values: &[f32]) -> usize {
    let mut best = 0;
    for (i, v) in values.iter().enumerate() {
        if *v > values[best] {
            best = i;
        }
    }
    best
}

impl PolicyGraph {
    /// Checks that the layers chain, the head and normaliser fit the layer widths, and the metadata
    /// lists are either empty or one entry per dimension.
    pub fn validate(&self) -> Result<(), ExportError> {
        let bad = |msg: String| Err(ExportError::InvalidGraph(msg));
        check_layers("actor", &self.actor)?;
        let obs_dim = self.obs_dim();
        let out_dim = self.actor.last().map_or(0, |l| l.d_out);
        if let Some(critic) = &self.critic {
            check_layers("critic", critic)?;
            if critic[0].d_in != obs_dim {
                return bad(format!(
                    "critic input width {} differs from actor input width {obs_dim}",
                    critic[0].d_in
                ));
            }
            if critic[critic.len() - 1].d_out != 1 {
                return bad("critic output width must be 1".into());
            }
        }
        if let Some(norm) = &self.normaliser {
            if norm.mean.len() != obs_dim || norm.var.len() != obs_dim {
                return bad(format!(
                    "normaliser has {} means and {} variances for {obs_dim} observations",
                    norm.mean.len(),
                    norm.var.len()
                ));
            }
            if norm.clip.is_nan() || norm.clip <= 0.0 || norm.eps.is_nan() || norm.eps < 0.0 {
                return bad(format!(
                    "normaliser clip {} must be > 0 and eps {} >= 0",
                    norm.clip, norm.eps
                ));
            }
            if let Some(j) = norm
                .var
                .iter()
                .position(|v| (v + norm.eps).is_nan() || v + norm.eps <= 0.0)
            {
                return bad(format!("normaliser var[{j}] + eps must be > 0"));
            }
        }
        match &self.head {
            ActionHead::Categorical { n } if *n != out_dim || *n < 2 => {
                return bad(format!(
                    "categorical head over {n} actions but the last layer has {out_dim} outputs"
                ));
            }
            ActionHead::Gaussian { transform } => {
                let (low, high) = transform.bounds();
                if low.len() != out_dim || high.len() != out_dim {
                    return bad(format!(
                        "action transform has {} lows and {} highs for {out_dim} actions",
                        low.len(),
                        high.len()
                    ));
                }
                if let Some(j) = (0..out_dim)
                    .position(|j| low[j].is_nan() || high[j].is_nan() || low[j] > high[j])
                {
                    return bad(format!("action bound {j}: low must be <= high"));
                }
            }
            _ => {}
        }
        let meta = &self.meta;
        let action_dim = self.action_dim();
        for (key, len, want) in [
            ("obs_names", meta.obs_names.len(), obs_dim),
            ("obs_units", meta.obs_units.len(), obs_dim),
            ("obs_low", meta.obs_low.len(), obs_dim),
            ("obs_high", meta.obs_high.len(), obs_dim),
            ("action_names", meta.action_names.len(), action_dim),
            ("action_units", meta.action_units.len(), action_dim),
            ("action_low", meta.action_low.len(), action_dim),
            ("action_high", meta.action_high.len(), action_dim),
        ] {
            if len != 0 && len != want {
                return bad(format!("meta.{key} has {len} entries, expected {want}"));
            }
        }
        Ok(())
    }
}

/// Checks one layer stack: non-empty, consistent sizes, consecutive widths chain.
fn check_layers(what: &str, layers: &[DenseLayer]) -> Result<(), ExportError> {
    let bad = |msg: String| Err(ExportError::InvalidGraph(format!("{what}: {msg}")));
    if layers.is_empty() {
        return bad("no layers".into());
    }
    for (i, layer) in layers.iter().enumerate() {
        if layer.d_in == 0 || layer.d_out == 0 {
            return bad(format!("layer {i} has a zero width"));
        }
        if layer.weight.len() != layer.d_in * layer.d_out || layer.bias.len() != layer.d_out {
            return bad(format!(
                "layer {i} ({} -> {}) has {} weights and {} biases",
                layer.d_in,
                layer.d_out,
                layer.weight.len(),
                layer.bias.len()
            ));
        }
        if i > 0 && layers[i - 1].d_out != layer.d_in {
            return bad(format!(
                "layer {i} takes {} inputs but layer {} gives {}",
                layer.d_in,
                i - 1,
                layers[i - 1].d_out
            ));
        }
    }
    Ok(())
}

impl ActionTransform {
    /// The `(low, high)` bounds per action dimension.
    pub fn bounds(&self) -> (&[f32], &[f32]) {
        match self {
            ActionTransform::Clip { low, high } | ActionTransform::TanhScale { low, high } => {
                (low, high)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layer(d_in: usize, d_out: usize, weight: &[f32], bias: &[f32]) -> DenseLayer {
        DenseLayer {
            d_in,
            d_out,
            weight: weight.to_vec(),
            bias: bias.to_vec(),
        }
    }

    /// Two observations, one hidden ReLU unit, Gaussian head: every number checked by hand.
    fn tiny(transform: ActionTransform) -> PolicyGraph {
        PolicyGraph {
            normaliser: Some(ObsNormaliser {
                mean: vec![1.0, -1.0],
                var: vec![4.0, 0.25],
                eps: 0.0,
                clip: 3.0,
            }),
            // h = relu(x0 - x1), out = 2 h - 1
            actor: vec![
                layer(2, 1, &[1.0, -1.0], &[0.0]),
                layer(1, 1, &[2.0], &[-1.0]),
            ],
            critic: None,
            activation: Activation::Relu,
            head: ActionHead::Gaussian { transform },
            meta: PolicyMeta::default(),
        }
    }

    #[test]
    fn act_applies_normaliser_layers_and_clip_in_order() {
        let graph = tiny(ActionTransform::Clip {
            low: vec![-0.5],
            high: vec![2.0],
        });
        // x = ((3 - 1) / 2, (-1 + 1) / 0.5) = (1, 0): h = 1, out = 1.
        // x = ((9 - 1) / 2 -> clip 3, (-2 + 1) / 0.5 = -2): h = 5, out = 9 -> 2.
        // x = ((1 - 1) / 2, (0 + 1) / 0.5 = 2): h = relu(-2) = 0, out = -1 -> -0.5.
        let obs = [3.0, -1.0, 9.0, -2.0, 1.0, 0.0];
        assert_eq!(graph.act(&obs, 3), vec![1.0, 2.0, -0.5]);
    }

    #[test]
    fn tanh_scale_maps_to_bounds() {
        let graph = tiny(ActionTransform::TanhScale {
            low: vec![-2.0],
            high: vec![6.0],
        });
        // out = 1 (first row above): -2 + (tanh(1) + 1) / 2 * 8.
        let want = -2.0 + (1.0f32.tanh() + 1.0) / 2.0 * 8.0;
        assert_eq!(graph.act(&[3.0, -1.0], 1), vec![want]);
    }

    #[test]
    fn categorical_head_returns_first_argmax() {
        let graph = PolicyGraph {
            normaliser: None,
            actor: vec![layer(1, 3, &[1.0, -1.0, 1.0], &[0.0, 0.0, 0.0])],
            critic: Some(vec![layer(1, 1, &[0.5], &[1.0])]),
            activation: Activation::Tanh,
            head: ActionHead::Categorical { n: 3 },
            meta: PolicyMeta::default(),
        };
        assert_eq!(graph.act(&[2.0, -2.0], 2), vec![0.0, 1.0]);
        assert_eq!(graph.value(&[2.0, -2.0], 2), Some(vec![2.0, 0.0]));
        assert_eq!(graph.action_dim(), 1);
        graph.validate().unwrap();
    }

    #[test]
    fn elu_matches_definition() {
        assert_eq!(Activation::Elu.apply(2.0), 2.0);
        assert!((Activation::Elu.apply(-1.0) - (-1.0f32).exp_m1()).abs() < 1e-7);
        assert_eq!(Activation::Relu.apply(-3.0), 0.0);
    }

    #[test]
    fn validate_rejects_inconsistent_graphs() {
        let ok = tiny(ActionTransform::Clip {
            low: vec![-1.0],
            high: vec![1.0],
        });
        ok.validate().unwrap();
        let mut bad_weights = ok.clone();
        bad_weights.actor[0].weight.pop();
        let mut bad_chain = ok.clone();
        bad_chain.actor[1] = layer(2, 1, &[1.0, 1.0], &[0.0]);
        let mut bad_norm = ok.clone();
        bad_norm.normaliser.as_mut().unwrap().mean.push(0.0);
        let mut bad_bounds = ok.clone();
        bad_bounds.head = ActionHead::Gaussian {
            transform: ActionTransform::Clip {
                low: vec![1.0],
                high: vec![-1.0],
            },
        };
        let mut bad_meta = ok.clone();
        bad_meta.meta.obs_names = vec!["only_one".into()];
        let mut bad_head = ok.clone();
        bad_head.head = ActionHead::Categorical { n: 2 };
        for (what, graph) in [
            ("weights", bad_weights),
            ("chain", bad_chain),
            ("normaliser", bad_norm),
            ("bounds", bad_bounds),
            ("meta", bad_meta),
            ("head", bad_head),
        ] {
            assert!(
                matches!(graph.validate(), Err(ExportError::InvalidGraph(_))),
                "{what} not rejected"
            );
        }
    }
}
