"""The Rust core from Python: parity with Rust-only rollouts, the GIL, bad input."""

import re
import threading
import time

import numpy as np
import pytest

import rlpkg
from conftest import python_digest


@pytest.mark.parametrize("threads", [1, 2])
def test_cartpole_rollout_matches_rust(threads):
    venv = rlpkg.make_vec("CartPole-v1", 64, autoreset_mode="same_step", num_threads=threads)
    got = python_digest(venv, seed=7, steps=500)
    assert got == rlpkg.rust_rollout_digest("CartPole-v1", 64, 500, 7, num_threads=threads)
    assert got != rlpkg.rust_rollout_digest("CartPole-v1", 64, 500, 8)


@pytest.mark.parametrize("threads", [1, 2])
def test_transport_rollout_matches_rust(threads, small_transport):
    venv = rlpkg.make_vec(
        "Transport-v0", 4, config=small_transport, autoreset_mode="same_step", num_threads=threads
    )
    got = python_digest(venv, seed=5, steps=50)
    expected = rlpkg.rust_rollout_digest(
        "Transport-v0", 4, 50, 5, config=small_transport, num_threads=threads
    )
    assert got == expected


def test_pendulum_rollout_matches_rust():
    venv = rlpkg.make_vec("Pendulum-v1", 8, autoreset_mode="next_step")
    got = python_digest(venv, seed=1, steps=450)
    assert got == rlpkg.rust_rollout_digest("Pendulum-v1", 8, 450, 1, autoreset_mode="next_step")


def _python_loop_rate(seconds):
    count, end = 0, time.perf_counter() + seconds
    while time.perf_counter() < end:
        count += 1
    return count / seconds


def test_the_step_releases_the_gil(small_transport):
    venv = rlpkg.make_vec("Transport-v0", 4, config=small_transport, num_threads=1)
    venv.reset(seed=0)
    actions = np.zeros((4, 3), dtype=np.float32)
    solo = _python_loop_rate(1.0)
    stop = threading.Event()
    steps = [0]

    def stepping():
        while not stop.is_set():
            venv.step(actions)
            steps[0] += 1

    worker = threading.Thread(target=stepping)
    worker.start()
    try:
        time.sleep(0.2)
        shared = _python_loop_rate(1.5)
    finally:
        stop.set()
        worker.join()
    assert steps[0] > 0
    assert shared >= 0.3 * solo, f"python loop {shared:.0f}/s beside stepping, {solo:.0f}/s alone"


def test_bad_input_raises(tmp_path, small_transport):
    cartpole = rlpkg.make_vec("CartPole-v1", 4)
    with pytest.raises(ValueError, match="step before reset"):
        cartpole.step(np.zeros(4, dtype=np.int64))
    cartpole.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(3,\); expected \(4,\)"):
        cartpole.step(np.zeros(3, dtype=np.int64))
    with pytest.raises(TypeError, match="expected integer indices"):
        cartpole.step(np.zeros(4, dtype=np.float32))
    with pytest.raises(ValueError, match="expected an index in 0..2"):
        cartpole.step(np.array([0, 1, 2, 0]))
    with pytest.raises(TypeError, match="dtype"):
        cartpole.step(np.array(["a"] * 4))
    with pytest.raises(ValueError, match="reset_mask"):
        cartpole.reset(options={"reset_mask": np.ones(3, dtype=bool)})
    with pytest.raises(ValueError, match="one per copy"):
        cartpole.reset(seed=[1, 2])
    pendulum = rlpkg.make_vec("Pendulum-v1", 2)
    pendulum.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        pendulum.step(np.array([[0.0], [np.nan]], dtype=np.float32))
    with pytest.raises(ValueError, match="unknown environment id 'Acrobot-v1'"):
        rlpkg.make_vec("Acrobot-v1", 2)
    with pytest.raises(ValueError, match="autoreset_mode"):
        rlpkg.make_vec("CartPole-v1", 2, autoreset_mode="later")
    with pytest.raises(ValueError, match="num_envs"):
        rlpkg.make_vec("CartPole-v1", 0)
    # Checked before anything is allocated (2**40 copies would abort the interpreter).
    for huge in (2**40, 2**64, 2**100):
        with pytest.raises(ValueError, match="at most 1048576 copies"):
            rlpkg.make_vec("CartPole-v1", huge)
    assert re.fullmatch(r"\d+\.\d+\.\d+", rlpkg.__version__)
    text = open(small_transport).read().replace("control_hz = 20.0", "control_hz = 20.0\ncontrl_hz = 3")
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    with pytest.raises(ValueError, match="contrl_hz"):
        rlpkg.make_vec("Transport-v0", 2, config=bad)
    with pytest.raises(ValueError, match="no such file"):
        rlpkg.make_vec("Transport-v0", 2, config=tmp_path / "missing.toml")
    # Disabled autoreset: stepping a finished copy raises until it is reset.
    env = rlpkg.make("CartPole-v1")
    env.reset(seed=0)
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(1)
        done = terminated or truncated
    with pytest.raises(ValueError, match="episode ended"):
        env.step(1)
    env.reset()
    env.step(0)


