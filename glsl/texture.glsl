// Textures as Mitsuba evaluates them (bitmap and checkerboard): the GLSL of
// src/scene/texture.rs, which packs the buffer and is its CPU twin. Needs
// shared.h and bsdf.glsl.
#ifndef QTRACE_TEXTURE_GLSL
#define QTRACE_TEXTURE_GLSL

WORDS(uv_texels, B_UVS)           // 2 per triangle, where a material is textured
WORDS(texture_texels, B_TEXTURES) // headers, then texels (TEXTURE_* in shared.h)
WORDS(attribute_texels, B_ATTRIBUTES) // 3 per triangle, where FEATURE_ATTRIBUTES

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

// Index i of a row or column of n texels, wrapped as the flags say. The
// remainder is taken in floats (exact below 2^24, nudged where the quotient
// rounds across an integer): lavapipe has no vector integer division.
int texture_wrap(int i, int n, uint flags) {
    if ((flags & TEXTURE_CLAMP) != 0u) {
        return clamp(i, 0, n - 1);
    }
    bool mirror = (flags & TEXTURE_MIRROR) != 0u;
    int period = mirror ? 2 * n : n;
    float p = float(period);
    int m = i - period * int(floor(float(i) / p));
    m += m < 0 ? period : m >= period ? -period : 0;
    return mirror && m >= n ? period - m - 1 : m;
}

// An sRGB byte's linear value, from the table the buffer begins with (the
// same floats the CPU twin computes; a lookup costs lavapipe less than pow).
float texture_srgb(uint b) {
    return uintBitsToFloat(FETCH(texture_texels, int(b >> 2u))[b & 3u]);
}

// Texel i of the bitmap with header h.
vec3 texture_texel(uvec4 h, uint i) {
    if ((h.x & 3u) == TEXTURE_BYTES) {
        uint word = FETCH(texture_texels, int(h.y + i / 4u))[i % 4u];
        if ((h.x & TEXTURE_SRGB) != 0u) {
            return vec3(texture_srgb(word & 255u), texture_srgb((word >> 8u) & 255u), texture_srgb((word >> 16u) & 255u));
        }
        return unpackUnorm4x8(word).rgb;
    }
    return uintBitsToFloat(FETCH(texture_texels, int(h.y + i)).rgb);
}

// The four texels of the bitmap with header h around point p (in texels,
// their centres at half integers), wrapped: those at (x, y), (x + 1, y),
// (x, y + 1) and (x + 1, y + 1); f is p's place between them.
uvec4 texture_cell(uvec4 h, vec2 p, out vec2 f) {
    p -= 0.5;
    vec2 base = floor(p);
    f = p - base;
    int w = int(h.z);
    int x0 = texture_wrap(int(base.x), w, h.x);
    int x1 = texture_wrap(int(base.x) + 1, w, h.x);
    int y0 = texture_wrap(int(base.y), int(h.w), h.x) * w;
    int y1 = texture_wrap(int(base.y) + 1, int(h.w), h.x) * w;
    return uvec4(y0 + x0, y0 + x1, y1 + x0, y1 + x1);
}

// Texture t's value at a surface's (u, v).
vec3 texture_eval(uint t, vec2 uv) {
    int at = int(TEXTURE_TABLE_WORDS + TEXTURE_HEADER_WORDS * t);
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
    int w = int(h.z);
    int rows = int(h.w);
    if ((h.x & TEXTURE_NEAREST) != 0u) {
        int x = texture_wrap(int(floor(p.x)), w, h.x);
        int y = texture_wrap(int(floor(p.y)), rows, h.x);
        return texture_texel(h, uint(y * w + x));
    }
    vec2 f;
    uvec4 i = texture_cell(h, p, f);
    vec3 top = mix(texture_texel(h, i.x), texture_texel(h, i.y), f.x);
    vec3 bottom = mix(texture_texel(h, i.z), texture_texel(h, i.w), f.x);
    return mix(top, bottom, f.y);
}

