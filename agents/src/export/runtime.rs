//! Running exported policies with tract (a pure-Rust ONNX runtime), comparing them with the
//! plain-Rust reference [`PolicyGraph::act`], and timing single-observation inference.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use prost::Message;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tract_onnx::pb::ModelProto;
use tract_onnx::prelude::*;

use super::graph::PolicyGraph;
use super::onnx::{OUTPUT_ACTION, OUTPUT_LOGITS, OUTPUT_VALUE};
use super::ExportError;

/// An ONNX policy loaded into tract, ready to run batches of observations of any size.
pub struct OnnxPolicy {
    plan: Arc<TypedRunnableModel>,
    source: PathBuf,
    obs_dim: usize,
    output_names: Vec<String>,
    metadata: BTreeMap<String, String>,
}

/// What an ONNX policy returned for a batch of `n` observations (row-major).
#[derive(Debug, Clone, PartialEq)]
pub struct PolicyOutputs {
    /// `[n, action_dim]` actions as the environment receives them (categorical: index as f32).
    pub action: Vec<f32>,
    /// `[n, n_actions]` logits, for categorical policies.
    pub logits: Option<Vec<f32>>,
    /// `[n, 1]` value estimates, when the critic was exported.
    pub value: Option<Vec<f32>>,
}

impl OnnxPolicy {
    /// Loads the ONNX file at `path`.
    pub fn load(path: &Path) -> Result<Self, ExportError> {
        let bytes = std::fs::read(path).map_err(|source| ExportError::Io {
            path: path.into(),
            source,
        })?;
        Self::from_bytes(&bytes, path)
    }

    /// Loads ONNX bytes; `source` only names them in errors.
    pub fn from_bytes(bytes: &[u8], source: &Path) -> Result<Self, ExportError> {
        let proto = ModelProto::decode(bytes).map_err(|e| ExportError::NotOnnx {
            path: source.into(),
            reason: e.to_string(),
        })?;
        let runtime_err = |e: TractError| ExportError::Runtime {
            path: source.into(),
            reason: format!("{e:#}"),
        };
        let graph = proto.graph.as_ref().ok_or_else(|| ExportError::NotOnnx {
            path: source.into(),
            reason: "the model has no graph".into(),
        })?;
        let obs_dim = input_width(graph).ok_or_else(|| ExportError::NotOnnx {
            path: source.into(),
            reason: "expected one input of shape [batch, obs_dim] with a fixed obs_dim".into(),
        })?;
        check_finite(graph, source)?;
        let output_names: Vec<String> = graph.output.iter().map(|o| o.name.clone()).collect();
        if !output_names.iter().any(|name| name == OUTPUT_ACTION) {
            return Err(ExportError::NotOnnx {
                path: source.into(),
                reason: format!(
                    "expected an output named `{OUTPUT_ACTION}`, found {output_names:?}"
                ),
            });
        }
        let metadata: BTreeMap<String, String> = proto
            .metadata_props
            .iter()
            .map(|p| (p.key.clone(), p.value.clone()))
            .collect();
        check_action_head(&metadata, &output_names, source)?;
        let plan = tract_onnx::onnx()
            .model_for_proto_model(&proto)
            .and_then(|model| model.into_optimized())
            .and_then(|model| model.into_runnable())
            .map_err(runtime_err)?;
        Ok(Self {
            plan,
            source: source.into(),
            obs_dim,
            output_names,
            metadata,
        })
    }

    /// Observation width the policy expects.
    pub fn obs_dim(&self) -> usize {
        self.obs_dim
    }

    /// The model's `metadata_props`.
    pub fn metadata(&self) -> &BTreeMap<String, String> {
        &self.metadata
    }

    /// Runs `n` observations (row-major `[n, obs_dim]`) and returns every known output.
    pub fn run(&self, obs: &[f32], n: usize) -> Result<PolicyOutputs, ExportError> {
        let expected = n * self.obs_dim;
        if obs.len() != expected {
            return Err(ExportError::ObsShape {
                rows: n,
                obs_dim: self.obs_dim,
                expected,
                got: obs.len(),
            });
        }
        let runtime_err = |e: TractError| ExportError::Runtime {
            path: self.source.clone(),
            reason: format!("{e:#}"),
        };
        let input = Tensor::from_shape(&[n, self.obs_dim], obs).map_err(runtime_err)?;
        let outputs = self
            .plan
            .run(tvec!(input.into_tvalue()))
            .map_err(runtime_err)?;
        let mut found = PolicyOutputs {
            action: Vec::new(),
            logits: None,
            value: None,
        };
        for (name, tensor) in self.output_names.iter().zip(outputs.iter()) {
            let values = tensor
                .cast_to::<f32>()
                .and_then(|t| {
                    Ok(t.to_plain_array_view::<f32>()?
                        .iter()
                        .copied()
                        .collect::<Vec<f32>>())
                })
                .map_err(runtime_err)?;
            match name.as_str() {
                OUTPUT_ACTION => found.action = values,
                OUTPUT_LOGITS => found.logits = Some(values),
                OUTPUT_VALUE => found.value = Some(values),
                _ => {}
            }
        }
        Ok(found)
    }

