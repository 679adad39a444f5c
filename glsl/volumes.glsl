// Radiance volumes and the tables that guide sampling in them (docs/guides.md):
// the nearest-volume lookup, each volume's alias table over sectors, its
// sums and Q. The reading side of the guide seam (guide.glsl) for the guides
// that sample from these tables: Expected Sarsa (sarsa.glsl), which learns
// them, and Neural-Q with inference at the volumes (neural_table.glsl),
// whose network fills them. Needs shared.h, sampling.glsl, bsdf.glsl and
// the `params` push constants.
#ifndef QTRACE_VOLUMES_GLSL
#define QTRACE_VOLUMES_GLSL

#include "grid.glsl"

// The tables the trace kernel only reads are uniform texel buffers of raw
// words (one vector gather per read on lavapipe; see scene.glsl).
WORDS(sector_texels, B_SECTORS) // 2 SectorEntry per texel
// Per volume: (irradiance (2 pi / n) sum_j Q_j cos(theta_j), or the max
// target's max_j Q_j cos(theta_j); total weight of its sector
// distribution; share of BSDF sampling in the mixture; 0), one texel each;
// see guide_build.comp.
WORDS(volume_sum_texels, B_VOLUME_SUMS)
WORDS(q_texels, B_Q) // 4 Q per texel
// The lookup tables of src/guide/lookup.rs: per triangle, its cells or its
// two sides' volumes; cells (uvec2, two per texel); list entries (volume
// position, volume index bits).
WORDS(lookup_triangle_texels, B_LOOKUP_TRIANGLES)
WORDS(lookup_cell_texels, B_LOOKUP_CELLS)
WORDS(lookup_item_texels, B_LOOKUP_ITEMS)

SectorEntry load_sector(uint i) {
    uvec4 t = FETCH(sector_texels, int(i >> 1u));
    return (i & 1u) == 0u ? SectorEntry(t.x, t.y) : SectorEntry(t.z, t.w);
}

float load_q(uint i) {
    return uintBitsToFloat(FETCH(q_texels, int(i >> 2u))[i & 3u]);
}


// Exact nearest volume to p, a point shading the front (or back) side of
// triangle `tri` (index `triangle`), among the volumes facing that side;
// NO_VOLUME if none. The triangle's entry or its cell holds the answer, or a
// short list that does.
uint nearest_volume(uint triangle, Triangle tri, vec3 p, bool front) {
    uvec4 t = FETCH(lookup_triangle_texels, int(triangle));
    if (t.y == 0u) {
        return front ? t.z : t.w;
    }
    uint nu = t.y & 0xffffu;
    uint nv = t.y >> 16;
    uint cell = t.x + (front ? 0u : nu * nv);
    if (nu * nv > 1u) {
        // Barycentric coordinates of p: its offset is along the triangle's
        // normal, so it drops out. (Triangles with a small angle at v0, where
        // these lose precision, have one cell; see src/guide/lookup.rs.)
        vec2 uv = barycentric(tri, p);
        uvec2 c = uvec2(clamp(uv * vec2(nu, nv), vec2(0.0), vec2(nu - 1u, nv - 1u)));
        cell += c.x + nu * c.y;
    }
    uvec4 pair = FETCH(lookup_cell_texels, int(cell >> 1u));
    uvec2 entry = (cell & 1u) == 0u ? pair.xy : pair.zw;
    if (entry.y == 0u) {
        return entry.x;
    }
    uint best = NO_VOLUME;
    float best_d2 = FAR;
    for (uint i = entry.x; i < entry.x + entry.y; ++i) {
        vec4 item = uintBitsToFloat(FETCH(lookup_item_texels, int(i)));
        vec3 d = item.xyz - p;
        float d2 = dot(d, d);
        if (d2 < best_d2) {
            best = floatBitsToUint(item.w);
            best_d2 = d2;
        }
    }
    return best;
}

