#!/usr/bin/env python3
"""Hostile-input probe of the `rlpkg` binary: hundreds of bad or hostile inputs across every command.

Each case is the arguments, a setup of its own folder (the working directory), the exit code it
must end with and words its message must hold. Every case runs in a fresh folder and is checked for:

* panic: exit code 101, a signal, or `panicked` / `RUST_BACKTRACE` on standard error;
* silent: exit code 0 (or running past the time limit) where bad input must be refused;
* wrong code: any other exit code than the expected one;
* clobbered: a file that was there before the command changed or vanished; a refused command
  (exit 2) must also leave no new file behind;
* message: the message lacks the words that name the culprit.

    python3 tools/hostile_probe.py --rlpkg target/release/rlpkg [--only WORD] [--list] [--jobs 1]

Prints one line per failing case and the counts; exit status 1 when any case fails. The figures of
a run are only meaningful for the binary given.
"""

import argparse
import gzip
import hashlib
import os
import re
import resource
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

REPO = Path(__file__).resolve().parent.parent
DATASET = REPO / "data/deformable-sim-real"
TAKE = DATASET / "HHHHH"
STUDY = REPO / "configs/scenes/study.toml"
MOTIVE_TAKE = REPO / "mocap/tests/fixtures/a30_m0.5_high_excerpt.csv.gz"

TINY_CARTPOLE = """
[run]
env = "CartPole-v1"
num_envs = 4
seed = 3
total_steps = 1024
checkpoint_every = 1

[ppo]
rollout_steps = 64
epochs = 1
minibatches = 2
gamma = 0.99
gae_lambda = 0.95
clip_ratio = 0.2
clip_value_loss = true
value_coef = 0.5
entropy_coef = 0.01
max_grad_norm = 0.5
learning_rate = 1e-3
lr_schedule = "linear"
desired_kl = 0.01
normalize_advantages = true
adam_epsilon = 1e-5

[policy]
actor_hidden = [16, 16]
critic_hidden = [16, 16]
activation = "tanh"
init_log_std = 0.0
action_transform = "clip"

[normalization]
observations = true
rewards = true
clip_obs = 10.0
clip_reward = 10.0
epsilon = 1e-8
"""


def quick_scene_text() -> str:
    """The study's scene on the coarsest grid with a 0.2 s rest: a replay in a second."""
    text = STUDY.read_text()
    text = text.replace("rest_time_s = 2.0", "rest_time_s = 0.2")
    text = text.replace("grid = [21, 25]", "grid = [6, 7]")
    text = text.replace("[health]", "[health]\nobject_outside = false")
    assert "grid = [6, 7]" in text
    return text


def calibration_text(preset: str = "quick.toml", out: str = "out") -> str:
    return (
        f'data = "{DATASET}"\ntrajectories = ["HHHHH"]\nout_dir = "{out}"\n\n'
        f'[sim]\npreset = "{preset}"\nbetween = 0\nmax_seconds = 0.05\n\n'
        "[optimiser]\niterations = 1\nbatch_size = 2\ninitial_points = 1\nseed = 5\n\n"
        '[[param]]\nname = "k_tri_e"\nlower = 1.0e4\nupper = 1.0e6\nlog = true\n'
    )


def transport_text() -> str:
    """The shipped transport task with its scene and recordings found from anywhere."""
    text = (REPO / "configs/train/transport.toml").read_text()
    text = text.replace('scene = "configs/', f'scene = "{REPO}/configs/')
    return text.replace('recordings = "data/', f'recordings = "{REPO}/data/')


def optimize_text() -> str:
    text = (REPO / "configs/optimize/transport.toml").read_text()
    return text.replace('transport = "configs/train/transport.toml"', 'transport = "transport.toml"')


def seal_text(out: str = "out") -> str:
    return (
        f'dataset = "ds"\nscene = "{STUDY}"\nout = "{out}"\nmax_seconds = 0.1\n\n'
        "[grid]\nvacuum_kpa = { min = 20.0, max = 30.0, steps = 2 }\n"
    )


def with_seal_dataset(d: Path):
    """Two takes of the study, the second flagged as a failure: what `seal fit` compares."""
    entries = (DATASET / "manifest.toml").read_text().split("[[trajectory]]")
    kept = []
    for entry in entries:
        if 'id = "HHHHH"' in entry or 'id = "HHHHM"' in entry:
            kept.append(entry if "HHHHH" in entry else entry.replace('split = "train"',
                                                                       'split = "excluded"\nfailure = true'))
    (d / "ds").mkdir()
    (d / "ds/manifest.toml").write_text("".join("[[trajectory]]" + e for e in kept))
    for take in ("HHHHH", "HHHHM"):
        copy_tree(DATASET / take, d / "ds" / take)


class Fixtures:
    """Things made once and copied into the cases that need them."""

    def __init__(self, rlpkg: Path, root: Path):
        self.rlpkg = rlpkg
        self.root = root
        self._run = None
        self._calibrated = None

    def _make(self, args, cwd):
        out = subprocess.run([str(self.rlpkg), *args], cwd=cwd, capture_output=True, text=True)
        if out.returncode != 0:
            sys.exit(f"fixture `rlpkg {' '.join(args)}` failed:\n{out.stderr}")

    def run(self) -> Path:
        """A CartPole run of 4 updates, exported."""
        if self._run is None:
            folder = self.root / "train"
            folder.mkdir()
            (folder / "tiny.toml").write_text(TINY_CARTPOLE)
            self._make(["train", "tiny.toml", "--quiet"], folder)
            self._run = folder / "runs/tiny"
        return self._run

    def calibrated(self) -> Path:
        """A folder with quick.toml, calibrate.toml and its finished calibration out/."""
        if self._calibrated is None:
            folder = self.root / "calibrated"
            folder.mkdir()
            (folder / "quick.toml").write_text(quick_scene_text())
            # Enough finite losses (12) for the surrogate posterior.
            (folder / "calibrate.toml").write_text(
                calibration_text().replace("iterations = 1", "iterations = 5"))
            self._make(["calibrate", "calibrate.toml"], folder)
            self._calibrated = folder
        return self._calibrated


FIX: Fixtures = None  # set in main


# ---- setups -------------------------------------------------------------------------------------


def copy_tree(src: Path, dst: Path):
    shutil.copytree(src, dst, symlinks=True)


def with_run(d: Path):
    copy_tree(FIX.run(), d / "run")


def with_tiny(d: Path, old: str = None, new: str = None):
    text = TINY_CARTPOLE
    if old is not None:
        assert old in text, old
        text = text.replace(old, new, 1)
    (d / "tiny.toml").write_text(text)


def with_quick(d: Path, old: str = None, new: str = None, name: str = "quick.toml"):
    text = quick_scene_text()
    if old is not None:
        assert old in text, old
        text = text.replace(old, new, 1)
    (d / name).write_text(text)


