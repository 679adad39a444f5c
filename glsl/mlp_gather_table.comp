#version 460
// Neural-Q trained on the volumes' target table (`training = "volumes"`):
// fills the batch with rows of volumes drawn uniformly (as many rows as the
// batch holds, but no more than there are volumes): the volume's encoded
// state and, for every sector, the running mean of the TD targets that
// landed in that (volume, sector) cell (Sarsa's tallies, folded by the
// guide update). So a target averages every transition that reached it
// instead of being one path's, and one forward and backward pass teaches
// all of a volume's sectors (mlp_train.comp with MLP_DENSE). One
// invocation per row; `selector` is the training step within the pass, so
// each step draws other rows.

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
layout(std430, set = 0, binding = B_MLP_DENSE) writeonly buffer Dense { float dense[]; };
// With NEE: per cell, the mean share of its targets that NEE carries.
layout(std430, set = 0, binding = B_Q_DIRECT) readonly buffer QDirect { float q_direct[]; };

void main() {
    uint slot = gl_GlobalInvocationID.x;
    uint rows = min(batch.capacity, params.volume_count);
    if (slot == 0u) {
        batch.count = rows;
    }
    if (slot >= rows) {
        return;
    }
    uint rng = rng_init(slot, params.pass_index * 64u + params.selector, params.seed);
    uint v = min(uint(rng_next(rng) * float(params.volume_count)), params.volume_count - 1u);
    neural_encode(states[2u * v].xyz, states[2u * v + 1u].xyz);
    for (uint j = 0u; j < MLP_IN4; j++) {
        batch_inputs[slot * MLP_IN4 + j] = MLP_V(j);
    }
    // With NEE the network learns what scattering should find, Q less the
    // share NEE carries (neural_volumes.comp adds that share back for the
    // tables' sums): learning all of Q and subtracting the exact share
    // afterwards left the network's error in Q, large where direct light
    // dominates, as the sampling weight (measured: relMSE 0.00132 against
    // pt+nee's 0.00098 on the Cornell box at 128x128, 256 spp).
    bool nee = (params.flags & FLAG_NEE) != 0u;
    for (uint k = 0u; k < MLP_OUTPUTS; k++) {
        uint cell = v * MLP_OUTPUTS + k;
        dense[slot * MLP_OUTPUTS + k] = max(q_data[cell] - (nee ? q_direct[cell] : 0.0), 0.0);
    }
    // The row's volume where a one-target row keeps its sector (for tests).
    batch_targets[slot] = MlpTarget(v, 0.0, 0.0, 0.0);
}