// A volume's sums and share of BSDF sampling, zero for NO_VOLUME.
vec3 volume_sums_of(uint v) {
    if (v == NO_VOLUME) {
        return vec3(0.0);
    }
    return uintBitsToFloat(FETCH(volume_sum_texels, int(v)).xyz);
}

// The guide seam's reading side (guide.glsl).

// A path vertex's volume and that volume's sums; and the vertex's point and
// normal (zero before the camera ray), which a learner that is not the
// table itself (neural_table.glsl) learns at. Sarsa leaves them unread, so
// they cost nothing there.
struct GuideVertex {
    uint volume;
    vec3 sums; // irradiance-like sum, total weight, share of BSDF sampling
    vec3 p;
    vec3 n;
};

// Whether a vertex that lets light through samples the other side's table
// too (guide.glsl's Mixture): a lookup finds a volume for either side.
const bool GUIDE_TWO_SIDED = true;

GuideVertex guide_vertex(uint volume) {
    return GuideVertex(volume, volume_sums_of(volume), vec3(0.0), vec3(0.0));
}

GuideVertex guide_none() {
    return GuideVertex(NO_VOLUME, vec3(0.0), vec3(0.0), vec3(0.0));
}

GuideVertex guide_at(uint triangle, Triangle tri, vec3 p, vec3 n, bool front) {
    uint v = nearest_volume(triangle, tri, p, front);
    return GuideVertex(v, volume_sums_of(v), p, n);
}

bool guide_covers(GuideVertex g) {
    return g.volume != NO_VOLUME;
}

float guide_total(GuideVertex g) {
    return g.sums.y;
}

float guide_irradiance(GuideVertex g) {
    return g.sums.x;
}

float guide_bsdf_share(GuideVertex g) {
    return g.sums.z;
}

float guide_sector_q(GuideVertex g, uint k) {
    return g.volume == NO_VOLUME ? 0.0 : max(load_q(g.volume * sector_count() + k), 0.0);
}

// One read of an alias table of n entries at `base` (see SectorEntry):
// with `pick`, the alias method (u, scaled to [0, n), picks a column; its
// fraction, in the column's units, decides between the column's entry and
// its alias); without, the probability of entry `given`. Returns the entry
// and its probability p, exact in the table's whole units.
uint alias_read(uint base, uint n, bool pick, float u, uint given, out float p) {
    uint c = column_units(n);
    float x = u * float(n);
    uint column = min(uint(x), n - 1u);
    SectorEntry e = load_sector(base + (pick ? column : given));
    uint unit = min(uint((x - float(column)) * float(c)), c - 1u);
    bool keep = !pick || unit < (e.column & 0xffffu);
    p = float(keep ? e.weights & 0xffffu : e.weights >> 16) / float(n * c);
    return pick ? (keep ? column : e.column >> 16) : given;
}

// One read of the alias table serves either side of the mixture: with
// `pick`, a sector drawn by u; without, the probability of `sector`, which
// BSDF sampling chose.
uint guide_choose_sector(GuideVertex g, bool pick, float u, uint sector, out float p) {
    uint n = sector_count();
    return alias_read(g.volume * n, n, pick, u, sector, p);
}

float guide_sector_probability(GuideVertex g, uint k) {
    float p;
    guide_choose_sector(g, false, 0.0, k, p);
    return p;
}

// NEE's choice of light at g (FLAG_GUIDE_LIGHTS): a light drawn by u from
// its volume's alias table (NO_VOLUME's row where it has none), and its
// probability p.
uint guide_choose_light(GuideVertex g, float u, out float p) {
    return alias_read(light_row(g.volume), light_groups(), true, u, 0u, p);
}

// The probability that NEE at g picks light l.
float guide_light_probability(GuideVertex g, uint l) {
    float p;
    alias_read(light_row(g.volume), light_groups(), false, 0.0, l, p);
    return p;
}

#endif
