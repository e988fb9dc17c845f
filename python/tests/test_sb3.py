"""Stable-Baselines3 PPO on rlpkg's environments (python/examples/sb3_ppo.py)."""

import math
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
import sb3_ppo  # noqa: E402


def test_ppo_solves_cartpole_within_50k_steps():
    _, curve, episodes = sb3_ppo.train("CartPole-v1", 50_000, seed=0, stop_at=195.0, verbose=False)
    print("steps, mean return of the last 100 episodes:", curve)
    assert curve[-1][1] >= 195.0, curve
    assert curve[-1][0] <= 50_000
    # CartPole-v1's episodes last at most 500 steps and pay 1 per step.
    assert all(r == l and 1 <= l <= 500 for r, l in episodes)


def test_ppo_on_transport_finishes_episodes_without_nan(small_transport):
    # One rollout of 4 copies x 64 steps (Transport-v0 steps at ~10 copies x steps/s here) and
    # its update.
    model, curve, episodes = sb3_ppo.train(
        "Transport-v0", 256, seed=0, num_envs=4, n_steps=64, config=small_transport, verbose=False
    )
    assert model.num_timesteps == 256
    assert episodes, "no episode finished"
    assert all(math.isfinite(r) and l >= 1 for r, l in episodes)
    assert all(torch.isfinite(p).all() for p in model.policy.parameters())
    obs = np.zeros((1, *model.observation_space.shape), dtype=np.float32)
    action, _ = model.predict(obs, deterministic=True)
    assert np.isfinite(action).all()
