"""`make`: one copy of an rlpkg environment as a Gymnasium ``Env``."""

from __future__ import annotations

import dataclasses
import os
from typing import Any

import gymnasium
import numpy as np
from gymnasium.envs.registration import EnvSpec

from rlpkg import _native
from rlpkg._spaces import single_spaces
from rlpkg._vector import (
    MAX_SEED,
    check_actions,
    check_id_and_config,
    check_num_threads,
    check_options,
    check_render_mode,
    open_core,
)


class RlpkgEnv(gymnasium.Env):
    """One copy of an rlpkg environment (see :func:`make`). An episode ends with ``terminated``
    or ``truncated`` (the environment's own time limit); call ``reset`` to start the next one
    (stepping a finished episode raises ValueError)."""

    metadata = {"render_modes": []}

    def __init__(
        self,
        env_id: str,
        *,
        config: str | os.PathLike | None = None,
        obs_mode: str = "actor",
        num_threads: int | None = None,
    ):
        num_threads = check_num_threads(num_threads)
        path = check_id_and_config(env_id, config)
        self._core = _native.VecEnvCore(env_id, 1, path, "disabled", num_threads)
        self.rlpkg_spec = self._core.spec()
        self.obs_mode = obs_mode
        self.observation_space, self.action_space = single_spaces(self.rlpkg_spec, obs_mode)
        self.render_mode = None
        self.info_names = list(self.rlpkg_spec["info_names"])
        self._discrete_n = self.rlpkg_spec.get("action_n")
        self._action_shape = self.action_space.shape
        kwargs = {"obs_mode": obs_mode} if config is None else {"config": os.fspath(config), "obs_mode": obs_mode}
        self.spec = EnvSpec(id=f"rlpkg/{env_id}", entry_point="rlpkg:make", kwargs={"id": env_id, **kwargs})

    @property
    def spec(self) -> EnvSpec | None:
        """Gymnasium's spec of this copy; its ``max_episode_steps`` is the environment's own time
        limit (kept when ``gymnasium.make`` sets a spec of its own without one)."""
        return self._spec

    @spec.setter
    def spec(self, value: EnvSpec | None):
        if value is not None and value.max_episode_steps is None:
            value = dataclasses.replace(value, max_episode_steps=int(self.rlpkg_spec["max_episode_steps"]))
        self._spec = value

    def render(self):
        """Not supported: rlpkg environments draw no frames (``rlpkg eval`` writes pictures and
        animations of evaluated episodes)."""
        raise NotImplementedError(
            f"{self.rlpkg_spec['id']} has no renderer (render_modes: []); pictures of episodes: `rlpkg eval`"
        )

    def _observation(self, obs, critic):
        if self.obs_mode == "dict":
            return {"policy": obs[0], "critic": critic[0]}
        return obs[0]

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Starts an episode; ``seed`` reseeds the copy (as copy 0 of ``make_vec`` reset with
        that seed), None continues its random stream."""
        # Checked before Gymnasium seeds its own generator, which raises its own error type.
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))):
            raise TypeError(f"seed={seed!r}: expected None or an integer >= 0")
        if seed is not None and not 0 <= seed <= MAX_SEED:
            raise ValueError(f"seed={seed}: expected an integer in [0, 2**64 - 1]")
        core = open_core(self, "reset")
        if check_options(options, "None or an empty dict"):
            raise ValueError(f"options: {sorted(options)}; {self.rlpkg_spec['id']} takes none")
        super().reset(seed=None if seed is None else int(seed))
        args = {} if seed is None else {"seed": int(seed)}
        obs, critic = core.reset(**args)
        return self._observation(obs, critic), {}

    def step(self, action):
        """One step; ``info`` holds the environment's per-step values (Transport-v0's reward
        terms and episode outcomes) as floats."""
        core = open_core(self, "step")
        flat = check_actions(action, self._discrete_n, self._action_shape)
        obs, critic, rewards, terminated, truncated, _, _, info = core.step(flat)
        infos = {name: float(info[0, k]) for k, name in enumerate(self.info_names)}
        return (
            self._observation(obs, critic),
            float(rewards[0]),
            bool(terminated[0]),
            bool(truncated[0]),
            infos,
        )

    def close(self):
        """Frees the Rust environment."""
        self._core = None


def make(id: str, **kwargs) -> RlpkgEnv:
    """One copy of ``id`` ("CartPole-v1", "Pendulum-v1", "Transport-v0") as a
    :class:`gymnasium.Env` without autoreset. Keywords: ``config`` (Transport-v0's configuration
    file), ``obs_mode`` ("actor" or "dict"), ``num_threads``; ``render_mode`` only None (the
    environments have no renderer)."""
    check_render_mode(kwargs.pop("render_mode", None))
    return RlpkgEnv(id, **kwargs)
