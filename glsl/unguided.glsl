// Plain path tracing behind the guide seam of guide.glsl: a guide that
// covers no vertex and learns nothing. The trace kernel then samples by the
// BSDF alone; every guide call folds to a constant, so the driver's compiler
// leaves none of the guides' code in the plain kernels.
#ifndef QTRACE_UNGUIDED_GLSL
#define QTRACE_UNGUIDED_GLSL

#include "grid.glsl"

const bool GUIDED = false;
const bool GUIDE_LIGHTS = false;

const bool GUIDE_TWO_SIDED = false;

struct GuideVertex {
    uint none;
};

GuideVertex guide_none() {
    return GuideVertex(0u);
}

GuideVertex guide_at(uint triangle, Triangle tri, vec3 p, vec3 n, bool front) {
    return guide_none();
}

bool guide_covers(GuideVertex g) {
    return false;
}

float guide_total(GuideVertex g) {
    return 0.0;
}

float guide_bsdf_share(GuideVertex g) {
    return 1.0;
}

float guide_irradiance(GuideVertex g) {
    return 0.0;
}

float guide_sector_probability(GuideVertex g, uint k) {
    return 0.0;
}

uint guide_choose_sector(GuideVertex g, bool pick, float u, uint sector, out float p) {
    p = 0.0;
    return sector;
}

float guide_sector_q(GuideVertex g, uint k) {
    return 0.0;
}

uint guide_choose_light(GuideVertex g, float u, out float p) {
    p = 0.0;
    return 0u;
}

float guide_light_probability(GuideVertex g, uint l) {
    return 0.0;
}

void guide_record_light(GuideVertex g, uint l, float brought) {
}

void guide_begin_path() {
}

void guide_learn(GuideVertex from, uint k, float q, float le, float mis_weight,
                 float reflected, float direct, inout float td_sq_sum, inout uint td_count,
                 inout uint rng) {
}

void guide_learn_share(GuideVertex from, float gradient) {
}

void guide_end_path(uint index, inout uint rng) {
}

#endif
