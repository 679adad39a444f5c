#!/usr/bin/env python3
"""Render a qtrace scene with Mitsuba 3 (llvm_ad_rgb) and print its samples/s.

A peer measurement for `qtrace bench --speed`; no test depends on it.

  python3 scripts/mitsuba_speed.py SCENE.toml [--width W] [--height H]
      [--spp N] [--max-depth D] [--batches B] [--exr OUT.exr]

Renders B+1 times with the same settings and different seeds, drops the first
(it pays for JIT compilation) and prints one JSON line on stdout.

Needs Python >= 3.11 (tomllib), `pip install mitsuba` and an LLVM shared
library (Debian 12: `apt-get install libllvm19`); DRJIT_LIBLLVM_PATH is set to
Debian's libLLVM-19 when unset.

The scene is rebuilt to match qtrace's estimator in expectation:
  * the same triangles (OBJ polygons fanned like qtrace's loader, procedural
    bumpy spheres regenerated), flat-shaded, one mesh per material;
  * diffuse surfaces and conductors scatter on both sides (qtrace shades
    with the normal facing the ray), so their BSDFs are wrapped in
    `twosided`; materials as docs/scenes.md maps them: `Pm 1` is `roughconductor`
    (GGX, alpha = Pr^2, `material none`, `specular_reflectance` Ks) or
    `conductor` for Pr 0, and `d 0` with `Ni` > 1 is `dielectric`
    (`int_ior` Ni, `specular_transmittance` Tf; the normal's side is outside);
  * emitters emit on the side of (v1-v0)x(v2-v0), which is Mitsuba's face
    normal for the same vertex order, so the OBJ winding carries over;
  * qtrace ends a path at any emitter it hits; here emissive meshes get a
    black BSDF, which ends the path just the same (no reflection, no NEE);
  * pinhole camera with vertical FOV, box filter, independent sampler;
  * `path` integrator: NEE with power-heuristic MIS, like `qtrace --nee`.
"""

import argparse
import json
import math
import os
import statistics
import sys
import time
from array import array

try:
    import tomllib
except ImportError:  # Python < 3.11
    tomllib = None

# Debian 12's libllvm19; Dr.Jit otherwise only looks for a plain libLLVM.so.
DEBIAN_LIBLLVM = ("/usr/lib/x86_64-linux-gnu/libLLVM-19.so",
                  "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")

# qtrace shades diffuse faces of a material without Kd with this albedo, and
# faces without a material at all with the same grey.
DEFAULT_ALBEDO = (0.8, 0.8, 0.8)

# qtrace's kernel applies Russian roulette after sampling the bounce at hit
# index d (0-based) when d + 1 >= 3, with q = min(max(throughput), 0.95).
# Mitsuba's `path` increments its depth after that bounce (depth = d + 1) and
# applies the same q when depth >= rr_depth, so rr_depth = 3.
RR_DEPTH = 3

SETUP_HINT = ("set up with `apt-get install libllvm19` and `pip install mitsuba`, "
              "and point DRJIT_LIBLLVM_PATH at libLLVM "
              "(e.g. /usr/lib/x86_64-linux-gnu/libLLVM-19.so)")


def fail(message, status=2):
    print(f"mitsuba_speed: {message}", file=sys.stderr)
    sys.exit(status)


class Parser(argparse.ArgumentParser):
    # One line and status 2 on a bad argument, not argparse's usage block.
    def error(self, message):
        fail(message)


def parse_args():
    p = Parser(description="Render a qtrace scene with Mitsuba 3 and print samples/s as JSON.")
    p.add_argument("scene", help="scene file: qtrace TOML, or Mitsuba XML")
    p.add_argument("--width", type=int, help="image width (default: scene's [render], else 256)")
    p.add_argument("--height", type=int, help="image height (default: scene's [render], else 256)")
    p.add_argument("--spp", type=int, default=32, help="samples per pixel per batch (default 32)")
    p.add_argument("--max-depth", type=int,
                   help="qtrace's max depth (default: scene's [render], else 64)")
    p.add_argument("--batches", type=int, default=4, help="timed batches (default 4)")
    p.add_argument("--exr", help="write the last batch's image here (linear RGB EXR)")
    p.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE",
                   help="a parameter of an XML scene, as mitsuba's -D")
    return p.parse_args()


