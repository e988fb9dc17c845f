#!/usr/bin/env python3
"""Independent check of policies exported by `rlpkg export`.

For every model given (files, or folders searched for *.onnx), this script
  1. runs ONNX's own checker (`onnx.checker.check_model(full_check=True)`),
  2. checks the interface: input `obs` [batch, obs_dim], output `action`, opset >= 17, and the
     metadata keys rlpkg writes,
  3. runs onnxruntime on the observations saved next to the model (`<name>.check.json`, written by
     the Rust tests or `rlpkg export --check-data`) and compares every output with the values the
     Rust reference evaluation computed (max abs difference <= the file's tolerance),
  4. prints the max abs difference and onnxruntime's single-observation latency.

Exit code 0 when every model passes, 1 when any check fails, 2 for bad usage (no model found).
"""

import argparse
import json
import pathlib
import sys
import time

import numpy as np
import onnx
import onnxruntime as ort

METADATA_KEYS = [
    "env_id", "rlpkg_version", "config_hash", "obs_names", "obs_units", "obs_low", "obs_high",
    "action_names", "action_units", "action_low", "action_high", "action_head", "obs_normaliser",
]
JSON_KEYS = [
    "obs_names", "obs_units", "obs_low", "obs_high", "action_names", "action_units", "action_low",
    "action_high",
]


def find_models(paths):
    models = []
    for path in map(pathlib.Path, paths):
        if path.is_dir():
            models.extend(sorted(path.glob("*.onnx")))
        elif path.suffix == ".onnx" and path.is_file():
            models.append(path)
        else:
            print(f"{path}: not an .onnx file or a folder", file=sys.stderr)
    return models


def check_interface(model):
    """Returns a list of problems with the model's interface and metadata."""
    problems = []
    opsets = {o.domain: o.version for o in model.opset_import}
    if opsets.get("", opsets.get("ai.onnx", 0)) < 17:
        problems.append(f"opset {opsets} < 17")
    inputs = [i.name for i in model.graph.input]
    if inputs != ["obs"]:
        problems.append(f"inputs {inputs}, expected ['obs']")
    else:
        dims = model.graph.input[0].type.tensor_type.shape.dim
        if len(dims) != 2 or dims[0].dim_param != "batch" or dims[1].dim_value <= 0:
            problems.append("input obs must have shape [batch, obs_dim] with a symbolic batch")
    outputs = [o.name for o in model.graph.output]
    if "action" not in outputs:
        problems.append(f"outputs {outputs} lack 'action'")
    meta = {p.key: p.value for p in model.metadata_props}
    for key in METADATA_KEYS:
        if key not in meta:
            problems.append(f"metadata key {key!r} missing")
    for key in JSON_KEYS:
        if key in meta:
            try:
                if not isinstance(json.loads(meta[key]), list):
                    problems.append(f"metadata {key!r} is not a JSON list")
            except json.JSONDecodeError as err:
                problems.append(f"metadata {key!r} is not JSON: {err}")
    return problems


def max_diff(got, want, scaled):
    """Largest |got - want|, divided by max(1, |want|) when `scaled` (as rlpkg does for logits and
    values: f32 holds ~7 significant digits, so large values cannot agree to 1e-5 absolutely)."""
    got = np.asarray(got, dtype=np.float64).reshape(-1)
    want = np.asarray(want, dtype=np.float64).reshape(-1)
    if got.shape != want.shape:
        return float("inf")
    if got.size == 0:
        return 0.0
    diff = np.abs(got - want)
    if scaled:
        diff /= np.maximum(np.abs(want), 1.0)
    diff[np.isnan(diff)] = np.inf
    return float(diff.max())


def check_model(path, latency_runs):
    """Checks one model; returns True when it passes."""
    print(f"== {path} ({path.stat().st_size} bytes)")
    model = onnx.load(str(path))
    try:
        onnx.checker.check_model(model, full_check=True)
        print("  onnx.checker (full_check): ok")
    except Exception as err:  # the checker raises several exception types
        print(f"  FAIL onnx.checker: {err}")
        return False
    problems = check_interface(model)
    for problem in problems:
        print(f"  FAIL {problem}")
    if problems:
        return False

    check_file = path.with_suffix(".check.json")
    if not check_file.is_file():
        print(f"  FAIL {check_file}: missing (expected observations and outputs)")
        return False
    data = json.loads(check_file.read_text())
    rows, obs_dim = data["rows"], data["obs_dim"]
    obs = np.asarray(data["obs"], dtype=np.float32).reshape(rows, obs_dim)

    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    names = [o.name for o in session.get_outputs()]
    results = dict(zip(names, session.run(None, {"obs": obs})))
    ok = True
    tolerance = float(data["tolerance"])
    worst = 0.0
    for name in ("action", "logits", "value"):
        want = data.get(name)
        if want is None:
            continue
        if name not in results:
            print(f"  FAIL output {name!r} missing (expected from the check data)")
            ok = False
            continue
        got = results[name]
        if got.shape[0] != rows:
            print(f"  FAIL output {name!r} has {got.shape[0]} rows, expected {rows}")
            ok = False
            continue
        diff = max_diff(got, want, scaled=name != "action")
        worst = max(worst, diff)
        status = "ok" if diff <= tolerance else "FAIL"
        ok &= diff <= tolerance
        kind = "abs" if name == "action" else "scaled"
        print(f"  {status} {name}: max {kind} diff onnxruntime vs rlpkg reference {diff:.3e} "
              f"over {rows} observations (tolerance {tolerance:.0e})")

    one = obs[:1]
    for _ in range(max(latency_runs // 10, 1)):
        session.run(None, {"obs": one})
    times = []
    for i in range(latency_runs):
        row = obs[i % rows:i % rows + 1]
        start = time.perf_counter()
        session.run(["action"], {"obs": row})
        times.append((time.perf_counter() - start) * 1e6)
    times.sort()
    if times:
        print(f"  onnxruntime {ort.__version__} single-observation latency: median "
              f"{times[len(times) // 2]:.1f} us, p90 {times[int(0.9 * (len(times) - 1))]:.1f} us "
              f"over {latency_runs} runs (1 thread)")
    print(f"  {'PASS' if ok else 'FAIL'} (max diff {worst:.3e})")
    return ok


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paths", nargs="+", help=".onnx files or folders holding them")
    parser.add_argument("--latency-runs", type=int, default=2000,
                        help="single-observation runs timed per model (default 2000)")
    args = parser.parse_args()
    models = find_models(args.paths)
    if not models:
        print("no .onnx model found in " + " ".join(args.paths), file=sys.stderr)
        return 2
    results = [check_model(path, args.latency_runs) for path in models]
    print(f"{sum(results)}/{len(results)} models passed")
    return 0 if all(results) else 1


if __name__ == "__main__":
    sys.exit(main())
