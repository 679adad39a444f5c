#!/usr/bin/env python3
"""Mitsuba's built-in shapes seen behind an emitter that hide_emitters hides.

For development: a probe of where Mitsuba 3 itself goes wrong, so that a
difference from it in such scenes is read right.

  python3 scripts/mitsuba_hidden_shapes.py [--variant llvm_ad_rgb]
      [--qtrace BIN] [--spp 256]

Each scene is a shape (sphere, disk, cylinder, rectangle, cube) lit by a
point light, seen through a pane that is an area emitter of next to no
radiance (1e-6) with a null BSDF, at max_depth -1 (so that the skip, which
takes no bounce, changes no path's length budget). With hide_emitters the
camera's ray skips the pane, so the image should be the same as without
(the pane adds 1e-6). Prints each renderer's image mean without and with
hide_emitters. Needs `pip install mitsuba numpy` (and, for llvm_ad_rgb, an
LLVM library: Debian's libllvm19).
"""

import argparse
import os
import subprocess
import sys
import tempfile

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

SHAPES = {
    "sphere": '<shape type="sphere"><bsdf type="diffuse"/></shape>',
    "disk": '<shape type="disk"><transform name="to_world"><rotate x="1" angle="20"/></transform>'
            '<bsdf type="diffuse"/></shape>',
    "cylinder": '<shape type="cylinder"><transform name="to_world"><rotate x="1" angle="60"/>'
                '<translate z="-0.5"/></transform><bsdf type="twosided"><bsdf type="diffuse"/></bsdf></shape>',
    "rectangle": '<shape type="rectangle"><transform name="to_world"><rotate x="1" angle="20"/></transform>'
                 '<bsdf type="diffuse"/></shape>',
    "cube": '<shape type="cube"><transform name="to_world"><rotate x="1" y="1" angle="20"/></transform>'
            '<bsdf type="diffuse"/></shape>',
}


def scene(shape, hide):
    return f'''<scene version="3.0.0">
<integrator type="path"><integer name="max_depth" value="-1"/><boolean name="hide_emitters" value="{hide}"/></integrator>
<sensor type="perspective"><float name="fov" value="30"/>
<transform name="to_world"><lookat origin="0, 0, 6" target="0, 0, 0" up="0, 1, 0"/></transform>
<film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/></film></sensor>
<shape type="rectangle"><transform name="to_world"><scale value="3"/><translate z="3"/></transform>
<bsdf type="null"/><emitter type="area"><rgb name="radiance" value="1e-6"/></emitter></shape>
{SHAPES[shape]}
<emitter type="point"><point name="position" value="2, 3, 2"/><rgb name="intensity" value="20"/></emitter>
</scene>
'''


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--qtrace", default=os.path.join(os.environ.get("CARGO_TARGET_DIR", "target"),
                                                    "release", "qtrace"))
    ap.add_argument("--spp", type=int, default=256)
    args = ap.parse_args()
    os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM-19.so")
    import mitsuba as mi
    import numpy as np
    mi.set_variant(args.variant)
    have_qtrace = os.path.exists(args.qtrace)
    print(f"{'shape':10} {'mitsuba shown':>14} {'hidden':>9} {'qtrace shown':>13} {'hidden':>9}")
    with tempfile.TemporaryDirectory() as tmp:
        for shape in SHAPES:
            row = []
            for hide in ("false", "true"):
                row.append(np.array(mi.render(mi.load_string(scene(shape, hide)), spp=args.spp)).mean())
            for hide in ("false", "true"):
                if not have_qtrace:
                    row.append(float("nan"))
                    continue
                xml, exr = os.path.join(tmp, "s.xml"), os.path.join(tmp, "s.exr")
                with open(xml, "w") as f:
                    f.write(scene(shape, hide))
                subprocess.run([args.qtrace, "render", xml, "--method", "pt", "--nee", "--spp", str(4 * args.spp),
                                "-o", exr], check=True, capture_output=True)
                row.append(np.array(mi.Bitmap(exr), dtype=np.float64)[..., :3].mean())
            print(f"{shape:10} {row[0]:14.5f} {row[1]:9.5f} {row[2]:13.5f} {row[3]:9.5f}", flush=True)


if __name__ == "__main__":
    sys.exit(main())
