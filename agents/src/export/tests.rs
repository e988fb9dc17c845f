//! Export -> tract round trips on random CartPole-, Pendulum- and transport-shaped policies.

use std::path::Path;

use super::check::{check_path, CheckData};
use super::onnx::{
    metadata_props_from_bytes, policy_meta_from_props, read_metadata_props, to_model_proto,
    OPSET_VERSION,
};
use super::random::{cartpole_like, pendulum_like, transport_like};
use super::runtime::{compare_with_reference, measure_latency, random_observations};
use super::*;

const ROWS: usize = 1000;

fn load(graph: &PolicyGraph) -> OnnxPolicy {
    OnnxPolicy::from_bytes(&to_onnx_bytes(graph).unwrap(), Path::new("<memory>")).unwrap()
}

/// When `RLPKG_ONNX_CHECK_DIR` is set (CI does), keeps the model and its check data there for
/// `tests/onnx_check.py`.
fn keep_for_external_check(name: &str, graph: &PolicyGraph, obs: &[f32]) {
    let Some(dir) = std::env::var_os("RLPKG_ONNX_CHECK_DIR") else {
        return;
    };
    let dir = Path::new(&dir);
    std::fs::create_dir_all(dir).unwrap();
    let model = dir.join(format!("{name}.onnx"));
    write_onnx(graph, &model).unwrap();
    CheckData::from_reference(graph, obs, obs.len() / graph.obs_dim(), TOLERANCE)
        .write(&check_path(&model))
        .unwrap();
}

fn assert_matches_reference(name: &str, graph: &PolicyGraph) -> Agreement {
    let policy = load(graph);
    let obs = random_observations(graph, ROWS, 7);
    let agreement = compare_with_reference(graph, &policy, &obs, ROWS).unwrap();
    println!("{name}: {agreement:?}");
    agreement.check(TOLERANCE).unwrap();
    keep_for_external_check(name, graph, &obs);
    agreement
}

#[test]
fn cartpole_policy_matches_reference_in_tract() {
    let graph = cartpole_like(1);
    let agreement = assert_matches_reference("cartpole", &graph);
    assert!(agreement.logits.is_some() && agreement.value.is_some());
    // Both actions occur, so the comparison exercises the argmax and not a constant.
    let actions = graph.act(&random_observations(&graph, ROWS, 7), ROWS);
    assert!(actions.contains(&0.0) && actions.contains(&1.0));
}

#[test]
fn pendulum_policy_matches_reference_in_tract() {
    let graph = pendulum_like(2);
    let agreement = assert_matches_reference("pendulum", &graph);
    assert!(agreement.logits.is_none() && agreement.value.is_some());
}

#[test]
fn tanh_scaled_elu_and_relu_policies_match_reference_in_tract() {
    let transport = transport_like(24, 3, 3);
    assert_matches_reference("transport", &transport);
    let mut relu = pendulum_like(4);
    relu.activation = Activation::Relu;
    relu.normaliser = None;
    assert_matches_reference("pendulum_relu_no_normaliser", &relu);
}

#[test]
fn clipped_actions_hit_the_bounds() {
    let mut graph = pendulum_like(5);
    // Scale the last layer so many means fall outside +-2 and the clip matters.
    graph
        .actor
        .last_mut()
        .unwrap()
        .weight
        .iter_mut()
        .for_each(|w| *w *= 20.0);
    let obs = random_observations(&graph, ROWS, 8);
    let actions = load(&graph).act(&obs, ROWS).unwrap();
    assert!(actions.contains(&2.0) && actions.contains(&-2.0));
    compare_with_reference(&graph, &load(&graph), &obs, ROWS)
        .unwrap()
        .check(TOLERANCE)
        .unwrap();
}

#[test]
fn wrong_normaliser_is_detected() {
    for graph in [cartpole_like(6), pendulum_like(6)] {
        let obs = random_observations(&graph, ROWS, 9);
        let mut shifted = graph.clone();
        shifted.normaliser.as_mut().unwrap().mean[0] += 0.5;
        let mut missing = graph.clone();
        missing.normaliser = None;
        let mut unclipped = graph.clone();
        unclipped.normaliser.as_mut().unwrap().clip = 100.0;
        for (what, wrong) in [
            ("shifted mean", shifted),
            ("missing", missing),
            ("no clip", unclipped),
        ] {
            let agreement = compare_with_reference(&graph, &load(&wrong), &obs, ROWS).unwrap();
            assert!(
                matches!(
                    agreement.check(TOLERANCE),
                    Err(ExportError::Mismatch { .. })
                ),
                "{} normaliser {what} not detected: {agreement:?}",
                graph.meta.env_id
            );
        }
    }
}

