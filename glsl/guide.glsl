// The guide seam. A guide (sarsa.glsl, neural.glsl, neural_table.glsl, or
// unguided.glsl for plain path tracing; included before this file) provides:
//   GUIDED                   const bool: whether it samples directions at all
//   GUIDE_TWO_SIDED          const bool: whether two of its vertices may be
//       held at once (a vertex that lets light through samples both sides)
//   struct GuideVertex       what it knows at a path vertex
//   guide_none()             the vertex before the camera ray: learns nothing
//   guide_at(triangle index, triangle, p, n, front side?)
//   guide_covers(g)          whether it has a sector distribution at g
//   guide_total(g)           the total weight w of that distribution
//   guide_bsdf_share(g)      the share of BSDF sampling in the mixture there
//   guide_irradiance(g)      (2 pi / n) sum_j Q_j cos(theta_j), for targets
//   guide_sector_probability(g, k)
//   guide_choose_sector(g, pick, u, sector, out p)  with pick, a sector
//       drawn by u and its probability p; else p of `sector`
//   guide_sector_q(g, k)     Q of sector k (0 where the guide has nothing)
//   guide_learn(from, k, q, le, mis_weight, reflected, direct, ...)  a
//       transition from vertex `from` through sector k (whose Q was q)
//       reached an emitter sending le, whose
//       scattering MIS weight is mis_weight, or (le 0) a surface that
//       reflects `reflected` back and gets `direct` by NEE, or a miss (the
//       environment as `reflected`)
//   guide_learn_share(from, gradient)  one sample's gradient for the share
//       of BSDF sampling at `from` (mixture_gradient times L^2)
//   guide_begin_path(), guide_end_path(pixel, rng)  around each path of a
//       pass that learns (a guide may keep something per path)
// and NEE's choice of light, which a guide may learn:
//   GUIDE_LIGHTS             bool (a constant or a specialization constant):
//       whether it picks NEE's light; else NEE picks by emitted power
//   guide_choose_light(g, u, out p)  a light (LightGroup) drawn by u at g,
//       and the probability p it had
//   guide_light_probability(g, l)    the probability of light l at g
//   guide_record_light(g, l, brought)  one NEE try of light l at g, in a
//       pass that learns, that brought `brought` (luminance, before its MIS
//       weight and the light's pick probability; 0 where blocked)
// On it, this file builds the one-sample mixture of BSDF sampling and the
// guide's sectors that every guided method samples, and the estimate of
// what a vertex reflects that both guides learn from.
#ifndef QTRACE_GUIDE_GLSL
#define QTRACE_GUIDE_GLSL

#include "rng.glsl"

// Whether the kernel has the learning code: FROZEN builds the kernel of the
// passes that learn nothing without it (on lavapipe, code no lane runs
// still costs time).
#ifdef FROZEN
const bool GUIDE_LEARNS = false;
#else
const bool GUIDE_LEARNS = GUIDED;
#endif

// Q of sector k from its probability p: a sector's weight is p times the
// total, and is Q cos(theta_k), or Q with FLAG_Q_DISTRIBUTION. (No read
// of Q in the trace kernel.)
float guide_q(GuideVertex g, uint k, float p) {
    float w = p * guide_total(g);
    return !EXPERIMENT(FLAG_Q_DISTRIBUTION) ? w / sector_cos(k, grid_a(), grid_b()) : w;
}

// Whether a vertex may sample both sides' tables: where the guide can hold
// two vertices and some material of the scene lets light through without a
// delta lobe (a constant: other scenes' kernels carry none of its code,
// which costs lavapipe time even where no lane runs it).
bool mixture_two_sided() {
    return GUIDE_TWO_SIDED && (MATERIAL_FEATURES & (FEATURE_ROUGH_GLASS | FEATURE_PRINCIPLED_THIN)) != 0u;
}

