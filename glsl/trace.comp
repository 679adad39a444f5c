#version 460
// The trace kernel: one path per pixel per pass. Method variants are compiled
// from this one source by build.rs (METHOD_PT, ...).

#include "shared.h"
#include "rng.glsl"
#include "sampling.glsl"
#include "scene.glsl"

layout(local_size_x = TILE_X, local_size_y = TILE_Y) in;

layout(push_constant) uniform Push { PassParams params; };

#ifdef METHOD_SARSA
#include "guide.glsl"

// Records the target of the bounce that just landed, if it left from a volume,
// and adds its squared TD error to the path's loss.
void learn_bounce(uint volume, uint sector, float q, float target, inout float td_sq_sum, inout uint td_count) {
    if (volume != NO_VOLUME) {
#ifdef WITH_NEE
        // With NEE, q is the sampling table's Q, short of what NEE carries;
        // the loss compares with Q itself.
        q = load_q(volume * sector_count() + sector);
#endif
        td_sq_sum += sarsa_record(volume, sector, target, q);
        td_count += 1u;
    }
}
#endif

#ifdef METHOD_NEURAL
#include "neural.glsl"

// Scores the bounce that just landed, if there was one, and offers it to
// the training batch.
void learn_bounce(bool has_prev, vec3 p, vec3 n, uint sector, float q, float target,
                  inout float td_sq_sum, inout uint td_count, inout uint rng) {
    if (has_prev) {
        float td = target - q;
        td_sq_sum += td * td;
        td_count += 1u;
        neural_offer(p, n, sector, target, rng_next(rng));
    }
}
#endif

#if defined(METHOD_SARSA) || defined(METHOD_NEURAL)
#define GUIDED
#endif
layout(set = 0, binding = B_LIGHTS) uniform usamplerBuffer light_texels; // 1 per Light
layout(std430, set = 0, binding = B_SAMPLES) writeonly buffer Samples { PathSample samples[]; };

float luminance(vec3 c) {
    return dot(c, vec3(0.2126, 0.7152, 0.0722));
}

float power_heuristic(float a, float b) {
    float a2 = a * a;
    float b2 = b * b;
    return a2 + b2 > 0.0 ? a2 / (a2 + b2) : 0.0;
}

// Index of the light whose inclusive CDF first exceeds u.
uint pick_light(float u) {
    uint lo = 0u;
    uint hi = params.light_count - 1u;
    while (lo < hi) {
        uint mid = (lo + hi) / 2u;
        if (uintBitsToFloat(texelFetch(light_texels, int(mid)).y) > u) {
            hi = mid;
        } else {
            lo = mid + 1u;
        }
    }
    return lo;
}

// Solid-angle pdf of choosing direction `local` (z = cos theta) by BSDF sampling.
float bsdf_pdf(float cos_theta) {
    if (cos_theta <= 0.0) {
        return 0.0;
    }
    return (params.flags & FLAG_UNIFORM) != 0u ? 0.5 * INV_PI : cos_theta * INV_PI;
}

// The state of the path being traced, shared by begin_path and bounce.
uvec2 pixel;
uint rng;
vec3 origin;
vec3 dir;
vec3 radiance;
vec3 throughput;
uint depth;
uint path_length;
uint rays;
float prev_bsdf_pdf; // 0 marks the camera ray: no MIS for what it hits
#ifdef WITH_NEE
bool nee;
#else
const bool nee = false;
#endif
float eps;
#ifdef GUIDED
// The previous bounce's sector and the Q the guide gave it, to update once
// its ray lands.
uint prev_sector;
float prev_q;
bool learn;
// The guide's estimate of the radiance this path's first hit sends to the
// camera: the scale Russian roulette compares a path's prospects with.
float path_estimate;
#endif
#ifdef METHOD_SARSA
uint prev_volume;
#endif
#ifdef METHOD_NEURAL
// The previous bounce's state, to offer its transition once it lands.
bool has_prev;
vec3 prev_position;
vec3 prev_normal;
#endif
uint td_count;
float td_sq_sum;

// Starts sample `sample_index` of this pixel: a camera ray through a
// uniformly jittered point of the pixel (box filter).
void begin_path(uint sample_index) {
    rng = rng_init(pixel.y * params.width + pixel.x, sample_index, params.seed);
    vec2 jitter = rng_next2(rng);
    vec2 ndc = vec2(
        2.0 * (float(pixel.x) + jitter.x) / float(params.width) - 1.0,
        1.0 - 2.0 * (float(pixel.y) + jitter.y) / float(params.height));
    origin = params.cam_pos.xyz;
    dir = normalize(params.cam_forward.xyz + ndc.x * params.cam_right.xyz + ndc.y * params.cam_up.xyz);
    radiance = vec3(0.0);
    throughput = vec3(1.0);
    depth = 0u;
    path_length = 0u;
    rays = 0u;
    prev_bsdf_pdf = 0.0;
#ifdef GUIDED
    prev_sector = 0u;
    prev_q = 0.0;
    path_estimate = 0.0;
#endif
#ifdef METHOD_SARSA
    prev_volume = NO_VOLUME;
#endif
#ifdef METHOD_NEURAL
    has_prev = false;
    prev_position = vec3(0.0);
    prev_normal = vec3(0.0);
#endif
    td_count = 0u;
    td_sq_sum = 0.0;
}

