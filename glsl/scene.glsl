// Scene buffers and BVH traversal.
#ifndef QTRACE_SCENE_GLSL
#define QTRACE_SCENE_GLSL

#include "shared.h"

layout(std430, set = 0, binding = B_NODES) readonly buffer Nodes { BvhNode nodes[]; };
layout(std430, set = 0, binding = B_TRIANGLES) readonly buffer Triangles { Triangle triangles[]; };
layout(std430, set = 0, binding = B_MATERIALS) readonly buffer Materials { Material materials[]; };

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
    if (intersect_box(o, inv_d, nodes[0].bmin, nodes[0].bmax, hit.t) == FAR) {
        return hit;
    }
    while (true) {
        BvhNode n = nodes[node];
        if (n.count > 0u) {
            for (uint i = n.first; i < n.first + n.count; ++i) {
                float t = intersect_triangle(o, d, triangles[i], hit.t);
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
            float ta = intersect_box(o, inv_d, nodes[a].bmin, nodes[a].bmax, hit.t);
            float tb = intersect_box(o, inv_d, nodes[b].bmin, nodes[b].bmax, hit.t);
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
            if (intersect_box(o, inv_d, nodes[candidate].bmin, nodes[candidate].bmax, hit.t) != FAR) {
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
