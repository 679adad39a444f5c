// The BSDF seam: all the trace kernel and the guides know of how a material
// scatters. Directions are local: z is the shading normal on the side the
// path arrives from, wo points back along the path. src/bsdf.rs holds the
// CPU twin. Needs shared.h, sampling.glsl and the `params` push
// constants (for FLAG_UNIFORM).
#ifndef QTRACE_BSDF_GLSL
#define QTRACE_BSDF_GLSL

float luminance(vec3 c) {
    return dot(c, vec3(0.2126, 0.7152, 0.0722));
}

// The smallest GGX alpha a rough conductor keeps (MIN_ALPHA in src/bsdf.rs).
#define MIN_ALPHA 1e-4

// False where the scene's materials are all diffuse: the kernel is then built
// without the other lobes, whose code costs on lavapipe even when no lane
// takes it (measured: 10-40% of a trace pass on the diffuse scenes).
layout(constant_id = CONSTANT_NON_DIFFUSE) const bool NON_DIFFUSE = true;
// The lobes' options some material of the scene uses (MATERIAL_BECKMANN,
// MATERIAL_FRESNEL, FEATURE_*); the code of the others is left out.
layout(constant_id = CONSTANT_MATERIAL_FEATURES) const uint MATERIAL_FEATURES =
    MATERIAL_BECKMANN | MATERIAL_FRESNEL | MATERIAL_NONLINEAR | FEATURE_PLASTIC | FEATURE_ROUGH_GLASS |
    FEATURE_ROUGH_PLASTIC | FEATURE_TEXTURES | FEATURE_PRINCIPLED | FEATURE_ANISOTROPIC | FEATURE_PRINCIPLED_THIN |
    FEATURE_PROJECTORS;

// A material's scattering at a surface point, seen from one side
// (docs/scenes.md).
struct Bsdf {
    uint kind;   // MATERIAL_*
    vec3 color;  // Kd, Ks, Tf, or a principled BSDF's base colour
    float alpha; // conductor, dielectric, plastic: alpha, 0 when smooth; principled: roughness
    float eta;   // dielectric: index beyond the surface / index on the path's side;
                 // plastic: its coat's relative index; principled: its dielectric's
    uint flags;  // MATERIAL_BECKMANN; conductor: MATERIAL_FRESNEL; plastic: MATERIAL_NONLINEAR;
                 // principled: its spec_trans (float bits)
    vec3 ior_eta; // conductor with MATERIAL_FRESNEL: its complex index eta + i k;
    vec3 ior_k;   // plastic: specular reflectance, and (internal reflectance, specular weight, alpha);
                  // glass, rough glass: its reflection's tint (ior_eta);
                  // principled: (metallic, specular tint, sheen), (sheen tint, flatness, clearcoat);
                  // thin principled: metallic's place holds its diffuse transmission
    uint table;  // rough plastic: the word its transmittance table begins at;
                 // principled: its clearcoat gloss (float bits)
    float alpha_v; // rough conductor, rough glass: alpha along the tangent's normal
                   // (alpha is along the tangent); principled: `anisotropic`
    vec2 tangent;  // where anisotropic: the surface's tangent (Mitsuba's dp/du)
                   // in the local frame, set by the trace kernel
};

// A float of the words after the materials (a rough plastic's table, a
// principled material's record). Kernels without the scene's buffers meet
// no material.
#ifdef QTRACE_SCENE_GLSL
float rough_table(uint word, uint i) {
    return uintBitsToFloat(FETCH(material_texels, int(word + i / 4u))[i % 4u]);
}
// Its floats 4 row to 4 row + 3, in one read.
vec4 record_row(uint word, uint row) {
    return uintBitsToFloat(FETCH(material_texels, int(word + row)));
}
#else
float rough_table(uint word, uint i) {
    return 1.0;
}
vec4 record_row(uint word, uint row) {
    return vec4(1.0);
}
#endif

Bsdf bsdf_diffuse(vec3 albedo) {
    return Bsdf(MATERIAL_DIFFUSE, albedo, 0.0, 1.0, 0u, vec3(0.0), vec3(0.0), 0u, 0.0, vec2(1.0, 0.0));
}

// A principled BSDF's GGX alphas along its tangent and across it, from its
// roughness r and `anisotropic` (Burley's, as Mitsuba maps them).
vec2 principled_alphas(float r, float anisotropic) {
    float aspect = sqrt(1.0 - 0.9 * anisotropic);
    return max(vec2(r * r / aspect, r * r * aspect), vec2(1e-3));
}

// A principled BSDF's spec_trans, which its `flags` hold.
float principled_spec_trans(Bsdf bsdf) {
    return uintBitsToFloat(bsdf.flags);
}

// Principled material m's BSDF of base colour `base`, roughness r and
// metallic weight `metallic` (its own, or its textures' values): on the
// front its own lobes; on the back, as Mitsuba's, its dielectric alone,
// weighted by the refracting part's weight: rough glass of the specular
// lobe's alpha, its transmission tinted by the base colour's square root
// (black where metallic is 1). Without spec_trans its back is its front's
// lobes (inside twosided; a one-sided material's is black before this). A
// thin one (`thin`, metallic its diffuse transmission) is the same on both
// sides. `own`: its record's first row (eta, clearcoat gloss, spec_trans,
// anisotropic); `extra`: the last three there (its own, or its textures').
Bsdf principled_bsdf(Material m, bool front, vec3 base, float r, float metallic, bool thin, vec4 own, vec3 extra) {
    float eta = own.x;
    float spec_trans = extra.y;
    float w = (1.0 - metallic) * spec_trans;
    if (!front && !thin && spec_trans <= 0.0 && own.z > 0.0) {
        // Where the texture of one that lets light through says opaque:
        // black from behind, as in Mitsuba.
        return bsdf_diffuse(vec3(0.0));
    }
    if (front || spec_trans <= 0.0 || thin) {
        return Bsdf(thin ? MATERIAL_PRINCIPLED_THIN : MATERIAL_PRINCIPLED, base, r, eta, floatBitsToUint(spec_trans),
                    vec3(metallic, m.eta.gb), m.k.rgb, floatBitsToUint(extra.x), extra.z, vec2(1.0, 0.0));
    }
    vec2 alpha = principled_alphas(r, extra.z);
    return Bsdf(MATERIAL_DIELECTRIC, sqrt(base) * w, alpha.x, 1.0 / eta, 0u, vec3(w), vec3(0.0), 0u, alpha.y,
                vec2(1.0, 0.0));
}