// Traces the path's current ray and scatters once; false when the path ended.
bool bounce() {
    Hit hit = trace_ray(origin, dir, FAR);
    rays += 1u;
    if (hit.triangle == NO_HIT) {
        radiance += throughput * params.environment.rgb;
#ifdef METHOD_SARSA
        if (learn) {
            learn_bounce(prev_volume, prev_sector, prev_q, luminance(params.environment.rgb), td_sq_sum, td_count);
        }
#endif
#ifdef METHOD_NEURAL
        if (learn) {
            learn_bounce(has_prev, prev_position, prev_normal, prev_sector, prev_q,
                         luminance(params.environment.rgb), td_sq_sum, td_count, rng);
        }
#endif
        return false;
    }
    path_length += 1u;
    Triangle tri = load_triangle(hit.triangle);
    Material mat = load_material(tri.material);
    vec3 n = normalize(cross(tri.e1, tri.e2));
    float cos_out = -dot(n, dir);

    if (tri.light_pdf > 0.0) {
        // Emitters end the path; they emit on their front side only.
        float weight = 1.0;
        if (cos_out > 0.0) {
            if (nee && prev_bsdf_pdf > 0.0) {
                float light_pdf = tri.light_pdf * hit.t * hit.t / cos_out;
                weight = power_heuristic(prev_bsdf_pdf, light_pdf);
            }
            radiance += throughput * mat.emission.rgb * weight;
        }
#ifdef METHOD_SARSA
        if (learn) {
            float le = cos_out > 0.0 ? luminance(mat.emission.rgb) : 0.0;
            learn_bounce(prev_volume, prev_sector, prev_q, le, td_sq_sum, td_count);
#ifdef WITH_NEE
            if (nee && prev_volume != NO_VOLUME) {
                sarsa_record_direct(prev_volume, prev_sector, le * (1.0 - weight));
            }
#endif
        }
#endif
#ifdef METHOD_NEURAL
        if (learn) {
            // With NEE, Q learns what scattering brings beyond NEE: of an
            // emitter it hits, its MIS share (see the NEE target below).
            float le = cos_out > 0.0 ? luminance(mat.emission.rgb) * weight : 0.0;
            learn_bounce(has_prev, prev_position, prev_normal, prev_sector, prev_q, le,
                         td_sq_sum, td_count, rng);
        }
#endif
        return false;
    }

    // Diffuse surfaces scatter on both sides: shade with the normal facing the ray.
    vec3 ns = cos_out > 0.0 ? n : -n;
    vec3 position = origin + hit.t * dir + ns * eps;
    vec3 albedo = mat.albedo.rgb;
#ifdef METHOD_SARSA
    uint volume = nearest_volume(tri, position, cos_out > 0.0);
    vec2 sums = volume_sums_of(volume);
    float outgoing = sarsa_surface_target(sums, luminance(albedo));
    if (depth == 0u) {
        path_estimate = outgoing;
    }
    if (learn) {
        learn_bounce(prev_volume, prev_sector, prev_q, outgoing, td_sq_sum, td_count);
    }
    bool guided_here = volume != NO_VOLUME;
#endif
#ifdef METHOD_NEURAL
    vec2 inferred = neural_infer(position, ns);
    float total = inferred.x;
    float outgoing = luminance(albedo) * INV_PI * inferred.y;
    if (depth == 0u) {
        path_estimate = outgoing;
    }
    // The landed bounce's target; NEE at this vertex adds to it below.
    float pending_target = outgoing;
    bool guided_here = total > 0.0;
#endif
    if (depth >= params.max_depth) {
#ifdef METHOD_NEURAL
        if (learn) {
            learn_bounce(has_prev, prev_position, prev_normal, prev_sector, prev_q,
                         pending_target, td_sq_sum, td_count, rng);
        }
#endif
        return false;
    }
    vec3 t;
    vec3 b;
    make_frame(ns, t, b);

    if (nee) {
        Triangle lt = load_triangle(texelFetch(light_texels, int(pick_light(rng_next(rng)))).x);
        vec2 u = rng_next2(rng);
        if (u.x + u.y > 1.0) {
            u = 1.0 - u;
        }
        vec3 target = lt.v0 + u.x * lt.e1 + u.y * lt.e2;
        vec3 to_light = target - position;
        float dist2 = dot(to_light, to_light);
        float dist = sqrt(dist2);
        vec3 wi = to_light / dist;
        float cos_x = dot(ns, wi);
        float cos_y = -dot(normalize(cross(lt.e1, lt.e2)), wi);
        if (cos_x > 0.0 && cos_y > 0.0) {
            rays += 1u;
            if (!occluded(position, wi, dist * (1.0 - 1e-4) - eps)) {
                float light_pdf = lt.light_pdf * dist2 / cos_y;
#if defined(METHOD_SARSA)
                float scatter_pdf = guide_pdf(volume, vec3(dot(wi, t), dot(wi, b), cos_x));
#elif defined(METHOD_NEURAL)
                float scatter_pdf = neural_pdf(total, vec3(dot(wi, t), dot(wi, b), cos_x));
#else
                float scatter_pdf = bsdf_pdf(cos_x);
#endif
                float weight = power_heuristic(light_pdf, scatter_pdf);
                vec3 le = load_material(lt.material).emission.rgb;
                vec3 direct = albedo * INV_PI * cos_x * le * weight / light_pdf;
                radiance += throughput * direct;
#ifdef METHOD_NEURAL
                // The light reaching the previous vertex from here
                // includes what NEE brings here.
                pending_target += luminance(direct);
#endif
            }
        }
    }
#ifdef METHOD_NEURAL
    if (learn) {
        learn_bounce(has_prev, prev_position, prev_normal, prev_sector, prev_q, pending_target,
                     td_sq_sum, td_count, rng);
    }
#endif

#ifdef METHOD_SARSA
    // Guided sampling: the mixture of cosine and the volume's sector distribution.
    uint sector;
    float p_sector;
    vec3 local = guide_sample(volume, vec3(rng_next2(rng), rng_next(rng)), sector, p_sector);
    float pdf = mixture_pdf(volume, p_sector, local.z);
    prev_volume = volume;
    prev_sector = sector;
    prev_q = sector_q(sums, sector, p_sector);
#elif defined(METHOD_NEURAL)
    uint sector;
    float p_sector;
    vec3 local = neural_sample(total, vec3(rng_next2(rng), rng_next(rng)), sector, p_sector);
    float pdf = neural_mixture_pdf(total, p_sector, local.z);
    prev_sector = sector;
    prev_q = neural_q(sector, p_sector * total);
    prev_position = position;
    prev_normal = ns;
    has_prev = true;
#else
    // BSDF sampling: cosine-weighted, or uniform (the equal-area map).
    vec2 u = rng_next2(rng);
    vec3 local = (params.flags & FLAG_UNIFORM) != 0u ? square_to_hemisphere(u) : sample_cosine(u);
    float pdf = bsdf_pdf(local.z);
#endif
    if (pdf <= 0.0) {
        return false;
    }
    throughput *= albedo * INV_PI * local.z / pdf;
    prev_bsdf_pdf = pdf;
    dir = normalize(local.x * t + local.y * b + local.z * ns);
    origin = position;

    if (depth + 1u >= RR_START_DEPTH) {
        float q = min(max(throughput.r, max(throughput.g, throughput.b)), 0.95);
#ifdef GUIDED
        // Guided paths toward light carry small weights because their pdf
        // is high, so throughput alone would end exactly the paths the guide
        // chose. They also survive by what they are expected to bring:
        // throughput times the radiance Q expects from the sampled sector,
        // against the estimate for the whole path (weight window at 1).
        // Never below the throughput rule, so a Q that underestimates ends
        // no more of a path's continuations than that rule would.
        if (guided_here && path_estimate > 0.0) {
            float expected = luminance(throughput) * prev_q;
            q = max(q, clamp(expected / path_estimate, 0.1, 0.95));
        }
#endif
        if (rng_next(rng) >= q) {
            return false;
        }
        throughput /= q;
    }
    depth += 1u;
    return true;
}