// Texture t's value at barycentric coordinates b of triangle i, where the
// surface's (u, v) is uv: a mesh attribute's from the triangle's corners,
// as Mitsuba interpolates it, times its scale; else texture_eval's.
vec3 texture_at(uint t, uint i, vec2 b, vec2 uv) {
    if ((MATERIAL_FEATURES & FEATURE_ATTRIBUTES) != 0u) {
        uvec4 h = FETCH(texture_texels, int(TEXTURE_TABLE_WORDS + TEXTURE_HEADER_WORDS * t));
        if ((h.x & 3u) == TEXTURE_ATTRIBUTE) {
            // Its place (h.z) among the triangle's attributes (h.w of them).
            int at = int(3u * (i * h.w + h.z));
            vec3 c0 = uintBitsToFloat(FETCH(attribute_texels, at).rgb);
            vec3 c1 = uintBitsToFloat(FETCH(attribute_texels, at + 1).rgb);
            vec3 c2 = uintBitsToFloat(FETCH(attribute_texels, at + 2).rgb);
            return uintBitsToFloat(h.y) * ((1.0 - b.x - b.y) * c0 + b.x * c1 + b.y * c2);
        }
    }
    return texture_eval(t, uv);
}

// The derivatives along a surface's u and v of texture t's luminance at
// (u, v), as its bilinear lookup varies (Mitsuba's eval_1_grad, scaled by
// the resolution after to_uv's transpose, as Mitsuba scales it); 0 for a
// nearest lookup or a checkerboard. The CPU twin is Texture::gradient.
vec2 texture_gradient(uint t, vec2 uv) {
    int at = int(TEXTURE_TABLE_WORDS + TEXTURE_HEADER_WORDS * t);
    uvec4 h = FETCH(texture_texels, at);
    if ((h.x & 3u) == TEXTURE_CHECKERBOARD || (h.x & TEXTURE_NEAREST) != 0u) {
        return vec2(0.0);
    }
    vec3 row0 = uintBitsToFloat(FETCH(texture_texels, at + 1).xyz);
    vec3 row1 = uintBitsToFloat(FETCH(texture_texels, at + 2).xyz);
    vec2 f;
    uvec4 i = texture_cell(h, vec2(dot(row0, vec3(uv, 1.0)), dot(row1, vec3(uv, 1.0))) * vec2(h.zw), f);
    float l00 = luminance(texture_texel(h, i.x));
    float l10 = luminance(texture_texel(h, i.y));
    float l01 = luminance(texture_texel(h, i.z));
    float l11 = luminance(texture_texel(h, i.w));
    vec2 g = vec2(mix(l10 - l00, l11 - l01, f.y), mix(l01 - l00, l11 - l10, f.x));
    return vec2(g.x * row0.x + g.y * row1.x, g.x * row0.y + g.y * row1.y) * vec2(h.zw);
}

// Material m's texture in slot s (TEXTURE_SLOT_*): 1 + its index, or 0.
uint texture_slot(Material m, uint s) {
    return (floatBitsToUint(m.eta.w) >> (TEXTURE_SLOT_BITS * s)) & ((1u << TEXTURE_SLOT_BITS) - 1u);
}

