// The Neural-Q network (layout and maths as in src/guide/mlp.rs): MLP_HIDDEN
// ReLU layers of MLP_WIDTH units, then a linear layer of MLP_OUTPUTS units
// and softplus, so every Q is non-negative. Parameters lie layer after layer,
// each a row-major fan_out x fan_in weight matrix followed by fan_out biases.
// Sizes are specialization constants: each pipeline is built for one shape.
#ifndef QTRACE_MLP_GLSL
#define QTRACE_MLP_GLSL

layout(constant_id = 0) const uint MLP_INPUTS = 1;
layout(constant_id = 1) const uint MLP_WIDTH = 1;
layout(constant_id = 2) const uint MLP_HIDDEN = 1;
layout(constant_id = 3) const uint MLP_OUTPUTS = 1;

layout(std430, set = 0, binding = B_MLP_PARAMS) buffer MlpParams { float mlp_params[]; };

// One invocation's state: the encoded input, the current hidden layer's
// activations, and scratch of one layer.
float mlp_in[MLP_INPUTS];
float mlp_h[MLP_WIDTH];
float mlp_t[MLP_WIDTH];

uint mlp_fan_in(uint l) {
    return l == 0u ? MLP_INPUTS : MLP_WIDTH;
}

uint mlp_fan_out(uint l) {
    return l == MLP_HIDDEN ? MLP_OUTPUTS : MLP_WIDTH;
}

// Where layer l's weights start; its biases follow them.
uint mlp_offset(uint l) {
    return l == 0u ? 0u : MLP_WIDTH * (MLP_INPUTS + 1u) + (l - 1u) * MLP_WIDTH * (MLP_WIDTH + 1u);
}

uint mlp_param_count() {
    return mlp_offset(MLP_HIDDEN) + MLP_OUTPUTS * (MLP_WIDTH + 1u);
}

float mlp_softplus(float z) {
    return z > 15.0 ? z : log(1.0 + exp(z));
}

float mlp_sigmoid(float z) {
    return 1.0 / (1.0 + exp(-z));
}

// Hidden layer l: from mlp_in (l = 0) or mlp_h, into mlp_h.
void mlp_hidden_layer(uint l) {
    uint fan_in = mlp_fan_in(l);
    uint w = mlp_offset(l);
    uint bias = w + MLP_WIDTH * fan_in;
    for (uint o = 0u; o < MLP_WIDTH; o++) {
        float z = mlp_params[bias + o];
        uint row = w + o * fan_in;
        if (l == 0u) {
            for (uint i = 0u; i < MLP_INPUTS; i++) {
                z += mlp_params[row + i] * mlp_in[i];
            }
        } else {
            for (uint i = 0u; i < MLP_WIDTH; i++) {
                z += mlp_params[row + i] * mlp_h[i];
            }
        }
        mlp_t[o] = max(z, 0.0);
    }
    for (uint o = 0u; o < MLP_WIDTH; o++) {
        mlp_h[o] = mlp_t[o];
    }
}

// All hidden layers for the input in mlp_in; the last one stays in mlp_h.
void mlp_hidden_layers() {
    for (uint l = 0u; l < MLP_HIDDEN; l++) {
        mlp_hidden_layer(l);
    }
}

// Pre-activation z of output k (Q = softplus(z)), after mlp_hidden_layers.
float mlp_output(uint k) {
    uint w = mlp_offset(MLP_HIDDEN);
    float z = mlp_params[w + MLP_OUTPUTS * MLP_WIDTH + k];
    uint row = w + k * MLP_WIDTH;
    for (uint i = 0u; i < MLP_WIDTH; i++) {
        z += mlp_params[row + i] * mlp_h[i];
    }
    return z;
}

#endif