#[test]
fn dynamic_batch_gives_the_same_rows() {
    let graph = cartpole_like(10);
    let policy = load(&graph);
    let obs = random_observations(&graph, 37, 11);
    let batch = policy.run(&obs, 37).unwrap();
    assert_eq!(batch.action.len(), 37);
    assert_eq!(batch.logits.as_ref().unwrap().len(), 74);
    for row in [0, 17, 36] {
        let single = policy.run(&obs[row * 4..][..4], 1).unwrap();
        assert_eq!(single.action[0], batch.action[row]);
        let (diff, _) = runtime::max_abs_diff(
            single.logits.as_ref().unwrap(),
            &batch.logits.as_ref().unwrap()[row * 2..][..2],
            2,
        );
        assert!(diff <= TOLERANCE);
    }
    assert!(matches!(
        policy.run(&obs[..5], 1),
        Err(ExportError::ObsShape { .. })
    ));
}

#[test]
fn model_declares_opset_symbolic_batch_and_outputs() {
    use tract_onnx::pb::{tensor_shape_proto::dimension::Value, type_proto};
    let model = to_model_proto(&cartpole_like(12)).unwrap();
    assert_eq!(model.opset_import[0].version, OPSET_VERSION);
    const { assert!(OPSET_VERSION >= 17) };
    let graph = model.graph.unwrap();
    let names: Vec<_> = graph.output.iter().map(|o| o.name.as_str()).collect();
    assert_eq!(names, ["action", "logits", "value"]);
    assert_eq!(graph.input[0].name, "obs");
    let Some(type_proto::Value::TensorType(t)) = &graph.input[0].r#type.as_ref().unwrap().value
    else {
        panic!("obs is not a tensor")
    };
    let dims = &t.shape.as_ref().unwrap().dim;
    assert_eq!(dims[0].value, Some(Value::DimParam("batch".into())));
    assert_eq!(dims[1].value, Some(Value::DimValue(4)));
    let ops: Vec<_> = graph.node.iter().map(|n| n.op_type.as_str()).collect();
    assert_eq!(
        &ops[..3],
        ["Sub", "Div", "Clip"],
        "normaliser must come first"
    );
    assert!(ops.contains(&"ArgMax"));
}

