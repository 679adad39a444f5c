// Scene buffers and BVH traversal.
#ifndef QTRACE_SCENE_GLSL
#define QTRACE_SCENE_GLSL

#include "shared.h"
#include "sampling.glsl"

// The scene's buffers, as raw uvec4 words (WORDS in shared.h).
WORDS(node_texels, B_NODES)         // 8 per BvhNode
WORDS(triangle_texels, B_TRIANGLES) // 3 per Triangle
WORDS(material_texels, B_MATERIALS) // 4 per Material
WORDS(normal_texels, B_NORMALS)     // 1 per triangle, with shading normals
WORDS(delta_light_texels, B_DELTA_LIGHTS) // 4 per DeltaLight

Triangle load_triangle(uint i) {
    uvec4 a = FETCH(triangle_texels, int(3u * i));
    uvec4 b = FETCH(triangle_texels, int(3u * i + 1u));
    uvec4 c = FETCH(triangle_texels, int(3u * i + 2u));
    return Triangle(uintBitsToFloat(a.xyz), a.w, uintBitsToFloat(b.xyz), uintBitsToFloat(b.w),
                    uintBitsToFloat(c.xyz), uintBitsToFloat(c.w));
}

Material load_material(uint i) {
    return Material(uintBitsToFloat(FETCH(material_texels, int(4u * i))),
                    uintBitsToFloat(FETCH(material_texels, int(4u * i + 1u))),
                    uintBitsToFloat(FETCH(material_texels, int(4u * i + 2u))),
                    uintBitsToFloat(FETCH(material_texels, int(4u * i + 3u))));
}

// A normal packed by pack_normal (src/scene/mod.rs): the octahedral map's
// point as two 16-bit signed fractions.
vec3 unpack_normal(uint p) {
    vec2 e = unpackSnorm2x16(p);
    vec3 v = vec3(e, 1.0 - abs(e.x) - abs(e.y));
    float t = max(-v.z, 0.0);
    v.xy += mix(vec2(t), vec2(-t), greaterThanEqual(v.xy, vec2(0.0)));
    return normalize(v);
}

// Barycentric coordinates (along e1 and e2) of point p of the triangle's
// plane: an offset along the normal drops out.
vec2 barycentric(Triangle tri, vec3 p) {
    vec3 q = p - tri.v0;
    float d00 = dot(tri.e1, tri.e1);
    float d01 = dot(tri.e1, tri.e2);
    float d11 = dot(tri.e2, tri.e2);
    float d20 = dot(q, tri.e1);
    float d21 = dot(q, tri.e2);
    float inv = 1.0 / (d00 * d11 - d01 * d01);
    return vec2(d11 * d20 - d01 * d21, d00 * d21 - d01 * d20) * inv;
}

// The shading normal of triangle i at point p on it: its corners' normals
// interpolated by p's barycentric coordinates.
vec3 shading_normal(uint i, Triangle tri, vec3 p) {
    vec2 uv = clamp(barycentric(tri, p), vec2(0.0), vec2(1.0));
    float v = uv.x;
    float w = uv.y;
    uvec4 q = FETCH(normal_texels, int(i));
    vec3 n = (1.0 - v - w) * unpack_normal(q.x) + v * unpack_normal(q.y) + w * unpack_normal(q.z);
    return normalize(n);
}

