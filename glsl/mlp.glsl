// The Neural-Q network (layout and maths as in src/guide/mlp.rs): MLP_HIDDEN
// ReLU layers of MLP_WIDTH units, then a linear layer of MLP_OUTPUTS units
// and softplus, so every Q is non-negative. Parameters lie layer after layer,
// each a row-major fan_out x fan_in weight matrix followed by fan_out biases.
// Sizes are specialization constants: each pipeline is built for one shape.
// MLP_INPUTS and MLP_WIDTH are multiples of 4, so every row starts on a vec4.
//
// Each invocation's vectors live in workgroup memory, lane-interleaved, in
// two regions that layers read and write in turn. Measured on llvmpipe:
// private arrays indexed in loops are 50x slower, and fully unrolled loops
// that keep them in registers take a minute to compile.
#ifndef QTRACE_MLP_GLSL
#define QTRACE_MLP_GLSL

layout(constant_id = 0) const uint MLP_INPUTS = 4;
layout(constant_id = 1) const uint MLP_WIDTH = 4;
layout(constant_id = 2) const uint MLP_HIDDEN = 1;
layout(constant_id = 3) const uint MLP_OUTPUTS = 1;
const uint MLP_IN4 = MLP_INPUTS / 4u;
const uint MLP_W4 = MLP_WIDTH / 4u;
// Region A (the input, then even layers' outputs... see mlp_hidden_layer)
// and region B, in vec4s.
const uint MLP_A4 = MLP_IN4 > MLP_W4 ? MLP_IN4 : MLP_W4;
const uint MLP_SPAN4 = MLP_A4 + MLP_W4;

// Kernels that run the network (all but those that define MLP_PARAMS_ONLY)
// run MLP_LANES invocations per workgroup (shared.h).
#ifndef MLP_PARAMS_ONLY
shared vec4 mlp_vectors[MLP_LANES * MLP_SPAN4];
#define MLP_V(i) mlp_vectors[(i) * MLP_LANES + gl_LocalInvocationIndex]
#endif

#ifdef MLP_PARAMS_ONLY
layout(std430, set = 0, binding = B_MLP_PARAMS) buffer MlpParams { vec4 mlp_params[]; };

vec4 mlp_w(uint i4) {
    return mlp_params[i4];
}
#else
// Kernels that only read the parameters read them as texels: lavapipe turns
// a storage-buffer read into a loop over lanes, a texel read into one gather.
WORDS(mlp_param_texels, B_MLP_PARAMS)

vec4 mlp_w(uint i4) {
    return uintBitsToFloat(FETCH(mlp_param_texels, int(i4)));
}
#endif

// Float i of a batch buffer read as texels of four floats (the Adam steps
// read the batch so: one gather instead of a loop over lanes).
#define MLP_TEXEL_FLOAT(texels, i) uintBitsToFloat(FETCH(texels, int((i) >> 2u))[(i) & 3u])

float mlp_param(uint i) {
    return mlp_w(i >> 2)[i & 3u];
}

// Where layer l's weights start (in floats); its biases follow them.
uint mlp_offset(uint l) {
    return l == 0u ? 0u : MLP_WIDTH * (MLP_INPUTS + 1u) + (l - 1u) * MLP_WIDTH * (MLP_WIDTH + 1u);
}

uint mlp_fan_in(uint l) {
    return l == 0u ? MLP_INPUTS : MLP_WIDTH;
}

uint mlp_fan_out(uint l) {
    return l == MLP_HIDDEN ? MLP_OUTPUTS : MLP_WIDTH;
}

uint mlp_param_count() {
    return mlp_offset(MLP_HIDDEN) + MLP_OUTPUTS * (MLP_WIDTH + 1u);
}

#ifndef MLP_PARAMS_ONLY
// The region (first vec4) holding layer l's input: the encoded input for
// l = 0 is in A; layer l writes its output to the other region.
uint mlp_input_region(uint l) {
    return (l & 1u) == 0u ? 0u : MLP_A4;
}