// Whether a material's kind is a principled one, thin or not; a constant
// false where the scene has none.
bool material_principled(uint kind) {
    return (MATERIAL_FEATURES & FEATURE_PRINCIPLED) != 0u &&
           (kind == MATERIAL_PRINCIPLED || ((MATERIAL_FEATURES & FEATURE_PRINCIPLED_THIN) != 0u && kind == MATERIAL_PRINCIPLED_THIN));
}

// The BSDF of material m for a path arriving on the side the triangle's
// normal faces (front) or on the other.
Bsdf bsdf_of(Material m, bool front) {
    uint code = uint(m.color.w);
    uint kind = code & (MATERIAL_ONE_SIDED - 1u);
    float p = m.emission.w;
    float rough = kind == MATERIAL_CONDUCTOR ? p : kind == MATERIAL_DIELECTRIC || kind == MATERIAL_PLASTIC ? m.k.z : 0.0;
    float alpha = rough > 0.0 ? max(rough, MIN_ALPHA) : 0.0;
    bool black = (code & MATERIAL_ONE_SIDED) != 0u && !front;
    vec3 color = black ? vec3(0.0) : m.color.rgb;
    // A plastic's coat, and a thin sheet, look the same from either side.
    float eta = front || kind == MATERIAL_PLASTIC || kind == MATERIAL_THIN ? p : 1.0 / p;
    vec3 specular = black ? vec3(0.0) : m.eta.rgb;
    if (material_principled(kind)) {
        // Its specular lobe does not scale with the base colour: a one-sided
        // one's back is a black diffuse lobe.
        vec4 own = record_row(uint(m.k.w), 0u);
        return black ? bsdf_diffuse(vec3(0.0))
                     : principled_bsdf(m, front, color, p, m.eta.x, kind == MATERIAL_PRINCIPLED_THIN, own, own.yzw);
    }
    // A rough conductor's or rough glass's alpha across its tangent, where
    // anisotropic, in k.w (rough glass's texture there is below 0:
    // bsdf_textured reads it).
    bool across = (MATERIAL_FEATURES & FEATURE_ANISOTROPIC) != 0u && alpha > 0.0 &&
                  (kind == MATERIAL_CONDUCTOR || kind == MATERIAL_DIELECTRIC) && m.k.w > 0.0;
    return Bsdf(kind, color, alpha, eta, code & (MATERIAL_BECKMANN | MATERIAL_FRESNEL | MATERIAL_NONLINEAR),
                kind == MATERIAL_PLASTIC || kind == MATERIAL_THIN ? specular : m.eta.rgb, m.k.rgb, uint(max(m.k.w, 0.0)),
                across ? max(m.k.w, MIN_ALPHA) : alpha, vec2(1.0, 0.0));
}

// Whether the BSDF is of kind MATERIAL_*; a constant where NON_DIFFUSE is false.
bool bsdf_is(Bsdf bsdf, uint kind) {
    return (NON_DIFFUSE ? bsdf.kind : MATERIAL_DIFFUSE) == kind;
}

// Whether the BSDF is a plastic; a constant false where the scene has none.
bool bsdf_plastic(Bsdf bsdf) {
    return (MATERIAL_FEATURES & FEATURE_PLASTIC) != 0u && bsdf_is(bsdf, MATERIAL_PLASTIC);
}

// Whether the BSDF's roughness differs along its tangent and across it
// (then the trace kernel sets its tangent); a constant false where the scene
// has no such BSDF.
bool bsdf_anisotropic(Bsdf bsdf) {
    return (MATERIAL_FEATURES & FEATURE_ANISOTROPIC) != 0u &&
           (material_principled(bsdf.kind) ? bsdf.alpha_v > 0.0 : bsdf.alpha_v != bsdf.alpha);
}

// A local direction in the frame of the BSDF's tangent, and back.
vec3 to_tangent(Bsdf bsdf, vec3 w) {
    return vec3(bsdf.tangent.x * w.x + bsdf.tangent.y * w.y, bsdf.tangent.x * w.y - bsdf.tangent.y * w.x, w.z);
}

vec3 from_tangent(Bsdf bsdf, vec3 w) {
    return vec3(bsdf.tangent.x * w.x - bsdf.tangent.y * w.y, bsdf.tangent.y * w.x + bsdf.tangent.x * w.y, w.z);
}

// Whether the BSDF is a principled one; a constant false where the scene has none.
bool bsdf_principled(Bsdf bsdf) {
    return (MATERIAL_FEATURES & FEATURE_PRINCIPLED) != 0u && bsdf_is(bsdf, MATERIAL_PRINCIPLED);
}

// Whether the BSDF is a rough glass; a constant false where the scene has none.
bool bsdf_rough_glass(Bsdf bsdf) {
    return (MATERIAL_FEATURES & FEATURE_ROUGH_GLASS) != 0u && bsdf_is(bsdf, MATERIAL_DIELECTRIC) && bsdf.alpha > 0.0;
}

// Whether the BSDF is a rough plastic; a constant false where the scene has none.
bool bsdf_rough_plastic(Bsdf bsdf) {
    return (MATERIAL_FEATURES & FEATURE_ROUGH_PLASTIC) != 0u && bsdf_plastic(bsdf) && bsdf.alpha > 0.0;
}

// Whether the BSDF is a plastic under a smooth coat, whose coat is a delta lobe.
bool bsdf_smooth_plastic(Bsdf bsdf) {
    return bsdf_plastic(bsdf) && !bsdf_rough_plastic(bsdf);
}

// Whether the BSDF is a delta distribution (a mirror, smooth glass): such a
// vertex samples with bsdf_sample_delta and skips NEE and guiding.
bool bsdf_is_delta(Bsdf bsdf) {
    return (bsdf_is(bsdf, MATERIAL_DIELECTRIC) && !bsdf_rough_glass(bsdf)) || bsdf_is(bsdf, MATERIAL_THIN) ||
           (bsdf_is(bsdf, MATERIAL_CONDUCTOR) && bsdf.alpha == 0.0);
}

bool principled_transmits(Bsdf bsdf);

// Whether the BSDF is a thin principled one; a constant false where the
// scene has none.
bool bsdf_principled_thin(Bsdf bsdf) {
    return (MATERIAL_FEATURES & FEATURE_PRINCIPLED_THIN) != 0u && bsdf_is(bsdf, MATERIAL_PRINCIPLED_THIN);
}

