// Shared between GLSL and Rust (src/shaders.rs mirrors the structs; build.rs
// turns every `#define NAME <integer>` below into a Rust constant).
#ifndef QTRACE_SHARED_H
#define QTRACE_SHARED_H

// Read-only buffers of uvec4 words, declared by WORDS and read by FETCH: as
// uniform texel buffers, which Mesa 22's llvmpipe reads with one gather where
// a storage buffer read is a branching loop over SIMD lanes per 32-bit word,
// or, with QTRACE_STORAGE_READS (the `_storage` kernels), as storage buffers,
// which Mesa 25's reads faster (see gpu::Reads).
// A texel buffer is declared without a sampler (utextureBuffer): SPIR-V 1.6
// drops sampled images of buffers, and Mesa 25 warns of them.
#ifdef QTRACE_STORAGE_READS
#define WORDS(name, b) layout(std430, set = 0, binding = b) readonly buffer name##_block { uvec4 name[]; };
#define FETCH(name, i) name[i]
#else
#extension GL_EXT_samplerless_texture_functions : require
#define WORDS(name, b) layout(set = 0, binding = b) uniform utextureBuffer name;
#define FETCH(name, i) texelFetch(name, i)
#endif

// Workgroup sizes. lavapipe puts its SIMD lanes along x: a tile 4 wide left
// half of them idle and doubled the trace pass; 16x4 was no faster than 8x8.
#define TILE_X 8
#define TILE_Y 8
#define LINEAR_GROUP 64
// Invocations of the guide update's workgroup a volume (guide_build.comp's
// WIDE_UPDATE): 144 sectors in three rounds.
#define WIDE_UPDATE_GROUP 64
// Invocations per workgroup of every kernel that runs the Neural-Q network
// (the trace tile and LINEAR_GROUP; src/shaders.rs checks): each keeps its
// vectors in workgroup memory.
#define MLP_LANES 64

