#!/usr/bin/env python3
"""Writes a large binary PLY mesh and a Mitsuba XML scene around it, for
measuring how qtrace loads real-sized scenes (docs/mitsuba.md, "Scale").

  python3 scripts/make_big_ply.py OUT_DIR TRIANGLES

OUT_DIR/big.ply is a rippled sphere of about TRIANGLES triangles with vertex
normals (binary little-endian, float positions and normals, int indices);
OUT_DIR/big.xml renders it in a box lit by an area light. Needs numpy.
"""

import os
import sys

import numpy as np


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    out, triangles = sys.argv[1], int(sys.argv[2])
    os.makedirs(out, exist_ok=True)
    # A UV sphere of n rings and 2n segments has about 4 n^2 triangles.
    n = max(4, int(round((triangles / 4) ** 0.5)))
    rings, segments = n, 2 * n
    theta = np.linspace(0, np.pi, rings + 1)[:, None]
    phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)[None, :]
    r = 1.0 + 0.05 * np.sin(8 * theta) * np.sin(8 * phi)
    x = (r * np.sin(theta) * np.cos(phi)).ravel()
    y = (r * np.cos(theta) * np.ones_like(phi)).ravel()
    z = (r * np.sin(theta) * np.sin(phi)).ravel()
    pos = np.stack([x, y, z], axis=1).astype(np.float32)
    nrm = pos / np.linalg.norm(pos, axis=1, keepdims=True)
    i = np.arange(rings)[:, None]
    j = np.arange(segments)[None, :]
    a = i * segments + j
    b = i * segments + (j + 1) % segments
    c = (i + 1) * segments + j
    d = (i + 1) * segments + (j + 1) % segments
    faces = np.concatenate([np.stack([a, b, c], -1)[1:], np.stack([b, d, c], -1)[:-1]], axis=0)
    faces = faces.reshape(-1, 3).astype(np.int32)
    vertex = np.zeros(len(pos), dtype=[("p", "<f4", 3), ("n", "<f4", 3)])
    vertex["p"], vertex["n"] = pos, nrm
    face = np.zeros(len(faces), dtype=[("k", "u1"), ("i", "<i4", 3)])
    face["k"], face["i"] = 3, faces
    with open(os.path.join(out, "big.ply"), "wb") as f:
        f.write((
            "ply\nformat binary_little_endian 1.0\n"
            f"element vertex {len(pos)}\nproperty float x\nproperty float y\nproperty float z\n"
            "property float nx\nproperty float ny\nproperty float nz\n"
            f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
        ).encode())
        f.write(vertex.tobytes())
        f.write(face.tobytes())
    with open(os.path.join(out, "big.xml"), "w") as f:
        f.write("""<scene version="3.0.0">
	<integrator type="path"><integer name="max_depth" value="8"/></integrator>
	<sensor type="perspective">
		<float name="fov" value="45"/>
		<transform name="to_world"><lookat origin="0, 0.5, 2.8" target="0, 0, 0"/></transform>
		<film type="hdrfilm"><integer name="width" value="256"/><integer name="height" value="256"/></film>
	</sensor>
	<shape type="ply">
		<string name="filename" value="big.ply"/>
		<bsdf type="twosided"><bsdf type="diffuse"/></bsdf>
	</shape>
	<shape type="cube">
		<transform name="to_world"><scale value="3"/></transform>
		<bsdf type="twosided"><bsdf type="diffuse"/></bsdf>
	</shape>
	<shape type="rectangle">
		<transform name="to_world"><rotate x="1" angle="90"/><scale value="0.5"/><translate y="2.9"/></transform>
		<bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>
		<emitter type="area"><rgb name="radiance" value="20"/></emitter>
	</shape>
</scene>
""")
    print(f"{out}/big.ply: {len(pos)} vertices, {len(faces)} triangles")


if __name__ == "__main__":
    main()
