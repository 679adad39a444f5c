#!/usr/bin/env python3
"""Cast rays with Mitsuba 3's sensors and at its built-in shapes, for tests/mitsuba.rs.

  python3 scripts/mitsuba_geometry_probes.py tests/fixtures/mitsuba/

Writes two files there. camera-rays.txt: for each sensor in SENSORS (one
scene per line, `sensor <its XML>`), lines of a point on the film window in
pixels (x, y from its top left) and Mitsuba's ray through it (origin,
direction; a thin lens's through its centre), from `Sensor.sample_ray` of
`scalar_rgb`. shape-hits.txt: for each shape in SHAPES (`shape <its XML>`),
lines of a ray (origin, direction) that meets it and what Mitsuba's
`Scene.ray_intersect` finds there: the distance, (u, v), the shading normal,
the geometric normal and dp/du. Points and rays are drawn from a fixed seed.
Needs `pip install mitsuba numpy`.
"""

import os
import sys

import mitsuba as mi
import numpy as np

FILM = '<film type="hdrfilm"><integer name="width" value="{w}"/><integer name="height" value="{h}"/>{crop}<rfilter type="box"/></film>'
CROP = '<integer name="crop_offset_x" value="{x}"/><integer name="crop_offset_y" value="{y}"/><integer name="crop_width" value="{cw}"/><integer name="crop_height" value="{ch}"/>'
LOOKAT = '<transform name="to_world"><lookat origin="1, 2, 3" target="0, 0, 0" up="0, 1, 0"/></transform>'
TURNED = '<transform name="to_world"><rotate x="0.43643578" y="0.87287156" z="0.21821789" angle="30"/><translate x="0.3" y="-1" z="2"/></transform>'
TILTED = '<transform name="to_world"><lookat origin="0, 0, 5" target="0, 1, 0" up="1, 1, 0"/></transform>'

# (sensor type, film width, height, crop window or None, the rest of it).
SENSORS = [
    ("perspective", 64, 64, None, '<float name="fov" value="45"/>' + LOOKAT),
    ("perspective", 80, 30, None, '<float name="fov" value="70"/><string name="fov_axis" value="x"/>' + TURNED),
    ("perspective", 80, 30, None, '<float name="fov" value="40"/><string name="fov_axis" value="y"/>' + TILTED),
    ("perspective", 30, 80, None, '<float name="fov" value="60"/><string name="fov_axis" value="diagonal"/>' + LOOKAT),
    ("perspective", 30, 80, None, '<float name="fov" value="50"/><string name="fov_axis" value="smaller"/>' + TURNED),
    ("perspective", 80, 30, None, '<float name="fov" value="50"/><string name="fov_axis" value="smaller"/>' + TURNED),
    ("perspective", 30, 80, None, '<float name="fov" value="35"/><string name="fov_axis" value="larger"/>' + TILTED),
    ("perspective", 80, 30, None, '<float name="fov" value="35"/><string name="fov_axis" value="larger"/>' + TILTED),
    ("perspective", 7, 3, None, '<string name="focal_length" value="28mm"/>' + LOOKAT),
    ("perspective", 64, 48, None, '<float name="fov" value="50"/><float name="principal_point_offset_x" value="0.2"/><float name="principal_point_offset_y" value="-0.35"/>' + TURNED),
    ("perspective", 64, 48, (16, 16, 32, 16), '<float name="fov" value="50"/><string name="fov_axis" value="x"/>' + LOOKAT),
    ("perspective", 80, 30, (20, 10, 40, 10), '<float name="fov" value="50"/><float name="principal_point_offset_x" value="-0.1"/><float name="principal_point_offset_y" value="0.25"/>' + TILTED),
    ("thinlens", 64, 48, None, '<float name="fov" value="40"/><float name="aperture_radius" value="0.1"/><float name="focus_distance" value="4"/>' + TURNED),
    ("thinlens", 30, 80, (5, 20, 20, 40), '<float name="fov" value="55"/><string name="fov_axis" value="diagonal"/><float name="aperture_radius" value="0.2"/>' + LOOKAT),
    ("orthographic", 80, 30, None, '<float name="near_clip" value="0.5"/><transform name="to_world"><scale x="2" y="3" z="1"/><lookat origin="1, 2, 3" target="0, 0, 0" up="0, 1, 0"/></transform>'),
    ("orthographic", 7, 3, (1, 1, 3, 2), '<transform name="to_world"><scale x="2" y="3" z="1"/><lookat origin="1, 2, 3" target="0, 0, 0" up="0, 1, 0"/></transform>'),
]

