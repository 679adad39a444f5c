#!/usr/bin/env python3
"""Generate the OBJ/MTL scene files for qtrace into ../scenes/.

Deterministic, standard library only.  Run:  python3 scripts/make_scenes.py

Conventions:
  * faces are triangles or quads (positions only);
  * the geometric normal (v1-v0)x(v2-v0) points INTO the visible side
    (room interiors for walls, outwards for boxes);
  * emitters are one-sided and emit along that normal.

After writing, the script re-reads every OBJ it wrote and runs an assertion
pass: no degenerate triangles, planar convex quads, every light normal points
in its specified direction, and (if the TOML files exist) a tiny ray caster
checks which surfaces the cameras see (e.g. that no camera ray hits a light
in the indirectly-lit scenes).
"""

import math
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = os.path.normpath(os.path.join(HERE, "..", "scenes"))

EPS_AREA = 1e-6

# --------------------------------------------------------------------------
# small vector helpers
# --------------------------------------------------------------------------


def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def mul(a, s):
    return (a[0] * s, a[1] * s, a[2] * s)


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def length(a):
    return math.sqrt(dot(a, a))


def normalize(a):
    l = length(a)
    return (a[0] / l, a[1] / l, a[2] / l)


def centroid(pts):
    n = float(len(pts))
    return (sum(p[0] for p in pts) / n, sum(p[1] for p in pts) / n, sum(p[2] for p in pts) / n)


def tri_normal(p0, p1, p2):
    return cross(sub(p1, p0), sub(p2, p0))


# --------------------------------------------------------------------------
# scene builder
# --------------------------------------------------------------------------


class Scene:
    def __init__(self, name):
        self.name = name
        self.materials = {}  # name -> (kd or None, ke or None, extra MTL lines)
        self.mat_order = []
        self.faces = []  # (group, material, [points])
        # expected emitter normals: material -> unit direction
        self.light_dirs = {}
        # checks: list of (group, kind, reference point) where kind is
        # "inward" (normal towards ref) or "outward" (normal away from ref)
        self.orient_checks = {}

    def material(self, name, kd, ke=None, extra=()):
        if name not in self.materials:
            self.mat_order.append(name)
        self.materials[name] = (kd, ke, tuple(extra))

    def face(self, group, mat, pts, want):
        """Add a polygon (3 or 4 points, in cyclic order), reordered so that
        its geometric normal has a positive component along `want`."""
        assert len(pts) in (3, 4)
        assert mat in self.materials, mat
        n = tri_normal(pts[0], pts[1], pts[2])
        if dot(n, want) < 0.0:
            pts = [pts[0]] + list(reversed(pts[1:]))
        n = normalize(tri_normal(pts[0], pts[1], pts[2]))
        assert dot(n, normalize(want)) > 0.0
        self.faces.append((group, mat, [tuple(float(c) for c in p) for p in pts]))

    # axis-aligned rectangle.  axis: 0/1/2 = x/y/z is constant at `value`;
    # (lo_a, hi_a) spans the first remaining axis, (lo_b, hi_b) the second
    # (remaining axes in increasing order: x->(y,z), y->(x,z), z->(x,y)).
    # sign: +1/-1, the normal points along +axis / -axis.
    def rect(self, group, mat, axis, value, span_a, span_b, sign):
        others = [i for i in range(3) if i != axis]
        a0, a1 = span_a
        b0, b1 = span_b
        corners = []
        for (a, b) in ((a0, b0), (a1, b0), (a1, b1), (a0, b1)):
            p = [0.0, 0.0, 0.0]
            p[axis] = value
            p[others[0]] = a
            p[others[1]] = b
            corners.append(tuple(p))
        want = [0.0, 0.0, 0.0]
        want[axis] = float(sign)
        self.face(group, mat, corners, tuple(want))

    def box(self, group, mat, center_xz, size_xz, y_range, angle_deg=0.0, bottom=True):
        """Box rotated about the vertical axis through center_xz by angle_deg
        (x' = x cos + z sin, z' = -x sin + z cos).  Outward normals."""
        cx, cz = center_xz
        hx, hz = size_xz[0] / 2.0, size_xz[1] / 2.0
        y0, y1 = y_range
        t = math.radians(angle_deg)
        c, s = math.cos(t), math.sin(t)

        def P(lx, lz, y):
            return (cx + lx * c + lz * s, y, cz - lx * s + lz * c)

        foot = [(-hx, -hz), (hx, -hz), (hx, hz), (-hx, hz)]
        self.box_from_corners(group, mat, [P(a, b, y0) for a, b in foot],
                              [P(a, b, y1) for a, b in foot], bottom)

    def box_from_corners(self, group, mat, lower, upper, bottom=True):
        """lower/upper: 4 footprint corners (cyclic) at the bottom/top."""
        ctr = centroid(lower + upper)
        faces = [upper]
        if bottom:
            faces.append(lower)
        for i in range(4):
            j = (i + 1) % 4
            faces.append([lower[i], lower[j], upper[j], upper[i]])
        for f in faces:
            self.face(group, mat, f, sub(centroid(f), ctr))
        self.orient_checks[group] = ("outward", ctr)

    def write(self, directory):
        os.makedirs(directory, exist_ok=True)
        mtl_path = os.path.join(directory, self.name + ".mtl")
        obj_path = os.path.join(directory, self.name + ".obj")
        with open(mtl_path, "w", newline="\n") as f:
            f.write("# qtrace scene '%s' (generated by scripts/make_scenes.py)\n" % self.name)
            for m in self.mat_order:
                kd, ke, extra = self.materials[m]
                f.write("\nnewmtl %s\n" % m)
                if kd is not None:
                    f.write("Kd %s\n" % " ".join(fmt(v) for v in kd))
                if ke is not None:
                    f.write("Ke %s\n" % " ".join(fmt(v) for v in ke))
                for line in extra:
                    f.write(line + "\n")
        verts = []
        index = {}
        face_lines = []
        cur = (None, None)
        for group, mat, pts in self.faces:
            if (group, mat) != cur:
                face_lines.append("o %s" % group)
                face_lines.append("usemtl %s" % mat)
                cur = (group, mat)
            ids = []
            for p in pts:
                key = tuple(fmt(v) for v in p)
                if key not in index:
                    verts.append(key)
                    index[key] = len(verts)
                ids.append(str(index[key]))
            face_lines.append("f " + " ".join(ids))
        with open(obj_path, "w", newline="\n") as f:
            f.write("mtllib %s.mtl\n" % self.name)
            f.write("# qtrace scene '%s' (generated by scripts/make_scenes.py)\n" % self.name)
            for v in verts:
                f.write("v %s\n" % " ".join(v))
            for line in face_lines:
                f.write(line + "\n")
        return obj_path, mtl_path