// Whether a thin principled BSDF lets light through (spec_trans, or a
// diffuse transmission).
bool thin_transmits(Bsdf bsdf) {
    return bsdf_principled_thin(bsdf) && (principled_spec_trans(bsdf) > 0.0 || bsdf.ior_eta.x > 0.0);
}

// Whether the BSDF sends light through the surface without a delta lobe
// (rough glass, a principled BSDF's refraction): its directions below the
// surface are sampled, evaluated and reached by NEE, and the guides sample
// there from the tables of both sides (guide.glsl's Mixture).
bool bsdf_transmits(Bsdf bsdf) {
    return bsdf_rough_glass(bsdf) || principled_transmits(bsdf) || thin_transmits(bsdf);
}

// The microfacet distributions in the frame of the surface's tangent:
// alpha.x along it, alpha.y across (equal where isotropic). GGX's normal
// distribution, written without the cancellation of 1 - cos^2 so that
// narrow lobes keep their precision.
float ggx_d(vec2 alpha, vec3 h) {
    float a2 = alpha.x * alpha.y;
    float t = h.x * h.x * (alpha.y / alpha.x) + h.y * h.y * (alpha.x / alpha.y) + a2 * h.z * h.z;
    return a2 / (PI * t * t);
}

// Smith's masking of GGX for a direction above the surface.
float ggx_g1(vec2 alpha, vec3 w) {
    vec2 s = alpha * w.xy;
    return 2.0 * w.z / (w.z + sqrt(dot(s, s) + w.z * w.z));
}

// Beckmann's normal distribution.
float beckmann_d(vec2 alpha, vec3 h) {
    float z2 = h.z * h.z;
    vec2 s = h.xy / alpha;
    return exp(-dot(s, s) / z2) / (PI * alpha.x * alpha.y * z2 * z2);
}

// Smith's masking of Beckmann, in Walter et al.'s rational fit (2007), as
// Mitsuba 3.9.1 has it.
float beckmann_g1(vec2 alpha, vec3 w) {
    vec2 s = alpha * w.xy;
    float tan2 = dot(s, s) / (w.z * w.z);
    float a = inversesqrt(max(tan2, 1e-30));
    float g = (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a);
    return a >= 1.6 ? 1.0 : g;
}

// The alphas of a microfacet lobe: along the tangent and across it.
vec2 microfacet_alphas(Bsdf bsdf) {
    return (MATERIAL_FEATURES & FEATURE_ANISOTROPIC) != 0u ? vec2(bsdf.alpha, bsdf.alpha_v) : vec2(bsdf.alpha);
}

bool bsdf_beckmann(Bsdf bsdf) {
    return (MATERIAL_FEATURES & MATERIAL_BECKMANN) != 0u && (bsdf.flags & MATERIAL_BECKMANN) != 0u;
}

float microfacet_d(Bsdf bsdf, vec3 h) {
    return bsdf_beckmann(bsdf) ? beckmann_d(microfacet_alphas(bsdf), h) : ggx_d(microfacet_alphas(bsdf), h);
}

// Smith's masking for a direction above the surface (rough glass passes
// one below mirrored).
float microfacet_g1(Bsdf bsdf, vec3 w) {
    return bsdf_beckmann(bsdf) ? beckmann_g1(microfacet_alphas(bsdf), w) : ggx_g1(microfacet_alphas(bsdf), w);
}

// D(h) G1(wo) G1(wi) of a microfacet lobe, wi on either side; over
// 4 wo.z, a reflection's f cos without its Fresnel term.
float microfacet_dg(Bsdf bsdf, vec3 wo, vec3 wi, vec3 h) {
    return microfacet_d(bsdf, h) * microfacet_g1(bsdf, wo) * microfacet_g1(bsdf, vec3(wi.xy, abs(wi.z)));
}

// A microfacet normal for a path arriving from wo: GGX draws the normals wo
// sees (spherical caps, Dupuy & Benyoub 2023), Beckmann all of them by
// D(m) m.z (its slopes are Gaussian, scaled by the alphas).
vec3 microfacet_sample(Bsdf bsdf, vec3 wo, vec2 u) {
    vec2 alpha = microfacet_alphas(bsdf);
    if (bsdf_beckmann(bsdf)) {
        float r = sqrt(-log(max(1.0 - u.x, 1e-30)));
        float phi = 2.0 * PI * u.y;
        return normalize(vec3(alpha * (r * vec2(cos(phi), sin(phi))), 1.0));
    }
    vec3 wh = normalize(vec3(alpha * wo.xy, wo.z));
    float phi = 2.0 * PI * u.x;
    float z = (1.0 - u.y) * (1.0 + wh.z) - wh.z;
    float s = sqrt(max(1.0 - z * z, 0.0));
    vec3 h = vec3(s * cos(phi), s * sin(phi), z) + wh;
    return normalize(vec3(alpha * h.xy, max(h.z, 0.0)));
}

// The density of microfacet_sample drawing m: GGX's visible normals
// G1(wo) (wo.m) D(m) / wo.z, Beckmann's D(m) m.z.
float microfacet_sample_pdf(Bsdf bsdf, vec3 wo, vec3 m) {
    vec2 alpha = microfacet_alphas(bsdf);
    return bsdf_beckmann(bsdf) ? beckmann_d(alpha, m) * m.z
                               : ggx_g1(alpha, wo) * max(dot(wo, m), 0.0) * ggx_d(alpha, m) / wo.z;
}

// wo mirrored about m; below the horizon (pdf 0) where wo does not see m.
vec3 microfacet_reflect(vec3 wo, vec3 m) {
    return dot(wo, m) > 0.0 ? 2.0 * dot(wo, m) * m - wo : vec3(0.0, 0.0, -1.0);
}

// A rough plastic's coat transmittance at cos, from its table (linear, as
// Mitsuba's lerp_gather).
float rough_transmittance(Bsdf bsdf, float cos) {
    float x = clamp(cos, 0.0, 1.0) * float(ROUGH_TABLE_SIZE - 1);
    uint i = min(uint(x), uint(ROUGH_TABLE_SIZE - 2));
    return mix(rough_table(bsdf.table, i), rough_table(bsdf.table, i + 1u), x - float(i));
}

// A rough plastic's probability of sampling its coat rather than its base
// (Mitsuba's choice: the coat's reflectance at wo against the base's
// transmittance, weighted by their mean colours).
float rough_coat_share(Bsdf bsdf, vec3 wo) {
    float t = rough_transmittance(bsdf, wo.z);
    float w = bsdf.ior_k.y;
    float s = (1.0 - t) * w;
    float d = t * (1.0 - w);
    return s + d > 0.0 ? s / (s + d) : 0.0;
}

