"""A Ray Tune sweep over ``rlpkg train`` runs: each trial runs the ``rlpkg`` binary on a training
configuration with ``--set`` overrides and reports the run's TensorBoard scalars.

    python python/examples/tune_sweep.py                                       # local Ray
    RLPKG_BIN=/path/to/rlpkg python python/examples/tune_sweep.py --address auto \
        --total-steps 200000 --samples 2

The binary is found by ``rlpkg.runs.find_binary`` (``RLPKG_BIN``, else ``target/release/rlpkg``).
Each trial takes one CPU (the trainer's threads are capped at one with ``RAYON_NUM_THREADS``).
"""

from __future__ import annotations

import argparse
import os
import subprocess
from pathlib import Path

import ray
from ray import tune

import rlpkg
from rlpkg.runs import find_binary, scalars


def train_trial(config):
    """One trial: ``rlpkg train <config["train_config"]> --set ...`` in the trial's folder; reports
    the last ``charts/episodic_return``, the step reached and the node it ran on."""
    run_root = Path(tune.get_context().get_trial_dir()) / "runs"
    overrides = {
        "ppo.learning_rate": config["learning_rate"],
        "run.seed": config["seed"],
        "run.total_steps": config["total_steps"],
    }
    command = [str(config["binary"]), "train", config["train_config"], "--out-dir", str(run_root),
               "--name", "run", "--no-export", "--quiet"]
    for key, value in overrides.items():
        command += ["--set", f"{key}={value}"]
    env = dict(os.environ, RAYON_NUM_THREADS="1")
    done = subprocess.run(command, capture_output=True, text=True, env=env)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed ({done.returncode}): {done.stderr.strip()}")
    series = scalars(run_root / "run")
    # Every update logs its learning rate; episodic returns only when an episode ended.
    step = series["charts/learning_rate"][-1][0]
    episodic_return = series["charts/episodic_return"][-1][1]
    tune.report(
        {
            "episodic_return": episodic_return,
            "step": step,
            "node_id": ray.get_runtime_context().get_node_id(),
        }
    )


def tuner(
    train_config: str,
    *,
    learning_rates=(2.5e-4, 1e-3),
    seeds=(1,),
    total_steps: int = 4096,
    storage_path: str | None = None,
    binary: str | None = None,
) -> tune.Tuner:
    """A grid over ``learning_rates`` x ``seeds``, one CPU per trial."""
    binary = binary or str(find_binary())
    return tune.Tuner(
        tune.with_resources(train_trial, {"cpu": 1}),
        param_space={
            "train_config": str(Path(train_config).resolve()),
            "binary": binary,
            "total_steps": total_steps,
            "learning_rate": tune.grid_search(list(learning_rates)),
            "seed": tune.grid_search(list(seeds)),
        },
        tune_config=tune.TuneConfig(metric="episodic_return", mode="max"),
        run_config=tune.RunConfig(name="rlpkg-sweep", storage_path=storage_path, verbose=0),
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--train-config", default=str(Path(rlpkg._native.REPOSITORY) / "configs/train/cartpole.toml"))
    parser.add_argument("--address", default=None)
    parser.add_argument("--total-steps", type=int, default=20_000)
    parser.add_argument("--learning-rates", type=float, nargs="+", default=[2.5e-4, 1e-3])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1])
    args = parser.parse_args()
    ray.init(address=args.address, include_dashboard=False)
    results = tuner(
        args.train_config, learning_rates=args.learning_rates, seeds=args.seeds, total_steps=args.total_steps
    ).fit()
    for result in results:
        c, m = result.config, result.metrics
        print(f"lr {c['learning_rate']:.2e} seed {c['seed']}: return {m['episodic_return']:.1f} at step {m['step']}")
    best = results.get_best_result()
    print(f"best: lr {best.config['learning_rate']:.2e}, return {best.metrics['episodic_return']:.1f}")
    ray.shutdown()


if __name__ == "__main__":
    main()