// Bindings (set 0; storage buffers, and buffers of words declared by WORDS).
#define B_NODES 0
#define B_TRIANGLES 1
#define B_MATERIALS 2
#define B_LIGHTS 3
#define B_SAMPLES 4
#define B_ACCUM 5
#define B_STATS 6
#define B_PROBE_IN 7
#define B_PROBE_OUT 8
#define B_Q 9
#define B_SECTORS 10
#define B_SUM 11
#define B_VISITS 12
#define B_VISITS_TOTAL 13
#define B_VOLUME_SUMS 14
#define B_LOOKUP_CELLS 15
#define B_LOOKUP_ITEMS 16
#define B_DIRECT_SUM 17
#define B_Q_DIRECT 18
// Neural-Q network (glsl/mlp.glsl).
#define B_MLP_PARAMS 19
#define B_MLP_MOMENTS 20
#define B_MLP_GRAD 21
#define B_MLP_INPUTS 22
#define B_MLP_TARGETS 23
#define B_MLP_ACTS 24
#define B_MLP_DELTAS 25
#define B_MLP_OUTPUTS 26
#define B_MLP_COUNT 27
#define B_NEURAL_VERTICES 28
#define B_LOOKUP_TRIANGLES 29
#define B_NEURAL_PENDING 30
// Neural-Q with inference at the volumes: each volume's point and normal.
#define B_NEURAL_STATES 31
// The training batch's rows grouped by sector (glsl/mlp_bucket.comp).
#define B_MLP_BUCKETS 32
// Rows with a target for every sector (training = "volumes"): per row and
// sector the target, then (after `capacity` rows) per row and sector the
// training pass's dLoss/dz.
#define B_MLP_DENSE 33
// Sarsa's learned share of BSDF sampling per volume (FLAG_LEARN_MIX): the
// pass's tallies of the gradient of the estimator's second moment with
// respect to the share's logit (positive part, negative part), and the
// logit's state (logit, Adam's two moments, steps).
#define B_MIX_GRAD 34
#define B_MIX_STATE 35
// Neural-Q's tables at the volumes: the target means' Q and visits.
#define B_MEAN_Q 36
#define B_MEAN_VISITS 37
// The race (src/render/race.rs): each pixel's sums when it began.
#define B_RACE_REF 38
// Trace dispatches' work counters (one per dispatch of a submit).
#define B_WORK 39
// Sarsa's choice of light for NEE (FLAG_GUIDE_LIGHTS), per (volume, light):
// the pass's tallies of what the light brought and of tries, their running
// mean and count, and each light's share of the scene's emitted power.
#define B_LIGHT_SUM 40
#define B_LIGHT_TRIES 41
#define B_LIGHT_MEAN 42
#define B_LIGHT_SEEN 43
#define B_LIGHT_POWER 44
// Shading normals at each triangle's corners, three packed normals a texel
// (pack_normal in src/scene/mod.rs), where CONSTANT_SHADING_NORMALS says so.
#define B_NORMALS 45
// Point, spot and directional lights (DeltaLight), which only NEE reaches;
// the light list names one by LIGHT_DELTA | its index here.
#define B_DELTA_LIGHTS 46
// Texture coordinates at each triangle's corners (two texels: u0 v0 u1 v1,
// u2 v2), and the textures (TEXTURE_*), where FEATURE_TEXTURES says so.
#define B_UVS 47
#define B_TEXTURES 48
// Per triangle, the values at its corners (three texels, rgb) of each mesh
// attribute the scene's textures read (TEXTURE_ATTRIBUTE), where
// FEATURE_ATTRIBUTES says so.
#define B_ATTRIBUTES 50
// The environment (glsl/environment.glsl): a header of
// ENVIRONMENT_HEADER_WORDS words ((width, height, cells, first cell word);
// the rows of to_local, whose w hold NEE's cells' block width and height
// and their columns), its texels (RGB radiance, a word each, or with
// SKY_DENSE floats one after another: four texels in three words), then
// for NEE per cell (density, part), then each part's alias table (a slot
// each: threshold, alias slot, cell, its density). Its fifth header word: the cells of
// its two parts (the second 0 where there is one) and their shares of its
// power. NEE's light list names its parts by LIGHT_ENVIRONMENT | part;
// PassParams.environment.x is the probability NEE picks the sky at all.
#define B_ENVIRONMENT 49
#define ENVIRONMENT_HEADER_WORDS 5
// NEE's cells of a sky: at most this many columns, half as many rows (a
// block of the cells between texels each, on larger maps).
#define MAX_SKY_CELLS 1024
#define LIGHT_ENVIRONMENT 0x40000000u
#define LIGHT_DELTA 0x80000000u
#define DELTA_POINT 0
#define DELTA_SPOT 1
#define DELTA_DIRECTIONAL 2
// Mitsuba's projector: a pinhole that casts an image (DeltaLight says how).
#define DELTA_PROJECTOR 3

// PassParams.flags bits.
#define FLAG_NEE 1
#define FLAG_UNIFORM 2
// Guides: record updates this pass (off once learning is frozen).
#define FLAG_LEARN 4
// Modes measured not to pay (docs/guides.md, "Experiments"): their flags are
// read, and their code built, only with the cargo feature `experiments`
// (build.rs then defines EXPERIMENTS).
#ifdef EXPERIMENTS
#define EXPERIMENT(flag) ((params.flags & (flag)) != 0u)
#else
#define EXPERIMENT(flag) false
#endif
// Guides: sample sectors in proportion to Q instead of Q * cos(theta).
#define FLAG_Q_DISTRIBUTION 8
// Neural: the Q-learning target (max over sectors) instead of the expected one.
#define FLAG_MAX_TARGET 16
// Neural: encode the state by the scene's vertices relative to it (thesis).
#define FLAG_VERTEX_ENCODING 32
// Sarsa: learn each volume's share of BSDF sampling (else guide_epsilon).
#define FLAG_LEARN_MIX 64
// The share's logit: Adam's learning rate, and its bounds (a share in
// [0.047, 0.953]: BSDF sampling never stops, so the image stays unbiased).
#define MIX_LEARNING_RATE 0.3
#define MIX_LOGIT_BOUND 3.0
// Sarsa: the visits a sector's Q counts as having of its volume's mean
// target where its sampling table and sums are built, so that a sector
// seen once or never does not set the table alone (docs/guides.md).
#define Q_PRIOR_VISITS 2
// Sarsa: each volume learns which light NEE should pick there, as an alias
// table over the scene's lights after the sector tables (guide_build.comp).
#define FLAG_GUIDE_LIGHTS 128
// ... and flags >> this is how many lights they pick among (LightGroup).
#define LIGHT_GROUPS_SHIFT 24
// The film samples beyond its border (Mitsuba's sample_border): a pixel's
// filter is not cut at the image's edge.
#define FLAG_SAMPLE_BORDER 256
// Scenes with several lights (src/guide/sarsa.rs, guided_light_power), at
// most this many, get it.
#define MAX_GUIDED_LIGHTS 16
// The share of a volume's choice that follows emitted power (as `pt` picks)
// whatever was learned, so that every light keeps being tried.
#define LIGHT_POWER_SHARE 0.25
// Tries a volume needs, over all lights, before its choice follows them.
#define LIGHT_MIN_TRIES 16

