#version 460
// One invocation per parameter: its gradient, the mean over the batch of
// delta (unit) x activation (input), then an Adam step.

#include "shared.h"
#include "mlp.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(push_constant) uniform Push { MlpPush push; };
layout(std430, set = 0, binding = B_MLP_INPUTS) readonly buffer Inputs { float inputs[]; };
layout(std430, set = 0, binding = B_MLP_COUNT) readonly buffer Batch { MlpBatch batch; };
layout(std430, set = 0, binding = B_MLP_TARGETS) readonly buffer Targets { MlpTarget targets[]; };
layout(std430, set = 0, binding = B_MLP_ACTS) readonly buffer Acts { float acts[]; };
layout(std430, set = 0, binding = B_MLP_DELTAS) readonly buffer Deltas { float deltas[]; };
// Adam's first and second moment per parameter.
layout(std430, set = 0, binding = B_MLP_MOMENTS) buffer Moments { vec2 moments[]; };
layout(std430, set = 0, binding = B_MLP_GRAD) writeonly buffer Grad { float grad[]; };

uint unit_index(uint s, uint l, uint o) {
    return (s * MLP_HIDDEN + l) * MLP_WIDTH + o;
}

void main() {
    uint p = gl_GlobalInvocationID.x;
    uint rows = min(batch.count, push.capacity);
    if (p >= mlp_param_count() || rows == 0u) {
        return;
    }
    uint l = 0u;
    while (l < MLP_HIDDEN && p >= mlp_offset(l + 1u)) {
        l++;
    }
    uint fan_in = mlp_fan_in(l);
    uint local_index = p - mlp_offset(l);
    bool is_bias = local_index >= mlp_fan_out(l) * fan_in;
    uint o = is_bias ? local_index - mlp_fan_out(l) * fan_in : local_index / fan_in;
    uint i = is_bias ? 0u : local_index % fan_in;

    float g = 0.0;
    for (uint s = 0u; s < rows; s++) {
        float delta;
        if (l == MLP_HIDDEN) {
            delta = targets[s].sector == o ? targets[s].delta : 0.0;
        } else {
            delta = deltas[unit_index(s, l, o)];
        }
        if (delta == 0.0) {
            continue;
        }
        float a = 1.0;
        if (!is_bias) {
            a = l == 0u ? inputs[s * MLP_INPUTS + i] : acts[unit_index(s, l - 1u, i)];
        }
        g += delta * a;
    }
    g /= float(rows);
    grad[p] = g;

    vec2 m = moments[p];
    m.x = push.beta1 * m.x + (1.0 - push.beta1) * g;
    m.y = push.beta2 * m.y + (1.0 - push.beta2) * g * g;
    moments[p] = m;
    float c1 = 1.0 - pow(push.beta1, float(push.step));
    float c2 = 1.0 - pow(push.beta2, float(push.step));
    mlp_params[p >> 2][p & 3u] -= push.learning_rate * (m.x / c1) / (sqrt(m.y / c2) + push.epsilon);
}