// What delta light i sends to x: the radiance-like term NEE weighs by the
// BSDF (intensity / distance^2 times a spot's falloff, or a directional
// light's irradiance; a projector's, where `projectors` builds its code in,
// before its image at `projected`: (u, v, 1 + texture index or 0), as a
// spot light's that casts an image), the direction toward it and its
// distance.
vec3 delta_light_radiance(uint i, vec3 x, bool projectors, out vec3 wi, out float dist, out vec3 projected) {
    vec4 position = uintBitsToFloat(FETCH(delta_light_texels, int(4u * i)));
    vec4 intensity = uintBitsToFloat(FETCH(delta_light_texels, int(4u * i + 1u)));
    vec4 axis = uintBitsToFloat(FETCH(delta_light_texels, int(4u * i + 2u)));
    vec4 falloff = uintBitsToFloat(FETCH(delta_light_texels, int(4u * i + 3u)));
    uint kind = uint(position.w) & 3u;
    projected = vec3(0.0);
    if (kind == DELTA_DIRECTIONAL) {
        wi = -position.xyz;
        dist = 3.0e38;
        return intensity.rgb;
    }
    vec3 to = position.xyz - x;
    float d2 = dot(to, to);
    dist = sqrt(d2);
    wi = to / dist;
    if (projectors && kind == DELTA_PROJECTOR) {
        // Mitsuba's: x in the projector's frame (z forward), its image's
        // point (u, v) as a perspective camera's, and irradiance at z = 1
        // made radiance by 1 / (z^2 cos): pi scale I(u, v) dist / z^3.
        vec3 d = -to;
        vec3 local = vec3(dot(d, falloff.xyz), falloff.w * dot(d, cross(axis.xyz, falloff.xyz)), dot(d, axis.xyz));
        vec2 uv = 0.5 - 0.5 * intensity.w * vec2(local.x, axis.w * local.y) / local.z;
        bool inside = local.z > 0.0 && all(greaterThanEqual(uv, vec2(0.0))) && all(lessThanEqual(uv, vec2(1.0)));
        projected = vec3(uv, float(uint(position.w) >> 2u));
        return inside ? intensity.rgb * (dist / (local.z * local.z * local.z)) : vec3(0.0);
    }
    vec3 l = intensity.rgb / d2;
    if (kind == DELTA_SPOT) {
        // Mitsuba's: full inside the beam, falling linearly in angle to
        // nothing at the cutoff.
        float c = dot(-wi, axis.xyz);
        float beam = c >= axis.w ? 1.0 : (falloff.x - acos(clamp(c, -1.0, 1.0))) * falloff.y;
        l *= c > intensity.w ? beam : 0.0;
        uint image = uint(position.w) >> 2u;
        if (projectors && image != 0u) {
            // Mitsuba's: the image spans the cone, (u, v) = 0.5 + 0.5
            // (x, y) / (z tan(cutoff)) in the spot's frame.
            vec3 t;
            vec3 b;
            make_frame(axis.xyz, t, b);
            vec3 x_axis = cos(falloff.z) * t + sin(falloff.z) * b;
            vec3 d = -wi;
            vec2 across = vec2(dot(d, x_axis), falloff.w * dot(d, cross(axis.xyz, x_axis)));
            vec2 uv = 0.5 + 0.5 * across / (max(c, 1e-6) * tan(falloff.x));
            projected = vec3(clamp(uv, vec2(0.0), vec2(1.0)), float(image));
        }
    }
    return l;
}

struct Hit {
    float t;
    uint triangle;   // 0xffffffff on a miss
};

const uint NO_HIT = 0xffffffffu;
// Stands for infinity; the scene is far smaller.
const float FAR = 3.0e38;

