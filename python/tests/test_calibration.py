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


SECONDS = r"max_seconds: expected a number of seconds > 0 \(or None\), "


@pytest.mark.parametrize(
    "kwargs, error, message",
    [
        # As the file's `trajectories = []` is refused: None keeps the file's ids.
        ({"trajectories": []}, ValueError, r"trajectories: expected .* at least one trajectory id .*, got \[\]"),
        ({"trajectories": [1]}, TypeError, r"trajectories: expected .* \(strings\), got \[1\] \(a list\)"),
        ({"max_seconds": "1"}, TypeError, SECONDS + r"got '1' \(a str\)"),
        ({"max_seconds": True}, TypeError, SECONDS + r"got True \(a bool\)"),
        ({"max_seconds": float("inf")}, ValueError, SECONDS + "got inf"),
    ],
)
def test_objective_arguments_are_refused_by_name(in_repository, kwargs, error, message):
    with pytest.raises(error, match=message):
        Objective(TINY, **kwargs)


@pytest.fixture(scope="module")
def tiny_objective():
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(REPOSITORY)
        return Objective(TINY, max_seconds=0.2)


BATCH = r"batch: expected a list of parameter vectors or \{name: value\} mappings \(for one, pass \[params\]\), "


@pytest.mark.parametrize(
    "call, error, message",
    [
        (lambda o: o.evaluate([1e4, 1e-3]), TypeError, BATCH + r"got \[10000.0, 0.001\] \(a list\)"),
        (lambda o: o.evaluate({"k_tri_e": 1e4, "k_tri_d": 1e-3}), TypeError, BATCH + r"got \{'k_tri_e'"),
        (lambda o: o.evaluate(None), TypeError, BATCH + r"got None"),
        (lambda o: o.evaluate([["a", "b"]]), TypeError, r"batch\[0\]\[0\]: expected a number, got 'a' \(a str\)"),
        (
            lambda o: o.evaluate([{"k_tri_e": 1e4, "k_tri_d": None}]),
            TypeError,
            r"batch\[0\]\['k_tri_d'\]: expected a number, got None",
        ),
        (lambda o: o.evaluate([5.0, [1e4, 1e-3]]), TypeError, r"batch\[0\]: expected a parameter vector .*, got 5.0"),
        (lambda o: o.log_likelihoods([o.base_values()], horizon="1"), TypeError, r"horizon: .*, got '1' \(a str\)"),
        (lambda o: o.log_likelihoods([o.base_values()], horizon=-1.0), ValueError, r"horizon: expected .*, got -1.0"),
    ],
)
def test_batches_and_horizons_are_refused_by_name(tiny_objective, call, error, message):
    with pytest.raises(error, match=message):
        call(tiny_objective)


# The files a sampled posterior writes, besides the command's calibrated.toml, corner.png and summary.json.
POSTERIOR_FILES = [
    "objective.toml", "evaluations.csv", "search.csv", "stages.csv", "samples.csv", "posterior.toml", "best.toml",
    "fisher.toml",
]


