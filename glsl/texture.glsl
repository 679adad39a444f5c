// Textures as Mitsuba evaluates them (bitmap and checkerboard): the GLSL of
// src/scene/texture.rs, which packs the buffer and is its CPU twin. Needs
// shared.h and bsdf.glsl.
#ifndef QTRACE_TEXTURE_GLSL
#define QTRACE_TEXTURE_GLSL

WORDS(uv_texels, B_UVS)           // 2 per triangle, where a material is textured
WORDS(texture_texels, B_TEXTURES) // headers, then texels (TEXTURE_* in shared.h)

// Whether some material of the scene is textured; a constant, so that the
// kernels of the others carry no texture code.
bool scene_textured() {
    return (MATERIAL_FEATURES & FEATURE_TEXTURES) != 0u;
}

// Texture coordinates of triangle i at barycentric coordinates b (along
// its e1 and e2).
vec2 surface_uv(uint i, vec2 b) {
    uvec4 p = FETCH(uv_texels, int(2u * i));
    uvec4 q = FETCH(uv_texels, int(2u * i + 1u));
    return (1.0 - b.x - b.y) * uintBitsToFloat(p.xy) + b.x * uintBitsToFloat(p.zw) + b.y * uintBitsToFloat(q.xy);
}

// Index i of a row or column of n texels, wrapped as the flags say (the
// divisions only of non-negative numbers, which GLSL defines).
int texture_wrap(int i, int n, uint flags) {
    if ((flags & TEXTURE_CLAMP) != 0u) {
        return clamp(i, 0, n - 1);
    }
    bool mirror = (flags & TEXTURE_MIRROR) != 0u;
    int period = mirror ? 2 * n : n;
    int m = i >= 0 ? i % period : period - 1 - (-i - 1) % period;
    return mirror && m >= n ? period - m - 1 : m;
}

vec3 srgb_to_linear(vec3 c) {
    return mix(c / 12.92, pow((c + 0.055) / 1.055, vec3(2.4)), greaterThan(c, vec3(0.04045)));
}

// Texel (x, y), wrapped, of the bitmap with header h.
vec3 texture_texel(uvec4 h, int x, int y) {
    uint i = uint(texture_wrap(y, int(h.w), h.x)) * h.z + uint(texture_wrap(x, int(h.z), h.x));
    if ((h.x & 3u) == TEXTURE_BYTES) {
        uvec4 word = FETCH(texture_texels, int(h.y + i / 4u));
        vec3 c = unpackUnorm4x8(word[i % 4u]).rgb;
        return (h.x & TEXTURE_SRGB) != 0u ? srgb_to_linear(c) : c;
    }
    return uintBitsToFloat(FETCH(texture_texels, int(h.y + i)).rgb);
}

// Texture t's value at a surface's (u, v).
vec3 texture_eval(uint t, vec2 uv) {
    int at = int(TEXTURE_HEADER_WORDS * t);
    uvec4 h = FETCH(texture_texels, at);
    vec3 row0 = uintBitsToFloat(FETCH(texture_texels, at + 1).xyz);
    vec3 row1 = uintBitsToFloat(FETCH(texture_texels, at + 2).xyz);
    uv = vec2(dot(row0, vec3(uv, 1.0)), dot(row1, vec3(uv, 1.0)));
    if ((h.x & 3u) == TEXTURE_CHECKERBOARD) {
        vec2 f = uv - floor(uv);
        uint second = (f.x > 0.5) == (f.y > 0.5) ? 0u : 1u;
        return uintBitsToFloat(FETCH(texture_texels, int(h.y + second)).rgb);
    }
    vec2 p = uv * vec2(h.zw);
    if ((h.x & TEXTURE_NEAREST) != 0u) {
        return texture_texel(h, int(floor(p.x)), int(floor(p.y)));
    }
    p -= 0.5;
    vec2 base = floor(p);
    vec2 w = p - base;
    int x = int(base.x);
    int y = int(base.y);
    vec3 top = mix(texture_texel(h, x, y), texture_texel(h, x + 1, y), w.x);
    vec3 bottom = mix(texture_texel(h, x, y + 1), texture_texel(h, x + 1, y + 1), w.x);
    return mix(top, bottom, w.y);
}

// Material m's texture in slot s (TEXTURE_SLOT_*): 1 + its index, or 0.
uint texture_slot(Material m, uint s) {
    return (floatBitsToUint(m.eta.w) >> (TEXTURE_SLOT_BITS * s)) & ((1u << TEXTURE_SLOT_BITS) - 1u);
}

// The BSDF of material m (bsdf_of's) with its textures looked up at uv: they
// replace its colour, its second colour and its alpha. A one-sided
// material's back stays black.
Bsdf bsdf_textured(Bsdf bsdf, Material m, bool front, vec2 uv) {
    if (!scene_textured() || ((uint(m.color.w) & MATERIAL_ONE_SIDED) != 0u && !front)) {
        return bsdf;
    }
    uint color = texture_slot(m, TEXTURE_SLOT_COLOR);
    uint second = texture_slot(m, TEXTURE_SLOT_SECOND);
    uint alpha = texture_slot(m, TEXTURE_SLOT_ALPHA);
    if (color != 0u) {
        bsdf.color = texture_eval(color - 1u, uv);
    }
    if (second != 0u) {
        bsdf.ior_eta = texture_eval(second - 1u, uv);
    }
    if (alpha != 0u) {
        bsdf.alpha = max(luminance(texture_eval(alpha - 1u, uv)), MIN_ALPHA);
    }
    return bsdf;
}

#endif