def load_xml(mi, path, defines, width, height, max_depth):
    """A Mitsuba XML scene as the file has it, but for the film's size and
    the path length qtrace renders it with (and Russian roulette from
    RR_DEPTH, as for TOML scenes). Their values may be $parameters, which
    are given here as numbers."""
    import xml.etree.ElementTree as ET
    tree = ET.parse(path)
    root = tree.getroot()
    for film in root.iter("film"):
        for el in film.findall("integer"):
            if el.get("name") == "width":
                el.set("value", str(width))
            elif el.get("name") == "height":
                el.set("value", str(height))
    for integrator in root.findall("integrator"):
        for el in list(integrator):
            if el.get("name") in ("max_depth", "rr_depth"):
                integrator.remove(el)
        ET.SubElement(integrator, "integer", name="max_depth", value=str(max_depth + 1))
        ET.SubElement(integrator, "integer", name="rr_depth", value=str(RR_DEPTH))
    params = {}
    for d in defines:
        k, sep, v = d.partition("=")
        if not sep:
            fail(f"-D {d}: expected NAME=VALUE")
        params[k] = v
    mi.Thread.thread().file_resolver().prepend(os.path.dirname(os.path.abspath(path)))
    try:
        return mi.load_string(ET.tostring(root, encoding="unicode"), **params)
    except Exception as e:
        fail(f"{path}: Mitsuba cannot load it: {str(e).splitlines()[0]}")


# --------------------------------------------------------------------------
# Scene file
# --------------------------------------------------------------------------

TOP_KEYS = {"mesh", "environment", "camera", "render", "procedural"}
CAMERA_KEYS = {"position", "look_at", "up", "fov_y"}
RENDER_KEYS = {"width", "height", "spp", "max_depth"}
BUMPY_KEYS = {"kind", "center", "radius", "segments", "rings", "amplitude", "frequency", "albedo"}


def check_keys(path, table, allowed, where):
    unknown = sorted(set(table) - allowed)
    if unknown:
        fail(f"{path}: unknown key {unknown[0]!r} in {where}")


def vec3(path, value, what):
    if (not isinstance(value, list) or len(value) != 3
            or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in value)):
        fail(f"{path}: {what} must be three finite numbers")
    return tuple(float(v) for v in value)


def read_scene_file(path):
    if tomllib is None:
        fail("needs Python >= 3.11 (tomllib) to read scene files")
    try:
        with open(path, "rb") as f:
            doc = tomllib.load(f)
    except OSError as e:
        fail(f"{path}: cannot read scene: {e.strerror}")
    except tomllib.TOMLDecodeError as e:
        fail(f"{path}: {e}")
    check_keys(path, doc, TOP_KEYS, "the scene")
    if "camera" not in doc:
        fail(f"{path}: missing [camera]")
    check_keys(path, doc["camera"], CAMERA_KEYS, "[camera]")
    check_keys(path, doc.get("render", {}), RENDER_KEYS, "[render]")
    for p in doc.get("procedural", []):
        if p.get("kind") != "bumpy-sphere":
            fail(f"{path}: procedural kind {p.get('kind')!r} is not supported")
        check_keys(path, p, BUMPY_KEYS, "[[procedural]]")
    return doc


def surface_of(keys):
    """The surface docs/scenes.md gives an MTL material's keys, as a hashable tuple:
    ("diffuse", Kd), ("conductor", Ks, alpha) or ("dielectric", Ni, Tf)."""
    if keys.get("d", 1.0) == 0.0 and keys.get("Ni", 1.0) > 1.0:
        return ("dielectric", keys["Ni"], keys.get("Tf", (1.0, 1.0, 1.0)))
    if keys.get("Pm", 0.0) == 1.0:
        return ("conductor", keys.get("Ks", (1.0, 1.0, 1.0)), keys.get("Pr", 0.0) ** 2)
    return ("diffuse", keys.get("Kd", DEFAULT_ALBEDO))


