"""The objective of ``rlpkg calibrate`` from Python, for optimisers other than its own.

    from rlpkg.calibration import Objective
    objective = Objective("configs/calibrate/soft-film.toml", trajectories=["HHHHH"], max_seconds=1.0)
    objective.names, objective.bounds          # from the configuration's [[param]] tables
    objective.evaluate([objective.base_values(), ...])   # [{"loss": ..., "chamfer_m": ..., ...}, ...]

Each ``evaluate`` simulates the whole batch on every trajectory in one batched rollout (without
the GIL) and gives the numbers ``rlpkg calibrate`` logs in ``evaluations.csv`` for the same
parameter vectors.

A configuration with an ``[smc]`` table samples the posterior as ``rlpkg calibrate`` does, with
its batches of candidates evaluated here or, where one machine is not enough, as Ray tasks:

    from rlpkg.calibration import RayMap, sample_posterior
    summary = sample_posterior("configs/calibrate/posterior-real-film.toml", out_dir="runs/p",
                               map_batches=RayMap(chunks=8))

``Objective.log_likelihoods(batch, horizon)`` gives the rows such a sampler logs.
"""

from __future__ import annotations

import contextlib
import math
import numbers
import os
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence

import numpy as np

from rlpkg import _native
from rlpkg._checks import fail, real

__all__ = ["Objective", "RayMap", "sample_posterior"]


def _seconds(name: str, value) -> float | None:
    """A duration argument (``max_seconds``, ``horizon``) checked: None or a finite number of
    seconds > 0."""
    if value is None:
        return None
    return real(name, value, "a number of seconds > 0 (or None)", lambda s: s > 0 and math.isfinite(s))


def _trajectory_ids(trajectories) -> list[str] | None:
    """``trajectories`` checked: None, one id or a non-empty list of ids (strings)."""
    if trajectories is None:
        return None
    if isinstance(trajectories, str):
        return [trajectories]
    expected = "None, a trajectory id or a list of at least one trajectory id (strings)"
    ids = list(trajectories) if isinstance(trajectories, Iterable) else None
    if ids is None or not all(isinstance(t, str) for t in ids):
        raise fail("trajectories", trajectories, expected, TypeError)
    if not ids:
        # As the configuration's `trajectories = []` is refused; None keeps the configuration's.
        raise fail("trajectories", trajectories, expected)
    return ids