def test_a_corrupt_events_file_is_a_value_error_naming_it(tmp_path):
    from rlpkg.runs import scalars

    for body in (bytes(range(256)), (20).to_bytes(8, "little") + bytes(4) + b"\xff" * 20 + bytes(4)):
        path = tmp_path / "events.out.tfevents.1"
        path.write_bytes(body)
        with pytest.raises(ValueError, match="events.out.tfevents.1: not a TensorBoard event file"):
            scalars(tmp_path)


def test_ray_map_chunks_are_whole_numbers():
    from rlpkg.calibration import RayMap

    assert RayMap(chunks=np.int64(2)).chunks == 2
    for bad in (True, 0, 1.5):
        with pytest.raises(ValueError, match="chunks="):
            RayMap(chunks=bad)


@pytest.mark.parametrize(
    "args, kwargs, error, message",
    [
        ((1, -1, 0), {}, ValueError, r"steps: expected a number of steps >= 0, got -1 \(an int\)"),
        ((1, 5, -1), {}, ValueError, r"seed: expected an integer in \[0, 2\*\*64 - 1\], got -1 \(an int\)"),
        ((1, 5, None), {}, TypeError, r"seed: expected an integer .*, got None"),
        ((1, 5, True), {}, TypeError, r"seed: expected an integer .*, got True \(a bool\)"),
        ((2, 5, 2**64 - 1), {}, ValueError, r"seed=18446744073709551615: copy 1's seed"),
        ((0, 5, 0), {}, ValueError, r"num_envs: expected an integer >= 1"),
        ((1, 5, 0), {"config": "missing.toml"}, ValueError, "config= is for Transport-v0"),
        ((1, 5, 0), {"autoreset_mode": ["same_step"]}, TypeError, r"autoreset_mode: .*, got \['same_step'\]"),
    ],
)
def test_rollout_digest_refuses_bad_arguments_by_name(args, kwargs, error, message):
    with pytest.raises(error, match=message):
        rlpkg.rust_rollout_digest("CartPole-v1", *args, **kwargs)


@pytest.mark.parametrize(
    "call, error, message",
    [
        (
            lambda: rlpkg.make_vec("CartPole-v1", 2, autoreset_mode=["next_step"]),
            TypeError,
            r"autoreset_mode: expected one of .*, got \['next_step'\] \(a list\)",
        ),
        (
            lambda: rlpkg.make_vec("Transport-v0", 1, config=5),
            TypeError,
            r"config: expected a path .*, got 5 \(an int\)",
        ),
        (lambda: rlpkg.make_vec("CartPole-v1", True), TypeError, r"num_envs: .*, got True \(a bool\)"),
        (lambda: rlpkg.make_vec("CartPole-v1", 2, seed_stride=2.0), TypeError, r"seed_stride: .*, got 2.0"),
        (
            lambda: rlpkg.make_vec("CartPole-v1", 2).reset(options=[1, 2]),
            TypeError,
            r"options: expected None or a dict .*, got \[1, 2\] \(a list\)",
        ),
        (
            lambda: rlpkg.make("CartPole-v1").reset(options=[1, 2]),
            TypeError,
            r"options: expected None or an empty dict, got \[1, 2\]",
        ),
    ],
)
def test_bad_arguments_are_named_with_what_was_expected(call, error, message):
    with pytest.raises(error, match=message):
        call()
