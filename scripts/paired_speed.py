#!/usr/bin/env python3
"""Compares the speed of two qtrace renders run side by side, one core each.

This machine's timings drift by 15-30% between runs minutes apart, so two
binaries or settings timed one after the other are hard to tell apart. Here
both renders run at the same time, each with one lavapipe thread
(LP_NUM_THREADS=1) pinned to its own core, so whatever slows the machine
slows both; the order of the cores alternates between rounds. An A/A run
(the same command twice) spreads about ±5%. With one thread per render it
cannot see how a change balances lavapipe's threads (llvmpipe gives each
thread a fixed share of a dispatch's workgroups): compare such changes in
alternating runs on all cores as well. The two cores need not be equally
fast (here one took 6-14% longer for hours), so each pair of rounds, one in
each order, gives one figure: the geometric mean of its two ratios, in
which the cores' difference cancels. It reports the median of those.

  scripts/paired_speed.py [--rounds N] [--spp S] \\
      "LABEL|QTRACE_BINARY|RENDER ARGS…" "LABEL|QTRACE_BINARY|RENDER ARGS…"

The render arguments start with the scene, e.g.
  "pt|target/release/qtrace|scenes/cornell-box.toml --nee --width 128 --height 128"
It prints, per round, each render's trace pass (GPU ms, from its stats) per
pass and per path vertex and all its dispatches per pass, and the median
ratios of the second to the first (all dispatches also per path vertex,
the cost a guide's per-vertex target is stated in). With `--reference REF.exr`
(the scene's reference at the same size, such as the one `qtrace bench`
caches) it also measures each image's relMSE against it and prints the
second's relMSE at the first's GPU time over the first's: relMSE times GPU
time, whose timing both renders share (relMSE falls as 1/time). A
reference's own error adds to every relMSE measured against it and pulls
that ratio toward 1: where the bench cached it beside the reference
(REF.relmse: its expected relMSE and sample count), the ratio is also given
with it taken out of both errors. Needs `taskset` (util-linux) and two
cores. Benchmarks only.
"""

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path


def trace_cost(stats_path):
    """Trace ms per pass and per path vertex, every dispatch's ms per pass
    (guide updates and training included), the mean path length and the pass
    after which a guide stood back (None if it did not), of one render."""
    s = json.loads(Path(stats_path).read_text())
    trace = next(p for p in s["gpu_passes"] if p["name"] == "trace")
    per_pass = trace["total_ms"] / trace["count"]
    every = sum(p["total_ms"] for p in s["gpu_passes"]) / trace["count"]
    length = max(s["mean_path_length"], 1e-9)
    return per_pass, per_pass / length, every, length, s.get("guide_stood_back_after")


def rel_mse(binary, image, reference):
    """relMSE of `image` against `reference`, by `qtrace compare`."""
    out = subprocess.run([binary, "compare", str(image), str(reference)],
                         capture_output=True, text=True, check=True).stdout
    for line in out.splitlines():
        words = line.split()
        if words[:1] == ["relMSE"]:
            return float(words[1])
    sys.exit(f"error: no relMSE in {out!r}")


def parse_configs(specs):
    """(label, binary, render arguments) of each "LABEL|BINARY|SCENE ARGS…"."""
    configs = []
    for c in specs:
        parts = c.split("|")
        if len(parts) != 3 or not parts[2].split():
            sys.exit(f"error: expected LABEL|BINARY|SCENE ARGS…, got {c!r}")
        configs.append((parts[0], parts[1], parts[2].split()))
    return configs