class Objective:
    """The calibration objective of the configuration file ``config`` (its relative paths are
    taken from the working folder, as ``rlpkg calibrate`` takes them).

    - ``trajectories``: trajectory ids to replay instead of the configuration's (``--trajectories``);
    - ``max_seconds``: compare only the first seconds of each (``--max-seconds``).
    """

    def __init__(
        self,
        config: str | os.PathLike,
        trajectories: Sequence[str] | None = None,
        max_seconds: float | None = None,
    ):
        self._core = _native.CalibrationObjective(
            os.fspath(config), _trajectory_ids(trajectories), _seconds("max_seconds", max_seconds)
        )
        self.config = os.fspath(config)

    @property
    def names(self) -> list[str]:
        """Parameter names, in the order of a parameter vector."""
        return self._core.names

    @property
    def bounds(self) -> list[tuple[float, float]]:
        """``(lower, upper)`` of each parameter."""
        return self._core.bounds

    @property
    def log_scale(self) -> list[bool]:
        """Whether each parameter is searched on a log scale (``log = true`` in the configuration)."""
        return self._core.log_scale

    @property
    def trajectories(self) -> list[str]:
        """The trajectory ids replayed."""
        return self._core.trajectories

    def base_values(self) -> list[float]:
        """The scene's own values of the parameters."""
        return self._core.base_values()

    def vector(self, params: Mapping[str, float] | Sequence[float], name: str = "params") -> list[float]:
        """A parameter vector from a mapping ``{name: value}`` (every name) or a sequence of
        numbers; ``name``: the argument errors name."""
        if isinstance(params, Mapping):
            missing = [n for n in self.names if n not in params]
            extra = sorted(set(params) - set(self.names))
            if missing or extra:
                raise ValueError(f"{name}: missing {missing}, unknown {extra}; expected exactly {self.names}")
            return [real(f"{name}[{n!r}]", params[n], "a number") for n in self.names]
        if isinstance(params, (str, bytes)) or not isinstance(params, Iterable):
            expected = f"a parameter vector (one number per parameter of {self.names}) or a {{name: value}} mapping"
            raise fail(name, params, expected, TypeError)
        return [real(f"{name}[{k}]", v, "a number") for k, v in enumerate(params)]

    def _batch(self, batch) -> list[list[float]]:
        """``batch`` as parameter vectors: a list (or array) of vectors or mappings."""
        one = isinstance(batch, (str, bytes, Mapping)) or not isinstance(batch, Iterable)
        rows = [] if one else list(batch)
        # A mapping or a flat list of numbers is one vector, not a batch: refused, not guessed.
        if one or (rows and all(isinstance(row, numbers.Real) for row in rows)):
            expected = "a list of parameter vectors or {name: value} mappings (for one, pass [params])"
            raise fail("batch", batch, expected, TypeError)
        return [self.vector(row, f"batch[{i}]") for i, row in enumerate(rows)]

    def evaluate(self, batch) -> list[dict[str, float]]:
        """Evaluates each parameter vector (or ``{name: value}`` mapping) of ``batch``; returns
        one ``{"loss", "chamfer_m", "object_mse_m2"}`` dict per entry. A diverged rollout gives
        a non-finite loss."""
        return self._core.evaluate(self._batch(batch))

    def log_likelihoods(self, batch, horizon: float | None = None) -> list[dict[str, float]]:
        """The rows a sampled posterior of this configuration (its ``[smc]`` and ``[likelihood]``
        tables) logs in ``evaluations.csv`` for the parameter vectors (or mappings) of ``batch``
        on the recordings' first ``horizon`` seconds (``None``: the whole recordings): one
        ``{"log_likelihood", "loss", "chamfer_m", "object_mse_m2", "site_mse_m2", "horizon_s"}``
        dict per entry, ``log_likelihood`` being the log's ``objective`` (``-inf`` when a rollout
        diverged)."""
        return self._core.log_likelihoods(self._batch(batch), _seconds("horizon", horizon))

    def __call__(self, params) -> float:
        """The loss of one parameter vector or mapping."""
        return self.evaluate([params])[0]["loss"]


def sample_posterior(
    config: str | os.PathLike,
    out_dir: str | os.PathLike | None = None,
    map_batches=None,
    fresh: bool = False,
) -> dict:
    """Samples the posterior of the configuration ``config`` (with an ``[smc]`` table; its relative
    paths taken from the working folder) as ``rlpkg calibrate`` does, into ``out_dir`` (default: the
    configuration's ``out_dir``): ``objective.toml``, ``evaluations.csv``, ``search.csv``,
    ``stages.csv``, ``samples.csv``, ``posterior.toml``, ``best.toml``, ``fisher.toml``, the same
    bytes as the command writes. A rerun into the folder resumes its log unless ``fresh``;
    ``rlpkg calibrate <config> --out <out_dir>`` afterwards serves every logged batch again and adds
    the command's ``calibrated.toml``, ``corner.png`` and ``summary.json``.

    Each batch of candidates is simulated here, without the GIL, unless ``map_batches`` is given:
    then ``map_batches(config, horizon, candidates)`` returns the rows of
    ``Objective(config).log_likelihoods(candidates, horizon)`` (e.g. :class:`RayMap`). The polish
    and the Fisher information are a few sequential rollouts and always run here. An error raised by
    ``map_batches`` is the cause of the ``RuntimeError`` that names the batch; rows that do not fit
    the batch (too few, a missing key, a value that is no number) are a ``ValueError`` naming it.

    Returns the summary of ``posterior.toml``: ``parameters`` (per parameter ``name``, ``lower_5``,
    ``median``, ``upper_95``, ``box_share``, ``best``), ``evaluations``, ``stages``,
    ``log_evidence``, ``best_log_likelihood``, ... and ``out_dir``."""
    if map_batches is not None and not callable(map_batches):
        raise TypeError(f"map_batches={map_batches!r}: expected None or a callable (config, horizon, candidates)")
    if not isinstance(fresh, bool):
        raise TypeError(f"fresh={fresh!r}: expected True or False")
    return _native.sample_posterior(
        os.fspath(config), None if out_dir is None else os.fspath(out_dir), map_batches, fresh
    )


