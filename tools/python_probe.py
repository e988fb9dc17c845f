#!/usr/bin/env python3
"""Hostile-input probe of rlpkg's Python API: hundreds of bad or hostile arguments, files and call
orders across the package (environments, vector environments, the SB3 adapter, calibration,
ProfileReference, runs), as a new user would try them.

Every case runs in its own subprocess (`nice -n 15`, 60 s timeout, its own process group), in a
fresh temporary working folder, one at a time, with the Python that runs this script:

    python tools/python_probe.py --site SITE [--out DIR] [--only WORD ...]

`SITE` is a folder holding the built package (`SITE/rlpkg`, with its `_native` module), as the
Python tests use it (docs/python.md). Writes `results.json` and `report.md` (one line per case that is
not fine) into `--out` (default: a new temporary folder); exit status 1 when any case is not fine.

Verdicts: fine, crash, silent, wrong type, unclear, clobbered, refused (valid input refused).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

PY = sys.executable
MAIN = Path(__file__).resolve().parent.parent
SMALL = MAIN / "python/tests/transport-small.toml"
TINY = MAIN / "python/tests/calibrate-tiny.toml"
DATA = MAIN / "data/deformable-sim-real"
TIMEOUT = 60
# Inputs outside the temporary folders that no case may change.
PROTECTED = [SMALL, TINY, MAIN / "configs/train/cartpole.toml", MAIN / "configs/train/transport.toml"]

SMALL_TEXT = SMALL.read_text()
SMALL_ABS = SMALL_TEXT.replace('"data/deformable-sim-real"', f'"{DATA}"')
assert SMALL_ABS != SMALL_TEXT
TINY_TEXT = TINY.read_text()
TINY_ABS = TINY_TEXT.replace('data = "data/deformable-sim-real"', f'data = "{DATA}"').replace(
    "max_seconds = 1.0", "max_seconds = 0.2"
)
assert TINY_ABS != TINY_TEXT
SMC_ABS = TINY_ABS.replace(
    "[optimiser]\niterations = 1\nbatch_size = 2\ninitial_points = 3\nseed = 0\n",
    "[smc]\nparticles = 6\nmoves = 1\nmax_stages = 2\nseed = 0\n",
)
assert "[smc]" in SMC_ABS
RATE_TABLE = "\n[transport.profile_rate]\nlimits_scale = 1.0\nmax_rate = 2.0\nmax_rate_change_per_s = 4.0\n"


def tf_event(step: int, tag: str, value: float) -> bytes:
    """One TFRecord holding a TensorBoard scalar event (CRCs zero: the reader skips them)."""

    def varint(n):
        out = b""
        while True:
            b = n & 0x7F
            n >>= 7
            if n:
                out += bytes([b | 0x80])
            else:
                return out + bytes([b])

    def field(num, wire, payload):
        key = varint((num << 3) | wire)
        if wire == 2:
            return key + varint(len(payload)) + payload
        return key + payload

    tagb = tag.encode()
    val = field(1, 2, tagb) + field(2, 5, struct.pack("<f", value))
    summary = field(1, 2, val)
    event = field(1, 1, struct.pack("<d", 1.0)) + field(2, 0, varint(step)) + field(5, 2, summary)
    return struct.pack("<Q", len(event)) + b"\0" * 4 + event + b"\0" * 4


GOOD_EVENTS = tf_event(1, "charts/episodic_return", 10.0) + tf_event(2, "charts/episodic_return", 20.0)

# ---------------------------------------------------------------------------------------------
# The child: runs one case's code, prints its outcome as one JSON line.
CHILD = r'''
import json, os, sys, time, traceback, warnings
spec = json.loads(sys.stdin.read())
MARK = "@@RESULT@@"

def safe(v, depth=0):
    try:
        if v is None or isinstance(v, (bool, int, str)):
            return v if not isinstance(v, str) else v[:400]
        if isinstance(v, float):
            return repr(v)
        if isinstance(v, (list, tuple)) and depth < 3:
            return [safe(x, depth + 1) for x in list(v)[:20]]
        if isinstance(v, dict) and depth < 3:
            return {str(k)[:80]: safe(x, depth + 1) for k, x in list(v.items())[:30]}
    except Exception:
        pass
    return repr(v)[:400]

ns = {"__name__": "__case__"}
out = {}
t0 = time.time()
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    try:
        exec(compile(spec["prelude"] + "\n" + spec["code"], "<case>", "exec"), ns)
        out = {"status": "return", "value": safe(ns.get("result"))}
    except BaseException as e:
        accepted = []
        for name in spec["accepted"]:
            try:
                accepted.append(eval(name, ns))
            except Exception:
                pass
        cause = e.__cause__
        out = {
            "status": "raise",
            "type": type(e).__module__ + "." + type(e).__qualname__,
            "message": str(e)[:600],
            "accepted": bool(accepted) and isinstance(e, tuple(accepted)),
            "bare": type(e) in (RuntimeError, Exception),
            "cause": None if cause is None else f"{type(cause).__qualname__}: {str(cause)[:200]}",
            "tb": traceback.format_exc()[-1500:],
        }
out["judge"] = safe(ns.get("judge"))
out["seconds"] = round(time.time() - t0, 2)
out["warnings"] = [f"{w.category.__name__}: {str(w.message)[:160]}" for w in caught][:5]
print(MARK + json.dumps(out), flush=True)
'''

PRELUDE = f'''
import os, sys, math, json
import numpy as np
import gymnasium.error
import rlpkg
SMALL = {str(SMALL)!r}
TINY = {str(TINY)!r}
DATA = {str(DATA)!r}
def vec(id="CartPole-v1", n=2, **kw):
    kw.setdefault("num_threads", 1)
    return rlpkg.make_vec(id, n, **kw)
def raises(fn):
    try:
        fn()
    except Exception as e:
        return f"{{type(e).__name__}}: {{e}}"
    return None
'''

VALUE = ("ValueError", "TypeError")
FILES = ("ValueError", "TypeError", "OSError")

CASES: list[dict] = []


def case(name, call, code, *, raises=VALUE, mention=(), allow_return=False, files=None, links=None,
         want="", env=None, mem_gb=16, timeout=TIMEOUT):
    """One probe. ``raises``: accepted exception types (None: the call must return);
    ``mention``: substrings (any, case-insensitive) a clear message names; ``allow_return``: a
    return is fine too; the code may set ``judge = (verdict, note)`` to override."""
    assert not any(c["name"] == name for c in CASES), name
    CASES.append(dict(name=name, call=call, code=textwrap.dedent(code), raises=raises,
                      mention=list(mention), allow_return=allow_return, files=files or {},
                      links=links or {}, want=want, env=env or {}, mem_gb=mem_gb, timeout=timeout))


OK = None  # raises=OK: the call must return

# --- package, version, registration ------------------------------------------------------------
case("version", "rlpkg.__version__", """
import re
result = rlpkg.__version__
if not (isinstance(result, str) and re.fullmatch(r"\\d+\\.\\d+\\.\\d+.*", result)):
    judge = ("silent", f"__version__ = {result!r} is not a version string")
