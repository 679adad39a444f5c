//! Procedural geometry: large meshes made by code rather than committed.

use super::file::Procedural;
use glam::Vec3;

/// Triangles (counter-clockwise seen from outside) and the albedo of one procedural object.
pub struct Generated {
    pub triangles: Vec<[Vec3; 3]>,
    pub albedo: Vec3,
    pub name: String,
}

/// Largest triangle count one procedural object may ask for.
pub const MAX_TRIANGLES: u64 = 20_000_000;

pub fn triangle_count(p: &Procedural) -> u64 {
    match *p {
        Procedural::BumpySphere {
            segments, rings, ..
        } => 2 * segments as u64 * (rings as u64).saturating_sub(1),
    }
}

/// Checks the parameters; the message names the problem.
pub fn validate(p: &Procedural) -> Result<(), String> {
    match *p {
        Procedural::BumpySphere {
            segments,
            rings,
            radius,
            amplitude,
            frequency,
            center,
            albedo,
        } => {
            if segments < 3 || rings < 2 {
                return Err("bumpy-sphere needs segments >= 3 and rings >= 2".into());
            }
            if triangle_count(p) > MAX_TRIANGLES {
                return Err(format!(
                    "bumpy-sphere would have {} triangles (at most {MAX_TRIANGLES})",
                    triangle_count(p)
                ));
            }
            let finite = center.iter().chain(&albedo).all(|v| v.is_finite())
                && radius.is_finite()
                && amplitude.is_finite()
                && frequency.is_finite();
            if !finite || radius <= 0.0 || amplitude.abs() >= radius {
                return Err(
                    "bumpy-sphere needs finite values and 0 <= |amplitude| < radius".into(),
                );
            }
            if albedo.iter().any(|&a| !(0.0..=1.0).contains(&a)) {
                return Err("bumpy-sphere albedo must lie in [0, 1]".into());
            }
            Ok(())
        }
    }
}

pub fn generate(p: &Procedural) -> Generated {
    match *p {
        Procedural::BumpySphere {
            center,
            radius,
            segments,
            rings,
            amplitude,
            frequency,
            albedo,
        } => {
            let center = Vec3::from(center);
            let point = |theta: f32, phi: f32| {
                let r = radius + amplitude * (frequency * theta).sin() * (frequency * phi).sin();
                center
                    + r * Vec3::new(
                        theta.sin() * phi.cos(),
                        theta.cos(),
                        theta.sin() * phi.sin(),
                    )
            };
            let theta = |i: u32| std::f32::consts::PI * i as f32 / rings as f32;
            let phi = |j: u32| 2.0 * std::f32::consts::PI * (j % segments) as f32 / segments as f32;
            let top = center + Vec3::new(0.0, radius, 0.0);
            let bottom = center - Vec3::new(0.0, radius, 0.0);
            let mut triangles = Vec::with_capacity(triangle_count(p) as usize);
            for j in 0..segments {
                // Pole caps are fans, so no triangle collapses to a point.
                triangles.push([top, point(theta(1), phi(j + 1)), point(theta(1), phi(j))]);
                triangles.push([
                    bottom,
                    point(theta(rings - 1), phi(j)),
                    point(theta(rings - 1), phi(j + 1)),
                ]);
            }
            for i in 1..rings - 1 {
                for j in 0..segments {
                    let a = point(theta(i), phi(j));
                    let b = point(theta(i), phi(j + 1));
                    let c = point(theta(i + 1), phi(j + 1));
                    let d = point(theta(i + 1), phi(j));
                    triangles.push([a, b, c]);
                    triangles.push([a, c, d]);
                }
            }
            Generated {
                triangles,
                albedo: Vec3::from(albedo),
                name: "bumpy-sphere".into(),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bumpy_sphere_faces_outward_and_counts_match() {
        let p = Procedural::BumpySphere {
            center: [1.0, 2.0, 3.0],
            radius: 2.0,
            segments: 16,
            rings: 8,
            amplitude: 0.1,
            frequency: 3.0,
            albedo: [0.5; 3],
        };
        validate(&p).unwrap();
        let g = generate(&p);
        assert_eq!(g.triangles.len() as u64, triangle_count(&p));
        for [a, b, c] in &g.triangles {
            let n = (*b - *a).cross(*c - *a);
            assert!(n.length() > 0.0, "degenerate triangle");
            let centroid = (*a + *b + *c) / 3.0 - Vec3::new(1.0, 2.0, 3.0);
            assert!(n.dot(centroid) > 0.0, "triangle faces inward");
        }
    }
}
