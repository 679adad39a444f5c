#version 460
// Batched inference: Q of every sector for each input row.

#include "shared.h"
#include "mlp.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(push_constant) uniform Push { MlpPush push; };
layout(std430, set = 0, binding = B_MLP_INPUTS) readonly buffer Inputs { vec4 inputs[]; };
layout(std430, set = 0, binding = B_MLP_COUNT) readonly buffer Batch { MlpBatch batch; };
layout(std430, set = 0, binding = B_MLP_OUTPUTS) writeonly buffer Outputs { float outputs[]; };

void main() {
    uint s = gl_GlobalInvocationID.x;
    if (s >= min(batch.count, push.capacity)) {
        return;
    }
    for (uint i = 0u; i < MLP_IN4; i++) {
        MLP_V(i) = inputs[s * MLP_IN4 + i];
    }
    mlp_hidden_layers();
    for (uint k = 0u; k < MLP_OUTPUTS; k++) {
        outputs[s * MLP_OUTPUTS + k] = mlp_softplus(mlp_output(k));
    }
}
