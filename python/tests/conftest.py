"""Shared fixtures of the rlpkg Python tests."""

from pathlib import Path

import numpy as np
import pytest

SMALL_TRANSPORT = Path(__file__).with_name("transport-small.toml")
REPOSITORY = Path(__file__).resolve().parents[2]

FNV_OFFSET = 0xCBF29CE484222325
FNV_PRIME = 0x100000001B3
MASK = (1 << 64) - 1


class WordDigest:
    """FNV-1a over 32-bit words, as rlpkg_vec_env::digest::WordDigest."""

    def __init__(self):
        self.value = FNV_OFFSET

    def words(self, array):
        h = self.value
        for w in np.ascontiguousarray(array).reshape(-1).view(np.uint32).tolist():
            h = ((h ^ w) * FNV_PRIME) & MASK
        self.value = h


def scripted_actions(venv, step):
    """rlpkg_vec_env::digest::scripted_action for every copy, in float32 as in Rust."""
    n = venv.num_envs
    base = 31 * step + 17 * np.arange(n)
    if venv.rlpkg_spec.get("action_n") is not None:
        return (base % venv.rlpkg_spec["action_n"]).astype(np.int64)
    low = np.asarray(venv.rlpkg_spec["action_low"], dtype=np.float32)
    high = np.asarray(venv.rlpkg_spec["action_high"], dtype=np.float32)
    dims = np.arange(low.size)
    k = ((base[:, None] + 7 * dims[None, :]) % 11).astype(np.float32)
    return low + (high - low) * (k / np.float32(10.0))


def python_digest(venv, seed, steps):
    """The digest of the rollout rlpkg.rust_rollout_digest runs, stepped through ``venv``."""
    digest = WordDigest()
    obs, _ = venv.reset(seed=seed)
    digest.words(obs.astype(np.float32))
    for step in range(steps):
        obs, rewards, terminated, truncated, _ = venv.step(scripted_actions(venv, step))
        digest.words(obs)
        digest.words(rewards.astype(np.float32))
        digest.words(terminated.astype(np.uint32))
        digest.words(truncated.astype(np.uint32))
    return digest.value


@pytest.fixture
def small_transport():
    return str(SMALL_TRANSPORT)


@pytest.fixture
def tiny_posterior(tmp_path):
    """A sampled posterior of two film parameters in seconds of CPU: the first 0.05 s of HHHHH on
    the physical scene's 11 x 13 grid after a 0.1 s rest, six particles after a growing-horizon
    mode search (0.025 s, then the whole 0.05 s). Returns the configuration's path."""
    scene = (REPOSITORY / "configs/scenes/physical-explicit.toml").read_text()
    assert "rest_time_s = 1.0" in scene
    (tmp_path / "quick-scene.toml").write_text(scene.replace("rest_time_s = 1.0", "rest_time_s = 0.1"))
    config = tmp_path / "posterior-tiny.toml"
    config.write_text(
        f"""data = "{REPOSITORY / 'data/deformable-sim-real'}"
out_dir = "{tmp_path / 'posterior'}"
trajectories = ["HHHHH"]

[sim]
preset = "{tmp_path / 'quick-scene.toml'}"
between = 1
max_seconds = 0.05
hold_disc = true

[smc]
particles = 6
moves = 1
seed = 3
polish_iterations = 0

[smc.mode_search]
population = 4
generations = 1
first_horizon_s = 0.025

[loss]
object = 1.0
package = 1.0
kind = "labelled"

[[param]]
name = "k_tri_e"
lower = 1.0e3
upper = 4.0e4
log = true

[[param]]
name = "k_tri_d"
lower = 1.0e-5
upper = 1.0e-1
log = true
"""
    )
    return config