def with_calibration(d: Path, old: str = None, new: str = None):
    with_quick(d)
    text = calibration_text()
    if old is not None:
        assert old in text, old
        text = text.replace(old, new, 1)
    (d / "calibrate.toml").write_text(text)


def with_calibrated(d: Path):
    for entry in FIX.calibrated().iterdir():
        if entry.is_dir():
            copy_tree(entry, d / entry.name)
        else:
            shutil.copy(entry, d / entry.name)


def with_optimize(d: Path, old: str = None, new: str = None):
    (d / "transport.toml").write_text(transport_text())
    text = optimize_text()
    if old is not None:
        assert old in text, old
        text = text.replace(old, new, 1)
    (d / "optimize.toml").write_text(text)


def with_seal(d: Path, old: str = None, new: str = None):
    text = seal_text()
    if old is not None:
        assert old in text, old
        text = text.replace(old, new, 1)
    (d / "seal.toml").write_text(text)
    with_seal_dataset(d)


def with_motive(d: Path, old: str = None, new: str = None):
    text = (REPO / "configs/import/motive.toml").read_text()
    if old is not None:
        assert old in text, old
        text = text.replace(old, new, 1)
    # The excerpt take of the tests, listed as a take must be.
    text += '\n[takes."a30_m0.5_high_excerpt"]\nsplit = "train"\nobject_total_mass_kg = 0.2268\n'
    (d / "motive.toml").write_text(text)


def with_recording(d: Path, name: str = "HHHHH"):
    copy_tree(TAKE, d / "rec" / name)


def with_manifest(d: Path):
    shutil.copy(REPO / "data/packages-v1/manifest.json", d / "manifest.json")


IMPORT = ["data", "import-motive", str(MOTIVE_TAKE), "--out", "out", "--config", "motive.toml"]
BASE = str(REPO / "configs/scenes/calibrated-coarse-soft-film.toml")
MANIFEST_SCENE = ["scene", "from-manifest", "manifest.json", "--base", BASE, "--out", "scene.toml"]


# ---- cases --------------------------------------------------------------------------------------


@dataclass
class Case:
    name: str
    args: list
    setup: Callable[[Path], None] = lambda d: None
    code: int = 2
    words: list = field(default_factory=list)
    stdout: str = "null"  # null | full | closed
    stderr: str = "pipe"  # pipe | full | closed
    signal: Optional[tuple] = None  # (signal number, seconds after the start)
    timeout: float = 60.0
    # "unchanged": the folder must be exactly as it was; "inputs": files that were there must be
    # unchanged, new files are allowed (a command that finished its work).
    keep: str = "unchanged"
    check: Optional[Callable[[Path], Optional[str]]] = None
    group: str = "fresh"


def option_cases() -> list:
    """Every numeric option of every command given values it must refuse."""
    garbage = ["abc", "", "1e999", "18446744073709551616"]
    floats = ["nan", "inf", "-inf"]
    table = [
        # (name, prefix args, setup, option, kind, extra bad values)
        ("eval", ["eval", "run"], with_run, "--episodes", "int", ["0", "-1", "100000000000"]),
        ("eval", ["eval", "run", "--episodes", "2"], with_run, "--seed", "int", ["-1"]),
        ("eval", ["eval", "run", "--episodes", "2"], with_run, "--scripted", "float", ["-1", "0"]),
        ("eval", ["eval", "run", "--episodes", "2"], with_run, "--profile", "float", ["-1", "0"]),
        ("export", ["export", "run", "--out", "p.onnx"], with_run, "--verify", "int",
         ["0", "-1", "1000000000000"]),
        ("export", ["export", "run", "--out", "p.onnx"], with_run, "--latency", "int",
         ["0", "-1", "1000000000000"]),
        ("train", ["train", "tiny.toml", "--quiet"], with_tiny, "--stop-after", "int", ["0", "-1"]),
        ("simulate", ["simulate", str(TAKE), "--out", "out", "--params", "quick.toml"], with_quick,
         "--seconds", "float", ["-1", "0", "1e300"]),
        ("simulate", ["simulate", str(TAKE), "--out", "out", "--seconds", "0.01"], with_quick,
         "--frames-every", "int", ["0", "-1", "1000000000000000"]),
        ("simulate", ["simulate", str(TAKE), "--out", "out", "--seconds", "0.01"], with_quick,
         "--png-every", "float", ["-1", "0", "1e-300"]),
        ("simulate", ["simulate", str(TAKE), "--out", "out", "--seconds", "0.01"], with_quick,
         "--between", "int", ["-1", "100000", "3074457345618258603"]),
        ("simulate", ["simulate", str(TAKE), "--out", "out", "--seconds", "0.01"], with_quick,
         "--grid", "grid", ["0x0", "1x1", "100000x100000", "5x", "x5", "5x5x5", "-5x5"]),
        ("calibrate", ["calibrate", "calibrate.toml"], with_calibration, "--iterations", "int",
         ["0", "-1", "1000000000"]),
        ("calibrate", ["calibrate", "calibrate.toml"], with_calibration, "--max-seconds", "float",
         ["0", "-1"]),
        ("posterior", ["posterior", "calibrate.toml"], with_calibrated, "--samples", "int",
         ["0", "-1", "1000000000000"]),
        ("posterior", ["posterior", "calibrate.toml"], with_calibrated, "--burn-in", "int",
         ["-1", "1000000000000"]),
        ("posterior", ["posterior", "calibrate.toml"], with_calibrated, "--thin", "int",
         ["0", "-1", "1000000000000"]),
        ("posterior", ["posterior", "calibrate.toml"], with_calibrated, "--epsilon-quantile",
         "float", ["0", "-1", "1.5"]),
        ("posterior", ["posterior", "calibrate.toml"], with_calibrated, "--epsilon-loss", "float",
         ["-1", "0"]),
        ("posterior", ["posterior", "calibrate.toml"], with_calibrated, "--recover", "int",
         ["0", "-1", "1000000"]),
        ("posterior", ["posterior", "calibrate.toml"], with_calibrated, "--validate", "int",
         ["0", "-1", "1000000000000"]),
        ("posterior", ["posterior", "calibrate.toml"], with_calibrated, "--spread", "float",
         ["0", "-1", "10"]),
        ("bench", ["bench", "sim", "--grid", "6x7", "--envs", "1"], None, "--seconds", "float",
         ["-1", "1e9"]),
        ("bench", ["bench", "sim", "--grid", "6x7", "--seconds", "0.1"], None, "--envs", "list",
         ["0", "-1", "1000000000000", "1,,2"]),
        ("bench", ["bench", "sim", "--envs", "1", "--seconds", "0.1"], None, "--grid", "grid",
         ["0x0", "1x1", "100000x100000", "5x", "6x7,"]),
        ("bench", ["bench", "sim", "--grid", "6x7", "--envs", "1", "--seconds", "0.1"], None,
         "--seed", "int", ["-1"]),
        ("bench", ["bench", "ppo", "--env-steps", "0", "--minibatches", "1"], None, "--minibatch",
         "int", ["0", "-1", "1000000000000"]),
        ("bench", ["bench", "ppo", "--env-steps", "0"], None, "--minibatches", "int",
         ["0", "-1", "1000000000000"]),
        ("bench", ["bench", "ppo", "--env-steps", "0", "--minibatches", "1"], None, "--obs-dim",
         "int", ["0", "-1", "1000000000000"]),
        ("bench", ["bench", "ppo", "--env-steps", "0", "--minibatches", "1"], None, "--action-dim",
         "int", ["0", "-1", "1000000000000"]),
        ("bench", ["bench", "ppo", "--env-steps", "0", "--minibatches", "1"], None, "--hidden",
         "list", ["0", "-1", "1000000000000", "16,,16"]),
        ("bench", ["bench", "ppo", "--minibatches", "1", "--minibatch", "64"], None, "--env-steps",
         "int", ["-1", "1000000000000"]),
        ("bench", ["bench", "ppo", "--minibatches", "1", "--minibatch", "64"], None, "--num-envs",
         "int", ["0", "-1", "1000000000000"]),
        ("scene", MANIFEST_SCENE, with_manifest, "--max-vertices", "int",
         ["0", "-1", "1", "1000000000000"]),
        ("eval", ["eval", "--params", "quick.toml", "--data", str(DATASET), "--out", "out"],
         with_quick, "--draws", "int", ["0", "-1", "1000000000000"]),
        ("eval", ["eval", "--params", "quick.toml", "--data", str(DATASET), "--out", "out"],
         with_quick, "--perturb", "float", ["-100", "-1000", "1e300"]),
    ]
    cases = []
    for command, prefix, setup, option, kind, extra in table:
        values = list(garbage) + list(extra)
        if kind in ("float", "list"):
            values += floats
        seen = set()
        for value in values:
            if value in seen:
                continue
            seen.add(value)
            # Every value reaches the option (numeric options take `-inf` and `-5x5` too), so
            # the refusal names the option.
            cases.append(
                Case(
                    name=f"{command} {option} {value!r}",
                    args=[*prefix, option, value],
                    setup=setup or (lambda d: None),
                    words=[option],
                    timeout=90.0,
                )
            )
    return cases


