// Learned guides: radiance-volume lookup, sector sampling and the Expected
// Sarsa update. Needs shared.h, sampling.glsl and the `params` push constants.
#ifndef QTRACE_GUIDE_GLSL
#define QTRACE_GUIDE_GLSL

#ifdef FLOAT_ATOMICS
#extension GL_EXT_shader_atomic_float : require
#endif

layout(std430, set = 0, binding = B_VOLUMES) readonly buffer Volumes { Volume volumes[]; };
layout(std430, set = 0, binding = B_Q) readonly buffer QValues { float q_values[]; };
layout(std430, set = 0, binding = B_CDF) readonly buffer Cdf { float cdf[]; };
layout(std430, set = 0, binding = B_IRRADIANCE) readonly buffer Irradiance { float irradiance[]; };
#ifdef FLOAT_ATOMICS
layout(std430, set = 0, binding = B_SUM) buffer TargetSums { float target_sum[]; };
#else
layout(std430, set = 0, binding = B_SUM) buffer TargetSums { uint target_sum_bits[]; };
#endif
layout(std430, set = 0, binding = B_VISITS) buffer Visits { uint visits[]; };
layout(std430, set = 0, binding = B_GRID) readonly buffer Grid {
    GridHeader grid;
    uvec2 grid_ranges[];
};
// (volume position, volume index bits) per list entry.
layout(std430, set = 0, binding = B_GRID_ITEMS) readonly buffer GridItems { vec4 grid_items[]; };

uint grid_a() {
    return params.sector_grid & 0xffffu;
}

uint grid_b() {
    return params.sector_grid >> 16;
}

uint sector_count() {
    return grid_a() * grid_b();
}

// Class of a query normal: 2 * dominant axis + (component < 0); ties go to
// the lower axis, as in src/guide/grid.rs.
uint normal_class(vec3 n) {
    vec3 a = abs(n);
    uint axis = (a.x >= a.y && a.x >= a.z) ? 0u : (a.y >= a.z ? 1u : 2u);
    return 2u * axis + (n[axis] < 0.0 ? 1u : 0u);
}

// The k-d tree search: exact everywhere, used where the grid has no list.
uint nearest_volume_kd(vec3 p, vec3 n) {
    uint best = NO_VOLUME;
    float best_d2 = FAR;
    uint stack_lo[KD_STACK_SIZE];
    uint stack_hi[KD_STACK_SIZE];
    float stack_d2[KD_STACK_SIZE];
    uint top = 0u;
    if (params.volume_count > 0u) {
        stack_lo[0] = 0u;
        stack_hi[0] = params.volume_count;
        stack_d2[0] = 0.0;
        top = 1u;
    }
    while (top > 0u) {
        --top;
        uint lo = stack_lo[top];
        uint hi = stack_hi[top];
        if (lo >= hi || stack_d2[top] >= best_d2) {
            continue;
        }
        uint m = (lo + hi) / 2u;
        Volume v = volumes[m];
        vec3 d = v.position - p;
        float d2 = dot(d, d);
        if (d2 < best_d2 && dot(v.normal, n) > 0.0) {
            best = m;
            best_d2 = d2;
        }
        if (v.axis == KD_LEAF) {
            continue;
        }
        float diff = p[v.axis] - v.position[v.axis];
        // Far side first, so the near side is searched next.
        stack_lo[top] = diff < 0.0 ? m + 1u : lo;
        stack_hi[top] = diff < 0.0 ? hi : m;
        stack_d2[top] = diff * diff;
        stack_lo[top + 1u] = diff < 0.0 ? lo : m + 1u;
        stack_hi[top + 1u] = diff < 0.0 ? m : hi;
        stack_d2[top + 1u] = 0.0;
        top += 2u;
    }
    return best;
}

// Exact nearest volume to p among those facing the same way as n (so a point
// never uses a volume on the other side of a thin wall); NO_VOLUME if none.
// The grid's list for p's cell and n's class holds the answer when it exists.
uint nearest_volume(vec3 p, vec3 n) {
    vec3 g = (p - grid.origin) * grid.inv_cell;
    if (all(greaterThanEqual(g, vec3(0.0))) && all(lessThan(g, vec3(grid.dims)))) {
        uvec3 c = min(uvec3(g), grid.dims - 1u);
        uint cell = c.x + grid.dims.x * (c.y + grid.dims.y * c.z);
        uvec2 range = grid_ranges[cell * NORMAL_CLASSES + normal_class(n)];
        if (range.y != GRID_FALLBACK) {
            uint best = NO_VOLUME;
            float best_d2 = FAR;
            for (uint i = range.x; i < range.x + range.y; ++i) {
                vec4 item = grid_items[i];
                vec3 d = item.xyz - p;
                float d2 = dot(d, d);
                // The normal is read only for a candidate that would win.
                if (d2 < best_d2) {
                    uint j = floatBitsToUint(item.w);
                    if (dot(volumes[j].normal, n) > 0.0) {
                        best = j;
                        best_d2 = d2;
                    }
                }
            }
            return best;
        }
    }
    return nearest_volume_kd(p, n);
}

