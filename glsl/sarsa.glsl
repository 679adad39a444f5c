// The Expected Sarsa guide (docs/guides.md) behind the guide seam of guide.glsl:
// the tables of volumes.glsl, learned by atomic updates in the trace kernel.
// Needs shared.h, sampling.glsl, bsdf.glsl and the `params` push constants.
#ifndef QTRACE_SARSA_GLSL
#define QTRACE_SARSA_GLSL

#include "atomics.glsl"
#include "volumes.glsl"

layout(std430, set = 0, binding = B_SUM) buffer TargetSums { TALLY target_sum[]; };
layout(std430, set = 0, binding = B_VISITS) buffer Visits { uint visits[]; };
// With NEE: per (volume, sector), the part of this pass's emitter targets
// that NEE already carries (Le times one minus the scattering MIS weight).
layout(std430, set = 0, binding = B_DIRECT_SUM) buffer DirectSums { TALLY direct_sum[]; };
// Per volume, the pass's tallies of the gradient for its share of BSDF
// sampling (FLAG_LEARN_MIX): positive part, negative part.
layout(std430, set = 0, binding = B_MIX_GRAD) buffer MixGrad { TALLY mix_grad[]; };

// With FLAG_GUIDE_LIGHTS, per (volume, light): what NEE's tries of the
// light brought there, without its MIS weight or the chance of picking it
// (the light's whole contribution, luminance), and how many tries.
layout(std430, set = 0, binding = B_LIGHT_SUM) buffer LightSums { TALLY light_sum[]; };
layout(std430, set = 0, binding = B_LIGHT_TRIES) buffer LightTries { uint light_tries[]; };

const bool GUIDED = true;
// Whether the tables pick NEE's light (FLAG_GUIDE_LIGHTS; volumes.glsl
// reads the choice).
layout(constant_id = CONSTANT_GUIDE_LIGHTS) const bool GUIDE_LIGHTS = false;

// Records one NEE try of light l at g that brought `brought` (0 where the
// light faced away or was blocked).
void guide_record_light(GuideVertex g, uint l, float brought) {
    if (g.volume != NO_VOLUME) {
        uint index = g.volume * light_groups() + l;
        ADD_TALLY(light_sum[index], brought);
        atomicAdd(light_tries[index], 1u);
    }
}

// Adds one target for (v, k), whose Q was q; the guide update turns sums and
// counts into means. Returns the squared temporal-difference error.
float sarsa_record(uint v, uint k, float target, float q) {
    uint index = v * sector_count() + k;
    ADD_TALLY(target_sum[index], target);
    atomicAdd(visits[index], 1u);
    float td = target - q;
    return td * td;
}

// With NEE: records the part of an emitter target for (v, k) that NEE
// already carries, so sampling can leave it to NEE.
void sarsa_record_direct(uint v, uint k, float excess) {
    uint index = v * sector_count() + k;
    ADD_TALLY(direct_sum[index], excess);
}

// The guide seam's learning side (guide.glsl).

// Records `target` for (from, k); with NEE, q is the sampling table's Q,
// short of what NEE carries, so the loss compares with Q itself.
void sarsa_learn(GuideVertex from, uint k, float q, float target, inout float td_sq_sum, inout uint td_count) {
    if (from.volume != NO_VOLUME) {
#ifdef WITH_NEE
        q = load_q(from.volume * sector_count() + k);
#endif
        td_sq_sum += sarsa_record(from.volume, k, target, q);
        td_count += 1u;
    }
}

void guide_begin_path() {
}

// Tallies one sample's gradient for the share of BSDF sampling at `from`,
// bounded so that no single path sets a volume's step (it only steers the
// share; the image stays unbiased).
void guide_learn_share(GuideVertex from, float gradient) {
    if ((params.flags & FLAG_LEARN_MIX) != 0u && from.volume != NO_VOLUME) {
        float g = clamp(gradient, -1.0e6, 1.0e6);
        ADD_TALLY(mix_grad[2u * from.volume + (g < 0.0 ? 1u : 0u)], abs(g));
    }
}

// Sarsa learns as transitions land (sarsa_record); nothing is left at a path's end.
void guide_end_path(uint index, inout uint rng) {
}

// Sarsa's target leaves out what NEE brings at the vertex it reached, and
// an emitter's target is all of its Le: NEE's share of that is learned
// apart (sarsa_record_direct) and taken out of the sampling distribution
// instead.
void guide_learn(GuideVertex from, uint k, float q, float le, float mis_weight,
                 float reflected, float direct, inout float td_sq_sum, inout uint td_count,
                 inout uint rng) {
    sarsa_learn(from, k, q, le + reflected, td_sq_sum, td_count);
#ifdef WITH_NEE
    if (from.volume != NO_VOLUME && mis_weight < 1.0) {
        sarsa_record_direct(from.volume, k, le * (1.0 - mis_weight));
    }
#endif
}

#endif