def read_mtl(path):
    """Material name -> (surface, emission), defaulting like qtrace's loader
    (which also checks the values; qtrace renders the scene first)."""
    materials = {}
    current = None
    try:
        lines = open(path, encoding="utf-8").read().splitlines()
    except OSError as e:
        fail(f"{path}: cannot read MTL: {e.strerror}")
    for line in lines:
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        if parts[0] == "newmtl":
            current = " ".join(parts[1:])
            materials[current] = {}
        elif current is None:
            continue
        elif parts[0] in ("Kd", "Ke", "Ks", "Tf"):
            values = [float(v) for v in parts[1:4]]
            materials[current][parts[0]] = tuple(values * 3 if len(values) == 1 else values)
        elif parts[0] in ("Pm", "Pr", "Ni", "d"):
            materials[current][parts[0]] = float(parts[1])
        elif parts[0] == "Tr":
            materials[current]["d"] = 1.0 - float(parts[1])
    return {k: (surface_of(v), v.get("Ke", (0.0, 0.0, 0.0))) for k, v in materials.items()}


def read_obj(path):
    """Triangles grouped by (surface, emission): {material: [v0, v1, v2, ...]}."""
    try:
        lines = open(path, encoding="utf-8").read().splitlines()
    except OSError as e:
        fail(f"{path}: cannot read mesh: {e.strerror}")
    positions = []
    materials = {}
    groups = {}
    default = (("diffuse", DEFAULT_ALBEDO), (0.0, 0.0, 0.0))
    current = default
    base = os.path.dirname(path)
    for number, line in enumerate(lines, 1):
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        key = parts[0]
        if key == "v":
            positions.append(tuple(float(v) for v in parts[1:4]))
        elif key == "mtllib":
            for name in parts[1:]:
                materials.update(read_mtl(os.path.join(base, name)))
        elif key == "usemtl":
            current = materials.get(" ".join(parts[1:]), default)
        elif key == "f":
            try:
                idx = [int(p.split("/")[0]) for p in parts[1:]]
                pts = [positions[i - 1 if i > 0 else i] for i in idx]
            except (ValueError, IndexError):
                fail(f"{path}:{number}: malformed face")
            if len(pts) < 3:
                fail(f"{path}:{number}: face with fewer than 3 vertices")
            tris = groups.setdefault(current, [])
            # Fan, as qtrace's loader triangulates polygons.
            for k in range(1, len(pts) - 1):
                tris.extend((pts[0], pts[k], pts[k + 1]))
    return groups


def bumpy_sphere(p):
    """The triangles of qtrace's procedural bumpy sphere, in the same order and winding."""
    cx, cy, cz = p["center"]
    radius, amplitude, frequency = p["radius"], p["amplitude"], p["frequency"]
    segments, rings = int(p["segments"]), int(p["rings"])
    if segments < 3 or rings < 2:
        fail("bumpy-sphere needs segments >= 3 and rings >= 2")

    def point(i, j):
        theta = math.pi * i / rings
        phi = 2.0 * math.pi * (j % segments) / segments
        r = radius + amplitude * math.sin(frequency * theta) * math.sin(frequency * phi)
        st = math.sin(theta)
        return (cx + r * st * math.cos(phi), cy + r * math.cos(theta), cz + r * st * math.sin(phi))

    top, bottom = (cx, cy + radius, cz), (cx, cy - radius, cz)
    tris = []
    for j in range(segments):
        tris.extend((top, point(1, j + 1), point(1, j)))
        tris.extend((bottom, point(rings - 1, j), point(rings - 1, j + 1)))
    # Each ring of points once, reused by the quads above and below it.
    ring = [[point(i, j) for j in range(segments + 1)] for i in range(rings + 1)]
    for i in range(1, rings - 1):
        upper, lower = ring[i], ring[i + 1]
        for j in range(segments):
            a, b, c, d = upper[j], upper[j + 1], lower[j + 1], lower[j]
            tris.extend((a, b, c, a, c, d))
    return tris


