// Local frames, the equal-area hemisphere map and BSDF sampling.
// src/sampling.rs holds the CPU twins of these functions.
#ifndef QTRACE_SAMPLING_GLSL
#define QTRACE_SAMPLING_GLSL

#define PI 3.14159265358979323846
#define INV_PI 0.31830988618379067154

// Orthonormal basis around n (Duff et al. 2017, branchless).
void make_frame(vec3 n, out vec3 t, out vec3 b) {
    float s = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (s + n.z);
    float c = n.x * n.y * a;
    t = vec3(1.0 + s * n.x * n.x * a, s * c, -s * n.x);
    b = vec3(c, s + n.y * n.y * a, -n.y);
}

// Shirley-Chiu concentric map: unit square -> unit disk, area-preserving.
vec2 square_to_disk(vec2 u) {
    vec2 o = 2.0 * u - 1.0;
    if (o.x == 0.0 && o.y == 0.0) {
        return vec2(0.0);
    }
    float r;
    float phi;
    if (abs(o.x) > abs(o.y)) {
        r = o.x;
        phi = (PI / 4.0) * (o.y / o.x);
    } else {
        r = o.y;
        phi = (PI / 2.0) - (PI / 4.0) * (o.x / o.y);
    }
    return r * vec2(cos(phi), sin(phi));
}

// Inverse of square_to_disk.
vec2 disk_to_square(vec2 p) {
    float r = length(p);
    vec2 o;
    if (r == 0.0) {
        o = vec2(0.0);
    } else if (abs(p.x) >= abs(p.y)) {
        float a = p.x >= 0.0 ? r : -r;
        o = vec2(a, a * atan(p.y / p.x) / (PI / 4.0));
    } else {
        float b = p.y >= 0.0 ? r : -r;
        o = vec2(b * atan(p.x / p.y) / (PI / 4.0), b);
    }
    return clamp(0.5 * (o + 1.0), 0.0, 1.0);
}

// Equal-area map unit square -> upper hemisphere (z >= 0): concentric disk,
// then the area-preserving lift z = 1 - r^2. Uniform u gives pdf 1 / (2 pi).
vec3 square_to_hemisphere(vec2 u) {
    vec2 d = square_to_disk(u);
    float r2 = dot(d, d);
    return vec3(d * sqrt(max(0.0, 2.0 - r2)), 1.0 - r2);
}

// Inverse of square_to_hemisphere for a local direction with z >= 0.
vec2 hemisphere_to_square(vec3 w) {
    float z = clamp(w.z, 0.0, 1.0);
    return disk_to_square(w.xy / sqrt(1.0 + z));
}

// cos(theta) at the centre of sector k of an a x b grid: the concentric map
// sends the centre to disk radius max(|x|, |y|) of its [-1, 1]^2 point, and
// the lift gives z = 1 - r^2.
float sector_cos(uint k, uint a, uint b) {
    vec2 o = 2.0 * vec2((float(k % a) + 0.5) / float(a), (float(k / a) + 0.5) / float(b)) - 1.0;
    float r = max(abs(o.x), abs(o.y));
    return 1.0 - r * r;
}

// Sector of a point of the unit square in an a x b grid.
uint square_sector(vec2 u, uint a, uint b) {
    uint i = min(uint(max(u.x, 0.0) * float(a)), a - 1u);
    uint j = min(uint(max(u.y, 0.0) * float(b)), b - 1u);
    return i + a * j;
}

// Sector of a local direction in an a x b grid over the square.
uint hemisphere_sector(vec3 w, uint a, uint b) {
    return square_sector(hemisphere_to_square(w), a, b);
}

// Cosine-weighted direction (Malley's method on the concentric disk).
vec3 sample_cosine(vec2 u) {
    vec2 d = square_to_disk(u);
    return vec3(d, sqrt(max(0.0, 1.0 - dot(d, d))));
}

#endif