def reference_floor(reference):
    """The reference's own expected relMSE, from the file `qtrace bench`
    caches beside it (REF.relmse: relMSE, sample count), or None."""
    try:
        words = Path(reference).with_suffix(".relmse").read_text().split()
        return float(words[0]), int(words[1])
    except (OSError, IndexError, ValueError):
        return None


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=4, help="rounds, an even number (pairs of core orders)")
    ap.add_argument("--spp", type=int, default=128, help="samples per pixel of each render")
    ap.add_argument("--reference", help="reference EXR: also compare relMSE at equal GPU time")
    ap.add_argument("configs", nargs=2, metavar="LABEL|BINARY|ARGS")
    args = ap.parse_args()
    if args.rounds < 2 or args.rounds % 2:
        sys.exit("error: --rounds must be an even number, 2 or more (each pair runs both core orders)")
    configs = parse_configs(args.configs)
    env = dict(os.environ, LP_NUM_THREADS="1")
    floor = reference_floor(args.reference) if args.reference else None
    if floor:
        print(f"the reference's own relMSE: {floor[0]:.3g} ({floor[1]} spp)")
    ratios, totals, total_vertex, equal_time, equal_time_clean = [], [], [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            order = configs if r % 2 == 0 else configs[::-1]
            running = []
            for core, (label, binary, rest) in enumerate(order):
                stats = Path(tmp) / f"{label}.json"
                cmd = ["taskset", "-c", str(core), binary, "render", *rest,
                       "--spp", str(args.spp), "-o", str(Path(tmp) / f"{label}.exr"),
                       "--stats", str(stats)]
                running.append((label, subprocess.Popen(
                    cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)))
            for label, proc in running:
                _, err = proc.communicate()
                if proc.returncode != 0:
                    sys.exit(f"error: {label} failed: {err.strip().splitlines()[-1:]}")
            (la, _, _), (lb, _, _) = configs
            a = trace_cost(Path(tmp) / f"{la}.json")
            b = trace_cost(Path(tmp) / f"{lb}.json")
            ratios.append(b[1] / a[1])
            totals.append(b[2] / a[2])
            total_vertex.append(b[2] / b[3] / (a[2] / a[3]))
            if args.reference:
                ea = rel_mse(configs[0][1], Path(tmp) / f"{la}.exr", args.reference)
                eb = rel_mse(configs[1][1], Path(tmp) / f"{lb}.exr", args.reference)
                equal_time.append(eb * b[2] / (ea * a[2]))
                clean = ""
                if floor and min(ea, eb) > floor[0]:
                    equal_time_clean.append((eb - floor[0]) * b[2] / ((ea - floor[0]) * a[2]))
                    clean = f" ({equal_time_clean[-1]:.3f}x without the reference's error)"
                print(f"round {r}: relMSE {la} {ea:.4g}, {lb} {eb:.4g}; "
                      f"{lb} at {la}'s time: {equal_time[-1]:.3f}x{clean}")
            # A guide that stood back (races read the clock) traced other paths.
            back = "".join(f", {label}'s guide stood back after {x[4]} passes"
                           for label, x in [(la, a), (lb, b)] if x[4] is not None)
            print(f"round {r}: {la} {a[0]:.2f} ms/pass ({a[1]:.2f} per vertex, {a[2]:.2f} all "
                  f"passes), {lb} {b[0]:.2f} ms/pass ({b[1]:.2f} per vertex, {b[2]:.2f} all "
                  f"passes): {ratios[-1]:.3f}, all passes {totals[-1]:.3f}{back}")
    for what, xs in [("trace time per path vertex", ratios), ("GPU time of all passes", totals),
                     ("GPU time of all passes per path vertex", total_vertex),
                     ("relMSE at equal GPU time", equal_time),
                     ("relMSE at equal GPU time without the reference's own error",
                      equal_time_clean if len(equal_time_clean) == len(equal_time) else [])]:
        pairs = [math.sqrt(x * y) for x, y in zip(xs[0::2], xs[1::2])]
        if not pairs:
            continue
        print(f"{lb} / {la}, {what}: median {statistics.median(pairs):.3f} "
              f"(range {min(pairs):.3f}-{max(pairs):.3f} over {len(pairs)} pairs of rounds)")
    # Rounds alternate the cores: the first config ran on core 0 in even rounds.
    even = statistics.median(ratios[0::2])
    odd = statistics.median(ratios[1::2])
    print(f"time on core 1 over core 0 (medians of the rounds): {math.sqrt(even / odd):.3f}")


if __name__ == "__main__":
    main()