def number_keys(text: str):
    """`(line, key, value)` of every `key = <number>` line of a TOML text (inline comments kept)."""
    for line in text.splitlines():
        m = re.match(r"^(\s*)([a-z_0-9]+)\s*=\s*(-?[0-9][0-9eE.+\-]*)(\s*(#.*)?)$", line)
        if m:
            yield line, m.group(2), m.group(3)


def key_cases() -> list:
    """Every number of the tiny configs of each command replaced by a value it must refuse."""
    cases = []
    targets = [
        ("train", TINY_CARTPOLE, with_tiny, ["train", "tiny.toml", "--quiet", "--no-export"],
         ["nan", "inf", '"7"', "-1", "1e30"]),
        ("simulate", quick_scene_text(), with_quick,
         ["simulate", str(TAKE), "--params", "quick.toml", "--seconds", "0.01", "--out", "out"],
         ["nan", "-inf", '"7"']),
        ("calibrate", calibration_text(), with_calibration, ["calibrate", "calibrate.toml"],
         ["nan", '"7"', "-1", "1e30"]),
        ("optimize", optimize_text(), with_optimize, ["optimize", "optimize.toml", "--quiet"],
         ["nan", '"7"', "-1", "1e30"]),
        ("seal", seal_text(), with_seal, ["seal", "fit", "seal.toml"], ["nan", '"7"', "-1"]),
        ("import", (REPO / "configs/import/motive.toml").read_text(), with_motive, IMPORT,
         ["nan", '"7"', "-1"]),
    ]
    # Values that are legitimately any number: refusing them would be wrong.
    any_sign = {"gravity_m_s2", "seed", "extra_mass_kg", "angle_deg", "init_log_std"}
    for command, text, setup, args, values in targets:
        for line, key, old in number_keys(text):
            for value in values:
                if value in ("-1", "1e30", "-inf") and (key in any_sign or key.endswith("_deg")):
                    continue
                if value == "1e30" and key in ("lower", "upper"):
                    continue
                new = line.replace(f"= {old}", f"= {value}", 1)
                if new == line:
                    continue

                def setup_case(d, setup=setup, line=line, new=new):
                    setup(d, line, new)

                cases.append(
                    Case(
                        name=f"{command} config {key} = {value}",
                        args=list(args),
                        setup=setup_case,
                        words=[key],
                        timeout=90.0,
                    )
                )
    return cases


def file_cases() -> list:
    """Config, run and data files that are missing, empty, binary, folders, devices or loops."""
    cases = []
    targets = [
        ("train", ["train", "X", "--quiet", "--no-export"]),
        ("calibrate", ["calibrate", "X"]),
        ("posterior", ["posterior", "X"]),
        ("optimize", ["optimize", "X"]),
        ("seal", ["seal", "fit", "X"]),
        ("simulate --params", ["simulate", str(TAKE), "--params", "X", "--seconds", "0.01",
                               "--out", "out"]),
        ("eval --params", ["eval", "--params", "X", "--data", str(DATASET), "--out", "out"]),
        ("import --config", ["data", "import-motive", str(MOTIVE_TAKE), "--out", "out",
                             "--config", "X"]),
        ("scene manifest", ["scene", "from-manifest", "X", "--base", BASE, "--out", "s.toml"]),
        ("scene --base", ["scene", "from-manifest", "manifest.json", "--out", "s.toml", "--base",
                          "X"]),
        ("bench sim --scene", ["bench", "sim", "--grid", "6x7", "--envs", "1", "--seconds", "0.1",
                               "--scene", "X"]),
        ("eval --policy", ["eval", "--policy", "X", "--episodes", "2"]),
        ("eval run", ["eval", "X", "--episodes", "2"]),
        ("export run", ["export", "X"]),
        ("train --resume", ["train", "--resume", "X"]),
        ("simulate recording", ["simulate", "X", "--seconds", "0.01", "--out", "out"]),
    ]

    def kinds():
        def missing(d):
            pass

        def empty(d):
            (d / "X").write_text("")

        def binary(d):
            (d / "X").write_bytes(bytes(range(256)) * 4)

        def bom_garbage(d):
            (d / "X").write_bytes(b"\xef\xbb\xbf[[[\n")

        def folder(d):
            (d / "X").mkdir()

        def loop(d):
            os.symlink("X", d / "X")

        def dangling(d):
            os.symlink("nowhere", d / "X")

        def zero(d):
            os.symlink("/dev/zero", d / "X")

        def huge_line(d):
            (d / "X").write_text("a" * 5_000_000)

        def unreadable(d):
            (d / "X").write_text("x = 1\n")
            os.chmod(d / "X", 0)

        return [("missing", missing), ("empty", empty), ("binary", binary),
                ("BOM and garbage", bom_garbage), ("a folder", folder), ("a symlink loop", loop),
                # A FIFO is left out: reading one waits for its writer, as `<(...)` needs.
                ("a dangling symlink", dangling), ("/dev/zero", zero),
                ("one 5 MB line", huge_line), ("unreadable", unreadable)]

    for label, args in targets:
        for kind, make in kinds():
            if kind == "unreadable" and os.geteuid() == 0:
                continue  # root reads anything

            def setup(d, make=make, label=label):
                if label.startswith("scene --base"):
                    with_manifest(d)
                make(d)

            cases.append(Case(name=f"{label}: {kind}", args=list(args), setup=setup, words=["X"],
                              timeout=30.0))
    return cases


