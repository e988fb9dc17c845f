"""Stable-Baselines3 PPO on rlpkg's environments through ``rlpkg.sb3.VecEnvAdapter``.

    python python/examples/sb3_ppo.py                                  # CartPole-v1, 50k steps
    python python/examples/sb3_ppo.py --env Transport-v0 --total-timesteps 20000 \
        --config python/tests/transport-small.toml

CartPole-v1 uses RL Baselines3 Zoo's PPO hyperparameters for it (8 copies x 32 steps, 20
epochs, linear schedules); Transport-v0 uses SB3's defaults with ``--n-steps`` steps per copy.
Prints the mean return of the last 100 finished episodes every ``--log-every`` steps.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
import torch

from rlpkg.sb3 import VecEnvAdapter


def linear(start: float):
    """SB3 schedule from ``start`` down to 0 over training."""
    return lambda progress_remaining: progress_remaining * start


def cartpole_hyperparameters() -> dict:
    """RL Baselines3 Zoo's PPO settings for CartPole-v1."""
    return dict(
        n_steps=32,
        batch_size=256,
        gae_lambda=0.8,
        gamma=0.98,
        n_epochs=20,
        ent_coef=0.0,
        learning_rate=linear(1e-3),
        clip_range=linear(0.2),
    )


def train(
    env_id: str = "CartPole-v1",
    total_timesteps: int = 50_000,
    *,
    seed: int = 0,
    num_envs: int | None = None,
    n_steps: int = 256,
    config: str | None = None,
    log_every: int = 4096,
    stop_at: float | None = None,
    num_threads: int = 1,
    verbose: bool = True,
):
    """Trains SB3 PPO on ``env_id``; returns ``(model, curve, episodes)``: ``curve`` holds
    ``(steps, mean return of the last 100 episodes)`` every ``log_every`` steps (and at the end),
    ``episodes`` every finished episode's ``(return, length)``. Training stops early once the
    mean return reaches ``stop_at``."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import VecMonitor

    torch.set_num_threads(num_threads)
    if env_id == "CartPole-v1":
        hyper = cartpole_hyperparameters()
        num_envs = num_envs or 8
    else:
        hyper = dict(n_steps=n_steps, batch_size=min(64, n_steps * (num_envs or 4)))
        num_envs = num_envs or 4
    kwargs = {"config": config} if config is not None else {}
    venv = VecMonitor(VecEnvAdapter(env_id, num_envs, num_threads=num_threads, **kwargs))
    venv.seed(seed)
    curve: list[tuple[int, float]] = []
    episodes: list[tuple[float, int]] = []

    class Curve(BaseCallback):
        def _on_step(self) -> bool:
            for info in self.locals["infos"]:
                if "episode" in info:
                    episodes.append((float(info["episode"]["r"]), int(info["episode"]["l"])))
            if self.num_timesteps % log_every < num_envs and episodes:
                mean = float(np.mean([r for r, _ in episodes[-100:]]))
                curve.append((self.num_timesteps, mean))
                if verbose:
                    print(f"{self.num_timesteps:8d} steps: mean return {mean:8.2f} ({len(episodes)} episodes)")
                if stop_at is not None and mean >= stop_at:
                    return False
            return True

    model = PPO("MlpPolicy", venv, seed=seed, device="cpu", verbose=0, **hyper)
    model.learn(total_timesteps=total_timesteps, callback=Curve())
    if episodes and (not curve or curve[-1][0] != model.num_timesteps):
        curve.append((model.num_timesteps, float(np.mean([r for r, _ in episodes[-100:]]))))
    venv.close()
    return model, curve, episodes


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="CartPole-v1", choices=["CartPole-v1", "Pendulum-v1", "Transport-v0"])
    parser.add_argument("--total-timesteps", type=int, default=50_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--num-envs", type=int, default=None)
    parser.add_argument("--n-steps", type=int, default=256, help="steps per copy per rollout (not CartPole)")
    parser.add_argument("--config", default=None, help="Transport-v0 configuration file")
    parser.add_argument("--log-every", type=int, default=4096)
    parser.add_argument("--threads", type=int, default=1, help="torch and environment threads")
    args = parser.parse_args()
    _, curve, episodes = train(
        args.env,
        args.total_timesteps,
        seed=args.seed,
        num_envs=args.num_envs,
        n_steps=args.n_steps,
        config=args.config,
        log_every=args.log_every,
        num_threads=args.threads,
    )
    returns = [r for r, _ in episodes]
    if returns and all(math.isfinite(r) for r in returns):
        print(f"{len(returns)} episodes, last mean return {curve[-1][1]:.2f}")
    else:
        print(f"{len(returns)} episodes finished; returns finite: {all(math.isfinite(r) for r in returns)}")


if __name__ == "__main__":
    main()
