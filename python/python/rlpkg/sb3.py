"""Stable-Baselines3's ``VecEnv`` interface over :func:`rlpkg.make_vec`.

``VecEnvAdapter`` subclasses ``stable_baselines3.common.vec_env.VecEnv`` when Stable-Baselines3
is installed (it is imported when the class is first used, not when this module is imported),
else plain ``object`` with the same methods. Finished copies restart in the step they end (SB3's
convention): their last observation is in ``infos[i]["terminal_observation"]`` and
``infos[i]["TimeLimit.truncated"]`` says the episode was cut by the time limit.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Any

import numpy as np

from rlpkg._checks import whole
from rlpkg._vector import MAX_SEED, check_seeds, make_vec, mode_name

__all__ = ["VecEnvAdapter"]

# No step_async since the last step_wait (None is an action argument like any other).
_NO_ACTIONS = object()


@functools.cache
def _adapter_class():
    try:
        from stable_baselines3.common.vec_env import VecEnv as Base
    except ImportError:
        Base = object

    class VecEnvAdapter(Base):
        """``num_envs`` copies of ``env_id`` (keywords as :func:`rlpkg.make_vec`, same-step
        autoreset) behind Stable-Baselines3's ``VecEnv`` methods."""

        def __init__(self, env_id: str, num_envs: int, **kwargs: Any):
            # SB3's VecEnv contract is same-step autoreset: another mode would be silently wrong.
            mode = kwargs.setdefault("autoreset_mode", "same_step")
            if mode_name(mode) != "same_step":
                raise ValueError(
                    f"autoreset_mode={mode!r}: VecEnvAdapter always uses same-step autoreset "
                    "(Stable-Baselines3's VecEnv contract); leave autoreset_mode out or pass 'same_step'"
                )
            self.venv = make_vec(env_id, num_envs, **kwargs)
            spaces = (self.venv.single_observation_space, self.venv.single_action_space)
            if Base is object:
                self.num_envs = self.venv.num_envs
                self.observation_space, self.action_space = spaces
                self.render_mode = None
            else:
                super().__init__(self.venv.num_envs, *spaces)
            self._actions = _NO_ACTIONS
            self._next_seed = None

        def reset(self):
            """Restarts every copy (seeded by the last ``seed`` call, if any)."""
            obs, _ = self.venv.reset(seed=self._next_seed)
            self._next_seed = None
            return obs

        def seed(self, seed: int | None = None):
            """Seeds the next reset: copy i from ``seed * seed_stride + i`` (``seed_stride`` of
            :func:`rlpkg.make_vec`, default 1). Returns each copy's seed."""
            if seed is None:
                self._next_seed = None
                return [None] * self.num_envs
            # Checked here rather than at the next reset, which would not name this call.
            seed = whole("seed", seed, "None or an integer in [0, 2**64 - 1]", 0, MAX_SEED)
            stride = self.venv.seed_stride
            check_seeds(seed, self.num_envs, stride)
            self._next_seed = seed
            return [seed * stride + i for i in range(self.num_envs)]

        def step_async(self, actions) -> None:
            """Keeps ``actions`` for :meth:`step_wait` (the copies step there, in Rust)."""
            self._actions = actions

        def step_wait(self):
            """Steps every copy with the actions of the last :meth:`step_async`."""
            if self._actions is _NO_ACTIONS:
                raise ValueError("step_wait: step_async(actions) was not called; call it first")
            actions, self._actions = self._actions, _NO_ACTIONS
            obs, rewards, terminated, truncated, info = self.venv.step(actions)
            dones = terminated | truncated
            infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
            for name in self.venv.info_names:
                for i in range(self.num_envs):
                    infos[i][name] = float(info[name][i])
            for i in np.flatnonzero(dones):
                infos[i]["terminal_observation"] = info["final_obs"][i]
                infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
            return obs, rewards, dones, infos

        def step(self, actions):
            self.step_async(actions)
            return self.step_wait()

        def close(self) -> None:
            self.venv.close()

        def _indices(self, indices):
            if indices is None:
                return range(self.num_envs)
            if isinstance(indices, int):
                return [indices]
            return indices

        def get_attr(self, attr_name: str, indices=None) -> list:
            return [getattr(self.venv, attr_name) for _ in self._indices(indices)]

        def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
            setattr(self.venv, attr_name, value)

        def env_method(self, method_name: str, *args, indices=None, **kwargs) -> list:
            raise AttributeError(
                f"env_method({method_name!r}): the copies are stepped together in Rust and have no "
                "separate Python environments"
            )

        def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
            return [False for _ in self._indices(indices)]

        def get_images(self):
            return []

    return VecEnvAdapter


if TYPE_CHECKING:

    class VecEnvAdapter:  # noqa: D101 - the real class is built by _adapter_class
        def __init__(self, env_id: str, num_envs: int, **kwargs: Any): ...


def __getattr__(name: str):
    if name == "VecEnvAdapter":
        return _adapter_class()
    raise AttributeError(f"module 'rlpkg.sb3' has no attribute {name!r}")
