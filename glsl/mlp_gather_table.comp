#version 460
// Neural-Q trained on the volumes' target table (`training = "volumes"`):
// fills the batch with rows drawn uniformly from every (volume, sector)
// cell: the volume's encoded state, the sector, and the running mean of
// the TD targets that landed in that cell (Sarsa's tallies, folded by the
// guide update), so a row's target averages every transition that reached
// it instead of being one path's. One invocation per row; `selector` is
// the training step within the pass, so each step draws other rows.

#include "shared.h"
#include "rng.glsl"
#include "sampling.glsl"

layout(local_size_x = MLP_LANES) in;

layout(push_constant) uniform Push { PassParams params; };

#include "bsdf.glsl"
#include "neural.glsl"

// Per volume: (position, 0), (normal, 0).
layout(std430, set = 0, binding = B_NEURAL_STATES) readonly buffer States { vec4 states[]; };
// The target table: per (volume, sector), the mean of its TD targets.
layout(std430, set = 0, binding = B_Q) readonly buffer Targets { float q_data[]; };

void main() {
    uint slot = gl_GlobalInvocationID.x;
    uint capacity = batch.capacity;
    if (slot == 0u) {
        batch.count = capacity;
    }
    if (slot >= capacity) {
        return;
    }
    uint rng = rng_init(slot, params.pass_index * 64u + params.selector, params.seed);
    uint cells = params.volume_count * MLP_OUTPUTS;
    // Two draws: 48 bits cover any table uniformly enough.
    float u = rng_next(rng) + rng_next(rng) / 16777216.0;
    uint cell = min(uint(u * float(cells)), cells - 1u);
    uint v = cell / MLP_OUTPUTS;
    uint k = cell - v * MLP_OUTPUTS;
    neural_encode(states[2u * v].xyz, states[2u * v + 1u].xyz);
    for (uint j = 0u; j < MLP_IN4; j++) {
        batch_inputs[slot * MLP_IN4 + j] = MLP_V(j);
    }
    batch_targets[slot] = MlpTarget(k, max(q_data[cell], 0.0), 0.0, 0.0);
}