""", raises=OK)
case("ids", "rlpkg.IDS", "result = list(rlpkg.IDS)", raises=OK)
case("register-twice", "rlpkg.register() twice; gymnasium.make('rlpkg/CartPole-v1')", """
import gymnasium
rlpkg.register(); rlpkg.register()
result = type(gymnasium.make("rlpkg/CartPole-v1").unwrapped).__name__
""", raises=OK)
case("private-native-all", "rlpkg._native.__all__ / REPOSITORY", "result = rlpkg._native.REPOSITORY", raises=OK)

# --- env ids --------------------------------------------------------------------------------------
for tag, expr in [("unknown", '"Nope-v0"'), ("empty", '""'), ("none", "None"), ("int", "123"),
                  ("lowercase", '"cartpole-v1"'), ("space", '" CartPole-v1"'), ("bytes", 'b"CartPole-v1"'),
                  ("list", '["CartPole-v1"]'), ("prefixed", '"rlpkg/CartPole-v1"'), ("old-version", '"CartPole-v0"')]:
    case(f"make-id-{tag}", f"rlpkg.make({expr})", f"result = rlpkg.make({expr})",
         mention=["id", "CartPole-v1"], want="ValueError naming the id and the known ids")
case("make_vec-id-unknown", 'rlpkg.make_vec("Nope-v0", 2)', 'result = vec("Nope-v0")', mention=["Nope-v0"])
case("make_vec-id-dict", "rlpkg.make_vec({}, 1)", "result = vec({}, 1)", mention=["id"])
case("gym-make-unknown", 'gymnasium.make("rlpkg/Nope-v0") after register()', """
import gymnasium
rlpkg.register()
result = gymnasium.make("rlpkg/Nope-v0")
""", raises=("gymnasium.error.Error",), mention=["Nope"])
case("gym-make-unregistered", 'gymnasium.make("rlpkg/CartPole-v1") without register()', """
import gymnasium
result = gymnasium.make("rlpkg/CartPole-v1")
""", raises=("gymnasium.error.Error",), mention=["rlpkg"], want="gymnasium NamespaceNotFound")

# --- make_vec sizes -------------------------------------------------------------------------------
for tag, expr in [("0", "0"), ("neg", "-1"), ("float", "2.0"), ("fraction", "1.5"), ("str", '"2"'),
                  ("bool", "True"), ("none", "None"), ("nan", "float('nan')"), ("complex", "2j")]:
    case(f"num_envs-{tag}", f"make_vec('CartPole-v1', {expr})", f"result = vec('CartPole-v1', {expr})",
         mention=["num_envs"], want="ValueError naming num_envs")
for tag, expr in [("2**20+1", "2**20 + 1"), ("2**40", "2**40"), ("2**63", "2**63"), ("2**64", "2**64"),
                  ("2**100", "2**100"), ("np.uint64-max", "np.uint64(2**64 - 1)")]:
    case(f"num_envs-huge-{tag}", f"make_vec('CartPole-v1', {expr})", f"result = vec('CartPole-v1', {expr})",
         raises=("ValueError",), mention=["num_envs", "1048576", "1,048,576", "copies"], mem_gb=4,
         want="ValueError: num_envs beyond 1,048,576 (docs/python.md)")
case("num_envs-np-int", "make_vec('CartPole-v1', np.int64(2))", """
e = vec('CartPole-v1', np.int64(2)); o, _ = e.reset(seed=0); result = list(o.shape)
""", raises=OK)
case("num_envs-max", "make_vec('CartPole-v1', 2**20) reset+step", """
e = vec('CartPole-v1', 2**20)
o, _ = e.reset(seed=0)
o, r, te, tr, i = e.step(np.zeros(2**20, np.int64))
result = list(o.shape)
""", raises=OK, mem_gb=6)
case("num_envs-huge-pendulum-2**40", "make_vec('Pendulum-v1', 2**40)", "result = vec('Pendulum-v1', 2**40)",
     raises=("ValueError",), mention=["num_envs", "1048576", "1,048,576", "copies"], mem_gb=4)
case("gym-make_vec-0", "gymnasium.make_vec('rlpkg/CartPole-v1', num_envs=0)", """
import gymnasium
rlpkg.register()
result = gymnasium.make_vec("rlpkg/CartPole-v1", num_envs=0)
""", mention=["num_envs"])
case("rollout-digest-0-envs", "rlpkg.rust_rollout_digest('CartPole-v1', 0, 5, 0)",
     "result = rlpkg.rust_rollout_digest('CartPole-v1', 0, 5, 0)", mention=["num_envs", "copies", "0"])
case("rollout-digest-neg-steps", "rlpkg.rust_rollout_digest('CartPole-v1', 1, -1, 0)",
     "result = rlpkg.rust_rollout_digest('CartPole-v1', 1, -1, 0)", mention=["steps"])
case("rollout-digest-neg-seed", "rlpkg.rust_rollout_digest('CartPole-v1', 1, 5, -1)",
     "result = rlpkg.rust_rollout_digest('CartPole-v1', 1, 5, -1)", mention=["seed"])
case("rollout-digest-seed-none", "rlpkg.rust_rollout_digest('CartPole-v1', 1, 5, None)",
     "result = rlpkg.rust_rollout_digest('CartPole-v1', 1, 5, None)", mention=["seed"])
case("rollout-digest-unknown-id", "rlpkg.rust_rollout_digest('Nope', 1, 5, 0)",
     "result = rlpkg.rust_rollout_digest('Nope', 1, 5, 0)", mention=["Nope"])
case("rollout-digest-config-for-cartpole", "rlpkg.rust_rollout_digest('CartPole-v1', 1, 5, 0, config='missing.toml')",
     "result = rlpkg.rust_rollout_digest('CartPole-v1', 1, 5, 0, config='missing.toml')",
     mention=["config"], want="ValueError as make_vec gives (config= is for Transport-v0)")
case("rollout-digest-bad-mode", "rlpkg.rust_rollout_digest('CartPole-v1', 1, 5, 0, autoreset_mode='x')",
     "result = rlpkg.rust_rollout_digest('CartPole-v1', 1, 5, 0, autoreset_mode='x')", mention=["autoreset_mode"])

# --- other make_vec arguments ---------------------------------------------------------------------
for tag, expr, mention in [("bogus", '"bogus"', ["autoreset_mode"]), ("upper", '"NEXT_STEP"', ["autoreset_mode"]),
                           ("none", "None", ["autoreset_mode"]), ("list", '["next_step"]', ["autoreset_mode"]),
                           ("int", "1", ["autoreset_mode"])]:
    case(f"autoreset-{tag}", f"make_vec('CartPole-v1', 2, autoreset_mode={expr})",
         f"result = vec(autoreset_mode={expr})", mention=mention, want="ValueError naming autoreset_mode")
case("autoreset-enum", "make_vec(autoreset_mode=AutoresetMode.SAME_STEP)", """
from gymnasium.vector import AutoresetMode
result = str(vec(autoreset_mode=AutoresetMode.SAME_STEP).autoreset_mode)
""", raises=OK)
for tag, expr in [("bogus", '"bogus"'), ("none", "None"), ("dict-cartpole", '"dict"')]:
    case(f"obs_mode-{tag}", f"make_vec('CartPole-v1', 2, obs_mode={expr})", f"result = vec(obs_mode={expr})",
         mention=["obs_mode"])
case("make-obs_mode-bogus", "rlpkg.make('Pendulum-v1', obs_mode='x')", "result = rlpkg.make('Pendulum-v1', obs_mode='x')",
     mention=["obs_mode"])
for tag, expr in [("0", "0"), ("neg", "-1"), ("float", "2.0"), ("str", '"2"')]:
    case(f"num_threads-{tag}", f"make_vec('CartPole-v1', 2, num_threads={expr})",
         f"result = rlpkg.make_vec('CartPole-v1', 2, num_threads={expr})", mention=["num_threads"])
case("num_threads-bool", "make_vec('CartPole-v1', 2, num_threads=True)", """
e = rlpkg.make_vec('CartPole-v1', 2, num_threads=True)
result = e.rlpkg_spec["num_threads"]
""", mention=["num_threads"], want="ValueError (a bool is not a thread count; num_envs/seed_stride refuse bools)")
case("num_threads-huge", "make_vec('CartPole-v1', 1, num_threads=2**40)", """
e = rlpkg.make_vec('CartPole-v1', 1, num_threads=2**40)
result = e.rlpkg_spec["num_threads"]
judge = ("silent", f"accepted: a pool of {result} threads was built")
""", raises=("ValueError",), mention=["num_threads"], mem_gb=3,
     want="ValueError: num_threads beyond a sane bound (e.g. the cores or rayon's max)")
case("make-num_threads-neg", "rlpkg.make('CartPole-v1', num_threads=-1)",
     "result = rlpkg.make('CartPole-v1', num_threads=-1)", mention=["num_threads"],
     want="ValueError naming num_threads (make_vec's check)")
case("make-num_threads-0", "rlpkg.make('CartPole-v1', num_threads=0)",
     "result = rlpkg.make('CartPole-v1', num_threads=0)", mention=["num_threads"])
case("make-num_threads-float", "rlpkg.make('CartPole-v1', num_threads=1.5)",
     "result = rlpkg.make('CartPole-v1', num_threads=1.5)", mention=["num_threads"])
for tag, expr in [("0", "0"), ("neg", "-3"), ("float", "2.5"), ("bool", "True")]:
    case(f"seed_stride-{tag}", f"make_vec('CartPole-v1', 2, seed_stride={expr})",
         f"result = vec(seed_stride={expr})", mention=["seed_stride"])
case("make_vec-unknown-kw", "make_vec('CartPole-v1', 2, foo=1)", "result = vec(foo=1)", mention=["foo"])
case("make-unknown-kw", "rlpkg.make('CartPole-v1', foo=1)", "result = rlpkg.make('CartPole-v1', foo=1)", mention=["foo"])

# --- seeds ----------------------------------------------------------------------------------------
for tag, expr, mention in [("neg", "-1", ["seed"]), ("float", "1.5", ["seed"]), ("float-int", "1.0", ["seed"]),
                           ("str", '"1"', ["seed"]), ("bool", "True", ["seed"]), ("short-list", "[0]", ["seed"]),
                           ("neg-in-list", "[0, -1]", ["seed"]), ("float-in-list", "[0, 1.0]", ["seed"]),
                           ("dict", "{0: 1}", ["seed"])]:
    case(f"vec-reset-seed-{tag}", f"make_vec('CartPole-v1', 2).reset(seed={expr})",
         f"e = vec(); result = e.reset(seed={expr})[0].tolist()", mention=mention)
for tag, expr in [("2**64", "2**64"), ("2**100", "2**100"), ("list-2**64", "[0, 2**64]")]:
    case(f"vec-reset-seed-huge-{tag}", f"make_vec('CartPole-v1', 2).reset(seed={expr})",
         f"e = vec(); result = e.reset(seed={expr})[0].tolist()", mention=["seed"],
         want="ValueError: seed beyond 2**64 - 1 (seeds are u64)")
case("vec-reset-seed-stride-overflow", "make_vec('CartPole-v1', 2, seed_stride=4).reset(seed=2**62)",
     "e = vec(seed_stride=4); result = e.reset(seed=2**62)[0].tolist()", mention=["seed"],
     want="ValueError: seed * seed_stride beyond u64")
case("vec-reset-seed-wrap", "make_vec('CartPole-v1', 2).reset(seed=2**64-1): copy 1's seed",
     """
e = vec(); a = e.reset(seed=2**64 - 1)[0]
b = vec().reset(seed=0)[0]
result = {"copy1": a[1].tolist(), "seed0_copy0": b[0].tolist()}
if np.array_equal(a[1], b[0]):
    judge = ("silent", "copy 1 of seed 2**64-1 is seeded as seed 0 (seed + i wraps around)")
