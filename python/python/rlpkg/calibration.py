"""The objective of ``rlpkg calibrate`` from Python, for optimisers other than its own.

    from rlpkg.calibration import Objective
    objective = Objective("configs/calibrate/soft-film.toml", trajectories=["HHHHH"], max_seconds=1.0)
    objective.names, objective.bounds          # from the configuration's [[param]] tables
    objective.evaluate([objective.base_values(), ...])   # [{"loss": ..., "chamfer_m": ..., ...}, ...]

Each ``evaluate`` simulates the whole batch on every trajectory in one batched rollout (without
the GIL) and gives the numbers ``rlpkg calibrate`` logs in ``evaluations.csv`` for the same
parameter vectors.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence

from rlpkg import _native

__all__ = ["Objective"]


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
        if isinstance(trajectories, str):
            trajectories = [trajectories]
        self._core = _native.CalibrationObjective(
            os.fspath(config), None if trajectories is None else list(trajectories), max_seconds
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

    def vector(self, params: Mapping[str, float] | Sequence[float]) -> list[float]:
        """A parameter vector from a mapping ``{name: value}`` (every name) or a sequence."""
        if isinstance(params, Mapping):
            missing = [n for n in self.names if n not in params]
            extra = sorted(set(params) - set(self.names))
            if missing or extra:
                raise ValueError(f"params: missing {missing}, unknown {extra}; expected exactly {self.names}")
            return [float(params[n]) for n in self.names]
        return [float(v) for v in params]

    def evaluate(self, batch) -> list[dict[str, float]]:
        """Evaluates each parameter vector (or ``{name: value}`` mapping) of ``batch``; returns
        one ``{"loss", "chamfer_m", "object_mse_m2"}`` dict per entry. A diverged rollout gives
        a non-finite loss."""
        return self._core.evaluate([self.vector(p) for p in batch])

    def __call__(self, params) -> float:
        """The loss of one parameter vector or mapping."""
        return self.evaluate([params])[0]["loss"]
