#version 460
// Runs the GLSL building blocks on host-given inputs so tests can compare them
// with CPU references: BVH traversal, the hemisphere map, the nearest radiance
// volume, guided sampling and the Sarsa update.

#include "shared.h"
#include "sampling.glsl"
#include "scene.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(push_constant) uniform Push { PassParams params; };

#include "guide.glsl"

layout(std430, set = 0, binding = B_PROBE_IN) readonly buffer ProbeIn { vec4 probe_in[]; };
layout(std430, set = 0, binding = B_PROBE_OUT) writeonly buffer ProbeOut { vec4 probe_out[]; };

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= params.item_count) {
        return;
    }
    if (params.probe_mode == PROBE_TRACE) {
        // in[2i] = origin, in[2i+1] = direction; out = (t, triangle bits, any-hit flag, 0)
        vec3 o = probe_in[2u * i].xyz;
        vec3 d = probe_in[2u * i + 1u].xyz;
        Hit h = trace_ray(o, d, FAR);
        probe_out[i] = vec4(h.t, uintBitsToFloat(h.triangle), occluded(o, d, FAR) ? 1.0 : 0.0, 0.0);
    } else if (params.probe_mode == PROBE_HEMISPHERE) {
        // in = (u, v, grid a, grid b); out = (direction, sector of that direction)
        vec4 q = probe_in[i];
        vec3 w = square_to_hemisphere(q.xy);
        uint sector = hemisphere_sector(w, uint(q.z), uint(q.w));
        probe_out[i] = vec4(w, float(sector));
    } else if (params.probe_mode == PROBE_NEAREST_VOLUME) {
        // in[2i] = point, in[2i+1] = (triangle bits, front side?); out.x = volume index bits
        uint t = floatBitsToUint(probe_in[2u * i + 1u].x);
        uint v = nearest_volume(load_triangle(t), probe_in[2u * i].xyz, probe_in[2u * i + 1u].y > 0.0);
        probe_out[i] = vec4(uintBitsToFloat(v), 0.0, 0.0, 0.0);
    } else if (params.probe_mode == PROBE_GUIDE_SAMPLE) {
        // in = (volume bits, u1, u2, u3); out = (local direction, pdf)
        vec4 q = probe_in[i];
        uint v = floatBitsToUint(q.x);
        uint sector;
        float p_sector;
        vec3 w = guide_sample(v, q.yzw, sector, p_sector);
        probe_out[i] = vec4(w, mixture_pdf(v, p_sector, w.z));
    } else if (params.probe_mode == PROBE_SARSA_UPDATE) {
        // in[2i] = (volume bits, sector bits, next volume bits, albedo or
        // -emitted), in[2i+1].x = the share of an emitted target NEE carries;
        // out.x = the target recorded
        vec4 q = probe_in[2u * i];
        uint v = floatBitsToUint(q.x);
        uint k = floatBitsToUint(q.y);
        uint vy = floatBitsToUint(q.z);
        float target = q.w < 0.0 ? -q.w : sarsa_surface_target(volume_sums_of(vy), q.w);
        sarsa_record(v, k, target, 0.0);
        if (q.w < 0.0) {
            sarsa_record_direct(v, k, probe_in[2u * i + 1u].x);
        }
        probe_out[i] = vec4(target, 0.0, 0.0, 0.0);
    }
}
