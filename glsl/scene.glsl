// Scene buffers and BVH traversal.
#ifndef QTRACE_SCENE_GLSL
#define QTRACE_SCENE_GLSL

#include "shared.h"

// The scene's buffers are read as uniform texel buffers of raw uvec4 words:
// lavapipe turns a texel fetch into one vector gather, where a storage
// buffer read is a branching loop over SIMD lanes per 32-bit word.
layout(set = 0, binding = B_NODES) uniform usamplerBuffer node_texels;         // 2 per BvhNode
layout(set = 0, binding = B_TRIANGLES) uniform usamplerBuffer triangle_texels; // 4 per Triangle
layout(set = 0, binding = B_MATERIALS) uniform usamplerBuffer material_texels; // 2 per Material

BvhNode load_node(uint i) {
    uvec4 a = texelFetch(node_texels, int(2u * i));
    uvec4 b = texelFetch(node_texels, int(2u * i + 1u));
    return BvhNode(uintBitsToFloat(a.xyz), a.w, uintBitsToFloat(b.xyz), b.w);
}

Triangle load_triangle(uint i) {
    uvec4 a = texelFetch(triangle_texels, int(4u * i));
    uvec4 b = texelFetch(triangle_texels, int(4u * i + 1u));
    uvec4 c = texelFetch(triangle_texels, int(4u * i + 2u));
    uvec4 d = texelFetch(triangle_texels, int(4u * i + 3u));
    return Triangle(uintBitsToFloat(a.xyz), a.w, uintBitsToFloat(b.xyz), uintBitsToFloat(b.w),
                    uintBitsToFloat(c.xyz), uintBitsToFloat(c.w), d);
}

Material load_material(uint i) {
    return Material(uintBitsToFloat(texelFetch(material_texels, int(2u * i))),
                    uintBitsToFloat(texelFetch(material_texels, int(2u * i + 1u))));
}

struct Hit {
    float t;
    uint triangle;   // 0xffffffff on a miss
};

const uint NO_HIT = 0xffffffffu;
// Stands for infinity; the scene is far smaller.
const float FAR = 3.0e38;

// Moller-Trumbore; returns t in (tmin, tmax) or -1.
float intersect_triangle(vec3 o, vec3 d, Triangle tri, float tmax) {
    vec3 p = cross(d, tri.e2);
    float det = dot(tri.e1, p);
    if (abs(det) < 1e-12) {
        return -1.0;
    }
    float inv = 1.0 / det;
    vec3 s = o - tri.v0;
    float u = dot(s, p) * inv;
    if (u < 0.0 || u > 1.0) {
        return -1.0;
    }
    vec3 q = cross(s, tri.e1);
    float v = dot(d, q) * inv;
    if (v < 0.0 || u + v > 1.0) {
        return -1.0;
    }
    float t = dot(tri.e2, q) * inv;
    return (t > 0.0 && t < tmax) ? t : -1.0;
}

// Entry distance of the ray into the box, or FAR when it misses before tmax.
float intersect_box(vec3 o, vec3 inv_d, vec3 bmin, vec3 bmax, float tmax) {
    vec3 t0 = (bmin - o) * inv_d;
    vec3 t1 = (bmax - o) * inv_d;
    vec3 lo = min(t0, t1);
    vec3 hi = max(t0, t1);
    float enter = max(max(lo.x, lo.y), max(lo.z, 0.0));
    float leave = min(min(hi.x, hi.y), min(hi.z, tmax));
    return enter <= leave ? enter : FAR;
}

vec3 safe_inverse(vec3 d) {
    const float tiny = 1e-20;
    return 1.0 / vec3(
        abs(d.x) > tiny ? d.x : (d.x >= 0.0 ? tiny : -tiny),
        abs(d.y) > tiny ? d.y : (d.y >= 0.0 ? tiny : -tiny),
        abs(d.z) > tiny ? d.z : (d.z >= 0.0 ? tiny : -tiny));
}

// Closest hit (any_hit = false) or any hit before tmax (shadow rays).
Hit trace_ray(vec3 o, vec3 d, float tmax, bool any_hit) {
    Hit hit = Hit(tmax, NO_HIT);
    vec3 inv_d = safe_inverse(d);
    uint stack[BVH_STACK_SIZE];
    uint top = 0u;
    uint node = 0u;
    BvhNode root = load_node(0u);
    if (intersect_box(o, inv_d, root.bmin, root.bmax, hit.t) == FAR) {
        return hit;
    }
    while (true) {
        BvhNode n = load_node(node);
        if (n.count > 0u) {
            for (uint i = n.first; i < n.first + n.count; ++i) {
                float t = intersect_triangle(o, d, load_triangle(i), hit.t);
                if (t > 0.0) {
                    hit.t = t;
                    hit.triangle = i;
                    if (any_hit) {
                        return hit;
                    }
                }
            }
        } else {
            uint a = n.first;
            uint b = n.first + 1u;
            BvhNode na = load_node(a);
            BvhNode nb = load_node(b);
            float ta = intersect_box(o, inv_d, na.bmin, na.bmax, hit.t);
            float tb = intersect_box(o, inv_d, nb.bmin, nb.bmax, hit.t);
            if (ta > tb) {
                float tt = ta; ta = tb; tb = tt;
                uint tn = a; a = b; b = tn;
            }
            if (ta != FAR) {
                if (tb != FAR) {
                    stack[top++] = b;
                }
                node = a;
                continue;
            }
        }
        // Pop until a node the ray still reaches before the current hit.
        bool found = false;
        while (top > 0u) {
            uint candidate = stack[--top];
            BvhNode c = load_node(candidate);
            if (intersect_box(o, inv_d, c.bmin, c.bmax, hit.t) != FAR) {
                node = candidate;
                found = true;
                break;
            }
        }
        if (!found) {
            break;
        }
    }
    return hit;
}

#endif