    /// Actions for `n` observations, `[n, action_dim]` (categorical: index as f32).
    pub fn act(&self, obs: &[f32], n: usize) -> Result<Vec<f32>, ExportError> {
        Ok(self.run(obs, n)?.action)
    }
}

/// Width of the single `[batch, obs_dim]` input.
/// The action heads `rlpkg export` writes (metadata `action_head`), and whether each outputs logits.
const ACTION_HEADS: [(&str, bool); 3] = [
    ("categorical_argmax", true),
    ("gaussian_mean_clip", false),
    ("gaussian_mean_tanh_scale", false),
];

/// The metadata `action_head`, when present, must be one `rlpkg export` writes and agree with the
/// outputs (logits for a categorical head only): an unknown head would be run as if it were known.
fn check_action_head(
    metadata: &BTreeMap<String, String>,
    output_names: &[String],
    source: &Path,
) -> Result<(), ExportError> {
    let Some(head) = metadata.get("action_head") else {
        return Ok(());
    };
    let has_logits = output_names.iter().any(|name| name == OUTPUT_LOGITS);
    match ACTION_HEADS.iter().find(|(name, _)| name == head) {
        Some(&(_, logits)) if logits == has_logits => Ok(()),
        Some(_) => Err(ExportError::Metadata {
            path: source.into(),
            key: "action_head".into(),
            expected: format!(
                "a head that fits the outputs {output_names:?} (`{head}` {} output `{OUTPUT_LOGITS}`)",
                if has_logits { "has no" } else { "needs an" }
            ),
        }),
        None => Err(ExportError::Metadata {
            path: source.into(),
            key: "action_head".into(),
            expected: format!(
                "one of {} (found `{head}`)",
                ACTION_HEADS.map(|(name, _)| name).join(", ")
            ),
        }),
    }
}

/// Every f32 initializer and constant of `graph` must be finite: tract would run a NaN weight
/// without a word and the policy would act on NaN.
fn check_finite(graph: &tract_onnx::pb::GraphProto, source: &Path) -> Result<(), ExportError> {
    const FLOAT: i32 = 1;
    let constants = graph.node.iter().flat_map(|node| {
        node.attribute
            .iter()
            .filter_map(move |a| a.t.as_ref().map(|t| (node.name.as_str(), t)))
    });
    let tensors = graph
        .initializer
        .iter()
        .map(|t| (t.name.as_str(), t))
        .chain(constants);
    for (name, tensor) in tensors {
        if tensor.data_type != FLOAT {
            continue;
        }
        let raw = tensor
            .raw_data
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]));
        let values = tensor.float_data.iter().copied().chain(raw);
        if let Some((index, value)) = values.enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(ExportError::NonFinite {
                path: source.into(),
                tensor: if tensor.name.is_empty() {
                    name
                } else {
                    &tensor.name
                }
                .to_string(),
                index,
                value,
            });
        }
    }
    Ok(())
}

fn input_width(graph: &tract_onnx::pb::GraphProto) -> Option<usize> {
    use tract_onnx::pb::{tensor_shape_proto::dimension::Value, type_proto};
    let [input] = graph.input.as_slice() else {
        return None;
    };
    let Some(type_proto::Value::TensorType(tensor)) = input.r#type.as_ref()?.value.as_ref() else {
        return None;
    };
    match tensor.shape.as_ref()?.dim.as_slice() {
        [_, width] => match width.value {
            Some(Value::DimValue(w)) if w > 0 => Some(w as usize),
            _ => None,
        },
        _ => None,
    }
}

/// How closely two evaluations of a policy agree on the same observations.
#[derive(Debug, Clone, PartialEq)]
pub struct Agreement {
    /// Observations compared.
    pub rows: usize,
    /// Largest absolute action difference, and the row where it occurs.
    pub action: (f32, usize),
    /// Largest logit difference, scaled as in [`max_scaled_diff`] (categorical heads).
    pub logits: Option<(f32, usize)>,
    /// Largest value difference, scaled as in [`max_scaled_diff`] (when the critic was exported).
    pub value: Option<(f32, usize)>,
}