""", raises=("ValueError",), allow_return=True, mention=["seed"])
case("vec-reset-seed-np-array", "make_vec(...).reset(seed=np.array([3, 4]))", """
e = vec(); a = e.reset(seed=np.array([3, 4]))[0]; b = vec().reset(seed=[3, 4])[0]
result = bool(np.array_equal(a, b))
""", raises=OK)
case("vec-reset-deterministic", "make_vec(...).reset(seed=7) twice", """
a = vec().reset(seed=7)[0]; b = vec().reset(seed=7)[0]
result = bool(np.array_equal(a, b))
if not result: judge = ("silent", "same seed gave different observations")
""", raises=OK)
for tag, expr in [("neg", "-5"), ("float", "2.0"), ("huge", "2**64"), ("str", '"0"')]:
    case(f"make-reset-seed-{tag}", f"rlpkg.make('CartPole-v1').reset(seed={expr})",
         f"e = rlpkg.make('CartPole-v1', num_threads=1); result = e.reset(seed={expr})[0].tolist()", mention=["seed"])
case("make-reset-seed-npint", "rlpkg.make('CartPole-v1').reset(seed=np.int64(3))",
     "e = rlpkg.make('CartPole-v1', num_threads=1); result = e.reset(seed=np.int64(3))[0].tolist()", raises=OK)
case("make-reset-options", "rlpkg.make('CartPole-v1').reset(options={'x': 1})",
     "e = rlpkg.make('CartPole-v1', num_threads=1); result = e.reset(options={'x': 1})", mention=["options", "x"])

# --- reset options / reset_mask ------------------------------------------------------------------
case("reset-mask-before-reset", "vec.reset(options={'reset_mask': [True, False]}) first",
     "e = vec(autoreset_mode='disabled'); result = e.reset(options={'reset_mask': np.array([True, False])})",
     mention=["reset_mask", "reset"])
case("reset-mask-int-dtype", "vec.reset(options={'reset_mask': np.array([1, 0])})",
     "e = vec(); e.reset(seed=0); result = e.reset(options={'reset_mask': np.array([1, 0])})",
     mention=["reset_mask"])
case("reset-mask-shape", "vec.reset(options={'reset_mask': np.ones(3, bool)})",
     "e = vec(); e.reset(seed=0); result = e.reset(options={'reset_mask': np.ones(3, bool)})",
     mention=["reset_mask"])
case("reset-mask-list-bool", "vec.reset(options={'reset_mask': [True, False]})", """
e = vec(); o0 = e.reset(seed=0)[0]; o1 = e.reset(seed=5, options={'reset_mask': [False, True]})[0]
result = o1.tolist()
if not np.array_equal(o0[0], o1[0]): judge = ("silent", "the unmasked row changed")
""", raises=OK)
case("reset-options-unknown", "vec.reset(options={'mask': ...})",
     "e = vec(); result = e.reset(options={'mask': np.ones(2, bool)})", mention=["mask", "options"])
case("reset-options-not-dict", "vec.reset(options=[1, 2])",
     "e = vec(); result = e.reset(options=[1, 2])", mention=["options"])

# --- steps: CartPole ------------------------------------------------------------------------------
def cp(tag, expr, mention=("actions",), raises=VALUE, want="", extra="", allow_return=False):
    case(f"cartpole-step-{tag}", f"make_vec('CartPole-v1', 2).step({expr})",
         f"e = vec(); e.reset(seed=0)\n{extra}\nresult = [x.tolist() if hasattr(x, 'tolist') else str(x) for x in e.step({expr})[:4]]",
         mention=list(mention), raises=raises, want=want, allow_return=allow_return)


cp("float", "np.array([0.0, 1.0])")
cp("shape-3", "np.array([0, 1, 1])")
cp("shape-2x1", "np.array([[0], [1]])")
cp("index-2", "np.array([0, 2])", mention=["actions[1]", "index"])
cp("index-neg", "np.array([-1, 0])", mention=["actions[0]", "index"])
cp("bool", "np.array([True, False])")
cp("scalar", "1")
cp("none", "None")
cp("str", '"01"')
cp("object", "np.array([0, None], dtype=object)")
cp("huge-int", "np.array([2**62, 0])", mention=["actions[0]", "index"])
cp("list-ok", "[0, 1]", raises=OK)
cp("uint8-ok", "np.array([0, 1], np.uint8)", raises=OK)
case("cartpole-step-before-reset", "make_vec('CartPole-v1', 2).step([0, 1]) before reset",
     "e = vec(); result = e.step(np.array([0, 1]))", mention=["reset"])
case("cartpole-step-after-close", "vec.close(); vec.step([0, 1])",
     "e = vec(); e.reset(seed=0); e.close(); result = e.step(np.array([0, 1]))",
     raises=("ValueError", "gymnasium.error.ClosedEnvironmentError"), mention=["close"],
     want="gymnasium.error.ClosedEnvironmentError (or ValueError), not a bare RuntimeError")
case("cartpole-reset-after-close", "vec.close(); vec.reset()",
     "e = vec(); e.close(); result = e.reset(seed=0)",
     raises=("ValueError", "gymnasium.error.ClosedEnvironmentError"), mention=["close"],
     want="gymnasium.error.ClosedEnvironmentError (or ValueError), not a bare RuntimeError")
case("cartpole-double-close", "vec.close(); vec.close()", "e = vec(); e.close(); e.close(); result = 'ok'", raises=OK)
case("make-step-after-close", "rlpkg.make('CartPole-v1'): close(); step(0)", """
e = rlpkg.make('CartPole-v1', num_threads=1); e.reset(seed=0); e.close(); result = e.step(0)
""", raises=("ValueError", "gymnasium.error.ClosedEnvironmentError"), mention=["close"],
     want="an error saying the environment is closed")
case("make-reset-after-close", "rlpkg.make('CartPole-v1'): close(); reset()", """
e = rlpkg.make('CartPole-v1', num_threads=1); e.close(); result = e.reset(seed=0)
""", raises=("ValueError", "gymnasium.error.ClosedEnvironmentError"), mention=["close"],
     want="an error saying the environment is closed")
case("make-double-close", "rlpkg.make('CartPole-v1'): close() twice",
     "e = rlpkg.make('CartPole-v1', num_threads=1); e.close(); e.close(); result = 'ok'", raises=OK)
case("make-step-before-reset", "rlpkg.make('CartPole-v1').step(0) before reset",
     "e = rlpkg.make('CartPole-v1', num_threads=1); result = e.step(0)", mention=["reset"])
case("gym-make-step-before-reset", "gymnasium.make('rlpkg/CartPole-v1').step(0) before reset", """
import gymnasium
rlpkg.register(); e = gymnasium.make('rlpkg/CartPole-v1'); result = e.step(0)
""", raises=("ValueError", "gymnasium.error.Error"), mention=["reset"])
for tag, expr, mention in [("int-ok", "1", None), ("np0d-ok", "np.array(1)", None), ("list1", "[1]", ["actions"]),
                           ("float", "1.0", ["actions"]), ("bool", "True", ["actions"]), ("2", "2", ["actions"]),
                           ("neg", "-1", ["actions"])]:
    case(f"make-cartpole-step-{tag}", f"rlpkg.make('CartPole-v1').step({expr})",
         f"e = rlpkg.make('CartPole-v1', num_threads=1); e.reset(seed=0); r = e.step({expr}); result = [str(x) for x in r[:4]]",
         raises=OK if mention is None else VALUE, mention=mention or ())
case("make-step-finished-episode", "rlpkg.make('CartPole-v1'): step after terminated", """
e = rlpkg.make('CartPole-v1', num_threads=1); e.reset(seed=0)
for k in range(600):
    _, _, te, tr, _ = e.step(0)
    if te or tr: break
result = e.step(0)
""", mention=["reset", "finished", "ended", "done", "terminated"])
case("disabled-step-finished-copy", "make_vec(autoreset_mode='disabled'): step a finished copy", """
e = vec(autoreset_mode='disabled'); e.reset(seed=0)
for k in range(600):
    _, _, te, tr, _ = e.step(np.zeros(2, np.int64))
    if (te | tr).any(): break
result = e.step(np.zeros(2, np.int64))
""", mention=["reset", "finished", "ended", "done", "reset_mask"])
case("same-step-final-obs", "make_vec(autoreset_mode='same_step'): final_obs on done", """
e = vec(autoreset_mode='same_step'); e.reset(seed=0)
for k in range(600):
    _, _, te, tr, info = e.step(np.zeros(2, np.int64))
    if (te | tr).any(): break
result = sorted(k for k in info if "final" in k)
if "final_obs" not in info: judge = ("silent", "no final_obs when a copy finished")
""", raises=OK)

# --- steps: Pendulum ------------------------------------------------------------------------------
def pd(tag, expr, mention=("action",), raises=VALUE, want=""):
    case(f"pendulum-step-{tag}", f"make_vec('Pendulum-v1', 2).step({expr})",
         f"e = vec('Pendulum-v1'); e.reset(seed=0)\nresult = [x.tolist() for x in e.step({expr})[:4]]",
         mention=list(mention), raises=raises, want=want)


pd("nan", "np.array([[np.nan], [0.0]])", mention=["finite", "nan"])
pd("inf", "np.array([[0.0], [np.inf]])", mention=["finite", "inf"])
pd("neg-inf", "np.array([[-np.inf], [0.0]])", mention=["finite", "inf"])
pd("1e39-f64", "np.array([[1e39], [0.0]])", mention=["finite", "1e+39", "float32", "inf"],
   want="ValueError naming the value 1e39 (finite in float64, inf in float32)")
pd("shape-2", "np.array([0.0, 0.0])")
pd("shape-1x2", "np.array([[0.0, 0.0]])")
pd("shape-2x2", "np.zeros((2, 2))")
pd("int-ok", "np.array([[1], [0]])", raises=OK)
pd("float16-ok", "np.zeros((2, 1), np.float16)", raises=OK)
pd("list-ok", "[[0.5], [-0.5]]", raises=OK)
pd("complex", "np.zeros((2, 1), complex)")
pd("str", "np.array([['a'], ['b']])")
pd("bool", "np.array([[True], [False]])", raises=VALUE)
pd("noncontig-ok", "np.zeros((2, 3), np.float32)[:, ::3]", raises=OK)
for tag, big, edge in [("high", "100.0", "2.0"), ("low", "-100.0", "-2.0")]:
    case(f"pendulum-out-of-bounds-{tag}", f"make_vec('Pendulum-v1', 2).step([[{big}], [{edge}]]) (bounds +-2)", f"""
e = vec('Pendulum-v1'); o = e.reset(seed=[0, 0])[0]
assert np.array_equal(o[0], o[1])
o2, r, *_ = e.step(np.array([[{big}], [{edge}]], np.float32))
result = {{"obs": o2.tolist(), "rewards": r.tolist()}}
if not np.array_equal(o2[0], o2[1]):
    judge = ("silent", "action {big} outside the Box(-2, 2) applied unclipped (differs from {edge}), no error")