void main() {
    pixel = gl_GlobalInvocationID.xy;
    if (pixel.x >= params.width || pixel.y >= params.height) {
        return;
    }
    uint index = pixel.y * params.width + pixel.x;
    uint pixels = params.width * params.height;
#ifdef WITH_NEE
    nee = (params.flags & FLAG_NEE) != 0u && params.light_count > 0u;
#endif
    eps = params.cam_pos.w;
#ifdef GUIDED
    learn = (params.flags & FLAG_LEARN) != 0u;
#endif
    // This dispatch traces samples pass_index .. pass_index + count - 1 of
    // each pixel. A lane whose path ends starts its next sample at once, so
    // SIMD lanes stay busy however unequal their paths' lengths; the step cap
    // keeps the loop within llvmpipe's 65 535 iterations (the host keeps
    // count * (max_depth + 1) below it).
    uint count = max(params.item_count, 1u);
    uint done = 0u;
    begin_path(params.pass_index);
    for (uint step = 0u; step < MAX_TRACE_STEPS; ++step) {
        if (!bounce()) {
            samples[done * pixels + index] = PathSample(radiance, path_length, rays, td_count, td_sq_sum, 0u);
            done += 1u;
            if (done == count) {
                break;
            }
            begin_path(params.pass_index + done);
        }
    }
}
