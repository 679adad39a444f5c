#!/usr/bin/env python3
"""Counts the instructions a qtrace render runs in llvmpipe's JIT code.

This machine's timings drift by 15-30% between runs, and even paired runs
(paired_speed.py) spread +-10% a round, so a change of a few percent in a
kernel's code cannot be timed here. An instruction count can: valgrind
(callgrind) runs the render, llvmpipe's JIT code has no symbols, and the
instructions in code of no object file are the shaders'. Two renders that
differ only in their sample count give, by difference, the instructions of
the extra passes alone (no start-up, no shader compilation), per path vertex
and per ray. The same command twice agrees within about 0.5%.

An instruction count is not a time: it does not see cache misses or the
cost of a gather, so a change that moves memory traffic still needs a
timing. And valgrind does not run AVX-512, so llvmpipe compiles AVX2 code
under it: the counts are of that code, a close relative of what runs
natively on an AVX-512 machine.

  scripts/icount.py [--spp A B] [--size N] [--functions K] \\
      "LABEL|QTRACE_BINARY|RENDER ARGS…" ["LABEL|BINARY|ARGS…" …]

The render arguments start with the scene, e.g.
  "pt|target/release/qtrace|scenes/cornell-box.toml --nee"
Each render runs single-threaded (LP_NUM_THREADS=1) at N×N pixels (32), at
A and at B samples per pixel (4 and 16). With --functions K it also lists
the K busiest JIT functions of the B run (the trace kernel, each texel
fetch, the guide update, accumulate…) by their share. Needs valgrind
(Debian: valgrind). Benchmarks only: about a minute per render at the
defaults.
"""

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

from paired_speed import parse_configs

# A callgrind_annotate line of a function in code of no object file.
JIT_LINE = re.compile(r"\s*([\d,]+) \([^)]*\)\s+\?\?\?:(0x[0-9a-f]+) \[\?\?\?\]$")


def jit_functions(binary, args, spp, size, tmp):
    """Instructions per JIT function (by address) and the stats of one render."""
    out = Path(tmp) / f"callgrind-{spp}.out"
    stats = Path(tmp) / f"stats-{spp}.json"
    command = ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}",
               binary, "render", *args, "--spp", str(spp), "--width", str(size),
               "--height", str(size), "-o", str(Path(tmp) / "image.exr"), "--stats", str(stats)]
    env = dict(os.environ, LP_NUM_THREADS="1")
    run = subprocess.run(command, env=env, capture_output=True, text=True)
    if run.returncode != 0 or not stats.exists():
        tail = (run.stderr.strip().splitlines() or ["(no output)"])[-1]
        sys.exit(f"error: the render under valgrind failed: {tail}")
    text = subprocess.run(["callgrind_annotate", "--threshold=100", str(out)],
                          capture_output=True, text=True, check=True).stdout
    functions = {}
    for line in text.splitlines():
        m = JIT_LINE.match(line)
        if m:
            functions[m.group(2)] = int(m.group(1).replace(",", ""))
    return functions, json.loads(stats.read_text())


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, nargs=2, default=[4, 16], metavar=("A", "B"),
                    help="the two sample counts whose difference is counted")
    ap.add_argument("--size", type=int, default=32, help="image width and height")
    ap.add_argument("--functions", type=int, default=0, metavar="K",
                    help="also list the K busiest JIT functions of the larger render")
    ap.add_argument("configs", nargs="+", metavar="LABEL|BINARY|ARGS")
    args = ap.parse_args()
    low, high = args.spp
    if not 1 <= low < high:
        sys.exit("error: --spp takes two sample counts, the first smaller")
    configs = parse_configs(args.configs)

    first = None
    for label, binary, render_args in configs:
        with tempfile.TemporaryDirectory() as tmp:
            a, sa = jit_functions(binary, render_args, low, args.size, tmp)
            b, sb = jit_functions(binary, render_args, high, args.size, tmp)
        instructions = sum(b.values()) - sum(a.values())
        vertices = sb["paths"] * sb["mean_path_length"] - sa["paths"] * sa["mean_path_length"]
        rays = sb["rays"] - sa["rays"]
        per_vertex = instructions / max(vertices, 1e-9)
        first = first or per_vertex
        print(f"{label}: {instructions / 1e6:.1f} M instructions in {high - low} passes: "
              f"{per_vertex:.0f} per path vertex ({per_vertex / first:.3f}x the first), "
              f"{instructions / max(rays, 1):.0f} per ray; mean path length {sb['mean_path_length']:.3f}")
        total = sum(b.values())
        for address, count in sorted(b.items(), key=lambda kv: -kv[1])[:args.functions]:
            print(f"  {100 * count / max(total, 1):5.1f}%  JIT function at {address}")


if __name__ == "__main__":
    main()
