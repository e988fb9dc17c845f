"""rlpkg's vectorised environments from Python, through Gymnasium's APIs.

- :func:`make_vec` -- a :class:`gymnasium.vector.VectorEnv` stepping ``num_envs`` copies in Rust
  (CartPole-v1, Pendulum-v1, Transport-v0), with Gymnasium's autoreset modes;
- :func:`make` -- one copy as a :class:`gymnasium.Env`;
- :func:`register` -- registers ``rlpkg/<id>`` for ``gymnasium.make`` and ``gymnasium.make_vec``;
- :mod:`rlpkg.sb3` -- an adapter to Stable-Baselines3's ``VecEnv`` interface;
- :class:`ProfileReference` -- on a robot, the reference a policy trained with
  ``[transport.profile_rate]`` drives: the same motion profile along the cell's path, advanced by
  each action's clock rate.
"""

from rlpkg._env import RlpkgEnv, make
from rlpkg._native import IDS, ProfileReference, __version__
from rlpkg._vector import (
    RlpkgVectorEnv,
    check_render_mode,
    default_transport_config,
    make_vec,
    rust_rollout_digest,
)

__all__ = [
    "IDS",
    "__version__",
    "ProfileReference",
    "RlpkgEnv",
    "RlpkgVectorEnv",
    "default_transport_config",
    "make",
    "make_vec",
    "register",
    "rust_rollout_digest",
]


def register() -> None:
    """Registers ``rlpkg/CartPole-v1``, ``rlpkg/Pendulum-v1`` and ``rlpkg/Transport-v0`` with
    Gymnasium, so that ``gymnasium.make("rlpkg/CartPole-v1")`` and
    ``gymnasium.make_vec("rlpkg/CartPole-v1", num_envs=8)`` build rlpkg's environments (keyword
    arguments are passed on to :func:`make` and :func:`make_vec`). Registering twice is harmless.
    """
    import functools

    import gymnasium

    for env_id in IDS:
        name = f"rlpkg/{env_id}"
        if name in gymnasium.registry:
            continue
        gymnasium.register(
            id=name,
            entry_point=functools.partial(make, env_id),
            vector_entry_point=functools.partial(_make_vec_entry, env_id),
            disable_env_checker=False,
        )


def _make_vec_entry(env_id, num_envs=1, **kwargs):
    """``gymnasium.make_vec``'s entry: it passes ``vectorization_mode`` and ``render_mode`` too."""
    kwargs.pop("vectorization_mode", None)
    check_render_mode(kwargs.pop("render_mode", None))
    return make_vec(env_id, num_envs, **kwargs)
