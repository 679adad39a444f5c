#version 460
// Neural-Q with inference at the volumes: Q of every sector at each radiance
// volume's point and normal, the network's output as the trace kernel would
// infer it there, into the Q table guide_build.comp turns into the volumes'
// sums and alias tables. With NEE, a network trained on the volumes' means
// learned Q less the share NEE carries (mlp_gather_table.comp): the table's
// Q adds that share back, so its sums hold all of Q and its distribution
// (Q less the share) is the network's own output. Where the network trains
// on the volumes' target means, the table blends each cell's mean of N
// targets with the network's Q as (N mean + m Q) / (N + m), m = the
// prior_visits setting in params.selector (infinite: the network alone).

#include "shared.h"
#include "rng.glsl"
#include "sampling.glsl"

layout(local_size_x = MLP_LANES) in;

layout(push_constant) uniform Push { PassParams params; };

#include "bsdf.glsl"
#include "neural.glsl"

// Per volume: (position, 0), (normal, 0).
layout(std430, set = 0, binding = B_NEURAL_STATES) readonly buffer States { vec4 states[]; };
layout(std430, set = 0, binding = B_Q) writeonly buffer QValues { float q_values[]; };
// The share NEE carries, copied from the target means (zero otherwise).
layout(std430, set = 0, binding = B_Q_DIRECT) readonly buffer QDirect { float q_direct[]; };
layout(std430, set = 0, binding = B_MEAN_Q) readonly buffer MeanQ { float mean_q[]; };
layout(std430, set = 0, binding = B_MEAN_VISITS) readonly buffer MeanVisits { uint mean_visits[]; };

void main() {
    uint v = gl_GlobalInvocationID.x;
    if (v >= params.volume_count) {
        return;
    }
    neural_encode(states[2u * v].xyz, states[2u * v + 1u].xyz);
    mlp_hidden_layers();
    bool nee = (params.flags & FLAG_NEE) != 0u;
    // The network's weight against a cell's running mean of targets, in visits.
    float prior = uintBitsToFloat(params.selector);
    for (uint k4 = 0u; 4u * k4 < MLP_OUTPUTS; k4++) {
        vec4 z = mlp_output4(k4);
        for (uint c = 0u; c < 4u; c++) {
            uint k = 4u * k4 + c;
            if (k < MLP_OUTPUTS) {
                uint cell = v * MLP_OUTPUTS + k;
                float net = mlp_softplus(z[c]) + (nee ? q_direct[cell] : 0.0);
                float seen = float(mean_visits[cell]);
                q_values[cell] = isinf(prior) || seen + prior == 0.0 ? net : (seen * mean_q[cell] + prior * net) / (seen + prior);
            }
        }
    }
}
