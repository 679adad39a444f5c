#!/usr/bin/env python3
"""Where a render's time goes inside llvmpipe's JIT-compiled shaders.

perf samples the JIT code of a running qtrace process, gdb dumps that code
from the process, and the script splits it into functions (llvmpipe emits
each texel-buffer fetch as a small function of its own) and reports the
share of samples in each, with the descriptor offset a fetch reads its
buffer from, so a fetch can be told apart from the kernel's own code.

  scripts/jit_profile.py [--warmup S] [--seconds S] -- qtrace render SCENE ...

Needs `perf` and `gdb` (Debian: linux-perf, gdb) and a render long enough
to outlast warmup + seconds (it is stopped afterwards). Benchmarks only.
"""

import argparse
import collections
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--warmup", type=float, default=3.0, help="seconds before sampling (JIT compile)")
    ap.add_argument("--seconds", type=float, default=5.0, help="seconds of sampling")
    ap.add_argument("--top", type=int, default=8, help="functions to list")
    ap.add_argument("--annotate", type=int, default=0, metavar="K",
                    help="also print the K busiest functions' instructions with their samples "
                         "(for a large function, its 40 busiest instructions)")
    ap.add_argument("command", nargs=argparse.REMAINDER, help="-- the render command")
    args = ap.parse_args()
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        sys.exit("error: give the render command after --")

    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "perf.data"
        proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            time.sleep(args.warmup)
            if proc.poll() is not None:
                sys.exit("error: the command ended before sampling began; render more samples")
            subprocess.run(
                ["perf", "record", "-F", "4000", "-p", str(proc.pid), "-o", str(data), "--",
                 "sleep", str(args.seconds)],
                check=True, capture_output=True)
            ips = subprocess.run(["perf", "script", "-i", str(data), "-F", "ip"],
                                 check=True, capture_output=True, text=True).stdout.split()
            samples = collections.Counter(int(a, 16) for a in ips)
            total = sum(samples.values())
            # The JIT code lies in anonymous pages: dump the busiest ones.
            pages = collections.Counter()
            for address, count in samples.items():
                pages[address >> 12] += count
            code = {}
            for page, _ in pages.most_common(12):
                out = subprocess.run(
                    ["gdb", "-p", str(proc.pid), "-batch", "-ex", f"x/2000i {page << 12:#x}"],
                    capture_output=True, text=True).stdout
                for line in out.splitlines():
                    m = re.match(r"\s+(0x[0-9a-f]+)(?: <[^>]*>)?:\s+(.*)", line)
                    if m:
                        code.setdefault(int(m.group(1), 16), m.group(2).strip())
        finally:
            proc.kill()
            proc.wait()

    # Functions end at a `ret`; a texel fetch starts by comparing the index
    # with its buffer's size in the descriptor, at a fixed offset.
    functions = []
    start, count, fetch = None, 0, None
    for address in sorted(code):
        text = code[address]
        if start is None:
            start, count, fetch = address, 0, None
        count += samples.get(address, 0)
        m = re.search(r"vpcmpltd (0x[0-9a-f]+)\(%rdi\)", text)
        if m and fetch is None and address - start < 32:
            fetch = m.group(1)
        if re.match(r"ret\b", text):
            functions.append((count, start, address - start + 1, fetch))
            start = None
    dumped = sum(f[0] for f in functions)
    print(f"{total} samples, {100 * dumped / max(total, 1):.1f}% in the dumped JIT code")
    print(f"{'share':>6}  {'bytes':>6}  what")
    for count, start, size, fetch in sorted(functions, reverse=True)[:args.top]:
        what = f"texel fetch, descriptor offset {fetch}" if fetch else "shader code"
        print(f"{100 * count / max(total, 1):5.1f}%  {size:6d}  {what} at {start:#x}")
    for count, start, size, fetch in sorted(functions, reverse=True)[:args.annotate]:
        body = [a for a in sorted(code) if start <= a < start + size]
        if len(body) > 120:
            body = sorted(sorted(body, key=lambda a: -samples.get(a, 0))[:40])
        print(f"\n{start:#x}: {100 * count / max(total, 1):.1f}%")
        for a in body:
            print(f"{100 * samples.get(a, 0) / max(total, 1):6.2f}%  {a - start:6d}  {code[a]}")


if __name__ == "__main__":
    main()
