#version 460
// The hidden layers' parameters: the gradient, the mean over the batch of
// delta (unit) x activation (input), then an Adam step.
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
WORDS(input_texels, B_MLP_INPUTS)
WORDS(act_texels, B_MLP_ACTS)
WORDS(delta_texels, B_MLP_DELTAS)

uint unit_index(uint s, uint l, uint o) {
    return (s * MLP_HIDDEN + l) * MLP_WIDTH + o;
}

// Invocations of layer l: one per four weights of a unit (a row's inputs
// are read a texel at a time, so each read serves four weights), then one
// per unit's bias. Where layer l's start.
uint slot_offset(uint l) {
    return l == 0u ? 0u : MLP_WIDTH * (MLP_IN4 + 1u) + (l - 1u) * MLP_WIDTH * (MLP_W4 + 1u);
}

void main() {
    uint p = gl_GlobalInvocationID.x;
    uint rows = min(batch.count, push.capacity);
    if (p >= slot_offset(MLP_HIDDEN) || rows == 0u) {
        return;
    }
    uint l = 0u;
    while (p >= slot_offset(l + 1u)) {
        l++;
    }
    uint in4 = mlp_fan_in(l) / 4u;
    uint local_index = p - slot_offset(l);
    bool is_bias = local_index >= MLP_WIDTH * in4;
    uint o = is_bias ? local_index - MLP_WIDTH * in4 : local_index / in4;
    uint q = is_bias ? 0u : local_index - o * in4;

    vec4 g = vec4(0.0);
    for (uint s = 0u; s < rows; s++) {
        float delta = MLP_TEXEL_FLOAT(delta_texels, unit_index(s, l, o));
        uvec4 a = l == 0u ? FETCH(input_texels, int(s * MLP_IN4 + q))
                          : FETCH(act_texels, int(unit_index(s, l - 1u, 0u) / 4u + q));
        g += delta * (is_bias ? vec4(1.0) : uintBitsToFloat(a));
    }
    g /= float(rows);
    if (is_bias) {
        adam_step(mlp_offset(l) + MLP_WIDTH * mlp_fan_in(l) + o, g.x);
    } else {
        uint w = mlp_offset(l) + o * mlp_fan_in(l) + 4u * q;
        for (uint c = 0u; c < 4u; c++) {
            adam_step(w + c, g[c]);
        }
    }
}
