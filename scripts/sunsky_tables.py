#!/usr/bin/env python3
"""Writes data/sunsky/hosek_wilkie_rgb.bin: the tables of the Hosek-Wilkie
sky and sun model in RGB, as Mitsuba 3 ships them (`pip install mitsuba`:
mitsuba/data/sunsky/), for qtrace's reading of Mitsuba's `sunsky` emitter
(src/scene/mitsuba/sunsky.rs). Little-endian float32, one table after
another, each in C order:

  sky_params_rgb  (turbidity 10, albedo 2, control point 6, channel 3, 9)
  sky_rad_rgb     (turbidity 10, albedo 2, control point 6, channel 3)
  sun_irradiance  (turbidity 10, elevation 30, wavelength 11: 320-720 nm)
  sun_rad_rgb     (turbidity 10, segment 45, channel 3, power 4, limb 6)

The tables are Lukas Hosek's and Alexander Wilkie's (3-clause BSD licence,
data/sunsky/LICENSE).

  python3 scripts/sunsky_tables.py
"""

import os
import struct
import sys

import numpy as np

DTYPES = {1: np.uint8, 2: np.int8, 3: np.uint16, 4: np.int16, 5: np.uint32, 6: np.int32,
          7: np.uint64, 8: np.int64, 9: np.float16, 10: np.float32, 11: np.float64}
TABLES = [("sunsky_datasets.bin", "sky_params_rgb", (10, 2, 6, 3, 9)),
          ("sunsky_datasets.bin", "sky_rad_rgb", (10, 2, 6, 3)),
          ("sampling_data.bin", "sun_irradiance", (10, 30, 11)),
          ("sunsky_datasets.bin", "sun_rad_rgb", (10, 45, 3, 4, 6))]


def read_tensor_file(path):
    """Mitsuba's TensorFile: a header of named fields, then their data."""
    b = open(path, "rb").read()
    if b[:12] != b"tensor_file\0":
        sys.exit(f"{path} is not a Mitsuba tensor file")
    (count,) = struct.unpack_from("<I", b, 14)
    at, fields = 18, {}
    for _ in range(count):
        (length,) = struct.unpack_from("<H", b, at)
        name = b[at + 2:at + 2 + length].decode()
        at += 2 + length
        ndim, dtype = struct.unpack_from("<HB", b, at)
        (offset,) = struct.unpack_from("<Q", b, at + 3)
        shape = struct.unpack_from(f"<{ndim}Q", b, at + 11)
        at += 11 + 8 * ndim
        fields[name] = np.frombuffer(b, DTYPES[dtype], int(np.prod(shape)), offset).reshape(shape)
    return fields


def main():
    import mitsuba
    src = os.path.join(os.path.dirname(mitsuba.__file__), "data", "sunsky")
    out = os.path.join(os.path.dirname(__file__), "..", "data", "sunsky", "hosek_wilkie_rgb.bin")
    files = {}
    with open(out, "wb") as f:
        for file, name, shape in TABLES:
            if file not in files:
                files[file] = read_tensor_file(os.path.join(src, file))
            table = files[file][name]
            if table.shape != shape:
                sys.exit(f"{name} has shape {table.shape}, not {shape}")
            f.write(table.astype("<f4").tobytes())
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
