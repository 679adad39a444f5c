// How Neural-Q's trace kernels offer transitions to the training batch,
// whichever way they sample (neural.glsl infers at every vertex,
// neural_table.glsl reads tables the network filled). The guide provides
// GuideVertex with the state's point p and normal n, and
// guide_has_state(g), false before the camera ray. Needs shared.h and rng.glsl.
#ifndef QTRACE_NEURAL_OFFER_GLSL
#define QTRACE_NEURAL_OFFER_GLSL

layout(std430, set = 0, binding = B_MLP_COUNT) buffer Batch { MlpBatch batch; };

const bool GUIDED = true;
// NEE picks lights by power (the network learns no choice; trained on the
// volumes' means, Neural-Q runs Sarsa's kernel, which does).
const bool GUIDE_LIGHTS = false;

void guide_record_light(GuideVertex g, uint l, float brought) {
}

// Per pixel, the transition its path kept for training (two vec4s:
// position and target; normal and sector + 1, or 0 when it offers none).
// src/guide/neural.rs's gather pass packs the offered ones into the batch
// in pixel order, so which transitions train, and in what order, does not
// depend on the order invocations run: one seed, one network.
layout(std430, set = 0, binding = B_NEURAL_PENDING) buffer Pending { vec4 pending[]; };

// The path's kept transition: one of its transitions, uniformly (reservoir
// sampling over them as they land).
uint kept_count;
vec3 kept_p;
vec3 kept_n;
uint kept_k;
float kept_target;

void guide_begin_path() {
    kept_count = 0u;
}

// Q learns all the light that reaches `from` through sector k beyond NEE at
// `from`: what the vertex it reached reflects, NEE there included; of an
// emitter it reached, with NEE, only the MIS share scattering brings.
void guide_learn(GuideVertex from, uint k, float q, float le, float mis_weight,
                 float reflected, float direct, inout float td_sq_sum, inout uint td_count,
                 inout uint rng) {
    if (guide_has_state(from)) {
        float target = le * mis_weight + reflected + direct;
        float td = target - q;
        td_sq_sum += td * td;
        td_count += 1u;
        kept_count += 1u;
        if (rng_next(rng) * float(kept_count) < 1.0) {
            kept_p = from.p;
            kept_n = from.n;
            kept_k = k;
            kept_target = target;
        }
    }
}

// Training on transitions, Neural-Q keeps `epsilon` (on the volumes' means
// it runs Sarsa's kernel, which learns the share).
void guide_learn_share(GuideVertex from, float gradient) {
}

// A learning pass's path at pixel `index` ended: it offers its kept
// transition with the batch's probability.
void guide_end_path(uint index, inout uint rng) {
    bool offer = kept_count > 0u && rng_next(rng) < batch.probability;
    pending[2u * index] = vec4(kept_p, kept_target);
    pending[2u * index + 1u] = vec4(kept_n, offer ? float(kept_k + 1u) : 0.0);
}

#endif