// How much of the guide's side of the mixture a lobe keeps: all for a
// diffuse lobe, alpha of it for a glossy one: the guide's sectors are
// uniform inside, so a lobe narrower than they are gains little from them
// (the roughest GGX, alpha 1, is as broad as a diffuse lobe). Delta lobes
// do not mix (bsdf_sample_delta). A principled BSDF that lets light through
// keeps all for its diffuse share, alpha for the rest.
float mixture_guide_reach(Bsdf bsdf) {
    if (bsdf_is(bsdf, MATERIAL_CONDUCTOR) || bsdf_rough_glass(bsdf)) {
        return min(bsdf.alpha, 1.0);
    }
    if (!mixture_two_sided()) {
        return 1.0;
    }
    float diffuse;
    if (principled_transmits(bsdf)) {
        diffuse = principled_shares(bsdf).x;
    } else if (thin_transmits(bsdf)) {
        vec3 share = thin_shares(bsdf);
        diffuse = 1.0 - share.x - share.y;
    } else {
        return 1.0;
    }
    return diffuse + (1.0 - diffuse) * min(principled_specular(bsdf).alpha, 1.0);
}

// The guide's half of the one-sample mixture at a vertex: the sector
// distribution of the side the path arrives on (`front`) and, where the
// BSDF lets light through (mixture_two_sided), that of the other side
// (`back`), each given the part of the guide's half that the BSDF sends to
// its side (bsdf_reflect_share), times the lobe's reach. A side the guide
// does not cover leaves its part to BSDF sampling. The back's sectors are
// those of a path arriving there: in its frame, make_frame(-n) = (t, -b),
// a direction (x, y, z) of the front's is (x, -y, -z).
struct Mixture {
    GuideVertex front;
    GuideVertex back;
    float e;     // the guide's own share of BSDF sampling: the front's,
    bool e_back; // or the back's where only it covers
    float kf;    // the parts of the guide's half: the front's
    float kb;    // and the back's
};

Mixture mixture_at(GuideVertex front, GuideVertex back, Bsdf bsdf, vec3 wo) {
    float reach = mixture_guide_reach(bsdf);
    bool two = mixture_two_sided() && guide_covers(back);
    float a = two ? bsdf_reflect_share(bsdf, wo) : 1.0;
    Mixture m;
    m.front = front;
    m.back = back;
    m.e_back = two && !guide_covers(front);
    m.e = guide_bsdf_share(m.e_back ? back : front);
    m.kf = guide_covers(front) ? reach * a : 0.0;
    m.kb = two ? reach * (1.0 - a) : 0.0;
    return m;
}

// The mixture of a vertex whose guide covers one side (the probes').
Mixture mixture_one_sided(GuideVertex g, Bsdf bsdf) {
    return mixture_at(g, guide_none(), bsdf, vec3(0.0, 0.0, 1.0));
}

// The vertex whose share of BSDF sampling the mixture takes (and learns).
GuideVertex mixture_share_vertex(Mixture m) {
    return m.e_back ? m.back : m.front;
}

// The share of BSDF sampling in the mixture: the guide's own share, and
// the rest where the lobe's reach or a side the guide does not cover
// leaves it.
float mixture_bsdf_share(Mixture m) {
    return 1.0 - (1.0 - m.e) * (m.kf + m.kb);
}

// Whether local direction wi lies on the back's side, and wi in the frame
// of the side it lies on.
bool mixture_back(vec3 wi) {
    return mixture_two_sided() && wi.z < 0.0;
}

vec3 mixture_side_direction(vec3 wi) {
    return mixture_back(wi) ? vec3(wi.x, -wi.y, -wi.z) : wi;
}

// The guide vertex of the side wi lies on.
GuideVertex mixture_side(Mixture m, vec3 wi) {
    return mixture_back(wi) ? m.back : m.front;
}

// Solid-angle density of the guide's half at wi, in a sector of probability
// p_sector of its side's distribution: uniform within the sector,
// p n / (2 pi), times the side's part of the guide's half.
float guide_density(Mixture m, vec3 wi, float p_sector) {
    float part = wi.z > 0.0 ? m.kf : mixture_back(wi) ? m.kb : 0.0;
    return part / max(m.kf + m.kb, 1e-30) * (p_sector * float(sector_count()) * 0.5 * INV_PI);
}

