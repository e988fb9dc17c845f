"""rlpkg's environments through Gymnasium: the checker, autoreset parity with SyncVectorEnv,
registration, spaces and observation groups."""

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode, SyncVectorEnv

import rlpkg

MODES = {
    "next_step": AutoresetMode.NEXT_STEP,
    "same_step": AutoresetMode.SAME_STEP,
    "disabled": AutoresetMode.DISABLED,
}


@pytest.mark.parametrize("env_id", ["CartPole-v1", "Pendulum-v1", "Transport-v0"])
def test_env_checker_passes(env_id, small_transport):
    kwargs = {"config": small_transport} if env_id == "Transport-v0" else {}
    env = rlpkg.make(env_id, **kwargs)
    check_env(env, skip_render_check=True)
    env.close()


@pytest.mark.parametrize("mode", list(MODES))
def test_autoreset_matches_sync_vector_env(mode):
    num_envs, steps = 16, 2000
    venv = rlpkg.make_vec("CartPole-v1", num_envs, autoreset_mode=mode)
    assert venv.metadata["autoreset_mode"] == MODES[mode]
    sync = SyncVectorEnv(
        [lambda: rlpkg.make("CartPole-v1") for _ in range(num_envs)], autoreset_mode=MODES[mode]
    )
    obs_a, _ = venv.reset(seed=3)
    obs_b, _ = sync.reset(seed=3)
    np.testing.assert_array_equal(obs_a, obs_b)
    rng = np.random.default_rng(3)
    episodes_ended = 0
    for step in range(steps):
        actions = rng.integers(0, 2, size=num_envs)
        a = venv.step(actions)
        b = sync.step(actions)
        for x, y in zip(a[:4], b[:4]):
            np.testing.assert_array_equal(x, y, err_msg=f"step {step}")
        done = a[2] | a[3]
        episodes_ended += int(done.sum())
        if mode == "same_step" and done.any():
            np.testing.assert_array_equal(a[4]["_final_obs"], b[4]["_final_obs"])
            for i in np.flatnonzero(done):
                np.testing.assert_array_equal(a[4]["final_obs"][i], b[4]["final_obs"][i])
        if mode == "disabled" and done.any():
            obs_a, _ = venv.reset(options={"reset_mask": done})
            obs_b, _ = sync.reset(options={"reset_mask": done})
            np.testing.assert_array_equal(obs_a, obs_b)
    assert episodes_ended > 100


def test_step_returns_fresh_float32_arrays():
    venv = rlpkg.make_vec("Pendulum-v1", 4)
    obs, _ = venv.reset(seed=0)
    first = obs.copy()
    obs2, rewards, terminated, truncated, _ = venv.step(np.zeros((4, 1), dtype=np.float32))
    assert obs.dtype == obs2.dtype == rewards.dtype == np.float32
    assert terminated.dtype == truncated.dtype == np.bool_
    assert obs2.base is None or not np.shares_memory(obs, obs2)
    np.testing.assert_array_equal(obs, first)
    assert venv.observation_space.shape == (4, 3) and venv.single_action_space.shape == (1,)


def test_reset_mask_touches_only_masked_copies():
    venv = rlpkg.make_vec("CartPole-v1", 4, autoreset_mode="disabled")
    venv.reset(seed=1)
    for _ in range(3):
        obs, *_ = venv.step(np.ones(4, dtype=np.int64))
    mask = np.array([False, True, False, False])
    again, _ = venv.reset(seed=1, options={"reset_mask": mask})
    fresh = rlpkg.make_vec("CartPole-v1", 4)
    start, _ = fresh.reset(seed=1)
    np.testing.assert_array_equal(again[1], start[1])
    np.testing.assert_array_equal(again[~mask], obs[~mask])


def test_seed_stride_keeps_workers_apart():
    def first_rows(stride, seed):
        venv = rlpkg.make_vec("CartPole-v1", 8, seed_stride=stride)
        obs, _ = venv.reset(seed=seed)
        return {row.tobytes() for row in obs}

    assert not first_rows(8, 0) & first_rows(8, 1)
    # With the default stride, worker 1's copies are worker 0's shifted by one.
    assert len(first_rows(1, 0) & first_rows(1, 1)) == 7
    # One seed per copy: copy i as copy 0 of make(...) reset with that seed.
    venv = rlpkg.make_vec("CartPole-v1", 3)
    obs, _ = venv.reset(seed=[10, 4, 99])
    for i, seed in enumerate([10, 4, 99]):
        single, _ = rlpkg.make("CartPole-v1").reset(seed=seed)
        np.testing.assert_array_equal(obs[i], single)


def test_registered_ids_build_through_gymnasium(small_transport):
    rlpkg.register()
    rlpkg.register()
    env = gymnasium.make("rlpkg/Pendulum-v1")
    obs, _ = env.reset(seed=2)
    assert obs.shape == (3,)
    venv = gymnasium.make_vec("rlpkg/CartPole-v1", num_envs=5, autoreset_mode="same_step")
    assert isinstance(venv, gymnasium.vector.VectorEnv) and venv.num_envs == 5
    assert venv.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    venv = gymnasium.make_vec("rlpkg/Transport-v0", num_envs=2, config=small_transport)
    obs, _ = venv.reset(seed=0)
    assert obs.shape == venv.observation_space.shape