// Probe kernel modes (tests of the GLSL building blocks).
#define PROBE_TRACE 0
#define PROBE_HEMISPHERE 1
#define PROBE_NEAREST_VOLUME 2
#define PROBE_GUIDE_SAMPLE 3
#define PROBE_SARSA_UPDATE 4
#define PROBE_BSDF 5
#define PROBE_LIGHT_CHOICE 6
#define PROBE_LIGHT_TRY 7
#define PROBE_TEXTURE 8
#define PROBE_ENVIRONMENT 9

// What a lookup returns when no volume faces the right way.
#define NO_VOLUME 0xffffffffu

// Most sample passes recorded into one submit; each has its PassStats slot
// (pass_index % MAX_BATCH).
#define MAX_BATCH 16
// Copies of each pass's stats, summed on the host: workgroups add to the copy
// of their index modulo this, so that on a GPU thousands of workgroups do not
// queue on the same few words (compare-and-swap retries most of all).
#define STATS_COPIES 64

// Bounces before Russian roulette may end a path.
#define RR_START_DEPTH 3
// ... for a path that does not count yet (trace.comp, survives_roulette).
#define PENDING_RR_START_DEPTH 5
// Most bounce steps one trace invocation takes: llvmpipe silently ends every
// loop of an invocation once they have run 65 535 iterations in all.
#define MAX_TRACE_STEPS 65000
// Most paths one trace invocation takes from its dispatch's work (see
// trace.comp). llvmpipe's iteration limit counts every loop of an invocation
// together (the BVH walks' steps too), so an invocation's work must stay
// bounded: this is twice the share per lane of a full dispatch (MAX_BATCH).
#define MAX_CLAIMS 32
// PassParams.selector of a trace dispatch: its samples-buffer slot, and
// above WORK_SLOT_SHIFT its work counter in the submit.
#define WORK_SLOT_SHIFT 8
// PathSample.lengths (MAX_DEPTH keeps both counts within their bits).
#define PATH_RAYS_SHIFT 16
#define PATH_LEARNED 0x80000000
// BvhNode child references.
#define BVH_LEAF 0x80000000
#define BVH_NO_CHILD 0xffffffff

// Neural-Q state encoding: position and normal, then sin and cos of the
// position at this many octaves.
#define ENCODING_FREQUENCIES 4
// 6 + 6 * ENCODING_FREQUENCIES, padded with zeros to a multiple of 4.
#define ENCODED_INPUTS 32
// The network's loss is relative: 0.5 (target - Q)^2 / (Q^2 + epsilon), Q
// held constant (as neural radiance caching's), epsilon = 1 / this.
#define MLP_LOSS_EPSILON_INV 100

// Bytes of the structs GLSL code needs the size of; build.rs checks each
// against the struct's std430 layout, and every struct's fields against
// its Rust mirror.
#define SIZEOF_PASS_STATS 48