// The microfacet normal (on wo's side) that takes wo to wi across a rough
// interface of relative index eta, in xyz, and in w 1 for a reflection, 0
// for a refraction; w -1 where wo or wi sees that normal from behind
// (Smith's masking 0).
vec4 rough_glass_half(vec3 wo, vec3 wi, float eta) {
    bool reflect = wi.z > 0.0;
    vec3 h = reflect ? wo + wi : wo + eta * wi;
    h = h.z < 0.0 ? -h : h;
    float l = length(h);
    if (wo.z <= 0.0 || wi.z == 0.0 || !(l > 0.0)) {
        return vec4(0.0, 0.0, 1.0, -1.0);
    }
    h /= l;
    bool ok = dot(wo, h) > 0.0 && (dot(wi, h) > 0.0) == reflect;
    return vec4(h, ok ? (reflect ? 1.0 : 0.0) : -1.0);
}

// A refraction from wo to wi about microfacet normal h across relative
// index eta (Walter et al.): the Jacobian of h over wi, its density's
// factor, eta^2 |wi.h| / (wo.h + eta wi.h)^2. A rough interface's f cos
// there is (1 - F) D G |wo.h| / (eta^2 wo.z) times it.
float refraction_jacobian(vec3 wo, vec3 wi, vec3 h, float eta) {
    float denom = dot(wo, h) + eta * dot(wi, h);
    return eta * eta * abs(dot(wi, h)) / (denom * denom);
}

// Fresnel reflectance of a conductor of complex index eta + i k for
// cos_i > 0 (exact, unpolarised).
vec3 fresnel_conductor(float cos_i, vec3 eta, vec3 k) {
    float c2 = cos_i * cos_i;
    float s2 = 1.0 - c2;
    vec3 t1 = eta * eta - k * k - s2;
    vec3 a2b2 = sqrt(max(t1 * t1 + 4.0 * k * k * eta * eta, 0.0));
    vec3 a = sqrt(max(0.5 * (a2b2 + t1), 0.0));
    vec3 t2 = a2b2 + c2;
    vec3 t3 = 2.0 * cos_i * a;
    vec3 rs = (t2 - t3) / (t2 + t3);
    vec3 t4 = a2b2 * c2 + s2 * s2;
    vec3 t5 = t3 * s2;
    vec3 rp = rs * (t4 - t5) / (t4 + t5);
    return 0.5 * (rs + rp);
}

// A conductor's reflectance at cos between the path and the microfacet
// normal: Ks, times the Fresnel term where it has one.
vec3 conductor_reflectance(Bsdf bsdf, float cos) {
    bool fresnel = (MATERIAL_FEATURES & MATERIAL_FRESNEL) != 0u && (bsdf.flags & MATERIAL_FRESNEL) != 0u;
    return fresnel ? bsdf.color * fresnel_conductor(cos, bsdf.ior_eta, bsdf.ior_k) : bsdf.color;
}

// Exact Fresnel reflectance of a smooth dielectric for cos_i > 0 and
// eta = eta_t / eta_i; sets cos_t (0 under total internal reflection).
float fresnel_dielectric(float cos_i, float eta, out float cos_t) {
    float sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if (sin2_t >= 1.0) {
        cos_t = 0.0;
        return 1.0;
    }
    cos_t = sqrt(1.0 - sin2_t);
    float rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    float rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    return 0.5 * (rs * rs + rp * rp);
}

float fresnel_dielectric(float cos_i, float eta) {
    float cos_t;
    return fresnel_dielectric(cos_i, eta, cos_t);
}

// What a thin sheet reflects of light arriving at cos_i: its first
// surface's Fresnel reflectance with every inner reflection after it.
float thin_reflectance(float cos_i, float eta) {
    float r = fresnel_dielectric(cos_i, eta);
    float t = 1.0 - r;
    return r < 1.0 ? r + t * t * r / (1.0 - r * r) : r;
}

// A plastic's diffuse f_s cos: the base seen through the coat both ways,
// light scattered back inside the coat accounted for.
vec3 plastic_eval(Bsdf bsdf, vec3 wo, vec3 wi) {
    float fi = fresnel_dielectric(wo.z, bsdf.eta);
    float fo = fresnel_dielectric(wi.z, bsdf.eta);
    float fdr = bsdf.ior_k.x;
    bool nonlinear = (MATERIAL_FEATURES & MATERIAL_NONLINEAR) != 0u && (bsdf.flags & MATERIAL_NONLINEAR) != 0u;
    vec3 inside = nonlinear ? 1.0 - bsdf.color * fdr : vec3(1.0 - fdr);
    return bsdf.color / inside * (INV_PI * wi.z / (bsdf.eta * bsdf.eta) * (1.0 - fi) * (1.0 - fo));
}

// Mitsuba's principled (src/bsdf/principled.rs, the CPU twin, says more).
// Schlick's weight (1 - c)^5.
float schlick_weight(float c) {
    float m = clamp(1.0 - c, 0.0, 1.0);
    return m * m * m * m * m;
}

// Schlick's Fresnel term of normal reflectance r0 at cos c across relative
// index eta; below 1, at the transmitted angle (1 past the critical one).
vec3 schlick(vec3 r0, float c, float eta) {
    float w = eta > 1.0 ? schlick_weight(c) : schlick_weight(sqrt(max(1.0 - (1.0 - c * c) / (eta * eta), 0.0)));
    return r0 + (1.0 - r0) * w;
}

// Smith's masking of GGX as the clearcoat takes it (alpha 0.25).
float clearcoat_g1(vec3 w) {
    float c2 = w.z * w.z;
    return 2.0 / (1.0 + sqrt(1.0 + 0.0625 * (1.0 - c2) / c2));
}

// Burley's GTR1 distribution of the clearcoat's normals.
float gtr1_d(float alpha, vec3 h) {
    float a2 = alpha * alpha;
    return (a2 - 1.0) / (PI * log(a2) * (1.0 + (a2 - 1.0) * h.z * h.z));
}

