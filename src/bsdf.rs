//! The BSDF seam on the host: the CPU twin of `glsl/bsdf.glsl`, for tests
//! and tools. Directions are local (z along the shading normal on the side
//! the path arrives from); `wo` points back along the path.

use crate::sampling::{sample_cosine, square_to_hemisphere};
use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};
use std::f32::consts::FRAC_1_PI;

/// How the BSDF picks bounce directions (`--sampling`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Sampling {
    #[default]
    Cosine,
    Uniform,
}

/// Luminance weights of linear RGB, as the kernels use them.
pub fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

/// A material's scattering at a surface point. Every material so far is
/// diffuse (two-sided Lambert).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bsdf {
    pub albedo: Vec3,
    /// How `sample` draws directions (`--sampling`).
    pub sampling: Sampling,
}

impl Bsdf {
    pub fn diffuse(albedo: Vec3) -> Self {
        Self {
            albedo,
            sampling: Sampling::Cosine,
        }
    }

    /// Whether the BSDF is a delta distribution; none so far is.
    pub fn is_delta(&self) -> bool {
        false
    }

    /// f_s(wo, wi) cos θ_i.
    pub fn eval(&self, _wo: Vec3, wi: Vec3) -> Vec3 {
        if wi.z > 0.0 {
            self.albedo * (FRAC_1_PI * wi.z)
        } else {
            Vec3::ZERO
        }
    }

    /// Solid-angle pdf of `sample` choosing wi.
    pub fn pdf(&self, _wo: Vec3, wi: Vec3) -> f32 {
        if wi.z <= 0.0 {
            return 0.0;
        }
        match self.sampling {
            Sampling::Cosine => wi.z * FRAC_1_PI,
            Sampling::Uniform => 0.5 * FRAC_1_PI,
        }
    }

    /// A direction from two uniform numbers, and its point of the
    /// equal-area square (the guides' sector grid).
    pub fn sample(&self, _wo: Vec3, u: Vec2) -> (Vec3, Vec2) {
        match self.sampling {
            Sampling::Uniform => (square_to_hemisphere(u), u),
            Sampling::Cosine => {
                let wi = sample_cosine(u);
                (wi, Vec2::splat(0.5) + (u - 0.5) / (1.0 + wi.z).sqrt())
            }
        }
    }

    /// Luminance reflected toward wo of a guide's expected light, given as
    /// (2π/n) Σ_j Q_j cos θ_j; exact for a diffuse lobe.
    pub fn reflect(&self, _wo: Vec3, irradiance: f32) -> f32 {
        luminance(self.albedo) * FRAC_1_PI * irradiance
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::{grid, hemisphere_to_square};

    /// White furnace per sampler: the mean of f cos / pdf over its samples
    /// is the albedo; each sample's square point is its equal-area point.
    #[test]
    fn samplers_return_the_albedo_and_their_square_points() {
        let wo = Vec3::Z;
        for sampling in [Sampling::Cosine, Sampling::Uniform] {
            let bsdf = Bsdf {
                albedo: Vec3::new(1.0, 0.5, 0.25),
                sampling,
            };
            let mut sum = Vec3::ZERO;
            let n = 256;
            for u in grid(n) {
                let (wi, square) = bsdf.sample(wo, u);
                assert!((wi.length() - 1.0).abs() < 1e-4);
                sum += bsdf.eval(wo, wi) / bsdf.pdf(wo, wi);
                let exact = hemisphere_to_square(wi);
                assert!(
                    (square - exact).abs().max_element() < 1e-3,
                    "{u}: {square} vs {exact}"
                );
            }
            let mean = sum / (n * n) as f32;
            assert!(
                (mean - bsdf.albedo).abs().max_element() < 2e-3,
                "{sampling:?}: {mean}"
            );
        }
    }

    #[test]
    fn diffuse_is_reciprocal_and_one_sided() {
        let bsdf = Bsdf::diffuse(Vec3::splat(0.8));
        let (a, b) = (Vec3::new(0.6, 0.0, 0.8), Vec3::new(0.0, 0.28, 0.96));
        assert!((bsdf.eval(a, b) / b.z - bsdf.eval(b, a) / a.z).length() < 1e-6);
        assert_eq!(bsdf.eval(a, -b), Vec3::ZERO);
        assert_eq!(bsdf.pdf(a, -b), 0.0);
        assert!(!bsdf.is_delta());
    }
}
