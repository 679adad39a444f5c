"""Writes the PLY meshes with attributes that tests/fixtures/mitsuba/coverage-p.xml
uses (deterministic, from a fixed seed), binary little-endian:

- painted-sphere.ply: a UV sphere (16 rings, 32 segments) with normals, a
  float colour per vertex (r g b: Mitsuba's vertex_color) and two
  one-channel attributes per vertex (w_0, rough_0: vertex_w, vertex_rough);
- tiles.ply: a 6x6 grid of squares in the xy plane, each two triangles, a
  float colour per face (face_color) and a roughness per vertex
  (rough_0: vertex_rough).

    python3 scripts/make_attribute_fixtures.py tests/fixtures/mitsuba
"""
import sys
import numpy as np

out = sys.argv[1]
rng = np.random.default_rng(11)


def write_ply(path, vertex_fields, vertices, faces, face_fields=(), face_values=None):
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(vertices)}"]
    header += [f"property float {n}" for n in vertex_fields]
    header += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
    header += [f"property float {n}" for n in face_fields]
    header.append("end_header")
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode())
        v = np.asarray(vertices, dtype="<f4")
        f.write(v.tobytes())
        for i, face in enumerate(faces):
            f.write(np.uint8(3).tobytes())
            f.write(np.asarray(face, dtype="<i4").tobytes())
            if face_fields:
                f.write(np.asarray(face_values[i], dtype="<f4").tobytes())


# The sphere: rings from pole to pole, colours varying smoothly with the
# position, a blend weight in bands and a roughness rising towards a pole.
rings, segments = 16, 32
verts, faces = [], []
for i in range(rings + 1):
    theta = np.pi * i / rings
    for j in range(segments):
        phi = 2.0 * np.pi * j / segments
        n = np.array([np.sin(theta) * np.cos(phi), np.cos(theta), np.sin(theta) * np.sin(phi)])
        color = 0.1 + 0.8 * (0.5 + 0.5 * np.array([n[0], np.sin(3.0 * phi), n[1]]))
        w = 0.5 + 0.5 * np.cos(4.0 * theta)
        rough = 0.05 + 0.5 * (i / rings)
        verts.append([*n, *n, *color, w, rough])
for i in range(rings):
    for j in range(segments):
        a, b = i * segments + j, i * segments + (j + 1) % segments
        c, d = a + segments, b + segments
        if i > 0:
            faces.append([a, b, d])
        if i < rings - 1:
            faces.append([a, d, c])
write_ply(f"{out}/painted-sphere.ply",
          ["x", "y", "z", "nx", "ny", "nz", "r", "g", "b", "w_0", "rough_0"], verts, faces)

# The tiles: random colours per square, roughness per vertex.
n = 6
verts = []
for y in range(n + 1):
    for x in range(n + 1):
        verts.append([x / n * 2.0 - 1.0, y / n * 2.0 - 1.0, 0.0, 0.05 + 0.4 * ((x + y) % 3) / 2.0])
faces, colors = [], []
for y in range(n):
    for x in range(n):
        a = y * (n + 1) + x
        c = 0.05 + 0.9 * rng.random(3)
        faces += [[a, a + 1, a + n + 2], [a, a + n + 2, a + n + 1]]
        colors += [c, c * 0.6]
write_ply(f"{out}/tiles.ply", ["x", "y", "z", "rough_0"], verts, faces, ["r", "g", "b"], colors)
