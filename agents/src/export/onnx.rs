//! [`PolicyGraph`] -> ONNX `ModelProto` (the prost types of `tract_onnx::pb`), and back for metadata.
//!
//! Graph: `obs` [batch, obs_dim] -> Sub(mean) -> Div(sqrt(var + eps)) -> Clip(-clip, clip) -> Gemm
//! layers with activations -> action transform -> `action` (+ `logits` for categorical heads, + `value`
//! when the critic is given). The batch dimension is symbolic (`dim_param = "batch"`).

use std::collections::BTreeMap;
use std::path::Path;

use prost::Message;
use tract_onnx::pb::{
    attribute_proto::AttributeType, tensor_proto::DataType, tensor_shape_proto, type_proto,
    AttributeProto, GraphProto, ModelProto, NodeProto, OperatorSetIdProto, StringStringEntryProto,
    TensorProto, TensorShapeProto, TypeProto, ValueInfoProto,
};

use super::graph::{ActionHead, ActionTransform, Activation, DenseLayer, PolicyGraph, PolicyMeta};
use super::ExportError;

/// ONNX operator set the graph is written for (Clip takes its bounds as inputs since opset 11).
pub const OPSET_VERSION: i64 = 17;
/// ONNX IR version matching [`OPSET_VERSION`].
pub const IR_VERSION: i64 = 8;
/// Name of the observation input.
pub const INPUT_OBS: &str = "obs";
/// Name of the action output.
pub const OUTPUT_ACTION: &str = "action";
/// Name of the logits output (categorical heads only).
pub const OUTPUT_LOGITS: &str = "logits";
/// Name of the value output (when the critic is exported).
pub const OUTPUT_VALUE: &str = "value";
/// Symbolic name of the batch dimension.
pub const BATCH_DIM: &str = "batch";

/// Builds the ONNX model for `graph` and encodes it as protobuf bytes.
pub fn to_onnx_bytes(graph: &PolicyGraph) -> Result<Vec<u8>, ExportError> {
    Ok(to_model_proto(graph)?.encode_to_vec())
}

/// Writes `graph` as an ONNX file at `path` atomically (temporary file in the same folder, then
/// rename); returns the file size in bytes.
pub fn write_onnx(graph: &PolicyGraph, path: &Path) -> Result<u64, ExportError> {
    let bytes = to_onnx_bytes(graph)?;
    write_atomically(path, &bytes)?;
    Ok(bytes.len() as u64)
}