def fmt(v):
    s = "%.4f" % v
    s = s.rstrip("0").rstrip(".")
    if s in ("-0", ""):
        s = "0"
    return s


# --------------------------------------------------------------------------
# shared pieces
# --------------------------------------------------------------------------

W, H, D = 556.0, 548.8, 559.2  # Cornell room extents (x, y, z)
ROOM_CENTER = (W / 2, H / 2, D / 2)

RED = (0.63, 0.065, 0.05)
GREEN = (0.14, 0.45, 0.091)
WHITE = (0.725, 0.71, 0.68)
LIGHT_KD = (0.78, 0.78, 0.78)

DOWN, UP = (0.0, -1.0, 0.0), (0.0, 1.0, 0.0)
PX, NX, PZ, NZ = (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, 0.0, -1.0)


def cornell_room(sc, left="red", right="green", white="white"):
    """Open-front (z=0) room, normals towards the interior."""
    sc.rect("floor", white, 1, 0.0, (0, W), (0, D), +1)
    sc.rect("ceiling", white, 1, H, (0, W), (0, D), -1)
    sc.rect("back_wall", white, 2, D, (0, W), (0, H), -1)
    sc.rect("left_wall", left, 0, W, (0, H), (0, D), -1)    # x=556, appears on the left
    sc.rect("right_wall", right, 0, 0.0, (0, H), (0, D), +1)  # x=0, appears on the right
    for g in ("floor", "ceiling", "back_wall", "left_wall", "right_wall"):
        sc.orient_checks[g] = ("inward", ROOM_CENTER)


def cornell_light(sc):
    sc.material("light", LIGHT_KD, (17.0, 12.0, 4.0))
    sc.rect("light", "light", 1, 548.7, (213.0, 343.0), (227.0, 332.0), -1)
    sc.light_dirs["light"] = DOWN


# --------------------------------------------------------------------------
# scenes
# --------------------------------------------------------------------------