// Burley's diffuse lobe over the Lambertian one, with retro-reflection at
// roughness r, flattened towards Hanrahan-Krueger's by `flatness`; ih is
// wi.h for the half vector h of wo and wi.
float burley_diffuse(vec3 wo, vec3 wi, float ih, float r, float flatness) {
    float fo = schlick_weight(wi.z);
    float fi = schlick_weight(wo.z);
    float diffuse = (1.0 - 0.5 * fi) * (1.0 - 0.5 * fo);
    float rr = 2.0 * r * ih * ih;
    float retro = rr * (fo + fi + fo * fi * (rr - 1.0));
    float ss90 = 0.5 * rr;
    float ss = (1.0 + (ss90 - 1.0) * fo) * (1.0 + (ss90 - 1.0) * fi);
    float subsurface = 1.25 * (ss * (1.0 / (wo.z + wi.z) - 0.5) + 0.5);
    return mix(diffuse + retro, subsurface, flatness);
}

// The specular lobe as a GGX conductor (principled_alphas), for the
// microfacet helpers.
Bsdf principled_specular(Bsdf bsdf) {
    vec2 alpha = principled_alphas(bsdf.alpha, bsdf.alpha_v);
    return Bsdf(MATERIAL_CONDUCTOR, vec3(1.0), alpha.x, 1.0, 0u, vec3(0.0), vec3(0.0), 0u, alpha.y, vec2(1.0, 0.0));
}

// The clearcoat's GTR1 alpha: 0.1 at gloss 0 to 0.001 at gloss 1.
float principled_clearcoat_alpha(Bsdf bsdf) {
    return mix(0.1, 1e-3, uintBitsToFloat(bsdf.table));
}

// The weights of its diffuse part and of its refracting one.
vec2 principled_weights(Bsdf bsdf) {
    float spec_trans = principled_spec_trans(bsdf);
    return (1.0 - bsdf.ior_eta.x) * vec2(1.0 - spec_trans, spec_trans);
}

// The probabilities of sampling the diffuse lobe and the clearcoat (the
// specular lobe takes the rest): Mitsuba's weights, the diffuse part's,
// clearcoat / 4 and 1.
vec2 principled_shares(Bsdf bsdf) {
    vec2 w = vec2(principled_weights(bsdf).x, 0.25 * bsdf.ior_k.z);
    return w / (w.x + w.y + 1.0);
}

// Whether its front lets light through.
bool principled_transmits(Bsdf bsdf) {
    return bsdf_principled(bsdf) && principled_weights(bsdf).y > 0.0;
}

vec3 principled_eval(Bsdf bsdf, vec3 wo, vec3 wi) {
    vec2 weights = principled_weights(bsdf);
    vec3 base = bsdf.color;
    if (wi.z < 0.0) {
        vec4 hr = rough_glass_half(wo, wi, bsdf.eta);
        if (hr.w != 0.0 || weights.y <= 0.0) {
            return vec3(0.0);
        }
        float oh = dot(wo, hr.xyz);
        float f = fresnel_dielectric(oh, bsdf.eta);
        float dg = microfacet_dg(principled_specular(bsdf), wo, wi, hr.xyz);
        float jacobian = refraction_jacobian(wo, wi, hr.xyz, bsdf.eta);
        return sqrt(base) * (weights.y * (1.0 - f) * dg * oh * jacobian / (bsdf.eta * bsdf.eta * wo.z));
    }
    vec3 h = normalize(wo + wi);
    float oh = dot(wo, h);
    float ih = dot(wi, h);
    float m = bsdf.ior_eta.x;
    float lum = luminance(base);
    vec3 tint = lum > 0.0 ? base / lum : vec3(1.0);
    vec3 value = vec3(0.0);
    // Mitsuba leaves the whole specular lobe out where the dielectric
    // reflects nothing (eta 1), its metallic part too.
    float fd = fresnel_dielectric(oh, bsdf.eta);
    if (fd > 0.0) {
        float r0 = (bsdf.eta - 1.0) / (bsdf.eta + 1.0);
        float st = bsdf.ior_eta.y;
        vec3 f = (1.0 - m) * (1.0 - st) * fd + m * schlick(base, oh, bsdf.eta) +
                 (1.0 - m) * st * schlick(tint * (r0 * r0), oh, bsdf.eta);
        value += f * (microfacet_dg(principled_specular(bsdf), wo, wi, h) / (4.0 * wo.z));
    }
    float clearcoat = bsdf.ior_k.z;
    if (clearcoat > 0.0) {
        float f = schlick(vec3(0.04), oh, bsdf.eta).x;
        float g = clearcoat_g1(wo) * clearcoat_g1(wi);
        value += 0.25 * clearcoat * f * gtr1_d(principled_clearcoat_alpha(bsdf), h) * g * wi.z;
    }
    if (weights.x > 0.0) {
        float lobe = burley_diffuse(wo, wi, ih, bsdf.alpha, bsdf.ior_k.y);
        value += base * (weights.x * wi.z * INV_PI * lobe);
        float sheen = bsdf.ior_eta.z;
        if (sheen > 0.0) {
            value += mix(vec3(1.0), tint, bsdf.ior_k.x) * (sheen * (1.0 - m) * schlick_weight(abs(ih)) * wi.z);
        }
    }
    return value;
}

float principled_pdf(Bsdf bsdf, vec3 wo, vec3 wi) {
    vec2 share = principled_shares(bsdf);
    float ps = 1.0 - share.x - share.y;
    vec4 hr = rough_glass_half(wo, wi, bsdf.eta);
    if (hr.w < 0.0 || (hr.w == 0.0 && !principled_transmits(bsdf))) {
        return 0.0;
    }
    vec3 h = hr.xyz;
    float oh = dot(wo, h);
    float refracts = principled_weights(bsdf).y * (1.0 - fresnel_dielectric(oh, bsdf.eta));
    float normal = microfacet_sample_pdf(principled_specular(bsdf), wo, h);
    if (hr.w == 0.0) {
        return ps * refracts * normal * refraction_jacobian(wo, wi, h, bsdf.eta);
    }
    float clearcoat = gtr1_d(principled_clearcoat_alpha(bsdf), h) * h.z;
    return (ps * (1.0 - refracts) * normal + share.y * clearcoat) / (4.0 * oh) + share.x * wi.z * INV_PI;
}