#[test]
fn metadata_round_trips_through_the_file() {
    let graph = cartpole_like(13);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("policy.onnx");
    let size = write_onnx(&graph, &path).unwrap();
    assert_eq!(size, std::fs::metadata(&path).unwrap().len());
    let props = read_metadata_props(&path).unwrap();
    assert_eq!(props["env_id"], "CartPole-v1");
    assert_eq!(props["obs_high"], r#"[4.8,"inf",0.418879,"inf"]"#);
    assert_eq!(policy_meta_from_props(&props, &path).unwrap(), graph.meta);
    assert_eq!(OnnxPolicy::load(&path).unwrap().metadata(), &props);
    // Only the model is left in the folder: the temporary file was renamed.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);

    let mut broken = props.clone();
    broken.insert("obs_low".into(), "[1, \"minus infinity\"]".into());
    let err = policy_meta_from_props(&broken, &path).unwrap_err();
    assert!(err.to_string().contains("obs_low"), "{err}");
}

#[test]
fn check_data_round_trips() {
    let graph = pendulum_like(14);
    let obs = random_observations(&graph, 20, 15);
    let data = CheckData::from_reference(&graph, &obs, 20, TOLERANCE);
    let dir = tempfile::tempdir().unwrap();
    let path = check_path(&dir.path().join("p.onnx"));
    assert!(path.ends_with("p.check.json"));
    data.write(&path).unwrap();
    assert_eq!(CheckData::read(&path).unwrap(), data);
}

#[test]
fn bad_inputs_give_typed_errors() {
    let not_onnx = OnnxPolicy::from_bytes(b"\x08\x07garbage", Path::new("x.onnx"));
    assert!(matches!(not_onnx, Err(ExportError::NotOnnx { .. })));
    let missing = OnnxPolicy::load(Path::new("/nonexistent/policy.onnx"));
    assert!(matches!(missing, Err(ExportError::Io { .. })));
    assert!(metadata_props_from_bytes(b"\xff\xff", Path::new("y.onnx")).is_err());
    let mut invalid = pendulum_like(16);
    invalid.actor[1].bias.pop();
    assert!(matches!(
        to_onnx_bytes(&invalid),
        Err(ExportError::InvalidGraph(_))
    ));
}

#[test]
fn latency_is_measured() {
    let graph = pendulum_like(17);
    let policy = load(&graph);
    let obs = random_observations(&graph, 10, 18);
    let latency = measure_latency(&policy, &obs, 50).unwrap();
    println!("tract single-observation latency: {latency:?}");
    assert_eq!(latency.runs, 50);
    assert!(latency.median_us > 0.0 && latency.median_us <= latency.p90_us);
}

#[test]
fn episodes_with_the_onnx_policy_match_the_reference() {
    let graph = cartpole_like(19);
    let policy = load(&graph);
    let mut env = rlpkg_vec_env::CartPole::new(6);
    let onnx = runtime::run_episodes(&mut env, 3, usize::MAX, |obs, n| policy.act(obs, n)).unwrap();
    let reference = runtime::run_episodes(&mut env, 3, usize::MAX, |obs, n| {
        Ok::<_, ExportError>(graph.act(obs, n))
    })
    .unwrap();
    assert_eq!(onnx, reference);
    assert_eq!(onnx.returns.len(), 6);
    assert_eq!(
        onnx.visited_obs.len(),
        onnx.lengths.iter().sum::<usize>() * 4
    );
    // CartPole pays 1 per step.
    assert!(onnx
        .returns
        .iter()
        .zip(&onnx.lengths)
        .all(|(r, l)| *r == *l as f32));
    // The visited observations are where deployment happens: compare there too.
    let rows = onnx.visited_obs.len() / 4;
    compare_with_reference(&graph, &policy, &onnx.visited_obs, rows)
        .unwrap()
        .check(TOLERANCE)
        .unwrap();
}

/// A trainer after one PPO update (trained weights and normaliser statistics) on `env`.
fn trained(env: &str, transform: &str) -> crate::runners::TrainedPolicy {
    let text = crate::config::tests::CARTPOLE_TEST
        .replace("CartPole-v1", env)
        .replace("\"clip\"", &format!("\"{transform}\""));
    let config = crate::TrainConfig::parse(&text, Path::new("test.toml")).unwrap();
    let env = crate::config::tests::classic_env(env, config.run.num_envs);
    let mut trainer = crate::Trainer::new(config, text, env).unwrap();
    trainer.run_update().unwrap();
    crate::runners::TrainedPolicy::from_trainer(&trainer)
}

#[test]
fn burn_policy_matches_tract_on_random_and_visited_observations() {
    for (env, transform) in [
        ("CartPole-v1", "clip"),
        ("Pendulum-v1", "clip"),
        ("Pendulum-v1", "tanh_scale"),
    ] {
        let burn = trained(env, transform);
        let graph = burn.policy_graph();
        assert!(
            graph.normaliser.is_some(),
            "the test config normalises observations"
        );
        let onnx = load(&graph);
        let random = random_observations(&graph, ROWS, 21);
        let mut episodes = crate::config::tests::classic_env(env, 100);
        let visited = runtime::run_episodes(episodes.as_mut(), 22, usize::MAX, |obs, n| {
            Ok::<_, ExportError>(burn.act(obs, n))
        })
        .unwrap()
        .visited_obs;
        let dim = graph.obs_dim();
        assert!(
            visited.len() >= ROWS * dim,
            "{env}: only {} visited rows",
            visited.len() / dim
        );
        for (what, obs) in [("random", &random[..]), ("visited", &visited[..ROWS * dim])] {
            let burn_actions = burn.act(obs, ROWS);
            let tract_actions = onnx.act(obs, ROWS).unwrap();
            let (diff, row) =
                runtime::max_abs_diff(&burn_actions, &tract_actions, graph.action_dim());
            println!("{env} {transform} {what}: max abs diff burn vs tract {diff:e}");
            assert!(
                diff <= TOLERANCE,
                "{env} {what}: burn vs tract {diff} at row {row}"
            );
            compare_with_reference(&graph, &onnx, obs, ROWS)
                .unwrap()
                .check(TOLERANCE)
                .unwrap();
        }
        if env == "Pendulum-v1" && transform == "clip" {
            // onnxruntime is then compared with burn's own actions.
            let name = "pendulum_burn";
            keep_for_external_check(name, &graph, &visited[..ROWS * dim]);
            if let Some(dir) = std::env::var_os("RLPKG_ONNX_CHECK_DIR") {
                let path = check_path(&Path::new(&dir).join(format!("{name}.onnx")));
                let mut data = CheckData::read(&path).unwrap();
                data.action = burn.act(&data.obs, data.rows);
                data.write(&path).unwrap();
            }
        }
    }
}

#[test]
fn scaled_differences_are_relative_above_one() {
    use runtime::{max_abs_diff, max_scaled_diff};
    assert_eq!(max_scaled_diff(&[0.5, 301.0], &[0.25, 300.0], 1), (0.25, 0));
    assert_eq!(max_scaled_diff(&[0.0, 303.0], &[0.0, 300.0], 1), (0.01, 1));
    assert_eq!(max_abs_diff(&[0.0, 303.0], &[0.0, 300.0], 2), (3.0, 0));
    assert_eq!(max_abs_diff(&[f32::NAN], &[1.0], 1).0, f32::INFINITY);
    assert_eq!(max_scaled_diff(&[1.0], &[1.0, 2.0], 1).0, f32::INFINITY);
}
