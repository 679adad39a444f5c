#version 460
// Walks host-given rays through the BVH and nothing else, to time the walk
// apart from path tracing (examples/bvh_steps.rs --gpu). Each invocation
// takes `selector` rays, ray g + j * G for j = 0, 1, ... (G invocations), so
// a SIMD group's lanes start on neighbouring rays. Without REFILL a lane
// walks its rays one after another, so its group waits for the longest
// walk of each round, as the trace kernel's lanes do. With REFILL a lane
// whose walk ended starts its next ray at the next step; with REFILL_HALF,
// once half its group waits (the start's code then runs less often).
#extension GL_KHR_shader_subgroup_vote : require
#extension GL_KHR_shader_subgroup_ballot : require

#include "shared.h"
#include "scene.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(push_constant) uniform Push { PassParams params; };

// Two texels per ray: (origin, tmax), (direction, 1 for any hit).
WORDS(ray_texels, B_PROBE_IN)
// Per ray: (t, triangle bits, 0, 0).
layout(std430, set = 0, binding = B_PROBE_OUT) writeonly buffer ProbeOut { vec4 probe_out[]; };

// Ray r's walk, and whether it looks for any hit.
Walk begin_ray(uint r, out bool any_hit) {
    vec4 a = uintBitsToFloat(FETCH(ray_texels, int(2u * r)));
    vec4 b = uintBitsToFloat(FETCH(ray_texels, int(2u * r + 1u)));
    any_hit = b.w > 0.5;
    return walk_begin(a.xyz, b.xyz, a.w);
}

void main() {
    uint g = gl_GlobalInvocationID.x;
    uint count = params.item_count;
    uint per_lane = max(params.selector, 1u);
    uint lanes = gl_NumWorkGroups.x * LINEAR_GROUP;
#ifndef REFILL
    for (uint j = 0u; j < per_lane; ++j) {
        uint r = g + j * lanes;
        if (r < count) {
            bool any_hit;
            Walk w = begin_ray(r, any_hit);
            while (w.node != BVH_NO_CHILD) {
                walk_step(w, any_hit);
            }
            probe_out[r] = vec4(w.hit.t, uintBitsToFloat(w.hit.triangle), 0.0, 0.0);
        }
    }
#else
    uint j = 0u;
    uint r = g;
    bool busy = r < count;
    bool any_hit;
    Walk w = begin_ray(min(r, count - 1u), any_hit);
    // llvmpipe ends an invocation's loops after 65 535 iterations in all.
    for (uint it = 0u; it < 60000u; ++it) {
        if (subgroupAll(!busy)) {
            break;
        }
#ifdef REFILL_HALF
        for (uint inner = 0u; inner < 4096u; ++inner) {
#endif
            bool walking = busy && w.node != BVH_NO_CHILD;
            Walk before = w;
            w.node = walking ? w.node : 0u;
            walk_step(w, any_hit);
            w = walking ? w : before;
#ifdef REFILL_HALF
            if (subgroupBallotBitCount(subgroupBallot(!busy || w.node == BVH_NO_CHILD)) >= 4u) {
                break;
            }
        }
#endif
        // A lane whose walk ended writes its hit and starts its next ray.
        if (busy && w.node == BVH_NO_CHILD) {
            probe_out[r] = vec4(w.hit.t, uintBitsToFloat(w.hit.triangle), 0.0, 0.0);
            j += 1u;
            r = g + j * lanes;
            busy = j < per_lane && r < count;
            bool next_any;
            Walk next = begin_ray(min(r, count - 1u), next_any);
            w = busy ? next : w;
            any_hit = busy ? next_any : any_hit;
        }
    }
#endif
}
