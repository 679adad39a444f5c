#version 460
// The hidden layers' parameters, one invocation each: the gradient, the mean
// over the batch of delta (unit) x activation (input), then an Adam step.
// (mlp_adam_output.comp does the output layer.)

#define MLP_PARAMS_ONLY
#include "shared.h"
#include "mlp.glsl"
#include "adam.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(std430, set = 0, binding = B_MLP_COUNT) readonly buffer Batch { MlpBatch batch; };
// The batch's inputs, activations and deltas, read as texels of four
// floats: lavapipe reads a storage buffer with a loop over lanes, a texel
// buffer with one gather.
layout(set = 0, binding = B_MLP_INPUTS) uniform usamplerBuffer input_texels;
layout(set = 0, binding = B_MLP_ACTS) uniform usamplerBuffer act_texels;
layout(set = 0, binding = B_MLP_DELTAS) uniform usamplerBuffer delta_texels;

uint unit_index(uint s, uint l, uint o) {
    return (s * MLP_HIDDEN + l) * MLP_WIDTH + o;
}

void main() {
    uint p = gl_GlobalInvocationID.x;
    uint rows = min(batch.count, push.capacity);
    if (p >= mlp_offset(MLP_HIDDEN) || rows == 0u) {
        return;
    }
    uint l = 0u;
    while (p >= mlp_offset(l + 1u)) {
        l++;
    }
    uint fan_in = mlp_fan_in(l);
    uint local_index = p - mlp_offset(l);
    bool is_bias = local_index >= MLP_WIDTH * fan_in;
    uint o = is_bias ? local_index - MLP_WIDTH * fan_in : local_index / fan_in;
    uint i = is_bias ? 0u : local_index % fan_in;

    float g = 0.0;
    for (uint s = 0u; s < rows; s++) {
        float delta = MLP_TEXEL_FLOAT(delta_texels, unit_index(s, l, o));
        float a = l == 0u ? MLP_TEXEL_FLOAT(input_texels, s * MLP_INPUTS + i)
                          : MLP_TEXEL_FLOAT(act_texels, unit_index(s, l - 1u, i));
        g += delta * (is_bias ? 1.0 : a);
    }
    adam_step(p, g / float(rows));
}