impl Agreement {
    /// The largest difference over every compared output (absolute for actions, scaled for logits
    /// and values).
    pub fn max_abs_diff(&self) -> f32 {
        [Some(self.action), self.logits, self.value]
            .into_iter()
            .flatten()
            .map(|(diff, _)| diff)
            .fold(0.0, f32::max)
    }

    /// `Ok` when every compared output agrees within `tolerance`, else the first that does not.
    pub fn check(&self, tolerance: f32) -> Result<(), ExportError> {
        let outputs = [
            (OUTPUT_ACTION, Some(self.action)),
            (OUTPUT_LOGITS, self.logits),
            (OUTPUT_VALUE, self.value),
        ];
        for (what, diff) in outputs {
            if let Some((max_abs_diff, row)) = diff {
                // NaN counts as a mismatch.
                if max_abs_diff.is_nan() || max_abs_diff > tolerance {
                    return Err(ExportError::Mismatch {
                        what: what.into(),
                        max_abs_diff,
                        tolerance,
                        row,
                    });
                }
            }
        }
        Ok(())
    }
}

/// Largest absolute difference between `a` and `b` (rows of `width`) and its row; NaN anywhere or
/// different lengths give an infinite difference.
pub fn max_abs_diff(a: &[f32], b: &[f32], width: usize) -> (f32, usize) {
    max_diff(a, b, width, |_| 1.0)
}

/// Like [`max_abs_diff`], but each difference is divided by `max(1, |b|)`: absolute for reference
/// values up to 1 in magnitude, relative above (an f32 holds about 7 significant digits, so a value
/// estimate of 300 cannot agree to 1e-5 absolutely).
pub fn max_scaled_diff(a: &[f32], b: &[f32], width: usize) -> (f32, usize) {
    max_diff(a, b, width, |reference| reference.abs().max(1.0))
}

fn max_diff(a: &[f32], b: &[f32], width: usize, scale: impl Fn(f32) -> f32) -> (f32, usize) {
    if a.len() != b.len() {
        return (f32::INFINITY, 0);
    }
    let mut worst = (0.0f32, 0);
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        let diff = if x.is_nan() || y.is_nan() {
            f32::INFINITY
        } else {
            (x - y).abs() / scale(*y)
        };
        if diff > worst.0 {
            worst = (diff, i / width.max(1));
        }
    }
    worst
}

/// Compares the ONNX policy with the reference `expected` graph on `n` observations: actions, and
/// logits / value when both sides have them.
pub fn compare_with_reference(
    expected: &PolicyGraph,
    policy: &OnnxPolicy,
    obs: &[f32],
    n: usize,
) -> Result<Agreement, ExportError> {
    let got = policy.run(obs, n)?;
    let want_action = expected.act(obs, n);
    let action = max_abs_diff(&got.action, &want_action, expected.action_dim());
    let logits = match (&got.logits, &expected.head) {
        (Some(logits), super::ActionHead::Categorical { n: width }) => Some(max_scaled_diff(
            logits,
            &expected.actor_output(obs, n),
            *width,
        )),
        _ => None,
    };
    let value = match (&got.value, expected.value(obs, n)) {
        (Some(got), Some(want)) => Some(max_scaled_diff(got, &want, 1)),
        _ => None,
    };
    Ok(Agreement {
        rows: n,
        action,
        logits,
        value,
    })
}

/// `n` random observations (row-major) for testing `graph`, seeded: with a normaliser, uniform in
/// mean +- 6 std (so some fall beyond the usual clips of 5 or less); otherwise uniform within the
/// observation bounds, and in [-3, 3] where a bound is unbounded (beyond 1e30) or unknown.
pub fn random_observations(graph: &PolicyGraph, n: usize, seed: u64) -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let dim = graph.obs_dim();
    let ranges: Vec<(f32, f32)> = (0..dim)
        .map(|j| match &graph.normaliser {
            Some(norm) => {
                let std = (norm.var[j] + norm.eps).sqrt();
                (norm.mean[j] - 6.0 * std, norm.mean[j] + 6.0 * std)
            }
            None => {
                // Environments mark unbounded dimensions with f32::MIN / f32::MAX.
                let bounded = |v: &f32| v.abs() < 1e30;
                let low = graph.meta.obs_low.get(j).copied().filter(bounded);
                let high = graph.meta.obs_high.get(j).copied().filter(bounded);
                match (low, high) {
                    (Some(lo), Some(hi)) if lo < hi => (lo, hi),
                    _ => (-3.0, 3.0),
                }
            }
        })
        .collect();
    (0..n)
        .flat_map(|_| ranges.clone())
        .map(|(lo, hi)| {
            if lo < hi {
                rng.random_range(lo..hi)
            } else {
                lo
            }
        })
        .collect()
}