// A BVH node holds its two children. A child is another node's index (its
// box is a = min, b = max), BVH_LEAF | the index of its one triangle (held
// here as a = v0, b = e1, c = e2, so a step reads one node), or
// BVH_NO_CHILD. `axis` is the axis the node split: child 0 holds the lower
// side. Walks visit the children in the order a ray's direction meets them
// along that axis, so each of the 8 direction octants has a depth-first
// order of the nodes, and `escapes[octant]` is the node after this one's
// subtree in it (BVH_NO_CHILD after the last): where the walk's short stack
// overflowed, it goes on from there.
struct BvhNode {
    vec3 a0;
    uint child0;
    vec3 b0;
    uint axis;
    vec3 c0;
    uint pad0;
    vec3 a1;
    uint child1;
    vec3 b1;
    uint pad1;
    vec3 c1;
    uint pad2;
    uint escapes[8];   // per octant = (d.x < 0) | (d.y < 0) << 1 | (d.z < 0) << 2
};// A triangle as v0 and two edges; the geometric normal is cross(e1, e2).
struct Triangle {
    vec3 v0;
    uint material;
    vec3 e1;
    float light_pdf;   // P(choose this light) / area; 0 for non-emitters
    vec3 e2;
    float area;
};

// Material kinds (docs/scenes.md), in Material.color.w.
#define MATERIAL_DIFFUSE 0
#define MATERIAL_CONDUCTOR 1
// A dielectric of index emission.w, eta.rgb tinting its reflection; rough
// (Mitsuba's roughdielectric) where k.z, its alpha, is above 0.
#define MATERIAL_DIELECTRIC 2
// Mitsuba's plastic: a diffuse base (color) under a smooth coat of relative
// index emission.w; eta.rgb is its specular reflectance, k.x the coat's
// internal diffuse reflectance, k.y the specular lobe's sampling weight.
// Rough (roughplastic) where k.z, its alpha, is above 0: k.w is then the
// word of the materials' buffer where its coat's transmittance table
// (ROUGH_TABLE_SIZE floats, after the materials) begins.
#define MATERIAL_PLASTIC 3
#define ROUGH_TABLE_SIZE 64
// Mitsuba's thindielectric: a thin sheet of relative index emission.w that
// reflects (eta.rgb tints) or lets light straight through (color tints),
// its inner reflections summed.
#define MATERIAL_THIN 4
// Mitsuba's mask, blendbsdf and twosided with two BSDFs: a material that
// stands for one of two others (emission.x and emission.y, as floats),
// chosen at each hit before any shading: by the side the path arrives on
// (color.z CHOICE_BY_SIDE: the first on the front), or at random, the
// second with probability color.x, or where color.y is above 0 the
// luminance of texture color.y - 1 there (CHOICE_AT_RANDOM; CHOICE_MASK
// for a mask, whose first is its clear part and second the masked
// material, its opacity the weight). Either may be a choice itself, to
// MAX_CHOICE_DEPTH levels. Where FEATURE_CHOICES says so.
#define MATERIAL_CHOICE 5
// Mitsuba's principled (src/bsdf/principled.rs): color.rgb its base
// colour, emission.w its roughness, eta.rgb its metallic, specular tint and
// sheen, k.rgb its sheen tint, flatness and clearcoat, k.w the word of the
// materials' buffer where (eta, clearcoat gloss, spec_trans, anisotropic)
// follow the materials. Where FEATURE_PRINCIPLED says so.
#define MATERIAL_PRINCIPLED 6
// Mitsuba's principledthin, laid out as a principled material: eta.x holds
// the share of its diffuse part it lets through (diff_trans / 2) in place
// of metallic; its clearcoat is 0. Where FEATURE_PRINCIPLED_THIN says so.
#define MATERIAL_PRINCIPLED_THIN 7
#define CHOICE_AT_RANDOM 0
#define CHOICE_BY_SIDE 1
#define CHOICE_MASK 2
#define MAX_CHOICE_DEPTH 4
// Added to the kind: the material is black on the side its triangle's
// normal does not face (Mitsuba's BSDFs outside `twosided`).
#define MATERIAL_ONE_SIDED 8
// Added to a rough lobe's kind: Beckmann's distribution instead of GGX's;
// to a conductor's: a Fresnel term of complex index eta + i k.
#define MATERIAL_BECKMANN 16
#define MATERIAL_FRESNEL 32
// Added to a plastic's kind: its internal scattering per colour (Mitsuba's
// `nonlinear`).
#define MATERIAL_NONLINEAR 64
// In CONSTANT_MATERIAL_FEATURES only: the scene has a plastic, a rough glass,
// a rough plastic.
#define FEATURE_PLASTIC 128
#define FEATURE_ROUGH_GLASS 256
#define FEATURE_ROUGH_PLASTIC 512
// ... a textured material (its texture slots in Material.eta.w).
#define FEATURE_TEXTURES 1024
// ... a normal-mapped material (Mitsuba's normalmap): its kind's bits from
// MATERIAL_NORMAL_MAP_SHIFT on hold 1 + the index of its normals' texture.
#define FEATURE_NORMAL_MAPS 2048
#define MATERIAL_NORMAL_MAP_SHIFT 8
// Added to a normal-mapped material's kind: the map lies inside `twosided`,
// so the unmapped normal tells the sides apart, and the back's normal is the
// mapped one mirrored (else the mapped normal tells them, as the BSDF under
// the map sees it).
#define MATERIAL_MAP_IN_TWOSIDED 128
// Added to a normal-mapped material's kind: the texture is Mitsuba's
// bumpmap's height field, its gradient times emission.x (the material
// emits nothing) tilting the normal.
#define MATERIAL_MAP_BUMP 131072
// Added to an emitter's kind: its BSDF is Mitsuba's null (as exporters give
// Blender's lights), so paths go on straight through it, each a bounce, as
// through any null surface; other emitters end a path.
#define MATERIAL_EMITTER_PASSES 262144
// Added to an emitter's kind: its BSDF scatters light (neither black nor
// null: a diffuse, a rough metal), so paths gather its emission and are
// shaded there as on any surface, as in Mitsuba (FEATURE_EMITTERS_REFLECT).
#define MATERIAL_EMITTER_REFLECTS 524288
// Added to an emitter's kind: some of its triangles' corner normals differ
// from their faces' (a smooth mesh, or normals against the winding), so it
// emits on the side its shading normal faces, as Mitsuba's area lights do
// (emits_along); other emitters need not read their normals. An emitter has
// no normal map, whose bits this shares.
#define MATERIAL_EMITTER_SMOOTH 1048576
// ... a choice (MATERIAL_CHOICE).
#define FEATURE_CHOICES 4096
// ... a principled material (MATERIAL_PRINCIPLED).
#define FEATURE_PRINCIPLED 8192
// ... an anisotropic roughness (a rough conductor's or rough glass's alpha
// across its tangent in k.w; a principled material's `anisotropic`).
#define FEATURE_ANISOTROPIC 16384
// ... a texture of mesh attributes (TEXTURE_ATTRIBUTE), whose values
// B_ATTRIBUTES holds.
#define FEATURE_ATTRIBUTES 32768
// ... an emitter whose BSDF scatters (MATERIAL_EMITTER_REFLECTS).
#define FEATURE_EMITTERS_REFLECT 65536
// ... a thin principled material (MATERIAL_PRINCIPLED_THIN; FEATURE_PRINCIPLED
// too).
#define FEATURE_PRINCIPLED_THIN 131072
// ... a projector among the delta lights (DELTA_PROJECTOR), or a spot light
// that casts an image: their code costs the other delta lights' NEE on
// lavapipe where compiled in.
#define FEATURE_PROJECTORS 262144
// ... an area light whose radiance is a texture (in its colour slot): its
// lookups cost a textured scene's trace kernel 8-17% on lavapipe where
// compiled in.
#define FEATURE_TEXTURED_LIGHTS 524288
// ... an emitter that emits on the side its shading normal faces
// (MATERIAL_EMITTER_SMOOTH): reading that normal costs other scenes' trace
// kernel 1.2% of its instructions on lavapipe where compiled in.
#define FEATURE_SMOOTH_LIGHTS 1048576
// Specialization constant of the kernels that shade: whether the scene has a
// material that is not diffuse (constants 0-3 are a network's shape).
#define CONSTANT_NON_DIFFUSE 4
// Specialization constant of Sarsa's trace kernels: the guide picks the
// light for NEE (FLAG_GUIDE_LIGHTS), so the code is left out where not.
#define CONSTANT_GUIDE_LIGHTS 5
// Specialization constant of the trace kernels: the scene has shading
// normals (B_NORMALS), so the code that reads them is built in.
#define CONSTANT_SHADING_NORMALS 6
// Specialization constant of the trace kernels: how a camera ray's point in
// its pixel is drawn (PixelFilter in src/scene/mod.rs): uniformly, from a
// tent of radius cam_forward.w, or from a Gaussian of standard deviation
// cam_forward.w. A constant, so the box filter's kernel has no other's code.
#define CONSTANT_PIXEL_FILTER 7
#define FILTER_BOX 0
#define FILTER_TENT 1
#define FILTER_GAUSSIAN 2
// Filters with negative lobes (Mitsuba's mitchell and catmullrom, cubics of
// B and C in PassParams.environment.yz, and lanczos of cam_forward.w
// lobes): a sample's point is drawn from the filter's magnitude, and its
// radiance carries the sign and the normalization (trace.comp,
// signed_filter_axis).
#define FILTER_CUBIC 3
#define FILTER_LANCZOS 4
// Specialization constant of the kernels that shade: the MATERIAL_BECKMANN,
// MATERIAL_FRESNEL and MATERIAL_NONLINEAR flags some material of the scene
// has, and FEATURE_PLASTIC (all, where not given), so that a scene without
// them runs no code for them.
#define CONSTANT_MATERIAL_FEATURES 8
// Specialization constant of the trace kernels: the scene has delta lights
// (B_DELTA_LIGHTS).
#define CONSTANT_DELTA_LIGHTS 9
// Specialization constant of the trace kernels: the scene's environment
// (B_ENVIRONMENT): none, its texels a word each, or packed (a sky too
// large for one buffer otherwise).
#define CONSTANT_ENVIRONMENT 10
#define SKY_NONE 0
#define SKY_TEXEL_WORDS 1
#define SKY_DENSE 2
// ... an analytic sky (Mitsuba's sunsky), whose words take the texels'
// place (sky_model in glsl/environment.glsl); its texels, on the host
// only, shaped NEE's cells.
#define SKY_MODEL 3
// Specialization constant of the trace kernels: Mitsuba's hide_emitters (the
// camera's ray passes through emitters, and the sky is black to a path whose
// every bounce so far went straight through a null surface or a thin sheet,
// Mitsuba's null lobe).
#define CONSTANT_HIDE_EMITTERS 11
// Specialization constants of the trace kernels: the camera is a thin lens
// (PassParams.cam_right.w above 0); some material has a normal map
// (FEATURE_NORMAL_MAPS). Constants, so that other scenes run no code for them.
#define CONSTANT_THIN_LENS 12
#define CONSTANT_NORMAL_MAPS 13
// ... the camera is orthographic: rays along cam_forward from cam_pos plus
// the image point times cam_right and cam_up (half extents).
#define CONSTANT_ORTHOGRAPHIC 14

