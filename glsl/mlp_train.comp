#version 460
// Training, per transition: the forward pass (keeping every hidden layer's
// activations), the loss 0.5 (target - Q_k)^2 and the backward pass, which
// keeps every hidden layer's deltas. mlp_adam.comp then sums the gradients.

#include "shared.h"
#include "mlp.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(push_constant) uniform Push { MlpPush push; };
layout(std430, set = 0, binding = B_MLP_INPUTS) readonly buffer Inputs { float inputs[]; };
layout(std430, set = 0, binding = B_MLP_COUNT) readonly buffer Batch { MlpBatch batch; };
layout(std430, set = 0, binding = B_MLP_TARGETS) buffer Targets { MlpTarget targets[]; };
// [transition][hidden layer][unit]
layout(std430, set = 0, binding = B_MLP_ACTS) buffer Acts { float acts[]; };
layout(std430, set = 0, binding = B_MLP_DELTAS) writeonly buffer Deltas { float deltas[]; };

uint unit_index(uint s, uint l, uint o) {
    return (s * MLP_HIDDEN + l) * MLP_WIDTH + o;
}

void main() {
    uint s = gl_GlobalInvocationID.x;
    if (s >= min(batch.count, push.capacity)) {
        return;
    }
    for (uint i = 0u; i < MLP_INPUTS; i++) {
        mlp_in[i] = inputs[s * MLP_INPUTS + i];
    }
    for (uint l = 0u; l < MLP_HIDDEN; l++) {
        mlp_hidden_layer(l);
        for (uint o = 0u; o < MLP_WIDTH; o++) {
            acts[unit_index(s, l, o)] = mlp_h[o];
        }
    }
    MlpTarget t = targets[s];
    float z = mlp_output(t.sector);
    float q = mlp_softplus(z);
    // Only output k enters the loss, so its delta is the only non-zero one.
    float delta_out = (q - t.target) * mlp_sigmoid(z);
    targets[s].loss = 0.5 * (t.target - q) * (t.target - q);
    targets[s].delta = delta_out;

    // Deltas of the last hidden layer (in mlp_t), then back through the rest.
    uint out_row = mlp_offset(MLP_HIDDEN) + t.sector * MLP_WIDTH;
    for (uint i = 0u; i < MLP_WIDTH; i++) {
        mlp_t[i] = mlp_h[i] > 0.0 ? mlp_params[out_row + i] * delta_out : 0.0;
        deltas[unit_index(s, MLP_HIDDEN - 1u, i)] = mlp_t[i];
    }
    for (uint l = MLP_HIDDEN - 1u; l > 0u; l--) {
        uint w = mlp_offset(l);
        for (uint j = 0u; j < MLP_WIDTH; j++) {
            float d = 0.0;
            if (acts[unit_index(s, l - 1u, j)] > 0.0) {
                for (uint o = 0u; o < MLP_WIDTH; o++) {
                    d += mlp_params[w + o * MLP_WIDTH + j] * mlp_t[o];
                }
            }
            mlp_h[j] = d;
        }
        for (uint j = 0u; j < MLP_WIDTH; j++) {
            mlp_t[j] = mlp_h[j];
            deltas[unit_index(s, l - 1u, j)] = mlp_h[j];
        }
    }
}
