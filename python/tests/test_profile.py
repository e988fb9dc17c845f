"""rlpkg.ProfileReference: the reference a profile-rate policy drives on a robot."""

import numpy as np
import pytest

import rlpkg
from conftest import SMALL_TRANSPORT

RATE_TABLE = """
[transport.profile_rate]
limits_scale = 1.0
max_rate = 2.0
max_rate_change_per_s = 4.0
"""


@pytest.fixture
def rate_config(tmp_path):
    path = tmp_path / "transport-rate.toml"
    text = SMALL_TRANSPORT.read_text()
    # The copy lives elsewhere: name the recordings by their absolute place.
    recordings = SMALL_TRANSPORT.parent.parent.parent / "data" / "deformable-sim-real"
    text = text.replace('"data/deformable-sim-real"', f'"{recordings}"')
    path.write_text(text + RATE_TABLE)
    return path


def lift_and_move(points=200):
    """A 0.1 m lift, then a 0.5 m straight move, tilting to 0.6 rad along it."""
    lift = np.linspace(0.0, 0.1, points // 4, endpoint=False)
    move = np.linspace(0.0, 0.5, points - points // 4)
    positions = np.concatenate(
        [
            np.stack([np.zeros_like(lift), np.zeros_like(lift), lift], axis=1),
            np.stack([move, np.zeros_like(move), np.full_like(move, 0.1)], axis=1),
        ]
    )
    tilts = np.concatenate([np.zeros_like(lift), 0.6 * move / 0.5])
    return positions, tilts


def drive(reference, action, max_steps=400):
    speeds, rates = [], []
    for _ in range(max_steps):
        _, speed = reference.step(action)
        speeds.append(speed)
        rates.append(reference.rate)
        if reference.progress_m == reference.length_m and speed == 0.0:
            break
    return np.array(speeds), np.array(rates)


def test_rate_one_plays_the_plan_to_rest_within_the_limits(rate_config):
    reference = rlpkg.ProfileReference(rate_config, *lift_and_move())
    assert reference.length_m == pytest.approx(0.6)
    assert reference.rate == 1.0 and reference.clock_s == 0.0
    speeds, rates = drive(reference, 1.0)
    steps = len(speeds)
    assert reference.progress_m == reference.length_m and speeds[-1] == 0.0
    assert np.all(rates == 1.0)
    assert reference.clock_s == pytest.approx(steps * reference.interval_s)
    # Within the tool's speed and acceleration (transport-small.toml: 0.945 m/s, 5.2 m/s^2).
    assert speeds.max() <= 0.945 + 1e-12
    assert np.abs(np.diff(speeds)).max() <= 5.2 * reference.interval_s + 1e-12
    # At rate 1 the reference keeps to the plan: done within a few intervals of its duration.
    assert steps * reference.interval_s <= reference.duration_s + 4 * reference.interval_s
    progress, speed = reference.planned(reference.duration_s)
    assert progress == pytest.approx(reference.length_m) and speed == pytest.approx(0.0)
    position, tilt = reference.pose(reference.length_m)
    assert position == pytest.approx([0.5, 0.0, 0.1]) and tilt == pytest.approx(0.6)


def test_the_rate_follows_the_action_within_its_change_limit(rate_config):
    fast = rlpkg.ProfileReference(rate_config, *lift_and_move())
    slow = rlpkg.ProfileReference(rate_config, *lift_and_move())
    _, fast_rates = drive(fast, 5.0)
    _, slow_rates = drive(slow, 0.5)
    step = 4.0 * fast.interval_s
    assert fast_rates[0] == pytest.approx(1.0 + step)
    assert fast_rates.max() == 2.0  # clamped at max_rate
    assert np.abs(np.diff(fast_rates)).max() <= step + 1e-12
    assert slow_rates[-1] == 0.5
    assert len(fast_rates) < len(slow_rates)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda p, t: (p[:, :2], t), "positions"),
        (lambda p, t: (p[:1], t[:1]), "positions"),
        (lambda p, t: (p, t[:-1]), "tilts"),
        (lambda p, t: (np.where(np.arange(len(p))[:, None] == 3, np.nan, p), t), "positions[3]"),
        (lambda p, t: (p, np.where(np.arange(len(t)) == 5, np.inf, t)), "tilts[5]"),
        (lambda p, t: (np.concatenate([p[:2], p[1:]]), np.concatenate([t[:2], t[1:]])), "positions[2]"),
    ],
)
def test_bad_paths_are_refused_by_name(rate_config, change, message):
    positions, tilts = change(*lift_and_move())
    with pytest.raises(ValueError, match=message.replace("[", r"\[")):
        rlpkg.ProfileReference(rate_config, positions, tilts)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda p, t: (p.astype(str), t), r"positions: expected a \(K, 3\) array of real .*, got an array of dtype <U"),
        (lambda p, t: (p, None), r"tilts: expected a \(K,\) array of real numbers.*, got None \(a NoneType\)"),
        (lambda p, t: (p > 0, t), r"positions: .*, got an array of dtype bool"),
    ],
)
def test_paths_of_other_types_are_refused_by_name(rate_config, change, message):
    with pytest.raises(TypeError, match=message):
        rlpkg.ProfileReference(rate_config, *change(*lift_and_move()))