// A direction by u.z's lobe: the cosine for its diffuse part, else a
// reflection about a clearcoat's GTR1 normal or a visible GGX one, which
// refracts with Mitsuba's probability; the zero vector where it leaves on
// the wrong side.
vec3 principled_sample(Bsdf bsdf, vec3 wo, vec3 u, out vec2 square) {
    vec2 share = principled_shares(bsdf);
    if (u.z < share.x) {
        vec3 wi = sample_cosine(u.xy);
        square = 0.5 + (u.xy - 0.5) / sqrt(1.0 + wi.z);
        return wi;
    }
    vec3 m;
    vec3 wi;
    if (u.z < share.x + share.y) {
        float a2 = principled_clearcoat_alpha(bsdf);
        a2 *= a2;
        float c2 = (1.0 - pow(a2, 1.0 - u.y)) / (1.0 - a2);
        float s = sqrt(max(1.0 - c2, 0.0));
        float phi = 2.0 * PI * u.x;
        m = vec3(s * cos(phi), s * sin(phi), sqrt(max(c2, 0.0)));
        wi = microfacet_reflect(wo, m);
        wi = wi.z > 0.0 ? wi : vec3(0.0);
    } else {
        m = microfacet_sample(principled_specular(bsdf), wo, u.xy);
        float c = dot(wo, m);
        float cos_t;
        float f = fresnel_dielectric(max(c, 0.0), bsdf.eta, cos_t);
        float ps = 1.0 - share.x - share.y;
        bool refract = c > 0.0 && u.z - share.x - share.y < ps * principled_weights(bsdf).y * (1.0 - f);
        wi = refract ? -wo / bsdf.eta + (c / bsdf.eta - cos_t) * m : microfacet_reflect(wo, m);
        wi = (wi.z < 0.0) == refract ? wi : vec3(0.0);
    }
    square = hemisphere_to_square(wi.z == 0.0 ? vec3(0.0, 0.0, 1.0) : vec3(wi.xy, abs(wi.z)));
    return wi;
}

// Mitsuba's principledthin (Principled::thin_* in src/bsdf/principled.rs
// says more): its shares of specular reflection, specular transmission and
// diffuse reflection (diffuse transmission takes the rest).
vec3 thin_shares(Bsdf bsdf) {
    float s = principled_spec_trans(bsdf);
    return vec3(0.5 * s, 0.5 * s, (1.0 - s) * (1.0 - bsdf.ior_eta.x));
}

// The transmission's lobe: the roughness scaled by 0.65 eta - 0.35.
Bsdf thin_transmission(Bsdf bsdf) {
    bsdf.alpha *= 0.65 * bsdf.eta - 0.35;
    return principled_specular(bsdf);
}

// The half vector of wo and wi mirrored above the surface, in xyz; w 0
// where the lobe of wi's side does not see it from the right sides
// (reflection: both in front of it; transmission: wi behind it).
vec4 thin_half(vec3 wo, vec3 wi) {
    vec3 h = normalize(wo + vec3(wi.xy, abs(wi.z)));
    return vec4(h, dot(wo, h) > 0.0 && (dot(wi, h) > 0.0) == (wi.z > 0.0) ? 1.0 : 0.0);
}

vec3 thin_eval(Bsdf bsdf, vec3 wo, vec3 wi) {
    float s = principled_spec_trans(bsdf);
    float through = bsdf.ior_eta.x;
    vec3 base = bsdf.color;
    float lum = luminance(base);
    vec3 tint = lum > 0.0 ? base / lum : vec3(1.0);
    vec3 value = vec3(0.0);
    vec4 hv = thin_half(wo, wi);
    if (s > 0.0 && hv.w > 0.0) {
        vec3 wi_r = vec3(wi.xy, abs(wi.z));
        float oh = dot(wo, hv.xyz);
        float fd = fresnel_dielectric(oh, bsdf.eta);
        if (wi.z > 0.0) {
            float r0 = (bsdf.eta - 1.0) / (bsdf.eta + 1.0);
            vec3 f = mix(vec3(fd), schlick(tint * (r0 * r0), oh, bsdf.eta), bsdf.ior_eta.y);
            value += f * (s * microfacet_dg(principled_specular(bsdf), wo, wi_r, hv.xyz) / (4.0 * wo.z));
        } else {
            value += base * (s * (1.0 - fd) * microfacet_dg(thin_transmission(bsdf), wo, wi_r, hv.xyz) / (4.0 * wo.z));
        }
    }
    float diffuse = (1.0 - s) * INV_PI * abs(wi.z);
    if (wi.z < 0.0) {
        return value + base * (diffuse * through);
    }
    float ih = dot(wi, normalize(wo + wi));
    value += base * (diffuse * (1.0 - through) * burley_diffuse(wo, wi, ih, bsdf.alpha, bsdf.ior_k.y));
    float sheen = bsdf.ior_eta.z;
    if (sheen > 0.0) {
        value += mix(vec3(1.0), tint, bsdf.ior_k.x) * (sheen * (1.0 - s) * (1.0 - through) * schlick_weight(abs(ih)) * wi.z);
    }
    return value;
}

float thin_pdf(Bsdf bsdf, vec3 wo, vec3 wi) {
    vec3 share = thin_shares(bsdf);
    float pdf = (wi.z > 0.0 ? share.z : 1.0 - share.x - share.y - share.z) * abs(wi.z) * INV_PI;
    vec4 hv = thin_half(wo, wi);
    if (share.x > 0.0 && hv.w > 0.0) {
        Bsdf lobe = wi.z > 0.0 ? principled_specular(bsdf) : thin_transmission(bsdf);
        pdf += share.x * microfacet_sample_pdf(lobe, wo, hv.xyz) / (4.0 * dot(vec3(wi.xy, abs(wi.z)), hv.xyz));
    }
    return pdf;
}

// A direction by u.z's lobe: a reflection about a visible GGX normal, one
// about the transmission's turned to the far side, or the cosine on either
// side; the zero vector where the reflection falls on the wrong side.
vec3 thin_sample(Bsdf bsdf, vec3 wo, vec3 u, out vec2 square) {
    vec3 share = thin_shares(bsdf);
    if (u.z >= share.x + share.y) {
        vec3 wi = sample_cosine(u.xy);
        square = 0.5 + (u.xy - 0.5) / sqrt(1.0 + wi.z);
        return u.z >= share.x + share.y + share.z ? -wi : wi;
    }
    bool reflect = u.z < share.x;
    vec3 m = microfacet_sample(reflect ? principled_specular(bsdf) : thin_transmission(bsdf), wo, u.xy);
    vec3 r = 2.0 * dot(wo, m) * m - wo;
    vec3 wi = reflect ? r : vec3(r.xy, -r.z);
    square = hemisphere_to_square(vec3(r.xy, max(r.z, 0.0)));
    return r.z > 0.0 && dot(wo, m) > 0.0 && (dot(wi, m) > 0.0) == reflect ? wi : vec3(0.0);
}