@contextlib.contextmanager
def _inside(folder: str | None):
    """Runs the block with ``folder`` (when given) as the working folder."""
    previous = os.getcwd()
    if folder is not None:
        os.chdir(folder)
    try:
        yield
    finally:
        os.chdir(previous)


# One objective per (root, configuration) in each Ray worker process, built by its first chunk.
_WORKER_OBJECTIVES: dict[tuple[str, str], Objective] = {}


def _evaluate_chunk(root: str, config: str, horizon: float | None, candidates):
    """A Ray task: this node's id and the rows of ``candidates``. The configuration's paths are
    taken from ``root`` when this node has that folder, else from the working folder (a cluster
    job's ``working_dir``)."""
    import ray

    key = (root, config)
    if key not in _WORKER_OBJECTIVES:
        with _inside(root if os.path.isdir(root) else None):
            _WORKER_OBJECTIVES[key] = Objective(config)
    rows = _WORKER_OBJECTIVES[key].log_likelihoods(candidates, horizon)
    return ray.get_runtime_context().get_node_id(), rows


class RayMap:
    """``map_batches`` of :func:`sample_posterior` on a Ray cluster (``ray.init`` first): each batch
    is split into ``chunks`` contiguous chunks, each evaluated as one Ray task whose worker builds
    and keeps its own :class:`Objective` of the configuration, and the rows are put back in order.
    A chunk's rows do not depend on the other candidates of its batch, so the files are the same
    as one machine writes.

    - ``root``: the folder the configuration's relative paths are taken from (default: the working
      folder now); a node without it takes them from its working folder;
    - ``options``: ``ray.remote`` options of each task (default ``num_cpus=1`` and the ``"SPREAD"``
      scheduling strategy).

    ``nodes`` counts the chunks each node (its Ray id) evaluated."""

    def __init__(self, chunks: int, root: str | os.PathLike | None = None, **options):
        if isinstance(chunks, bool) or not isinstance(chunks, (int, np.integer)) or chunks < 1:
            raise ValueError(f"chunks={chunks!r}: expected a whole number >= 1")
        self.chunks = int(chunks)
        self.root = os.path.abspath(os.fspath(root) if root is not None else os.getcwd())
        self.options = {"num_cpus": 1, "scheduling_strategy": "SPREAD", **options}
        self.nodes: Counter[str] = Counter()

    def __call__(self, config: str, horizon: float | None, candidates) -> list[dict[str, float]]:
        import ray

        task = ray.remote(_evaluate_chunk).options(**self.options)
        n = len(candidates)
        edges = [n * k // self.chunks for k in range(self.chunks + 1)]
        spans = [(a, b) for a, b in zip(edges, edges[1:]) if b > a]
        refs = [task.remote(self.root, config, horizon, candidates[a:b]) for a, b in spans]
        rows = []
        for k, ((a, b), (node, chunk)) in enumerate(zip(spans, ray.get(refs))):
            if len(chunk) != b - a:
                raise ValueError(
                    f"chunk {k} (candidates {a} to {b - 1}) returned {len(chunk)} rows for {b - a} candidates"
                )
            self.nodes[node] += 1
            rows.extend(chunk)
        return rows
