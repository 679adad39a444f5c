#version 460
#extension GL_EXT_control_flow_attributes : require
// Training, per transition: the forward pass (keeping every hidden layer's
// activations), the relative loss 0.5 (target - Q_k)^2 / (Q_k^2 + epsilon)
// (Q_k in the denominator held constant) and the backward pass, which keeps
// every hidden layer's deltas. mlp_adam.comp then sums the gradients.
// With MLP_DENSE a row has a target for every sector (a volume's row of
// target means), and the loss sums over them: one forward and backward pass
// teaches all the row's outputs.

#include "shared.h"
#include "mlp.glsl"

layout(local_size_x = LINEAR_GROUP) in;

layout(push_constant) uniform Push { MlpPush push; };
layout(std430, set = 0, binding = B_MLP_INPUTS) readonly buffer Inputs { vec4 inputs[]; };
layout(std430, set = 0, binding = B_MLP_COUNT) readonly buffer Batch { MlpBatch batch; };
layout(std430, set = 0, binding = B_MLP_TARGETS) buffer Targets { MlpTarget targets[]; };
// [transition][hidden layer][unit / 4]
layout(std430, set = 0, binding = B_MLP_ACTS) buffer Acts { vec4 acts[]; };
layout(std430, set = 0, binding = B_MLP_DELTAS) writeonly buffer Deltas { vec4 deltas[]; };
#ifdef MLP_DENSE
layout(std430, set = 0, binding = B_MLP_DENSE) buffer Dense { float dense[]; };
#endif

// The relative loss's weight at Q = q, held constant in the gradient.
float relative_weight(float q) {
    return 1.0 / (q * q + 1.0 / float(MLP_LOSS_EPSILON_INV));
}

uint unit4(uint s, uint l) {
    return (s * MLP_HIDDEN + l) * MLP_W4;
}

void main() {
    uint s = gl_GlobalInvocationID.x;
    if (s >= min(batch.count, push.capacity)) {
        return;
    }
    for (uint i = 0u; i < MLP_IN4; i++) {
        MLP_V(i) = inputs[s * MLP_IN4 + i];
    }
    for (uint l = 0u; l < MLP_HIDDEN; l++) {
        mlp_hidden_layer(l);
        uint h = mlp_output_region(l);
        for (uint i = 0u; i < MLP_W4; i++) {
            acts[unit4(s, l) + i] = MLP_V(h + i);
        }
    }
    // Relative to Q, the loss weighs dim places, where guiding matters most,
    // as much as bright ones (measured: relMSE 0.100 -> 0.058 on the room
    // at 128x128 with training = "volumes").
    // The last hidden layer's activations and deltas stay in registers
    // (unrolled loops index the arrays with constants), as every output
    // reads and adds to them: llvmpipe reads and writes workgroup memory one
    // lane and word at a time.
    vec4 h[MLP_W4];
    vec4 d[MLP_W4];
    uint last_region = mlp_last_region();
    [[unroll]] for (uint i = 0u; i < MLP_W4; i++) {
        h[i] = MLP_V(last_region + i);
        d[i] = vec4(0.0);
    }
    uint last = mlp_offset(MLP_HIDDEN);
#ifdef MLP_DENSE
    // Every output adds to the deltas; its weights are read once for both.
    vec4 w[MLP_W4];
    float loss = 0.0;
    for (uint k = 0u; k < MLP_OUTPUTS; k++) {
        uint out_row = last / 4u + k * MLP_W4;
        float z = mlp_param(last + MLP_OUTPUTS * MLP_WIDTH + k);
        [[unroll]] for (uint i = 0u; i < MLP_W4; i++) {
            w[i] = mlp_w(out_row + i);
            z += dot(w[i], h[i]);
        }
        float q = mlp_softplus(z);
        float target = dense[s * MLP_OUTPUTS + k];
        float relative = relative_weight(q);
        float delta_out = (q - target) * mlp_sigmoid(z) * relative;
        loss += 0.5 * (target - q) * (target - q) * relative;
        dense[(push.capacity + s) * MLP_OUTPUTS + k] = delta_out;
        [[unroll]] for (uint i = 0u; i < MLP_W4; i++) {
            d[i] += w[i] * delta_out;
        }
    }
    targets[s].loss = loss;
#else
    MlpTarget t = targets[s];
    float z = mlp_output(t.sector);
    float q = mlp_softplus(z);
    // Only output k enters the loss, so its delta is the only non-zero one.
    float relative = relative_weight(q);
    float delta_out = (q - t.target) * mlp_sigmoid(z) * relative;
    targets[s].loss = 0.5 * (t.target - q) * (t.target - q) * relative;
    targets[s].delta = delta_out;
    uint out_row = last / 4u + t.sector * MLP_W4;
    [[unroll]] for (uint i = 0u; i < MLP_W4; i++) {
        d[i] = mlp_w(out_row + i) * delta_out;
    }
#endif
    [[unroll]] for (uint i = 0u; i < MLP_W4; i++) {
        d[i] = mix(vec4(0.0), d[i], greaterThan(h[i], vec4(0.0)));
        deltas[unit4(s, MLP_HIDDEN - 1u) + i] = d[i];
    }
    // Earlier layers' deltas go through workgroup memory, in the region the
    // last activations do not occupy, then each layer's to the other in turn.
    uint from = last_region == 0u ? MLP_A4 : 0u;
    [[unroll]] for (uint i = 0u; i < MLP_W4; i++) {
        MLP_V(from + i) = d[i];
    }
    for (uint l = MLP_HIDDEN - 1u; l > 0u; l--) {
        // delta_{l-1}[j] = sum_o W_l[o][j] delta_l[o], where unit j was active.
        uint to = from == 0u ? MLP_A4 : 0u;
        uint w4 = mlp_offset(l) / 4u;
        for (uint j = 0u; j < MLP_W4; j++) {
            MLP_V(to + j) = vec4(0.0);
        }
        for (uint o = 0u; o < MLP_WIDTH; o++) {
            float d_o = MLP_V(from + o / 4u)[o % 4u];
            if (d_o != 0.0) {
                for (uint j = 0u; j < MLP_W4; j++) {
                    MLP_V(to + j) += d_o * mlp_w(w4 + o * MLP_W4 + j);
                }
            }
        }
        for (uint j = 0u; j < MLP_W4; j++) {
            vec4 dj = mix(vec4(0.0), MLP_V(to + j), greaterThan(acts[unit4(s, l - 1u) + j], vec4(0.0)));
            MLP_V(to + j) = dj;
            deltas[unit4(s, l - 1u) + j] = dj;
        }
        from = to;
    }
}
