#version 460
// After a pass that learns: packs the transitions the paths offered (one
// per pixel at most, see neural.glsl) into the training batch in pixel
// order, encoding each state, and counts them all (past capacity too, for
// the batch pass's probability). One workgroup: each invocation takes a
// contiguous run of pixels, and a prefix sum over the runs places them.

#include "shared.h"
#include "rng.glsl"
#include "sampling.glsl"

layout(local_size_x = MLP_LANES) in;

layout(push_constant) uniform Push { PassParams params; };

#include "bsdf.glsl"
#include "neural.glsl"

shared uint run_offers[MLP_LANES];

// llvmpipe ends a loop after 65 535 iterations: runs go in blocks.
#define BLOCK 32768u

bool offered(uint pixel) {
    return pending[2u * pixel + 1u].w > 0.0;
}

void main() {
    uint lane = gl_LocalInvocationIndex;
    uint pixels = params.width * params.height;
    uint run = (pixels + MLP_LANES - 1u) / MLP_LANES;
    uint first = min(lane * run, pixels);
    uint end = min(first + run, pixels);
    uint count = 0u;
    for (uint b = first; b < end; b += BLOCK) {
        for (uint i = b; i < min(b + BLOCK, end); ++i) {
            count += offered(i) ? 1u : 0u;
        }
    }
    run_offers[lane] = count;
    barrier();
    if (lane == 0u) {
        uint total = 0u;
        for (uint l = 0u; l < MLP_LANES; ++l) {
            uint c = run_offers[l];
            run_offers[l] = total;
            total += c;
        }
        batch.count = total;
    }
    barrier();
    uint slot = run_offers[lane];
    uint capacity = batch.capacity;
    for (uint b = first; b < end && slot < capacity; b += BLOCK) {
        for (uint i = b; i < min(b + BLOCK, end) && slot < capacity; ++i) {
            if (offered(i)) {
                vec4 a = pending[2u * i];
                vec4 c = pending[2u * i + 1u];
                neural_encode(a.xyz, c.xyz);
                for (uint j = 0u; j < MLP_IN4; j++) {
                    batch_inputs[slot * MLP_IN4 + j] = MLP_V(j);
                }
                batch_targets[slot] = MlpTarget(uint(c.w) - 1u, a.w, 0.0, 0.0);
                slot += 1u;
            }
        }
    }
}