uint mlp_output_region(uint l) {
    return (l & 1u) == 0u ? MLP_A4 : 0u;
}

// The region holding the last hidden layer's activations.
uint mlp_last_region() {
    return mlp_output_region(MLP_HIDDEN - 1u);
}

// Input i of the encoded state.
void mlp_set_input(uint i, float value) {
    mlp_vectors[(i / 4u) * MLP_LANES + gl_LocalInvocationIndex][i % 4u] = value;
}

float mlp_softplus(float z) {
    return z > 15.0 ? z : log(1.0 + exp(z));
}

float mlp_sigmoid(float z) {
    return 1.0 / (1.0 + exp(-z));
}

// Hidden layer l, from its input region into its output region.
void mlp_hidden_layer(uint l) {
    uint from = mlp_input_region(l);
    uint to = mlp_output_region(l);
    uint fan_in4 = mlp_fan_in(l) / 4u;
    uint row4 = mlp_offset(l) / 4u;
    uint bias4 = row4 + MLP_WIDTH * fan_in4;
    // Four units at a time, so each input vec4 is read once for four rows.
    for (uint o4 = 0u; o4 < MLP_W4; o4++) {
        vec4 z = mlp_w(bias4 + o4);
        uint row = row4 + 4u * o4 * fan_in4;
        for (uint i = 0u; i < fan_in4; i++) {
            vec4 x = MLP_V(from + i);
            z += vec4(dot(mlp_w(row + i), x),
                      dot(mlp_w(row + fan_in4 + i), x),
                      dot(mlp_w(row + 2u * fan_in4 + i), x),
                      dot(mlp_w(row + 3u * fan_in4 + i), x));
        }
        MLP_V(to + o4) = max(z, vec4(0.0));
    }
}

// All hidden layers for the encoded input; the last stays in mlp_last_region.
void mlp_hidden_layers() {
    for (uint l = 0u; l < MLP_HIDDEN; l++) {
        mlp_hidden_layer(l);
    }
}

// Pre-activations of outputs 4 k4 .. 4 k4 + 3 (those past MLP_OUTPUTS are
// 0), after mlp_hidden_layers: each hidden vec4 is read once for four rows.
vec4 mlp_output4(uint k4) {
    uint last = mlp_offset(MLP_HIDDEN);
    uint h = mlp_last_region();
    vec4 z = vec4(0.0);
    uint first = 4u * k4;
    // Rows past the end repeat the last row; their results are dropped.
    uint r0 = last / 4u + min(first, MLP_OUTPUTS - 1u) * MLP_W4;
    uint r1 = last / 4u + min(first + 1u, MLP_OUTPUTS - 1u) * MLP_W4;
    uint r2 = last / 4u + min(first + 2u, MLP_OUTPUTS - 1u) * MLP_W4;
    uint r3 = last / 4u + min(first + 3u, MLP_OUTPUTS - 1u) * MLP_W4;
    for (uint i = 0u; i < MLP_W4; i++) {
        vec4 x = MLP_V(h + i);
        z += vec4(dot(mlp_w(r0 + i), x), dot(mlp_w(r1 + i), x),
                  dot(mlp_w(r2 + i), x), dot(mlp_w(r3 + i), x));
    }
    uint bias = last + MLP_OUTPUTS * MLP_WIDTH;
    for (uint c = 0u; c < 4u; c++) {
        z[c] = first + c < MLP_OUTPUTS ? z[c] + mlp_param(bias + first + c) : 0.0;
    }
    return z;
}

// Pre-activation z of output k (Q = softplus(z)), after mlp_hidden_layers.
float mlp_output(uint k) {
    uint last = mlp_offset(MLP_HIDDEN);
    uint row = last / 4u + k * MLP_W4;
    uint h = mlp_last_region();
    float z = mlp_param(last + MLP_OUTPUTS * MLP_WIDTH + k);
    for (uint i = 0u; i < MLP_W4; i++) {
        z += dot(mlp_w(row + i), MLP_V(h + i));
    }
    return z;
}
#endif

#endif
