// Light from the sky: the environment map as Mitsuba evaluates it, and the
// distribution NEE draws its directions from. src/scene/environment.rs
// packs the buffer and is the CPU twin. Needs shared.h.
#ifndef QTRACE_ENVIRONMENT_GLSL
#define QTRACE_ENVIRONMENT_GLSL

WORDS(environment_texels, B_ENVIRONMENT)

// Whether the scene has an environment (SKY_*); a constant, so that the
// kernels of scenes without one carry none of this code, and those of the
// others only the code of its texels' layout.
layout(constant_id = CONSTANT_ENVIRONMENT) const uint SKY = SKY_TEXEL_WORDS;
const bool ENVIRONMENT = SKY != SKY_NONE;

// World direction d in the map's frame.
vec3 environment_local(vec3 d) {
    return vec3(dot(uintBitsToFloat(FETCH(environment_texels, 1).xyz), d),
                dot(uintBitsToFloat(FETCH(environment_texels, 2).xyz), d),
                dot(uintBitsToFloat(FETCH(environment_texels, 3).xyz), d));
}

// Data coordinates of world direction d: columns from texel centres
// (wrapping), rows from the top row at the map's +y pole to the bottom one.
vec2 environment_data(vec3 d, uvec4 h) {
    vec3 l = environment_local(d);
    float u = atan(l.x, -l.z) * (0.5 * INV_PI) - 0.5 / float(h.x);
    // atan rather than acos: Mesa's acos is a short polynomial, ~3e-4 off.
    float v = atan(length(l.xz), l.y) * INV_PI;
    return vec2((u - floor(u)) * float(h.x), v * float(h.y - 1u));
}

// The cell between texels (column, row) a data point lies in.
uvec2 environment_texel_cell(vec2 p, uvec4 h) {
    return min(uvec2(max(p, vec2(0.0))), uvec2(h.x - 1u, h.y - 2u));
}

// NEE's cell holding the cell between texels c: blocks of (block width,
// block height), as many columns as the third header row's w says.
uint environment_cell(uvec2 c) {
    uint bw = FETCH(environment_texels, 1).w;
    uint bh = FETCH(environment_texels, 2).w;
    uint columns = FETCH(environment_texels, 3).w;
    return (c.y / bh) * columns + c.x / bw;
}

// Texel (x, y): a word each, or (SKY_DENSE) three floats from where 3 i
// falls (four texels fill three words; a spare word follows the last).
vec3 environment_texel(uint x, uint y, uvec4 h) {
    uint i = y * h.x + x % h.x;
    if (SKY != SKY_DENSE) {
        return uintBitsToFloat(FETCH(environment_texels, int(ENVIRONMENT_HEADER_WORDS + i)).rgb);
    }
    uint f = 3u * i;
    int at = int(ENVIRONMENT_HEADER_WORDS + f / 4u);
    uvec4 a = FETCH(environment_texels, at);
    uvec4 b = FETCH(environment_texels, at + 1);
    uint k = f & 3u;
    uvec3 bits = k == 0u ? a.xyz : k == 1u ? a.yzw : k == 2u ? uvec3(a.zw, b.x) : uvec3(a.w, b.xy);
    return uintBitsToFloat(bits);
}

vec4 sky_word(int i) {
    return uintBitsToFloat(FETCH(environment_texels, ENVIRONMENT_HEADER_WORDS + i));
}

// Mitsuba's sunsky at unit direction l of the map's frame (y up): the
// Hosek-Wilkie sky and the sun's disk, from the words
// src/scene/mitsuba/sunsky.rs writes (sky_model in
// src/scene/environment.rs, the CPU twin, says what each holds).
vec3 sky_model(vec3 l) {
    if (l.y < 0.0) {
        return vec3(0.0);
    }
    vec4 sun = sky_word(0);
    float cos_gamma = clamp(dot(l, sun.xyz), -1.0, 1.0);
    float sin_gamma = length(cross(l, sun.xyz));
    // atan rather than acos: Mesa's acos is a short polynomial.
    float gamma = atan(sin_gamma, dot(l, sun.xyz));
    vec3 radiance;
    for (int c = 0; c < 3; c++) {
        vec4 a = sky_word(2 + 3 * c);
        vec4 b = sky_word(3 + 3 * c);
        vec4 e = sky_word(4 + 3 * c);
        float c1 = 1.0 + a.x * exp(a.y / (l.y + 0.01));
        float q = 1.0 + e.x * e.x - 2.0 * e.x * cos_gamma;
        float chi = (1.0 + cos_gamma * cos_gamma) / (q * sqrt(q));
        float c2 = a.z + a.w * exp(b.x * gamma) + b.y * cos_gamma * cos_gamma + b.z * chi +
                   b.w * sqrt(l.y);
        radiance[c] = c1 * c2 * e.y;
    }
    if (sin_gamma <= sun.w && cos_gamma > 0.0) {
        vec4 m = sky_word(1);
        if (m.y == 0.0) {
            radiance += sky_word(11).rgb;
        } else {
            float elevation = atan(l.y, length(l.xz));
            int segment = min(int(pow(max(2.0 * elevation * INV_PI, 0.0), 1.0 / 3.0) * 45.0), 44);
            float s = float(segment) / 45.0;
            float x = elevation - 0.5 * PI * s * s * s;
            float ratio = sin_gamma / m.x;
            float cos_psi = sqrt(max(1.0 - ratio * ratio, 0.0));
            int first = segment * 72;
            for (int c = 0; c < 3; c++) {
                float x_k = 1.0;
                for (int k = 0; k < 4; k++) {
                    float psi_j = 1.0;
                    for (int j = 0; j < 6; j++) {
                        int i = first + (c * 4 + k) * 6 + j;
                        radiance[c] += x_k * psi_j * sky_word(12 + i / 4)[i % 4];
                        psi_j *= cos_psi;
                    }
                    x_k *= x;
                }
            }
        }
    }
    return radiance;
}

