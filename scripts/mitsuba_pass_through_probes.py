#!/usr/bin/env python3
"""Render Mitsuba 3's images of paths that pass through surfaces, for tests/mitsuba.rs.

  python3 scripts/mitsuba_pass_through_probes.py tests/fixtures/mitsuba/pass-through.txt

Mitsuba's `path` keeps a sample's light only if its path scattered somewhere
(or began under a visible sky); at the last allowed vertex its vectorized
variants still draw a BSDF sample, which counts if its lobe is not null (its
`scalar_rgb` counts there only an emitter, without hide_emitters). Each scene
in SCENES shows that rule: `null` panes, a thin sheet or a mask before
lights, lit squares, a sky or nothing, on a 4x4 film. For each, at max_depth
1, 2, 3 and -1 and with hide_emitters off and on, the file gets a line
`max_depth hide mean stderr`: the image's mean and its standard error from 4
passes of 16,384 samples per pixel (`llvm_ad_rgb`, seeds 0-3). The scene's
own line, `scene <its XML>`, reads $max_depth and $hide.
Needs `pip install mitsuba numpy` and an LLVM library (Debian: libllvm19).
"""

import os
import sys

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM-19.so")
import mitsuba as mi  # noqa: E402
import numpy as np  # noqa: E402

HEAD = ('<scene version="3.0.0"><default name="max_depth" value="-1"/><default name="hide" value="false"/>'
        '<integrator type="path"><integer name="max_depth" value="$max_depth"/>'
        '<boolean name="hide_emitters" value="$hide"/></integrator>'
        '<sensor type="perspective"><float name="fov" value="10"/>'
        '<transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform>'
        '<film type="hdrfilm"><integer name="width" value="4"/><integer name="height" value="4"/>'
        '<rfilter type="box"/></film></sensor>')
# A pane at z = 1 in front of what lies at z = 0.
def pane(bsdf):
    return f'<shape type="rectangle"><transform name="to_world"><translate z="1"/></transform>{bsdf}</shape>'
NULL = '<bsdf type="null"/>'
THIN = '<bsdf type="thindielectric"/>'
MASK = '<bsdf type="mask"><float name="opacity" value="0.5"/><bsdf type="diffuse"/></bsdf>'
# An area light facing the camera (its BSDF `bsdf`), or turned away.
def light(bsdf=''):
    return f'<shape type="rectangle"><emitter type="area"><rgb name="radiance" value="1"/></emitter>{bsdf}</shape>'
TURNED_LIGHT = ('<shape type="rectangle"><transform name="to_world"><rotate y="1" angle="180"/></transform>'
                '<emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>')
# A white square lit by a point light before the pane (which shadows it).
LIT = ('<shape type="rectangle"><bsdf type="diffuse"><rgb name="reflectance" value="1"/></bsdf></shape>'
       '<emitter type="point"><point name="position" x="0" y="0" z="3"/><rgb name="intensity" value="1"/></emitter>')
POINT = '<emitter type="point"><point name="position" x="0" y="0" z="3"/><rgb name="intensity" value="1"/></emitter>'
SKY = '<emitter type="constant"><rgb name="radiance" value="0.1"/></emitter>'
# A light with a null BSDF seen through four null panes, before a grey square
# (the first surface that scatters, some passes after the light's).
STACK = (''.join(f'<shape type="rectangle"><transform name="to_world"><translate z="{z}"/></transform>{NULL}</shape>'
                 for z in (1, 1.5, 2, 2.5))
         + '<shape type="rectangle"><transform name="to_world"><translate z="0.5"/></transform>'
           f'<emitter type="area"><rgb name="radiance" value="1"/></emitter>{NULL}</shape>'
           '<shape type="rectangle"><bsdf type="diffuse"/></shape>')

SCENES = [
    light(NULL),                       # a light whose BSDF is null, against nothing
    pane(NULL) + light(),              # a light behind a null pane
    pane(THIN) + light(),              # ... behind a thin sheet
    pane(MASK) + LIT,                  # a lit mask before a shadowed square
    pane(MASK) + TURNED_LIGHT + POINT,  # ... before a light turned away
    pane(MASK) + light() + POINT,      # ... before a light
    pane(MASK) + SKY,                  # a mask under a sky
    pane(NULL) + SKY,                  # a null pane under a sky
    STACK,                             # a null light through null panes
]


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    mi.set_variant('llvm_ad_rgb')
    lines = []
    for body in SCENES:
        xml = HEAD + body + '</scene>'
        lines.append(f'scene {xml}')
        for depth in (1, 2, 3, -1):
            for hide in (False, True):
                scene = mi.load_string(xml, max_depth=str(depth), hide=str(hide).lower())
                means = [float(np.mean(np.array(mi.render(scene, spp=16384, seed=s))[..., :3]))
                         for s in range(4)]
                mean, err = np.mean(means), np.std(means, ddof=1) / 2.0
                lines.append(f'{depth} {int(hide)} {mean:.6g} {err:.3g}')
                print(lines[-1], flush=True)
    with open(sys.argv[1], 'w') as f:
        f.write('\n'.join(lines) + '\n')


if __name__ == '__main__':
    main()
