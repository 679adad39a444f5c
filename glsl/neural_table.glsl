// Neural-Q with inference at the radiance volumes (`inference = "volumes"`)
// behind the guide seam of guide.glsl: after each pass that trains, the
// network's Q at every volume's point and normal fills the tables of
// volumes.glsl (neural_volumes.comp, then guide_build.comp), and paths
// sample from them as Sarsa's do, at one table read per vertex instead of
// one inference. Training still learns at each transition's own state.
// Needs shared.h, rng.glsl, sampling.glsl, bsdf.glsl and the `params` push
// constants.
#ifndef QTRACE_NEURAL_TABLE_GLSL
#define QTRACE_NEURAL_TABLE_GLSL

#include "volumes.glsl"

bool guide_has_state(GuideVertex g) {
    return g.n != vec3(0.0);
}

#include "neural_offer.glsl"

#endif
