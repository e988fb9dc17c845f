"""rlpkg.calibration.Objective: the numbers of `rlpkg calibrate`'s evaluations.csv."""

import csv
import math
import subprocess
from pathlib import Path

import pytest

from rlpkg.calibration import Objective
from rlpkg.runs import find_binary

REPOSITORY = Path(__file__).resolve().parents[2]
TINY = "python/tests/calibrate-tiny.toml"
METRICS = ["loss", "chamfer_m", "object_mse_m2"]


@pytest.fixture
def in_repository(monkeypatch):
    monkeypatch.chdir(REPOSITORY)


def test_objective_equals_the_calibration_log(in_repository, tmp_path):
    try:
        binary = find_binary()
    except FileNotFoundError as e:
        pytest.fail(str(e))
    out = tmp_path / "calibration"
    done = subprocess.run(
        [str(binary), "calibrate", TINY, "--out", str(out), "--fresh"], capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    with open(out / "evaluations.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    objective = Objective(TINY)
    assert objective.names == ["k_tri_e", "k_tri_d"]
    assert objective.bounds == [(1.0e3, 4.0e4), (1.0e-5, 0.1)]
    assert objective.log_scale == [True, True] and objective.trajectories == ["HHHHH"]
    # The scene's own values go first, then a Latin hypercube and one Bayesian batch.
    assert len(rows) == 6
    batch = [[float(row[name]) for name in objective.names] for row in rows]
    assert batch[0] == objective.base_values()
    results = objective.evaluate(batch)
    for row, result in zip(rows, results):
        for metric in METRICS:
            # The log holds the shortest decimal text that parses back to the same f64.
            logged = float(row[metric])
            assert logged == result[metric] or (math.isnan(logged) and math.isnan(result[metric])), (
                metric, row, result
            )
    assert all(math.isfinite(r["loss"]) for r in results)
    # One vector at a time gives the same numbers as the batch.
    assert objective.evaluate([batch[3]])[0] == results[3]
    assert objective({"k_tri_e": batch[1][0], "k_tri_d": batch[1][1]}) == results[1]["loss"]


def test_objective_overrides_and_bad_input(in_repository):
    objective = Objective(TINY, trajectories=["HHHHM"], max_seconds=0.5)
    assert objective.trajectories == ["HHHHM"]
    with pytest.raises(ValueError, match="expected one per parameter"):
        objective.evaluate([[1e4]])
    with pytest.raises(ValueError, match="finite"):
        objective.evaluate([[1e4, float("nan")]])
    with pytest.raises(ValueError, match="missing"):
        objective.evaluate([{"k_tri_e": 1e4}])
    with pytest.raises(ValueError, match="max_seconds"):
        Objective(TINY, max_seconds=-1.0)
    with pytest.raises(ValueError, match="nothere.toml"):
        Objective("nothere.toml")