struct Material {
    vec4 color;        // rgb: Kd (diffuse), Ks (conductor) or Tf (dielectric); w: kind (+ MATERIAL_* flags)
    vec4 emission;     // rgb: radiance, emitted on the front side only;
                       // w: alpha (conductor; 0 is a mirror) or Ni (dielectric)
    vec4 eta;          // rgb: a conductor's eta (with MATERIAL_FRESNEL); w: its texture slots (as bits)
    vec4 k;            // rgb: a conductor's k (with MATERIAL_FRESNEL); w: see MATERIAL_PLASTIC
};

// Textures (glsl/texture.glsl). A material's slots, TEXTURE_SLOT_BITS each
// in the bits of eta.w, hold 1 + the index of the texture that replaces its
// colour (Bsdf.color), its second colour (Bsdf.ior_eta where it is one) and
// its alpha, or 0. The texture buffer holds the linear values of the 256
// sRGB bytes (TEXTURE_TABLE_WORDS words), then TEXTURE_HEADER_WORDS words
// per texture: (flags, first word of its texels, width, height) and the
// two rows of its to_uv; then the texels: one float RGB a word, or four
// 8-bit RGB a word (TEXTURE_BYTES), or a checkerboard's two colours; a mesh
// attribute (TEXTURE_ATTRIBUTE) has none: its header holds its scale, its
// place among each triangle's attributes in B_ATTRIBUTES and their number.
#define TEXTURE_SLOT_BITS 9
// Set in every word of slots, so that it reads as a normal float.
#define TEXTURE_SLOT_MARK 0x40000000u
#define TEXTURE_SLOT_COLOR 0
#define TEXTURE_SLOT_SECOND 1
#define TEXTURE_SLOT_ALPHA 2
// Rough glass's alpha across its tangent: not among eta.w's bits but in its
// k.w (which holds that alpha where it is a number), as -(1 + index).
#define TEXTURE_SLOT_ACROSS 3
// A principled material's weights that live in its Bsdf: specular tint,
// sheen, sheen tint, flatness, clearcoat, clearcoat gloss, anisotropic and
// spec_trans, each 1 + the index of its texture or 0, in its record (the
// floats after eta, clearcoat gloss, spec_trans and anisotropic: slot s is
// float s).
#define TEXTURE_SLOT_HIGHLIGHT_TINT 4
#define TEXTURE_SLOT_SHEEN 5
#define TEXTURE_SLOT_SHEEN_TINT 6
#define TEXTURE_SLOT_FLATNESS 7
#define TEXTURE_SLOT_CLEARCOAT 8
#define TEXTURE_SLOT_CLEARCOAT_GLOSS 9
#define TEXTURE_SLOT_ANISOTROPIC 10
#define TEXTURE_SLOT_TRANSMISSION 11
#define TEXTURE_HEADER_WORDS 3
#define TEXTURE_TABLE_WORDS 64
#define TEXTURE_FLOATS 0
#define TEXTURE_BYTES 1
#define TEXTURE_CHECKERBOARD 2
#define TEXTURE_ATTRIBUTE 3
#define TEXTURE_SRGB 4
#define TEXTURE_NEAREST 8
#define TEXTURE_REPEAT 0
#define TEXTURE_MIRROR 16
#define TEXTURE_CLAMP 32