""", raises=OK, want="clipped to the action space, or a ValueError")
case("make-pendulum-step-scalar", "rlpkg.make('Pendulum-v1').step(0.5)",
     "e = rlpkg.make('Pendulum-v1', num_threads=1); e.reset(seed=0); result = str(e.step(0.5))",
     mention=["actions", "shape"])
case("make-pendulum-step-nan", "rlpkg.make('Pendulum-v1').step([nan])",
     "e = rlpkg.make('Pendulum-v1', num_threads=1); e.reset(seed=0); result = str(e.step(np.array([np.nan])))",
     mention=["finite"])
case("check_env-cartpole", "gymnasium.utils.env_checker.check_env(rlpkg.make('CartPole-v1'))", """
from gymnasium.utils.env_checker import check_env
check_env(rlpkg.make('CartPole-v1', num_threads=1), skip_render_check=True); result = 'passed'
""", raises=OK)
case("check_env-pendulum", "check_env(rlpkg.make('Pendulum-v1'))", """
from gymnasium.utils.env_checker import check_env
check_env(rlpkg.make('Pendulum-v1', num_threads=1), skip_render_check=True); result = 'passed'
""", raises=OK)

# --- render_mode, spec ----------------------------------------------------------------------------
for tag, expr in [("human", '"human"'), ("rgb", '"rgb_array"'), ("int", "5"), ("empty", '""')]:
    case(f"make-render_mode-{tag}", f"rlpkg.make('CartPole-v1', render_mode={expr})",
         f"result = rlpkg.make('CartPole-v1', render_mode={expr})", raises=("ValueError",), mention=["render_mode"])
case("make-render_mode-none", "rlpkg.make('CartPole-v1', render_mode=None)",
     "result = rlpkg.make('CartPole-v1', render_mode=None).render_mode", raises=OK)
case("make-render", "rlpkg.make('CartPole-v1').render()",
     "e = rlpkg.make('CartPole-v1', num_threads=1); e.reset(seed=0); result = e.render()",
     raises=("NotImplementedError",), mention=["rlpkg eval", "render"])
case("gym-make-render_mode", "gymnasium.make('rlpkg/CartPole-v1', render_mode='rgb_array')", """
import gymnasium
rlpkg.register(); result = gymnasium.make('rlpkg/CartPole-v1', render_mode='rgb_array')
""", raises=("ValueError",), mention=["render_mode"])
case("gym-make_vec-render_mode", "gymnasium.make_vec('rlpkg/CartPole-v1', 2, render_mode='human')", """
import gymnasium
rlpkg.register(); result = gymnasium.make_vec('rlpkg/CartPole-v1', num_envs=2, render_mode='human')
""", raises=("ValueError",), mention=["render_mode"])
case("make_vec-render_mode-none", "rlpkg.make_vec('CartPole-v1', 2, render_mode=None)",
     "result = vec(render_mode=None).render_mode", raises=OK,
     want="accepted as rlpkg.make accepts render_mode=None (docs: only a mode other than None is refused)")
case("make_vec-render_mode-human", "rlpkg.make_vec('CartPole-v1', 2, render_mode='human')",
     "result = vec(render_mode='human')", raises=VALUE, mention=["render_mode"],
     want="ValueError naming render_mode, as make / gymnasium.make_vec give")
case("vec-render", "make_vec('CartPole-v1', 2).render()", "e = vec(); e.reset(seed=0); result = e.render()",
     raises=("NotImplementedError",), allow_return=True, mention=["render"])
for env_id, steps in [("CartPole-v1", 500), ("Pendulum-v1", 200)]:
    case(f"spec-{env_id}", f"rlpkg.make('{env_id}').spec.max_episode_steps", f"""
s = rlpkg.make('{env_id}', num_threads=1).spec
result = [s.id, s.max_episode_steps]
if s.max_episode_steps != {steps}: judge = ("silent", f"max_episode_steps {{s.max_episode_steps}} != {steps}")
""", raises=OK)
case("spec-gym-make", "gymnasium.make('rlpkg/CartPole-v1').spec.max_episode_steps", """
import gymnasium
rlpkg.register(); e = gymnasium.make('rlpkg/CartPole-v1')
result = [e.spec.id, e.spec.max_episode_steps]
if e.spec.max_episode_steps != 500: judge = ("silent", f"max_episode_steps {e.spec.max_episode_steps}")
""", raises=OK)
case("spec-gym-make-limit-10", "gymnasium.make('rlpkg/CartPole-v1', max_episode_steps=10): truncation", """
import gymnasium
rlpkg.register(); e = gymnasium.make('rlpkg/CartPole-v1', max_episode_steps=10); e.reset(seed=0)
n = 0
for n in range(1, 50):
    _, _, te, tr, _ = e.step(n % 2)
    if te or tr: break
result = [n, bool(tr), e.spec.max_episode_steps]
if not (n == 10 and tr): judge = ("silent", f"episode ended at step {n} (truncated={tr}), not at 10")
""", raises=OK)
case("spec-remake", "gymnasium.make(rlpkg.make('Pendulum-v1').spec)", """
import gymnasium
rlpkg.register(); s = rlpkg.make('Pendulum-v1', num_threads=1).spec
e = gymnasium.make(s); result = [type(e.unwrapped).__name__, e.spec.max_episode_steps]
""", raises=OK)
case("spec-gym-make_vec", "gymnasium.make_vec('rlpkg/CartPole-v1', 2).spec", """
import gymnasium
rlpkg.register(); e = gymnasium.make_vec('rlpkg/CartPole-v1', num_envs=2)
result = None if e.spec is None else [e.spec.id, e.spec.max_episode_steps]
""", raises=OK)
case("spec-transport", "rlpkg.make('Transport-v0', config=transport-small.toml).spec.max_episode_steps", """
s = rlpkg.make('Transport-v0', config=SMALL, num_threads=1).spec
result = [s.id, s.max_episode_steps]
if s.max_episode_steps != 240: judge = ("silent", f"max_episode_steps {s.max_episode_steps}, config says 12 s x 20 Hz = 240")
""", raises=OK)

# --- Transport-v0 configuration files -------------------------------------------------------------
case("config-missing", "make_vec('Transport-v0', 1, config='missing.toml')",
     "result = vec('Transport-v0', 1, config='missing.toml')", raises=FILES, mention=["missing.toml"])
case("config-folder", "make_vec('Transport-v0', 1, config=<a folder>)",
     "os.mkdir('cfgdir'); result = vec('Transport-v0', 1, config='cfgdir')", raises=FILES, mention=["cfgdir"])
case("config-empty-string", "make_vec('Transport-v0', 1, config='')",
     "result = vec('Transport-v0', 1, config='')", raises=FILES, mention=["config"])
case("config-int", "make_vec('Transport-v0', 1, config=5)",
     "result = vec('Transport-v0', 1, config=5)", raises=FILES, mention=["config"])
case("config-garbage", "make_vec('Transport-v0', 1, config=<garbage TOML>)",
     "result = vec('Transport-v0', 1, config='bad.toml')", raises=FILES, mention=["bad.toml"],
     files={"bad.toml": "[transport\nscene = = 'x'\n\x07"})
case("config-binary", "make_vec('Transport-v0', 1, config=<binary file>)",
     "result = vec('Transport-v0', 1, config='bin.toml')", raises=FILES, mention=["bin.toml"],
     files={"bin.toml": b"\xff\xfe\x00\x81garbage\x00"})
case("config-empty-file", "make_vec('Transport-v0', 1, config=<empty file>)",
     "result = vec('Transport-v0', 1, config='empty.toml')", raises=FILES, mention=["empty.toml", "[transport]"],
     files={"empty.toml": ""})
case("config-cartpole-train", "make_vec('Transport-v0', 1, config=configs/train/cartpole.toml)",
     f"result = vec('Transport-v0', 1, config={str(MAIN / 'configs/train/cartpole.toml')!r})", raises=FILES,
     mention=["transport"])
case("config-for-cartpole", "make_vec('CartPole-v1', 2, config=transport-small.toml)",
     "result = vec('CartPole-v1', 2, config=SMALL)", mention=["config"])
case("config-relative-other-folder", "make_vec('Transport-v0', 1, config=<copy of transport-small.toml in a folder with no data/>)",
     "result = vec('Transport-v0', 1, config='cfg/transport.toml')", raises=FILES,
     mention=["data/deformable-sim-real", "recordings"], files={"cfg/transport.toml": SMALL_TEXT},
     want="ValueError naming the recordings path and where it was looked for")
case("config-relative-from-subfolder", "cd elsewhere/; make_vec('Transport-v0', 1, config='../cfg/transport.toml') (data/ beside cfg/)", """
os.makedirs('elsewhere'); os.chdir('elsewhere')
e = vec('Transport-v0', 1, config='../cfg/transport.toml'); result = e.rlpkg_spec['max_episode_steps']
""", raises=OK, files={"cfg/transport.toml": SMALL_TEXT}, links={"data": str(DATA.parent)})
case("config-pathlike", "make_vec('Transport-v0', 1, config=pathlib.Path(transport-small.toml))", """
import pathlib
result = vec('Transport-v0', 1, config=pathlib.Path(SMALL)).rlpkg_spec['max_episode_steps']
""", raises=OK)
case("config-default-path", "rlpkg.default_transport_config() from a temp folder",
     "result = str(rlpkg.default_transport_config())", raises=OK)


def bad_transport(tag, old, new, mention, want="", run=True):
    text = SMALL_ABS.replace(old, new, 1)
    assert text != SMALL_ABS, tag
    step = "e.reset(seed=0); e.step(np.zeros((1, 3), np.float32))" if run else ""
    case(f"config-{tag}", f"make_vec('Transport-v0', 1, config=<small, {new.strip()[:60]}>)",
         f"e = vec('Transport-v0', 1, config='t.toml')\n{step}\nresult = 'built'",
         raises=FILES, mention=mention, files={"t.toml": text},
         want=want or f"ValueError naming the file and the key ({mention[0]})")


bad_transport("unknown-key", "[transport]\n", "[transport]\nbogus_key = 1\n", ["bogus_key"], run=False)
bad_transport("unknown-table", "[transport.limits]\n", "[transport.limitz]\nx = 1\n\n[transport.limits]\n", ["limitz"], run=False)
bad_transport("grid-str", "grid = [11, 13]", 'grid = "x"', ["grid"], run=False)
bad_transport("grid-1x1", "grid = [11, 13]", "grid = [1, 1]", ["grid"])
bad_transport("grid-0x0", "grid = [11, 13]", "grid = [0, 0]", ["grid"])
bad_transport("grid-neg", "grid = [11, 13]", "grid = [-11, 13]", ["grid"], run=False)
bad_transport("time-limit-neg", "time_limit_s = 12.0", "time_limit_s = -1.0", ["time_limit_s"])
bad_transport("time-limit-nan", "time_limit_s = 12.0", "time_limit_s = nan", ["time_limit_s"])
bad_transport("control-hz-0", "control_hz = 20.0", "control_hz = 0.0", ["control_hz"])
bad_transport("settled-variants-0", "settled_variants = 2", "settled_variants = 0", ["settled_variants"])
bad_transport("settle-neg", "settle_s = 0.5", "settle_s = -0.5", ["settle_s"])
bad_transport("scene-unknown", 'scene = "physical"', 'scene = "nope"', ["nope", "scene"], run=False)
bad_transport("recordings-missing", f'recordings = "{DATA}"', 'recordings = "/nonexistent/recs"', ["/nonexistent/recs", "recordings"], run=False)
bad_transport("paths-empty", 'paths = ["HHMHL", "HHHHM", "HHHHH"]', "paths = []", ["paths"])
bad_transport("paths-unknown", 'paths = ["HHMHL", "HHHHM", "HHHHH"]', 'paths = ["ZZZZZ"]', ["ZZZZZ", "paths"], run=False)
bad_transport("speed-neg", "max_path_speed_m_s = 0.945", "max_path_speed_m_s = -1.0", ["max_path_speed_m_s"])
bad_transport("tilt-range-reversed", "target_tilt_deg = [30.0, 60.0]", "target_tilt_deg = [60.0, 30.0]", ["target_tilt_deg"])
bad_transport("mass-neg", "object_mass_kg = [0.287, 0.595]", "object_mass_kg = [-1.0, 0.595]", ["object_mass_kg"])
bad_transport("reward-nan", "progress = 10.0", "progress = nan", ["progress"])
bad_transport("param-scale-unknown", "param_scale = { k_tri_e = [0.8, 1.25] }", "param_scale = { k_nope = [0.8, 1.25] }", ["k_nope"], run=False)

case("transport-nan-action", "make_vec('Transport-v0', 1, small).step([[nan, 0, 0]])", """
e = vec('Transport-v0', 1, config=SMALL); e.reset(seed=0)
result = e.step(np.array([[np.nan, 0.0, 0.0]], np.float32))
""", mention=["finite"])
case("transport-out-of-bounds", "make_vec('Transport-v0', 2, small).step([[5, 5, 5], [50, 50, 50]]) (Box [0..0.945, +-0.349])", """
# Two copies from the same seed; both actions lie beyond the Box: equal rows after the step mean
# both were clipped to the same bound. (Passing the float32 `high` itself differs by ~3e-6: the
# bounds are clamped in f64.)
e = vec('Transport-v0', 2, config=SMALL); o = e.reset(seed=[0, 0])[0]
same_start = bool(np.array_equal(o[0], o[1]))
o2, r, *_ = e.step(np.array([[5.0, 5.0, 5.0], [50.0, 50.0, 50.0]], np.float32))
o3, r3, *_ = e.step(np.array([[-5.0, -5.0, -5.0], [-50.0, -50.0, -50.0]], np.float32))
result = {"same_start": same_start, "rows_equal_after": bool(np.array_equal(o2[0], o2[1]) and np.array_equal(o3[0], o3[1])),
          "rewards": r.tolist() + r3.tolist()}