// P(sector k) of volume v's distribution (the CDF is inclusive).
float sector_probability(uint v, uint k) {
    uint base = v * sector_count();
    return cdf[base + k] - (k > 0u ? cdf[base + k - 1u] : 0.0);
}

// First sector whose inclusive CDF exceeds u.
uint pick_sector(uint v, float u) {
    uint base = v * sector_count();
    uint lo = 0u;
    uint hi = sector_count() - 1u;
    while (lo < hi) {
        uint mid = (lo + hi) / 2u;
        if (cdf[base + mid] > u) {
            hi = mid;
        } else {
            lo = mid + 1u;
        }
    }
    return lo;
}

// Solid-angle pdf of the one-sample mixture epsilon * cosine + (1 - epsilon) * guide
// for a local direction with cos(theta) = cos_theta lying in sector k; the
// guide's density in sector k is P(k) * n / (2 pi).
float guide_pdf_in_sector(uint v, uint k, float cos_theta) {
    if (cos_theta <= 0.0) {
        return 0.0;
    }
    float cosine = cos_theta * INV_PI;
    if (v == NO_VOLUME) {
        return cosine;
    }
    float guided = sector_probability(v, k) * float(sector_count()) * 0.5 * INV_PI;
    return params.guide_epsilon * cosine + (1.0 - params.guide_epsilon) * guided;
}

float guide_pdf(uint v, vec3 local) {
    return guide_pdf_in_sector(v, hemisphere_sector(local, grid_a(), grid_b()), local.z);
}

// A local direction from the mixture, and the sector it lies in; u = three
// uniform numbers.
vec3 guide_sample(uint v, vec3 u, out uint sector) {
    if (v == NO_VOLUME || u.z < params.guide_epsilon) {
        vec3 w = sample_cosine(u.xy);
        sector = hemisphere_sector(w, grid_a(), grid_b());
        return w;
    }
    // Reuse u.z, rescaled, to pick the sector.
    float us = (u.z - params.guide_epsilon) / (1.0 - params.guide_epsilon);
    uint k = pick_sector(v, min(us, 0.99999994));
    uint a = grid_a();
    uint i = k % a;
    uint j = k / a;
    // Keep clear of the cell's edges: rounding in the map must not move the
    // direction into a neighbouring sector, so that k is the sector guide_pdf
    // finds for it. (The strip left out is 2e-5 of the cell.)
    vec2 inner = clamp(u.xy, vec2(1e-5), vec2(1.0 - 1e-5));
    vec2 cell = vec2((float(i) + inner.x) / float(a), (float(j) + inner.y) / float(grid_b()));
    sector = k;
    return square_to_hemisphere(cell);
}

// Expected Sarsa target for a bounce that reached a surface y with volume vy:
// (2 pi / n) sum_j Q(vy, j) f_s cos(theta_j) = albedo / pi * irradiance[vy].
float sarsa_surface_target(uint vy, float albedo) {
    return vy == NO_VOLUME ? 0.0 : albedo * INV_PI * irradiance[vy];
}

// Adds one target for (v, k); the fold pass turns sums and counts into means.
// Returns the squared temporal-difference error against the current Q.
float sarsa_record(uint v, uint k, float target) {
    uint index = v * sector_count() + k;
#ifdef FLOAT_ATOMICS
    atomicAdd(target_sum[index], target);
#else
    // Compare-and-swap fallback for devices without float atomics.
    uint seen = target_sum_bits[index];
    while (true) {
        uint wanted = floatBitsToUint(uintBitsToFloat(seen) + target);
        uint found = atomicCompSwap(target_sum_bits[index], seen, wanted);
        if (found == seen) {
            break;
        }
        seen = found;
    }
#endif
    atomicAdd(visits[index], 1u);
    float td = target - q_values[index];
    return td * td;
}

#endif
