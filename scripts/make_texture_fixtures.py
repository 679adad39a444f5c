"""Writes the small textures tests/fixtures/mitsuba/coverage-e.xml uses
(deterministic, from a fixed seed): an 8-bit sRGB PNG of coloured tiles, an
8-bit greyscale PNG of roughness values, and a float OpenEXR.

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