// Radiance arriving from world direction d (a unit vector).
vec3 environment_eval(vec3 d) {
    if (SKY == SKY_MODEL) {
        return sky_model(environment_local(d));
    }
    uvec4 h = FETCH(environment_texels, 0);
    vec2 p = environment_data(d, h);
    uvec2 c = environment_texel_cell(p, h);
    vec2 f = p - vec2(c);
    vec3 top = mix(environment_texel(c.x, c.y, h), environment_texel(c.x + 1u, c.y, h), f.x);
    vec3 bottom = mix(environment_texel(c.x, c.y + 1u, h), environment_texel(c.x + 1u, c.y + 1u, h), f.x);
    return mix(top, bottom, f.y);
}

// The solid-angle density NEE draws direction d with, picking the sky's
// parts by power, and the part d lies in.
float environment_pdf(vec3 d, out uint part) {
    uvec4 h = FETCH(environment_texels, 0);
    uint c = environment_cell(environment_texel_cell(environment_data(d, h), h));
    uvec4 cell = FETCH(environment_texels, int(h.w + c));
    part = cell.y;
    return uintBitsToFloat(cell.x);
}

// How many of NEE's lights the sky is (1 or 2), and part k's share of its power.
uint environment_parts() {
    return FETCH(environment_texels, 4).y == 0u ? 1u : 2u;
}

float environment_share(uint k) {
    return uintBitsToFloat(FETCH(environment_texels, 4)[2u + k]);
}

// A direction of part `part` for NEE from four uniform numbers (the cell,
// its alias, the point in it: uniform in azimuth and cos theta), with the
// density environment_pdf gives it.
vec3 environment_sample(vec4 u, uint part, out float pdf) {
    uvec4 h = FETCH(environment_texels, 0);
    uvec4 parts = FETCH(environment_texels, 4);
    uint n = part == 0u ? parts.x : parts.y;
    uint table = h.w + h.z + (part == 0u ? 0u : parts.x);
    uint slot = min(uint(u.x * float(n)), n - 1u);
    uvec4 entry = FETCH(environment_texels, int(table + slot));
    if (u.y >= uintBitsToFloat(entry.x)) {
        entry = FETCH(environment_texels, int(table + entry.y));
    }
    uint c = entry.z;
    pdf = uintBitsToFloat(entry.w);
    uint bw = FETCH(environment_texels, 1).w;
    uint bh = FETCH(environment_texels, 2).w;
    uint columns = FETCH(environment_texels, 3).w;
    // The block's columns and rows of cells between texels.
    uint x0 = (c % columns) * bw;
    uint y0 = (c / columns) * bh;
    float x1 = float(min(x0 + bw, h.x));
    float y1 = float(min(y0 + bh, h.y - 1u));
    float rows = float(h.y - 1u);
    float x = mix(float(x0), x1, u.z);
    float phi = 2.0 * PI * ((x + 0.5) / float(h.x));
    float c0 = cos(PI * float(y0) / rows);
    float c1 = cos(PI * y1 / rows);
    float cos_theta = c0 + (c1 - c0) * u.w;
    float sin_theta = sqrt(max(1.0 - cos_theta * cos_theta, 0.0));
    vec3 l = vec3(sin(phi) * sin_theta, cos_theta, -cos(phi) * sin_theta);
    // to_local is a rotation: its transpose takes l back to the world.
    return uintBitsToFloat(FETCH(environment_texels, 1).xyz) * l.x +
           uintBitsToFloat(FETCH(environment_texels, 2).xyz) * l.y +
           uintBitsToFloat(FETCH(environment_texels, 3).xyz) * l.z;
}

#endif
