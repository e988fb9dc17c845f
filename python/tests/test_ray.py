"""Ray on a two-node cluster started on this machine (ray.cluster_utils.Cluster, one CPU and
one custom resource per node): RLlib PPO with env runners on both nodes, a Tune sweep of
``rlpkg train`` runs whose trials land on both nodes, and Tune with Optuna's GP sampler over the
calibration objective."""

import math
import os
import sys
from pathlib import Path

import pytest
import ray

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
REPOSITORY = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(EXAMPLES))

# Small Ray processes: no usage reporting or metrics export, a 80 MiB object store per node.
RAY_ENV = {
    "RAY_USAGE_STATS_ENABLED": "0",
    "RAY_enable_metrics_collection": "0",
    "RAY_DEDUP_LOGS": "0",
    "RAY_memory_monitor_refresh_ms": "0",
    "RAY_worker_register_timeout_seconds": "120",
}
OBJECT_STORE_BYTES = 80 * 1024 * 1024


@pytest.fixture(scope="module")
def cluster():
    from ray.cluster_utils import Cluster

    saved = {k: os.environ.get(k) for k in [*RAY_ENV, "PYTHONPATH"]}
    os.environ.update(RAY_ENV)
    # The workers import the examples' modules (the env creator, the trial function).
    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(EXAMPLES), saved["PYTHONPATH"]]))
    node_args = dict(num_cpus=1, object_store_memory=OBJECT_STORE_BYTES, include_dashboard=False)
    c = Cluster(initialize_head=True, head_node_args={**node_args, "resources": {"node_a": 1}})
    c.add_node(**{k: v for k, v in node_args.items() if k != "include_dashboard"}, resources={"node_b": 1})
    c.wait_for_nodes()
    ray.init(address=c.address, include_dashboard=False, log_to_driver=False)
    try:
        yield c
    finally:
        ray.shutdown()
        c.shutdown()
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _node_ids():
    return {n["NodeID"] for n in ray.nodes() if n["Alive"]}


def test_rllib_ppo_env_runners_on_both_nodes(cluster, small_transport):
    import rllib_ppo

    assert len(_node_ids()) == 2
    algo = rllib_ppo.ppo_config(
        "CartPole-v1", env_runners=2, envs_per_runner=4, rollout_fragment_length=64, minibatch_size=128, epochs=2
    ).build_algo()
    try:
        runners = algo.env_runner_group.foreach_env_runner(
            lambda r: (ray.get_runtime_context().get_node_id(), type(r.env.unwrapped).__name__, r.num_envs),
            local_env_runner=False,
        )
        assert {node for node, _, _ in runners} == _node_ids()
        assert all(kind == "RlpkgVectorEnv" and n == 4 for _, kind, n in runners)
        for _ in range(3):
            result = algo.train()
        stats = result["env_runners"]
        assert stats["num_env_steps_sampled_lifetime"] >= 3 * 2 * 4 * 64
        # CartPole-v1 pays 1 per step: an episode's return is its length, at most 500 steps.
        episodes = algo.env_runner_group.foreach_env_runner(
            lambda r: [(len(e), e.get_return(), e.is_done) for e in r.sample(num_episodes=2, explore=True)],
            local_env_runner=False,
        )
        flat = [e for runner in episodes for e in runner]
        assert len(flat) >= 4
        assert all(done and 1 <= length <= 500 and ret == length for length, ret, done in flat), flat
        assert stats["episode_len_mean"] == pytest.approx(stats["episode_return_mean"])
    finally:
        algo.stop()

    algo = rllib_ppo.ppo_config(
        "Transport-v0", config=small_transport, env_runners=2, envs_per_runner=1,
        rollout_fragment_length=32, minibatch_size=32, epochs=1,
    ).build_algo()
    try:
        result = algo.train()
        sampled = result.get("env_runners", {}).get("num_env_steps_sampled_lifetime", 0)
        assert sampled >= 64, sorted(result)
        # 12 s at 20 Hz: no episode is longer than 240 steps.
        lengths = algo.env_runner_group.foreach_env_runner(
            lambda r: [len(e) for e in r.sample(num_episodes=1, explore=True)], local_env_runner=False
        )
        assert all(1 <= n <= 240 for runner in lengths for n in runner), lengths
    finally:
        algo.stop()


def test_tune_sweep_of_rlpkg_train_on_both_nodes(cluster, tmp_path):
    import tune_sweep
    from rlpkg.runs import find_binary

    try:
        binary = find_binary()
    except FileNotFoundError as e:
        pytest.fail(str(e))
    results = tune_sweep.tuner(
        str(REPOSITORY / "configs/train/cartpole.toml"),
        learning_rates=(2.5e-4, 1e-3),
        total_steps=2048,
        storage_path=str(tmp_path),
        binary=str(binary),
    ).fit()
    assert not results.errors, results.errors
    assert len(results) == 2
    assert {r.metrics["node_id"] for r in results} == _node_ids()
    for r in results:
        # 2,048 steps of 4 copies x 128: 4 updates, the last scalar at step 2,048.
        assert r.metrics["step"] == 2048
        assert 8 <= r.metrics["episodic_return"] <= 500


def test_tune_calibration_with_optuna_gp_sampler(cluster, tmp_path, monkeypatch):
    import tune_calibrate
    from rlpkg.calibration import Objective

    monkeypatch.chdir(REPOSITORY)
    config = "python/tests/calibrate-tiny.toml"
    results = tune_calibrate.tuner(config, trials=6, seed=0, startup_trials=3, storage_path=str(tmp_path)).fit()
    assert not results.errors, results.errors
    assert len(results) == 6
    params = [r.config["params"] for r in results]
    losses = [r.metrics["loss"] for r in results]
    assert all(math.isfinite(loss) for loss in losses), losses
    assert len({tuple(p.values()) for p in params}) == 6
    expected = Objective(config).evaluate(params)
    assert losses == [e["loss"] for e in expected]


def test_sampled_posterior_batches_as_ray_tasks_on_both_nodes(cluster, tiny_posterior, tmp_path):
    from rlpkg.calibration import RayMap, sample_posterior

    local = sample_posterior(tiny_posterior, out_dir=tmp_path / "local")
    ray_map = RayMap(chunks=2)
    remote = sample_posterior(tiny_posterior, out_dir=tmp_path / "ray", map_batches=ray_map)
    for name in ["evaluations.csv", "samples.csv", "search.csv", "stages.csv", "posterior.toml", "best.toml", "fisher.toml"]:
        assert (tmp_path / "ray" / name).read_bytes() == (tmp_path / "local" / name).read_bytes(), name
    assert remote["evaluations"] == local["evaluations"]
    with open(tmp_path / "ray" / "evaluations.csv") as f:
        batches = {line.split(",")[0] for line in f.readlines()[1:]}
    # Every batch went out in two chunks, and the chunks ran on both nodes.
    assert sum(ray_map.nodes.values()) == 2 * len(batches)
    assert set(ray_map.nodes) == _node_ids()
