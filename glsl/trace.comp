#version 460
// The trace kernel: one path per pixel per pass. Method variants are compiled
// from this one source by build.rs (METHOD_PT, ...).
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_ballot : require
#extension GL_KHR_shader_subgroup_vote : require

#include "shared.h"
#include "rng.glsl"
#include "sampling.glsl"
#include "scene.glsl"

layout(local_size_x = TILE_X, local_size_y = TILE_Y) in;

layout(push_constant) uniform Push { PassParams params; };

#include "bsdf.glsl"
#include "texture.glsl"
#include "environment.glsl"

// The method's guide behind the seam of guide.glsl; plain path tracing's
// (unguided.glsl) covers nothing, and the guides' code folds away.
#if defined(METHOD_SARSA)
#include "sarsa.glsl"
#elif defined(NEURAL_TABLE)
#include "neural_table.glsl"
#elif defined(METHOD_NEURAL)
#include "neural.glsl"
#else
#include "unguided.glsl"
#endif
#include "guide.glsl"

WORDS(light_texels, B_LIGHTS) // 1 per Light

// Whether the scene has shading normals (B_NORMALS): without, the kernel
// is built without the code that reads them.
layout(constant_id = CONSTANT_SHADING_NORMALS) const bool SHADING_NORMALS = false;
layout(constant_id = CONSTANT_PIXEL_FILTER) const uint PIXEL_FILTER = FILTER_BOX;
// Whether the scene has lights only NEE reaches (B_DELTA_LIGHTS).
layout(constant_id = CONSTANT_DELTA_LIGHTS) const bool DELTA_LIGHTS = false;
layout(constant_id = CONSTANT_HIDE_EMITTERS) const bool HIDE_EMITTERS = false;
layout(constant_id = CONSTANT_THIN_LENS) const bool THIN_LENS = false;
layout(constant_id = CONSTANT_NORMAL_MAPS) const bool NORMAL_MAPS = false;
layout(constant_id = CONSTANT_ORTHOGRAPHIC) const bool ORTHOGRAPHIC = false;
layout(std430, set = 0, binding = B_SAMPLES) writeonly buffer Samples { PathSample samples[]; };
layout(std430, set = 0, binding = B_WORK) buffer Work { uint work_counters[]; };

float power_heuristic(float a, float b) {
    float a2 = a * a;
    float b2 = b * b;
    return a2 + b2 > 0.0 ? a2 / (a2 + b2) : 0.0;
}

// Of the `count` light texels from `base`, whose .y is an inclusive CDF,
// the index (from base) of the first that exceeds u.
uint search_cdf(uint base, uint count, float u) {
    uint lo = 0u;
    uint hi = count - 1u;
    while (lo < hi) {
        uint mid = (lo + hi) / 2u;
        if (uintBitsToFloat(FETCH(light_texels, int(base + mid)).y) > u) {
            hi = mid;
        } else {
            lo = mid + 1u;
        }
    }
    return lo;
}

// Index of the light whose inclusive CDF first exceeds u.
uint pick_light(float u) {
    return search_cdf(0u, params.light_count, u);
}