def test_dict_observations_give_the_critic_group(small_transport):
    venv = rlpkg.make_vec("Transport-v0", 2, config=small_transport, obs_mode="dict", autoreset_mode="same_step")
    obs, _ = venv.reset(seed=0)
    assert set(obs) == {"policy", "critic"}
    assert obs["critic"].shape[1] > obs["policy"].shape[1]
    assert venv.observation_space["critic"].shape == obs["critic"].shape
    out = venv.step(np.zeros((2, 3), dtype=np.float32))
    assert "reward/progress" in out[4] and out[4]["_reward/progress"].all()
    with pytest.raises(ValueError, match="no critic observation group"):
        rlpkg.make_vec("CartPole-v1", 2, obs_mode="dict")


def test_sb3_adapter_reports_terminal_observations():
    from rlpkg.sb3 import VecEnvAdapter

    # Same-step autoreset said explicitly is what the adapter uses anyway.
    venv = VecEnvAdapter("CartPole-v1", 4, autoreset_mode="same_step")
    assert venv.seed(5) == [5, 6, 7, 8]
    obs = venv.reset()
    assert obs.shape == (4, 4)
    seen = False
    for _ in range(200):
        obs, rewards, dones, infos = venv.step(np.ones(4, dtype=np.int64))
        for i in np.flatnonzero(dones):
            seen = True
            assert infos[i]["terminal_observation"].shape == (4,)
            assert infos[i]["TimeLimit.truncated"] is False
            assert not np.array_equal(infos[i]["terminal_observation"], obs[i])
    assert seen
    venv.close()


def _sb3_adapter():
    from rlpkg.sb3 import VecEnvAdapter

    return VecEnvAdapter("CartPole-v1", 2)


# Each kind of environment and an action of it.
KINDS = {
    "make_vec": (lambda: rlpkg.make_vec("CartPole-v1", 2), np.zeros(2, np.int64)),
    "make": (lambda: rlpkg.make("CartPole-v1"), 0),
    "sb3": (_sb3_adapter, np.zeros(2, np.int64)),
}


@pytest.mark.parametrize("kind", list(KINDS))
@pytest.mark.parametrize("call", ["step", "reset"])
def test_a_closed_environment_raises_gymnasiums_closed_environment_error(kind, call):
    make, action = KINDS[kind]
    env = make()
    env.reset()
    env.close()
    env.close()  # closing twice is harmless
    with pytest.raises(gymnasium.error.ClosedEnvironmentError, match=f"{call} after close: .* is closed"):
        env.step(action) if call == "step" else env.reset()


@pytest.mark.parametrize(
    "call, error, message",
    [
        (
            lambda a: type(a)("CartPole-v1", 2, autoreset_mode="next_step"),
            ValueError,
            "autoreset_mode='next_step': VecEnvAdapter always uses same-step autoreset",
        ),
        (lambda a: a.step_wait(), ValueError, r"step_wait: step_async\(actions\) was not called"),
        (lambda a: a.seed("x"), TypeError, r"seed: expected None or an integer .*, got 'x' \(a str\)"),
        (lambda a: a.seed(-1), ValueError, r"seed: expected None or an integer .*, got -1"),
    ],
)
def test_sb3_adapter_refuses_misuse_by_name(call, error, message):
    adapter = _sb3_adapter()
    adapter.reset()
    with pytest.raises(error, match=message):
        call(adapter)


def test_a_negative_or_non_integer_seed_raises_value_or_type_error():
    env = rlpkg.make("CartPole-v1")
    venv = rlpkg.make_vec("CartPole-v1", 2)
    for reset in (env.reset, venv.reset):
        with pytest.raises(ValueError, match="seed=-1"):
            reset(seed=-1)
        with pytest.raises(TypeError, match="seed="):
            reset(seed=1.5)
        with pytest.raises(ValueError, match="seed="):
            reset(seed=2**64)
        reset(seed=0)
        reset(seed=np.int64(3))
    # Copy 1's seed would wrap past 2**64 - 1 onto copy 0's of seed 0.
    with pytest.raises(ValueError, match="seed=18446744073709551615"):
        venv.reset(seed=2**64 - 1)
    makers = (
        lambda n: rlpkg.make("CartPole-v1", num_threads=n),
        lambda n: rlpkg.make_vec("CartPole-v1", 1, num_threads=n),
    )
    for make in makers:
        for bad, error in ((-1, ValueError), (2**40, ValueError), (True, TypeError), (1.5, TypeError)):
            with pytest.raises(error, match="num_threads="):
                make(bad)


def test_spec_gives_the_time_limit_and_render_modes_are_refused():
    env = rlpkg.make("CartPole-v1")
    assert env.spec.id == "rlpkg/CartPole-v1" and env.spec.max_episode_steps == 500
    assert gymnasium.make(env.spec).spec.max_episode_steps == 500
    rlpkg.register()
    assert gymnasium.make("rlpkg/Pendulum-v1").spec.max_episode_steps == 200
    with pytest.raises(NotImplementedError, match="rlpkg eval"):
        env.render()
    for make in (
        lambda: rlpkg.make("CartPole-v1", render_mode="rgb_array"),
        lambda: gymnasium.make("rlpkg/CartPole-v1", render_mode="human"),
        lambda: gymnasium.make_vec("rlpkg/CartPole-v1", 2, render_mode="rgb_array"),
        lambda: rlpkg.make_vec("CartPole-v1", 2, render_mode="rgb_array"),
    ):
        with pytest.raises((ValueError, gymnasium.error.Error), match="render"):
            make()
    rlpkg.make_vec("CartPole-v1", 2, render_mode=None).close()