def cornell_scene(name, blocks=()):
    """A Cornell room with its light, its three colours, and the materials
    `blocks` name (name, MTL lines) for the short and tall blocks."""
    sc = Scene(name)
    sc.material("white", WHITE)
    sc.material("red", RED)
    sc.material("green", GREEN)
    for material, lines in blocks:
        sc.material(material, None, extra=lines)
    cornell_room(sc)
    cornell_light(sc)
    return sc


def short_box(sc, mat):
    sc.box("short_box", mat, (185.0, 169.0), (165.0, 165.0), (0.0, 165.0), -17.0, bottom=False)


def tall_box(sc, mat, y_range=(0.0, 330.0), bottom=False):
    sc.box("tall_box", mat, (368.0, 351.0), (165.0, 165.0), y_range, 17.0, bottom=bottom)


def make_cornell_box():
    sc = cornell_scene("cornell-box")
    short_box(sc, "white")
    tall_box(sc, "white")
    return sc


def blocked_light_and_box(sc, box_material):
    """The indirectly lit room's contents: a blocker slab high near the back
    wall, the light just above it facing the ceiling, and a floor box."""
    # opaque blocker slab (closed box, outward normals)
    sc.box_from_corners(
        "blocker", "white",
        [(178.0, 380.0, 300.0), (378.0, 380.0, 300.0), (378.0, 380.0, 500.0), (178.0, 380.0, 500.0)],
        [(178.0, 400.0, 300.0), (378.0, 400.0, 300.0), (378.0, 400.0, 500.0), (178.0, 400.0, 500.0)],
        bottom=True)
    sc.rect("light", "light", 1, 400.5, (198.0, 358.0), (320.0, 480.0), +1)
    sc.light_dirs["light"] = UP
    sc.box("floor_box", box_material, (200.0, 170.0), (120.0, 120.0), (0.0, 120.0), 20.0,
           bottom=False)


def make_indirect_room():
    sc = Scene("indirect-room")
    sc.material("white", (0.7, 0.7, 0.7))
    sc.material("light", LIGHT_KD, (20.0, 20.0, 20.0))
    cornell_room(sc, left="white", right="white", white="white")
    blocked_light_and_box(sc, "white")
    return sc


def make_complex_direct():
    return cornell_scene("complex-direct")


# door-ajar geometry
DA_WALL_X0 = 556.0      # shared wall, viewer side
DA_WALL_X1 = 560.0      # shared wall, light-room side (wall is 4 units thick)
DA_FAR_X = 900.0        # light room far wall
DA_HOLE_Z = (180.0, 330.0)
DA_HOLE_Y = 400.0
DA_DOOR_ANGLE = 20.0
DA_DOOR_THICK = 4.0