if same_start and not result["rows_equal_after"]:
    judge = ("silent", "actions outside the Box applied unclipped (5 and 50 differ), no error")
""", raises=OK, want="clipped to the action space, or a ValueError")
case("transport-wrong-shape", "make_vec('Transport-v0', 1, small).step(np.zeros(3))", """
e = vec('Transport-v0', 1, config=SMALL); e.reset(seed=0); result = e.step(np.zeros(3, np.float32))
""", mention=["shape"])
case("transport-obs-dict", "make_vec('Transport-v0', 1, small, obs_mode='dict').reset()", """
e = vec('Transport-v0', 1, config=SMALL, obs_mode='dict'); o, _ = e.reset(seed=0)
result = {k: list(v.shape) for k, v in o.items()}
""", raises=OK)

# --- calibration ----------------------------------------------------------------------------------
CAL = "from rlpkg.calibration import Objective, sample_posterior, RayMap\n"
case("cal-missing", "Objective('missing.toml')", CAL + "result = Objective('missing.toml')", raises=FILES, mention=["missing.toml"])
case("cal-folder", "Objective(<a folder>)", CAL + "os.mkdir('d'); result = Objective('d')", raises=FILES, mention=["'d'", '"d"', "d:", "d "])
case("cal-none", "Objective(None)", CAL + "result = Objective(None)", mention=["config", "path", "NoneType"])
case("cal-garbage", "Objective(<garbage TOML>)", CAL + "result = Objective('bad.toml')", raises=FILES,
     mention=["bad.toml"], files={"bad.toml": "data = [\n\x00"})
case("cal-unknown-key", "Objective(<tiny + unknown key>)", CAL + "result = Objective('c.toml')", raises=FILES,
     mention=["bogus"], files={"c.toml": TINY_ABS.replace("[sim]\n", "[sim]\nbogus = 1\n")})
case("cal-training-config", "Objective(configs/train/cartpole.toml)",
     CAL + f"result = Objective({str(MAIN / 'configs/train/cartpole.toml')!r})", raises=FILES, mention=["cartpole.toml"])
case("cal-relative-data-other-folder", "Objective(<copy of calibrate-tiny.toml>) from a folder without data/",
     CAL + "result = Objective('tiny.toml')", raises=FILES, mention=["data/deformable-sim-real"],
     files={"tiny.toml": TINY_TEXT}, want="ValueError naming the data folder")
case("cal-preset-unknown", "Objective(<tiny, preset='nope'>)", CAL + "result = Objective('c.toml').base_values()",
     raises=FILES, mention=["nope", "preset"], files={"c.toml": TINY_ABS.replace('preset = "physical"', 'preset = "nope"')})
case("cal-param-unknown", "Objective(<tiny, param name 'k_nope'>)", CAL + "result = Objective('c.toml').base_values()",
     raises=FILES, mention=["k_nope"], files={"c.toml": TINY_ABS.replace('name = "k_tri_d"', 'name = "k_nope"')})
case("cal-param-reversed-bounds", "Objective(<tiny, lower > upper>)", CAL + "result = Objective('c.toml').bounds",
     raises=FILES, mention=["lower", "upper", "k_tri_e"],
     files={"c.toml": TINY_ABS.replace("lower = 1.0e3\nupper = 4.0e4", "lower = 4.0e4\nupper = 1.0e3")})
case("cal-param-duplicate", "Objective(<tiny, k_tri_e twice>)", CAL + "result = Objective('c.toml').names",
     raises=FILES, mention=["k_tri_e"], files={"c.toml": TINY_ABS.replace('name = "k_tri_d"', 'name = "k_tri_e"')})
case("cal-log-nonpositive", "Objective(<tiny, log=true with lower=0>)", CAL + "result = Objective('c.toml').bounds",
     raises=FILES, mention=["k_tri_d", "lower", "log"],
     files={"c.toml": TINY_ABS.replace("lower = 1.0e-5", "lower = 0.0")})
case("cal-budget-iterations-0", "Objective(<tiny, [optimiser] iterations = 0>)", CAL + "result = Objective('c.toml').names",
     raises=FILES, mention=["optimiser.iterations"], files={"c.toml": TINY_ABS.replace("iterations = 1\n", "iterations = 0\n")})
case("cal-budget-batch-neg", "Objective(<tiny, [optimiser] batch_size = -1>)", CAL + "result = Objective('c.toml').names",
     raises=FILES, mention=["batch_size"], files={"c.toml": TINY_ABS.replace("batch_size = 2", "batch_size = -1")})
case("cal-both-methods", "Objective(<[optimiser] and [smc]>)", CAL + "result = Objective('c.toml').names",
     raises=FILES, mention=["optimiser", "smc"],
     files={"c.toml": TINY_ABS.replace("[optimiser]", "[smc]\nparticles = 6\nmoves = 1\n\n[optimiser]")})
case("cal-trajectory-unknown", "Objective(tiny, trajectories=['NOPE'])", CAL + "result = Objective('c.toml', trajectories=['NOPE'])",
     raises=FILES, mention=["NOPE"], files={"c.toml": TINY_ABS})
case("cal-trajectories-empty", "Objective(tiny, trajectories=[])", CAL + "o = Objective('c.toml', trajectories=[]); result = o.trajectories",
     mention=["trajectories"], files={"c.toml": TINY_ABS},
     want="ValueError (the file's `trajectories = []` is refused: 'at least one trajectory id')")
case("cal-trajectories-dup", "Objective(tiny, trajectories=['HHHHH', 'HHHHH'])",
     CAL + "result = Objective('c.toml', trajectories=['HHHHH', 'HHHHH'])", mention=["HHHHH"], files={"c.toml": TINY_ABS})
case("cal-trajectories-int", "Objective(tiny, trajectories=[1])", CAL + "result = Objective('c.toml', trajectories=[1])",
     mention=["trajectories"], files={"c.toml": TINY_ABS})
case("cal-trajectories-str-ok", "Objective(tiny, trajectories='HHHHH')",
     CAL + "result = Objective('c.toml', trajectories='HHHHH').trajectories", raises=OK, files={"c.toml": TINY_ABS})
for tag, expr in [("0", "0"), ("neg", "-1.0"), ("nan", "float('nan')"), ("inf", "float('inf')"), ("str", '"1"')]:
    case(f"cal-max_seconds-{tag}", f"Objective(tiny, max_seconds={expr})",
         CAL + f"result = Objective('c.toml', max_seconds={expr})", mention=["max_seconds"], files={"c.toml": TINY_ABS})
case("cal-max_seconds-bool", "Objective(tiny, max_seconds=True)",
     CAL + "result = Objective('c.toml', max_seconds=True).trajectories", mention=["max_seconds"], files={"c.toml": TINY_ABS},
     want="TypeError: a bool is not a duration")
case("cal-max_seconds-tiny", "Objective(tiny, max_seconds=1e-6).evaluate([base])",
     CAL + "o = Objective('c.toml', max_seconds=1e-6); result = o.evaluate([o.base_values()])",
     raises=VALUE, allow_return=True, mention=["max_seconds", "frame"], files={"c.toml": TINY_ABS})
case("cal-max_seconds-huge", "Objective(tiny, max_seconds=1e9).trajectories",
     CAL + "result = Objective('c.toml', max_seconds=1e9).trajectories", raises=VALUE, allow_return=True,
     mention=["max_seconds"], files={"c.toml": TINY_ABS})

EV = CAL + "o = Objective('c.toml')\n"
for tag, expr, mention in [("short", "[[1e4]]", ["batch[0]", "per parameter"]),
                           ("long", "[[1e4, 1e-3, 5.0]]", ["batch[0]", "per parameter"]),
                           ("nan", "[[float('nan'), 1e-3]]", ["batch[0][0]", "finite"]),
                           ("inf", "[[1e4, float('inf')]]", ["batch[0][1]", "finite"]),
                           ("flat-vector", "[1e4, 1e-3]", ["batch", "vector", "list"]),
                           ("mapping-not-in-list", "{'k_tri_e': 1e4, 'k_tri_d': 1e-3}", ["batch", "mapping", "list"]),
                           ("mapping-missing", "[{'k_tri_e': 1e4}]", ["k_tri_d"]),
                           ("mapping-extra", "[{'k_tri_e': 1e4, 'k_tri_d': 1e-3, 'x': 1}]", ["'x'"]),
                           ("strings", "[['a', 'b']]", ["'a'"]),
                           ("none", "None", ["batch"]),
                           ("numpy-2d", "np.array([[1e4, 1e-3, 7.0]])", ["batch[0]", "per parameter"])]:
    case(f"cal-evaluate-{tag}", f"Objective(tiny).evaluate({expr})", EV + f"result = o.evaluate({expr})",
         mention=mention, files={"c.toml": TINY_ABS})
case("cal-evaluate-empty", "Objective(tiny).evaluate([])", EV + "result = o.evaluate([])", raises=OK, files={"c.toml": TINY_ABS})
case("cal-evaluate-negative-params", "Objective(tiny).evaluate([[-1e3, -1.0]]) (bounds 1e3..4e4, 1e-5..0.1)",
     EV + """
