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

// A material's scattering at a surface point. Every material so far is
// diffuse (two-sided Lambert); a new lobe adds its parameters here.
struct Bsdf {
    vec3 albedo;
};

Bsdf bsdf_of(Material m) {
    return Bsdf(m.albedo.rgb);
}

// Whether the BSDF is a delta distribution (a mirror, smooth glass): such a
// vertex skips NEE and guiding. No material so far is.
bool bsdf_is_delta(Bsdf bsdf) {
    return false;
}

// f_s(wo, wi) cos(theta_i).
vec3 bsdf_eval(Bsdf bsdf, vec3 wo, vec3 wi) {
    return wi.z > 0.0 ? bsdf.albedo * (INV_PI * wi.z) : vec3(0.0);
}

// Solid-angle pdf of bsdf_sample choosing wi: cosine-weighted, or uniform
// over the hemisphere with FLAG_UNIFORM (`--sampling uniform`).
float bsdf_pdf(Bsdf bsdf, vec3 wo, vec3 wi) {
    if (wi.z <= 0.0) {
        return 0.0;
    }
    return (params.flags & FLAG_UNIFORM) != 0u ? 0.5 * INV_PI : wi.z * INV_PI;
}

// A direction wi from two uniform numbers u; bsdf_pdf gives its density.
// Also sets `square` to wi's point of the equal-area square (the guides'
// sector grid), which samplers built on the concentric map know without
// inverting it (hemisphere_to_square(wi) costs an atan).
vec3 bsdf_sample(Bsdf bsdf, vec3 wo, vec2 u, out vec2 square) {
    if ((params.flags & FLAG_UNIFORM) != 0u) {
        square = u;
        return square_to_hemisphere(u);
    }
    // Malley's method keeps the concentric map's angle, so the equal-area
    // point is the disk's square point scaled by 1 / sqrt(1 + z).
    vec3 wi = sample_cosine(u);
    square = 0.5 + (u - 0.5) / sqrt(1.0 + wi.z);
    return wi;
}

// Luminance the vertex reflects toward wo of the light a guide expects from
// its n sectors, given as `irradiance` = (2 pi / n) sum_j Q_j cos(theta_j):
// the guides' bootstrap targets. Exact for a diffuse lobe, whose f_s is one
// constant; a lobe that varies needs the per-sector sum instead.
float bsdf_reflect(Bsdf bsdf, vec3 wo, float irradiance) {
    return luminance(bsdf.albedo) * INV_PI * irradiance;
}

#endif