def make_door_ajar():
    sc = Scene("door-ajar")
    sc.material("white", WHITE)
    sc.material("door", (0.6, 0.5, 0.4))
    sc.material("light", LIGHT_KD, (30.0, 30.0, 30.0))
    z0, z1 = DA_HOLE_Z
    # ---- viewer room x 0..556, open front at z=0 ----
    vc = (W / 2, H / 2, D / 2)
    sc.rect("v_floor", "white", 1, 0.0, (0, W), (0, D), +1)
    sc.rect("v_ceiling", "white", 1, H, (0, W), (0, D), -1)
    sc.rect("v_back_wall", "white", 2, D, (0, W), (0, H), -1)
    sc.rect("v_right_wall", "white", 0, 0.0, (0, H), (0, D), +1)
    for g in ("v_floor", "v_ceiling", "v_back_wall", "v_right_wall"):
        sc.orient_checks[g] = ("inward", vc)
    # shared wall, viewer side (normal -x), quads around the door hole
    for g, x, sign, ref in (("shared_wall_viewer", DA_WALL_X0, -1, vc),
                            ("shared_wall_lightroom", DA_WALL_X1, +1, None)):
        sc.rect(g, "white", 0, x, (0.0, H), (0.0, z0), sign)
        sc.rect(g, "white", 0, x, (0.0, H), (z1, D), sign)
        sc.rect(g, "white", 0, x, (DA_HOLE_Y, H), (z0, z1), sign)
    # door jambs / lintel inside the 4-unit-thick wall (normals into the hole)
    sc.rect("door_frame", "white", 2, z0, (DA_WALL_X0, DA_WALL_X1), (0.0, DA_HOLE_Y), +1)
    sc.rect("door_frame", "white", 2, z1, (DA_WALL_X0, DA_WALL_X1), (0.0, DA_HOLE_Y), -1)
    sc.rect("door_frame", "white", 1, DA_HOLE_Y, (DA_WALL_X0, DA_WALL_X1), (z0, z1), -1)
    # threshold: floor strip under the opening (the wall is 4 units thick)
    sc.rect("door_frame", "white", 1, 0.0, (DA_WALL_X0, DA_WALL_X1), (z0, z1), +1)
    sc.orient_checks["shared_wall_viewer"] = ("inward", vc)
    # ---- light room x 560..900, fully closed ----
    lc = ((DA_WALL_X1 + DA_FAR_X) / 2, H / 2, D / 2)
    sc.rect("l_floor", "white", 1, 0.0, (DA_WALL_X1, DA_FAR_X), (0, D), +1)
    sc.rect("l_ceiling", "white", 1, H, (DA_WALL_X1, DA_FAR_X), (0, D), -1)
    sc.rect("l_back_wall", "white", 2, D, (DA_WALL_X1, DA_FAR_X), (0, H), -1)
    sc.rect("l_front_wall", "white", 2, 0.0, (DA_WALL_X1, DA_FAR_X), (0, H), +1)
    sc.rect("l_far_wall", "white", 0, DA_FAR_X, (0, H), (0, D), -1)
    for g in ("l_floor", "l_ceiling", "l_back_wall", "l_front_wall", "l_far_wall",
              "shared_wall_lightroom"):
        sc.orient_checks[g] = ("inward", lc)
    # ceiling light 150x150 in the middle of the light room, facing down
    lx, lz = lc[0], lc[2]
    sc.rect("light", "light", 1, 548.7, (lx - 75.0, lx + 75.0), (lz - 75.0, lz + 75.0), -1)
    sc.light_dirs["light"] = DOWN
    # door panel: hinged at (x=560, z=180), 150 wide, 400 high, 4 thick,
    # swung open by DA_DOOR_ANGLE into the light room
    t = math.radians(DA_DOOR_ANGLE)
    d = (math.sin(t), 0.0, math.cos(t))     # along the panel (hinge -> free edge)
    n = (math.cos(t), 0.0, -math.sin(t))    # panel thickness, into the light room
    hinge = (DA_WALL_X1, 0.0, z0)
    width = z1 - z0
    foot = [hinge, add(hinge, mul(d, width)),
            add(add(hinge, mul(d, width)), mul(n, DA_DOOR_THICK)), add(hinge, mul(n, DA_DOOR_THICK))]
    sc.box_from_corners("door", "door", foot, [add(p, (0.0, DA_HOLE_Y, 0.0)) for p in foot],
                        bottom=True)
    return sc


def make_several_lights():
    sc = Scene("several-lights")
    sc.material("white", WHITE)
    sc.material("light_ceiling", LIGHT_KD, (40.0, 35.0, 30.0))
    sc.material("light_warm", LIGHT_KD, (6.0, 3.0, 1.0))
    sc.material("light_blue", LIGHT_KD, (1.0, 2.0, 6.0))
    cornell_room(sc, left="white", right="white", white="white")
    # small bright ceiling quad, 60x60, facing down
    sc.rect("light_ceiling", "light_ceiling", 1, 548.7, (320.0, 380.0), (200.0, 260.0), -1)
    sc.light_dirs["light_ceiling"] = DOWN
    # tall thin warm strip on the back wall, facing the camera (-z)
    sc.rect("light_warm", "light_warm", 2, 559.1, (80.0, 120.0), (60.0, 460.0), -1)
    sc.light_dirs["light_warm"] = NZ
    # bluish panel on the x=556 wall (left in the picture), facing -x
    sc.rect("light_blue", "light_blue", 0, 555.9, (220.0, 360.0), (150.0, 400.0), -1)
    sc.light_dirs["light_blue"] = NX
    sc.box("box_a", "white", (180.0, 190.0), (140.0, 140.0), (0.0, 140.0), -20.0, bottom=False)
    sc.box("box_b", "white", (390.0, 370.0), (120.0, 120.0), (0.0, 260.0), 15.0, bottom=False)
    return sc


