// PCG random numbers (O'Neill), one stream per path.
#ifndef QTRACE_RNG_GLSL
#define QTRACE_RNG_GLSL

uint pcg_hash(uint v) {
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// Seeds a stream from the pixel, the pass and the user's seed.
uint rng_init(uint pixel, uint pass_index, uint seed) {
    return pcg_hash(pixel ^ pcg_hash(pass_index ^ pcg_hash(seed)));
}

// Uniform in [0, 1).
float rng_next(inout uint state) {
    state = state * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    word = (word >> 22u) ^ word;
    return float(word >> 8u) * (1.0 / 16777216.0);
}

vec2 rng_next2(inout uint state) {
    float a = rng_next(state);
    return vec2(a, rng_next(state));
}

#endif