// The BSDF of material m (bsdf_of's) with its textures looked up at
// barycentric coordinates b of triangle i, (u, v) uv there: they
// replace its colour, its second colour (a rough conductor's: its alpha
// across its tangent), its alpha (a principled material's: metallic and
// roughness), rough glass's alpha across its tangent
// (TEXTURE_SLOT_ACROSS, in k.w) and a principled material's weights
// (slots 4-11, in its record). A one-sided material's back stays black.
Bsdf bsdf_textured(Bsdf bsdf, Material m, bool front, uint i, vec2 b, vec2 uv) {
    if (!scene_textured() || ((uint(m.color.w) & MATERIAL_ONE_SIDED) != 0u && !front)) {
        return bsdf;
    }
    uint kind = uint(m.color.w) & (MATERIAL_ONE_SIDED - 1u);
    bool principled = material_principled(kind);
    // Slot s's texture, 1 + its index or 0: 0-2 in eta.w's bits, 3 in k.w
    // (rough glass's, below 0), a principled material's 4-11 in its
    // record's rows 1 and 2 (row 0: its own eta, clearcoat gloss,
    // spec_trans and anisotropic).
    vec4 own = vec4(0.0);
    vec4 tints = vec4(0.0);
    vec4 coats = vec4(0.0);
    // The colour's lookup on its own (the one most textured scenes have),
    // the others' in a loop: lavapipe inlines every call, and a lookup
    // written out for each slot made the trace kernel 10-20% slower on
    // scenes with principled textures, while the colour's in the loop made
    // it 11% slower on a box of textured walls.
    uint color_slot = texture_slot(m, TEXTURE_SLOT_COLOR);
    vec3 color = bsdf.color;
    if (color_slot != 0u) {
        color = texture_at(color_slot - 1u, i, b, uv);
    }
    uint textured = color_slot != 0u ? 1u : 0u;
    for (uint s = 1u; s < 3u; s++) {
        textured |= texture_slot(m, s) != 0u ? 1u << s : 0u;
    }
    if (principled) {
        uint word = uint(m.k.w);
        own = record_row(word, 0u);
        tints = record_row(word, 1u);
        coats = record_row(word, 2u);
        for (int k = 0; k < 4; k++) {
            textured |= (tints[k] != 0.0 ? 16u : 0u) << k | (coats[k] != 0.0 ? 256u : 0u) << k;
        }
    } else if (m.k.w < 0.0 && bsdf_is(bsdf, MATERIAL_DIELECTRIC)) {
        textured |= 1u << TEXTURE_SLOT_ACROSS;
    }
    vec3 second = vec3(0.0);
    vec2 alphas = vec2(0.0); // slots 2 and 3
    // Slots 4-11's numbers: specular tint, sheen, sheen tint, flatness;
    // clearcoat, clearcoat gloss, anisotropic, spec_trans.
    vec4 lobe = vec4(m.eta.gb, m.k.rg);
    vec4 more = vec4(m.k.b, own.y, own.w, own.z);
    uint slots = textured & ~1u;
    while (slots != 0u) {
        int s = findLSB(slots);
        slots &= slots - 1u;
        int k = s & 3;
        float row = s < 8 ? tints[k] : coats[k];
        uint t = s < 3 ? texture_slot(m, uint(s)) : (s == 3 ? uint(-m.k.w) : uint(row));
        vec3 v = texture_at(t - 1u, i, b, uv);
        float value = luminance(v);
        if (s == 1) {
            second = v;
        } else if (s < 4) {
            alphas[s - 2] = value;
        } else if (s < 8) {
            lobe[k] = value;
        } else {
            more[k] = value;
        }
    }
    bool has_second = (textured & 2u) != 0u;
    bool has_alpha = (textured & 4u) != 0u;
    bsdf.color = color;
    if (principled) {
        // Numbers from the second and alpha slots, as Mitsuba reads them:
        // metallic (a thin one's diffuse transmission, whose range Mitsuba
        // halves), and the roughness (not clamped as an alpha is); all
        // enter both sides' lobes.
        bool thin = kind == MATERIAL_PRINCIPLED_THIN;
        vec3 base = (textured & 1u) != 0u ? color : m.color.rgb;
        float r = has_alpha ? alphas.x : m.emission.w;
        float metallic = has_second ? luminance(second) * (thin ? 0.5 : 1.0) : m.eta.x;
        Bsdf p = principled_bsdf(m, front, base, r, metallic, thin, own, more.ywz);
        if (material_principled(p.kind)) {
            // Its lobes' weights (the back of one that refracts is glass).
            p.ior_eta.yz = lobe.xy;
            p.ior_k = vec3(lobe.zw, more.x);
        }
        return p;
    }
    // An isotropic roughness's texture sets both alphas; a rough
    // conductor's second texture, its alpha across its tangent.
    bool isotropic = bsdf.alpha_v == bsdf.alpha;
    bool conductor = bsdf_is(bsdf, MATERIAL_CONDUCTOR);
    if (has_second) {
        if (conductor) {
            bsdf.alpha_v = max(luminance(second), MIN_ALPHA);
        } else {
            bsdf.ior_eta = second;
        }
    }
    if (has_alpha) {
        bsdf.alpha = max(alphas.x, MIN_ALPHA);
        bsdf.alpha_v = isotropic && !(conductor && has_second) ? bsdf.alpha : bsdf.alpha_v;
    }
    if ((textured & (1u << TEXTURE_SLOT_ACROSS)) != 0u) {
        bsdf.alpha_v = max(alphas.y, MIN_ALPHA);
    }
    return bsdf;
}

// What emitting material m sends from triangle i at barycentric b: its
// radiance texture's value there (the colour slot of an emitter; a mesh
// attribute's, interpolated), else its radiance.
vec3 emitted(Material m, uint i, vec2 b) {
    uint t = texture_slot(m, TEXTURE_SLOT_COLOR);
    if ((MATERIAL_FEATURES & FEATURE_TEXTURED_LIGHTS) == 0u || t == 0u) {
        return m.emission.rgb;
    }
    b = clamp(b, vec2(0.0), vec2(1.0));
    return texture_at(t - 1u, i, b, surface_uv(i, b));
}

#endif