// Index of the light that is triangle `triangle` (lights are in triangle order).
uint light_of(uint triangle) {
    uint lo = 0u;
    uint hi = params.light_count - 1u;
    while (lo < hi) {
        uint mid = (lo + hi) / 2u;
        if (FETCH(light_texels, int(mid)).x < triangle) {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo;
}

// The pass's settings, set once by main and only read after.
#ifdef WITH_NEE
bool nee;
#else
const bool nee = false;
#endif
float eps;
// Whether this pass learns (never in a kernel without GUIDE_LEARNS).
bool learn;

// A path being traced: begin_path starts it, each bounce moves it on.
struct Path {
    uint rng;
    vec3 origin;
    vec3 dir;
    vec3 radiance;
    vec3 throughput;
    uint depth;
    uint hits; // surfaces its rays reached (PathSample.lengths)
    uint rays;
    float prev_bsdf_pdf; // 0 marks the camera ray: no MIS for what it hits
    // Whether its radiance counts, as Mitsuba's path tracer decides: from
    // the start under a visible sky, else once a bounce samples a lobe that
    // is not null (a null BSDF, a mask's clear part, a thin sheet's
    // transmission are null), the one drawn at its last allowed vertex
    // (which it does not follow) included. A path that only passes
    // through surfaces into empty space (or a hidden sky) counts nothing.
    bool valid;
    // The squared TD errors of the transitions the guide learned from it.
    uint td_count;
    float td_sq_sum;
    // What its radiance counts for in the image: a filter with negative
    // lobes' sign and normalization at its point (1 for the others).
    float filter_weight;
};

// What the guide keeps of a path, to learn from it and to steer its roulette.
struct Trail {
    // The vertex the path's ray left from, the sector it took there and the
    // Q the guide gave that sector, to learn from once the ray lands.
    GuideVertex prev_vertex;
    // The vertex whose choice of NEE's light the MIS weight of what that
    // ray reaches takes: NEE picks from the table of the side the path
    // arrives on, while a bounce through a surface that lets light through
    // leaves by the other side's (pick_vertex_of; mixture_two_sided only).
    GuideVertex pick_vertex;
    uint prev_sector;
    float prev_q;
    // Whether prev_q is what the guide expects along the path's ray (else
    // the roulette follows the throughput alone).
    bool guided_roulette;
    // The guide's estimate of the radiance this path's first hit sends to
    // the camera: the scale Russian roulette compares a path's prospects with.
    float path_estimate;
    // A transition that lands on a delta vertex (a mirror, glass) learns
    // where the path next reaches one that is not (or ends): its target is
    // what arrives there times the delta bounces' weights, one sample of
    // what the delta vertex sends back. The guide's own estimate there
    // (guide_reflect) knows nothing of what lies behind glass. `chaining`
    // while such a transition waits; a path that ends on the way learns
    // nothing from it.
    bool chaining;
    GuideVertex chain_from;
    uint chain_sector;
    float chain_q;
    float chain_weight;
    // The share of BSDF sampling learns from the radiance L a sampled
    // direction brought, squared (mixture_gradient). The path's own estimate
    // of it is known once the path ends: what it gathered after the sample,
    // per unit of the throughput it then had. (Q, which bootstraps from a
    // small start, underestimates light that arrives after many bounces, and
    // would steer the share away from BSDF sampling just where the guide
    // knows least.) Kept for the first two sampled vertices of a path.
    GuideVertex share_from0;
    float share_mix0; // mixture_gradient; 0: none kept
    float share_throughput0;
    float share_radiance0;
    GuideVertex share_from1;
    float share_mix1;
    float share_throughput1;
    float share_radiance1;
    // The transition the current ray completes, kept by scatter() where the
    // ray landed for the one call of guide_learn in bounce(): lavapipe runs
    // the code of every call site, the guide's atomics included, at every
    // vertex.
    GuideVertex land_from;
    uint land_sector;
    float land_q;
    float land_le;
    float land_mis_weight;
    float land_reflected;
    float land_direct;
    float land_scale;
};

// A point of the pixel, as an offset from its corner, drawn from the
// scene's pixel filter (PIXEL_FILTER): the image converges to the one a
// renderer that splats each sample with that filter makes.
vec2 filter_offset(vec2 u) {
    float r = params.cam_forward.w;
    if (PIXEL_FILTER == FILTER_TENT) {
        vec2 t = mix(sqrt(2.0 * u) - 1.0, 1.0 - sqrt(2.0 - 2.0 * u), step(0.5, u));
        return 0.5 + r * t;
    }
    if (PIXEL_FILTER == FILTER_GAUSSIAN) {
        // Box-Muller; Mitsuba cuts its Gaussian at 4 deviations, where
        // less than 1e-3 of its weight lies beyond.
        float l = r * sqrt(-2.0 * log(max(1.0 - u.x, 1e-30)));
        return 0.5 + l * vec2(cos(2.0 * PI * u.y), sin(2.0 * PI * u.y));
    }
    return u;
}

// A signed filter's value at offset x (in pixels, from the pixel's centre)
// along one axis (Mitsuba's mitchell, catmullrom and lanczos).
float signed_filter(float x) {
    x = abs(x);
    if (PIXEL_FILTER == FILTER_LANCZOS) {
        float r = params.cam_forward.w;
        float x1 = PI * x;
        float x2 = x1 / r;
        return x < 1e-6 ? 1.0 : x > r ? 0.0 : sin(x1) * sin(x2) / (x1 * x2);
    }
    float b = params.environment.y;
    float c = params.environment.z;
    float x2 = x * x;
    float x3 = x2 * x;
    float v = x < 1.0 ? (12.0 - 9.0 * b - 6.0 * c) * x3 + (-18.0 + 12.0 * b + 6.0 * c) * x2 + (6.0 - 2.0 * b)
                      : (-b - 6.0 * c) * x3 + (6.0 * b + 30.0 * c) * x2 + (-12.0 * b - 48.0 * c) * x + (8.0 * b + 24.0 * c);
    return x < 2.0 ? v / 6.0 : 0.0;
}

// One axis of a signed filter's point for a pixel whose offsets inside the
// image lie in [lo, hi): drawn in proportion to the filter's magnitude
// there (by rejection under params.environment.w), with weight
// sign x (integral of |f| / integral of f) over [lo, hi), as a renderer that
// splats with the filter weighs the samples it gathers (midpoint sums of
// 64 steps).
float signed_filter_axis(float lo, float hi, inout uint rng, inout float weight) {
    float r = PIXEL_FILTER == FILTER_LANCZOS ? params.cam_forward.w : 2.0;
    lo = max(lo, -r);
    hi = min(hi, r);
    float x = 0.0;
    float fx = 1.0;
    for (uint i = 0u; i < 64u; i++) {
        float u = rng_next(rng);
        float v = rng_next(rng);
        float t = mix(lo, hi, u);
        float f = signed_filter(t);
        if (v * params.environment.w < abs(f)) {
            x = t;
            fx = f;
            break;
        }
    }
    float total = 0.0;
    float magnitude = 0.0;
    float dx = (hi - lo) / 64.0;
    for (uint k = 0u; k < 64u; k++) {
        float f = signed_filter(lo + (float(k) + 0.5) * dx);
        total += f;
        magnitude += abs(f);
    }
    weight *= (fx < 0.0 ? -1.0 : 1.0) * magnitude / total;
    return x;
}

// A point of the image for this pixel, in pixels. A splatting renderer's
// pixel at the border gathers only samples inside the image, so its filter
// is cut at the border: draws that land outside are drawn again (a box
// filter's never do).
vec2 image_point(uvec2 pixel, inout uint rng, inout float weight) {
    bool border = (params.flags & FLAG_SAMPLE_BORDER) != 0u;
    if (PIXEL_FILTER >= FILTER_CUBIC) {
        // Offsets from the pixel's centre that stay inside the image, or
        // with the border sampled, the filter's whole support.
        vec2 c = vec2(pixel) + 0.5;
        vec2 lo = border ? vec2(-1e9) : -c;
        vec2 hi = border ? vec2(1e9) : vec2(float(params.width), float(params.height)) - c;
        float x = signed_filter_axis(lo.x, hi.x, rng, weight);
        float y = signed_filter_axis(lo.y, hi.y, rng, weight);
        return c + vec2(x, y);
    }
    vec2 p = vec2(pixel) + filter_offset(rng_next2(rng));
    if (PIXEL_FILTER == FILTER_BOX || border) {
        return p;
    }
    vec2 size = vec2(float(params.width), float(params.height));
    for (uint i = 0u; i < 16u && (any(lessThan(p, vec2(0.0))) || any(greaterThanEqual(p, size))); i++) {
        vec2 again = vec2(pixel) + filter_offset(rng_next2(rng));
        bvec2 out_lo = lessThan(p, vec2(0.0));
        bvec2 out_hi = greaterThanEqual(p, size);
        p = mix(p, again, bvec2(out_lo.x || out_hi.x, out_lo.y || out_hi.y));
    }
    return clamp(p, vec2(0.0), size);
}

// Starts sample `sample_index` of this pixel: a camera ray through a point
// of the pixel drawn from the pixel filter.
void begin_path(uvec2 pixel, uint sample_index, out Path path, out Trail trail) {
    path.rng = rng_init(pixel.y * params.width + pixel.x, sample_index, params.seed);
    path.filter_weight = 1.0;
    vec2 point = image_point(pixel, path.rng, path.filter_weight);
    vec2 ndc = vec2(
        2.0 * point.x / float(params.width) - 1.0,
        1.0 - 2.0 * point.y / float(params.height));
    vec3 across = ndc.x * params.cam_right.xyz + ndc.y * params.cam_up.xyz;
    vec3 through = params.cam_forward.xyz + across;
    path.origin = params.cam_pos.xyz;
    if (ORTHOGRAPHIC) {
        path.origin += across;
        through = params.cam_forward.xyz;
    }
    if (THIN_LENS) {
        // A thin lens of radius cam_right.w, in focus on the plane
        // cam_up.w ahead: a point of the lens, aimed where the pinhole's
        // ray meets that plane.
        vec2 lens = params.cam_right.w * square_to_disk(rng_next2(path.rng));
        vec3 offset = lens.x * normalize(params.cam_right.xyz) + lens.y * normalize(params.cam_up.xyz);
        path.origin += offset;
        through = through * params.cam_up.w - offset;
    }
    path.dir = normalize(through);
    path.radiance = vec3(0.0);
    path.throughput = vec3(1.0);
    path.depth = 0u;
    path.hits = 0u;
    path.rays = 0u;
    path.prev_bsdf_pdf = 0.0;
    path.valid = ENVIRONMENT && !HIDE_EMITTERS;
    guide_begin_path();
    trail.prev_vertex = guide_none();
    if (mixture_two_sided()) {
        trail.pick_vertex = guide_none();
    }
    trail.prev_sector = 0u;
    trail.prev_q = 0.0;
    trail.guided_roulette = false;
    trail.path_estimate = 0.0;
    trail.chaining = false;
    trail.share_mix0 = 0.0;
    trail.share_mix1 = 0.0;
    path.td_count = 0u;
    path.td_sq_sum = 0.0;
}

void keep_share_sample(inout Trail trail, Path path, GuideVertex g, float mix) {
    if (trail.share_mix0 == 0.0) {
        trail.share_from0 = g;
        trail.share_mix0 = mix;
        trail.share_throughput0 = luminance(path.throughput);
        trail.share_radiance0 = luminance(path.radiance);
    } else if (trail.share_mix1 == 0.0) {
        trail.share_from1 = g;
        trail.share_mix1 = mix;
        trail.share_throughput1 = luminance(path.throughput);
        trail.share_radiance1 = luminance(path.radiance);
    }
}

float share_gradient(Path path, float mix, float t, float r) {
    float l = t > 0.0 ? max(luminance(path.radiance) - r, 0.0) / t : 0.0;
    return mix * l * l;
}

// At the path's end: each kept sample's gradient to the guide.
void learn_share_samples(Trail trail, Path path) {
    if (trail.share_mix0 != 0.0) {
        guide_learn_share(trail.share_from0, share_gradient(path, trail.share_mix0, trail.share_throughput0, trail.share_radiance0));
    }
    if (trail.share_mix1 != 0.0) {
        guide_learn_share(trail.share_from1, share_gradient(path, trail.share_mix1, trail.share_throughput1, trail.share_radiance1));
    }
}

void land(inout Trail trail, float le, float mis_weight, float reflected, float direct) {
    trail.land_from = trail.chaining ? trail.chain_from : trail.prev_vertex;
    trail.land_sector = trail.chaining ? trail.chain_sector : trail.prev_sector;
    trail.land_q = trail.chaining ? trail.chain_q : trail.prev_q;
    trail.land_scale = trail.chaining ? trail.chain_weight : 1.0;
    trail.chaining = false;
    trail.land_le = le * trail.land_scale;
    trail.land_mis_weight = mis_weight;
    trail.land_reflected = reflected * trail.land_scale;
    trail.land_direct = direct * trail.land_scale;
}

// The path's ray landed on a delta vertex, from a vertex the guide covers
// or through delta vertices from one: the transition waits (see chaining).
void pass_through_delta(inout Trail trail) {
    if (!trail.chaining) {
        trail.chain_from = trail.prev_vertex;
        trail.chain_sector = trail.prev_sector;
        trail.chain_q = trail.prev_q;
        trail.chain_weight = 1.0;
        trail.chaining = true;
    }
    trail.land_from = guide_none();
}

// After a bounce the guide did not sample (a delta lobe, rough glass) from
// vertex g: guides learn along reflections, which stay in g's hemisphere.
void follow_unguided(inout Trail trail, GuideVertex g, vec3 local, vec3 weight) {
    bool up = local.z > 0.0;
    if (GUIDE_LEARNS && !trail.chaining && guide_covers(g)) {
        trail.prev_sector = up ? hemisphere_sector(local, grid_a(), grid_b()) : 0u;
        trail.prev_q = up ? guide_sector_q(g, trail.prev_sector) : 0.0;
        trail.guided_roulette = true;
    } else {
        // Not looked up (a kernel without the learning code, a pass that
        // does not learn, no volume there) or a transition waiting
        // (chaining), whose Q stands for the path: the roulette keeps what
        // the vertex before expected from this direction, per unit of the
        // throughput it had then.
        trail.prev_q /= max(luminance(weight), 1e-6);
        if (trail.chaining) {
            trail.chain_weight *= luminance(weight);
        }
    }
    trail.prev_vertex = up ? g : guide_none();
    if (mixture_two_sided()) {
        trail.pick_vertex = trail.prev_vertex;
    }
}

// The vertex whose choice of NEE's light a ray from the trail's last vertex
// weighs what it reaches by (Trail.pick_vertex).
GuideVertex pick_vertex_of(Trail trail) {
    return mixture_two_sided() ? trail.pick_vertex : trail.prev_vertex;
}

// What MIS takes as the probability that NEE picks `entry` where it picked
// it with probability p: at least power's, so that a light the guide picks
// seldom does not make the bounces that find it fireflies (the two
// weights still sum to one, as both sides take this).
float mis_pick(float p, uvec4 entry) {
    return max(p, uintBitsToFloat(entry.z));
}

// Light l (LightGroup) of those the guides pick among.
uvec4 light_group(uint l) {
    return FETCH(light_texels, int(params.light_count + l));
}

// The probability of NEE's list's `entry` within its light (LightGroup).
float share_in_light(uvec4 entry) {
    return uintBitsToFloat(entry.z) / uintBitsToFloat(light_group(entry.w).z);
}

// NEE's light at g, its index in NEE's list: where the guide learns the
// choice (GUIDE_LIGHTS), a light (LightGroup) `group` drawn from the
// guide's table with probability p_group, then one of its entries by
// power, p the entry's probability; else an entry by emitted power (p 0:
// its own pdf holds it).
uint nee_choose_light(GuideVertex g, inout uint rng, out uint group, out float p_group, out float p) {
    p = 0.0;
    p_group = 0.0;
    group = 0u;
    if (!GUIDE_LIGHTS) {
        return pick_light(rng_next(rng));
    }
    group = guide_choose_light(g, rng_next(rng), p_group);
    uvec4 light = light_group(group);
    // Its members follow the lights.
    uint base = params.light_count + light_groups() + light.x;
    uint entry = FETCH(light_texels, int(base + search_cdf(base, light.y, rng_next(rng)))).x;
    p = p_group * share_in_light(FETCH(light_texels, int(entry)));
    return entry;
}

// Where the guide picks NEE's light, the probability of picking entry
// `light` of NEE's list that MIS weighs NEE by at vertex `from`: the larger
// of the guide's choice and power's (`mis_pick`).
float nee_mis_pick(GuideVertex from, uint light) {
    uvec4 entry = FETCH(light_texels, int(light));
    return mis_pick(guide_light_probability(from, entry.w) * share_in_light(entry), entry);
}

// The path's ray left the scene: the sky, weighed against NEE's draws of
// it as an emitter is.
void gather_sky(inout Path path, inout Trail trail) {
    vec3 le = ENVIRONMENT && path.valid ? environment_eval(path.dir) : vec3(0.0);
    float weight = 1.0;
    if (ENVIRONMENT && nee && path.prev_bsdf_pdf > 0.0) {
        // The sky's parts are the last of NEE's lights.
        uint part;
        float density = environment_pdf(path.dir, part);
        uint light = params.light_count - environment_parts() + part;
        float pick = GUIDE_LIGHTS ? nee_mis_pick(pick_vertex_of(trail), light)
                                  : uintBitsToFloat(FETCH(light_texels, int(light)).z);
        weight = power_heuristic(path.prev_bsdf_pdf, pick * density / environment_share(part));
    }
    path.radiance += path.throughput * le * weight;
    if (learn) {
        land(trail, luminance(le), weight, 0.0, 0.0);
    }
}

// Whether emitting triangle i of material `mat` sends light from point p
// along unit direction d: on the side its shading normal faces, as
// Mitsuba's area lights emit, so a smooth mesh's light ends where its
// normals turn away (MATERIAL_EMITTER_SMOOTH, FEATURE_SMOOTH_LIGHTS; else
// where the geometric cosine `cos_geometric` is positive).
bool emits_along(uint i, Triangle tri, Material mat, vec3 p, vec3 d, float cos_geometric) {
    if (SHADING_NORMALS && (MATERIAL_FEATURES & FEATURE_SMOOTH_LIGHTS) != 0u && (uint(mat.color.w) & MATERIAL_EMITTER_SMOOTH) != 0u) {
        return dot(shading_normal(i, tri, p), d) > 0.0;
    }
    return cos_geometric > 0.0;
}

// The path's ray reached an emitter: its emission (on its front side only),
// weighed against NEE's draws of it (nee_mis_pick), added to the path's
// radiance; returns the emission's luminance and that weight, for the
// guide.
vec2 emitter_light(inout Path path, inout Trail trail, Hit hit, Triangle tri, Material mat, float cos_out) {
    float weight = 1.0;
    vec3 le = vec3(0.0);
    vec3 p = path.origin + hit.t * path.dir;
    if (emits_along(hit.triangle, tri, mat, p, -path.dir, cos_out)) {
        le = emitted(mat, hit.triangle, barycentric(tri, p));
        if (nee && path.prev_bsdf_pdf > 0.0) {
            float area_pdf = GUIDE_LIGHTS ? nee_mis_pick(pick_vertex_of(trail), light_of(hit.triangle)) / tri.area
                                          : tri.light_pdf;
            float light_pdf = area_pdf * hit.t * hit.t / abs(cos_out);
            weight = power_heuristic(path.prev_bsdf_pdf, light_pdf);
        }
        path.radiance += path.throughput * le * weight;
    }
    return vec2(luminance(le), weight);
}

// The path's ray reached an emitter whose BSDF is black or null, where the
// transition it took lands.
void gather_emitter(inout Path path, inout Trail trail, Hit hit, Triangle tri, Material mat, float cos_out) {
    vec2 light = emitter_light(path, trail, hit, tri, mat, cos_out);
    if (learn) {
        land(trail, light.x, light.y, 0.0, 0.0);
    }
}

// A surface point the path reached, and its shading frame.
struct Shading {
    vec3 point;    // on the surface
    vec3 position; // off it by eps, on the side the ray came from
    vec3 ng;       // the geometric normal, facing the ray
    vec3 ns;       // the shading normal, facing the ray (ng without shading normals)
    vec3 t;        // the frame (t, b, ns)
    vec3 b;
    vec3 wo;       // toward where the ray came from, in the frame
    // Under a normal map (NORMAL_MAPS), ns is the mapped normal; `unmapped`
    // the normal it turned, and `map_alpha2` the roughness its shadowing
    // takes (normal_map_weight); -1 where the material has no map.
    vec3 unmapped;
    float map_alpha2;
};

// Whether a vertex's shading normal may differ from its surface's.
const bool SHADING_FRAME = SHADING_NORMALS || NORMAL_MAPS;

// A triangle's texture coordinates at barycentric coordinates b and its
// (u, v) tangents dp/du and dp/dv (as Mitsuba's meshes have them); `valid`
// false where its texture coordinates span no area.
struct UvFrame {
    vec2 uv;
    vec3 dp_du;
    vec3 dp_dv;
    bool valid;
};

UvFrame uv_frame(uint triangle, Triangle tri, vec2 b) {
    uvec4 p = FETCH(uv_texels, int(2u * triangle));
    uvec4 q = FETCH(uv_texels, int(2u * triangle + 1u));
    vec2 uv0 = uintBitsToFloat(p.xy);
    vec2 d1 = uintBitsToFloat(p.zw) - uv0;
    vec2 d2 = uintBitsToFloat(q.xy) - uv0;
    float det = d1.x * d2.y - d1.y * d2.x;
    return UvFrame(uv0 + b.x * d1 + b.y * d2, (d2.y * tri.e1 - d1.y * tri.e2) / det,
                   (d1.x * tri.e2 - d2.x * tri.e1) / det, det != 0.0);
}

// Mitsuba's normalmap: the normal n0 (the surface's own shading normal, not
// turned toward the ray) turned by texel 2 rgb - 1 of texture `map`, read
// in the frame of n0 and the surface's tangent dp/du, at `at`.
vec3 mapped_normal(UvFrame at, vec3 n0, uint map) {
    vec3 s = at.dp_du - n0 * dot(n0, at.dp_du);
    vec3 t;
    if (!at.valid || !(dot(s, s) > 0.0)) {
        make_frame(n0, s, t);
    } else {
        s = normalize(s);
        t = cross(n0, s);
    }
    vec3 m = normalize(2.0 * texture_eval(map, at.uv) - 1.0);
    return normalize(m.x * s + m.y * t + m.z * n0);
}

// Mitsuba's bumpmap: the normal of the surface whose tangents dp/du and
// dp/dv at `at` are tilted along the unmapped normal n0 by the gradient of
// height field `map` times `scale`, turned to the side of the geometric
// normal ng.
vec3 bumped_normal(UvFrame at, vec3 n0, vec3 ng, uint map, float scale) {
    vec2 g = scale * texture_gradient(map, at.uv);
    vec3 m = cross(at.dp_du + n0 * (g.x - dot(n0, at.dp_du)), at.dp_dv + n0 * (g.y - dot(n0, at.dp_dv)));
    m = dot(m, ng) < 0.0 ? -m : m;
    return !at.valid || !(dot(m, m) > 0.0) ? n0 : normalize(m);
}

// What a normal map leaves of light leaving the surface in direction d:
// nothing on the other side of the unmapped normal than of the mapped one,
// else the shadowing of Conty Estevez and Kulla (2018) of a surface whose
// roughness the angle between the two normals sets (as Mitsuba weighs it).
// 1 without a map.
float normal_map_weight(Shading s, vec3 d) {
    if (!NORMAL_MAPS || s.map_alpha2 < 0.0) {
        return 1.0;
    }
    float c = dot(d, s.unmapped);
    if (c * dot(d, s.ns) <= 0.0) {
        return 0.0;
    }
    float c2 = c * c;
    return 2.0 / (1.0 + sqrt(1.0 + s.map_alpha2 * (1.0 - c2) / c2));
}

// NEE at shading point `s`: one light (the guide's choice where it learns
// one, else by power), one point or direction on it, a shadow ray, and
// the sample weighed by MIS against the bounce's density (the mixture `m`).
// Adds it to the path's radiance and returns its luminance (what the
// transition that reached s learns NEE brought there). `coverage`: the
// share of the surface that scatters (a mask's opacity; 1 elsewhere), which
// scales the BSDF and its density as Mitsuba's mask does.
float next_event(inout Path path, Shading s, Bsdf bsdf, GuideVertex here, Mixture m, bool transmits, float coverage) {
    float direct_lum = 0.0;
    float pick_pdf;
    uint group;
    float group_pdf;
    uint light = nee_choose_light(here, path.rng, group, group_pdf, pick_pdf);
    uvec4 entry = FETCH(light_texels, int(light));
    float brought = 0.0;
    // A delta light: its one direction, its pick's probability as the
    // pdf, no MIS (no bounce finds it). An emitting triangle: a point
    // on it, its solid-angle density.
    bool delta_light = DELTA_LIGHTS && (entry.x & LIGHT_DELTA) != 0u;
    vec3 wi;
    float dist;
    float light_pdf;
    vec3 le;
    bool faces = true;
    if (delta_light) {
        vec3 projected;
        bool projectors = (MATERIAL_FEATURES & FEATURE_PROJECTORS) != 0u;
        le = delta_light_radiance(entry.x & ~LIGHT_DELTA, s.position, projectors, wi, dist, projected);
        // A projector's image there.
        if (scene_textured() && projected.z > 0.0) {
            le *= texture_eval(uint(projected.z) - 1u, projected.xy);
        }
        light_pdf = GUIDE_LIGHTS ? pick_pdf : uintBitsToFloat(entry.z);
    } else if (ENVIRONMENT && (entry.x & ~1u) == LIGHT_ENVIRONMENT) {
        // A part of the sky: a direction by its brightness, unbounded.
        uint part = entry.x & 1u;
        wi = environment_sample(vec4(rng_next2(path.rng), rng_next2(path.rng)), part, light_pdf);
        light_pdf *= (GUIDE_LIGHTS ? pick_pdf : uintBitsToFloat(entry.z)) / environment_share(part);
        le = environment_eval(wi);
        dist = 3.0e38;
        faces = light_pdf > 0.0;
    } else {
        Triangle lt = load_triangle(entry.x);
        float area_pdf = GUIDE_LIGHTS ? pick_pdf / lt.area : lt.light_pdf;
        vec2 u = rng_next2(path.rng);
        if (u.x + u.y > 1.0) {
            u = 1.0 - u;
        }
        vec3 target = lt.v0 + u.x * lt.e1 + u.y * lt.e2;
        vec3 to_light = target - s.position;
        float dist2 = dot(to_light, to_light);
        dist = sqrt(dist2);
        wi = to_light / dist;
        float cos_y = -dot(normalize(cross(lt.e1, lt.e2)), wi);
        Material lm = load_material(lt.material);
        faces = cos_y != 0.0 && emits_along(entry.x, lt, lm, target, -wi, cos_y);
        light_pdf = area_pdf * dist2 / abs(cos_y);
        le = emitted(lm, entry.x, u);
    }
    float cos_x = dot(s.ns, wi);
    if ((cos_x > 0.0 || (transmits && cos_x < 0.0)) && faces) {
        path.rays += 1u;
        // A direction the shading normal allows may lie below the
        // geometric surface, as rough glass's transmission does: the
        // shadow ray then leaves from beneath.
        // It aims at the light's point from there (a directional
        // light's direction stays).
        vec3 from = s.position;
        vec3 shadow_dir = wi;
        float reach = dist;
        if ((SHADING_FRAME || transmits) && dot(wi, s.ng) < 0.0) {
            from = s.point - s.ng * eps;
            vec3 to = s.position + wi * dist - from;
            reach = dist < 1e30 ? length(to) : dist;
            shadow_dir = dist < 1e30 ? to / reach : wi;
        }
        if (!occluded(from, shadow_dir, reach * (1.0 - 1e-4) - eps)) {
            vec3 wi_local = vec3(dot(wi, s.t), dot(wi, s.b), cos_x);
            float scatter_pdf = mixture_pdf(m, bsdf, s.wo, wi_local);
            // A plastic's coat takes some bounces as a mirror.
            scatter_pdf *= (1.0 - bsdf_delta_share(bsdf, s.wo)) * coverage;
            // The light's density as MIS takes it (mis_pick).
            float per_pick = GUIDE_LIGHTS ? light_pdf / pick_pdf : 0.0;
            float mis_pdf = GUIDE_LIGHTS ? per_pick * mis_pick(pick_pdf, entry) : light_pdf;
            float weight = delta_light ? 1.0 : power_heuristic(mis_pdf, scatter_pdf);
            vec3 f_le = bsdf_eval(bsdf, s.wo, wi_local) * (normal_map_weight(s, wi) * coverage) * le;
            vec3 direct = f_le * weight / light_pdf;
            path.radiance += path.throughput * direct;
            direct_lum = luminance(direct);
            if (GUIDE_LIGHTS) {
                // What its whole light brought, weighed as MIS would
                // were NEE to pick by power (not by the guide's own
                // choice, which would only confirm itself).
                float by_power = per_pick * uintBitsToFloat(entry.z);
                float mis = delta_light ? 1.0 : power_heuristic(by_power, scatter_pdf);
                brought = luminance(f_le) * mis / light_pdf * group_pdf;
            }
        }
    }
    if (GUIDE_LIGHTS && learn) {
        guide_record_light(here, group, brought);
    }
    return direct_lum;
}

// The bounce at shading point `s`: a delta lobe's one direction (no MIS for
// what it hits, as NEE skipped it), or a direction from the mixture at
// `m` (BSDF sampling alone without a guide) with its density.
// Sets the path's next ray and throughput; false when the path ends (a
// direction of zero density). `mix`: the sample's gradient for the share of
// BSDF sampling, in a pass that learns.
bool sample_bounce(inout Path path, inout Trail trail, Shading s, Bsdf bsdf, GuideVertex here, Mixture m,
                   bool delta, bool transmits, bool glossy, out float mix) {
    vec3 local;
    vec3 weight;
    float pdf = 0.0;
    mix = 0.0;
    // A plastic takes its coat's mirror with this probability, as a delta
    // vertex would (and what that ray hits takes no MIS, as NEE cannot
    // find it); else its base, of density (1 - share) times the sampler's.
    float delta_share = bsdf_delta_share(bsdf, s.wo);
    bool take_delta = delta || (delta_share > 0.0 && rng_next(path.rng) < delta_share);
    if (take_delta) {
        local = bsdf_sample_delta(bsdf, s.wo, rng_next(path.rng), weight);
        weight /= delta ? 1.0 : delta_share;
        follow_unguided(trail, here, local, weight);
        path.valid = path.valid || !bsdf_is(bsdf, MATERIAL_THIN) || local.z * s.wo.z >= 0.0;
    } else {
        path.valid = true;
        uint sector = 0u;
        float p_sector = 0.0;
        float p_bsdf = 0.0;
        // The guide vertex of the side the bounce leaves on: the other
        // side's, through a surface that lets light through (Mixture).
        GuideVertex side = here;
        if (GUIDED) {
            local = mixture_sample(m, bsdf, s.wo, vec3(rng_next2(path.rng), rng_next(path.rng)), sector, p_sector);
            p_bsdf = bsdf_pdf(bsdf, s.wo, local);
            pdf = mixture_pdf_of(m, p_bsdf, local, p_sector);
            side = mixture_side(m, local);
            trail.prev_vertex = side;
            if (mixture_two_sided()) {
                trail.pick_vertex = here;
            }
            trail.prev_sector = sector;
            trail.prev_q = guide_q(side, sector, p_sector);
            trail.guided_roulette = guide_covers(side);
        } else {
            vec2 square;
            // The third number picks a lobe (of rough glass, a rough plastic, a
            // principled BSDF); drawn only where there is one.
            bool rough = (MATERIAL_FEATURES & (FEATURE_ROUGH_GLASS | FEATURE_ROUGH_PLASTIC | FEATURE_PRINCIPLED)) != 0u;
            local = bsdf_sample(bsdf, s.wo, vec3(rng_next2(path.rng), rough ? rng_next(path.rng) : 0.0), square);
            pdf = bsdf_pdf(bsdf, s.wo, local);
        }
        pdf *= 1.0 - delta_share;
        if (pdf <= 0.0) {
            return false;
        }
        weight = bsdf_eval(bsdf, s.wo, local) / pdf;
        if (transmits && !mixture_two_sided()) {
            // Rough glass where the guide holds one vertex at a time:
            // sampled by its BSDF alone, learned through as a delta vertex.
            follow_unguided(trail, here, local, weight);
        }
        mix = learn ? mixture_gradient(m, p_bsdf, local, p_sector, pdf, weight) : 0.0;
        if (glossy && (learn || path.depth == 0u)) {
            // What a glossy lobe reflects of the light the guide expects,
            // (2 pi / n) sum_j Q_j f cos(theta_j): one sample's estimate from
            // the mixture's own draw, Q of its sector times f cos / pdf
            // (unbiased for Q constant over each sector). Q itself, not the
            // sampling table's weight (prev_q), which with NEE leaves out
            // NEE's share.
            float estimate = luminance(weight) * guide_sector_q(side, sector);
            trail.land_reflected = estimate * trail.land_scale;
            if (path.depth == 0u) {
                trail.path_estimate = estimate;
            }
        }
    }
    path.throughput *= weight;
    path.prev_bsdf_pdf = pdf;
    path.dir = normalize(local.x * s.t + local.y * s.b + local.z * s.ns);
    path.origin = s.point + ((SHADING_FRAME ? dot(path.dir, s.ng) > 0.0 : local.z > 0.0) ? eps : -eps) * s.ng;
    if (NORMAL_MAPS) {
        float shadowing = normal_map_weight(s, path.dir);
        if (shadowing <= 0.0) {
            return false;
        }
        path.throughput *= shadowing;
    }
    return true;
}

// Russian roulette from RR_START_DEPTH on; false ends the path. A path
// that does not count yet (Path.valid) drops the light it gathered when it
// ends, so where its roulette starts shapes the image: such a path takes
// Mitsuba's, from its fifth vertex on, by the throughput alone.
bool survives_roulette(inout Path path, Trail trail) {
    bool pending = !path.valid;
    if (path.depth + 1u < (pending ? PENDING_RR_START_DEPTH : RR_START_DEPTH)) {
        return true;
    }
    float q = min(max(path.throughput.r, max(path.throughput.g, path.throughput.b)), 0.95);
    // Guided paths toward light carry small weights because their pdf
    // is high, so throughput alone would end exactly the paths the guide
    // chose. They also survive by what they are expected to bring:
    // throughput times the radiance Q expects from the sampled sector,
    // against the estimate for the whole path (weight window at 1).
    // Never below the throughput rule, so a Q that underestimates ends
    // no more of a path's continuations than that rule would.
    if (!pending && trail.guided_roulette && trail.path_estimate > 0.0) {
        float expected = luminance(path.throughput) * trail.prev_q;
        q = max(q, clamp(expected / trail.path_estimate, 0.1, 0.95));
    }
    if (rng_next(path.rng) >= q) {
        return false;
    }
    path.throughput /= q;
    return true;
}

// The camera's ray past the emitters it meets (HIDE_EMITTERS), from
// its first hit; a miss after more than a few.
Hit pass_emitters(inout Path path, Hit hit) {
    for (uint i = 0u; i < 16u; ++i) {
        if (hit.triangle == NO_HIT) {
            return hit;
        }
        Triangle tri = load_triangle(hit.triangle);
        if (tri.light_pdf <= 0.0) {
            return hit;
        }
        vec3 n = normalize(cross(tri.e1, tri.e2));
        path.origin += hit.t * path.dir + (dot(n, path.dir) > 0.0 ? eps : -eps) * n;
        hit = trace_ray(path.origin, path.dir, FAR);
        path.rays += 1u;
    }
    hit.triangle = NO_HIT;
    return hit;
}

// The material choice `mat` stands for at point p of triangle i (Mitsuba's
// mask, blendbsdf, twosided with two BSDFs; MATERIAL_CHOICE). Taking one
// of the two at random by the weight, rather than Mitsuba's mixture of
// their values, converges to the same image. A mask (CHOICE_MASK) always
// gives its inner material, for NEE to see the surface, multiplies
// `coverage` by its opacity and sets `passes` where the path goes through
// its clear part.
Material chosen_material(Material mat, bool front, uint i, Triangle tri, vec3 p, inout uint rng, inout float coverage,
                         inout bool passes) {
    for (uint level = 0u; level < MAX_CHOICE_DEPTH && uint(mat.color.w) == MATERIAL_CHOICE; ++level) {
        bool second;
        uint by = uint(mat.color.z);
        if (by == CHOICE_BY_SIDE) {
            second = !front;
        } else {
            float w = mat.color.x;
            uint t = uint(mat.color.y);
            if (scene_textured() && t != 0u) {
                vec2 b = clamp(barycentric(tri, p), vec2(0.0), vec2(1.0));
                w = clamp(luminance(texture_at(t - 1u, i, b, surface_uv(i, b))), 0.0, 1.0);
            }
            second = rng_next(rng) < w;
            if (by == CHOICE_MASK) {
                coverage *= w;
                passes = passes || !second;
                second = true;
            }
        }
        mat = load_material(uint(second ? mat.emission.y : mat.emission.x));
    }
    return mat;
}

// Traces the path's current ray and scatters once; false when the path ended.
bool scatter(inout Path path, inout Trail trail) {
    Hit hit = trace_ray(path.origin, path.dir, FAR);
    path.rays += 1u;
    if (HIDE_EMITTERS && path.hits == 0u) {
        hit = pass_emitters(path, hit);
    }
    if (hit.triangle == NO_HIT) {
        gather_sky(path, trail);
        return false;
    }
    path.hits += 1u;
    Triangle tri = load_triangle(hit.triangle);
    Material mat = load_material(tri.material);
    vec3 n = normalize(cross(tri.e1, tri.e2));
    float cos_out = -dot(n, path.dir);
    // An emitter whose BSDF scatters: its light, which the transition's
    // landing here takes with what the vertex reflects.
    vec2 light = vec2(0.0, 1.0);
    bool scatters = (MATERIAL_FEATURES & FEATURE_EMITTERS_REFLECT) != 0u && tri.light_pdf > 0.0 &&
                    (uint(mat.color.w) & MATERIAL_EMITTER_REFLECTS) != 0u;
    if (scatters) {
        light = emitter_light(path, trail, hit, tri, mat, cos_out);
    } else if (tri.light_pdf > 0.0) {
        gather_emitter(path, trail, hit, tri, mat, cos_out);
        bool null_bsdf = (uint(mat.color.w) & MATERIAL_EMITTER_PASSES) != 0u;
        if (!null_bsdf || path.depth >= params.max_depth) {
            // A black BSDF's sample ends the path here and counts it (its
            // lobe is not null); a null BSDF's at the last vertex does not.
            path.valid = path.valid || !null_bsdf;
            return false;
        }
        // A null BSDF: on through the emitter, a delta bounce counted in
        // the depth (as in Mitsuba). The guide learned its emission; what
        // lies beyond goes unlearned.
        path.origin = path.origin + hit.t * path.dir + (cos_out > 0.0 ? -eps : eps) * n;
        path.prev_bsdf_pdf = 0.0;
        trail.prev_vertex = guide_none();
        if (mixture_two_sided()) {
            trail.pick_vertex = guide_none();
        }
        trail.chaining = false;
        if (!path.valid && !survives_roulette(path, trail)) {
            return false;
        }
        path.depth += 1u;
        return true;
    }

    // Shade in the frame of the normal facing the ray (materials are
    // two-sided; a dielectric knows which side it is hit on). With shading
    // normals, that frame's and the side's normal is the interpolated one,
    // as in Mitsuba; rays still leave off the geometric surface (ng).
    Shading s;
    s.ng = cos_out > 0.0 ? n : -n;
    s.point = path.origin + hit.t * path.dir;
    s.position = s.point + s.ng * eps;
    bool front = cos_out > 0.0;
    s.ns = s.ng;
    if (SHADING_NORMALS) {
        vec3 sn = shading_normal(hit.triangle, tri, s.point);
        front = dot(sn, path.dir) < 0.0;
        s.ns = front ? sn : -sn;
    }
    // Under a mask: the share of the surface that scatters, and whether
    // the path goes through its clear part (after NEE at the surface).
    float coverage = 1.0;
    bool passes = false;
    if ((MATERIAL_FEATURES & FEATURE_CHOICES) != 0u) {
        mat = chosen_material(mat, front, hit.triangle, tri, s.point, path.rng, coverage, passes);
    }
    s.unmapped = s.ns;
    s.map_alpha2 = -1.0;
    if (NORMAL_MAPS) {
        uint code = uint(mat.color.w);
        uint map = (code >> MATERIAL_NORMAL_MAP_SHIFT) & ((1u << TEXTURE_SLOT_BITS) - 1u);
        if (map != 0u) {
            // As Mitsuba maps normals: where the ray lies on one side of
            // the unmapped normal n0 and the other of the mapped one m, m
            // mirrored about n0 instead (2 (m.n0) n0 - m: its tangential
            // part turned over).
            vec2 b = clamp(barycentric(tri, s.point), vec2(0.0), vec2(1.0));
            vec3 n0 = front ? s.ns : -s.ns;
            UvFrame at = uv_frame(hit.triangle, tri, b);
            vec3 m = (code & MATERIAL_MAP_BUMP) != 0u ? bumped_normal(at, n0, n, map - 1u, mat.emission.x)
                                                      : mapped_normal(at, n0, map - 1u);
            float c = dot(m, n0);
            vec3 v = -path.dir;
            if ((code & MATERIAL_MAP_IN_TWOSIDED) != 0u) {
                // Sides by n0: twosided turns the back's directions over
                // (across the surface) before the map sees them.
                vec3 seen = front ? v : v - 2.0 * dot(v, n0) * n0;
                m = dot(seen, m) < 0.0 ? 2.0 * c * n0 - m : m;
                s.ns = front ? m : m - 2.0 * c * n0;
            } else {
                // The BSDF under the map tells the sides by the mapped normal,
                // turned to the side of the unmapped one the ray comes from.
                m = dot(v, n0) * dot(v, m) <= 0.0 ? 2.0 * c * n0 - m : m;
                bool mapped_front = dot(v, m) > 0.0;
                s.ns = mapped_front ? m : -m;
                s.unmapped = mapped_front ? n0 : -n0;
                front = mapped_front;
            }
            s.map_alpha2 = clamp(0.125 * (1.0 - c * c) / (c * c), 0.0, 1.0);
        }
    }
    // The BSDF of the side a normal map leaves the ray on. (An emitter's
    // colour slot holds its radiance's texture.)
    Bsdf bsdf = bsdf_of(mat, front);
    if (scene_textured() && !scatters) {
        vec2 b = clamp(barycentric(tri, s.point), vec2(0.0), vec2(1.0));
        bsdf = bsdf_textured(bsdf, mat, front, hit.triangle, b, surface_uv(hit.triangle, b));
    }
    bool delta = bsdf_is_delta(bsdf);
    // Rough glass: sampled and reached by NEE on both sides.
    bool transmits = bsdf_transmits(bsdf);
    make_frame(s.ns, s.t, s.b);
    if (bsdf_anisotropic(bsdf)) {
        // Mitsuba's tangent: dp/du (from the texture coordinates) made
        // perpendicular to the shading normal; the local frame's own where
        // they span no area.
        UvFrame at = uv_frame(hit.triangle, tri, clamp(barycentric(tri, s.point), vec2(0.0), vec2(1.0)));
        vec2 t = vec2(dot(at.dp_du, s.t), dot(at.dp_du, s.b));
        bsdf.tangent = at.valid && dot(t, t) > 0.0 ? normalize(t) : vec2(1.0, 0.0);
    }
    s.wo = vec3(-dot(path.dir, s.t), -dot(path.dir, s.b), SHADING_FRAME ? -dot(path.dir, s.ns) : abs(cos_out));
    // A delta vertex is never guided, nor is rough glass where the guide
    // holds one vertex at a time: unless it learns, the guide's lookup there
    // (a network inference, for neural) would only tune the roulette. Its
    // bounces learn as a delta vertex's (chaining).
    bool unguided = delta || (transmits && !mixture_two_sided());
    GuideVertex here = unguided && !learn ? guide_none() : guide_at(hit.triangle, tri, s.position, s.ng, cos_out > 0.0);
    // What the bounce and NEE's MIS sample from: BSDF sampling alone where
    // the guide does not sample; through a surface that lets light through,
    // the guide on both sides.
    GuideVertex beyond = guide_none();
    if (mixture_two_sided() && transmits && !delta) {
        beyond = guide_at(hit.triangle, tri, s.point - eps * s.ng, -s.ng, cos_out <= 0.0);
    }
    Mixture mixture = mixture_at(unguided ? guide_none() : here, beyond, bsdf, s.wo);
    // What this vertex is expected to send back along the ray: the landed
    // bounce's target, which NEE here adds to (see guide_learn). A glossy
    // lobe's (0 here) is estimated from the bounce's own direction
    // (sample_bounce). Without the learning code, only the roulette's scale
    // needs it, at the first hit: the diffuse form serves every lobe there
    // (lavapipe would run a glossy lobe's estimate, a BSDF sample, at every
    // vertex).
    bool glossy = GUIDE_LEARNS && !unguided && !passes && !bsdf_is(bsdf, MATERIAL_DIFFUSE) && !bsdf_smooth_plastic(bsdf);
    float reflected = 0.0;
    if (!GUIDE_LEARNS) {
        reflected = path.depth == 0u ? bsdf_reflect(bsdf, s.wo, guide_irradiance(here)) : 0.0;
    } else if (learn || path.depth == 0u) {
        reflected = guide_reflect(here, bsdf, s.wo);
    }
    if (path.depth == 0u) {
        trail.path_estimate = reflected;
    }
    if (path.depth >= params.max_depth) {
        if (learn) {
            // (A glossy lobe here, where the path ends, learns 0 for what it
            // would reflect: only paths max_depth long reach it.)
            land(trail, light.x, light.y, reflected, 0.0);
        }
        // Mitsuba's vectorized path tracer draws a BSDF sample at the last
        // vertex too, and the path counts if its lobe is not null.
        if (!path.valid && !passes) {
            path.valid = !bsdf_is(bsdf, MATERIAL_THIN) || rng_next(path.rng) < thin_reflectance(s.wo.z, bsdf.eta);
        }
        return false;
    }

    float direct_lum = nee && !delta ? next_event(path, s, bsdf, here, mixture, transmits, coverage) : 0.0;
    if (learn) {
        if ((unguided || passes) && (trail.chaining || guide_covers(trail.prev_vertex))) {
            pass_through_delta(trail);
        } else {
            land(trail, light.x, light.y, reflected, direct_lum);
        }
    }
    float mix = 0.0;
    if (passes) {
        // Straight on through the mask's clear part: a null lobe's bounce,
        // counted in the depth, which no MIS weighs what it reaches by.
        follow_unguided(trail, here, -s.wo, vec3(1.0));
        path.prev_bsdf_pdf = 0.0;
        path.origin = s.point - eps * s.ng;
    } else if (!sample_bounce(path, trail, s, bsdf, here, mixture, delta, transmits, glossy, mix)) {
        return false;
    }
    // The density MIS weighs what the bounce reaches by: the mask's.
    path.prev_bsdf_pdf *= coverage;
    if (!survives_roulette(path, trail)) {
        return false;
    }
    if (mix != 0.0) {
        keep_share_sample(trail, path, mixture_share_vertex(mixture), mix);
    }
    path.depth += 1u;
    return true;
}

// scatter(), then, in a pass that learns, learning from where its ray landed.
bool bounce(inout Path path, inout Trail trail) {
    bool more = scatter(path, trail);
    if (learn) {
        guide_learn(trail.land_from, trail.land_sector, trail.land_q, trail.land_le, trail.land_mis_weight,
                    trail.land_reflected, trail.land_direct, path.td_sq_sum, path.td_count, path.rng);
    }
    return more;
}

// The next work item for each lane that `needs` one, from the dispatch's
// work counter `slot`: lanes that claim together take consecutive items, by
// one atomic add per subgroup. Call with the whole subgroup active.
uint claim(bool needs, uint slot) {
    uvec4 ballot = subgroupBallot(needs);
    uint n = subgroupBallotBitCount(ballot);
    uint base = 0u;
    if (n > 0u) {
        if (subgroupElect()) {
            base = atomicAdd(work_counters[slot], n);
        }
        base = subgroupBroadcastFirst(base);
    }
    return base + subgroupBallotExclusiveBitCount(ballot);
}

// Begins item `item` of a dispatch of `count` samples per pixel: sample
// item % count (`sample_index`) of pixel item / count (`index`).
void begin_item(uint item, uint count, out uint index, out uint sample_index, out Path path, out Trail trail) {
    index = item / count;
    sample_index = item % count;
    uvec2 pixel = uvec2(index % params.width, index / params.width);
    begin_path(pixel, params.pass_index + sample_index, path, trail);
}

void main() {
    uint pixels = params.width * params.height;
#ifdef WITH_NEE
    nee = (params.flags & FLAG_NEE) != 0u && params.light_count > 0u;
#endif
    eps = params.cam_pos.w;
    learn = GUIDE_LEARNS && (params.flags & FLAG_LEARN) != 0u;
    // This dispatch traces samples pass_index .. pass_index + count - 1 of
    // every pixel: count * pixels items, each pixel's samples one after
    // another. A lane whose path ends claims the next item at once, so the
    // lanes of a SIMD group stay busy however unequal their paths (lavapipe
    // runs a group until its last lane is done), even in a dispatch of one
    // sample. An item is (pixel, sample), so which lane traces it changes
    // nothing in the image.
    uint count = max(params.item_count, 1u);
    uint total = count * pixels;
    uint slot = params.selector >> WORK_SLOT_SHIFT;
    uint first_slot = params.selector & ((1u << WORK_SLOT_SHIFT) - 1u);
    uint item = claim(true, slot);
    uint taken = 1u;
    bool alive = item < total;
    // The lane's path: the pixel (`index`) and sample it traces.
    uint index;
    uint sample_index;
    Path path;
    Trail trail;
    if (alive) {
        begin_item(item, count, index, sample_index, path, trail);
    }
    // Lanes stay in the loop until their whole subgroup is done, for claim.
    for (uint step = 0u; step < MAX_TRACE_STEPS; ++step) {
        if (subgroupAll(!alive)) {
            break;
        }
        bool ended = false;
        if (alive) {
            ended = !bounce(path, trail);
        }
        if (ended) {
            // Only the words accumulate reads (see PathSample).
            uint out_slot = (first_slot + sample_index) * pixels + index;
            uint lengths = path.hits | (path.rays << PATH_RAYS_SHIFT);
            if (GUIDE_LEARNS) {
                samples[out_slot].td_count = path.td_count;
                samples[out_slot].td_sq_sum = path.td_sq_sum;
                lengths |= PATH_LEARNED;
            }
            if (!path.valid) {
                path.radiance = vec3(0.0);
            }
            samples[out_slot].radiance = PIXEL_FILTER >= FILTER_CUBIC ? path.radiance * path.filter_weight : path.radiance;
            samples[out_slot].lengths = lengths;
            if (learn) {
                learn_share_samples(trail, path);
                guide_end_path(index, path.rng);
            }
        }
        // A lane takes up to `count` paths as long as any are left, and more
        // while the step cap leaves room for a whole path (the host keeps
        // count * (max_depth + 2) under it): so every item is traced.
        bool room = taken < MAX_CLAIMS && step + params.max_depth + 2u < MAX_TRACE_STEPS;
        bool needs = ended && (taken < count || room);
        uint next = claim(needs, slot);
        if (ended) {
            alive = needs && next < total;
            taken += 1u;
            if (alive) {
                begin_item(next, count, index, sample_index, path, trail);
            }
        }
    }
}
