#version 460
// Runs the Sarsa guide's GLSL on host-given inputs so tests can compare it
// with CPU references: the nearest radiance volume, mixture sampling, the
// update and NEE's choice of light.

#include "shared.h"
#include "sampling.glsl"
#include "scene.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(push_constant) uniform Push { PassParams params; };

#include "bsdf.glsl"
#include "sarsa.glsl"
#include "guide.glsl"

layout(std430, set = 0, binding = B_PROBE_IN) readonly buffer ProbeIn { vec4 probe_in[]; };
layout(std430, set = 0, binding = B_PROBE_OUT) writeonly buffer ProbeOut { vec4 probe_out[]; };

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= params.item_count) {
        return;
    }
    if (params.selector == PROBE_NEAREST_VOLUME) {
        // in[2i] = point, in[2i+1] = (triangle bits, front side?); out.x = volume index bits
        uint t = floatBitsToUint(probe_in[2u * i + 1u].x);
        uint v = nearest_volume(t, load_triangle(t), probe_in[2u * i].xyz, probe_in[2u * i + 1u].y > 0.0);
        probe_out[i] = vec4(uintBitsToFloat(v), 0.0, 0.0, 0.0);
    } else if (params.selector == PROBE_GUIDE_SAMPLE) {
        // in[0..4] = a Material, in[4] = (wo, front side? 1 : 0), in[5].x =
        // the volume on the far side (bits; NO_VOLUME: none), in[6 + i] =
        // (volume bits, u1, u2, u3); out = (local direction, pdf) of the
        // mixture with that material's BSDF, and the pdf NEE's MIS finds
        vec4 q = probe_in[6u + i];
        Bsdf bsdf = bsdf_of(Material(probe_in[0], probe_in[1], probe_in[2], probe_in[3]), probe_in[4].w > 0.5);
        vec3 wo = probe_in[4].xyz;
        Mixture m = mixture_at(guide_vertex(floatBitsToUint(q.x)), guide_vertex(floatBitsToUint(probe_in[5].x)), bsdf, wo);
        uint sector;
        float p_sector;
        vec3 w = mixture_sample(m, bsdf, wo, q.yzw, sector, p_sector);
        probe_out[2u * i] = vec4(w, mixture_pdf_in(m, bsdf, wo, w, p_sector));
        probe_out[2u * i + 1u] = vec4(mixture_pdf(m, bsdf, wo, w), 0.0, 0.0, 0.0);
    } else if (params.selector == PROBE_SARSA_UPDATE) {
        // in[2i] = (volume bits, sector bits, next volume bits, albedo or
        // -emitted), in[2i+1].x = the share of an emitted target NEE carries;
        // out.x = the target recorded
        vec4 q = probe_in[2u * i];
        uint v = floatBitsToUint(q.x);
        uint k = floatBitsToUint(q.y);
        uint vy = floatBitsToUint(q.z);
        float target = q.w < 0.0 ? -q.w : q.w * INV_PI * guide_irradiance(guide_vertex(vy));
        sarsa_record(v, k, target, 0.0);
        if (q.w < 0.0) {
            sarsa_record_direct(v, k, probe_in[2u * i + 1u].x);
        }
        probe_out[i] = vec4(target, 0.0, 0.0, 0.0);
    } else if (params.selector == PROBE_LIGHT_CHOICE) {
        // in[i] = (volume bits, u, 0, 0); out = (light index bits, its
        // probability as drawn, as NEE's MIS looks it up, 0)
        GuideVertex g = guide_vertex(floatBitsToUint(probe_in[i].x));
        float p;
        uint l = guide_choose_light(g, probe_in[i].y, p);
        probe_out[i] = vec4(uintBitsToFloat(l), p, guide_light_probability(g, l), 0.0);
    } else if (params.selector == PROBE_LIGHT_TRY) {
        // in[i] = (volume bits, light index bits, what the try brought, 0)
        vec4 t = probe_in[i];
        guide_record_light(guide_vertex(floatBitsToUint(t.x)), floatBitsToUint(t.y), t.z);
        probe_out[i] = vec4(0.0);
    }
}