def full(path: str) -> Optional[str]:
    return None


def output_cases() -> list:
    """Outputs that are inputs, devices, files where folders go, full or closed streams, locks."""
    cases = []
    quick = ["--params", "quick.toml", "--seconds", "0.01"]
    # Output paths that are one of the command's own inputs.
    cases += [
        Case("scene --out over its manifest", ["scene", "from-manifest", "manifest.json", "--base",
                                               BASE, "--out", "manifest.json"], with_manifest,
             words=["manifest.json"]),
        Case("scene --out over its base", ["scene", "from-manifest", "manifest.json", "--out",
                                           "base.toml", "--base", "base.toml"],
             lambda d: (with_manifest(d), with_quick(d, name="base.toml")), words=["base.toml"]),
        Case("scene --out to /dev/null", [*MANIFEST_SCENE[:5], "--out", "/dev/null"],
             with_manifest, words=["/dev/null"]),
        Case("scene --out into a missing folder", [*MANIFEST_SCENE[:5], "--out", "no/s.toml"],
             with_manifest, words=["no/s.toml"]),
        Case("scene --out a folder", [*MANIFEST_SCENE[:5], "--out", "f"],
             lambda d: (with_manifest(d), (d / "f").mkdir()), words=["f"]),
        Case("seal --write-params over its config", ["seal", "fit", "seal.toml", "--write-params",
                                                     "seal.toml"], with_seal,
             words=["seal.toml"]),
        Case("seal --write-params to /dev/null", ["seal", "fit", "seal.toml", "--write-params",
                                                  "/dev/null"], with_seal, words=["/dev/null"]),
        Case("seal --write-params into a missing folder",
             ["seal", "fit", "seal.toml", "--write-params", "no/x.toml"], with_seal,
             words=["no/x.toml"]),
        Case("seal out over its scene", ["seal", "fit", "seal.toml"],
             lambda d: with_seal(d, 'out = "out"', f'out = "{STUDY.parent}"'),
             words=["seal.toml"]),
        Case("calibrate --write-params over its config",
             ["calibrate", "calibrate.toml", "--write-params", "calibrate.toml"],
             with_calibration, words=["--write-params", "calibration config"]),
        Case("calibrate --write-params over its scene",
             ["calibrate", "calibrate.toml", "--write-params", "./quick.toml"],
             with_calibration, words=["--write-params", "sim.preset"]),
        Case("calibrate --write-params a folder",
             ["calibrate", "calibrate.toml", "--write-params", "."], with_calibration,
             words=["--write-params"]),
        Case("calibrate --write-params into the dataset",
             ["calibrate", "calibrate.toml", "--write-params", str(TAKE / "meta.toml")],
             with_calibration, words=["--write-params", "dataset"]),
        Case("calibrate --out where its config is best.toml",
             ["calibrate", "out/best.toml"],
             lambda d: (with_calibration(d), (d / "out").mkdir(),
                        shutil.move(d / "calibrate.toml", d / "out/best.toml")),
             words=["out/best.toml", "calibration config"]),
        Case("calibrate --out where its scene is calibrated.toml",
             ["calibrate", "calibrate.toml"],
             lambda d: (with_calibration(d, 'preset = "quick.toml"',
                                         'preset = "out/calibrated.toml"'),
                        (d / "out").mkdir(), with_quick(d, name="out/calibrated.toml")),
             words=["out/calibrated.toml", "sim.preset"]),
        Case("calibrate --out a file", ["calibrate", "calibrate.toml", "--out", "calibrate.toml"],
             with_calibration, words=["calibrate.toml", "is a file"]),
        Case("posterior --out a file", ["posterior", "calibrate.toml", "--out", "calibrate.toml"],
             with_calibrated, words=["calibrate.toml"]),
        Case("posterior --out over its calibration's log",
             ["posterior", "calibrate.toml", "--out", "out", "--samples", "10", "--burn-in", "0"],
             with_calibrated, keep="inputs", code=None),
        Case("simulate --out a file", ["simulate", str(TAKE), *quick, "--out", "quick.toml"],
             with_quick, words=["quick.toml"]),
        Case("simulate --out into its own recording",
             ["simulate", "rec/HHHHH", "--seconds", "0.01", "--out", "rec/HHHHH"],
             with_recording, code=None, keep="inputs"),
        Case("simulate --out into /proc", ["simulate", str(TAKE), *quick, "--out", "/proc/x"],
             with_quick, words=["/proc/x"]),
        Case("eval --params --out a file",
             ["eval", "--params", "quick.toml", "--data", str(DATASET), "--out", "quick.toml"],
             with_quick, words=["quick.toml"]),
        Case("optimize --out a file", ["optimize", "optimize.toml", "--out", "optimize.toml"],
             with_optimize, words=["optimize.toml"]),
        Case("import --out a file", [*IMPORT[:3], "--out", "motive.toml", "--config",
                                     "motive.toml"], with_motive, words=["motive.toml"]),
        Case("import --out over the take's folder", ["data", "import-motive", "take/x.csv",
                                                     "--out", "take", "--config", "motive.toml"],
             lambda d: (with_motive(d), (d / "take").mkdir(),
                        (d / "take/x.csv").write_bytes(gzip.decompress(MOTIVE_TAKE.read_bytes()))),
             code=None, keep="inputs"),
        Case("export --out over the run's state",
             ["export", "run", "--out", "run/checkpoints/update_000004/state.json"], with_run,
             words=["--out", "run"]),
        Case("export --out a folder", ["export", "run", "--out", "run"], with_run,
             words=["--out"]),
        Case("export --out /dev/null", ["export", "run", "--out", "/dev/null"], with_run,
             words=["/dev/null"]),
        Case("train --out-dir a file", ["train", "tiny.toml", "--out-dir", "tiny.toml"],
             with_tiny, words=["tiny.toml"]),
        Case("train --name with a slash", ["train", "tiny.toml", "--name", "a/b"], with_tiny,
             words=["--name"]),
        Case("train --name of 300 characters", ["train", "tiny.toml", "--name", "n" * 300],
             with_tiny, words=["File name too long"]),
        Case("train --name dot", ["train", "tiny.toml", "--name", "."], with_tiny,
             words=["--name"]),
        Case("train --name with a NUL-like escape", ["train", "tiny.toml", "--name", "a\nb"],
             with_tiny, words=["--name"]),
    ]
    # Locks held by a live process (this probe).
    pid = os.getpid()

    def held(folder):
        def setup(d):
            (d / folder).mkdir(parents=True, exist_ok=True)
            (d / folder / ".lock").write_text(f"{pid}\n")
        return setup

    cases += [
        Case("train into a held run", ["train", "tiny.toml", "--quiet"],
             lambda d: (with_tiny(d), held("runs/tiny")(d)), words=["in use by process"]),
        Case("resume a held run", ["train", "--resume", "run", "--quiet"],
             lambda d: (with_run(d), held("run")(d)), words=["in use by process"]),
        Case("calibrate into a held folder", ["calibrate", "calibrate.toml"],
             lambda d: (with_calibration(d), held("out")(d)), words=["in use by process"]),
        Case("lock file with garbage", ["calibrate", "calibrate.toml"],
             lambda d: (with_calibration(d), (d / "out").mkdir(),
                        (d / "out/.lock").write_text("not a pid\n")), words=[".lock"]),
    ]
    # Full or closed streams on commands that finish quickly: exit 2 naming standard output with
    # the work done, or a quiet success for a reader that went away.
    quick_runs = [
        ("--help", ["--help"], None),
        ("version", ["--version"], None),
        ("eval", ["eval", "run", "--episodes", "2"], with_run),
        ("eval --json", ["eval", "run", "--episodes", "2", "--json"], with_run),
        ("export --json", ["export", "run", "--out", "p.onnx", "--json", "--verify", "10"],
         with_run),
        ("bench sim --json", ["bench", "sim", "--grid", "6x7", "--envs", "1", "--seconds", "0.2",
                              "--workload", "command", "--json"], None),
        ("bench ppo", ["bench", "ppo", "--env-steps", "100", "--minibatches", "1", "--minibatch",
                       "64", "--backend", "ndarray", "--json"], None),
        ("simulate", ["simulate", str(TAKE), *quick, "--out", "out"], with_quick),
        ("scene", MANIFEST_SCENE, with_manifest),
        ("train", ["train", "tiny.toml"], with_tiny),
    ]
    for label, args, setup in quick_runs:
        setup = setup or (lambda d: None)
        cases.append(Case(f"{label} > /dev/full", list(args), setup, code=2,
                          words=["standard output"], stdout="full", keep="inputs",
                          timeout=120.0))
        cases.append(Case(f"{label} | closed pipe", list(args), setup, code=0, stdout="closed",
                          keep="inputs", timeout=120.0))
    cases += [
        Case("error with stderr full", ["train", "missing.toml"], code=2, stderr="full"),
        Case("usage error with stderr full", ["train", "--bogus"], code=2, stderr="full"),
        Case("eval of nothing with stderr full", ["eval", "norun"], code=2, stderr="full"),
    ]
    # Signals: a command stopped leaves its output folder as it was.
    for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        cases.append(Case(f"simulate stopped by {sig.name}",
                          ["simulate", str(TAKE), "--params", "quick.toml", "--out", "out"],
                          with_quick, code=130, signal=(sig, 1.5),
                          check=lambda d: None if not any((d / "out").rglob("*.png")) else
                          "pictures left in out/"))
    return cases