def make_furnace():
    sc = Scene("furnace")
    sc.material("white", (1.0, 1.0, 1.0))
    c = (50.0, 50.0, 50.0)
    sc.rect("floor", "white", 1, 0.0, (0, 100), (0, 100), +1)
    sc.rect("ceiling", "white", 1, 100.0, (0, 100), (0, 100), -1)
    sc.rect("back_wall", "white", 2, 100.0, (0, 100), (0, 100), -1)
    sc.rect("left_wall", "white", 0, 100.0, (0, 100), (0, 100), -1)
    sc.rect("right_wall", "white", 0, 0.0, (0, 100), (0, 100), +1)
    for g in ("floor", "ceiling", "back_wall", "left_wall", "right_wall"):
        sc.orient_checks[g] = ("inward", c)
    return sc


def conductor(ks, pr):
    """MTL lines of a GGX conductor (docs/scenes.md): reflectance Ks, roughness Pr."""
    return ("Pm 1", "Ks %s" % " ".join(fmt(v) for v in ks), "Pr %s" % fmt(pr))


def glass(ni, tf=(1.0, 1.0, 1.0)):
    """MTL lines of a smooth dielectric (docs/scenes.md)."""
    return ("Ni %s" % fmt(ni), "d 0", "Tf %s" % " ".join(fmt(v) for v in tf))


def make_glossy_cornell():
    """The Cornell box with metal blocks: a rough gold short box and a
    polished steel tall box; lit directly."""
    sc = cornell_scene("glossy-cornell", [("gold", conductor((0.95, 0.75, 0.35), 0.55)),
                                          ("steel", conductor((0.85, 0.85, 0.85), 0.3))])
    short_box(sc, "gold")
    tall_box(sc, "steel")
    return sc


def make_glossy_room():
    """The indirectly lit room with a brushed-metal ceiling: the light faces
    the ceiling, so most light reaches the camera by glossy reflection."""
    sc = Scene("glossy-room")
    sc.material("white", (0.7, 0.7, 0.7))
    sc.material("metal_ceiling", None, extra=conductor((0.9, 0.9, 0.9), 0.4))
    sc.material("copper", None, extra=conductor((0.95, 0.64, 0.54), 0.25))
    sc.material("light", LIGHT_KD, (20.0, 20.0, 20.0))
    cornell_room(sc, left="white", right="white", white="white")
    # the ceiling is metal: replace the white one cornell_room made
    sc.faces = [f for f in sc.faces if f[0] != "ceiling"]
    sc.rect("ceiling", "metal_ceiling", 1, H, (0, W), (0, D), -1)
    blocked_light_and_box(sc, "copper")
    return sc


def make_glass_cornell():
    """The Cornell box with a glass tall block and a mirror short block."""
    sc = cornell_scene("glass-cornell", [("glass", glass(1.5, (0.95, 0.98, 0.95))),
                                         ("mirror", conductor((0.9, 0.9, 0.9), 0.0))])
    short_box(sc, "mirror")
    # closed (with a bottom), so that inside and outside are well defined
    tall_box(sc, "glass", (0.5, 330.0), bottom=True)
    return sc


BUILDERS = [make_cornell_box, make_indirect_room, make_complex_direct, make_door_ajar,
            make_several_lights, make_furnace, make_glossy_cornell, make_glossy_room,
            make_glass_cornell]


# --------------------------------------------------------------------------
# verification (re-reads the written files)
# --------------------------------------------------------------------------


def read_mtl(path):
    mats, cur = {}, None
    with open(path) as f:
        for line in f:
            p = line.split()
            if not p or p[0].startswith("#"):
                continue
            if p[0] == "newmtl":
                cur = p[1]
                mats[cur] = {"Kd": (0.0, 0.0, 0.0), "Ke": (0.0, 0.0, 0.0)}
            elif p[0] in ("Kd", "Ke"):
                mats[cur][p[0]] = tuple(float(x) for x in p[1:4])
    return mats


def read_obj(path):
    """Returns (mtllib, [(group, material, [pts])])."""
    verts, faces = [], []
    group, mat, mtllib = None, None, None
    with open(path) as f:
        first = f.readline().split()
        assert first[0] == "mtllib", "%s must start with mtllib" % path
        mtllib = first[1]
        for line in f:
            p = line.split()
            if not p or p[0].startswith("#"):
                continue
            if p[0] == "v":
                verts.append(tuple(float(x) for x in p[1:4]))
            elif p[0] == "o":
                group = p[1]
            elif p[0] == "usemtl":
                mat = p[1]
            elif p[0] == "f":
                idx = [int(x) for x in p[1:]]
                assert len(idx) in (3, 4), line
                faces.append((group, mat, [verts[i - 1] for i in idx]))
    return mtllib, faces