// An entry of NEE's light list: an emissive triangle, a delta light
// (LIGHT_DELTA) or the sky (LIGHT_ENVIRONMENT); chosen by `cdf` (inclusive).
struct Light {
    uint triangle;
    float cdf;
    float pdf;         // P(choose this light)
    uint group;        // the light (LightGroup) it is part of
};

// What the guides pick for NEE (FLAG_GUIDE_LIGHTS): a light, which is an
// emitter's connected triangles, a delta light or the sky; NEE then draws
// one of its entries by power. Where the guides may pick, the light list's
// buffer holds after NEE's list the lights (light_groups() of them), then
// their members, each light's together.
struct LightGroup {
    uint first;        // its first member, counted from the first LightMember
    uint count;
    float power;       // its members' summed pdf
    uint pad;
};

struct LightMember {
    uint light;        // its entry in NEE's list
    float cdf;         // inclusive, within its light
    uint pad0;
    uint pad1;
};

// A light only NEE reaches (Mitsuba's point, spot, directional and
// projector). A projector: position.w is DELTA_PROJECTOR + 4 (1 + its
// image's texture index, or 0 where its irradiance is a colour);
// intensity.rgb is pi scale (times that colour), intensity.w the
// cotangent of half its field of view across; axis.xyz its forward axis,
// axis.w its image's width over height; falloff.xyz its image's x axis,
// falloff.w 1, or -1 where its frame is mirrored. A spot light that casts
// an image: position.w is DELTA_SPOT + 4 (1 + its texture index); its
// image's x axis is cos(falloff.z) t + sin(falloff.z) b, (t, b) make_frame
// of its axis, and falloff.w is 1, or -1 where its frame is mirrored.
struct DeltaLight {
    vec4 position;  // xyz: where it is (point, spot) or the direction its light travels (directional); w: DELTA_*
    vec4 intensity; // rgb: intensity (point, spot) or irradiance (directional); w: spot: cos of the cutoff angle
    vec4 axis;      // xyz: a spot's axis; w: cos of its beam width
    vec4 falloff;   // x: a spot's cutoff angle, y: 1 / (cutoff angle - beam width), in radians
};

