// The Neural-Q guide (docs/guides.md) behind the guide seam of guide.glsl: the
// state encoding, inference of every sector's Q at a path vertex and sector
// sampling from it; neural_offer.glsl offers the transitions to training.
// Needs shared.h, sampling.glsl, bsdf.glsl and the `params` push constants;
// the sector grid must have MLP_OUTPUTS sectors.
#ifndef QTRACE_NEURAL_GLSL
#define QTRACE_NEURAL_GLSL

#include "grid.glsl"
#include "mlp.glsl"

// What the guide knows at a path vertex: the state (p, n), the total of
// the sector weights it inferred into neural_w (negative: the vertex before
// the camera ray, which has no state) and (2 pi / n) sum_j Q_j cos(theta_j)
// (expected target), or max_j Q_j cos(theta_j) (Q-learning).
// One network inference a vertex (neural_w holds it): a vertex that lets
// light through is not guided (guide.glsl's Mixture).
const bool GUIDE_TWO_SIDED = false;

struct GuideVertex {
    vec3 p;
    vec3 n;
    float total;
    float reach;
};

bool guide_has_state(GuideVertex g) {
    return g.total >= 0.0;
}

#include "neural_offer.glsl"

layout(std430, set = 0, binding = B_MLP_INPUTS) writeonly buffer BatchInputs { vec4 batch_inputs[]; };
layout(std430, set = 0, binding = B_MLP_TARGETS) writeonly buffer BatchTargets { MlpTarget batch_targets[]; };
layout(std430, set = 0, binding = B_NEURAL_VERTICES) readonly buffer Vertices { vec4 neural_vertices[]; };

// The state of a point p with normal n, as the network's input: p in the
// scene's box mapped to [-1, 1]^3, n, then sin and cos of p at
// ENCODING_FREQUENCIES octaves, then zeros.
//
// Or, with FLAG_VERTEX_ENCODING (the thesis's, for small scenes): every
// scene vertex relative to p, over the scene's extent, then n, then zeros.
void neural_encode(vec3 p, vec3 n) {
    if (EXPERIMENT(FLAG_VERTEX_ENCODING)) {
        uint count = batch.vertex_count;
        for (uint v = 0u; v < count; v++) {
            vec3 d = (neural_vertices[v].xyz - p) * batch.bounds_scale.xyz;
            for (uint i = 0u; i < 3u; i++) {
                mlp_set_input(3u * v + i, d[i]);
            }
        }
        for (uint i = 0u; i < 3u; i++) {
            mlp_set_input(3u * count + i, n[i]);
        }
        for (uint i = 3u * count + 3u; i < MLP_INPUTS; i++) {
            mlp_set_input(i, 0.0);
        }
        return;
    }
    vec3 u = (p - batch.bounds_min.xyz) * batch.bounds_scale.xyz;
    for (uint i = 0u; i < 3u; i++) {
        mlp_set_input(i, 2.0 * u[i] - 1.0);
        mlp_set_input(3u + i, n[i]);
    }
    float f = PI;
    for (uint o = 0u; o < ENCODING_FREQUENCIES; o++) {
        vec3 s = sin(u * f);
        vec3 c = cos(u * f);
        for (uint i = 0u; i < 3u; i++) {
            mlp_set_input(6u + 6u * o + i, s[i]);
            mlp_set_input(9u + 6u * o + i, c[i]);
        }
        f *= 2.0;
    }
    for (uint i = 6u + 6u * ENCODING_FREQUENCIES; i < MLP_INPUTS; i++) {
        mlp_set_input(i, 0.0);
    }
}

// The sampling weight of every sector at the current vertex: Q, or Q cos
// theta. (Kept, not recomputed: measured 20% faster on llvmpipe.)
float neural_w[MLP_OUTPUTS];

GuideVertex guide_none() {
    return GuideVertex(vec3(0.0), vec3(0.0), -1.0, 0.0);
}

// Infers Q at p (normal n) into neural_w.
GuideVertex neural_infer(vec3 p, vec3 n) {
    neural_encode(p, n);
    mlp_hidden_layers();
    uint a = grid_a();
    uint b = grid_b();
    bool cos_weights = !EXPERIMENT(FLAG_Q_DISTRIBUTION);
    float total = 0.0;
    float sum = 0.0;
    float best = 0.0;
    for (uint k4 = 0u; 4u * k4 < MLP_OUTPUTS; k4++) {
        vec4 z = mlp_output4(k4);
        for (uint c = 0u; c < 4u; c++) {
            uint k = 4u * k4 + c;
            if (k >= MLP_OUTPUTS) {
                break;
            }
            float q = mlp_softplus(z[c]);
            float qc = q * sector_cos(k, a, b);
            float w = cos_weights ? qc : q;
            neural_w[k] = w;
            total += w;
            sum += qc;
            best = max(best, qc);
        }
    }
    float reach = EXPERIMENT(FLAG_MAX_TARGET) ? best : sum * 2.0 * PI / float(MLP_OUTPUTS);
    return GuideVertex(p, n, total, reach);
}

GuideVertex guide_at(uint triangle, Triangle tri, vec3 p, vec3 n, bool front) {
    return neural_infer(p, n);
}

bool guide_covers(GuideVertex g) {
    return g.total > 0.0;
}

float guide_bsdf_share(GuideVertex g) {
    return params.guide_epsilon;
}

float guide_total(GuideVertex g) {
    return g.total;
}

float guide_irradiance(GuideVertex g) {
    return g.reach;
}

float guide_sector_probability(GuideVertex g, uint k) {
    return neural_w[k] / g.total;
}

// Of the vertex inferred last (neural_w).
float guide_sector_q(GuideVertex g, uint k) {
    if (g.total <= 0.0) {
        return 0.0;
    }
    return !EXPERIMENT(FLAG_Q_DISTRIBUTION) ? neural_w[k] / sector_cos(k, grid_a(), grid_b()) : neural_w[k];
}

// Inverse CDF by a scan; rounding past the end falls to the last sector of
// non-zero weight, never to one the pdf calls impossible.
uint guide_pick_sector(GuideVertex g, float u, out float p) {
    float x = u * g.total;
    float acc = 0.0;
    uint k = 0u;
    for (uint j = 0u; j < MLP_OUTPUTS; j++) {
        if (neural_w[j] > 0.0) {
            k = j;
        }
        acc += neural_w[j];
        if (x < acc) {
            break;
        }
    }
    p = neural_w[k] / g.total;
    return k;
}

uint guide_choose_sector(GuideVertex g, bool pick, float u, uint sector, out float p) {
    if (pick) {
        return guide_pick_sector(g, u, p);
    }
    p = guide_sector_probability(g, sector);
    return sector;
}

// No light choice (GUIDE_LIGHTS is false).
uint guide_choose_light(GuideVertex g, float u, out float p) {
    p = 0.0;
    return 0u;
}

float guide_light_probability(GuideVertex g, uint l) {
    return 0.0;
}

#endif