def triangulate(pts):
    if len(pts) == 3:
        return [tuple(pts)]
    return [(pts[0], pts[1], pts[2]), (pts[0], pts[2], pts[3])]


def ray_tri(o, d, tri):
    """Moller-Trumbore; returns t or None."""
    p0, p1, p2 = tri
    e1, e2 = sub(p1, p0), sub(p2, p0)
    pv = cross(d, e2)
    det = dot(e1, pv)
    if abs(det) < 1e-12:
        return None
    inv = 1.0 / det
    tv = sub(o, p0)
    u = dot(tv, pv) * inv
    if u < 0.0 or u > 1.0:
        return None
    qv = cross(tv, e1)
    v = dot(d, qv) * inv
    if v < 0.0 or u + v > 1.0:
        return None
    t = dot(e2, qv) * inv
    return t if t > 1e-6 else None


def ray_sphere(o, d, c, r):
    oc = sub(o, c)
    b = dot(oc, d)
    cc = dot(oc, oc) - r * r
    disc = b * b - cc
    if disc < 0.0:
        return None
    s = math.sqrt(disc)
    for t in (-b - s, -b + s):
        if t > 1e-6:
            return t
    return None


def cast(o, d, tris, spheres=()):
    """Closest hit: returns (t, kind, payload) or None.  kind 'tri' payload =
    (group, material, normal); kind 'sphere' payload = index."""
    best = None
    for group, mat, tri, n in tris:
        t = ray_tri(o, d, tri)
        if t is not None and (best is None or t < best[0]):
            best = (t, "tri", (group, mat, n))
    for i, (c, r) in enumerate(spheres):
        t = ray_sphere(o, d, c, r)
        if t is not None and (best is None or t < best[0]):
            best = (t, "sphere", i)
    return best


def camera_rays(cam, nx, ny, aspect=1.0):
    pos = tuple(cam["position"])
    fwd = normalize(sub(tuple(cam["look_at"]), pos))
    right = normalize(cross(fwd, tuple(cam["up"])))
    up = cross(right, fwd)
    th = math.tan(math.radians(cam["fov_y"]) / 2.0)
    for j in range(ny):
        for i in range(nx):
            sx = ((i + 0.5) / nx * 2.0 - 1.0) * th * aspect
            sy = (1.0 - (j + 0.5) / ny * 2.0) * th
            yield i, j, pos, normalize(add(fwd, add(mul(right, sx), mul(up, sy))))


def verify(scenes):
    print("\nverification:")
    counts = {}
    for sc in scenes:
        obj = os.path.join(SCENES, sc.name + ".obj")
        mtl = os.path.join(SCENES, sc.name + ".mtl")
        mtllib, faces = read_obj(obj)
        assert mtllib == sc.name + ".mtl"
        mats = read_mtl(mtl)
        ntri = 0
        for group, mat, pts in faces:
            assert mat in mats, (sc.name, mat)
            tris = triangulate(pts)
            n0 = normalize(tri_normal(*tris[0]))
            for tri in tris:
                n = tri_normal(*tri)
                area = 0.5 * length(n)
                assert area > EPS_AREA, ("degenerate triangle", sc.name, group, tri)
                # quads must be planar and convex: both halves agree
                assert dot(normalize(n), n0) > 1.0 - 1e-9, ("non-planar/concave quad", sc.name, group)
                ntri += 1
            # orientation checks for rooms / boxes
            chk = sc.orient_checks.get(group)
            if chk is not None:
                kind, ref = chk
                s = dot(n0, sub(ref, centroid(pts)))
                if kind == "inward":
                    assert s > 0.0, ("wall normal not facing interior", sc.name, group, pts)
                else:
                    assert s < 0.0, ("box normal not outward", sc.name, group, pts)
            # light normals
            ke = mats[mat]["Ke"]
            if max(ke) > 0.0:
                want = sc.light_dirs[mat]
                assert dot(n0, want) > 0.999999, ("light normal wrong", sc.name, mat, n0, want)
        lights = sorted({m for _, m, _ in faces if max(mats[m]["Ke"]) > 0.0})
        for m in lights:
            print("  %-16s light %-14s Ke=%-18s normal=%s OK" % (
                sc.name, m, " ".join(fmt(x) for x in mats[m]["Ke"]), sc.light_dirs[m]))
        assert set(lights) == set(sc.light_dirs), (sc.name, lights)
        counts[sc.name] = ntri
    print("\ntriangle counts:")
    for name, n in counts.items():
        print("  %-16s %6d" % (name, n))
    verify_visibility(scenes)