def misc_cases() -> list:
    """Option combinations and values that would do nothing, or the wrong thing, silently."""
    quick = ["--params", "quick.toml"]
    return [
        Case("bench sim unknown workload", ["bench", "sim", "--workload", "fast"],
             words=["--workload"]),
        Case("bench sim unknown scene", ["bench", "sim", "--scene", "nosuch"], words=["nosuch"]),
        Case("bench ppo unknown backend", ["bench", "ppo", "--backend", "cuda"],
             words=["cuda"]),
        Case("bench ppo empty hidden", ["bench", "ppo", "--hidden", ""], words=["--hidden"]),
        Case("eval unknown recorded level", ["eval", "run", "--recorded", "fast"], with_run,
             words=["--recorded"]),
        Case("eval unknown split", ["eval", "--params", "quick.toml", "--split", "nope"],
             with_quick, words=["nope"]),
        Case("eval --set without --config", ["eval", "run", "--set", "a=1"], with_run,
             words=["--set"]),
        Case("train --set unknown key", ["train", "tiny.toml", "--set", "ppo.gama=1"], with_tiny,
             words=["gama"]),
        Case("train --set without =", ["train", "tiny.toml", "--set", "ppo.gamma"], with_tiny,
             words=["ppo.gamma"]),
        Case("train --set a table", ["train", "tiny.toml", "--set", "ppo=1"], with_tiny,
             words=["ppo"]),
        Case("train --set nan", ["train", "tiny.toml", "--set", "ppo.gamma=nan"], with_tiny,
             words=["gamma"]),
        Case("train --set twice", ["train", "tiny.toml", "--set", "ppo.gamma=0.9", "--set",
                                   "ppo.gamma=0.8"], with_tiny, words=["ppo.gamma"]),
        Case("train resume and config", ["train", "tiny.toml", "--resume", "run"],
             lambda d: (with_tiny(d), with_run(d)), words=["--resume"]),
        Case("train duplicate key", ["train", "tiny.toml"],
             lambda d: with_tiny(d, "gamma = 0.99", "gamma = 0.99\ngamma = 0.9"),
             words=["gamma"]),
        Case("train unknown env", ["train", "tiny.toml"],
             lambda d: with_tiny(d, 'env = "CartPole-v1"', 'env = "Nope-v0"'), words=["Nope-v0"]),
        Case("train unknown activation", ["train", "tiny.toml"],
             lambda d: with_tiny(d, 'activation = "tanh"', 'activation = "gelu9"'),
             words=["gelu9"]),
        Case("train empty hidden layer", ["train", "tiny.toml"],
             lambda d: with_tiny(d, "actor_hidden = [16, 16]", "actor_hidden = [16, 0]"),
             words=["actor_hidden"]),
        Case("train minibatches beyond the batch", ["train", "tiny.toml"],
             lambda d: with_tiny(d, "minibatches = 2", "minibatches = 100000"),
             words=["minibatches"]),
        Case("train total steps below one rollout", ["train", "tiny.toml"],
             lambda d: with_tiny(d, "total_steps = 1024", "total_steps = 1"),
             words=["total_steps"]),
        Case("calibrate lower above upper", ["calibrate", "calibrate.toml"],
             lambda d: with_calibration(d, "lower = 1.0e4", "lower = 1.0e7"), words=["lower"]),
        Case("calibrate log scale with zero lower", ["calibrate", "calibrate.toml"],
             lambda d: with_calibration(d, "lower = 1.0e4", "lower = 0.0"), words=["lower"]),
        Case("calibrate unknown parameter", ["calibrate", "calibrate.toml"],
             lambda d: with_calibration(d, 'name = "k_tri_e"', 'name = "k_nope"'),
             words=["k_nope"]),
        Case("calibrate unknown trajectory", ["calibrate", "calibrate.toml", "--trajectories",
                                              "ZZZZZ"], with_calibration, words=["ZZZZZ"]),
        Case("calibrate no parameters", ["calibrate", "calibrate.toml"],
             lambda d: (with_calibration(d), (d / "calibrate.toml").write_text(
                 (d / "calibrate.toml").read_text().split("[[param]]")[0])), words=["param"]),
        Case("calibrate missing dataset", ["calibrate", "calibrate.toml"],
             lambda d: with_calibration(d, str(DATASET), "/nonexistent/data"),
             words=["/nonexistent/data"]),
        Case("calibrate preset missing", ["calibrate", "calibrate.toml"],
             lambda d: with_calibration(d, 'preset = "quick.toml"', 'preset = "none.toml"'),
             words=["none.toml"]),
        Case("posterior --from missing", ["posterior", "calibrate.toml", "--from", "nope"],
             with_calibrated, words=["nope"]),
        Case("posterior --from holding a garbage log", ["posterior", "calibrate.toml"],
             lambda d: (with_calibrated(d), (d / "out/evaluations.csv").write_text("a,b\n1\n")),
             words=["evaluations.csv"]),
        Case("posterior --replays missing", ["posterior", "calibrate.toml", "--replays", "no.csv"],
             with_calibrated, words=["no.csv"]),
        Case("simulate a recording missing tool.csv", ["simulate", "rec/HHHHH", "--seconds",
                                                        "0.01", "--out", "out"],
             lambda d: (with_recording(d), os.remove(d / "rec/HHHHH/tool.csv")),
             words=["tool.csv"]),
        Case("simulate a recording with a truncated tool.csv",
             ["simulate", "rec/HHHHH", "--seconds", "0.01", "--out", "out"],
             lambda d: (with_recording(d), (d / "rec/HHHHH/tool.csv").write_text(
                 (d / "rec/HHHHH/tool.csv").read_text()[:200])), words=["tool.csv"]),
        Case("simulate a recording with nan in object.csv",
             ["simulate", "rec/HHHHH", "--seconds", "0.01", "--out", "out"],
             lambda d: (with_recording(d), (d / "rec/HHHHH/object.csv").write_text(
                 re.sub(r"\n([^,\n]*),[^,\n]*", r"\n\1,nan",
                        (d / "rec/HHHHH/object.csv").read_text(), count=3))),
             words=["object.csv"]),
        Case("simulate --grid with --between", ["simulate", str(TAKE), *quick, "--grid", "6x7",
                                                "--between", "1"], with_quick,
             words=["--between"]),
        Case("simulate two positional", ["simulate", str(TAKE), str(TAKE)], words=[str(TAKE)]),
        Case("seal grid with one step", ["seal", "fit", "seal.toml"],
             lambda d: with_seal(d, "steps = 2", "steps = 1"), words=["steps"]),
        Case("seal grid min above max", ["seal", "fit", "seal.toml"],
             lambda d: with_seal(d, "min = 20.0", "min = 40.0"), words=["min"]),
        Case("seal grid of a billion steps", ["seal", "fit", "seal.toml"],
             lambda d: with_seal(d, "steps = 2", "steps = 1000000000"), words=["steps"]),
        Case("optimize elites above population", ["optimize", "optimize.toml"],
             lambda d: with_optimize(d, "elites = 4", "elites = 40"), words=["elites"]),
        Case("optimize unknown key", ["optimize", "optimize.toml"],
             lambda d: with_optimize(d, "seed = 1 ", "sede = 1 "), words=["sede"]),
        Case("optimize quantile above one", ["optimize", "optimize.toml"],
             lambda d: with_optimize(d, "quantile = 0.9", "quantile = 1.5"), words=["quantile"]),
        Case("import a take listed nowhere", ["data", "import-motive", "zz.csv", "--out", "out",
                                              "--config", "motive.toml"],
             lambda d: (with_motive(d), (d / "zz.csv").write_text("garbage\n")),
             words=['"zz"', "motive.toml"]),
        Case("import the same take twice", [*IMPORT[:3], str(MOTIVE_TAKE), *IMPORT[3:]],
             with_motive, words=["twice"]),
        Case("import a truncated gzip", ["data", "import-motive", "a30_m0.5_high.csv.gz", "--out",
                                         "out", "--config", "motive.toml"],
             lambda d: (with_motive(d), (d / "a30_m0.5_high.csv.gz").write_bytes(
                 MOTIVE_TAKE.read_bytes()[:3000])), words=["a30_m0.5_high.csv.gz"]),
        Case("import --robot count mismatch", [*IMPORT, "--robot", "r1.csv", "r2.csv"],
             lambda d: with_motive(d), words=["r1.csv", "_robot.csv"]),
        Case("scene manifest with garbage JSON", ["scene", "from-manifest", "m.json", "--base", BASE,
                                                  "--out", "s.toml"],
             lambda d: (d / "m.json").write_text('{"packages": [1, 2'), words=["m.json"]),
        Case("scene manifest of an empty object", ["scene", "from-manifest", "m.json", "--base", BASE,
                                                   "--out", "s.toml"],
             lambda d: (d / "m.json").write_text("{}"), words=["m.json"]),
        Case("eval --policy with garbage ONNX", ["eval", "--policy", "p.onnx", "--episodes", "2"],
             lambda d: (d / "p.onnx").write_bytes(b"\x08\x07garbage" * 100), words=["p.onnx"]),
        Case("eval a run with a truncated checkpoint", ["eval", "run", "--episodes", "2"],
             lambda d: (with_run(d), (d / "run/checkpoints/update_000004/model.bpk").write_bytes(
                 (d / "run/checkpoints/update_000004/model.bpk").read_bytes()[:100])),
             words=["model.bpk"]),
        Case("eval a run whose checkpoint is a folder", ["eval", "run", "--episodes", "2"],
             lambda d: (with_run(d), os.remove(d / "run/checkpoints/update_000004/model.bpk"),
                        (d / "run/checkpoints/update_000004/model.bpk").mkdir()),
             words=["model.bpk"]),
        Case("train --resume with a state.json of garbage", ["train", "--resume", "run"],
             lambda d: (with_run(d), (d / "run/checkpoints/update_000004/state.json").write_text(
                 "{")), words=["state.json"]),
        Case("train --resume of a folder without checkpoints", ["train", "--resume", "run"],
             lambda d: (with_run(d), shutil.rmtree(d / "run/checkpoints")),
             words=["checkpoints"]),
        Case("export a run without config.toml", ["export", "run"],
             lambda d: (with_run(d), os.remove(d / "run/config.toml")), words=["config.toml"]),
        Case("unknown command", ["fly"], words=["fly"]),
        Case("no command", [], words=["Usage"]),
        Case("non-UTF-8 argument", ["train", b"\xff\xfe.toml"], words=[".toml"]),
    ]


