"""Short runs of the examples in python/examples."""

import math
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
import cleanrl_ppo  # noqa: E402


def test_cleanrl_ppo_runs_on_pendulum():
    args = cleanrl_ppo.parse_args(
        ["--total-timesteps", "2048", "--num-envs", "4", "--num-steps", "256", "--num-minibatches", "4"]
    )
    agent, episodes = cleanrl_ppo.train(args)
    # Pendulum-v1 is cut at 200 steps: each copy finishes two episodes in 512 steps (200, the
    # autoreset step, 200), and the autoreset step is not counted in a length.
    assert len(episodes) == 8
    assert all(length == 200 and -3000 < ret < 0 for _, ret, length in episodes)
    assert all(torch.isfinite(p).all() for p in agent.parameters())


def test_cleanrl_ppo_runs_on_transport(small_transport):
    args = cleanrl_ppo.parse_args(
        ["--env-id", "Transport-v0", "--config", small_transport, "--total-timesteps", "128",
         "--num-envs", "2", "--num-steps", "64", "--num-minibatches", "2", "--update-epochs", "2"]
    )
    agent, episodes = cleanrl_ppo.train(args)
    assert episodes, "no episode finished"
    assert all(math.isfinite(ret) for _, ret, _ in episodes)
    assert all(torch.isfinite(p).all() for p in agent.parameters())
