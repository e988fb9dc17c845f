"""Steps per second of rlpkg's environments stepped from Python, against the same stepping in
Rust alone, in one process and alternating round by round (the machine's load hits both).

    python python/benchmarks/step_rate.py                      # Transport-v0 x 16, CartPole-v1 x 4096
    python python/benchmarks/step_rate.py --rounds 5 --transport-steps 400

The Python loop is what a learner's rollout pays: ``VectorEnv.step`` with a NumPy action array,
its checks, the copy of every output into fresh arrays and the info dict. The Rust reference
(``rlpkg._native.rust_step_seconds``) steps the same environment with the same actions and no
Python in between. Both use next-step autoreset and the same thread count.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import rlpkg
from rlpkg import _native


def python_seconds(env_id, num_envs, steps, seed, action, config, threads):
    venv = rlpkg.make_vec(env_id, num_envs, config=config, num_threads=threads)
    venv.reset(seed=seed)
    actions = np.repeat(np.asarray(action)[None, ...], num_envs, axis=0)
    if venv.rlpkg_spec.get("action_n") is not None:
        actions = actions.astype(np.int64).reshape(num_envs)
    else:
        actions = actions.astype(np.float32)
    start = time.perf_counter()
    for _ in range(steps):
        venv.step(actions)
    elapsed = time.perf_counter() - start
    venv.close()
    return elapsed


def measure(env_id, num_envs, steps, rounds, config, threads):
    spec = _native.VecEnvCore(env_id, 1, config, "next_step", 1).spec()
    if spec.get("action_n") is not None:
        action = [0.0]
    else:
        low, high = np.asarray(spec["action_low"]), np.asarray(spec["action_high"])
        action = list(0.5 * (low + high))
    rust, python = [], []
    for r in range(rounds):
        rust.append(
            _native.rust_step_seconds(
                env_id, num_envs, steps, r, action, config=config, num_threads=threads
            )
        )
        python.append(python_seconds(env_id, num_envs, steps, r, action, config, threads))
    rate = lambda seconds: num_envs * steps / statistics.median(seconds)  # noqa: E731
    ratio = statistics.median(r / p for r, p in zip(rust, python))
    print(
        f"{env_id:13} x {num_envs:5}: Rust {rate(rust):12,.0f} steps/s, Python {rate(python):12,.0f} "
        f"steps/s, Python/Rust {ratio:.3f} (median of {rounds} rounds of {steps} steps, {threads} threads)"
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--transport-envs", type=int, default=16)
    parser.add_argument("--transport-steps", type=int, default=200)
    parser.add_argument("--cartpole-envs", type=int, default=4096)
    parser.add_argument("--cartpole-steps", type=int, default=2000)
    parser.add_argument("--config", default=None, help="Transport-v0 configuration (default: the repository's)")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    config = str(args.config or rlpkg.default_transport_config())
    measure("Transport-v0", args.transport_envs, args.transport_steps, args.rounds, config, args.threads)
    measure("CartPole-v1", args.cartpole_envs, args.cartpole_steps, args.rounds, None, args.threads)


if __name__ == "__main__":
    main()