def issue_cases() -> list:
    """The cases of the hostile report the suite fixed, each tried again."""
    quick = ["--params", "quick.toml", "--seconds", "0.01"]
    cases = [
        Case("eval --json > /dev/full", ["eval", "run", "--episodes", "2", "--json"], with_run,
             stdout="full", words=["standard output"]),
        Case("train > /dev/full exports the run", ["train", "tiny.toml"], with_tiny,
             stdout="full", words=["standard output"], keep="inputs", timeout=120,
             check=lambda d: None if (d / "runs/tiny/policy.onnx").exists() else "not exported"),
        Case("train | closed pipe exports the run", ["train", "tiny.toml"], with_tiny,
             stdout="closed", code=0, keep="inputs", timeout=120,
             check=lambda d: None if (d / "runs/tiny/policy.onnx").exists() else "not exported"),
        Case("eval norun 2> /dev/full", ["eval", "norun"], stderr="full"),
        Case("train 2>&1 | head -c 10 exports the run", ["train", "tiny.toml"], with_tiny,
             stdout="closed", stderr="closed", code=0, keep="inputs", timeout=120,
             check=lambda d: None if (d / "runs/tiny/policy.onnx").exists() else "not exported"),
        Case("export over a checkpoint", ["export", "run", "--out",
                                          "run/checkpoints/update_000004/model.bpk"], with_run,
             words=["would destroy the run"]),
        Case("export over config.toml", ["export", "run", "--out", "run/config.toml"], with_run,
             words=["configuration"]),
        Case("calibrate --write-params own config", ["calibrate", "calibrate.toml",
                                                     "--write-params", "calibrate.toml"],
             with_calibration, words=["calibration config"]),
        Case("calibrate --write-params nodir", ["calibrate", "calibrate.toml", "--write-params",
                                                "nodir/x.toml"], with_calibration,
             words=["nodir"]),
        Case("calibrate --write-params /dev/null", ["calibrate", "calibrate.toml",
                                                    "--write-params", "/dev/null"],
             with_calibration, words=["/dev/null"]),
        Case("train --name of 300 chars leaves no runs/", ["train", "tiny.toml", "--name",
                                                          "x" * 300], with_tiny,
             words=["File name too long"]),
        Case("posterior --epsilon-loss below the best loss",
             ["posterior", "calibrate.toml", "--epsilon-loss", "0.0000001"], with_calibrated,
             words=["--epsilon-loss"]),
        Case("seal fit without failure takes", ["seal", "fit", "seal.toml"],
             lambda d: (with_seal(d), (d / "ds/manifest.toml").write_text(
                 (d / "ds/manifest.toml").read_text().replace("failure = true", "failure = false"))),
             words=["at least one failure take"]),
        Case("seal fit into a file", ["seal", "fit", "seal.toml"],
             lambda d: (with_seal(d), (d / "out").write_text("")), words=["is a file"]),
        Case("bench sim motionless counts no frozen lanes",
             ["bench", "sim", "--grid", "6x7", "--envs", "4", "--seconds", "0.3", "--workload",
              "motionless", "--json"], code=0, keep="inputs"),
        Case("bench ppo --num-envs 0", ["bench", "ppo", "--num-envs", "0"], words=["--num-envs"]),
        Case("optimize initial speed 100", ["optimize", "optimize.toml"],
             lambda d: with_optimize(d, "initial_speed_m_s = 0.5", "initial_speed_m_s = 100"),
             words=["initial_speed_m_s"]),
        Case("optimize horizon 1e6", ["optimize", "optimize.toml"],
             lambda d: with_optimize(d, "horizon_s = 3.5", "horizon_s = 1e6"),
             words=["horizon_s"]),
        Case("calibrate duplicate trajectories", ["calibrate", "calibrate.toml"],
             lambda d: with_calibration(d, 'trajectories = ["HHHHH"]',
                                        'trajectories = ["HHHHH", "HHHHH"]'),
             words=["trajectories"]),
        Case("tanh_scale on CartPole", ["train", "tiny.toml"],
             lambda d: with_tiny(d, 'action_transform = "clip"', 'action_transform = "tanh_scale"'),
             words=["action_transform"]),
        Case("resume with --name", ["train", "--resume", "run", "--name", "other"], with_run,
             words=["--name"]),
        Case("--help > /dev/full", ["--help"], stdout="full", words=["standard output"]),
        Case("bench sim --json > /dev/full names stdout",
             ["bench", "sim", "--grid", "6x7", "--envs", "1", "--seconds", "0.1", "--workload",
              "command", "--json"], stdout="full", words=["standard output"], keep="inputs"),
        Case("posterior --burn-in 1e12", ["posterior", "calibrate.toml", "--burn-in",
                                          "1000000000000"], with_calibrated, words=["--burn-in"]),
        Case("--set error cites the user's line", ["train", "tiny.toml", "--set", "ppo.gamma=2"],
             with_tiny, words=["gamma"]),
        Case("SIGTERM during simulate", ["simulate", str(TAKE), "--params", "quick.toml", "--out",
                                         "out"], with_quick, code=130,
             signal=(signal.SIGTERM, 1.5)),
    ]
    for case in cases:
        case.group = "issue"
    return cases + transport_issue_cases()


