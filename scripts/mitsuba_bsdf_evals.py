#!/usr/bin/env python3
"""Evaluate Mitsuba 3 BSDFs at fixed directions, for tests/mitsuba.rs.

  python3 scripts/mitsuba_bsdf_evals.py tests/fixtures/mitsuba/bsdf-evals.txt

Writes, for each BSDF in CASES, a line `bsdf <its XML>` and then one line per
pair of directions in its local frame (z the normal): wo (toward the
viewer, above the surface), wi (anywhere) and Mitsuba's f(wo, wi) cos(wi)
(`BSDF.eval` of `scalar_rgb`, with si.wi = wo). The directions are drawn
from a fixed seed. Needs `pip install mitsuba numpy`.
"""

import sys

import mitsuba as mi
import numpy as np

CASES = [
    '<bsdf type="diffuse"><rgb name="reflectance" value="0.3, 0.5, 0.7"/></bsdf>',
    '<bsdf type="plastic"><rgb name="diffuse_reflectance" value="0.3, 0.5, 0.7"/><float name="int_ior" value="1.6"/></bsdf>',
    '<bsdf type="plastic"><rgb name="diffuse_reflectance" value="0.3, 0.5, 0.7"/><boolean name="nonlinear" value="true"/></bsdf>',
    '<bsdf type="roughplastic"><rgb name="diffuse_reflectance" value="0.3, 0.5, 0.7"/><float name="alpha" value="0.25"/></bsdf>',
    '<bsdf type="roughplastic"><string name="distribution" value="ggx"/><rgb name="diffuse_reflectance" value="0.6, 0.2, 0.1"/><float name="alpha" value="0.4"/><boolean name="nonlinear" value="true"/><float name="int_ior" value="1.8"/></bsdf>',
    '<bsdf type="roughconductor"><string name="material" value="Au"/><float name="alpha" value="0.3"/></bsdf>',
    '<bsdf type="roughconductor"><string name="distribution" value="beckmann"/><string name="material" value="Cu"/><float name="alpha" value="0.15"/></bsdf>',
    '<bsdf type="roughconductor"><rgb name="eta" value="0.2, 0.9, 1.1"/><rgb name="k" value="3.9, 2.4, 2.2"/><float name="alpha" value="0.5"/><rgb name="specular_reflectance" value="0.8, 0.9, 1"/></bsdf>',
    '<bsdf type="roughdielectric"><float name="int_ior" value="1.5"/><float name="alpha" value="0.2"/></bsdf>',
    '<bsdf type="roughdielectric"><string name="distribution" value="ggx"/><float name="int_ior" value="1.33"/><float name="alpha" value="0.45"/><rgb name="specular_transmittance" value="0.9, 0.7, 0.5"/></bsdf>',
    '<bsdf type="principled"><rgb name="base_color" value="0.7, 0.3, 0.2"/><float name="roughness" value="0.4"/><float name="metallic" value="0.3"/></bsdf>',
    '<bsdf type="principled"><rgb name="base_color" value="0.2, 0.6, 0.3"/><float name="roughness" value="0.6"/><float name="specular" value="0.7"/><float name="spec_tint" value="0.5"/><float name="sheen" value="0.8"/><float name="sheen_tint" value="0.4"/><float name="clearcoat" value="0.6"/><float name="clearcoat_gloss" value="0.7"/></bsdf>',
    '<bsdf type="principled"><rgb name="base_color" value="0.9, 0.9, 0.9"/><float name="roughness" value="0.3"/><float name="spec_trans" value="0.7"/><float name="eta" value="1.45"/></bsdf>',
    '<bsdf type="principledthin"><rgb name="base_color" value="0.5, 0.7, 0.2"/><float name="roughness" value="0.5"/><float name="spec_trans" value="0.4"/><float name="diff_trans" value="0.3"/><float name="flatness" value="0.5"/></bsdf>',
    '<bsdf type="twosided"><bsdf type="roughconductor"><string name="material" value="Al"/><float name="alpha" value="0.2"/></bsdf></bsdf>',
]
PAIRS = 64


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    mi.set_variant("scalar_rgb")
    rng = np.random.default_rng(3)
    wo = rng.normal(size=(PAIRS, 3))
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    wo[:, 2] = np.abs(wo[:, 2])
    wi = rng.normal(size=(PAIRS, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    lines = []
    for case in CASES:
        bsdf = mi.load_string(case.replace("<bsdf ", '<bsdf version="3.0.0" ', 1))
        lines.append("bsdf " + case)
        for a, b in zip(wo, wi):
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(a)
            si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
            si.n = mi.Vector3f(0, 0, 1)
            f = np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(b)))
            lines.append(" ".join(f"{x:.9g}" for x in [*a, *b, *f]))
    with open(sys.argv[1], "w") as out:
        out.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