def load_scene(path):
    doc = read_scene_file(path)
    groups = {}
    if "mesh" in doc:
        obj = os.path.join(os.path.dirname(path), doc["mesh"])
        for material, tris in read_obj(obj).items():
            groups.setdefault(material, []).extend(tris)
    for p in doc.get("procedural", []):
        albedo = vec3(path, p["albedo"], "procedural albedo")
        groups.setdefault((("diffuse", albedo), (0.0, 0.0, 0.0)), []).extend(bumpy_sphere(p))
    if not groups:
        fail(f"{path}: the scene has no triangles")
    environment = vec3(path, doc.get("environment", [0.0, 0.0, 0.0]), "environment")
    if max(environment) <= 0.0 and not any(max(e) > 0.0 for _, e in groups):
        fail(f"{path}: the scene has no emitter")
    return doc, groups, environment


# --------------------------------------------------------------------------
# Mitsuba
# --------------------------------------------------------------------------


def import_mitsuba():
    """Imports Mitsuba with its LLVM variant, or exits 3 saying what is missing."""
    if "DRJIT_LIBLLVM_PATH" not in os.environ:
        found = next((p for p in DEBIAN_LIBLLVM if os.path.exists(p)), None)
        if found:
            os.environ["DRJIT_LIBLLVM_PATH"] = found
    # Dr.Jit reports a missing libLLVM on the C-level stderr; keep it off the
    # terminal so a failure prints only the one line below.
    saved = os.dup(2)
    with open(os.devnull, "w") as devnull:
        os.dup2(devnull.fileno(), 2)
        try:
            import drjit as dr
            import mitsuba as mi
            problem = None
            if not dr.has_backend(dr.JitBackend.LLVM):
                problem = "Dr.Jit's LLVM backend found no libLLVM"
            else:
                mi.set_variant("llvm_ad_rgb")
        except ImportError as e:
            # drjit comes with the mitsuba package, so either missing means the same.
            problem = ("the Python package 'mitsuba' is not installed"
                       if e.name in ("mitsuba", "drjit")
                       else f"Mitsuba's llvm_ad_rgb variant did not load ({str(e).splitlines()[0]})")
        except Exception as e:  # a variant that fails to initialise
            problem = f"Mitsuba's llvm_ad_rgb variant did not load ({str(e).splitlines()[0]})"
        finally:
            os.dup2(saved, 2)
            os.close(saved)
    if problem:
        libllvm = os.environ.get("DRJIT_LIBLLVM_PATH", "unset")
        fail(f"{problem} (DRJIT_LIBLLVM_PATH={libllvm}); {SETUP_HINT}", status=3)
    return dr, mi


def rgb(value):
    return {"type": "rgb", "value": list(value)}


