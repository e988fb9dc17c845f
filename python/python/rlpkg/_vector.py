"""`make_vec`: rlpkg's vectorised environments as a Gymnasium ``VectorEnv``."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium.error import ClosedEnvironmentError
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from rlpkg import _native
from rlpkg._checks import fail, whole
from rlpkg._spaces import single_spaces

TRANSPORT = "Transport-v0"
DEFAULT_TRANSPORT_CONFIG = Path("configs/train/transport.toml")

_MODES = {
    "next_step": AutoresetMode.NEXT_STEP,
    "same_step": AutoresetMode.SAME_STEP,
    "disabled": AutoresetMode.DISABLED,
}


def mode_name(mode: str | AutoresetMode) -> str:
    """The native name of ``mode`` (a name like ``"next_step"`` or Gymnasium's enum)."""
    if isinstance(mode, AutoresetMode):
        return next(name for name, value in _MODES.items() if value == mode)
    # Only a string is looked up: a list is unhashable, and no other type names a mode.
    if isinstance(mode, str) and mode in _MODES:
        return mode
    expected = f"one of {sorted(_MODES)} or a gymnasium.vector.AutoresetMode"
    raise fail("autoreset_mode", mode, expected, ValueError if isinstance(mode, str) else TypeError)


def default_transport_config() -> Path:
    """``configs/train/transport.toml`` of the rlpkg repository: found from the working folder
    (or one of its parents), else in the repository the package was built from."""
    for folder in [Path.cwd(), *Path.cwd().parents]:
        candidate = folder / DEFAULT_TRANSPORT_CONFIG
        if candidate.is_file():
            return candidate
    built_from = Path(_native.REPOSITORY) / DEFAULT_TRANSPORT_CONFIG
    if built_from.is_file():
        return built_from
    raise ValueError(
        f"{TRANSPORT} needs config=<path to a transport TOML file>: no "
        f"{DEFAULT_TRANSPORT_CONFIG} in the working folder, its parents or {_native.REPOSITORY}"
    )


def check_id_and_config(env_id: str, config: str | os.PathLike | None) -> str | None:
    """Checks the id and returns the configuration path the core gets (Transport-v0 only)."""
    if env_id not in _native.IDS:
        raise ValueError(f"unknown environment id {env_id!r}: expected one of {list(_native.IDS)}")
    if config is not None and not isinstance(config, (str, os.PathLike)):
        raise fail("config", config, "a path (str or os.PathLike) to a transport TOML file", TypeError)
    if env_id != TRANSPORT:
        if config is not None:
            raise ValueError(f"config= is for {TRANSPORT}; {env_id} takes no configuration")
        return None
    path = Path(config) if config is not None else default_transport_config()
    if not path.is_file():
        raise ValueError(f"config={str(path)!r}: no such file; expected a transport TOML file")
    return str(path)


def check_actions(actions: Any, space_n: int | None, shape: tuple, low=None, high=None) -> np.ndarray:
    """``actions`` as a flat float32 array for the core, after checking dtype, shape and values.
    ``space_n``: the number of discrete actions (None for a box of ``shape``)."""
    array = np.asarray(actions)
    if space_n is not None:
        if not np.issubdtype(array.dtype, np.integer):
            raise TypeError(
                f"actions: dtype {array.dtype}; expected integer indices in 0..{space_n} (e.g. int64)"
            )
    elif not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise TypeError(f"actions: dtype {array.dtype}; expected real numbers (e.g. float32)")
    if array.shape != shape:
        raise ValueError(f"actions: shape {array.shape}; expected {shape}")
    if space_n is not None:
        bad = np.flatnonzero((array < 0) | (array >= space_n))
        if bad.size:
            i = int(bad[0])
            raise ValueError(f"actions[{i}] = {array.flat[i]}: expected an index in 0..{space_n}")
    else:
        bad = np.flatnonzero(~np.isfinite(array))
        if bad.size:
            i = int(bad[0])
            raise ValueError(f"actions: value {array.flat[i]} at flat index {i}; expected finite numbers")
    return np.ascontiguousarray(array, dtype=np.float32).reshape(-1)


# Seeds are unsigned 64-bit in the environment.
MAX_SEED = 2**64 - 1

# The most copies an environment takes (rlpkg_env::tasks::MAX_ENVS), checked before anything is
# allocated.
MAX_ENVS = 2**20


def check_num_envs(num_envs: Any) -> int:
    """``num_envs`` checked: an integer in [1, MAX_ENVS]."""
    return whole("num_envs", num_envs, f"an integer >= 1 and at most {MAX_ENVS} copies", 1, MAX_ENVS)


# More pool threads than this is a typo, not a machine (each is an OS thread).
MAX_THREADS = 1024


def check_num_threads(num_threads: Any) -> int | None:
    """``num_threads`` checked: None or an integer in [1, MAX_THREADS]."""
    if num_threads is None:
        return None
    if isinstance(num_threads, bool) or not isinstance(num_threads, (int, np.integer)):
        raise TypeError(f"num_threads={num_threads!r}: expected None or an integer in [1, {MAX_THREADS}]")
    if not 1 <= num_threads <= MAX_THREADS:
        raise ValueError(f"num_threads={num_threads}: expected None or an integer in [1, {MAX_THREADS}]")
    return int(num_threads)


def check_render_mode(render_mode) -> None:
    """Refuses a render mode: no rlpkg environment draws frames."""
    if render_mode is not None:
        raise ValueError(
            f"render_mode={render_mode!r}: rlpkg environments have no renderer; expected None "
            "(pictures and animations of evaluated episodes: `rlpkg eval`)"
        )


def check_seeds(seed: Any, num_envs: int, seed_stride: int) -> dict:
    """The core's reset arguments for ``seed``: None, an int (copy i from ``seed * seed_stride +
    i``, all within unsigned 64 bits) or one int per copy."""
    if seed is None:
        return {}
    if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
        if seed < 0:
            raise ValueError(f"seed={seed}: expected an integer >= 0")
        if int(seed) * seed_stride + num_envs - 1 > MAX_SEED:
            raise ValueError(
                f"seed={seed}: copy {num_envs - 1}'s seed (seed x seed_stride {seed_stride} + copy) "
                f"would exceed 2**64 - 1; expected a smaller seed"
            )
        return {"seed": int(seed) * seed_stride}
    if isinstance(seed, (list, tuple, np.ndarray)):
        seeds = list(seed)
        if len(seeds) != num_envs:
            raise ValueError(f"seed: {len(seeds)} seeds; expected one per copy ({num_envs})")
        if not all(isinstance(s, (int, np.integer)) and not isinstance(s, bool) and s >= 0 for s in seeds):
            raise TypeError(f"seed: {seeds!r}; expected integers >= 0 (one per copy)")
        if any(int(s) > MAX_SEED for s in seeds):
            raise ValueError(f"seed: {seeds!r}; expected integers up to 2**64 - 1")
        return {"seeds": [int(s) for s in seeds]}
    raise TypeError(f"seed={seed!r}: expected None, an integer or a list of integers")


def check_options(options: Any, expected: str) -> dict:
    """``reset``'s ``options`` (None or a mapping) as a fresh dict; ``expected`` says what it holds."""
    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise fail("options", options, expected, TypeError)
    return dict(options)


def open_core(env: Any, call: str) -> Any:
    """``env``'s native core; once ``env`` is closed, Gymnasium's ClosedEnvironmentError (what
    its own AsyncVectorEnv raises) for ``call``."""
    if env._core is None:
        raise ClosedEnvironmentError(f"{call} after close: this {type(env).__name__} is closed; make a new one")
    return env._core


class RlpkgVectorEnv(VectorEnv):
    """``num_envs`` copies of an rlpkg environment stepped in Rust (see :func:`make_vec`).

    ``step`` returns fresh float32 arrays (the caller owns them), rewards float32, flags bool;
    the Rust step runs without the GIL on the environment's own thread pool.
    """

    def __init__(
        self,
        env_id: str,
        num_envs: int,
        *,
        config: str | os.PathLike | None = None,
        autoreset_mode: str | AutoresetMode = "next_step",
        obs_mode: str = "actor",
        num_threads: int | None = None,
        seed_stride: int = 1,
    ):
        num_envs = check_num_envs(num_envs)
        seed_stride = whole("seed_stride", seed_stride, "an integer >= 1", 1)
        num_threads = check_num_threads(num_threads)
        mode = mode_name(autoreset_mode)
        path = check_id_and_config(env_id, config)
        self._core = _native.VecEnvCore(env_id, num_envs, path, mode, num_threads)
        self.rlpkg_spec = self._core.spec()
        self.num_envs = num_envs
        self.obs_mode = obs_mode
        self.seed_stride = seed_stride
        self.single_observation_space, self.single_action_space = single_spaces(self.rlpkg_spec, obs_mode)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.metadata = {"autoreset_mode": _MODES[mode], "render_modes": []}
        self.render_mode = None
        self.info_names = list(self.rlpkg_spec["info_names"])
        self._discrete_n = self.rlpkg_spec.get("action_n")
        self._action_shape = self.action_space.shape

    @property
    def autoreset_mode(self) -> AutoresetMode:
        """Gymnasium's autoreset mode of this environment."""
        return self.metadata["autoreset_mode"]

    def _observations(self, obs, critic):
        if self.obs_mode == "dict":
            return {"policy": obs, "critic": critic}
        return obs

    def reset(self, *, seed=None, options=None):
        """Restarts every copy, or those of ``options["reset_mask"]`` (a bool array, one per
        copy; the other rows keep their observations). ``seed``: an int (copy i from ``seed *
        seed_stride + i``), one int per copy, or None (each copy continues its random stream)."""
        core = open_core(self, "reset")
        # Checked before Gymnasium seeds its own generator, which raises its own error type.
        args = check_seeds(seed, self.num_envs, self.seed_stride)
        options = check_options(options, "None or a dict of reset options ({'reset_mask': mask})")
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            super().reset(seed=int(seed))
        mask = options.pop("reset_mask", None)
        if options:
            raise ValueError(f"options: unknown keys {sorted(options)}; expected only 'reset_mask'")
        if mask is not None:
            mask = np.asarray(mask)
            if mask.dtype != np.bool_ or mask.shape != (self.num_envs,):
                raise ValueError(
                    f"reset_mask: dtype {mask.dtype}, shape {mask.shape}; expected bool of shape ({self.num_envs},)"
                )
            args["mask"] = np.ascontiguousarray(mask)
        obs, critic = core.reset(**args)
        return self._observations(obs, critic), {}

    def step(self, actions):
        """Steps every copy; see :class:`gymnasium.vector.VectorEnv`. Infos: each of
        ``info_names`` (one value per copy) with its ``_name`` mask; in same-step mode,
        ``final_obs`` and ``final_info`` of the copies that finished (masks ``_final_obs`` and
        ``_final_info``), as Gymnasium's ``SyncVectorEnv`` gives them."""
        core = open_core(self, "step")
        flat = check_actions(actions, self._discrete_n, self._action_shape)
        obs, critic, rewards, terminated, truncated, final_obs, final_critic, info = core.step(flat)
        infos: dict[str, Any] = {}
        everyone = np.ones(self.num_envs, dtype=bool)
        for k, name in enumerate(self.info_names):
            infos[name] = info[:, k].copy()
            infos[f"_{name}"] = everyone.copy()
        if self.autoreset_mode == AutoresetMode.SAME_STEP:
            done = terminated | truncated
            if done.any():
                rows = np.full(self.num_envs, None, dtype=object)
                final_info: dict[str, Any] = {}
                for i in np.flatnonzero(done):
                    rows[i] = (
                        {"policy": final_obs[i].copy(), "critic": final_critic[i].copy()}
                        if self.obs_mode == "dict"
                        else final_obs[i].copy()
                    )
                for k, name in enumerate(self.info_names):
                    final_info[name] = np.where(done, info[:, k], 0).astype(info.dtype)
                    final_info[f"_{name}"] = done.copy()
                infos["final_obs"], infos["_final_obs"] = rows, done.copy()
                infos["final_info"], infos["_final_info"] = final_info, done.copy()
        return self._observations(obs, critic), rewards, terminated, truncated, infos

    def close_extras(self, **kwargs):
        """Frees the Rust environment."""
        self._core = None


def make_vec(
    id: str,
    num_envs: int,
    *,
    config: str | os.PathLike | None = None,
    autoreset_mode: str | AutoresetMode = "next_step",
    obs_mode: str = "actor",
    num_threads: int | None = None,
    seed_stride: int = 1,
    render_mode: None = None,
) -> RlpkgVectorEnv:
    """``num_envs`` copies of ``id`` ("CartPole-v1", "Pendulum-v1", "Transport-v0") as a
    :class:`gymnasium.vector.VectorEnv`.

    - ``config``: Transport-v0's configuration file (default: ``configs/train/transport.toml`` of
      the repository, see :func:`default_transport_config`);
    - ``autoreset_mode``: "next_step" (Gymnasium's default), "same_step" (rlpkg's trainer) or
      "disabled" (reset finished copies with ``options={"reset_mask": ...}``), or Gymnasium's enum;
    - ``obs_mode``: "actor", or "dict" for ``{"policy": ..., "critic": ...}`` (Transport-v0's
      critic group);
    - ``num_threads``: the size of the environment's thread pool (default: RAYON_NUM_THREADS,
      else OMP_NUM_THREADS, else the cores);
    - ``seed_stride``: ``reset(seed=s)`` seeds copy i from ``s * seed_stride + i`` (use
      ``num_envs`` so that workers seeded 0, 1, ... share no copy's seed);
    - ``render_mode``: only None (the environments have no renderer).
    """
    check_render_mode(render_mode)
    return RlpkgVectorEnv(
        id,
        num_envs,
        config=config,
        autoreset_mode=autoreset_mode,
        obs_mode=obs_mode,
        num_threads=num_threads,
        seed_stride=seed_stride,
    )


def rust_rollout_digest(
    id: str,
    num_envs: int,
    steps: int,
    seed: int,
    config: str | os.PathLike | None = None,
    autoreset_mode: str | AutoresetMode = "same_step",
    num_threads: int | None = None,
) -> int:
    """The digest of ``steps`` scripted steps of ``num_envs`` copies of ``id`` after
    ``reset(seed=seed)``, stepped in Rust only (``rlpkg_vec_env::digest``): the reference the tests
    compare :func:`make_vec`'s stepping with. The arguments are checked as :func:`make_vec` checks
    them (``config`` only for Transport-v0)."""
    num_envs = check_num_envs(num_envs)
    steps = whole("steps", steps, "a number of steps >= 0", 0, 2**64 - 1)
    seed = whole("seed", seed, "an integer in [0, 2**64 - 1]", 0, MAX_SEED)
    # Copy i starts from seed + i, all within 64 bits.
    check_seeds(seed, num_envs, 1)
    mode = mode_name(autoreset_mode)
    num_threads = check_num_threads(num_threads)
    path = check_id_and_config(id, config)
    return _native.rust_rollout_digest(id, num_envs, steps, seed, path, mode, num_threads)