r = o.evaluate([[-1e3, -1.0]]); result = r
if math.isfinite(r[0]["loss"]):
    judge = ("silent", f"negative stiffness and damping simulated, finite loss {r[0]['loss']:.4g}")
""", raises=VALUE, allow_return=True, mention=["k_tri_e"], files={"c.toml": TINY_ABS},
     want="ValueError for physically invalid (negative) parameters, or a non-finite loss")
case("cal-evaluate-zero-params", "Objective(tiny).evaluate([[0.0, 0.0]])", EV + "result = o.evaluate([[0.0, 0.0]])",
     raises=VALUE, allow_return=True, mention=["k_tri_e"], files={"c.toml": TINY_ABS})
case("cal-evaluate-huge-params", "Objective(tiny).evaluate([[1e300, 1e300]]) (diverges?)",
     EV + """
r = o.evaluate([[1e300, 1e300]]); result = r
if math.isfinite(r[0]["loss"]): judge = ("fine", "finite loss (no divergence)")
""", raises=VALUE, allow_return=True, mention=["k_tri_e"], files={"c.toml": TINY_ABS})
case("cal-call-mapping", "Objective(tiny)({'k_tri_e': 1e4, 'k_tri_d': 1e-3})",
     EV + "result = o({'k_tri_e': 1e4, 'k_tri_d': 1e-3})", raises=OK, files={"c.toml": TINY_ABS})
for tag, expr in [("neg", "-1.0"), ("nan", "float('nan')"), ("tiny", "1e-9"), ("str", '"1"')]:
    case(f"cal-horizon-{tag}", f"Objective(tiny).log_likelihoods([base], horizon={expr})",
         EV + f"result = o.log_likelihoods([o.base_values()], horizon={expr})", mention=["horizon", "frame"],
         files={"c.toml": TINY_ABS}, allow_return=(tag == "tiny"))
case("cal-horizon-huge", "Objective(tiny).log_likelihoods([base], horizon=1e6)",
     EV + "result = o.log_likelihoods([o.base_values()], horizon=1e6)", raises=VALUE, allow_return=True,
     mention=["horizon"], files={"c.toml": TINY_ABS})

SP = CAL + """
def fake(config, horizon, cands):
    return [dict(log_likelihood=-((math.log(c[0]) - 8) ** 2), loss=1.0, chamfer_m=0.1, object_mse_m2=0.1,
                 site_mse_m2=0.1, horizon_s=0.2) for c in cands]
"""
case("post-no-smc", "sample_posterior(<tiny, [optimiser] only>)", SP + "result = sample_posterior('c.toml', out_dir='out')",
     raises=FILES, mention=["[smc]"], files={"c.toml": TINY_ABS})
case("post-missing", "sample_posterior('missing.toml')", SP + "result = sample_posterior('missing.toml')",
     raises=FILES, mention=["missing.toml"])
case("post-particles-1", "sample_posterior(<smc particles = 1>)", SP + "result = sample_posterior('s.toml', out_dir='out')",
     raises=FILES, mention=["particles"], files={"s.toml": SMC_ABS.replace("particles = 6", "particles = 1")})
case("post-moves-0", "sample_posterior(<smc moves = 0>)", SP + "result = sample_posterior('s.toml', out_dir='out')",
     raises=FILES, mention=["moves"], files={"s.toml": SMC_ABS.replace("moves = 1", "moves = 0")})
case("post-max-stages-0", "sample_posterior(<smc max_stages = 0>)", SP + "result = sample_posterior('s.toml', out_dir='out')",
     raises=FILES, mention=["max_stages"], files={"s.toml": SMC_ABS.replace("max_stages = 2", "max_stages = 0")})
case("post-ok-fake", "sample_posterior(smc, out_dir='out', map_batches=<fast fake rows>)",
     SP + "r = sample_posterior('s.toml', out_dir='out', map_batches=fake); result = [r['evaluations'], sorted(os.listdir('out'))]",
     raises=OK, files={"s.toml": SMC_ABS})
case("post-out-is-config-file", "sample_posterior('s.toml', out_dir='s.toml')",
     SP + "result = sample_posterior('s.toml', out_dir='s.toml', map_batches=fake)", raises=FILES, mention=["s.toml"],
     files={"s.toml": SMC_ABS})
case("post-out-under-file", "sample_posterior('s.toml', out_dir='s.toml/sub')",
     SP + "result = sample_posterior('s.toml', out_dir='s.toml/sub', map_batches=fake)", raises=FILES, mention=["s.toml"],
     files={"s.toml": SMC_ABS})
case("post-config-named-posterior.toml", "sample_posterior('posterior.toml', out_dir='.') (config in the output folder)",
     SP + "result = sample_posterior('posterior.toml', out_dir='.', map_batches=fake)['evaluations']",
     raises=FILES, mention=["posterior.toml"], files={"posterior.toml": SMC_ABS},
     want="refusal to write over the input configuration")
case("post-config-named-objective.toml-fresh", "sample_posterior('objective.toml', out_dir='.', fresh=True)",
     SP + "result = sample_posterior('objective.toml', out_dir='.', map_batches=fake, fresh=True)['evaluations']",
     raises=FILES, mention=["objective.toml"], files={"objective.toml": SMC_ABS},
     want="refusal to delete/replace the input configuration")
case("post-config-named-objective.toml", "sample_posterior('objective.toml', out_dir='.')",
     SP + "result = sample_posterior('objective.toml', out_dir='.', map_batches=fake)['evaluations']",
     raises=FILES, mention=["objective.toml"], files={"objective.toml": SMC_ABS})
case("post-fresh-keeps-other-files", "sample_posterior(fresh=True) into a folder with the user's notes.csv/samples.csv",
     SP + "result = sample_posterior('s.toml', out_dir='res', map_batches=fake, fresh=True)['evaluations']",
     raises=OK, files={"s.toml": SMC_ABS, "res/notes.csv": "keep me\n"})
case("post-map-raises", "sample_posterior(map_batches=<raises KeyError>)",
     SP + "def bad(*a):\n    raise KeyError('boom')\nresult = sample_posterior('s.toml', out_dir='out', map_batches=bad)",
     raises=("RuntimeError",), mention=["batch", "boom"], files={"s.toml": SMC_ABS})
case("post-map-not-callable", "sample_posterior(map_batches=5)",
     SP + "result = sample_posterior('s.toml', out_dir='out', map_batches=5)", mention=["map_batches"],
     files={"s.toml": SMC_ABS}, want="TypeError naming map_batches before anything runs")
case("post-map-short", "sample_posterior(map_batches=<returns one row too few>)",
     SP + "result = sample_posterior('s.toml', out_dir='out', map_batches=lambda c, h, x: fake(c, h, x)[:-1])",
     raises=("ValueError",), mention=["batch"], files={"s.toml": SMC_ABS})
case("post-map-missing-key", "sample_posterior(map_batches=<rows without log_likelihood>)",
     SP + "result = sample_posterior('s.toml', out_dir='out', map_batches=lambda c, h, x: [{'loss': 1.0}] * len(x))",
     raises=("ValueError",), mention=["log_likelihood"], files={"s.toml": SMC_ABS})
case("post-map-nan-rows", "sample_posterior(map_batches=<every log_likelihood NaN>)",
     SP + """
def nan_rows(c, h, x):
    return [dict(log_likelihood=float('nan'), loss=1.0, chamfer_m=0.1, object_mse_m2=0.1, site_mse_m2=0.1, horizon_s=0.2) for _ in x]