// One path's result, written by the trace pass, read by accumulate.
// `lengths` packs the path's surface hits (low 16 bits) and the rays it
// cast, shadow rays included (from bit PATH_RAYS_SHIFT), with PATH_LEARNED
// set by the kernels that learn, which alone write the words after it: on
// lavapipe every 32-bit word stored costs a loop over the SIMD lanes, run
// at every bounce (11% of a `pt` render's time with eight words).
struct PathSample {
    vec3 radiance;
    uint lengths;
    uint td_count;     // guide updates made along the path
    float td_sq_sum;   // their summed squared temporal-difference error
    uint pad0;
    uint pad1;
};

// Running sums per pixel.
struct Accum {
    vec4 sum;          // rgb sum of path estimates, w = sample count
    vec4 sum_sq;       // rgb sum of squares
};

// Totals of one sample pass (reset before each pass).
struct PassStats {
    uint paths;
    uint zero_paths;
    uint length_sum;
    uint rays;
    uint nan_paths;
    uint td_count;     // guide updates this pass
    uint td_sq_bits;   // float bits: their summed squared TD error (the pass's loss)
    uint dev_bits;     // float bits: summed relative squared deviation from pixel means
    uint lap_bits[4];  // float bits, a race's passes only (accumulate.comp)
};

// Push constants shared by every pass of a render.
struct PassParams {
    vec4 cam_pos;      // xyz, w = ray offset epsilon
    vec4 cam_right;    // r * tan(horizontal fov / 2), w = a thin lens's radius (0: a pinhole)
    vec4 cam_up;       // u * tan(vertical fov / 2), w = the lens's focus distance
    vec4 cam_forward;  // f, w = the pixel filter's radius or deviation
    vec4 environment;  // x: the probability NEE picks the environment; y, z: a cubic filter's B and C, w: its magnitude's bound
    uint width;
    uint height;
    uint pass_index;
    uint seed;
    uint max_depth;
    uint flags;
    uint light_count;
    uint selector;     // probe kernels: the block to run; trace: the samples slot of its first sample, | its work counter << WORK_SLOT_SHIFT
    uint item_count;   // items of a probe pass; trace and accumulate: samples per pixel
    uint volume_count; // guides: radiance volumes
    uint sector_grid;  // guides: a | (b << 16), n = a * b sectors
    float guide_epsilon; // guides: weight of cosine sampling in the mixture
};

