#version 460
// After a training step: aims the next pass's offer probability at 90% of
// the batch's capacity, from how many transitions this pass offered, and
// empties the batch.

#include "shared.h"

layout(local_size_x = 1) in;

layout(std430, set = 0, binding = B_MLP_COUNT) buffer Batch { MlpBatch batch; };

void main() {
    if (batch.count > 0u) {
        float transitions = float(batch.count) / batch.probability;
        batch.probability = clamp(0.9 * float(batch.capacity) / transitions, 1e-6, 1.0);
    }
    batch.count = 0u;
}