r = sample_posterior('s.toml', out_dir='out', map_batches=nan_rows); result = r
judge = ("silent", f"a posterior from all-NaN log-likelihoods: log_evidence {r['log_evidence']}")
""", raises=("ValueError", "RuntimeError"), mention=["likelihood", "nan", "finite"], files={"s.toml": SMC_ABS},
     want="an error: no candidate has a finite log-likelihood")
case("post-fresh-str", "sample_posterior(fresh='yes')",
     SP + "result = sample_posterior('s.toml', out_dir='out', map_batches=fake, fresh='yes')", mention=["fresh"],
     files={"s.toml": SMC_ABS})
case("raymap-chunks-0", "RayMap(chunks=0)", CAL + "result = RayMap(chunks=0)", mention=["chunks"])
case("raymap-chunks-float", "RayMap(chunks=2.5)", CAL + "result = RayMap(chunks=2.5)", mention=["chunks"])
case("raymap-chunks-bool", "RayMap(chunks=True)", CAL + "result = RayMap(chunks=True).chunks", mention=["chunks"],
     want="ValueError (a bool is not a chunk count)")
case("raymap-chunks-npint", "RayMap(chunks=np.int64(2))", CAL + "result = RayMap(chunks=np.int64(2)).chunks", raises=OK,
     want="accepted as make_vec accepts numpy integers")

# --- runs -----------------------------------------------------------------------------------------
RUNS = "from rlpkg import runs\n"
case("runs-missing", "runs.scalars('missing')", RUNS + "result = runs.scalars('missing')", raises=FILES, mention=["missing"])
case("runs-empty-folder", "runs.scalars(<empty folder>)", RUNS + "os.mkdir('r'); result = runs.scalars('r')", raises=FILES, mention=["r"])
case("runs-file", "runs.scalars(<a file>)", RUNS + "result = runs.scalars('f.txt')", raises=FILES, mention=["f.txt"],
     files={"f.txt": "x"})
case("runs-none", "runs.scalars(None)", RUNS + "result = runs.scalars(None)", mention=["run_dir", "None", "NoneType"])
case("runs-good", "runs.scalars(<valid hand-made events file>)", RUNS + "result = runs.scalars('r')", raises=OK,
     files={"r/events.out.tfevents.1": GOOD_EVENTS})
case("runs-garbage", "runs.scalars(<events file of random bytes>)", RUNS + """
r = runs.scalars('r'); result = r
judge = ("silent", f"a corrupt events file read as {r!r}")
""", raises=FILES, mention=["events.out.tfevents"], files={"r/events.out.tfevents.1": bytes(range(256)) * 8 + b"\xff" * 50})
case("runs-garbage-small-length", "runs.scalars(<events file: small length, garbage body>)", RUNS + """
r = runs.scalars('r'); result = r
judge = ("silent", f"a corrupt events file read as {r!r}")
""", raises=FILES, mention=["events.out.tfevents"],
     files={"r/events.out.tfevents.1": struct.pack("<Q", 20) + b"\0" * 4 + b"\xff" * 20 + b"\0" * 4})
case("runs-truncated", "runs.scalars(<valid events file cut mid-record>)", RUNS + """
r = runs.scalars('r'); result = r
n = sum(len(v) for v in r.values())
if n != 1: judge = ("silent", f"cut file gave {n} scalars without error: {r!r}")
""", raises=FILES, allow_return=True, mention=["events.out.tfevents"],
     files={"r/events.out.tfevents.1": GOOD_EVENTS[: len(GOOD_EVENTS) - 12]})
case("runs-empty-events", "runs.scalars(<empty events file>)", RUNS + "result = runs.scalars('r')", raises=OK,
     files={"r/events.out.tfevents.1": b""})
case("runs-events-is-dir", "runs.scalars(<events.out.tfevents.x is a folder>)",
     RUNS + "os.makedirs('r/events.out.tfevents.1'); result = runs.scalars('r')", raises=FILES, mention=["events.out.tfevents"])
case("runs-bin-missing", "RLPKG_BIN=/nonexistent runs.find_binary()", RUNS + "result = str(runs.find_binary())",
     raises=("FileNotFoundError",), mention=["RLPKG_BIN", "/nonexistent"], env={"RLPKG_BIN": "/nonexistent/rlpkg"})
case("runs-bin-folder", "RLPKG_BIN=<folder> runs.find_binary()", RUNS + "result = str(runs.find_binary())",
     raises=("FileNotFoundError",), mention=["RLPKG_BIN"], env={"RLPKG_BIN": "/tmp"})
case("runs-bin-not-exec", "RLPKG_BIN=<non-executable file> runs.find_binary()", RUNS + "result = str(runs.find_binary())",
     raises=("FileNotFoundError", "PermissionError"), mention=["RLPKG_BIN"], env={"RLPKG_BIN": str(TINY)})
case("runs-bin-default", "runs.find_binary() (no RLPKG_BIN)", RUNS + "result = str(runs.find_binary())",
     raises=("FileNotFoundError",), allow_return=True, mention=["RLPKG_BIN"])

# --- Stable-Baselines3 ----------------------------------------------------------------------------
SB = "from rlpkg.sb3 import VecEnvAdapter\n"
case("sb3-unknown-id", "VecEnvAdapter('Nope', 1)", SB + "result = VecEnvAdapter('Nope', 1)", mention=["Nope"])
case("sb3-zero-envs", "VecEnvAdapter('CartPole-v1', 0)", SB + "result = VecEnvAdapter('CartPole-v1', 0)", mention=["num_envs"])
case("sb3-huge-envs", "VecEnvAdapter('CartPole-v1', 2**64)", SB + "result = VecEnvAdapter('CartPole-v1', 2**64)",
     raises=("ValueError",), mention=["num_envs"], mem_gb=4)
case("sb3-autoreset-overridden", "VecEnvAdapter('CartPole-v1', 2, autoreset_mode='next_step')", SB + """
a = VecEnvAdapter('CartPole-v1', 2, autoreset_mode='next_step', num_threads=1)
result = str(a.venv.autoreset_mode)
judge = ("silent", f"autoreset_mode='next_step' silently replaced by {result}")
""", mention=["autoreset_mode"], want="ValueError: the adapter always uses same-step autoreset")
case("sb3-step-wrong-shape", "VecEnvAdapter('CartPole-v1', 2).step(np.array([0]))",
     SB + "a = VecEnvAdapter('CartPole-v1', 2, num_threads=1); a.reset(); result = str(a.step(np.array([0])))", mention=["shape"])
case("sb3-step-float", "VecEnvAdapter('CartPole-v1', 2).step(np.array([0.0, 1.0]))",
     SB + "a = VecEnvAdapter('CartPole-v1', 2, num_threads=1); a.reset(); result = str(a.step(np.array([0.0, 1.0])))", mention=["dtype"])
case("sb3-step_wait-first", "VecEnvAdapter('CartPole-v1', 2): step_wait() without step_async",
     SB + "a = VecEnvAdapter('CartPole-v1', 2, num_threads=1); a.reset(); result = str(a.step_wait())",
     mention=["step_async"], want="an error saying step_async was not called")
case("sb3-seed-neg", "VecEnvAdapter: seed(-1); reset()",
     SB + "a = VecEnvAdapter('CartPole-v1', 2, num_threads=1); a.seed(-1); result = a.reset().tolist()", mention=["seed"])
case("sb3-seed-str", "VecEnvAdapter: seed('x'); reset()",
     SB + "a = VecEnvAdapter('CartPole-v1', 2, num_threads=1); a.seed('x'); result = a.reset().tolist()", mention=["seed"])
case("sb3-seed-huge", "VecEnvAdapter: seed(2**64); reset()",
     SB + "a = VecEnvAdapter('CartPole-v1', 2, num_threads=1); a.seed(2**64); result = a.reset().tolist()",
     raises=("ValueError",), mention=["seed"])
case("sb3-get_attr-missing", "VecEnvAdapter.get_attr('nope')",
     SB + "a = VecEnvAdapter('CartPole-v1', 2, num_threads=1); result = a.get_attr('nope')",
     raises=("AttributeError",), mention=["nope"])
case("sb3-env_method", "VecEnvAdapter.env_method('reset')",
     SB + "a = VecEnvAdapter('CartPole-v1', 2, num_threads=1); result = a.env_method('reset')",
     raises=("AttributeError",), mention=["env_method"])
case("sb3-dict-obs-cartpole", "VecEnvAdapter('CartPole-v1', 2, obs_mode='dict')",
     SB + "result = VecEnvAdapter('CartPole-v1', 2, obs_mode='dict')", mention=["obs_mode"])
case("sb3-module-attr", "rlpkg.sb3.Nope", "import rlpkg.sb3\nresult = rlpkg.sb3.Nope", raises=("AttributeError",), mention=["Nope"])
case("sb3-step-after-close", "VecEnvAdapter: close(); step()",
     SB + "a = VecEnvAdapter('CartPole-v1', 2, num_threads=1); a.reset(); a.close(); result = str(a.step(np.array([0, 1])))",
     raises=("ValueError", "gymnasium.error.ClosedEnvironmentError"), mention=["close"])
case("sb3-ppo-learn", "PPO('MlpPolicy', VecEnvAdapter('CartPole-v1', 2), n_steps=16, batch_size=16).learn(32)", SB + """
import torch; torch.set_num_threads(1)
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecMonitor
m = PPO('MlpPolicy', VecMonitor(VecEnvAdapter('CartPole-v1', 2, num_threads=1)), n_steps=16, batch_size=16, n_epochs=1, seed=0, device='cpu')
m.learn(32); result = m.num_timesteps
""", raises=OK)
case("sb3-check-env", "stable_baselines3 VecEnv seed()/reset() round trip", SB + """
a = VecEnvAdapter('CartPole-v1', 2, num_threads=1)
s = a.seed(3); o1 = a.reset(); a.seed(3); o2 = a.reset()
result = [s, bool(np.array_equal(o1, o2))]
if not np.array_equal(o1, o2): judge = ("silent", "seed(3) did not make reset reproducible")
""", raises=OK)

# --- ProfileReference ------------------------------------------------------------------------------
PR = """
lift = np.linspace(0.0, 0.1, 10, endpoint=False); move = np.linspace(0.0, 0.5, 30)
P = np.concatenate([np.stack([0 * lift, 0 * lift, lift], 1), np.stack([move, 0 * move, 0 * move + 0.1], 1)])
T = np.concatenate([0 * lift, 0.6 * move / 0.5])
"""
RATE = {"rate.toml": SMALL_ABS + RATE_TABLE}
case("profile-ok", "ProfileReference(rate.toml, P, T).step(1.0)", PR + "r = rlpkg.ProfileReference('rate.toml', P, T); result = list(r.step(1.0))",
     raises=OK, files=RATE)
case("profile-no-table", "ProfileReference(transport-small.toml, P, T)", PR + "result = rlpkg.ProfileReference(SMALL, P, T)",
     mention=["profile_rate"])
case("profile-missing-config", "ProfileReference('missing.toml', P, T)", PR + "result = rlpkg.ProfileReference('missing.toml', P, T)",
     raises=FILES, mention=["missing.toml"])
case("profile-lists", "ProfileReference(rate.toml, P.tolist(), T.tolist())",
     PR + "result = rlpkg.ProfileReference('rate.toml', P.tolist(), T.tolist()).length_m", mention=["positions"], files=RATE,
     allow_return=True)
case("profile-float32", "ProfileReference(rate.toml, P.astype(float32), T)",
     PR + "result = rlpkg.ProfileReference('rate.toml', P.astype(np.float32), T).length_m", mention=["positions"], files=RATE,
     allow_return=True)
case("profile-shape", "ProfileReference(rate.toml, P[:, :2], T)", PR + "result = rlpkg.ProfileReference('rate.toml', P[:, :2], T)",
     mention=["positions"], files=RATE)
case("profile-one-point", "ProfileReference(rate.toml, P[:1], T[:1])", PR + "result = rlpkg.ProfileReference('rate.toml', P[:1], T[:1])",
     mention=["positions"], files=RATE)
case("profile-repeated", "ProfileReference(rate.toml, <repeated point>, T)",
     PR + "P[5] = P[4]; result = rlpkg.ProfileReference('rate.toml', P, T)", mention=["positions", "5", "4"], files=RATE)
case("profile-nan-tilt", "ProfileReference(rate.toml, P, T with NaN)",
     PR + "T[3] = np.nan; result = rlpkg.ProfileReference('rate.toml', P, T)", mention=["tilts[3]"], files=RATE)
case("profile-tilt-count", "ProfileReference(rate.toml, P, T[:-1])", PR + "result = rlpkg.ProfileReference('rate.toml', P, T[:-1])",
     mention=["tilts"], files=RATE)
for tag, expr in [("nan", "float('nan')"), ("inf", "float('inf')"), ("str", '"1"')]:
    case(f"profile-step-{tag}", f"ProfileReference.step({expr})",
         PR + f"r = rlpkg.ProfileReference('rate.toml', P, T); result = r.step({expr})", mention=["action"], files=RATE)
case("profile-tilt_offsets-nan", "ProfileReference.tilt_offsets(nan, 0)",
     PR + "r = rlpkg.ProfileReference('rate.toml', P, T); result = r.tilt_offsets(float('nan'), 0.0)", mention=["action", "tilt offsets"], files=RATE)
case("profile-pose-nan", "ProfileReference.pose(nan)",
     PR + "r = rlpkg.ProfileReference('rate.toml', P, T); result = r.pose(float('nan'))", mention=["progress"], files=RATE,
     want="ValueError for a non-finite progress")
case("profile-pose-neg", "ProfileReference.pose(-1.0)",
     PR + "r = rlpkg.ProfileReference('rate.toml', P, T); result = r.pose(-1.0)", mention=["progress"], files=RATE,
     allow_return=True)
case("profile-planned-nan", "ProfileReference.planned(nan)",
     PR + "r = rlpkg.ProfileReference('rate.toml', P, T); result = r.planned(float('nan'))", mention=["t_s", "time"], files=RATE,
     want="ValueError for a non-finite time")
case("profile-max-rate-neg", "ProfileReference(<profile_rate max_rate = -1>)",
     PR + "result = rlpkg.ProfileReference('rate.toml', P, T)", raises=FILES, mention=["max_rate"],
     files={"rate.toml": SMALL_ABS + RATE_TABLE.replace("max_rate = 2.0", "max_rate = -1.0")})


# ---------------------------------------------------------------------------------------------
def snapshot(folder: Path) -> dict[str, str]:
    """Hashes of the regular files under ``folder`` (not following links) and of PROTECTED."""
    out = {}
    for root, dirs, files in os.walk(folder):
        dirs[:] = [d for d in dirs if not os.path.islink(os.path.join(root, d))]
        for f in files:
            p = Path(root, f)
            if p.is_symlink() or not p.is_file():
                continue
            out[str(p.relative_to(folder))] = hashlib.sha256(p.read_bytes()).hexdigest()
    for p in PROTECTED:
        out[str(p)] = hashlib.sha256(p.read_bytes()).hexdigest() if p.exists() else "(missing)"
    return out


def limits(mem_gb):
    def apply():
        import resource
        resource.setrlimit(resource.RLIMIT_AS, (mem_gb << 30, mem_gb << 30))
    return apply


def run_case(c: dict, tmp_root: Path) -> dict:
    work = Path(tempfile.mkdtemp(prefix=c["name"][:40] + "-", dir=tmp_root))
    for rel, content in c["files"].items():
        p = work / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        (p.write_bytes if isinstance(content, bytes) else p.write_text)(content)
    for rel, target in c["links"].items():
        (work / rel).symlink_to(target)
    before = snapshot(work)
    # Only files that existed before the call count for clobbering.
    env = {k: v for k, v in os.environ.items() if k not in ("RLPKG_BIN", "PYTHONPATH")}
    env.update({"PYTHONPATH": str(c["site"]), "RAYON_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
                "PYTHONDONTWRITEBYTECODE": "1", "PYTHONFAULTHANDLER": "1"})
    env.update(c["env"])
    spec = json.dumps({"code": c["code"], "prelude": PRELUDE, "accepted": list(c["raises"] or [])})
    start = time.time()
    proc = subprocess.Popen(["nice", "-n", "15", PY, "-c", CHILD], cwd=work, env=env, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
                            preexec_fn=limits(c["mem_gb"]))
    timed_out = False
    try:
        stdout, stderr = proc.communicate(spec.encode(), timeout=c["timeout"])
    except subprocess.TimeoutExpired:
        timed_out = True
        os.killpg(proc.pid, signal.SIGKILL)
        stdout, stderr = proc.communicate()
    seconds = round(time.time() - start, 1)
    stdout, stderr = stdout.decode(errors="replace"), stderr.decode(errors="replace")
    after = snapshot(work)
    changed = sorted(k for k in before if after.get(k) != before[k])
    outcome = None
    for line in stdout.splitlines():
        if line.startswith("@@RESULT@@"):
            outcome = json.loads(line[len("@@RESULT@@"):])
    rec = dict(name=c["name"], call=c["call"], want=c["want"], returncode=proc.returncode, timed_out=timed_out,
               seconds=seconds, stderr_tail=stderr[-1200:], outcome=outcome, clobbered=changed)
    rec["verdict"], rec["note"] = judge(c, rec, stderr)
    if rec["verdict"] == "fine":
        shutil.rmtree(work, ignore_errors=True)
    else:
        rec["work"] = str(work)
    return rec


def describe(o: dict | None) -> str:
    if o is None:
        return "no result"
    if o["status"] == "return":
        return f"returned {json.dumps(o['value'])[:160]}"
    cause = f" (cause {o['cause']})" if o.get("cause") else ""
    return f"{o['type'].replace('builtins.', '')}: {o['message'][:220]}{cause}"


def judge(c: dict, rec: dict, stderr: str) -> tuple[str, str]:
    o = rec["outcome"]
    if rec["timed_out"]:
        return "crash", f"hung past {c['timeout']} s"
    if rec["returncode"] and rec["returncode"] < 0:
        return "crash", f"killed by signal {-rec['returncode']}: {stderr.strip()[-300:]}"
    if o is None:
        return "crash", f"exit code {rec['returncode']} without a result: {stderr.strip()[-300:]}"
    text = (o.get("message") or "") + stderr
    if "panicked" in text or "PanicException" in (o.get("type") or ""):
        return "crash", "Rust panic: " + describe(o)
    if rec["clobbered"]:
        return "clobbered", f"{rec['clobbered']} changed or vanished; {describe(o)}"
    if o.get("judge"):
        verdict, note = o["judge"]
        return verdict, f"{note}; {describe(o)}"
    if o["status"] == "return":
        if c["raises"] is None or c["allow_return"]:
            return "fine", describe(o)
        return "silent", describe(o)
    # An exception.
    if c["raises"] is None:
        return "refused", describe(o)
    if not o["accepted"] or (o["bare"] and "RuntimeError" not in c["raises"]):
        return "wrong type", describe(o)
    message = (o["message"] + " " + (o.get("cause") or "")).lower()
    if c["mention"] and not any(m.lower() in message for m in c["mention"]):
        return "unclear", describe(o)
    return "fine", describe(o)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--site", type=Path, required=True, help="folder holding the built rlpkg package")
    parser.add_argument("--out", type=Path, help="folder for results.json and report.md")
    parser.add_argument("--only", nargs="*", default=[], help="cases whose name holds one of these")
    args = parser.parse_args()
    if not (args.site / "rlpkg" / "__init__.py").is_file():
        sys.exit(f"--site {args.site}: expected a folder holding rlpkg/__init__.py")
    out = args.out or Path(tempfile.mkdtemp(prefix="rlpkg-python-probe-"))
    selected = [c for c in CASES if not args.only or any(s in c["name"] for s in args.only)]
    for c in selected:
        c["site"] = args.site.resolve()
    tmp_root = out / "tmp"
    tmp_root.mkdir(parents=True, exist_ok=True)
    results_path = out / "results.json"
    results = []
    print(f"{len(selected)} of {len(CASES)} cases", flush=True)
    for k, c in enumerate(selected):
        rec = run_case(c, tmp_root)
        results.append(rec)
        print(f"[{k + 1}/{len(selected)}] {rec['verdict']:10} {rec['seconds']:5}s {c['name']}: {rec['note'][:200]!r}", flush=True)
        results_path.write_text(json.dumps(results, indent=1))
    counts: dict[str, int] = {}
    for r in results:
        counts[r["verdict"]] = counts.get(r["verdict"], 0) + 1
    lines = ["# rlpkg Python API probe", "", f"{len(results)} cases: " +
             ", ".join(f"{v} {n}" for v, n in sorted(counts.items(), key=lambda kv: -kv[1])), ""]
    for r in results:
        if r["verdict"] != "fine":
            want = f" -- expected: {r['want']}" if r["want"] else ""
            lines.append(f"- [{r['verdict']}] `{r['call']}`: {r['note'][:300]}{want}")
    (out / "report.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines[:3]))
    print(f"wrote {results_path} and {out / 'report.md'}")
    sys.exit(0 if counts.get("fine", 0) == len(results) else 1)


if __name__ == "__main__":
    main()