def transport_posterior(d: Path, rows: bytes):
    text = (REPO / "configs/train/transport-posterior.toml").read_text()
    text = text.replace('scene = "configs/', f'scene = "{REPO}/configs/')
    text = text.replace('recordings = "data/', f'recordings = "{REPO}/data/')
    old = 'posterior = "data/posteriors/coarse-soft-film"'
    assert old in text
    (d / "transport-posterior.toml").write_text(text.replace(old, 'posterior = "post/samples.csv"'))
    (d / "post").mkdir()
    (d / "post/samples.csv").write_bytes(rows)


def transport_issue_cases() -> list:
    rows = b"k_tri_e,k_spr_e,mu_con\n2000,30,0.5\n2000,30,1e6\n"
    manifest = REPO / "data/packages-v1/manifest.json"

    def zero_angles(d):
        text = manifest.read_text()
        m = re.search(r'"cup_angles_deg"\s*:\s*\[[^\]]*\]', text)
        if m is None:
            (d / "m.json").write_text(text)
            return
        (d / "m.json").write_text(text.replace(m.group(0), '"cup_angles_deg": [0, 0, 0, 0]'))

    def scene_edited(d):
        folder = d
        (folder / "scene.toml").write_text(quick_scene_text())
        with_tiny(folder)

    return [
        Case("posterior draw of 1e6", ["train", "transport-posterior.toml"],
             lambda d: transport_posterior(d, rows), words=["line 3", "mu_con"], group="issue"),
        Case("BOM in samples.csv accepted", ["train", "transport-posterior.toml", "--stop-after",
                                              "1", "--no-export", "--quiet"],
             lambda d: transport_posterior(d, b"\xef\xbb\xbf" + rows.replace(b",1e6", b",0.5")),
             code=0, keep="inputs", timeout=300, group="issue"),
        Case("manifest cup angles all zero", ["scene", "from-manifest", "m.json", "--base", BASE,
                                              "--out", "s.toml"], zero_angles, words=["m.json", "angles_deg"],
             group="issue"),
    ]


