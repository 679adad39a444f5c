//! CPU twins of `glsl/sampling.glsl`: local frames and the equal-area hemisphere
//! map that the guides' sector grids are built on.

use glam::{Vec2, Vec3};
use std::f32::consts::{FRAC_PI_2, FRAC_PI_4};

/// Orthonormal basis (t, b) around the unit normal n (Duff et al. 2017).
pub fn make_frame(n: Vec3) -> (Vec3, Vec3) {
    let s = if n.z >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (s + n.z);
    let c = n.x * n.y * a;
    (
        Vec3::new(1.0 + s * n.x * n.x * a, s * c, -s * n.x),
        Vec3::new(c, s + n.y * n.y * a, -n.y),
    )
}

/// Shirley–Chiu concentric map: unit square → unit disk, area-preserving.
pub fn square_to_disk(u: Vec2) -> Vec2 {
    let o = 2.0 * u - Vec2::ONE;
    if o == Vec2::ZERO {
        return Vec2::ZERO;
    }
    let (r, phi) = if o.x.abs() > o.y.abs() {
        (o.x, FRAC_PI_4 * (o.y / o.x))
    } else {
        (o.y, FRAC_PI_2 - FRAC_PI_4 * (o.x / o.y))
    };
    r * Vec2::new(phi.cos(), phi.sin())
}

/// Inverse of [`square_to_disk`].
pub fn disk_to_square(p: Vec2) -> Vec2 {
    let r = p.length();
    let o = if r == 0.0 {
        Vec2::ZERO
    } else if p.x.abs() >= p.y.abs() {
        let a = if p.x >= 0.0 { r } else { -r };
        Vec2::new(a, a * (p.y / p.x).atan() / FRAC_PI_4)
    } else {
        let b = if p.y >= 0.0 { r } else { -r };
        Vec2::new(b * (p.x / p.y).atan() / FRAC_PI_4, b)
    };
    (0.5 * (o + Vec2::ONE)).clamp(Vec2::ZERO, Vec2::ONE)
}

/// Equal-area map unit square → upper hemisphere (z ≥ 0): the concentric disk
/// lifted by z = 1 − r². Every region of the square keeps its share of 2π sr.
pub fn square_to_hemisphere(u: Vec2) -> Vec3 {
    let d = square_to_disk(u);
    let r2 = d.length_squared();
    let s = (2.0 - r2).max(0.0).sqrt();
    Vec3::new(d.x * s, d.y * s, 1.0 - r2)
}

/// Inverse of [`square_to_hemisphere`] for a local direction with z ≥ 0.
pub fn hemisphere_to_square(w: Vec3) -> Vec2 {
    let z = w.z.clamp(0.0, 1.0);
    disk_to_square(Vec2::new(w.x, w.y) / (1.0 + z).sqrt())
}

/// Sector index of a local direction in an `a` × `b` grid over the square.
pub fn hemisphere_sector(w: Vec3, a: u32, b: u32) -> u32 {
    let u = hemisphere_to_square(w);
    let i = ((u.x * a as f32) as u32).min(a - 1);
    let j = ((u.y * b as f32) as u32).min(b - 1);
    i + a * j
}

/// Cosine-weighted direction (Malley's method); pdf cos θ / π.
pub fn sample_cosine(u: Vec2) -> Vec3 {
    let d = square_to_disk(u);
    Vec3::new(d.x, d.y, (1.0 - d.length_squared()).max(0.0).sqrt())
}

/// cos θ at the centre of sector k of an a×b grid (as `sector_cos` in
/// glsl/sampling.glsl): the concentric map sends the centre to disk radius
/// max(|x|, |y|) of its [-1, 1]² point, and the lift gives z = 1 − r².
pub fn sector_cos(k: u32, a: u32, b: u32) -> f32 {
    let o =
        2.0 * Vec2::new(
            ((k % a) as f32 + 0.5) / a as f32,
            ((k / a) as f32 + 0.5) / b as f32,
        ) - Vec2::ONE;
    let r = o.x.abs().max(o.y.abs());
    1.0 - r * r
}

/// The centres of an n × n grid over the unit square (tests' stratified samples).
#[cfg(test)]
pub(crate) fn grid(n: usize) -> impl Iterator<Item = Vec2> {
    (0..n).flat_map(move |i| {
        (0..n).map(move |j| Vec2::new((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f32::consts::PI;

    #[test]
    fn hemisphere_map_inverts() {
        for u in grid(64) {
            let w = square_to_hemisphere(u);
            assert!((w.length() - 1.0).abs() < 1e-5, "not unit: {w}");
            assert!(w.z >= 0.0);
            let back = hemisphere_to_square(w);
            assert!(
                (back - u).abs().max_element() < 1e-4,
                "{u} -> {w} -> {back}"
            );
        }
    }

    #[test]
    fn frame_is_orthonormal() {
        for u in grid(16) {
            let n = square_to_hemisphere(u) * if u.x > 0.5 { 1.0 } else { -1.0 };
            let n = n.normalize();
            let (t, b) = make_frame(n);
            for (x, y) in [(t, b), (t, n), (b, n)] {
                assert!(x.dot(y).abs() < 1e-5);
            }
            assert!((t.cross(b) - n).length() < 1e-4, "right-handed frame");
        }
    }

    /// Each sector of the 12×12 grid covers 2π/144 sr: its share of uniformly
    /// distributed directions matches 1/144 within Monte Carlo error.
    #[test]
    fn hemisphere_sectors_are_equal_area() {
        let (a, b) = (12u32, 12u32);
        let n = (a * b) as usize;
        let mut counts = vec![0u32; n];
        // Stratified uniform directions on the hemisphere from (cos θ, φ) directly,
        // independent of the map under test.
        let m = 1200usize;
        for i in 0..m {
            for j in 0..m {
                let z = (i as f32 + 0.5) / m as f32; // uniform in cos θ = uniform in solid angle
                let phi = 2.0 * PI * (j as f32 + 0.5) / m as f32;
                let s = (1.0 - z * z).sqrt();
                let w = Vec3::new(s * phi.cos(), s * phi.sin(), z);
                counts[hemisphere_sector(w, a, b) as usize] += 1;
            }
        }
        let expected = (m * m) as f32 / n as f32;
        for (k, &c) in counts.iter().enumerate() {
            let rel = (c as f32 - expected).abs() / expected;
            assert!(
                rel < 0.02,
                "sector {k}: {c} directions, expected {expected}"
            );
        }
    }
}
