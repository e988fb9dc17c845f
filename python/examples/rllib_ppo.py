"""RLlib PPO (new API stack) on rlpkg's environments, its env runners spread over a Ray cluster.

    python python/examples/rllib_ppo.py --iterations 20                        # local Ray
    python python/examples/rllib_ppo.py --address auto --env-runners 8          # a running cluster
    python python/examples/rllib_ppo.py --env Transport-v0 --config configs/train/transport.toml

Each env runner steps ``--envs-per-runner`` copies in one ``rlpkg.make_vec`` (RLlib's
``vector_entry_point`` mode, next-step autoreset); the learner runs in this process.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import ray
from ray.rllib.algorithms.ppo import PPOConfig
from ray.tune.registry import register_env

import rlpkg


def env_creator(env_config):
    """An rlpkg environment from RLlib's env config: ``id``, ``config`` (Transport-v0's file,
    absolute or relative to the worker's folder), ``num_envs`` (given by RLlib for a vector env),
    ``num_threads``. Env runner ``k`` of ``n`` seeds its copies apart from the others'."""
    env_id = env_config["id"]
    kwargs = {"num_threads": env_config.get("num_threads", 1)}
    if env_config.get("config"):
        kwargs["config"] = env_config["config"]
    if "num_envs" in env_config:
        return rlpkg.make_vec(env_id, env_config["num_envs"], seed_stride=env_config["num_envs"], **kwargs)
    return rlpkg.make(env_id, **kwargs)


def register(name: str = "rlpkg") -> str:
    """Registers :func:`env_creator` with Ray Tune under ``name``; returns the name."""
    register_env(name, env_creator)
    return name


def ppo_config(
    env_id: str = "CartPole-v1",
    *,
    config: str | None = None,
    env_runners: int = 2,
    envs_per_runner: int = 8,
    rollout_fragment_length: int = 64,
    minibatch_size: int = 256,
    epochs: int = 6,
    lr: float = 3e-4,
    seed: int = 0,
    sample_timeout_s: float = 900.0,
) -> PPOConfig:
    """PPO on ``env_id`` with ``env_runners`` remote env runners of 1 CPU each."""
    env_config = {"id": env_id}
    if config is not None:
        env_config["config"] = str(Path(config).resolve())
    return (
        PPOConfig()
        .environment(register(), env_config=env_config)
        .env_runners(
            num_env_runners=env_runners,
            num_envs_per_env_runner=envs_per_runner,
            gym_env_vectorize_mode="vector_entry_point",
            num_cpus_per_env_runner=1,
            rollout_fragment_length=rollout_fragment_length,
            # A Transport-v0 runner settles its packages at its first reset (seconds per copy on
            # a loaded machine): RLlib's 60 s default would return an empty sample.
            sample_timeout_s=sample_timeout_s,
        )
        .learners(num_learners=0)
        .training(
            train_batch_size_per_learner=env_runners * envs_per_runner * rollout_fragment_length,
            minibatch_size=minibatch_size,
            num_epochs=epochs,
            lr=lr,
        )
        .debugging(seed=seed)
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="CartPole-v1", choices=["CartPole-v1", "Pendulum-v1", "Transport-v0"])
    parser.add_argument("--config", default=None, help="Transport-v0 configuration file")
    parser.add_argument("--address", default=None, help="Ray cluster address (e.g. auto); default: start one")
    parser.add_argument("--env-runners", type=int, default=2)
    parser.add_argument("--envs-per-runner", type=int, default=8)
    parser.add_argument("--iterations", type=int, default=10)
    args = parser.parse_args()
    ray.init(address=args.address, include_dashboard=False)
    algo = ppo_config(
        args.env, config=args.config, env_runners=args.env_runners, envs_per_runner=args.envs_per_runner
    ).build_algo()
    nodes = algo.env_runner_group.foreach_env_runner(
        lambda runner: ray.get_runtime_context().get_node_id(), local_env_runner=False
    )
    print(f"{len(nodes)} env runners on {len(set(nodes))} node(s)")
    for i in range(args.iterations):
        result = algo.train()
        runners = result["env_runners"]
        print(
            f"iteration {i + 1}: {int(runners['num_env_steps_sampled_lifetime'])} steps, "
            f"episode return mean {runners.get('episode_return_mean', float('nan')):.2f}, "
            f"episode length mean {runners.get('episode_len_mean', float('nan')):.1f}"
        )
    algo.stop()
    ray.shutdown()


if __name__ == "__main__":
    main()