# ---- runner -------------------------------------------------------------------------------------


def snapshot(d: Path) -> dict:
    files = {}
    for root, dirs, names in os.walk(d, followlinks=False):
        for name in dirs + names:
            path = Path(root) / name
            rel = str(path.relative_to(d))
            st = os.lstat(path)
            if stat.S_ISLNK(st.st_mode):
                files[rel] = "link:" + os.readlink(path)
            elif stat.S_ISDIR(st.st_mode):
                files[rel] = "dir"
            elif stat.S_ISREG(st.st_mode):
                try:
                    files[rel] = hashlib.sha256(path.read_bytes()).hexdigest()
                except PermissionError:
                    files[rel] = f"unreadable:{st.st_size}:{st.st_mtime_ns}"
            else:
                files[rel] = f"special:{stat.S_IFMT(st.st_mode)}"
    return files


def limits():
    # A probe must not take the machine down: 8 GB of address space, a session of its own.
    resource.setrlimit(resource.RLIMIT_AS, (8 << 30, 8 << 30))
    os.setsid()


def run_case(rlpkg: Path, case: Case, base: Path) -> list:
    d = Path(tempfile.mkdtemp(dir=base))
    case.setup(d)
    before = snapshot(d)
    stdout = {"null": subprocess.DEVNULL, "full": open("/dev/full", "w"),
              "closed": subprocess.PIPE}[case.stdout]
    stderr_full = case.stderr in ("full", "closed")  # nothing to read either way
    stderr = open("/dev/full", "w") if case.stderr == "full" else subprocess.PIPE
    env = {k: v for k, v in os.environ.items() if k != "RUST_BACKTRACE"}
    env["RAYON_NUM_THREADS"] = "2"
    started = time.monotonic()
    child = subprocess.Popen([str(rlpkg), *case.args], cwd=d, stdin=subprocess.DEVNULL,
                             stdout=stdout, stderr=stderr, env=env, preexec_fn=limits)
    if case.stdout == "closed":
        child.stdout.close()
    if case.stderr == "closed":
        child.stderr.close()
    timed_out = False
    if case.signal:
        time.sleep(case.signal[1])
        if child.poll() is None:
            child.send_signal(case.signal[0])
    try:
        _, err = child.communicate(timeout=max(1.0, case.timeout - (time.monotonic() - started)))
    except subprocess.TimeoutExpired:
        timed_out = True
        os.killpg(child.pid, signal.SIGKILL)
        _, err = child.communicate()
    err = err or b""
    text = err.decode("utf-8", "replace")
    code = child.returncode
    problems = []
    if code is not None and (code == 101 or code < 0) and not timed_out:
        problems.append(("panic", f"exit {code}"))
    if "panicked" in text or "RUST_BACKTRACE" in text:
        problems.append(("panic", "panicked"))
    if timed_out:
        problems.append(("silent", f"still running after {case.timeout:.0f} s"))
    elif case.code is not None and code != case.code and not any(p[0] == "panic" for p in problems):
        kind = "silent" if code == 0 else "wrong code"
        problems.append((kind, f"exit {code}, expected {case.code}"))
    if case.code is None and code not in (0, 2) and not problems:
        problems.append(("wrong code", f"exit {code}, expected 0 or 2"))
    if not stderr_full and case.code not in (0, None) and not timed_out:
        for word in case.words:
            if word not in text:
                problems.append(("message", f"lacks `{word}`"))
    after = snapshot(d)
    changed = [p for p, h in before.items() if after.get(p) != h]
    if changed:
        problems.append(("clobbered", "changed or removed: " + ", ".join(sorted(changed)[:4])))
    if case.keep == "unchanged" and code != 0 and not timed_out:
        new = sorted(set(after) - set(before))
        if new:
            problems.append(("half-written", "left: " + ", ".join(new[:4])))
    if case.check and not timed_out:
        message = case.check(d)
        if message:
            problems.append(("lost", message))
    shutil.rmtree(d, ignore_errors=True)
    first = text.strip().splitlines()[-1] if text.strip() else ""
    return problems, code, first


def all_cases() -> list:
    return issue_cases() + option_cases() + key_cases() + file_cases() + output_cases() + misc_cases()


def main():
    global FIX
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rlpkg", default=str(REPO / "target/release/rlpkg"))
    parser.add_argument("--only", help="run only the cases whose name contains this")
    parser.add_argument("--group", choices=["issue", "fresh"], help="run only this group")
    parser.add_argument("--list", action="store_true", help="list the cases and exit")
    parser.add_argument("--verbose", action="store_true", help="print every case")
    args = parser.parse_args()
    cases = all_cases()
    if args.only:
        cases = [c for c in cases if args.only in c.name]
    if args.group:
        cases = [c for c in cases if c.group == args.group]
    if args.list:
        for case in cases:
            print(f"[{case.group}] {case.name}")
        print(f"{len(cases)} cases")
        return
    rlpkg = Path(args.rlpkg).resolve()
    with tempfile.TemporaryDirectory(prefix="hostile-") as base:
        base = Path(base)
        (base / "fixtures").mkdir()
        FIX = Fixtures(rlpkg, base / "fixtures")
        counts = {}
        failed = 0
        started = time.monotonic()
        for i, case in enumerate(cases):
            problems, code, last = run_case(rlpkg, case, base)
            for kind, _ in problems:
                counts[kind] = counts.get(kind, 0) + 1
            if problems:
                failed += 1
                what = "; ".join(f"{k}: {m}" for k, m in problems)
                print(f"FAIL [{case.group}] {case.name}: {what}\n     rlpkg {' '.join(map(str, case.args))[:160]}\n     {last[:300]}", flush=True)
            elif args.verbose:
                print(f"ok   [{case.group}] {case.name}: exit {code}: {last[:160]}", flush=True)
        print(f"{len(cases)} cases in {time.monotonic() - started:.0f} s: {len(cases) - failed} as "
              f"promised, {failed} not")
        for kind in ("panic", "silent", "clobbered", "half-written", "wrong code", "lost",
                     "message"):
            print(f"  {kind}: {counts.get(kind, 0)}")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
