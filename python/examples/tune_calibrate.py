"""Calibration with Ray Tune and Optuna's Gaussian-process sampler over ``rlpkg.calibration.Objective``
(the objective of ``rlpkg calibrate``): one trial per parameter vector.

    python python/examples/tune_calibrate.py configs/calibrate/soft-film.toml --trials 30
    python python/examples/tune_calibrate.py python/tests/calibrate-tiny.toml --trials 6

Relative paths in the configuration are taken from ``--root`` (default: the working folder), so
run it from the repository root, or on a cluster with the repository as the job's
``working_dir`` and ``RAY_CHDIR_TO_TRIAL_DIR=0`` (set here for the trials). Trials run one at a
time so that the sampler sees every result before proposing the next vector.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
from pathlib import Path

import ray
from ray import tune
from ray.tune.search.optuna import OptunaSearch

from rlpkg.calibration import Objective


def evaluate_trial(config):
    """One trial: the loss of ``config["params"]`` (a dict name -> value). The configuration's
    paths are taken from ``config["root"]`` when this node has that folder, else from the working
    folder (a cluster job's ``working_dir``)."""
    if config.get("root") and os.path.isdir(config["root"]):
        os.chdir(config["root"])
    objective = Objective(config["config"], config.get("trajectories"), config.get("max_seconds"))
    result = objective.evaluate([config["params"]])[0]
    finite = math.isfinite(result["loss"])
    # A diverged rollout gives a non-finite loss: report a large finite one so the sampler moves on.
    tune.report({**result, "objective": result["loss"] if finite else 1e30, "diverged": not finite})


@contextlib.contextmanager
def inside(folder: str):
    """Runs the block with ``folder`` as the working folder."""
    previous = os.getcwd()
    os.chdir(folder)
    try:
        yield
    finally:
        os.chdir(previous)


def search_space(objective: Objective) -> dict:
    """Tune's space from the configuration's [[param]] bounds and scales."""
    return {
        name: (tune.loguniform if log else tune.uniform)(low, high)
        for name, (low, high), log in zip(objective.names, objective.bounds, objective.log_scale)
    }


def tuner(
    config: str,
    *,
    trials: int = 6,
    seed: int = 0,
    startup_trials: int = 10,
    trajectories=None,
    max_seconds: float | None = None,
    root: str | None = None,
    storage_path: str | None = None,
) -> tune.Tuner:
    """Tune over the objective of ``config`` with ``OptunaSearch(GPSampler(seed))``; the sampler
    draws ``startup_trials`` vectors at random before fitting its Gaussian process."""
    import optuna

    root = str(Path(root or os.getcwd()).resolve())
    with inside(root):
        objective = Objective(config, trajectories, max_seconds)
    space = {
        "params": search_space(objective),
        "config": str(config),
        "root": root,
        "trajectories": list(objective.trajectories),
        "max_seconds": max_seconds,
    }
    searcher = OptunaSearch(sampler=optuna.samplers.GPSampler(seed=seed, n_startup_trials=startup_trials), metric="objective", mode="min")
    return tune.Tuner(
        tune.with_resources(evaluate_trial, {"cpu": 1}),
        param_space=space,
        tune_config=tune.TuneConfig(search_alg=searcher, num_samples=trials, max_concurrent_trials=1),
        run_config=tune.RunConfig(name="rlpkg-calibrate", storage_path=storage_path, verbose=0),
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("config", help="calibration configuration (TOML), as for rlpkg calibrate")
    parser.add_argument("--trials", type=int, default=6)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--startup-trials", type=int, default=10, help="random trials before the GP")
    parser.add_argument("--trajectories", nargs="+", default=None)
    parser.add_argument("--max-seconds", type=float, default=None)
    parser.add_argument("--root", default=None, help="folder the configuration's paths are relative to")
    parser.add_argument("--address", default=None)
    args = parser.parse_args()
    ray.init(
        address=args.address,
        include_dashboard=False,
        runtime_env={"env_vars": {"RAY_CHDIR_TO_TRIAL_DIR": "0"}},
    )
    results = tuner(
        args.config, trials=args.trials, seed=args.seed, startup_trials=args.startup_trials, trajectories=args.trajectories,
        max_seconds=args.max_seconds, root=args.root,
    ).fit()
    for r in results:
        params = ", ".join(f"{k} {v:.4g}" for k, v in r.config["params"].items())
        print(f"{params}: loss {r.metrics['loss']:.6g}")
    best = results.get_best_result(metric="objective", mode="min")
    print("best:", best.config["params"], "loss", best.metrics["loss"])
    ray.shutdown()


if __name__ == "__main__":
    main()
