#!/usr/bin/env python3
"""Render a Mitsuba 3 XML scene with Mitsuba 3 (llvm_ad_rgb) as a reference.

For development: the test fixtures under tests/fixtures/mitsuba/ were made
with it, so that tests compare qtrace against Mitsuba without Mitsuba.

  python3 scripts/mitsuba_reference.py SCENE.xml OUT.exr --spp N --passes K
      [-D name=value ...]

Renders K passes of N samples per pixel with different seeds and writes
OUT.exr, their mean, and OUT.var.exr, the variance of that mean per pixel and
channel (from the spread of the passes), which the tests take as the
reference's own noise. Scene parameters (film size, max_depth, ...) are given
with -D as to `mitsuba`; the scene's own sample count is not used.

Needs `pip install mitsuba` and an LLVM shared library (Debian 12:
`apt-get install libllvm19`); DRJIT_LIBLLVM_PATH is set to Debian's
libLLVM-19 when unset.
"""

import argparse
import os
import sys
import time

DEBIAN_LIBLLVM = ("/usr/lib/x86_64-linux-gnu/libLLVM-19.so",
                  "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("out")
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--passes", type=int, default=16)
    ap.add_argument("-D", dest="defines", action="append", default=[],
                    metavar="NAME=VALUE")
    args = ap.parse_args()
    if args.passes < 2:
        sys.exit("--passes must be at least 2 (the variance needs a spread)")
    if "DRJIT_LIBLLVM_PATH" not in os.environ:
        for p in DEBIAN_LIBLLVM:
            if os.path.exists(p):
                os.environ["DRJIT_LIBLLVM_PATH"] = p
                break
    import mitsuba as mi
    import numpy as np
    mi.set_variant("llvm_ad_rgb")
    params = {}
    for d in args.defines:
        k, sep, v = d.partition("=")
        if not sep:
            sys.exit(f"-D {d}: expected NAME=VALUE")
        params[k] = v
    scene = mi.load_file(args.scene, **params)
    start = time.time()
    total = None
    total_sq = None
    for i in range(args.passes):
        img = np.array(mi.render(scene, spp=args.spp, seed=i), dtype=np.float64)[:, :, :3]
        total = img if total is None else total + img
        total_sq = img * img if total_sq is None else total_sq + img * img
    k = args.passes
    mean = total / k
    # Variance of the mean of k passes: the passes' sample variance over k.
    var = np.maximum(total_sq / k - mean * mean, 0.0) * k / (k - 1) / k
    mi.Bitmap(mean.astype(np.float32)).write(args.out)
    var_path = args.out[:-4] + ".var.exr" if args.out.endswith(".exr") else args.out + ".var.exr"
    mi.Bitmap(var.astype(np.float32)).write(var_path)
    print(f"{args.out}: {mean.shape[1]}x{mean.shape[0]}, {k} x {args.spp} spp, "
          f"mean {mean.mean():.6f}, {time.time() - start:.1f} s, Mitsuba {mi.__version__}")


if __name__ == "__main__":
    main()