def logged_batches(out_dir):
    """The evaluation log's rows by batch."""
    with open(out_dir / "evaluations.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    batches = {}
    for row in rows:
        batches.setdefault(int(row["batch"]), []).append(row)
    return [batches[b] for b in sorted(batches)]


def test_sampled_posterior_equals_the_command(tiny_posterior, tmp_path):
    from rlpkg.calibration import sample_posterior

    try:
        binary = find_binary()
    except FileNotFoundError as e:
        pytest.fail(str(e))
    command = tmp_path / "command"
    done = subprocess.run(
        [str(binary), "calibrate", str(tiny_posterior), "--out", str(command), "--fresh"], capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    summary = sample_posterior(tiny_posterior, out_dir=tmp_path / "python")
    for name in POSTERIOR_FILES:
        assert (tmp_path / "python" / name).read_bytes() == (command / name).read_bytes(), name
    assert summary["out_dir"] == str(tmp_path / "python")
    assert [p["name"] for p in summary["parameters"]] == ["k_tri_e", "k_tri_d"]
    batches = logged_batches(command)
    assert summary["evaluations"] == sum(len(b) for b in batches)
    # The growing-horizon search's first generation scores the first 0.025 s, the sampler the whole 0.05 s.
    objective = Objective(tiny_posterior)
    for batch, horizon in [(batches[0], 0.025), (batches[-1], None)]:
        assert {row["horizon_s"] for row in batch} == {str(horizon or 0.05)}
        vectors = [[float(row[name]) for name in objective.names] for row in batch]
        for row, result in zip(batch, objective.log_likelihoods(vectors, horizon)):
            assert float(row["objective"]) == result["log_likelihood"], (row, result)
            for metric in ["loss", "chamfer_m", "object_mse_m2", "site_mse_m2", "horizon_s"]:
                assert float(row[metric]) == result[metric], (metric, row, result)


def test_sampled_posterior_errors_name_the_batch(in_repository, tiny_posterior, tmp_path):
    from rlpkg.calibration import sample_posterior

    row = {"log_likelihood": 0.0, "loss": 0.0, "chamfer_m": 0.0, "object_mse_m2": 0.0, "site_mse_m2": 0.0}

    def short(config, horizon, candidates):
        return [{**row, "horizon_s": horizon}] * (len(candidates) - 1)

    with pytest.raises(ValueError, match="batch 0: 3 rows for 4 candidates"):
        sample_posterior(tiny_posterior, out_dir=tmp_path / "short", map_batches=short)

    def failing(config, horizon, candidates):
        raise ZeroDivisionError("no workers")

    with pytest.raises(RuntimeError, match="batch 0: map_batches: ZeroDivisionError: no workers") as raised:
        sample_posterior(tiny_posterior, out_dir=tmp_path / "failing", map_batches=failing)
    assert isinstance(raised.value.__cause__, ZeroDivisionError)

    def no_site(config, horizon, candidates):
        return [{k: v for k, v in row.items() if k != "site_mse_m2"}] * len(candidates)

    # Rows that do not fit the batch are a ValueError naming the key, as the docs say.
    with pytest.raises(ValueError, match="batch 0: map_batches: row 0: no site_mse_m2 key"):
        sample_posterior(tiny_posterior, out_dir=tmp_path / "no-site", map_batches=no_site)
    with pytest.raises(ValueError, match="row 0: no log_likelihood key"):
        sample_posterior(tiny_posterior, out_dir=tmp_path / "no-ll", map_batches=lambda c, h, x: [{}] * len(x))
    with pytest.raises(ValueError, match=r"map_batches: returned None \(a NoneType\), not a list of rows"):
        sample_posterior(tiny_posterior, out_dir=tmp_path / "none", map_batches=lambda c, h, x: None)
    with pytest.raises(ValueError, match=r"no \[smc\] table"):
        sample_posterior(TINY, out_dir=tmp_path / "optimiser")
    with pytest.raises(TypeError, match="map_batches=5"):
        sample_posterior(tiny_posterior, out_dir=tmp_path / "not-callable", map_batches=5)
    with pytest.raises(TypeError, match="fresh='yes'"):
        sample_posterior(tiny_posterior, out_dir=tmp_path / "not-bool", fresh="yes")
    assert not (tmp_path / "not-callable").exists() and not (tmp_path / "not-bool").exists()
    # A folder holding another objective's evaluations is not resumed.
    other = tmp_path / "short" / "objective.toml"
    other.write_text(other.read_text().replace("seed = 3", "seed = 4"))
    with pytest.raises(ValueError, match="objective.toml line"):
        sample_posterior(tiny_posterior, out_dir=tmp_path / "short")
    # A config in the output folder under a name the calibration writes is never written over,
    # with or without `fresh`.
    inside = tmp_path / "inside"
    inside.mkdir()
    for name in ("posterior.toml", "objective.toml"):
        config = inside / name
        config.write_text(tiny_posterior.read_text())
        for fresh in (False, True):
            with pytest.raises(ValueError, match=f"which is .*{name}, the calibration config"):
                sample_posterior(config, out_dir=inside, fresh=fresh)
            assert config.read_text() == tiny_posterior.read_text()
        config.unlink()