// Moller-Trumbore; returns t in (0, tmax) or -1. Without early returns:
// lavapipe runs every branch anyway, and each would add masks and selects.
float intersect_triangle(vec3 o, vec3 d, Triangle tri, float tmax) {
    vec3 p = cross(d, tri.e2);
    float det = dot(tri.e1, p);
    float inv = 1.0 / det;
    vec3 s = o - tri.v0;
    float u = dot(s, p) * inv;
    vec3 q = cross(s, tri.e1);
    float v = dot(d, q) * inv;
    float t = dot(tri.e2, q) * inv;
    bool inside = abs(det) >= 1e-12 && u >= 0.0 && u <= 1.0 && v >= 0.0 && u + v <= 1.0;
    return inside && t > 0.0 && t < tmax ? t : -1.0;
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

// Visits child `c` of a node: a leaf's triangle (v0 = p, e1 = q, e2 = r),
// keeping the nearer hit, or an inner child's box (min p, max q). Returns the
// box's entry distance; FAR for a missed box, a leaf or no child.
float visit_child(vec3 o, vec3 d, vec3 inv_d, uint c, vec3 p, vec3 q, vec3 r, inout Hit hit) {
    bool leaf = (c & BVH_LEAF) != 0u; // BVH_NO_CHILD too
    float t = intersect_triangle(o, d, Triangle(p, 0u, q, 0.0, r, 0.0), hit.t);
    bool take = leaf && c != BVH_NO_CHILD && t > 0.0;
    hit.triangle = take ? c & ~BVH_LEAF : hit.triangle;
    hit.t = take ? t : hit.t;
    float enter = intersect_box(o, inv_d, p, q, hit.t);
    return leaf ? FAR : enter;
}

// The walk (walk_bvh below): the nearest hit before tmax (any_hit false),
// or any hit (shadow rays).
// Each step reads one node and visits both its children, so every lane does
// the same work per step (lavapipe runs both sides of a branch). Children
// are taken in the order the ray's direction octant meets them along the
// node's axis. When the ray enters both boxes, the walk goes into the first
// and keeps the second on a stack of three held in registers (an indexed
// per-lane array would cost lavapipe a scatter per push and a gather per
// pop); when it enters neither, it pops. A push onto a full stack drops the
// oldest entry, the last due, and from then on an empty stack sends the walk
// along the node's escape link for the octant: the next node of the
// octant's depth-first order after its subtree, a safe continuation from any
// node because each entry popped since came earlier in that order. (A
// walk a step at a time, walk_begin and walk_step, serves walk_bench.comp.)

// A walk in progress: the ray, the node to visit next (BVH_NO_CHILD once
// done), the stack, top first, its depth, whether it ever dropped an entry,
// and the nearest hit so far.
struct Walk {
    vec3 o;
    vec3 d;
    vec3 inv_d;
    uint octant;
    uint node;
    uint s0;
    uint s1;
    uint s2;
    uint depth;
    bool lost;
    Hit hit;
};

Walk walk_begin(vec3 o, vec3 d, float tmax) {
    uint octant = (d.x < 0.0 ? 1u : 0u) | (d.y < 0.0 ? 2u : 0u) | (d.z < 0.0 ? 4u : 0u);
    return Walk(o, d, safe_inverse(d), octant, 0u, 0u, 0u, 0u, 0u, false, Hit(tmax, NO_HIT));
}

// One step of walk w: reads node w.node and visits both its children. A
// walk for any hit (a shadow ray) ends at its first.
void walk_step(inout Walk w, bool any_hit) {
    int base = int(8u * w.node);
    uvec4 a0 = FETCH(node_texels, base);
    uvec4 b0 = FETCH(node_texels, base + 1);
    uvec4 k0 = FETCH(node_texels, base + 2);
    uvec4 a1 = FETCH(node_texels, base + 3);
    uvec4 b1 = FETCH(node_texels, base + 4);
    uvec4 k1 = FETCH(node_texels, base + 5);
    uint escape = FETCH(node_texels, base + 6 + int(w.octant >> 2u))[w.octant & 3u];
    float t0 = visit_child(w.o, w.d, w.inv_d, a0.w, uintBitsToFloat(a0.xyz), uintBitsToFloat(b0.xyz),
                           uintBitsToFloat(k0.xyz), w.hit);
    float t1 = visit_child(w.o, w.d, w.inv_d, a1.w, uintBitsToFloat(a1.xyz), uintBitsToFloat(b1.xyz),
                           uintBitsToFloat(k1.xyz), w.hit);
    bool swap = ((w.octant >> b0.w) & 1u) != 0u;
    uint first = swap ? a1.w : a0.w;
    uint second = swap ? a0.w : a1.w;
    bool hit_first = (swap ? t1 : t0) != FAR;
    bool hit_second = (swap ? t0 : t1) != FAR;
    // Push, pop or neither, as selects (see intersect_triangle).
    uint popped = w.depth > 0u ? w.s0 : (w.lost ? escape : BVH_NO_CHILD);
    bool push = hit_first && hit_second;
    bool pop = !hit_first && !hit_second && w.depth > 0u;
    w.lost = w.lost || (push && w.depth == 3u);
    w.depth = push ? min(w.depth + 1u, 3u) : (pop ? w.depth - 1u : w.depth);
    uint n0 = push ? second : (pop ? w.s1 : w.s0);
    uint n1 = push ? w.s0 : (pop ? w.s2 : w.s1);
    uint n2 = push ? w.s1 : w.s2;
    w.s0 = n0;
    w.s1 = n1;
    w.s2 = n2;
    uint next = hit_first ? first : (hit_second ? second : popped);
    w.node = any_hit && w.hit.triangle != NO_HIT ? BVH_NO_CHILD : next;
}

Hit walk_bvh(vec3 o, vec3 d, float tmax, bool any_hit) {
    Walk w = walk_begin(o, d, tmax);
    while (w.node != BVH_NO_CHILD) {
        walk_step(w, any_hit);
    }
    return w.hit;
}

Hit trace_ray(vec3 o, vec3 d, float tmax) {
    return walk_bvh(o, d, tmax, false);
}

// Whether anything lies on the ray before tmax.
bool occluded(vec3 o, vec3 d, float tmax) {
    return walk_bvh(o, d, tmax, true).triangle != NO_HIT;
}

#endif
