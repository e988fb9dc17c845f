"""Gymnasium spaces of one copy, from the spec the native core reports."""

import numpy as np
from gymnasium import spaces


def box(low, high) -> spaces.Box:
    """A float32 box; ``f32::MIN``/``f32::MAX`` bounds (unbounded in rlpkg) become infinite."""
    low = np.asarray(low, dtype=np.float32)
    high = np.asarray(high, dtype=np.float32)
    big = np.finfo(np.float32).max
    low = np.where(low <= -big, -np.inf, low).astype(np.float32)
    high = np.where(high >= big, np.inf, high).astype(np.float32)
    return spaces.Box(low=low, high=high, dtype=np.float32)


def single_spaces(spec: dict, obs_mode: str):
    """``(observation_space, action_space)`` of one copy. ``obs_mode``: "actor" (the policy's
    observations) or "dict" (``{"policy": ..., "critic": ...}``; needs a critic group)."""
    actor = box(spec["obs_low"], spec["obs_high"])
    if obs_mode == "actor":
        observation = actor
    elif obs_mode == "dict":
        if "critic_low" not in spec:
            raise ValueError(
                f"obs_mode='dict': {spec['id']} has no critic observation group; "
                "expected obs_mode='actor'"
            )
        critic = box(spec["critic_low"], spec["critic_high"])
        observation = spaces.Dict({"policy": actor, "critic": critic})
    else:
        raise ValueError(f"obs_mode={obs_mode!r}: expected 'actor' or 'dict'")
    if "action_n" in spec:
        action = spaces.Discrete(spec["action_n"])
    else:
        action = box(spec["action_low"], spec["action_high"])
    return observation, action