def bsdf_dict(surface):
    kind = surface[0]
    if kind == "dielectric":
        return {"type": "dielectric", "int_ior": surface[1], "ext_ior": 1.0,
                "specular_transmittance": rgb(surface[2])}
    if kind == "conductor":
        _, ks, alpha = surface
        inner = ({"type": "roughconductor", "distribution": "ggx", "alpha": alpha}
                 if alpha > 0.0 else {"type": "conductor"})
        inner.update({"material": "none", "specular_reflectance": rgb(ks)})
        return {"type": "twosided", "bsdf": inner}
    return {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": rgb(surface[1])}}


def build_mesh(mi, name, tris, surface, emission):
    props = mi.Properties()
    if max(emission) > 0.0:
        props["bsdf"] = mi.load_dict({"type": "diffuse", "reflectance": rgb((0.0, 0.0, 0.0))})
        props["emitter"] = mi.load_dict({"type": "area", "radiance": rgb(emission)})
    else:
        props["bsdf"] = mi.load_dict(bsdf_dict(surface))
    # Unshared vertices and no vertex normals: flat shading with the face
    # normal of each triangle's own vertex order.
    mesh = mi.Mesh(name, len(tris), len(tris) // 3, props=props,
                   has_vertex_normals=False, has_vertex_texcoords=False)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(array("f", (c for v in tris for c in v)))
    params["faces"] = mi.UInt32(array("I", range(len(tris))))
    params.update()
    return mesh


def build_scene(mi, path, doc, groups, environment, width, height, max_depth):
    cam = doc["camera"]
    fov_y = float(cam["fov_y"])
    if not 0.0 < fov_y < 180.0:
        fail(f"{path}: camera fov_y {fov_y} must lie in (0, 180) degrees")
    position = vec3(path, cam["position"], "camera position")
    # Clip planes scaled to the scene, so no camera ray is cut short.
    points = [v for tris in groups.values() for v in tris]
    far = 2.0 * max(math.dist(position, v) for v in points) + 1.0
    scene = {
        "type": "scene",
        # qtrace's max depth D: its kernel does NEE and bounces at hit indices
        # 0..D-1 and stops at hit D after adding that hit's emission, so its
        # longest path has D+1 segments. Mitsuba's max_depth counts segments
        # (1 = directly visible emitters only), hence D + 1.
        "integrator": {"type": "path", "max_depth": max_depth + 1, "rr_depth": RR_DEPTH,
                       "hide_emitters": False},
        "sensor": {
            "type": "perspective",
            "fov": fov_y,
            "fov_axis": "y",
            "near_clip": far * 1e-7,
            "far_clip": far,
            # Mitsuba's look_at keeps the image's right = forward x up, as qtrace.
            "to_world": mi.ScalarTransform4f().look_at(
                origin=position,
                target=vec3(path, cam["look_at"], "camera look_at"),
                up=vec3(path, cam["up"], "camera up")),
            "sampler": {"type": "independent", "sample_count": 1},
            "film": {"type": "hdrfilm", "width": width, "height": height,
                     "pixel_format": "rgb", "component_format": "float32",
                     "rfilter": {"type": "box"}},
        },
    }
    if max(environment) > 0.0:
        scene["environment"] = {"type": "constant", "radiance": rgb(environment)}
    for k, ((surface, emission), tris) in enumerate(groups.items()):
        scene[f"mesh_{k}"] = build_mesh(mi, f"mesh_{k}", tris, surface, emission)
    return mi.load_dict(scene)


def main():
    args = parse_args()
    if not os.path.isfile(args.scene):
        fail(f"{args.scene}: scene file not found")
    if args.scene.lower().endswith(".xml"):
        # qtrace gives the size and the path length it rendered with.
        width, height = args.width or 256, args.height or 256
        max_depth = args.max_depth if args.max_depth is not None else 64
        dr, mi = import_mitsuba()
        scene = load_xml(mi, args.scene, args.defines, width, height, max_depth)
        return time_renders(dr, mi, args, scene, width, height)
    doc, groups, environment = load_scene(args.scene)
    render = doc.get("render", {})
    width = args.width if args.width is not None else render.get("width", 256)
    height = args.height if args.height is not None else render.get("height", 256)
    max_depth = args.max_depth if args.max_depth is not None else render.get("max_depth", 64)
    for name, value in (("width", width), ("height", height), ("spp", args.spp),
                        ("batches", args.batches)):
        if not isinstance(value, int) or value < 1:
            fail(f"{name} must be a positive integer, not {value!r}")
    if not isinstance(max_depth, int) or max_depth < 0:
        fail(f"max depth must be a non-negative integer, not {max_depth!r}")

    dr, mi = import_mitsuba()
    scene = build_scene(mi, args.scene, doc, groups, environment, width, height, max_depth)
    time_renders(dr, mi, args, scene, width, height)


def time_renders(dr, mi, args, scene, width, height):
    """Renders the batches, prints the JSON line."""
    times = []
    image = None
    for batch in range(args.batches + 1):
        start = time.perf_counter()
        image = mi.render(scene, spp=args.spp, seed=batch)
        # Rendering is lazy: force the kernel to run before stopping the clock.
        dr.eval(image)
        dr.sync_thread()
        elapsed = time.perf_counter() - start
        if batch > 0:  # the first batch pays for tracing and compiling the kernel
            times.append(elapsed)

    if args.exr:
        try:
            mi.Bitmap(image).write(args.exr)
        except Exception as e:
            fail(f"{args.exr}: cannot write EXR: {str(e).splitlines()[0]}")

    samples = width * height * args.spp
    print(json.dumps({
        "renderer": "mitsuba",
        "version": mi.__version__,
        "variant": "llvm_ad_rgb",
        "scene": args.scene,
        "width": width,
        "height": height,
        "spp": args.spp,
        "batches": args.batches,
        "seconds": statistics.fmean(times),
        "samples_per_second": samples / min(times),
        "samples_per_second_median": samples / statistics.median(times),
    }))


if __name__ == "__main__":
    main()
