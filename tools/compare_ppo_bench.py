#!/usr/bin/env python3
"""Interleaved comparison of `rlpkg bench ppo` with the same update in JAX (tools/jax_ppo_bench.py).

Each round runs rlpkg (every backend asked for), then the `--baseline` build if given (another
rlpkg binary, e.g. the one before a change; its rows are named `baseline-<backend>`), then JAX at
each minibatch size, so all see the same machine load; the summary gives the median samples/s of
each, its ratio to JAX and the load average before and after.

    /work/venv-jax/bin/python tools/compare_ppo_bench.py --rlpkg target/release/rlpkg \\
        --rounds 3 --minibatch 4096,512 --backend flex,ndarray
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rlpkg", required=True, help="path of the rlpkg binary")
    parser.add_argument("--baseline", help="path of another rlpkg binary to run in the same rounds")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--minibatch", default="4096,512")
    parser.add_argument("--backend", default="flex")
    parser.add_argument("--samples", type=int, default=40960, help="samples timed per run")
    args = parser.parse_args()
    jax_script = Path(__file__).with_name("jax_ppo_bench.py")
    sizes = [int(s) for s in args.minibatch.split(",")]
    binaries = [("", args.rlpkg)] + ([("baseline-", args.baseline)] if args.baseline else [])
    load_before = os.getloadavg()
    results = {}  # (name, minibatch) -> [samples/s]
    cpu_results = {}  # (name, minibatch) -> [samples per CPU second]
    for round_index in range(args.rounds):
        for minibatch in sizes:
            minibatches = str(max(3, args.samples // minibatch))
            for prefix, binary in binaries:
                out = subprocess.run(
                    [binary, "bench", "ppo", "--backend", args.backend, "--minibatch",
                     str(minibatch), "--minibatches", minibatches, "--env-steps", "0", "--json"],
                    check=True, capture_output=True, text=True,
                )
                for row in json.loads(out.stdout)["ppo_update"]:
                    name = prefix + row["backend"]
                    results.setdefault((name, minibatch), []).append(row["samples_per_second"])
                    if row.get("samples_per_cpu_second"):
                        cpu_results.setdefault((name, minibatch), []).append(
                            row["samples_per_cpu_second"])
            out = subprocess.run(
                [sys.executable, str(jax_script), "--minibatch", str(minibatch),
                 "--minibatches", minibatches],
                check=True, capture_output=True, text=True,
            )
            row = json.loads(out.stdout)
            results.setdefault(("jax", minibatch), []).append(row["samples_per_second"])
            cpu_results.setdefault(("jax", minibatch), []).append(row["samples_per_cpu_second"])
            print(f"round {round_index + 1} minibatch {minibatch}: " + ", ".join(
                f"{name} {values[-1]:.0f}" for (name, mb), values in results.items() if mb == minibatch
            ), flush=True)
    summary = []
    for minibatch in sizes:
        jax = statistics.median(results[("jax", minibatch)])
        jax_cpu = statistics.median(cpu_results[("jax", minibatch)])
        for (name, mb), values in results.items():
            if mb != minibatch:
                continue
            median = statistics.median(values)
            row = {
                "name": name, "minibatch": mb, "median_samples_per_second": round(median),
                "runs": [round(v) for v in values], "ratio_to_jax": round(median / jax, 3),
            }
            # Throughput per CPU second is what load from other processes does not change.
            if (name, mb) in cpu_results:
                cpu = statistics.median(cpu_results[(name, mb)])
                row["median_samples_per_cpu_second"] = round(cpu)
                row["cpu_ratio_to_jax"] = round(cpu / jax_cpu, 3)
            summary.append(row)
    load_after = os.getloadavg()
    print(json.dumps(summary, indent=1))
    print(f"load average (1, 5, 15 min): before {load_before[0]:.2f} {load_before[1]:.2f} "
          f"{load_before[2]:.2f}, after {load_after[0]:.2f} {load_after[1]:.2f} {load_after[2]:.2f}")


if __name__ == "__main__":
    main()