/// Writes `bytes` to `path` through a temporary file in the same folder and a rename, so readers
/// never see a half-written file.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), ExportError> {
    rlpkg_files::write_atomic(path, bytes).map_err(|source| ExportError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Builds the ONNX `ModelProto` for `graph` (validated first).
pub fn to_model_proto(graph: &PolicyGraph) -> Result<ModelProto, ExportError> {
    graph.validate()?;
    let mut b = GraphBuilder::default();
    let obs_dim = graph.obs_dim() as i64;

    let mut features = INPUT_OBS.to_string();
    if let Some(norm) = &graph.normaliser {
        // Constants computed exactly as `ObsNormaliser::apply` does, so both divide by the same f32s.
        let mean = b.constant("norm_mean", &[obs_dim], &norm.mean);
        let std = b.constant("norm_std", &[obs_dim], &norm.std());
        let lo = b.constant("norm_clip_low", &[], &[-norm.clip]);
        let hi = b.constant("norm_clip_high", &[], &[norm.clip]);
        let centred = b.node("Sub", &[&features, &mean], "norm_centred", vec![]);
        let scaled = b.node("Div", &[&centred, &std], "norm_scaled", vec![]);
        features = b.node("Clip", &[&scaled, &lo, &hi], "obs_normalised", vec![]);
    }

    let head_out = match graph.head {
        ActionHead::Categorical { .. } => OUTPUT_LOGITS,
        ActionHead::Gaussian { .. } => "action_mean",
    };
    let actor_out = b.mlp("actor", &graph.actor, graph.activation, &features, head_out);

    let mut outputs = Vec::new();
    match &graph.head {
        ActionHead::Categorical { n } => {
            let argmax = vec![attr_int("axis", 1), attr_int("keepdims", 1)];
            b.node("ArgMax", &[&actor_out], OUTPUT_ACTION, argmax);
            outputs.push(value_info(OUTPUT_ACTION, DataType::Int64, 1));
            outputs.push(value_info(OUTPUT_LOGITS, DataType::Float, *n as i64));
        }
        ActionHead::Gaussian { transform } => {
            let dim = graph.action_dim() as i64;
            match transform {
                ActionTransform::Clip { low, high } => {
                    // ONNX Clip takes scalar bounds only: per-dimension bounds are Max then Min.
                    let low = b.constant("action_low", &[dim], low);
                    let high = b.constant("action_high", &[dim], high);
                    let floored = b.node("Max", &[&actor_out, &low], "action_floored", vec![]);
                    b.node("Min", &[&floored, &high], OUTPUT_ACTION, vec![]);
                }
                ActionTransform::TanhScale { low, high } => {
                    let range: Vec<f32> = low.iter().zip(high).map(|(l, h)| h - l).collect();
                    let one = b.constant("one", &[], &[1.0]);
                    let two = b.constant("two", &[], &[2.0]);
                    let range = b.constant("action_range", &[dim], &range);
                    let low = b.constant("action_low", &[dim], low);
                    let squashed = b.node("Tanh", &[&actor_out], "action_tanh", vec![]);
                    let shifted = b.node("Add", &[&squashed, &one], "action_shifted", vec![]);
                    let unit = b.node("Div", &[&shifted, &two], "action_unit", vec![]);
                    let scaled = b.node("Mul", &[&unit, &range], "action_scaled", vec![]);
                    b.node("Add", &[&low, &scaled], OUTPUT_ACTION, vec![]);
                }
            }
            outputs.push(value_info(OUTPUT_ACTION, DataType::Float, dim));
        }
    }
    if let Some(critic) = &graph.critic {
        b.mlp("critic", critic, graph.activation, &features, OUTPUT_VALUE);
        outputs.push(value_info(OUTPUT_VALUE, DataType::Float, 1));
    }

    let onnx_graph = GraphProto {
        name: format!("rlpkg_policy_{}", graph.meta.env_id),
        node: b.nodes,
        initializer: b.initializers,
        input: vec![value_info(INPUT_OBS, DataType::Float, obs_dim)],
        output: outputs,
        doc_string: "Deterministic rlpkg policy: observation normaliser, actor MLP and action \
                     transform to the environment's bounds."
            .into(),
        ..Default::default()
    };
    Ok(ModelProto {
        ir_version: IR_VERSION,
        opset_import: vec![OperatorSetIdProto {
            domain: String::new(),
            version: OPSET_VERSION,
        }],
        producer_name: "rlpkg".into(),
        producer_version: graph.meta.rlpkg_version.clone(),
        model_version: 1,
        doc_string: format!("rlpkg policy for {}", graph.meta.env_id),
        graph: Some(onnx_graph),
        metadata_props: metadata_props(graph)
            .into_iter()
            .map(|(key, value)| StringStringEntryProto { key, value })
            .collect(),
        ..Default::default()
    })
}

/// The `metadata_props` written for `graph`: lists and bounds as JSON strings (non-finite bounds
/// as the strings `"inf"` / `"-inf"`, since JSON has no infinity).
pub fn metadata_props(graph: &PolicyGraph) -> BTreeMap<String, String> {
    let meta = &graph.meta;
    let strings = |v: &[String]| serde_json::Value::from(v.to_vec()).to_string();
    let mut props = BTreeMap::new();
    props.insert("env_id".into(), meta.env_id.clone());
    props.insert("rlpkg_version".into(), meta.rlpkg_version.clone());
    props.insert("config_hash".into(), meta.config_hash.clone());
    props.insert("obs_names".into(), strings(&meta.obs_names));
    props.insert("obs_units".into(), strings(&meta.obs_units));
    props.insert("obs_low".into(), bounds_json(&meta.obs_low));
    props.insert("obs_high".into(), bounds_json(&meta.obs_high));
    props.insert("action_names".into(), strings(&meta.action_names));
    props.insert("action_units".into(), strings(&meta.action_units));
    props.insert("action_low".into(), bounds_json(&meta.action_low));
    props.insert("action_high".into(), bounds_json(&meta.action_high));
    let head = match &graph.head {
        ActionHead::Categorical { .. } => "categorical_argmax",
        ActionHead::Gaussian {
            transform: ActionTransform::Clip { .. },
        } => "gaussian_mean_clip",
        ActionHead::Gaussian {
            transform: ActionTransform::TanhScale { .. },
        } => "gaussian_mean_tanh_scale",
    };
    props.insert("action_head".into(), head.into());
    let norm = match &graph.normaliser {
        Some(n) => format!(
            "in_graph: clamp((obs - mean) / sqrt(var + {:e}), -{}, {})",
            n.eps, n.clip, n.clip
        ),
        None => "none".into(),
    };
    props.insert("obs_normaliser".into(), norm);
    props
}

/// JSON array of bounds; non-finite values become the strings `"inf"`, `"-inf"`, `"nan"`. Finite
/// values are written as shortest round-trip f32 decimals (`4.8`, not `4.800000190734863`).
fn bounds_json(values: &[f32]) -> String {
    let items: Vec<String> = values
        .iter()
        .map(|&v| {
            if v.is_finite() {
                format!("{v}")
            } else if v.is_nan() {
                "\"nan\"".into()
            } else if v > 0.0 {
                "\"inf\"".into()
            } else {
                "\"-inf\"".into()
            }
        })
        .collect();
    format!("[{}]", items.join(","))
}

/// Reads the `metadata_props` of the ONNX file at `path`.
pub fn read_metadata_props(path: &Path) -> Result<BTreeMap<String, String>, ExportError> {
    let bytes = std::fs::read(path).map_err(|source| ExportError::Io {
        path: path.into(),
        source,
    })?;
    metadata_props_from_bytes(&bytes, path)
}

/// Decodes ONNX bytes and returns their `metadata_props`; `path` only names the source in errors.
pub fn metadata_props_from_bytes(
    bytes: &[u8],
    path: &Path,
) -> Result<BTreeMap<String, String>, ExportError> {
    let model = ModelProto::decode(bytes).map_err(|e| ExportError::NotOnnx {
        path: path.into(),
        reason: e.to_string(),
    })?;
    Ok(model
        .metadata_props
        .into_iter()
        .map(|p| (p.key, p.value))
        .collect())
}

/// Rebuilds the [`PolicyMeta`] recorded by [`metadata_props`]; `path` only names the source in errors.
pub fn policy_meta_from_props(
    props: &BTreeMap<String, String>,
    path: &Path,
) -> Result<PolicyMeta, ExportError> {
    let err = |key: &str, expected: &str| ExportError::Metadata {
        path: path.into(),
        key: key.into(),
        expected: expected.into(),
    };
    let text = |key: &str| props.get(key).cloned().ok_or_else(|| err(key, "a string"));
    let strings = |key: &str| -> Result<Vec<String>, ExportError> {
        serde_json::from_str(&text(key)?).map_err(|_| err(key, "a JSON array of strings"))
    };
    let bounds = |key: &str| -> Result<Vec<f32>, ExportError> {
        let expected = "a JSON array of numbers or \"inf\"/\"-inf\"/\"nan\"";
        let items: Vec<serde_json::Value> =
            serde_json::from_str(&text(key)?).map_err(|_| err(key, expected))?;
        items
            .iter()
            .map(|item| match item {
                serde_json::Value::Number(n) => n.as_f64().map(|v| v as f32),
                serde_json::Value::String(s) => match s.as_str() {
                    "inf" => Some(f32::INFINITY),
                    "-inf" => Some(f32::NEG_INFINITY),
                    "nan" => Some(f32::NAN),
                    _ => None,
                },
                _ => None,
            })
            .collect::<Option<Vec<f32>>>()
            .ok_or_else(|| err(key, expected))
    };
    Ok(PolicyMeta {
        env_id: text("env_id")?,
        obs_names: strings("obs_names")?,
        obs_units: strings("obs_units")?,
        obs_low: bounds("obs_low")?,
        obs_high: bounds("obs_high")?,
        action_names: strings("action_names")?,
        action_units: strings("action_units")?,
        action_low: bounds("action_low")?,
        action_high: bounds("action_high")?,
        rlpkg_version: text("rlpkg_version")?,
        config_hash: text("config_hash")?,
    })
}

/// Accumulates nodes and initializers with unique names.
#[derive(Default)]
struct GraphBuilder {
    nodes: Vec<NodeProto>,
    initializers: Vec<TensorProto>,
}

impl GraphBuilder {
    /// Adds an f32 initializer and returns its name.
    fn constant(&mut self, name: &str, dims: &[i64], data: &[f32]) -> String {
        self.initializers.push(TensorProto {
            name: name.into(),
            dims: dims.to_vec(),
            data_type: DataType::Float as i32,
            float_data: data.to_vec(),
            ..Default::default()
        });
        name.into()
    }

    /// Adds a node with one output and returns the output's name.
    fn node(
        &mut self,
        op: &str,
        inputs: &[&str],
        output: &str,
        attribute: Vec<AttributeProto>,
    ) -> String {
        self.nodes.push(NodeProto {
            name: format!("{output}_{}", op.to_lowercase()),
            op_type: op.into(),
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: vec![output.into()],
            attribute,
            ..Default::default()
        });
        output.into()
    }

    /// Adds Gemm layers (activation after all but the last); the last output is named `output`.
    fn mlp(
        &mut self,
        prefix: &str,
        layers: &[DenseLayer],
        activation: Activation,
        input: &str,
        output: &str,
    ) -> String {
        let mut h = input.to_string();
        for (i, layer) in layers.iter().enumerate() {
            let (d_in, d_out) = (layer.d_in as i64, layer.d_out as i64);
            let w = self.constant(
                &format!("{prefix}_{i}_weight"),
                &[d_in, d_out],
                &layer.weight,
            );
            let bias = self.constant(&format!("{prefix}_{i}_bias"), &[d_out], &layer.bias);
            let last = i + 1 == layers.len();
            let linear = if last {
                output.to_string()
            } else {
                format!("{prefix}_{i}_linear")
            };
            h = self.node("Gemm", &[&h, &w, &bias], &linear, vec![]);
            if !last {
                let (op, attrs) = match activation {
                    Activation::Tanh => ("Tanh", vec![]),
                    Activation::Relu => ("Relu", vec![]),
                    Activation::Elu => ("Elu", vec![attr_float("alpha", 1.0)]),
                };
                h = self.node(
                    op,
                    &[&h],
                    &format!("{prefix}_{i}_{}", op.to_lowercase()),
                    attrs,
                );
            }
        }
        h
    }
}

fn attr_int(name: &str, value: i64) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        r#type: AttributeType::Int as i32,
        i: value,
        ..Default::default()
    }
}

fn attr_float(name: &str, value: f32) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        r#type: AttributeType::Float as i32,
        f: value,
        ..Default::default()
    }
}

/// A `[batch, width]` tensor type with a symbolic batch dimension.
fn value_info(name: &str, elem: DataType, width: i64) -> ValueInfoProto {
    use tensor_shape_proto::{dimension::Value, Dimension};
    let dim = |value| Dimension {
        value: Some(value),
        ..Default::default()
    };
    ValueInfoProto {
        name: name.into(),
        r#type: Some(TypeProto {
            value: Some(type_proto::Value::TensorType(type_proto::Tensor {
                elem_type: elem as i32,
                shape: Some(TensorShapeProto {
                    dim: vec![
                        dim(Value::DimParam(BATCH_DIM.into())),
                        dim(Value::DimValue(width)),
                    ],
                }),
            })),
            ..Default::default()
        }),
        ..Default::default()
    }
}