/// Single-observation inference latency over repeated runs, in microseconds.
#[derive(Debug, Clone, PartialEq)]
pub struct Latency {
    /// Timed runs (after warm-up).
    pub runs: usize,
    /// Median over the runs.
    pub median_us: f64,
    /// 90th percentile.
    pub p90_us: f64,
    /// Mean.
    pub mean_us: f64,
}

/// Times `runs` single-observation inferences of `policy` after `runs / 10` warm-up runs. The
/// observations come from `obs` (rows of `obs_dim`), cycling.
pub fn measure_latency(
    policy: &OnnxPolicy,
    obs: &[f32],
    runs: usize,
) -> Result<Latency, ExportError> {
    let runs = runs.max(1);
    let dim = policy.obs_dim();
    let rows = obs.len() / dim;
    if rows == 0 {
        return Err(ExportError::ObsShape {
            rows: 1,
            obs_dim: dim,
            expected: dim,
            got: obs.len(),
        });
    }
    for i in 0..runs / 10 {
        policy.act(&obs[(i % rows) * dim..][..dim], 1)?;
    }
    let mut times = Vec::with_capacity(runs);
    for i in 0..runs {
        let row = &obs[(i % rows) * dim..][..dim];
        let start = Instant::now();
        let action = policy.act(row, 1)?;
        times.push(start.elapsed().as_secs_f64() * 1e6);
        std::hint::black_box(action);
    }
    times.sort_by(f64::total_cmp);
    let pick = |q: f64| times[((times.len() - 1) as f64 * q).round() as usize];
    Ok(Latency {
        runs,
        median_us: pick(0.5),
        p90_us: pick(0.9),
        mean_us: times.iter().sum::<f64>() / runs.max(1) as f64,
    })
}

/// Returns of deterministic episodes, and every observation the policy acted on.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeStats {
    /// Undiscounted return of each episode, in environment-copy order.
    pub returns: Vec<f32>,
    /// Length in steps of each episode.
    pub lengths: Vec<usize>,
    /// Row-major observations the policy acted on during the counted episodes.
    pub visited_obs: Vec<f32>,
}

impl EpisodeStats {
    /// Mean return over the episodes.
    pub fn mean_return(&self) -> f64 {
        self.returns.iter().map(|&r| r as f64).sum::<f64>() / self.returns.len().max(1) as f64
    }

    /// Population standard deviation of the returns.
    pub fn std_return(&self) -> f64 {
        let mean = self.mean_return();
        let var = self
            .returns
            .iter()
            .map(|&r| (r as f64 - mean).powi(2))
            .sum::<f64>()
            / self.returns.len().max(1) as f64;
        var.sqrt()
    }
}

/// Runs one deterministic episode per copy of `env`, all in lockstep (copy `i` seeded from
/// `seed + i`), choosing actions with `act(obs, rows)`; keeps at most `keep_rows` visited
/// observations (an evaluation of many episodes needs none, and keeping them all would grow with
/// episodes x length).
pub fn run_episodes<E>(
    env: &mut dyn rlpkg_vec_env::VecEnv,
    seed: u64,
    keep_rows: usize,
    mut act: impl FnMut(&[f32], usize) -> Result<Vec<f32>, E>,
) -> Result<EpisodeStats, E>
where
    E: From<rlpkg_vec_env::EnvError>,
{
    let episodes = env.num_envs();
    let obs_dim = env.spec().observation.dim();
    let mut buffers = env.buffers();
    env.reset(seed, &mut buffers)?;
    let mut returns = vec![0.0f32; episodes];
    let mut lengths = vec![0usize; episodes];
    let mut running = vec![true; episodes];
    let mut visited_obs = Vec::new();
    while running.iter().any(|&r| r) {
        for (env_index, _) in running.iter().enumerate().filter(|(_, &r)| r) {
            if visited_obs.len() / obs_dim.max(1) >= keep_rows {
                break;
            }
            visited_obs.extend_from_slice(&buffers.obs[env_index * obs_dim..][..obs_dim]);
        }
        let actions = act(&buffers.obs, episodes)?;
        env.step(&actions, &mut buffers)?;
        for env_index in 0..episodes {
            if running[env_index] {
                returns[env_index] += buffers.rewards[env_index];
                lengths[env_index] += 1;
                running[env_index] = !buffers.done(env_index);
            }
        }
    }
    Ok(EpisodeStats {
        returns,
        lengths,
        visited_obs,
    })
}