// Solid-angle pdf of the mixture at wi, which lies in a sector of
// probability p_sector (of its side's distribution) and where the BSDF's
// own pdf is p_bsdf; pure BSDF sampling where the guide has nothing.
// (Callers evaluate the BSDF's pdf once: lavapipe inlines each call, a
// principled BSDF's pdf at length.)
float mixture_pdf_of(Mixture m, float p_bsdf, vec3 wi, float p_sector) {
    if (m.kf + m.kb <= 0.0) {
        return p_bsdf;
    }
    float eps = mixture_bsdf_share(m);
    return eps * p_bsdf + (1.0 - eps) * guide_density(m, wi, p_sector);
}

float mixture_pdf_in(Mixture m, Bsdf bsdf, vec3 wo, vec3 wi, float p_sector) {
    return mixture_pdf_of(m, bsdf_pdf(bsdf, wo, wi), wi, p_sector);
}

float mixture_pdf(Mixture m, Bsdf bsdf, vec3 wo, vec3 wi) {
    GuideVertex g = mixture_side(m, wi);
    float p = guide_covers(g) ? guide_sector_probability(g, hemisphere_sector(mixture_side_direction(wi), grid_a(), grid_b())) : 0.0;
    return mixture_pdf_in(m, bsdf, wo, wi, p);
}

// A direction from the mixture, the sector it lies in (of its side's
// distribution) and that sector's probability; u = three uniform numbers.
vec3 mixture_sample(Mixture m, Bsdf bsdf, vec3 wo, vec3 u, out uint sector, out float p_sector) {
    float eps = mixture_bsdf_share(m);
    uint a = grid_a();
    uint b = grid_b();
    bool guided = u.z >= eps;
    // Both halves are worked out (lavapipe runs both sides of a branch
    // anyway), so that one read of the guide's table serves either.
    vec2 square;
    // Where BSDF sampling is chosen, u.z / eps is uniform again: it picks
    // among the lobes; where the guide is, (u.z - eps) / (1 - eps) picks
    // its side, then, uniform again, the sector.
    float lobe_u = min(u.z / max(eps, 1e-30), 0.99999994);
    vec3 wi = bsdf_sample(bsdf, wo, vec3(u.xy, lobe_u), square);
    float t = guided ? (u.z - eps) / (1.0 - eps) : 0.0;
    float front_part = m.kf / max(m.kf + m.kb, 1e-30);
    bool back = mixture_two_sided() && (guided ? t >= front_part : wi.z < 0.0);
    t = back ? (t - front_part) / max(1.0 - front_part, 1e-30) : t / max(front_part, 1e-30);
    GuideVertex g = back ? m.back : m.front;
    sector = back ? hemisphere_sector(mixture_side_direction(wi), a, b) : square_sector(square, a, b);
    p_sector = 0.0;
    if (guide_covers(g)) {
        sector = guide_choose_sector(g, guided, min(t, 0.99999994), sector, p_sector);
    }
    if (guided) {
        // Uniform within the sector, clear of its edges: rounding in the map
        // must not move the direction into a neighbouring sector, so that
        // the sector is the one a pdf lookup finds. (The strip left out is
        // 2e-5 of the cell.)
        vec2 inner = clamp(u.xy, vec2(1e-5), vec2(1.0 - 1e-5));
        vec3 w = square_to_hemisphere(vec2((float(sector % a) + inner.x) / float(a),
                                           (float(sector / a) + inner.y) / float(b)));
        return back ? vec3(w.x, -w.y, -w.z) : w;
    }
    return wi;
}