// One sector of a volume's sampling distribution, as an alias table (Walker)
// in whole units: sector k has weight w_k of W = n C units, C = 65535 / n
// a column, and P(k) = w_k / W is the exact probability of a draw, which
// keeps the pdf right in 8 bytes. Column k keeps `kept` of its C units for
// sector k and gives the rest to `alias`; w_alias is the alias's weight.
struct SectorEntry {
    uint weights; // w_k | w_alias << 16
    uint column;  // kept | alias << 16
};

// One training transition of the Neural-Q network (its input is in the
// inputs buffer at the same index): the loss is 0.5 (target - Q_sector)^2.
struct MlpTarget {
    uint sector;
    float target;
    float loss;        // written by the training pass
    float delta;       // dLoss/dz of the sector's output, written by the training pass
};

// The Neural-Q training batch the trace kernel fills: each transition is
// offered with `probability` and takes slot `count` (counted even when past
// capacity, so the batch pass can aim the next pass's probability at it).
struct MlpBatch {
    uint count;
    uint capacity;
    float probability;
    uint vertex_count; // the scene's vertices, for the vertex encoding
    vec4 bounds_min;   // the scene's box, for the encoding
    vec4 bounds_scale; // 1 / its extent
};

// Push constants of the network's own passes.
struct MlpPush {
    uint capacity;     // rows of the inputs/targets buffers
    uint step;         // Adam step, from 1
    float learning_rate;
    float beta1;
    float beta2;
    float epsilon;
    uint pad[2];
};

#endif