@pytest.mark.parametrize(
    "change",
    [lambda p, t: (p.tolist(), t.tolist()), lambda p, t: (p.astype(np.float32), t.astype(np.float32))],
    ids=["lists", "float32"],
)
def test_array_likes_are_converted_to_float64(rate_config, change):
    positions, tilts = lift_and_move()
    reference = rlpkg.ProfileReference(rate_config, positions, tilts)
    converted = rlpkg.ProfileReference(rate_config, *change(positions, tilts))
    assert converted.length_m == pytest.approx(reference.length_m, rel=1e-6)
    assert converted.duration_s == pytest.approx(reference.duration_s, rel=1e-6)
    assert converted.step(1.0) == pytest.approx(reference.step(1.0), rel=1e-6)


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda r: r.step("1"), r"action: expected a finite clock rate \(a number\), got '1' \(a str\)"),
        (lambda r: r.step(True), r"action: .*, got True \(a bool\)"),
        (lambda r: r.pose("1"), r"progress_m: expected an arc length along the path \(m\), got '1'"),
        (lambda r: r.planned(None), r"t_s: expected a time along the plan \(s\), got None"),
        (lambda r: r.tilt_offsets(0.0, "x"), r"action_z: expected a finite tilt offset \(rad\), got 'x'"),
    ],
)
def test_arguments_of_other_types_are_refused_by_name(rate_config, call, message):
    reference = rlpkg.ProfileReference(rate_config, *lift_and_move())
    with pytest.raises(TypeError, match=message):
        call(reference)
    assert reference.progress_m == 0.0 and reference.rate == 1.0


def test_a_config_without_the_profile_rate_table_is_refused(tmp_path):
    with pytest.raises(ValueError, match=r"transport\.profile_rate"):
        rlpkg.ProfileReference(SMALL_TRANSPORT, *lift_and_move())
    with pytest.raises(ValueError, match="transport-missing.toml"):
        rlpkg.ProfileReference(tmp_path / "transport-missing.toml", *lift_and_move())


def test_a_non_finite_action_is_refused(rate_config):
    reference = rlpkg.ProfileReference(rate_config, *lift_and_move())
    with pytest.raises(ValueError, match="action"):
        reference.step(float("nan"))
    assert reference.progress_m == 0.0
    with pytest.raises(ValueError, match="tilt offsets"):
        reference.tilt_offsets(0.1, float("inf"))
    with pytest.raises(ValueError, match="progress_m: NaN"):
        reference.pose(float("nan"))
    with pytest.raises(ValueError, match="t_s: NaN"):
        reference.planned(float("nan"))


def test_tilt_offsets_are_bounded_and_fade_over_the_last_stretch(rate_config):
    full = np.radians(20.0)
    reference = rlpkg.ProfileReference(rate_config, *lift_and_move())
    assert reference.tilt_offsets(1.0, -0.1) == (full, -0.1)
    faded = rate_config.with_name("transport-fade.toml")
    faded.write_text(
        rate_config.read_text().replace(
            "max_tilt_offset_deg = 20.0", "max_tilt_offset_deg = 20.0\ntilt_offset_fade_m = 0.1"
        )
    )
    reference = rlpkg.ProfileReference(faded, *lift_and_move())
    bounds = []
    while not (reference.progress_m == reference.length_m and reference.path_speed_m_s == 0.0):
        reference.step(1.0)
        remaining = reference.length_m - reference.progress_m
        x, z = reference.tilt_offsets(1.0, -1.0)
        assert x == -z == pytest.approx(full * min(1.0, remaining / 0.1))
        bounds.append(x)
    assert bounds[0] == full and bounds[-1] == 0.0
    assert 0.0 < min(b for b in bounds if b > 0.0) < full