TURN = '<rotate x="0.6" y="0.8" angle="50"/>'
FLIP = '<boolean name="flip_normals" value="true"/>'
SHAPES = [
    '<shape type="sphere"/>',
    '<shape type="sphere"><point name="center" x="1" y="-0.5" z="0.3"/><float name="radius" value="0.7"/></shape>',
    f'<shape type="sphere"><transform name="to_world">{TURN}<scale value="1.3"/><translate x="0.2"/></transform></shape>',
    f'<shape type="sphere">{FLIP}<transform name="to_world"><rotate x="1" angle="-90"/></transform></shape>',
    '<shape type="cylinder"/>',
    '<shape type="cylinder"><point name="p0" x="0.2" y="-1" z="0.1"/><point name="p1" x="-0.3" y="1" z="0.4"/><float name="radius" value="0.4"/></shape>',
    f'<shape type="cylinder">{FLIP}<transform name="to_world">{TURN}<translate z="-0.5"/></transform></shape>',
    '<shape type="disk"/>',
    f'<shape type="disk">{FLIP}<transform name="to_world"><scale x="2" y="0.5"/>{TURN}</transform></shape>',
    '<shape type="rectangle"/>',
    f'<shape type="rectangle">{FLIP}<transform name="to_world"><scale x="2" y="0.5"/>{TURN}<translate y="0.3"/></transform></shape>',
    '<shape type="cube"/>',
    f'<shape type="cube">{FLIP}<transform name="to_world"><scale x="2" y="0.5" z="0.7"/>{TURN}</transform></shape>',
]


def scene(body):
    return f'<scene version="3.0.0">{body}<emitter type="constant"/></scene>'


def numbers(values):
    return " ".join(f"{float(x):.9g}" for x in values)


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    mi.set_variant("scalar_rgb")
    rng = np.random.default_rng(40)
    out = []
    for kind, w, h, crop, rest in SENSORS:
        window = CROP.format(x=crop[0], y=crop[1], cw=crop[2], ch=crop[3]) if crop else ""
        xml = f'<sensor type="{kind}">{rest}{FILM.format(w=w, h=h, crop=window)}</sensor>'
        sensor = mi.load_string(scene(xml)).sensors()[0]
        cw, ch = (crop[2], crop[3]) if crop else (w, h)
        out.append(f"sensor {xml}")
        for u, v in rng.uniform(0, 1, size=(8, 2)):
            ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(u, v), mi.Point2f(0.5, 0.5))
            out.append(numbers([u * cw, v * ch, *ray.o, *ray.d]))
    with open(os.path.join(sys.argv[1], "camera-rays.txt"), "w") as f:
        f.write("\n".join(out) + "\n")

    out = []
    for xml in SHAPES:
        s = mi.load_string(scene(xml))
        out.append(f"shape {xml}")
        hits = 0
        while hits < 12:
            o = rng.normal(size=3)
            o = 5 * o / np.linalg.norm(o)
            d = rng.uniform(-0.9, 0.9, size=3) - o
            d /= np.linalg.norm(d)
            si = s.ray_intersect(mi.Ray3f(mi.Point3f(*o), mi.Vector3f(*d)))
            if not si.is_valid():
                continue
            hits += 1
            out.append(numbers([*o, *d, si.t, *si.uv, *si.sh_frame.n, *si.n, *si.dp_du]))
    with open(os.path.join(sys.argv[1], "shape-hits.txt"), "w") as f:
        f.write("\n".join(out) + "\n")


if __name__ == "__main__":
    main()