// For a guide that learns its share of BSDF sampling (its logit theta): the
// one-sample estimate, per unit of L^2 (L the radiance arriving along wi,
// which the path estimates), of the gradient of the second
// moment of f cos L / p with respect to theta: d/dtheta E[(f cos L / p)^2]
// = -E[(f cos L)^2 dp/dtheta / p^3]. wi was drawn from the mixture, whose
// pdf there is `pdf` (the BSDF's own p_bsdf) and whose f cos / pdf is
// `weight`.
float mixture_gradient(Mixture m, float p_bsdf, vec3 wi, float p_sector, float pdf, vec3 weight) {
    if (m.kf + m.kb <= 0.0 || pdf <= 0.0) {
        return 0.0;
    }
    float e = m.e;
    float dp = (p_bsdf - guide_density(m, wi, p_sector)) * (m.kf + m.kb) * e * (1.0 - e);
    float w = luminance(weight);
    return -w * w * dp / pdf;
}

// Luminance the vertex g reflects toward wo of the light the guide expects
// there: the target a transition that reached g learns (docs/guides.md:
// (2 pi / n) sum_j Q_j f_s(w_j, wo) cos(theta_j)).
// - Diffuse: exact, from the guide's irradiance-like sum.
// - Rough conductor and rough plastic: 0 here; trace.comp estimates it from the bounce's own
//   direction (Q of its sector times f cos / pdf), where a sample of its
//   own would cost a second lobe sample, evaluation and table read. (A sum
//   over all sectors would miss a lobe narrower than a sector and cost n
//   reads.)
// - Mirror: its reflectance times Q of the mirrored direction's sector.
// - Plastic: its coat's mirror so, and its base as a diffuse lobe.
// - Thin sheet: its reflection so; what it lets through as glass's.
// - Glass, smooth or rough (as if smooth): the Fresnel share of the
//   mirrored direction's Q; the transmitted
//   share sees the other side, of which the guide at g knows nothing, so it
//   takes the cosine-weighted mean of g's Q instead.
//   A transition into a delta vertex learns from the path beyond it instead
//   (trace.comp, chaining); these two serve where it cannot: at the maximum
//   depth, and as the roulette's scale at a camera ray's first hit. A rough
//   estimate only steers sampling; the image stays unbiased.
float guide_reflect(GuideVertex g, Bsdf bsdf, vec3 wo) {
    if (bsdf_is(bsdf, MATERIAL_DIFFUSE)) {
        return bsdf_reflect(bsdf, wo, guide_irradiance(g));
    }
    if (!bsdf_is_delta(bsdf) && !bsdf_smooth_plastic(bsdf) && !bsdf_rough_glass(bsdf)) {
        return 0.0;
    }
    uint a = grid_a();
    uint b = grid_b();
    float mirrored = guide_sector_q(g, hemisphere_sector(vec3(-wo.xy, wo.z), a, b));
    if (bsdf_smooth_plastic(bsdf)) {
        // The coat's mirror, and the base through it (the way out's
        // Fresnel loss left out).
        float f = fresnel_dielectric(wo.z, bsdf.eta);
        float base = luminance(bsdf.color / (1.0 - bsdf.ior_k.x)) * (1.0 - f) / (bsdf.eta * bsdf.eta);
        return f * luminance(bsdf.ior_eta) * mirrored + base * INV_PI * guide_irradiance(g);
    }
    if (bsdf_is(bsdf, MATERIAL_CONDUCTOR)) {
        return luminance(conductor_reflectance(bsdf, wo.z)) * mirrored;
    }
    if (bsdf_is(bsdf, MATERIAL_THIN)) {
        // What passes straight through comes from the other side, of which
        // g knows nothing: its cosine-weighted mean of Q stands in.
        float r = thin_reflectance(wo.z, bsdf.eta);
        return r * luminance(bsdf.ior_eta) * mirrored + (1.0 - r) * luminance(bsdf.color) * INV_PI * guide_irradiance(g);
    }
    float cos_t;
    float f = fresnel_dielectric(wo.z, bsdf.eta, cos_t);
    float through = luminance(bsdf.color) / (bsdf.eta * bsdf.eta) * INV_PI * guide_irradiance(g);
    return f * mirrored + (1.0 - f) * through;
}

#endif
