#version 460
// Per volume: the irradiance-like sum the Sarsa target needs,
// (2 pi / n) sum_j Q_j cos(theta_j), and the sampling CDF over sectors
// (proportional to Q, or to Q cos(theta) with FLAG_COS_DISTRIBUTION).

#include "shared.h"
#include "sampling.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(push_constant) uniform Push { PassParams params; };
layout(std430, set = 0, binding = B_Q) readonly buffer QValues { float q_values[]; };
layout(std430, set = 0, binding = B_CDF) buffer Cdf { float cdf[]; };
layout(std430, set = 0, binding = B_IRRADIANCE) writeonly buffer Irradiance { float irradiance[]; };

void main() {
    uint v = gl_GlobalInvocationID.x;
    if (v >= params.volume_count) {
        return;
    }
    uint a = params.sector_grid & 0xffffu;
    uint b = params.sector_grid >> 16;
    uint n = a * b;
    uint base = v * n;
    bool cos_weighted = (params.flags & FLAG_COS_DISTRIBUTION) != 0u;
    float weighted = 0.0;
    float total = 0.0;
    for (uint k = 0u; k < n; ++k) {
        vec2 centre = vec2((float(k % a) + 0.5) / float(a), (float(k / a) + 0.5) / float(b));
        float cos_k = square_to_hemisphere(centre).z;
        float q = max(q_values[base + k], 0.0);
        weighted += q * cos_k;
        total += cos_weighted ? q * cos_k : q;
        cdf[base + k] = total;
    }
    irradiance[v] = weighted * 2.0 * PI / float(n);
    for (uint k = 0u; k < n; ++k) {
        // An all-zero volume samples sectors uniformly.
        cdf[base + k] = total > 0.0 ? cdf[base + k] / total : float(k + 1u) / float(n);
    }
    cdf[base + n - 1u] = 1.0;
}
