#!/usr/bin/env python3
"""Writes a latitude-longitude sky as a Radiance .hdr file (no dependencies):
a blue gradient above the horizon, a dim ground below it, and a small,
bright sun. Rows run from the +y pole (up) to the -y pole; columns follow
Mitsuba's envmap convention, azimuth phi = atan2(x, -z) at column
(i + 0.5) / width.

    scripts/make_sky.py OUT.hdr [--width 512] [--height 256]
        [--sun-elevation 35] [--sun-azimuth 60] [--sun-radius 2.5]
        [--sun-radiance 3000] [--sky 1.0]

The sun is every texel whose centre lies within --sun-radius degrees of its
direction; --sun-radiance is its radiance there. The shipped scenes' skies
and the test fixture's were made with this script (their commands are in
their READMEs).
"""

import argparse
import math


def rgbe(r, g, b):
    m = max(r, g, b)
    if m < 1e-32:
        return bytes((0, 0, 0, 0))
    e = math.frexp(m)[1]
    scale = 256.0 / 2.0**e
    return bytes((int(r * scale), int(g * scale), int(b * scale), e + 128))


def sky(d, sun, sun_cos, args):
    x, y, z = d
    if sum(a * b for a, b in zip(d, sun)) >= sun_cos:
        return (args.sun_radiance,) * 3
    if y >= 0.0:
        t = y ** 0.5
        horizon, zenith = (0.85, 0.9, 1.0), (0.25, 0.45, 1.0)
        return tuple(args.sky * (h + (zc - h) * t) for h, zc in zip(horizon, zenith))
    return tuple(args.sky * c for c in (0.25, 0.22, 0.18))


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("out")
    p.add_argument("--width", type=int, default=512)
    p.add_argument("--height", type=int, default=256)
    p.add_argument("--sun-elevation", type=float, default=35.0)
    p.add_argument("--sun-azimuth", type=float, default=60.0)
    p.add_argument("--sun-radius", type=float, default=2.5)
    p.add_argument("--sun-radiance", type=float, default=3000.0)
    p.add_argument("--sky", type=float, default=1.0)
    args = p.parse_args()
    el, az = math.radians(args.sun_elevation), math.radians(args.sun_azimuth)
    sun = (math.cos(el) * math.sin(az), math.sin(el), -math.cos(el) * math.cos(az))
    sun_cos = math.cos(math.radians(args.sun_radius))
    w, h = args.width, args.height
    with open(args.out, "wb") as f:
        f.write(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n")
        f.write(f"-Y {h} +X {w}\n".encode())
        for j in range(h):
            theta = math.pi * j / (h - 1)
            row = bytearray()
            for i in range(w):
                phi = 2.0 * math.pi * (i + 0.5) / w
                d = (math.sin(phi) * math.sin(theta), math.cos(theta), -math.cos(phi) * math.sin(theta))
                row += rgbe(*sky(d, sun, sun_cos, args))
            f.write(bytes(row))
    print(f"{args.out}: {w}x{h}")


if __name__ == "__main__":
    main()