def load_toml(name):
    path = os.path.join(SCENES, name + ".toml")
    if not os.path.exists(path):
        return None
    try:
        import tomllib
    except ImportError:  # Python < 3.11
        return None
    with open(path, "rb") as f:
        return tomllib.load(f)


def scene_tris(name):
    _, faces = read_obj(os.path.join(SCENES, name + ".obj"))
    out = []
    for group, mat, pts in faces:
        for tri in triangulate(pts):
            out.append((group, mat, tri, normalize(tri_normal(*tri))))
    return out


def verify_visibility(scenes):
    """Low-resolution ray casts from the TOML cameras (only if TOMLs exist)."""
    names = [sc.name for sc in scenes]
    light_mats = {sc.name: set(sc.light_dirs) for sc in scenes}
    print("\ncamera checks (32x32 primary rays):")
    for name in names:
        cfg = load_toml(name)
        if cfg is None:
            print("  %-16s (no TOML yet, skipped)" % name)
            continue
        assert cfg["mesh"] == name + ".obj"
        tris = scene_tris(name)
        spheres = [(tuple(p["center"]), p["radius"] + p["amplitude"])
                   for p in cfg.get("procedural", [])]
        aspect = cfg["render"]["width"] / float(cfg["render"]["height"])
        hits = {}
        n = 32
        left_hit = None
        for i, j, o, d in camera_rays(cfg["camera"], n, n, aspect):
            h = cast(o, d, tris, spheres)
            if h is None:
                key = "<sky>"
            elif h[1] == "sphere":
                key = "<sphere%d>" % h[2]
            else:
                group, mat, nrm = h[2]
                key = group
                # the visible side must be the front side
                assert dot(nrm, d) < 0.0, ("camera sees back side", name, group)
            hits[key] = hits.get(key, 0) + 1
            if (i, j) == (0, n // 2):
                left_hit = key
        seen_lights = {k for k in hits if k in light_mats[name]}
        summary = ", ".join("%s:%d" % kv for kv in sorted(hits.items()))
        print("  %-16s %s" % (name, summary))
        print("  %-16s leftmost-middle pixel hits %s; lights seen directly: %s" % (
            "", left_hit, sorted(seen_lights) or "none"))
        if name in ("cornell-box", "complex-direct"):
            assert left_hit == "left_wall", "red wall (x=556) must appear on the left"
        if name in ("indirect-room", "door-ajar"):
            assert not seen_lights, "%s: camera sees the light directly" % name
        if name == "furnace":
            assert "<sky>" in hits
        if name == "door-ajar":
            into = sum(v for k, v in hits.items() if k.startswith("l_"))
            assert into > 0, "door-ajar: the door gap is not visible"
            print("  %-16s primary rays seeing light-room surfaces through the gap: %d/%d" % ("", into, n * n))
    # indirect-room: the floor must not see the light (it is one-sided, facing up,
    # and everything below y=400.5 is behind it) - check a few floor points
    if "indirect-room" in names:
        tris = scene_tris("indirect-room")
        lt = [t for t in tris if t[1] == "light"]
        for fx in (50.0, 278.0, 500.0):
            for fz in (50.0, 280.0, 540.0):
                p = (fx, 0.01, fz)
                for _, _, tri, nrm in lt:
                    q = centroid(tri)
                    assert dot(nrm, sub(p, q)) < 0.0  # floor is behind the emitter
        print("  indirect-room    floor points all lie behind the upward-facing light: OK")


def main():
    scenes = []
    for b in BUILDERS:
        sc = b()
        obj, mtl = sc.write(SCENES)
        print("wrote %s, %s" % (os.path.relpath(obj), os.path.relpath(mtl)))
        scenes.append(sc)
    verify(scenes)
    print("\nall checks passed")


if __name__ == "__main__":
    sys.exit(main())