// The share of the BSDF's scattering from wo that stays on wo's side, as
// its sampler chooses lobes (a refraction's Fresnel term taken at the
// surface's normal rather than a microfacet's): how a vertex that lets
// light through splits the guide's half of the mixture between the two
// sides (guide.glsl). 1 where nothing passes.
float bsdf_reflect_share(Bsdf bsdf, vec3 wo) {
    if (bsdf_rough_glass(bsdf)) {
        return fresnel_dielectric(wo.z, bsdf.eta);
    }
    if (principled_transmits(bsdf)) {
        vec2 share = principled_shares(bsdf);
        return 1.0 - (1.0 - share.x - share.y) * principled_weights(bsdf).y * (1.0 - fresnel_dielectric(wo.z, bsdf.eta));
    }
    if (thin_transmits(bsdf)) {
        vec3 share = thin_shares(bsdf);
        return share.x + share.z;
    }
    return 1.0;
}

// The probability that a bounce from wo takes the BSDF's delta lobe: 1 for
// a mirror or glass, a plastic's Fresnel-weighted share of its coat's
// reflection, 0 for the rest. bsdf_sample_delta draws that lobe;
// bsdf_sample, bsdf_pdf and bsdf_eval are the others', bsdf_pdf conditional
// on not taking it.
float bsdf_delta_share(Bsdf bsdf, vec3 wo) {
    if (bsdf_smooth_plastic(bsdf)) {
        float f = fresnel_dielectric(wo.z, bsdf.eta);
        float w = bsdf.ior_k.y;
        float s = f * w;
        float d = (1.0 - f) * (1.0 - w);
        return s + d > 0.0 ? s / (s + d) : 0.0;
    }
    return bsdf_is_delta(bsdf) ? 1.0 : 0.0;
}

// f_s(wo, wi) cos(theta_i); zero for delta lobes.
vec3 bsdf_eval(Bsdf bsdf, vec3 wo, vec3 wi) {
    if (bsdf_anisotropic(bsdf)) {
        wo = to_tangent(bsdf, wo);
        wi = to_tangent(bsdf, wi);
    }
    if (bsdf_rough_glass(bsdf)) {
        vec4 hr = rough_glass_half(wo, wi, bsdf.eta);
        if (hr.w < 0.0) {
            return vec3(0.0);
        }
        vec3 h = hr.xyz;
        float oh = dot(wo, h);
        float f = fresnel_dielectric(oh, bsdf.eta);
        float dg = microfacet_dg(bsdf, wo, wi, h);
        if (hr.w > 0.0) {
            return bsdf.ior_eta * (f * dg / (4.0 * wo.z));
        }
        float jacobian = refraction_jacobian(wo, wi, h, bsdf.eta);
        return bsdf.color * ((1.0 - f) * dg * oh * jacobian / (bsdf.eta * bsdf.eta * wo.z));
    }
    if (bsdf_principled(bsdf)) {
        return wo.z > 0.0 && wi.z != 0.0 ? principled_eval(bsdf, wo, wi) : vec3(0.0);
    }
    if (bsdf_principled_thin(bsdf)) {
        return wo.z > 0.0 && wi.z != 0.0 ? thin_eval(bsdf, wo, wi) : vec3(0.0);
    }
    if (wi.z <= 0.0 || wo.z <= 0.0) {
        return vec3(0.0);
    }
    if (bsdf_is(bsdf, MATERIAL_DIFFUSE)) {
        return bsdf.color * (INV_PI * wi.z);
    }
    if (bsdf_rough_plastic(bsdf)) {
        vec3 h = normalize(wo + wi);
        vec3 coat = bsdf.ior_eta * (fresnel_dielectric(dot(wo, h), bsdf.eta) * microfacet_dg(bsdf, wo, wi, h) / (4.0 * wo.z));
        bool nonlinear = (MATERIAL_FEATURES & MATERIAL_NONLINEAR) != 0u && (bsdf.flags & MATERIAL_NONLINEAR) != 0u;
        float fdr = bsdf.ior_k.x;
        vec3 inside = nonlinear ? 1.0 - bsdf.color * fdr : vec3(1.0 - fdr);
        float through = rough_transmittance(bsdf, wo.z) * rough_transmittance(bsdf, wi.z);
        return coat + bsdf.color / inside * (INV_PI * wi.z / (bsdf.eta * bsdf.eta) * through);
    }
    if (bsdf_plastic(bsdf)) {
        return plastic_eval(bsdf, wo, wi);
    }
    if (bsdf_is(bsdf, MATERIAL_CONDUCTOR) && bsdf.alpha > 0.0) {
        vec3 h = normalize(wo + wi);
        return conductor_reflectance(bsdf, dot(wo, h)) * (microfacet_dg(bsdf, wo, wi, h) / (4.0 * wo.z));
    }
    return vec3(0.0);
}

// Solid-angle pdf of bsdf_sample choosing wi; zero for delta lobes. A
// diffuse lobe samples the cosine, or the hemisphere uniformly with
// FLAG_UNIFORM (`--sampling uniform`); a GGX conductor its visible normals:
// D_wo(h) / (4 wo.h) with D_wo(h) = G1(wo) (wo.h) D(h) / wo.z; a Beckmann
// conductor all its normals: D(h) h.z / (4 wo.h).
float bsdf_pdf(Bsdf bsdf, vec3 wo, vec3 wi) {
    if (bsdf_anisotropic(bsdf)) {
        wo = to_tangent(bsdf, wo);
        wi = to_tangent(bsdf, wi);
    }
    if (bsdf_rough_glass(bsdf)) {
        vec4 hr = rough_glass_half(wo, wi, bsdf.eta);
        if (hr.w < 0.0) {
            return 0.0;
        }
        float oh = dot(wo, hr.xyz);
        float f = fresnel_dielectric(oh, bsdf.eta);
        float m = microfacet_sample_pdf(bsdf, wo, hr.xyz);
        if (hr.w > 0.0) {
            return f * m / (4.0 * oh);
        }
        return (1.0 - f) * m * refraction_jacobian(wo, wi, hr.xyz, bsdf.eta);
    }
    if (bsdf_principled(bsdf)) {
        return principled_pdf(bsdf, wo, wi);
    }
    if (bsdf_principled_thin(bsdf)) {
        return wo.z > 0.0 && wi.z != 0.0 ? thin_pdf(bsdf, wo, wi) : 0.0;
    }
    if (wi.z <= 0.0 || wo.z <= 0.0) {
        return 0.0;
    }
    if (bsdf_is(bsdf, MATERIAL_DIFFUSE)) {
        return (params.flags & FLAG_UNIFORM) != 0u ? 0.5 * INV_PI : wi.z * INV_PI;
    }
    if (bsdf_rough_plastic(bsdf)) {
        float share = rough_coat_share(bsdf, wo);
        vec3 h = normalize(wo + wi);
        return share * microfacet_sample_pdf(bsdf, wo, h) / (4.0 * dot(wo, h)) + (1.0 - share) * wi.z * INV_PI;
    }
    if (bsdf_plastic(bsdf)) {
        return wi.z * INV_PI;
    }
    if (bsdf_is(bsdf, MATERIAL_CONDUCTOR) && bsdf.alpha > 0.0) {
        // microfacet_sample_pdf over the reflection's Jacobian 4 wo.h,
        // simplified.
        vec3 h = normalize(wo + wi);
        vec2 alpha = microfacet_alphas(bsdf);
        return bsdf_beckmann(bsdf) ? beckmann_d(alpha, h) * h.z / (4.0 * dot(wo, h))
                                   : ggx_g1(alpha, wo) * ggx_d(alpha, h) / (4.0 * wo.z);
    }
    return 0.0;
}

