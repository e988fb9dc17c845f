"""Type stubs of ``rlpkg._native``, the Rust core of the package."""

from os import PathLike
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

IDS: list[str]
__version__: str
REPOSITORY: str

class VecEnvCore:
    """One vectorised environment with its own rayon thread pool."""

    def __init__(
        self,
        id: str,
        num_envs: int,
        config: str | PathLike[str] | None = None,
        autoreset_mode: str = "next_step",
        num_threads: int | None = None,
    ) -> None: ...
    def spec(self) -> dict[str, Any]: ...
    def reset(
        self,
        seed: int | None = None,
        seeds: list[int] | None = None,
        mask: npt.NDArray[np.bool_] | None = None,
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32] | None]: ...
    def step(
        self, actions: npt.NDArray[np.float32]
    ) -> tuple[
        npt.NDArray[np.float32],
        npt.NDArray[np.float32] | None,
        npt.NDArray[np.float32],
        npt.NDArray[np.bool_],
        npt.NDArray[np.bool_],
        npt.NDArray[np.float32],
        npt.NDArray[np.float32] | None,
        npt.NDArray[np.float32],
    ]: ...

def rust_rollout_digest(
    id: str,
    num_envs: int,
    steps: int,
    seed: int,
    config: str | PathLike[str] | None = None,
    autoreset_mode: str = "same_step",
    num_threads: int | None = None,
) -> int: ...

def rust_step_seconds(
    id: str,
    num_envs: int,
    steps: int,
    seed: int,
    actions: list[float],
    config: str | PathLike[str] | None = None,
    autoreset_mode: str = "next_step",
    num_threads: int | None = None,
) -> float: ...

class CalibrationObjective:
    """The objective of ``rlpkg calibrate`` for a calibration configuration."""

    def __init__(
        self,
        config: str | PathLike[str],
        trajectories: list[str] | None = None,
        max_seconds: float | None = None,
    ) -> None: ...
    @property
    def names(self) -> list[str]: ...
    @property
    def bounds(self) -> list[tuple[float, float]]: ...
    @property
    def log_scale(self) -> list[bool]: ...
    @property
    def trajectories(self) -> list[str]: ...
    def base_values(self) -> list[float]: ...
    def evaluate(self, batch: list[list[float]]) -> list[dict[str, float]]: ...
    def log_likelihoods(self, batch: list[list[float]], horizon: float | None = None) -> list[dict[str, float]]: ...

def sample_posterior(
    config: str | PathLike[str],
    out_dir: str | PathLike[str] | None = None,
    map_batches: Callable[[str, float | None, list[list[float]]], list[dict[str, float]]] | None = None,
    fresh: bool = False,
) -> dict[str, Any]: ...

class ProfileReference:
    """The reference a profile-rate policy drives on a robot: Transport-v0's motion profile along
    the cell's own path, advanced by each action's clock rate."""

    def __init__(
        self,
        config: str | PathLike[str],
        positions: npt.ArrayLike,
        tilts: npt.ArrayLike,
    ) -> None: ...
    def step(self, action: float) -> tuple[float, float]: ...
    def pose(self, progress_m: float) -> tuple[list[float], float]: ...
    def tilt_offsets(self, action_x: float, action_z: float) -> tuple[float, float]: ...
    def planned(self, t_s: float) -> tuple[float, float]: ...
    @property
    def clock_s(self) -> float: ...
    @property
    def rate(self) -> float: ...
    @property
    def progress_m(self) -> float: ...
    @property
    def path_speed_m_s(self) -> float: ...
    @property
    def length_m(self) -> float: ...
    @property
    def duration_s(self) -> float: ...
    @property
    def interval_s(self) -> float: ...
