"""Writes the small textures that tests/fixtures/mitsuba/coverage-e.xml,
coverage-j.xml, coverage-l.xml and coverage-m.xml use (deterministic, from a
fixed seed): an 8-bit sRGB PNG of coloured tiles, an 8-bit greyscale PNG of
roughness values, a float OpenEXR, an 8-bit normal map of round bumps, an
8-bit greyscale opacity of two leaves and 8-bit greyscale heights.

    python3 scripts/make_texture_fixtures.py tests/fixtures/textures
"""
import sys
import numpy as np
import mitsuba as mi

mi.set_variant("scalar_rgb")
out = sys.argv[1]
rng = np.random.default_rng(7)

# 16x16 tiles: 4x4 blocks of random colours with a lighter border texel.
base = rng.integers(40, 230, size=(4, 4, 3))
tiles = np.repeat(np.repeat(base, 4, axis=0), 4, axis=1).astype(np.uint8)
tiles[::4, :, :] = np.minimum(tiles[::4, :, :] + 25, 255)
mi.Bitmap(tiles, mi.Bitmap.PixelFormat.RGB).write(f"{out}/tiles.png")

# 8x8 roughness from 0.05 to 0.6 (used raw, as alpha).
y, x = np.mgrid[0:8, 0:8]
rough = (0.05 + 0.55 * ((x + 2 * y) % 8) / 7.0) * 255.0
mi.Bitmap(rough.round().astype(np.uint8)[:, :, None], mi.Bitmap.PixelFormat.Y).write(f"{out}/rough.png")

# 6x5 linear floats in [0.05, 0.9].
floats = (0.05 + 0.85 * rng.random((5, 6, 3))).astype(np.float32)
mi.Bitmap(floats, mi.Bitmap.PixelFormat.RGB).write(f"{out}/floats.exr")

# 32x32 normals of four round bumps a side, (n + 1) / 2 in 8 bits (read raw).
y, x = (np.mgrid[0:32, 0:32] + 0.5) / 8.0
fx, fy = x - np.floor(x) - 0.5, y - np.floor(y) - 0.5
r2 = np.minimum(fx * fx + fy * fy, 0.2)
slope = 1.6 * (0.2 - r2)
n = np.stack([slope * fx * 4.0, slope * fy * 4.0, np.ones_like(fx)], axis=-1)
n /= np.linalg.norm(n, axis=-1, keepdims=True)
bumps = ((n + 1.0) * 0.5 * 255.0).round().astype(np.uint8)
mi.Bitmap(bumps, mi.Bitmap.PixelFormat.RGB).write(f"{out}/bumps.png")

# 32x32 opacity of two leaves (ellipses turned 30 degrees, soft at the edge),
# 8-bit greyscale (read raw, as a mask's opacity).
y, x = (np.mgrid[0:32, 0:32] + 0.5) / 32.0
leaf = np.zeros((32, 32))
for cx, cy in [(0.3, 0.35), (0.68, 0.66)]:
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    u, v = (x - cx) * c + (y - cy) * s, -(x - cx) * s + (y - cy) * c
    r = np.sqrt((u / 0.26) ** 2 + (v / 0.12) ** 2)
    leaf = np.maximum(leaf, np.clip((1.0 - r) * 6.0, 0.0, 1.0))
mi.Bitmap((leaf * 255.0).round().astype(np.uint8)[:, :, None], mi.Bitmap.PixelFormat.Y).write(f"{out}/leaves.png")

# 32x32 heights of ridges crossed by round dimples, 8-bit greyscale (read
# raw, as a bump map's height field).
y, x = (np.mgrid[0:32, 0:32] + 0.5) / 32.0
heights = 0.5 + 0.25 * np.sin(2 * np.pi * 3 * x) * np.cos(2 * np.pi * 2 * y)
fx, fy = x * 4 - np.floor(x * 4) - 0.5, y * 4 - np.floor(y * 4) - 0.5
heights -= 0.2 * np.exp(-(fx * fx + fy * fy) / 0.02)
mi.Bitmap((np.clip(heights, 0, 1) * 255.0).round().astype(np.uint8)[:, :, None], mi.Bitmap.PixelFormat.Y).write(f"{out}/heights.png")