// A direction wi from three uniform numbers u; bsdf_pdf gives its density
// (zero, for a rough lobe, where it falls below the horizon). u.z picks a
// rough plastic's lobe, or rough glass's reflection against refraction.
// Also sets `square` to wi's point of the equal-area square (the guides'
// sector grid; the mirrored direction's for one below), which samplers
// built on the concentric map know without inverting it
// (hemisphere_to_square(wi) costs an atan). Not for delta lobes.
vec3 bsdf_sample_local(Bsdf bsdf, vec3 wo, vec3 u, out vec2 square);

vec3 bsdf_sample(Bsdf bsdf, vec3 wo, vec3 u, out vec2 square) {
    if (!bsdf_anisotropic(bsdf)) {
        return bsdf_sample_local(bsdf, wo, u, square);
    }
    vec3 wi = from_tangent(bsdf, bsdf_sample_local(bsdf, to_tangent(bsdf, wo), u, square));
    square = hemisphere_to_square(wi.z == 0.0 ? vec3(0.0, 0.0, 1.0) : vec3(wi.xy, abs(wi.z)));
    return wi;
}

// bsdf_sample in the frame of the BSDF's tangent.
vec3 bsdf_sample_local(Bsdf bsdf, vec3 wo, vec3 u, out vec2 square) {
    if (bsdf_principled(bsdf)) {
        return principled_sample(bsdf, wo, u, square);
    }
    if (bsdf_principled_thin(bsdf)) {
        return thin_sample(bsdf, wo, u, square);
    }
    bool coat = bsdf_rough_plastic(bsdf) && u.z < rough_coat_share(bsdf, wo);
    if (bsdf_is(bsdf, MATERIAL_CONDUCTOR) || coat || bsdf_rough_glass(bsdf)) {
        vec3 m = microfacet_sample(bsdf, wo, u.xy);
        vec3 wi = microfacet_reflect(wo, m);
        if (bsdf_rough_glass(bsdf)) {
            // Reflect with the Fresnel probability, else refract; no
            // direction (pdf 0) where either leaves on the wrong side.
            float c = dot(wo, m);
            float cos_t;
            float f = fresnel_dielectric(max(c, 0.0), bsdf.eta, cos_t);
            bool reflect = u.z < f;
            wi = reflect ? 2.0 * c * m - wo : -wo / bsdf.eta + (c / bsdf.eta - cos_t) * m;
            wi = c > 0.0 && (wi.z > 0.0) == reflect ? wi : vec3(0.0);
        }
        square = hemisphere_to_square(wi.z == 0.0 ? vec3(0.0, 0.0, 1.0) : vec3(wi.xy, abs(wi.z)));
        return wi;
    }
    if ((params.flags & FLAG_UNIFORM) != 0u && bsdf_is(bsdf, MATERIAL_DIFFUSE)) {
        square = u.xy;
        return square_to_hemisphere(u.xy);
    }
    // Malley's method keeps the concentric map's angle, so the equal-area
    // point is the disk's square point scaled by 1 / sqrt(1 + z).
    vec3 wi = sample_cosine(u.xy);
    square = 0.5 + (u.xy - 0.5) / sqrt(1.0 + wi.z);
    return wi;
}

// A delta lobe's direction from one uniform number, and its weight f cos /
// pdf: a mirror reflects; glass reflects with the Fresnel probability and
// else refracts, its radiance scaled by 1 / eta^2 as the solid angle
// compresses.
vec3 bsdf_sample_delta(Bsdf bsdf, vec3 wo, float u, out vec3 weight) {
    vec3 mirror = vec3(-wo.xy, wo.z);
    if (bsdf_is(bsdf, MATERIAL_DIELECTRIC)) {
        float cos_t;
        float f = fresnel_dielectric(wo.z, bsdf.eta, cos_t);
        if (u < f) {
            weight = bsdf.ior_eta;
            return mirror;
        }
        weight = bsdf.color / (bsdf.eta * bsdf.eta);
        return vec3(-wo.xy / bsdf.eta, -cos_t);
    }
    if (bsdf_is(bsdf, MATERIAL_THIN)) {
        float r = thin_reflectance(wo.z, bsdf.eta);
        weight = u < r ? bsdf.ior_eta : bsdf.color;
        return u < r ? mirror : -wo;
    }
    // A plastic's coat: its weight before dividing by bsdf_delta_share.
    weight = bsdf_plastic(bsdf) ? bsdf.ior_eta * fresnel_dielectric(wo.z, bsdf.eta) : conductor_reflectance(bsdf, wo.z);
    return mirror;
}

// Luminance a diffuse lobe reflects toward wo of the light a guide expects
// from its n sectors, given as `irradiance` = (2 pi / n) sum_j Q_j
// cos(theta_j). The other lobes' estimates are guide_reflect's (guide.glsl)
// and, for a rough conductor, trace.comp's from the bounce's own direction.
float bsdf_reflect(Bsdf bsdf, vec3 wo, float irradiance) {
    return luminance(bsdf.color) * INV_PI * irradiance;
}

#endif
