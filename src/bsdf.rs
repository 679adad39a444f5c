//! The BSDF seam on the host: the CPU twin of `glsl/bsdf.glsl`, for tests
//! and tools. Directions are local (z along the shading normal on the side
//! the path arrives from); `wo` points back along the path.

use crate::sampling::{hemisphere_to_square, sample_cosine, square_to_hemisphere};
use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};
use std::f32::consts::{FRAC_1_PI, PI};

mod principled;
pub use principled::Principled;

/// How a diffuse BSDF picks bounce directions (`--sampling`).
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

/// The smallest GGX α a rough conductor keeps: below it a lobe is a mirror
/// to every purpose, and its D would lose float precision.
pub const MIN_ALPHA: f32 = 1e-4;

/// How a surface scatters, as docs/scenes.md describes it; the same for
/// both sides except for a dielectric's orientation.
// A rough plastic carries its table by value: a material has one Surface,
// and copies stay cheap enough to keep the type Copy.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Surface {
    /// Two-sided Lambert with albedo `Kd`.
    Diffuse { albedo: Vec3 },
    /// Microfacet conductor: reflectance `Ks` times the Fresnel term
    /// (1 without one, as an MTL conductor), α = `Pr`² for an MTL one (0: a
    /// perfect mirror), Smith's separable masking-shadowing.
    Conductor {
        reflectance: Vec3,
        alpha: f32,
        /// Where anisotropic: alpha across the surface's tangent (Mitsuba's
        /// dp/du), `alpha` being along it.
        alpha_v: Option<f32>,
        distribution: Distribution,
        fresnel: Option<ComplexIor>,
    },
    /// Smooth dielectric of index `Ni` on the side the normal does not face,
    /// transmission tinted by `Tf`, reflection by `reflectance` (1 for an
    /// MTL's glass; Mitsuba's `specular_reflectance`).
    Dielectric {
        ior: f32,
        transmittance: Vec3,
        reflectance: Vec3,
    },
    /// Mitsuba's `thindielectric`: a thin sheet of relative index `eta`
    /// that reflects (tinted by `reflectance`) or lets light straight
    /// through (tinted by `transmittance`), its inner reflections summed.
    Thin {
        eta: f32,
        reflectance: Vec3,
        transmittance: Vec3,
    },
    /// Mitsuba's `plastic`: a diffuse base under a smooth dielectric coat
    /// of relative index `eta`, reflecting `specular` times the Fresnel term
    /// as a mirror; light scattered inside the coat by the base is
    /// accounted for in the mean (or, `nonlinear`, per colour).
    Plastic {
        diffuse: Vec3,
        specular: Vec3,
        eta: f32,
        nonlinear: bool,
    },
    /// Mitsuba's `roughdielectric`: a rough interface of index `ior` on
    /// the side the normal does not face, reflecting (tinted by
    /// `reflectance`) and transmitting (tinted by `transmittance`) through
    /// its microfacets (Walter et al. 2007).
    RoughDielectric {
        ior: f32,
        reflectance: Vec3,
        transmittance: Vec3,
        alpha: f32,
        /// As a conductor's.
        alpha_v: Option<f32>,
        distribution: Distribution,
    },
    /// Mitsuba's `roughplastic`: `Plastic` under a rough coat, whose
    /// microfacets reflect as a glossy lobe and whose transmittance into
    /// and out of the base comes from `table`.
    RoughPlastic {
        diffuse: Vec3,
        specular: Vec3,
        eta: f32,
        nonlinear: bool,
        alpha: f32,
        distribution: Distribution,
        table: RoughTable,
    },
    /// Mitsuba's `principled` without transmission (see [`Principled`]).
    Principled {
        base_color: Vec3,
        params: Principled,
    },
}

/// Entries of a rough coat's transmittance table, at cos θ = i / 63.
pub const ROUGH_TABLE_SIZE: usize = crate::shaders::ROUGH_TABLE_SIZE as usize;

/// What a rough dielectric coat lets through, integrated over its
/// microfacets: the fraction of light arriving at cos θ that is refracted
/// into the coat (and not masked), tabulated as Mitsuba tabulates it, and
/// the cosine-weighted mean reflectance of its inside.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RoughTable {
    pub transmittance: [f32; ROUGH_TABLE_SIZE],
    pub internal_reflectance: f32,
}

impl RoughTable {
    /// The table of a coat of relative index `eta`; each distinct coat is
    /// integrated once per process (15 ms), with 64 nodes a side (within
    /// 1.3e-4 of 512).
    pub fn new(eta: f32, alpha: f32, distribution: Distribution) -> Self {
        type Key = (u32, u32, bool);
        static CACHE: std::sync::Mutex<Vec<(Key, RoughTable)>> = std::sync::Mutex::new(Vec::new());
        let key = (
            eta.to_bits(),
            alpha.to_bits(),
            distribution == Distribution::Beckmann,
        );
        let mut cache = CACHE.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, t)) = cache.iter().find(|(k, _)| *k == key) {
            return *t;
        }
        let table = Self::with_nodes(eta, alpha, distribution, 64);
        // A scene has a few coats; a long-lived process (the fuzzer) many.
        if cache.len() >= 64 {
            cache.clear();
        }
        cache.push((key, table));
        table
    }

    fn with_nodes(eta: f32, alpha: f32, distribution: Distribution, nodes: usize) -> Self {
        let nodes = gauss_legendre(nodes);
        let n = ROUGH_TABLE_SIZE;
        let direction = |i: usize| {
            let mu = (i as f32 / (n - 1) as f32).max(1e-6);
            Vec3::new((1.0 - mu * mu).sqrt(), 0.0, mu)
        };
        let mut transmittance = [0.0; ROUGH_TABLE_SIZE];
        let mut internal = 0.0f64;
        for (i, t) in transmittance.iter_mut().enumerate() {
            let wi = direction(i);
            *t = rough_interface_albedo(&nodes, distribution, alpha, eta, wi).1 as f32;
            internal +=
                rough_interface_albedo(&nodes, distribution, alpha, 1.0 / eta, wi).0 * wi.z as f64;
        }
        Self {
            transmittance,
            internal_reflectance: (2.0 * internal / n as f64) as f32,
        }
    }

    /// The transmittance at cos θ, interpolated linearly.
    pub fn at(&self, cos: f32) -> f32 {
        let x = cos.clamp(0.0, 1.0) * (ROUGH_TABLE_SIZE - 1) as f32;
        let i = (x as usize).min(ROUGH_TABLE_SIZE - 2);
        let w = x - i as f32;
        self.transmittance[i] * (1.0 - w) + self.transmittance[i + 1] * w
    }
}

/// A cosine-distributed direction and its point of the equal-area square:
/// Malley's method keeps the concentric map's angle, so that point is the
/// disk's square point scaled by 1 / sqrt(1 + z).
fn cosine(u: Vec2) -> (Vec3, Vec2) {
    let wi = sample_cosine(u);
    (wi, Vec2::splat(0.5) + (u - 0.5) / (1.0 + wi.z).sqrt())
}

/// The microfacet normal (facing wo's side) that takes wo to wi across a
/// rough interface of relative index `eta`, and whether wi is a
/// reflection; None where wo or wi would see that normal from behind
/// (where Smith's masking is 0).
fn rough_glass_half(wo: Vec3, wi: Vec3, eta: f32) -> Option<(Vec3, bool)> {
    if wo.z <= 0.0 || wi.z == 0.0 {
        return None;
    }
    let reflect = wi.z > 0.0;
    let h = if reflect { wo + wi } else { wo + eta * wi };
    let h = (h * h.z.signum()).try_normalize()?;
    let (oh, ih) = (wo.dot(h), wi.dot(h));
    (oh > 0.0 && (ih > 0.0) == reflect).then_some((h, reflect))
}

/// A refraction from wo to wi about microfacet normal h across relative
/// index η (Walter et al.): the Jacobian of h over wi, its density's
/// factor, η² |wi·h| / (wo·h + η wi·h)². A rough interface's f cos there
/// is (1 − F) D G |wo·h| / (η² wo.z) times it. (`refraction_jacobian` in
/// glsl/bsdf.glsl.)
fn refraction_jacobian(wo: Vec3, wi: Vec3, h: Vec3, eta: f32) -> f32 {
    let denom = wo.dot(h) + eta * wi.dot(h);
    eta * eta * wi.dot(h).abs() / (denom * denom)
}

/// Gauss-Legendre nodes and weights on [0, 1].
fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
    (0..n)
        .map(|i| {
            // Newton's method on P_n from Chebyshev's guess.
            let mut x = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
            let mut dp = 1.0;
            for _ in 0..100 {
                let (mut p0, mut p1) = (1.0, x);
                for k in 2..=n {
                    let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
                    p0 = p1;
                    p1 = p2;
                }
                dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
                let dx = p1 / dp;
                x -= dx;
                if dx.abs() < 1e-15 {
                    break;
                }
            }
            (0.5 * (1.0 - x), 1.0 / ((1.0 - x * x) * dp * dp))
        })
        .collect()
}

/// What a rough dielectric interface of relative index `eta` reflects and
/// transmits of light arriving from wi, neither masked on the way out, by
/// quadrature over the normals wi sees.
fn rough_interface_albedo(
    nodes: &[(f64, f64)],
    distribution: Distribution,
    alpha: f32,
    eta: f32,
    wi: Vec3,
) -> (f64, f64) {
    let alpha = Vec2::splat(alpha);
    let (mut reflected, mut transmitted) = (0.0f64, 0.0f64);
    for &(x, wx) in nodes {
        for &(y, wy) in nodes {
            let m = distribution.sample_normal(alpha, wi, Vec2::new(x as f32, y as f32));
            let weight = distribution.visible_weight(alpha, wi, m);
            let c = wi.dot(m);
            if !(c > 0.0 && weight > 0.0) {
                continue;
            }
            let (f, cos_t) = fresnel_dielectric(c, eta);
            let r = 2.0 * c * m - wi;
            if r.z > 0.0 {
                reflected += wx * wy * (weight * f * distribution.g1(alpha, r)) as f64;
            }
            if f < 1.0 {
                let t = -wi / eta + (c / eta - cos_t) * m;
                if t.z < 0.0 {
                    let g = distribution.g1(alpha, Vec3::new(t.x, t.y, -t.z));
                    transmitted += wx * wy * (weight * (1.0 - f) * g) as f64;
                }
            }
        }
    }
    (reflected, transmitted)
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Distribution {
    #[default]
    Ggx,
    Beckmann,
}

/// A conductor's complex index of refraction η + i k, per RGB channel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ComplexIor {
    pub eta: Vec3,
    pub k: Vec3,
}

impl Surface {
    /// A GGX conductor without a Fresnel term (an MTL file's `Pm 1`).
    pub fn conductor(reflectance: Vec3, alpha: f32) -> Self {
        Surface::Conductor {
            reflectance,
            alpha,
            alpha_v: None,
            distribution: Distribution::Ggx,
            fresnel: None,
        }
    }

    /// The lobe's kind as the GPU's `Material.color.w` holds it.
    pub fn kind(&self) -> u32 {
        match self {
            Surface::Diffuse { .. } => crate::shaders::MATERIAL_DIFFUSE,
            Surface::Conductor { .. } => crate::shaders::MATERIAL_CONDUCTOR,
            Surface::Dielectric { .. } | Surface::RoughDielectric { .. } => {
                crate::shaders::MATERIAL_DIELECTRIC
            }
            Surface::Plastic { .. } | Surface::RoughPlastic { .. } => {
                crate::shaders::MATERIAL_PLASTIC
            }
            Surface::Thin { .. } => crate::shaders::MATERIAL_THIN,
            Surface::Principled { params, .. } if params.thin.is_some() => {
                crate::shaders::MATERIAL_PRINCIPLED_THIN
            }
            Surface::Principled { .. } => crate::shaders::MATERIAL_PRINCIPLED,
        }
    }

    /// What users call the surface: "diffuse", "conductor" or "glass".
    pub fn name(&self) -> &'static str {
        match self {
            Surface::Diffuse { .. } => "diffuse",
            Surface::Conductor { .. } => "conductor",
            Surface::Dielectric { .. } => "glass",
            Surface::Plastic { .. } => "plastic",
            Surface::Thin { .. } => "thin glass",
            Surface::RoughDielectric { .. } => "rough glass",
            Surface::RoughPlastic { .. } => "rough plastic",
            Surface::Principled { params, .. } if params.thin.is_some() => "thin principled",
            Surface::Principled { .. } => "principled",
        }
    }

    /// The surface's colour (Kd, Ks, Tf or a base colour) and its parameter
    /// (α, Ni, a roughness, or 0), as the GPU's `Material` holds them.
    pub fn color_and_parameter(&self) -> (Vec3, f32) {
        match *self {
            Surface::Diffuse { albedo } => (albedo, 0.0),
            Surface::Conductor {
                reflectance, alpha, ..
            } => (reflectance, alpha),
            Surface::Dielectric {
                ior, transmittance, ..
            } => (transmittance, ior),
            Surface::Plastic { diffuse, eta, .. } | Surface::RoughPlastic { diffuse, eta, .. } => {
                (diffuse, eta)
            }
            Surface::RoughDielectric {
                ior, transmittance, ..
            } => (transmittance, ior),
            Surface::Thin {
                eta, transmittance, ..
            } => (transmittance, eta),
            Surface::Principled { base_color, params } => (base_color, params.roughness),
        }
    }

    /// The surface with textures' means in place of its colour, second
    /// colour, alpha and rough glass's alpha across its tangent (see
    /// [`Bsdf::textured`]): what a textured material's lobe weights and the
    /// guides' host-side estimates use.
    pub fn with_means(
        mut self,
        color: Option<Vec3>,
        second: Option<Vec3>,
        a: Option<f32>,
        across: Option<f32>,
    ) -> Self {
        match &mut self {
            Surface::Diffuse { albedo } => *albedo = color.unwrap_or(*albedo),
            // A rough conductor's second texture is its alpha across its
            // tangent.
            Surface::Conductor {
                reflectance,
                alpha,
                alpha_v,
                ..
            } => {
                *reflectance = color.unwrap_or(*reflectance);
                *alpha = a.unwrap_or(*alpha);
                if let Some(s) = second {
                    *alpha_v = Some(luminance(s).clamp(1e-4, 1.0));
                }
            }
            Surface::Dielectric {
                transmittance,
                reflectance,
                ..
            } => {
                *transmittance = color.unwrap_or(*transmittance);
                *reflectance = second.unwrap_or(*reflectance);
            }
            Surface::Thin {
                reflectance,
                transmittance,
                ..
            } => {
                *transmittance = color.unwrap_or(*transmittance);
                *reflectance = second.unwrap_or(*reflectance);
            }
            Surface::RoughDielectric {
                reflectance,
                transmittance,
                alpha,
                alpha_v,
                ..
            } => {
                *transmittance = color.unwrap_or(*transmittance);
                *reflectance = second.unwrap_or(*reflectance);
                *alpha = a.unwrap_or(*alpha);
                *alpha_v = across.or(*alpha_v);
            }
            Surface::Plastic {
                diffuse, specular, ..
            }
            | Surface::RoughPlastic {
                diffuse, specular, ..
            } => {
                *diffuse = color.unwrap_or(*diffuse);
                *specular = second.unwrap_or(*specular);
            }
            // Its second texture is the metallic weight (a thin one's
            // diffuse transmission, halved as Mitsuba does), its alpha's
            // the roughness.
            Surface::Principled { base_color, params } => {
                *base_color = color.unwrap_or(*base_color);
                match &mut params.thin {
                    Some(through) => *through = second.map_or(*through, |c| 0.5 * luminance(c)),
                    None => params.metallic = second.map_or(params.metallic, luminance),
                }
                params.roughness = a.unwrap_or(params.roughness);
            }
        }
        self
    }

    /// A principled surface with its weights that textures may give beside
    /// its colour, roughness and metallic (specular tint, sheen, sheen tint,
    /// flatness, clearcoat, clearcoat gloss, anisotropic, spec_trans:
    /// `TEXTURE_SLOT_HIGHLIGHT_TINT..`) set to `weight(slot)` where that is
    /// a value.
    pub fn with_weight_means(mut self, weight: impl Fn(u32) -> Option<f32>) -> Self {
        use crate::shaders::{
            TEXTURE_SLOT_ANISOTROPIC, TEXTURE_SLOT_CLEARCOAT, TEXTURE_SLOT_CLEARCOAT_GLOSS,
            TEXTURE_SLOT_FLATNESS, TEXTURE_SLOT_HIGHLIGHT_TINT, TEXTURE_SLOT_SHEEN,
            TEXTURE_SLOT_SHEEN_TINT, TEXTURE_SLOT_TRANSMISSION,
        };
        if let Surface::Principled { params, .. } = &mut self {
            for (slot, value) in [
                (TEXTURE_SLOT_HIGHLIGHT_TINT, &mut params.specular_tint),
                (TEXTURE_SLOT_SHEEN, &mut params.sheen),
                (TEXTURE_SLOT_SHEEN_TINT, &mut params.sheen_tint),
                (TEXTURE_SLOT_FLATNESS, &mut params.flatness),
                (TEXTURE_SLOT_CLEARCOAT, &mut params.clearcoat),
                (TEXTURE_SLOT_CLEARCOAT_GLOSS, &mut params.clearcoat_gloss),
                (TEXTURE_SLOT_ANISOTROPIC, &mut params.anisotropic),
                (TEXTURE_SLOT_TRANSMISSION, &mut params.spec_trans),
            ] {
                *value = weight(slot).unwrap_or(*value);
            }
        }
        self
    }

    /// A plastic's specular colour and (internal diffuse reflectance,
    /// probability weight of the specular lobe, α: 0 for a smooth coat):
    /// the GPU `Material`'s `eta` and `k`.
    pub fn plastic_terms(&self) -> Option<(Vec3, Vec3)> {
        match *self {
            Surface::Plastic {
                diffuse,
                specular,
                eta,
                ..
            } => Some((
                specular,
                Vec3::new(
                    fresnel_diffuse_reflectance(1.0 / eta),
                    specular_weight(diffuse, specular),
                    0.0,
                ),
            )),
            Surface::RoughPlastic {
                diffuse,
                specular,
                alpha,
                table,
                ..
            } => Some((
                specular,
                Vec3::new(
                    table.internal_reflectance,
                    specular_weight(diffuse, specular),
                    alpha,
                ),
            )),
            _ => None,
        }
    }

    /// Whether light passes through it by a lobe that is not a delta one
    /// (rough glass, a principled BSDF's refraction).
    pub fn rough_transmission(&self) -> bool {
        match self {
            Surface::RoughDielectric { .. } => true,
            Surface::Principled { params, .. } => params.transmits(),
            _ => false,
        }
    }

    /// A rough conductor's or rough glass's alpha across the surface's
    /// tangent, where it differs from the one along it.
    pub fn alpha_across(&self) -> Option<f32> {
        match *self {
            Surface::Conductor { alpha, alpha_v, .. } if alpha > 0.0 => alpha_v,
            Surface::RoughDielectric { alpha_v, .. } => alpha_v,
            _ => None,
        }
    }

    /// Whether its roughness differs along the surface's tangent (Mitsuba's
    /// dp/du) and across it.
    pub fn anisotropic(&self) -> bool {
        match self {
            Surface::Principled { params, .. } => params.anisotropic > 0.0,
            _ => self.alpha_across().is_some(),
        }
    }

    /// The microfacet distribution of a rough lobe's options
    /// (MATERIAL_BECKMANN), if the surface has one.
    pub fn distribution(&self) -> Option<Distribution> {
        match *self {
            Surface::Conductor { distribution, .. }
            | Surface::RoughDielectric { distribution, .. }
            | Surface::RoughPlastic { distribution, .. } => Some(distribution),
            _ => None,
        }
    }
}

/// What a thin sheet reflects of light arriving at cos θ_i: its first
/// surface's Fresnel reflectance with every inner reflection after it.
pub fn thin_reflectance(cos_i: f32, eta: f32) -> f32 {
    let r = fresnel_dielectric(cos_i, eta).0;
    let t = 1.0 - r;
    if r < 1.0 {
        r + t * t * r / (1.0 - r * r)
    } else {
        r
    }
}

/// The share of a plastic's specular lobe in its lobe choice before the
/// Fresnel term (Mitsuba's: mean specular over mean specular and diffuse).
fn specular_weight(diffuse: Vec3, specular: Vec3) -> f32 {
    let (d, s) = (diffuse.element_sum() / 3.0, specular.element_sum() / 3.0);
    if d + s > 0.0 {
        s / (d + s)
    } else {
        0.5
    }
}

/// The hemispherical mean of the dielectric Fresnel reflectance for
/// relative index `eta`, in the fits Mitsuba uses (Egan and Hilgeman for
/// eta < 1, d'Eon and Irving above).
pub fn fresnel_diffuse_reflectance(eta: f32) -> f32 {
    let inv = 1.0 / eta;
    if eta < 1.0 {
        0.0636 * inv + eta * (eta * -1.4399 + 0.7099) + 0.6681
    } else {
        let c = [0.919317, -3.4793, 6.75335, -7.80989, 4.98554, -1.36881];
        c.iter().rev().fold(0.0, |acc, &k| acc * inv + k)
    }
}

/// The lobe at one surface point, seen from one side.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Copy, Debug, PartialEq)]
enum Lobe {
    Diffuse(Sampling),
    /// `alpha` along the tangent, `alpha_v` across (equal where isotropic).
    Conductor {
        alpha: f32,
        alpha_v: f32,
        distribution: Distribution,
        fresnel: Option<ComplexIor>,
    },
    /// η = η_t / η_i: the index beyond the surface over the index on the
    /// side the path arrives from.
    Dielectric {
        eta: f32,
        reflectance: Vec3,
    },
    /// `color` is what passes through.
    Thin {
        eta: f32,
        reflectance: Vec3,
    },
    /// `color` is the base's diffuse reflectance.
    Plastic {
        eta: f32,
        specular: Vec3,
        /// The coat's internal diffuse reflectance.
        fdr_int: f32,
        specular_weight: f32,
        nonlinear: bool,
    },
    /// η as `Dielectric`'s; `color` is what is transmitted.
    RoughDielectric {
        eta: f32,
        reflectance: Vec3,
        alpha: f32,
        alpha_v: f32,
        distribution: Distribution,
    },
    /// `color` is the base's diffuse reflectance.
    RoughPlastic {
        eta: f32,
        specular: Vec3,
        alpha: f32,
        distribution: Distribution,
        specular_weight: f32,
        nonlinear: bool,
        table: RoughTable,
    },
    /// `color` is the base colour.
    Principled(Principled),
}

/// A material's scattering at a surface point, seen from one side.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bsdf {
    lobe: Lobe,
    /// Kd, Ks or Tf.
    pub color: Vec3,
    /// Where its roughness is anisotropic: the surface's tangent (Mitsuba's
    /// dp/du) in the local frame; (1, 0) by default.
    tangent: Vec2,
}

/// The microfacet distributions in the frame of the surface's tangent:
/// alpha.x along it, alpha.y across (equal where isotropic). GGX's normal
/// distribution, written without the cancellation of 1 − cos²θ so that
/// narrow lobes keep their precision.
fn ggx_d(alpha: Vec2, h: Vec3) -> f32 {
    let a2 = alpha.x * alpha.y;
    let t = h.x * h.x * (alpha.y / alpha.x) + h.y * h.y * (alpha.x / alpha.y) + a2 * h.z * h.z;
    a2 / (PI * t * t)
}

/// Smith's masking of GGX for a direction above the surface.
fn ggx_g1(alpha: Vec2, w: Vec3) -> f32 {
    let s = alpha * w.truncate();
    2.0 * w.z / (w.z + (s.dot(s) + w.z * w.z).sqrt())
}

/// Beckmann's normal distribution.
fn beckmann_d(alpha: Vec2, h: Vec3) -> f32 {
    let z2 = h.z * h.z;
    let s = h.truncate() / alpha;
    (-s.dot(s) / z2).exp() / (PI * alpha.x * alpha.y * z2 * z2)
}

/// Smith's masking of Beckmann, in Walter et al.'s rational fit (2007), as
/// Mitsuba 3.9.1 has it.
fn beckmann_g1(alpha: Vec2, w: Vec3) -> f32 {
    let s = alpha * w.truncate();
    let tan2 = s.dot(s) / (w.z * w.z);
    if tan2 <= 0.0 {
        return 1.0;
    }
    let a = 1.0 / tan2.sqrt();
    if a >= 1.6 {
        1.0
    } else {
        (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)
    }
}

/// Fresnel reflectance of a conductor of complex index η + i k for
/// cos θ_i > 0 (exact, unpolarised).
pub fn fresnel_conductor(cos_i: f32, ior: ComplexIor) -> Vec3 {
    let c2 = cos_i * cos_i;
    let s2 = 1.0 - c2;
    let (eta, k) = (ior.eta, ior.k);
    let t1 = eta * eta - k * k - Vec3::splat(s2);
    let a2b2 = (t1 * t1 + 4.0 * k * k * eta * eta).max(Vec3::ZERO);
    let a2b2 = Vec3::new(a2b2.x.sqrt(), a2b2.y.sqrt(), a2b2.z.sqrt());
    let a = (0.5 * (a2b2 + t1)).max(Vec3::ZERO);
    let a = Vec3::new(a.x.sqrt(), a.y.sqrt(), a.z.sqrt());
    let t2 = a2b2 + Vec3::splat(c2);
    let t3 = 2.0 * cos_i * a;
    let rs = (t2 - t3) / (t2 + t3);
    let t4 = a2b2 * c2 + Vec3::splat(s2 * s2);
    let t5 = t3 * s2;
    let rp = rs * (t4 - t5) / (t4 + t5);
    0.5 * (rs + rp)
}

impl Distribution {
    fn d(self, alpha: Vec2, h: Vec3) -> f32 {
        match self {
            Distribution::Ggx => ggx_d(alpha, h),
            Distribution::Beckmann => beckmann_d(alpha, h),
        }
    }

    fn g1(self, alpha: Vec2, w: Vec3) -> f32 {
        match self {
            Distribution::Ggx => ggx_g1(alpha, w),
            Distribution::Beckmann => beckmann_g1(alpha, w),
        }
    }

    /// D(h) G1(wo) G1(wi), wi on either side; over 4 wo.z, a reflection's
    /// f cos without its Fresnel term.
    fn dg(self, alpha: Vec2, wo: Vec3, wi: Vec3, h: Vec3) -> f32 {
        self.d(alpha, h) * self.g1(alpha, wo) * self.g1(alpha, Vec3::new(wi.x, wi.y, wi.z.abs()))
    }

    /// A microfacet normal for a path arriving from wo: GGX draws the
    /// normals wo sees (spherical caps, Dupuy & Benyoub 2023), Beckmann
    /// all of them by D(m) m.z.
    fn sample_normal(self, alpha: Vec2, wo: Vec3, u: Vec2) -> Vec3 {
        match self {
            Distribution::Ggx => {
                let wh = (alpha * wo.truncate()).extend(wo.z).normalize();
                let phi = 2.0 * PI * u.x;
                let z = (1.0 - u.y) * (1.0 + wh.z) - wh.z;
                let s = (1.0 - z * z).max(0.0).sqrt();
                let h = Vec3::new(s * phi.cos(), s * phi.sin(), z) + wh;
                (alpha * h.truncate()).extend(h.z.max(0.0)).normalize()
            }
            Distribution::Beckmann => {
                // Its slopes are Gaussian, scaled by the alphas.
                let r = (-(1.0 - u.x).max(1e-30).ln()).sqrt();
                let phi = 2.0 * PI * u.y;
                (alpha * (r * Vec2::new(phi.cos(), phi.sin())))
                    .extend(1.0)
                    .normalize()
            }
        }
    }

    /// The density of `sample_normal` drawing m: GGX's visible normals
    /// G1(wo) (wo·m) D(m) / wo.z, Beckmann's D(m) m.z.
    fn sampler_pdf(self, alpha: Vec2, wo: Vec3, m: Vec3) -> f32 {
        match self {
            Distribution::Ggx => ggx_g1(alpha, wo) * wo.dot(m).max(0.0) * ggx_d(alpha, m) / wo.z,
            Distribution::Beckmann => beckmann_d(alpha, m) * m.z,
        }
    }

    /// The density of the normals wo sees over `sampler_pdf`, at m.
    fn visible_weight(self, alpha: Vec2, wo: Vec3, m: Vec3) -> f32 {
        match self {
            Distribution::Ggx => 1.0,
            Distribution::Beckmann => beckmann_g1(alpha, wo) * wo.dot(m).max(0.0) / (wo.z * m.z),
        }
    }
}

/// Exact Fresnel reflectance of a smooth dielectric for cos θ_i > 0 and
/// η = η_t / η_i, and cos θ_t (0 under total internal reflection).
pub fn fresnel_dielectric(cos_i: f32, eta: f32) -> (f32, f32) {
    let sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if sin2_t >= 1.0 {
        return (1.0, 0.0);
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    let rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    (0.5 * (rs * rs + rp * rp), cos_t)
}

impl Bsdf {
    pub fn diffuse(albedo: Vec3) -> Self {
        Self::new(Surface::Diffuse { albedo }, true, Sampling::Cosine)
    }

    /// The BSDF of `surface` for a path arriving on its front side (the
    /// side the triangle's normal faces) or its back.
    pub fn new(surface: Surface, front: bool, sampling: Sampling) -> Self {
        let (lobe, color) = match surface {
            Surface::Diffuse { albedo } => (Lobe::Diffuse(sampling), albedo),
            Surface::Conductor {
                reflectance,
                alpha,
                alpha_v,
                distribution,
                fresnel,
            } => {
                let alpha = if alpha > 0.0 {
                    alpha.max(MIN_ALPHA)
                } else {
                    0.0
                };
                let alpha_v = alpha_v
                    .filter(|_| alpha > 0.0)
                    .map_or(alpha, |a| a.max(MIN_ALPHA));
                (
                    Lobe::Conductor {
                        alpha,
                        alpha_v,
                        distribution,
                        fresnel,
                    },
                    reflectance,
                )
            }
            Surface::Dielectric {
                ior,
                transmittance,
                reflectance,
            } => (
                Lobe::Dielectric {
                    eta: if front { ior } else { 1.0 / ior },
                    reflectance,
                },
                transmittance,
            ),
            Surface::Thin {
                eta,
                reflectance,
                transmittance,
            } => (Lobe::Thin { eta, reflectance }, transmittance),
            Surface::Plastic {
                diffuse,
                specular,
                eta,
                nonlinear,
            } => (
                Lobe::Plastic {
                    eta,
                    specular,
                    fdr_int: fresnel_diffuse_reflectance(1.0 / eta),
                    specular_weight: specular_weight(diffuse, specular),
                    nonlinear,
                },
                diffuse,
            ),
            Surface::RoughDielectric {
                ior,
                reflectance,
                transmittance,
                alpha,
                alpha_v,
                distribution,
            } => (
                Lobe::RoughDielectric {
                    eta: if front { ior } else { 1.0 / ior },
                    reflectance,
                    alpha: alpha.max(MIN_ALPHA),
                    alpha_v: alpha_v.unwrap_or(alpha).max(MIN_ALPHA),
                    distribution,
                },
                transmittance,
            ),
            Surface::RoughPlastic {
                diffuse,
                specular,
                eta,
                nonlinear,
                alpha,
                distribution,
                table,
            } => (
                Lobe::RoughPlastic {
                    eta,
                    specular,
                    alpha: alpha.max(MIN_ALPHA),
                    distribution,
                    specular_weight: specular_weight(diffuse, specular),
                    nonlinear,
                    table,
                },
                diffuse,
            ),
            // Without spec_trans, its back is its front's lobes (inside
            // `twosided`) or black (one-sided, `Material::bsdf`); a thin
            // one's is its front's.
            Surface::Principled { base_color, params }
                if front || params.spec_trans <= 0.0 || params.thin.is_some() =>
            {
                (Lobe::Principled(params), base_color)
            }
            Surface::Principled { base_color, params } => {
                return Self::new(params.back(base_color), false, sampling);
            }
        };
        Self {
            lobe,
            color,
            tangent: Vec2::X,
        }
    }

    /// The BSDF with the surface's tangent (Mitsuba's dp/du) at `tangent`
    /// in the local frame, which an anisotropic roughness follows.
    pub fn with_tangent(mut self, tangent: Vec2) -> Self {
        self.tangent = tangent;
        self
    }

    /// Whether its roughness differs along its tangent and across it.
    fn anisotropic(&self) -> bool {
        match self.lobe {
            Lobe::Conductor { alpha, alpha_v, .. }
            | Lobe::RoughDielectric { alpha, alpha_v, .. } => alpha != alpha_v,
            Lobe::Principled(p) => p.anisotropic > 0.0,
            _ => false,
        }
    }

    /// Its microfacet lobe's alphas along its tangent and across it.
    fn alphas(&self) -> Vec2 {
        match self.lobe {
            Lobe::Conductor { alpha, alpha_v, .. }
            | Lobe::RoughDielectric { alpha, alpha_v, .. } => Vec2::new(alpha, alpha_v),
            Lobe::RoughPlastic { alpha, .. } => Vec2::splat(alpha),
            Lobe::Principled(p) => p.alphas(),
            _ => Vec2::ZERO,
        }
    }

    /// A local direction in the frame of its tangent, and back.
    fn in_tangent_frame(&self, w: Vec3) -> Vec3 {
        let t = self.tangent;
        Vec3::new(t.x * w.x + t.y * w.y, t.x * w.y - t.y * w.x, w.z)
    }

    fn in_local_frame(&self, w: Vec3) -> Vec3 {
        let t = self.tangent;
        Vec3::new(t.x * w.x - t.y * w.y, t.y * w.x + t.x * w.y, w.z)
    }

    /// The same lobe reflecting nothing: a one-sided material seen from
    /// behind.
    pub fn black(mut self) -> Self {
        self.color = Vec3::ZERO;
        match &mut self.lobe {
            Lobe::Plastic { specular, .. } | Lobe::RoughPlastic { specular, .. } => {
                *specular = Vec3::ZERO
            }
            Lobe::Thin { reflectance, .. } => *reflectance = Vec3::ZERO,
            _ => {}
        }
        self
    }

    /// The BSDF with a texture's values in place of its colour, its second
    /// colour (a plastic's specular, a sheet's or rough glass's reflection),
    /// its alpha and rough glass's alpha across its tangent (the CPU twin of
    /// `bsdf_textured` in glsl/texture.glsl).
    pub fn textured(
        mut self,
        color: Option<Vec3>,
        second: Option<Vec3>,
        alpha: Option<f32>,
        across: Option<f32>,
    ) -> Self {
        if let Some(c) = color {
            self.color = c;
        }
        match &mut self.lobe {
            Lobe::Plastic { specular, .. } | Lobe::RoughPlastic { specular, .. } => {
                *specular = second.unwrap_or(*specular)
            }
            Lobe::Thin { reflectance, .. }
            | Lobe::RoughDielectric { reflectance, .. }
            | Lobe::Dielectric { reflectance, .. } => *reflectance = second.unwrap_or(*reflectance),
            _ => {}
        }
        // An isotropic roughness's texture sets both alphas; a rough
        // conductor's second texture, its alpha across its tangent.
        let conductor = matches!(self.lobe, Lobe::Conductor { .. });
        if let Lobe::Conductor {
            alpha: a, alpha_v, ..
        }
        | Lobe::RoughDielectric {
            alpha: a, alpha_v, ..
        } = &mut self.lobe
        {
            let isotropic = *alpha_v == *a;
            let conductor_across = second.filter(|_| conductor);
            if let Some(s) = conductor_across {
                *alpha_v = luminance(s).max(MIN_ALPHA);
            }
            if let Some(t) = alpha {
                *a = t.max(MIN_ALPHA);
                if isotropic && conductor_across.is_none() {
                    *alpha_v = *a;
                }
            }
        }
        if let Lobe::RoughDielectric { alpha_v, .. } = &mut self.lobe {
            if let Some(t) = across {
                *alpha_v = t.max(MIN_ALPHA);
            }
        }
        self
    }

    /// Its second colour where it has one (as `textured` sets it), for
    /// probes.
    pub fn second_color(&self) -> Option<Vec3> {
        match self.lobe {
            Lobe::Plastic { specular, .. } | Lobe::RoughPlastic { specular, .. } => Some(specular),
            Lobe::Thin { reflectance, .. }
            | Lobe::RoughDielectric { reflectance, .. }
            | Lobe::Dielectric { reflectance, .. } => Some(reflectance),
            _ => None,
        }
    }

    /// Its alpha where it is rough, for probes.
    pub fn alpha(&self) -> Option<f32> {
        match self.lobe {
            Lobe::Conductor { alpha, .. }
            | Lobe::RoughDielectric { alpha, .. }
            | Lobe::RoughPlastic { alpha, .. } => Some(alpha),
            _ => None,
        }
    }

    /// A principled lobe's (metallic, specular tint, sheen) and (sheen
    /// tint, flatness, clearcoat), as the GPU's Bsdf holds them (a thin
    /// one's diffuse transmission in metallic's place), for probes.
    pub fn principled_weights(&self) -> Option<(Vec3, Vec3)> {
        match self.lobe {
            Lobe::Principled(p) => Some((
                Vec3::new(p.thin.unwrap_or(p.metallic), p.specular_tint, p.sheen),
                Vec3::new(p.sheen_tint, p.flatness, p.clearcoat),
            )),
            _ => None,
        }
    }

    /// A principled lobe's clearcoat gloss, spec_trans and anisotropic, for
    /// probes.
    pub fn principled_extra(&self) -> Option<Vec3> {
        match self.lobe {
            Lobe::Principled(p) => Some(Vec3::new(p.clearcoat_gloss, p.spec_trans, p.anisotropic)),
            _ => None,
        }
    }

    /// A rough conductor's or rough glass's alpha across its tangent (its
    /// alpha where isotropic), for probes.
    pub fn alpha_across(&self) -> Option<f32> {
        match self.lobe {
            Lobe::Conductor { alpha, alpha_v, .. } if alpha > 0.0 => Some(alpha_v),
            Lobe::RoughDielectric { alpha_v, .. } => Some(alpha_v),
            _ => None,
        }
    }

    /// The probability that a bounce from wo takes the BSDF's delta lobe:
    /// 1 for a mirror or glass, a plastic's Fresnel-weighted share of its
    /// coat's reflection, 0 for the rest. `sample_delta` draws that lobe;
    /// `sample`, `pdf` and `eval` are the others', `pdf` conditional on
    /// not taking it.
    pub fn delta_share(&self, wo: Vec3) -> f32 {
        match self.lobe {
            Lobe::Plastic {
                eta,
                specular_weight,
                ..
            } => {
                let f = fresnel_dielectric(wo.z, eta).0;
                let (s, d) = (f * specular_weight, (1.0 - f) * (1.0 - specular_weight));
                if s + d > 0.0 {
                    s / (s + d)
                } else {
                    0.0
                }
            }
            _ if self.is_delta() => 1.0,
            _ => 0.0,
        }
    }

    /// Whether the BSDF is a delta distribution (a mirror, smooth glass):
    /// such a vertex samples with `sample_delta` and skips NEE and guiding.
    pub fn is_delta(&self) -> bool {
        match self.lobe {
            Lobe::Diffuse(_) => false,
            Lobe::Conductor { alpha, .. } => alpha == 0.0,
            Lobe::Dielectric { .. } | Lobe::Thin { .. } => true,
            Lobe::Plastic { .. }
            | Lobe::RoughDielectric { .. }
            | Lobe::RoughPlastic { .. }
            | Lobe::Principled(_) => false,
        }
    }

    /// Whether the lobe sends light through the surface without being a
    /// delta lobe (rough glass): sampled, evaluated and reached by NEE
    /// below the surface too, and guided from the tables of both sides.
    pub fn transmits(&self) -> bool {
        match self.lobe {
            Lobe::RoughDielectric { .. } => true,
            Lobe::Principled(p) => p.transmits(),
            _ => false,
        }
    }

    /// A rough plastic's probability of sampling its coat's microfacets
    /// rather than its base (Mitsuba's choice: the coat's reflectance at wo
    /// against the base's transmittance, weighted by their mean colours).
    fn coat_share(table: &RoughTable, specular_weight: f32, wo: Vec3) -> f32 {
        let t = table.at(wo.z);
        let (s, d) = ((1.0 - t) * specular_weight, t * (1.0 - specular_weight));
        if s + d > 0.0 {
            s / (s + d)
        } else {
            0.0
        }
    }

    /// f_s(wo, wi) cos θ_i; zero for delta lobes.
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        if self.anisotropic() {
            return self.eval_local(self.in_tangent_frame(wo), self.in_tangent_frame(wi));
        }
        self.eval_local(wo, wi)
    }

    /// Solid-angle pdf of `sample` choosing wi; zero for delta lobes.
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if self.anisotropic() {
            return self.pdf_local(self.in_tangent_frame(wo), self.in_tangent_frame(wi));
        }
        self.pdf_local(wo, wi)
    }

    /// A direction from three uniform numbers (None where the lobe sends
    /// none, as a rough conductor may below the horizon), and its point of
    /// the equal-area square (the guides' sector grid; of the mirrored
    /// direction for one below). u.z picks a lobe or reflection against
    /// refraction where there is a choice. Not for delta lobes.
    pub fn sample(&self, wo: Vec3, u: Vec3) -> Option<(Vec3, Vec2)> {
        if !self.anisotropic() {
            return self.sample_local(wo, u);
        }
        let (wi, _) = self.sample_local(self.in_tangent_frame(wo), u)?;
        let wi = self.in_local_frame(wi);
        Some((wi, hemisphere_to_square(Vec3::new(wi.x, wi.y, wi.z.abs()))))
    }

    /// `eval`, `pdf` and `sample` in the frame of its tangent.
    fn eval_local(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        if let Lobe::RoughDielectric {
            eta,
            reflectance,
            distribution: m,
            ..
        } = self.lobe
        {
            return match rough_glass_half(wo, wi, eta) {
                Some((h, true)) => {
                    reflectance
                        * (fresnel_dielectric(wo.dot(h), eta).0 * m.dg(self.alphas(), wo, wi, h)
                            / (4.0 * wo.z))
                }
                Some((h, false)) => {
                    let oh = wo.dot(h);
                    let f = fresnel_dielectric(oh, eta).0;
                    self.color
                        * ((1.0 - f)
                            * m.dg(self.alphas(), wo, wi, h)
                            * oh
                            * refraction_jacobian(wo, wi, h, eta)
                            / (eta * eta * wo.z))
                }
                None => Vec3::ZERO,
            };
        }
        if let Lobe::Principled(p) = self.lobe {
            return p.eval(self.color, wo, wi);
        }
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return Vec3::ZERO;
        }
        match self.lobe {
            Lobe::RoughPlastic {
                eta,
                specular,
                distribution: m,
                nonlinear,
                table,
                ..
            } => {
                let h = (wo + wi).normalize();
                let coat = specular
                    * (fresnel_dielectric(wo.dot(h), eta).0 * m.dg(self.alphas(), wo, wi, h)
                        / (4.0 * wo.z));
                let d = self.color;
                let inside = if nonlinear {
                    Vec3::ONE - d * table.internal_reflectance
                } else {
                    Vec3::splat(1.0 - table.internal_reflectance)
                };
                coat + d / inside
                    * (FRAC_1_PI * wi.z / (eta * eta) * table.at(wo.z) * table.at(wi.z))
            }
            Lobe::Diffuse(_) => self.color * (FRAC_1_PI * wi.z),
            Lobe::Plastic {
                eta,
                fdr_int,
                nonlinear,
                ..
            } => {
                let (fi, fo) = (
                    fresnel_dielectric(wo.z, eta).0,
                    fresnel_dielectric(wi.z, eta).0,
                );
                let d = self.color;
                let inside = if nonlinear {
                    Vec3::ONE - d * fdr_int
                } else {
                    Vec3::splat(1.0 - fdr_int)
                };
                d / inside * (FRAC_1_PI * wi.z / (eta * eta) * (1.0 - fi) * (1.0 - fo))
            }
            Lobe::Conductor {
                alpha,
                distribution: m,
                fresnel,
                ..
            } if alpha > 0.0 => {
                let h = (wo + wi).normalize();
                self.color
                    * self.fresnel(fresnel, wo.dot(h))
                    * (m.dg(self.alphas(), wo, wi, h) / (4.0 * wo.z))
            }
            _ => Vec3::ZERO,
        }
    }

    fn pdf_local(&self, wo: Vec3, wi: Vec3) -> f32 {
        if let Lobe::RoughDielectric {
            eta,
            distribution: m,
            ..
        } = self.lobe
        {
            return match rough_glass_half(wo, wi, eta) {
                Some((h, reflect)) => {
                    let oh = wo.dot(h);
                    let f = fresnel_dielectric(oh, eta).0;
                    let normal = m.sampler_pdf(self.alphas(), wo, h);
                    if reflect {
                        f * normal / (4.0 * oh)
                    } else {
                        (1.0 - f) * normal * refraction_jacobian(wo, wi, h, eta)
                    }
                }
                None => 0.0,
            };
        }
        if let Lobe::Principled(p) = self.lobe {
            return p.pdf(wo, wi);
        }
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return 0.0;
        }
        match self.lobe {
            Lobe::RoughPlastic {
                distribution: m,
                specular_weight,
                table,
                ..
            } => {
                let share = Self::coat_share(&table, specular_weight, wo);
                let h = (wo + wi).normalize();
                share * m.sampler_pdf(self.alphas(), wo, h) / (4.0 * wo.dot(h))
                    + (1.0 - share) * wi.z * FRAC_1_PI
            }
            Lobe::Diffuse(Sampling::Cosine) | Lobe::Plastic { .. } => wi.z * FRAC_1_PI,
            Lobe::Diffuse(Sampling::Uniform) => 0.5 * FRAC_1_PI,
            // The normal's density over the reflection's Jacobian 4 wo·h.
            Lobe::Conductor {
                alpha,
                distribution: m,
                ..
            } if alpha > 0.0 => {
                let h = (wo + wi).normalize();
                m.sampler_pdf(self.alphas(), wo, h) / (4.0 * wo.dot(h))
            }
            _ => 0.0,
        }
    }

    fn sample_local(&self, wo: Vec3, u: Vec3) -> Option<(Vec3, Vec2)> {
        let reflect = |m: Vec3| {
            let wi = 2.0 * wo.dot(m) * m - wo;
            (wi.z > 0.0 && wo.dot(m) > 0.0).then(|| (wi, hemisphere_to_square(wi)))
        };
        match self.lobe {
            Lobe::Diffuse(Sampling::Uniform) => {
                Some((square_to_hemisphere(u.truncate()), u.truncate()))
            }
            Lobe::Diffuse(Sampling::Cosine) | Lobe::Plastic { .. } => Some(cosine(u.truncate())),
            Lobe::Principled(p) => p.sample(wo, u),
            Lobe::Conductor { distribution, .. } => {
                reflect(distribution.sample_normal(self.alphas(), wo, u.truncate()))
            }
            Lobe::RoughPlastic {
                distribution,
                specular_weight,
                table,
                ..
            } => {
                if u.z < Self::coat_share(&table, specular_weight, wo) {
                    reflect(distribution.sample_normal(self.alphas(), wo, u.truncate()))
                } else {
                    Some(cosine(u.truncate()))
                }
            }
            Lobe::RoughDielectric {
                eta, distribution, ..
            } => {
                let m = distribution.sample_normal(self.alphas(), wo, u.truncate());
                let c = wo.dot(m);
                let (f, cos_t) = fresnel_dielectric(c, eta);
                if c <= 0.0 || u.z < f {
                    return reflect(m);
                }
                let wi = -wo / eta + (c / eta - cos_t) * m;
                (wi.z < 0.0).then(|| (wi, hemisphere_to_square(Vec3::new(wi.x, wi.y, -wi.z))))
            }
            Lobe::Dielectric { .. } | Lobe::Thin { .. } => None,
        }
    }

    /// A delta lobe's direction from one uniform number, and its weight
    /// f cos / pdf: a mirror reflects; glass reflects with the Fresnel
    /// probability and else refracts, its radiance scaled by 1 / η² as the
    /// solid angle compresses.
    pub fn sample_delta(&self, wo: Vec3, u: f32) -> (Vec3, Vec3) {
        let mirror = Vec3::new(-wo.x, -wo.y, wo.z);
        match self.lobe {
            Lobe::Dielectric { eta, reflectance } => {
                let (f, cos_t) = fresnel_dielectric(wo.z, eta);
                if u < f {
                    (mirror, reflectance)
                } else {
                    (
                        Vec3::new(-wo.x / eta, -wo.y / eta, -cos_t),
                        self.color / (eta * eta),
                    )
                }
            }
            Lobe::Conductor { fresnel, .. } => (mirror, self.color * self.fresnel(fresnel, wo.z)),
            Lobe::Thin { eta, reflectance } => {
                if u < thin_reflectance(wo.z, eta) {
                    (mirror, reflectance)
                } else {
                    (-wo, self.color)
                }
            }
            // The coat's mirror: its weight before dividing by delta_share.
            Lobe::Plastic { eta, specular, .. } => {
                (mirror, specular * fresnel_dielectric(wo.z, eta).0)
            }
            _ => (mirror, self.color),
        }
    }

    /// The Fresnel term at cos θ between the path and the microfacet normal.
    fn fresnel(&self, fresnel: Option<ComplexIor>, cos: f32) -> Vec3 {
        fresnel.map_or(Vec3::ONE, |ior| fresnel_conductor(cos, ior))
    }

    /// Luminance reflected toward wo of a guide's expected light, given as
    /// (2π/n) Σ_j Q_j cos θ_j; exact for a diffuse lobe (the other lobes'
    /// targets are in glsl/guide.glsl).
    pub fn reflect(&self, _wo: Vec3, irradiance: f32) -> f32 {
        luminance(self.color) * FRAC_1_PI * irradiance
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::{grid, hemisphere_to_square};

    fn direction(theta_degrees: f32) -> Vec3 {
        let t = theta_degrees.to_radians();
        Vec3::new(t.sin(), 0.0, t.cos())
    }

    /// The metal of Veach's MIS scene: η + i k per channel.
    const VEACH_METAL: ComplexIor = ComplexIor {
        eta: Vec3::new(0.200438, 0.924033, 1.10221),
        k: Vec3::new(3.91295, 2.45285, 2.14219),
    };

    /// Every kind of rough conductor: GGX and Beckmann, with and without
    /// a Fresnel term.
    fn conductors(alpha: f32) -> Vec<(String, Bsdf)> {
        let mut out = Vec::new();
        for distribution in [Distribution::Ggx, Distribution::Beckmann] {
            for fresnel in [None, Some(VEACH_METAL)] {
                let surface = Surface::Conductor {
                    reflectance: Vec3::ONE,
                    alpha,
                    alpha_v: None,
                    distribution,
                    fresnel,
                };
                out.push((
                    format!("{distribution:?} α {alpha} Fresnel {}", fresnel.is_some()),
                    Bsdf::new(surface, true, Sampling::Cosine),
                ));
            }
        }
        out
    }

    /// White furnace per diffuse sampler: the mean of f cos / pdf over its
    /// samples is the albedo; each sample's square point is its equal-area point.
    #[test]
    fn samplers_return_the_albedo_and_their_square_points() {
        let wo = Vec3::Z;
        for sampling in [Sampling::Cosine, Sampling::Uniform] {
            let bsdf = Bsdf::new(
                Surface::Diffuse {
                    albedo: Vec3::new(1.0, 0.5, 0.25),
                },
                true,
                sampling,
            );
            let mut sum = Vec3::ZERO;
            let n = 256;
            for u in grid(n) {
                let (wi, square) = bsdf.sample(wo, u.extend(0.5)).unwrap();
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
                (mean - bsdf.color).abs().max_element() < 2e-3,
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

    /// f_s(wo, wi) = f_s(wi, wo) for the rough conductor over a spread of
    /// directions and roughnesses.
    #[test]
    fn conductor_is_reciprocal() {
        for (name, bsdf) in [0.05, 0.2, 0.5, 1.0].into_iter().flat_map(conductors) {
            for (a, b) in [
                (5.0f32, 40.0f32),
                (30.0, -60.0),
                (75.0, 10.0),
                (85.0, -85.0),
            ] {
                let wo = direction(a);
                let wi = (direction(b.abs()) * Vec3::new(b.signum(), 1.0, 1.0)
                    + Vec3::new(0.0, 0.3, 0.0))
                .normalize();
                let f1 = bsdf.eval(wo, wi) / wi.z;
                let f2 = bsdf.eval(wi, wo) / wo.z;
                assert!(
                    (f1 - f2).abs().max_element() <= 1e-4 * f1.max_element().max(1.0),
                    "{name}: {f1} vs {f2}"
                );
            }
        }
    }

    /// Beckmann's masking as Mitsuba 3.9.1 has it: its `roughconductor`
    /// (alpha 0.15, no Fresnel) at the mirror direction, eval · 4 cos θ / D
    /// = G1², at four grazing angles (the coefficients of Mitsuba's older
    /// fit were 7% lower at cos θ = 0.1).
    #[test]
    fn beckmann_masking_is_mitsubas() {
        for (cos, want) in [
            (0.05f32, 0.69515),
            (0.1, 0.90923),
            (0.15, 0.97782),
            (0.2, 0.99774),
        ] {
            let w = Vec3::new((1.0 - cos * cos).sqrt(), 0.0, cos);
            let g = beckmann_g1(Vec2::splat(0.15), w);
            assert!(
                (g - want).abs() < 3e-4,
                "cos θ {cos}: {g} vs Mitsuba's {want}"
            );
        }
    }

    /// The sampler's estimate of the directional albedo, mean of f cos / pdf,
    /// equals the albedo integrated by quadrature, and neither exceeds 1
    /// (single-scattering GGX loses energy at high roughness, never gains).
    #[test]
    fn conductor_conserves_energy_and_sampler_matches_its_integral() {
        for (name, bsdf) in [0.02, 0.1, 0.3, 0.6, 1.0].into_iter().flat_map(conductors) {
            let alpha = match bsdf.lobe {
                Lobe::Conductor { alpha, .. } => alpha,
                _ => unreachable!(),
            };
            for theta in [0.0, 30.0, 60.0, 80.0] {
                let wo = direction(theta);
                let n = 400;
                let sampled: f32 = grid(n)
                    .filter_map(|u| bsdf.sample(wo, u.extend(0.5)))
                    .map(|(wi, _)| bsdf.eval(wo, wi).x / bsdf.pdf(wo, wi))
                    .sum::<f32>()
                    / (n * n) as f32;
                // Quadrature over the equal-area square: every cell is 2π / m² sr.
                let m = 1000;
                let integral: f64 = grid(m)
                    .map(|u| bsdf.eval(wo, square_to_hemisphere(u)).x as f64)
                    .sum::<f64>()
                    * 2.0
                    * std::f64::consts::PI
                    / (m * m) as f64;
                assert!(sampled <= 1.0 + 1e-3, "{name} θ {theta}: {sampled}");
                // Narrow lobes need the sampler; quadrature only checks broad ones.
                if alpha >= 0.1 {
                    assert!(
                        (sampled as f64 - integral).abs() < 5e-3,
                        "{name} θ {theta}: sampled {sampled}, quadrature {integral}"
                    );
                }
                if theta == 0.0 && alpha <= 0.1 && name.ends_with("false") {
                    assert!(sampled > 0.98, "{name}: {sampled}");
                }
            }
        }
    }

    /// Pearson's χ² of `bsdf`'s sampler from wo against its pdf over an
    /// equal-area grid of sectors on each side of the surface, pooling
    /// sparse bins; panics far beyond the 1e-6 quantile.
    fn assert_sampler_follows_pdf(name: &str, bsdf: &Bsdf, wo: Vec3, seed: u64) {
        let (cells, samples) = (16u32, 200_000usize);
        let bins = (cells * cells) as usize;
        let mut observed = vec![0.0f64; 2 * bins];
        let mut rng = crate::fuzz::Rng::new(seed);
        for _ in 0..samples {
            let u = Vec3::new(rng.unit(), rng.unit(), rng.unit());
            if let Some((wi, _)) = bsdf.sample(wo, u) {
                let up = Vec3::new(wi.x, wi.y, wi.z.abs());
                let k = crate::sampling::hemisphere_sector(up, cells, cells) as usize;
                observed[k + if wi.z < 0.0 { bins } else { 0 }] += 1.0;
            }
        }
        // Expected counts: the pdf integrated over each cell.
        let sub = 24;
        let expected: Vec<f64> = (0..2 * bins)
            .map(|k| {
                let c = (k % bins) as u32;
                let (i, j) = ((c % cells) as f32, (c / cells) as f32);
                let side = if k < bins { 1.0 } else { -1.0 };
                let mut sum = 0.0f64;
                for s in grid(sub) {
                    let wi = square_to_hemisphere((Vec2::new(i, j) + s) / cells as f32);
                    sum += bsdf.pdf(wo, Vec3::new(wi.x, wi.y, side * wi.z)) as f64;
                }
                sum * 2.0 * std::f64::consts::PI / (sub * sub) as f64 / bins as f64 * samples as f64
            })
            .collect();
        let (mut chi2, mut dof, mut pool_e, mut pool_o) = (0.0, 0usize, 0.0, 0.0);
        for (e, o) in expected.iter().zip(&observed) {
            if *e < 5.0 {
                pool_e += e;
                pool_o += o;
            } else {
                chi2 += (o - e) * (o - e) / e;
                dof += 1;
            }
        }
        if pool_e >= 5.0 {
            chi2 += (pool_o - pool_e) * (pool_o - pool_e) / pool_e;
            dof += 1;
        }
        // Mean dof, sd sqrt(2 dof).
        let limit = dof as f64 + 7.0 * (2.0 * dof as f64).sqrt();
        assert!(chi2 < limit, "{name}: χ² {chi2:.1} over {dof} bins");
    }

    #[test]
    fn conductor_sampler_follows_its_pdf() {
        for (name, bsdf) in [0.08, 0.3, 0.9].into_iter().flat_map(conductors) {
            for theta in [10.0, 50.0, 80.0] {
                let what = format!("{name} θ {theta}");
                assert_sampler_follows_pdf(&what, &bsdf, direction(theta), 7 + theta as u64);
            }
        }
    }

    /// Every rough glass and rough plastic the tests use: both
    /// distributions, a narrow and a broad lobe, glass from either side.
    fn rough_lobes() -> Vec<(String, Bsdf)> {
        let mut out = Vec::new();
        for distribution in [Distribution::Ggx, Distribution::Beckmann] {
            for alpha in [0.05, 0.3, 0.8] {
                let glass = Surface::RoughDielectric {
                    ior: 1.5,
                    reflectance: Vec3::ONE,
                    transmittance: Vec3::ONE,
                    alpha,
                    alpha_v: None,
                    distribution,
                };
                for front in [true, false] {
                    let name = format!("glass {distribution:?} α {alpha} front {front}");
                    out.push((name, Bsdf::new(glass, front, Sampling::Cosine)));
                }
                let plastic = Surface::RoughPlastic {
                    diffuse: Vec3::new(0.9, 0.5, 0.1),
                    specular: Vec3::splat(0.8),
                    eta: 1.49,
                    nonlinear: alpha > 0.5,
                    alpha,
                    distribution,
                    table: RoughTable::new(1.49, alpha, distribution),
                };
                let name = format!("plastic {distribution:?} α {alpha}");
                out.push((name, Bsdf::new(plastic, true, Sampling::Cosine)));
            }
        }
        out.extend(principled_lobes());
        out.extend(anisotropic_lobes());
        out
    }

    /// Anisotropic rough lobes, their tangents turned away from the local x
    /// axis: conductors of both distributions, glass from either side, a
    /// principled BSDF.
    fn anisotropic_lobes() -> Vec<(String, Bsdf)> {
        let conductor = |alpha, alpha_v, distribution| Surface::Conductor {
            reflectance: Vec3::ONE,
            alpha,
            alpha_v: Some(alpha_v),
            distribution,
            fresnel: Some(VEACH_METAL),
        };
        let glass = Surface::RoughDielectric {
            ior: 1.5,
            reflectance: Vec3::ONE,
            transmittance: Vec3::ONE,
            alpha: 0.15,
            alpha_v: Some(0.6),
            distribution: Distribution::Ggx,
        };
        let principled = Surface::Principled {
            base_color: Vec3::new(0.7, 0.5, 0.3),
            params: Principled {
                roughness: 0.6,
                metallic: 0.5,
                clearcoat: 0.3,
                clearcoat_gloss: 0.2,
                anisotropic: 0.8,
                ..Principled::default()
            },
        };
        let thin = Surface::Principled {
            base_color: Vec3::new(0.4, 0.7, 0.5),
            params: Principled {
                roughness: 0.5,
                spec_trans: 0.7,
                anisotropic: 0.9,
                thin: Some(0.3),
                ..Principled::default()
            },
        };
        let cases = [
            (
                "anisotropic GGX",
                conductor(0.1, 0.5, Distribution::Ggx),
                true,
                0.4,
            ),
            (
                "anisotropic Beckmann",
                conductor(0.5, 0.15, Distribution::Beckmann),
                true,
                1.1,
            ),
            ("anisotropic glass front true", glass, true, 2.0),
            ("anisotropic glass front false", glass, false, -0.6),
            ("anisotropic principled", principled, true, 0.9),
            ("anisotropic principled thin", thin, false, -1.3),
        ];
        cases
            .into_iter()
            .map(|(name, surface, front, angle)| {
                let bsdf = Bsdf::new(surface, front, Sampling::Cosine);
                (name.to_string(), bsdf.with_tangent(Vec2::from_angle(angle)))
            })
            .collect()
    }

    /// Principled BSDFs: nearly all diffuse, metallic with a clearcoat,
    /// sheen and flatness across an index below 1.
    fn principled_lobes() -> Vec<(String, Bsdf)> {
        let p = Principled::default();
        let cases = [
            ("principled diffuse", Vec3::new(0.8, 0.4, 0.2), p),
            (
                "principled metal α 0.05",
                Vec3::new(0.9, 0.6, 0.3),
                Principled {
                    roughness: 0.22,
                    metallic: 0.8,
                    specular_tint: 0.5,
                    clearcoat: 0.7,
                    clearcoat_gloss: 0.8,
                    spec_trans: 0.0,
                    anisotropic: 0.0,
                    ..p
                },
            ),
            (
                "principled sheen",
                Vec3::new(0.2, 0.5, 0.7),
                Principled {
                    roughness: 0.3,
                    sheen: 0.6,
                    sheen_tint: 0.5,
                    flatness: 0.4,
                    eta: 0.8,
                    ..p
                },
            ),
            (
                "principled glass",
                Vec3::new(0.9, 0.8, 0.7),
                Principled {
                    roughness: 0.45,
                    spec_trans: 1.0,
                    anisotropic: 0.0,
                    ..p
                },
            ),
            (
                "principled half glass",
                Vec3::new(0.6, 0.7, 0.9),
                Principled {
                    roughness: 0.6,
                    metallic: 0.2,
                    spec_trans: 0.5,
                    anisotropic: 0.0,
                    clearcoat: 0.5,
                    eta: 1.33,
                    ..p
                },
            ),
            (
                "principled thin leaf",
                Vec3::new(0.3, 0.6, 0.2),
                Principled {
                    roughness: 0.4,
                    sheen: 0.5,
                    sheen_tint: 0.3,
                    flatness: 0.3,
                    thin: Some(0.4),
                    ..p
                },
            ),
            (
                "principled thin glass",
                Vec3::new(0.9, 0.8, 0.7),
                Principled {
                    roughness: 0.3,
                    spec_trans: 1.0,
                    specular_tint: 0.4,
                    thin: Some(0.0),
                    ..p
                },
            ),
            (
                "principled thin mix",
                Vec3::new(0.6, 0.7, 0.9),
                Principled {
                    roughness: 0.6,
                    spec_trans: 0.5,
                    eta: 1.33,
                    thin: Some(0.6),
                    ..p
                },
            ),
        ];
        let mut out = Vec::new();
        for (name, base_color, params) in cases {
            let surface = Surface::Principled { base_color, params };
            // Where it lets light through, its back too.
            for front in [true, false]
                .into_iter()
                .take(if params.transmits() { 2 } else { 1 })
            {
                let name = format!("{name} front {front}");
                out.push((name, Bsdf::new(surface, front, Sampling::Cosine)));
            }
        }
        out
    }

    #[test]
    fn rough_lobes_sample_their_pdf() {
        for (name, bsdf) in rough_lobes() {
            for theta in [10.0, 50.0, 80.0] {
                let what = format!("{name} θ {theta}");
                assert_sampler_follows_pdf(&what, &bsdf, direction(theta), 11 + theta as u64);
            }
        }
    }

    /// The sampler's mean of f cos / pdf equals f cos integrated over both
    /// sides by quadrature; no lobe creates energy (transmitted radiance
    /// counted at η² for the flux it carries), and a nearly smooth glass
    /// loses almost none at normal incidence.
    #[test]
    fn rough_lobes_conserve_energy_and_sample_their_integral() {
        let mut rng = crate::fuzz::Rng::new(5);
        for (name, bsdf) in rough_lobes() {
            let eta = match bsdf.lobe {
                Lobe::RoughDielectric { eta, .. } => eta,
                // A thin sheet passes light through unbent.
                Lobe::Principled(p) if p.thin.is_none() => p.eta,
                _ => 1.0,
            };
            for theta in [0.0, 45.0, 80.0] {
                let wo = direction(theta);
                let n = 200_000;
                let (mut sampled, mut flux) = (0.0f64, 0.0f64);
                for _ in 0..n {
                    let u = Vec3::new(rng.unit(), rng.unit(), rng.unit());
                    if let Some((wi, _)) = bsdf.sample(wo, u) {
                        let w = (bsdf.eval(wo, wi).y / bsdf.pdf(wo, wi)) as f64;
                        sampled += w;
                        flux += if wi.z < 0.0 {
                            w * (eta * eta) as f64
                        } else {
                            w
                        };
                    }
                }
                let (sampled, flux) = (sampled / n as f64, flux / n as f64);
                let m = 800;
                let mut integral = 0.0f64;
                for u in grid(m) {
                    let wi = square_to_hemisphere(u);
                    integral += bsdf.eval(wo, wi).y as f64;
                    integral += bsdf.eval(wo, Vec3::new(wi.x, wi.y, -wi.z)).y as f64;
                }
                integral *= 2.0 * std::f64::consts::PI / (m * m) as f64;
                // Burley's model is not: its sheen and flattened diffuse lobe
                // return 1.43 of the light at 80° (Mitsuba's own albedo there,
                // principled.rs).
                assert!(
                    flux <= 1.0 + 5e-3 || name.starts_with("principled"),
                    "{name} θ {theta}: {flux}"
                );
                if name.contains("α 0.05") && name.starts_with("glass") && theta == 0.0 {
                    assert!(flux > 0.99, "{name}: {flux}");
                }
                // Quadrature misses narrow lobes: it checks the broad ones.
                if !name.contains("α 0.05") {
                    assert!(
                        (sampled - integral).abs() < 0.01 * integral.max(0.1),
                        "{name} θ {theta}: sampled {sampled}, quadrature {integral}"
                    );
                }
            }
        }
    }

    /// Reciprocity: a rough plastic's f is symmetric; rough glass's
    /// transmission seen from the other side is η² times as large, the
    /// radiance it carries compressed into the denser medium's solid angle.
    #[test]
    fn rough_lobes_are_reciprocal() {
        for (name, bsdf) in rough_lobes() {
            for (a, b) in [
                (5.0f32, 40.0f32),
                (30.0, -60.0),
                (75.0, 10.0),
                (60.0, -20.0),
            ] {
                let wo = direction(a);
                let wi = (direction(b.abs()) * Vec3::new(b.signum(), 1.0, 1.0)
                    + Vec3::new(0.0, 0.3, 0.0))
                .normalize();
                let (f1, f2) = (bsdf.eval(wo, wi) / wi.z, bsdf.eval(wi, wo) / wo.z);
                assert!(
                    (f1 - f2).abs().max_element() <= 1e-4 * f1.max_element().max(1.0),
                    "{name}: {f1} vs {f2}"
                );
                // Through the surface: wo above, wi below, and back.
                let (eta, other) = match bsdf.lobe {
                    Lobe::RoughDielectric {
                        eta,
                        reflectance,
                        alpha,
                        alpha_v,
                        distribution,
                    } => {
                        let lobe = Lobe::RoughDielectric {
                            eta: 1.0 / eta,
                            reflectance,
                            alpha,
                            alpha_v,
                            distribution,
                        };
                        (
                            eta,
                            Bsdf {
                                lobe,
                                color: bsdf.color,
                                tangent: bsdf.tangent,
                            },
                        )
                    }
                    // A thin sheet's back is its front.
                    Lobe::Principled(p) if p.thin.is_some() => (1.0, bsdf),
                    // Its back is rough glass (Principled::back).
                    Lobe::Principled(p) if p.transmits() => (
                        p.eta,
                        Bsdf::new(p.back(bsdf.color), false, Sampling::Cosine),
                    ),
                    _ => continue,
                };
                let below = Vec3::new(wi.x, wi.y, -wi.z);
                let there = bsdf.eval(wo, below) / below.z.abs();
                let flip = |v: Vec3| Vec3::new(v.x, v.y, -v.z);
                let back_again = other.eval(flip(below), flip(wo)) / wo.z;
                // Mitsuba's thin sheet passes light only where the far
                // direction sees the half vector from behind, which need not
                // hold both ways at grazing angles: not reciprocal there.
                let thin = matches!(bsdf.lobe, Lobe::Principled(p) if p.thin.is_some());
                let seen = |wo, wi| Principled::thin_half(wo, wi).is_some();
                if thin && seen(wo, below) != seen(flip(below), flip(wo)) {
                    continue;
                }
                assert!(
                    (back_again - there * eta * eta).abs().max_element()
                        <= 1e-3 * back_again.max_element().max(1e-3),
                    "{name} {a} {b}: {there} vs {back_again}"
                );
            }
        }
    }

    /// A rough plastic's base as Mitsuba 3.9.1 evaluates it (its
    /// `roughplastic`, diffuse component only, diffuse_reflectance 0.5,
    /// wi = wo at cos θ, scalar_rgb): its transmittance table and internal
    /// reflectance, integrated by qtrace's own quadrature (converged: 512
    /// nodes change it by 1e-4), agree within 0.2%; near grazing, where
    /// Mitsuba integrates with 32 nodes over its own sampler of Beckmann's
    /// visible normals, within 8% (the base sends little light there).
    #[test]
    fn rough_plastic_base_is_mitsubas() {
        let cases = [
            (
                Distribution::Beckmann,
                0.1,
                [
                    (1.0, 0.15584558),
                    (0.8, 0.12356943),
                    (0.5, 0.06994212),
                    (0.2, 0.01565285),
                    (0.05, 0.0016605518),
                ],
            ),
            (
                Distribution::Ggx,
                0.3,
                [
                    (1.0, 0.11053859),
                    (0.8, 0.08587269),
                    (0.5, 0.047818),
                    (0.2, 0.014468054),
                    (0.05, 0.0028018656),
                ],
            ),
        ];
        for (distribution, alpha, values) in cases {
            let surface = Surface::RoughPlastic {
                diffuse: Vec3::splat(0.5),
                specular: Vec3::ZERO,
                eta: 1.49,
                nonlinear: false,
                alpha,
                distribution,
                table: RoughTable::new(1.49, alpha, distribution),
            };
            let bsdf = Bsdf::new(surface, true, Sampling::Cosine);
            for (mu, want) in values {
                let w = Vec3::new((1.0f32 - mu * mu).sqrt(), 0.0, mu);
                let got = bsdf.eval(w, w).x;
                assert!(
                    (got - want).abs() < if mu >= 0.2 { 2e-3 } else { 0.08 } * want,
                    "{distribution:?} α {alpha} cos {mu}: {got} vs Mitsuba's {want}"
                );
            }
        }
    }

    #[test]
    fn glass_splits_by_fresnel_and_refracts_by_snell() {
        let glass = Surface::Dielectric {
            ior: 1.5,
            transmittance: Vec3::ONE,
            reflectance: Vec3::ONE,
        };
        let outside = Bsdf::new(glass, true, Sampling::Cosine);
        let inside = Bsdf::new(glass, false, Sampling::Cosine);
        assert!(outside.is_delta() && inside.is_delta());
        // Normal incidence: ((η − 1) / (η + 1))² = 0.04.
        assert!((fresnel_dielectric(1.0, 1.5).0 - 0.04).abs() < 1e-6);
        for theta in [0.0f32, 20.0, 45.0, 70.0, 89.0] {
            let wo = direction(theta);
            let (f, _) = fresnel_dielectric(wo.z, 1.5);
            let (r, wr) = outside.sample_delta(wo, f * 0.5);
            assert_eq!((r, wr), (Vec3::new(-wo.x, -wo.y, wo.z), Vec3::ONE));
            let (t, wt) = outside.sample_delta(wo, 0.5 * (1.0 + f));
            // Snell: sin θ_t = sin θ_i / η, below the surface, unit length.
            assert!((t.length() - 1.0).abs() < 1e-5 && t.z < 0.0);
            assert!((t.x.abs() * 1.5 - wo.x).abs() < 1e-5);
            assert!((wt - Vec3::splat(1.0 / 2.25)).abs().max_element() < 1e-6);
            // Back through the surface from inside: the same path reversed,
            // the same Fresnel split, and radiance scaled back up by η².
            let back = -t;
            let (f_in, _) = fresnel_dielectric(back.z, 1.0 / 1.5);
            assert!((f_in - f).abs() < 1e-4, "θ {theta}: {f_in} vs {f}");
            let (out, w_out) = inside.sample_delta(back, 0.999_999);
            assert!((out + wo).length() < 1e-4 || f_in > 0.999_999);
            assert!((w_out - Vec3::splat(2.25)).abs().max_element() < 1e-4);
        }
        // Beyond the critical angle inside: total internal reflection.
        let grazing = direction(60.0);
        assert_eq!(fresnel_dielectric(grazing.z, 1.0 / 1.5).0, 1.0);
        assert_eq!(inside.sample_delta(grazing, 0.999).0.z, grazing.z);
    }

    /// At normal incidence the conductor Fresnel term is
    /// ((η − 1)² + k²) / ((η + 1)² + k²); at grazing incidence it is 1; a
    /// dielectric (k = 0) gets the dielectric term.
    #[test]
    fn conductor_fresnel_has_its_limits() {
        let ior = VEACH_METAL;
        let normal = fresnel_conductor(1.0, ior);
        let e = ior.eta;
        let k2 = ior.k * ior.k;
        let want = ((e - 1.0) * (e - 1.0) + k2) / ((e + 1.0) * (e + 1.0) + k2);
        assert!(
            (normal - want).abs().max_element() < 1e-5,
            "{normal} vs {want}"
        );
        assert!(
            (fresnel_conductor(1e-6, ior) - Vec3::ONE)
                .abs()
                .max_element()
                < 1e-3
        );
        for cos in [0.1f32, 0.5, 0.9] {
            let glass = ComplexIor {
                eta: Vec3::splat(1.5),
                k: Vec3::ZERO,
            };
            let f = fresnel_conductor(cos, glass).x;
            assert!(
                (f - fresnel_dielectric(cos, 1.5).0).abs() < 1e-5,
                "{cos}: {f}"
            );
        }
        // A smooth Fresnel conductor reflects with the term at wo.
        let mirror = Bsdf::new(
            Surface::Conductor {
                reflectance: Vec3::splat(0.5),
                alpha: 0.0,
                alpha_v: None,
                distribution: Distribution::Beckmann,
                fresnel: Some(ior),
            },
            true,
            Sampling::Cosine,
        );
        let wo = direction(40.0);
        let (_, w) = mirror.sample_delta(wo, 0.5);
        assert!((w - 0.5 * fresnel_conductor(wo.z, ior)).abs().max_element() < 1e-6);
    }

    /// Mitsuba's fits of the hemispherical Fresnel reflectance (values from
    /// Mitsuba 3.9.1's `fresnel_diffuse_reflectance`).
    #[test]
    fn fresnel_diffuse_reflectance_is_mitsubas() {
        for (eta, want) in [
            (1.49f32, 0.090299964),
            (1.0 / 1.49, 0.5907325),
            (1.5, 0.09177428),
            (2.0, 0.16058916),
        ] {
            let got = fresnel_diffuse_reflectance(eta);
            assert!((got - want).abs() < 1e-5, "{eta}: {got} vs {want}");
        }
    }

    /// A plastic's two lobes: the base's sampler follows its pdf (the
    /// cosine) and reproduces its integral, the coat's share follows the
    /// Fresnel term, and the whole BSDF, both lobes sampled as the kernel
    /// samples them, reflects what its parts integrate to; it is reciprocal.
    #[test]
    fn plastic_lobes_sample_what_they_evaluate() {
        for nonlinear in [false, true] {
            let surface = Surface::Plastic {
                diffuse: Vec3::new(0.9, 0.5, 0.1),
                specular: Vec3::splat(0.8),
                eta: 1.49,
                nonlinear,
            };
            let bsdf = Bsdf::new(surface, true, Sampling::Uniform);
            for theta in [0.0f32, 40.0, 75.0, 88.0] {
                let wo = direction(theta);
                let share = bsdf.delta_share(wo);
                let f = fresnel_dielectric(wo.z, 1.49).0;
                // Mitsuba's choice: F weighted by the specular's share of
                // the mean colours, against 1 - F by the diffuse's.
                let w = 0.8 / (0.8 + 0.5);
                let want = f * w / (f * w + (1.0 - f) * (1.0 - w));
                assert!((share - want).abs() < 1e-6, "{share} vs {want}");
                // The base: E[f cos / pdf] over its sampler against quadrature.
                let n = 300;
                let sampled: Vec3 = grid(n)
                    .filter_map(|u| bsdf.sample(wo, u.extend(0.5)))
                    .map(|(wi, _)| bsdf.eval(wo, wi) / bsdf.pdf(wo, wi))
                    .sum::<Vec3>()
                    / (n * n) as f32;
                let m = 600;
                let integral: Vec3 = grid(m)
                    .map(|u| bsdf.eval(wo, square_to_hemisphere(u)))
                    .sum::<Vec3>()
                    * (2.0 * PI / (m * m) as f32);
                assert!(
                    (sampled - integral).abs().max_element() < 3e-3,
                    "θ {theta}: {sampled} vs {integral}"
                );
                // The whole, as the kernel weighs it: the coat with
                // probability share, its weight over share; the base
                // otherwise, its density (1 - share) times the sampler's.
                let (_, coat) = bsdf.sample_delta(wo, 0.5);
                assert!((coat - Vec3::splat(0.8 * f)).abs().max_element() < 1e-6);
                let whole = share * (coat / share) + (1.0 - share) * (sampled / (1.0 - share));
                assert!((whole - (coat + integral)).abs().max_element() < 3e-3);
                for b in [10.0f32, 50.0, 80.0] {
                    let wi = (direction(b) + Vec3::new(0.0, 0.2, 0.0)).normalize();
                    let (f1, f2) = (bsdf.eval(wo, wi) / wi.z, bsdf.eval(wi, wo) / wo.z);
                    assert!((f1 - f2).abs().max_element() < 1e-5, "{f1} vs {f2}");
                }
            }
        }
    }

    /// A thin sheet reflects 2F / (1 + F) of what arrives (its inner
    /// reflections summed), passes the rest straight through, and looks the
    /// same from both sides.
    #[test]
    fn thin_glass_reflects_its_summed_fresnel_and_passes_the_rest() {
        let sheet = Surface::Thin {
            eta: 1.5,
            reflectance: Vec3::splat(0.9),
            transmittance: Vec3::new(1.0, 0.5, 0.25),
        };
        for front in [true, false] {
            let b = Bsdf::new(sheet, front, Sampling::Cosine);
            assert!(b.is_delta() && b.delta_share(Vec3::Z) == 1.0);
            for theta in [0.0f32, 45.0, 80.0] {
                let wo = direction(theta);
                let f = fresnel_dielectric(wo.z, 1.5).0;
                let r = thin_reflectance(wo.z, 1.5);
                assert!((r - 2.0 * f / (1.0 + f)).abs() < 1e-6, "{r} vs {f}");
                let (wr, weight) = b.sample_delta(wo, 0.99 * r);
                assert_eq!(
                    (wr, weight),
                    (Vec3::new(-wo.x, -wo.y, wo.z), Vec3::splat(0.9))
                );
                let (wt, weight) = b.sample_delta(wo, r + 0.01 * (1.0 - r));
                assert_eq!((wt, weight), (-wo, Vec3::new(1.0, 0.5, 0.25)));
            }
        }
    }

    #[test]
    fn mirror_reflects_with_its_reflectance() {
        let mirror = Bsdf::new(
            Surface::conductor(Vec3::new(0.9, 0.5, 0.1), 0.0),
            false,
            Sampling::Cosine,
        );
        assert!(mirror.is_delta());
        let wo = direction(35.0);
        assert_eq!(mirror.eval(wo, wo), Vec3::ZERO);
        assert_eq!(
            mirror.sample_delta(wo, 0.3),
            (Vec3::new(-wo.x, -wo.y, wo.z), Vec3::new(0.9, 0.5, 0.1))
        );
    }

    /// Rough glass and rough plastic evaluate as Mitsuba 3.9.1's
    /// `roughdielectric` and `roughplastic` do (scalar_rgb, `eval` with
    /// si.wi = wo; directions as (θ, φ) in degrees; ext_ior air).
    #[test]
    fn rough_lobes_evaluate_as_mitsuba() {
        let air = 1.000277;
        let dir = |t: f32, p: f32| {
            let (t, p) = (t.to_radians(), p.to_radians());
            Vec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
        };
        let plastic = |diffuse: Vec3, ior: f32, alpha: f32, distribution| {
            let eta = ior / air;
            Surface::RoughPlastic {
                diffuse,
                specular: Vec3::ONE,
                eta,
                nonlinear: false,
                alpha,
                distribution,
                table: RoughTable::new(eta, alpha, distribution),
            }
        };
        let glass = |ior: f32, alpha: f32, distribution| Surface::RoughDielectric {
            ior: ior / air,
            reflectance: Vec3::ONE,
            transmittance: Vec3::ONE,
            alpha,
            alpha_v: None,
            distribution,
        };
        let cases = [
            (
                plastic(Vec3::new(0.3, 0.45, 0.6), 1.6, 0.4, Distribution::Ggx),
                [
                    (10.0, 180.0, Vec3::new(0.0704726, 0.0963881, 0.122304)),
                    (60.0, 90.0, Vec3::new(0.027217, 0.0392721, 0.0513273)),
                ],
            ),
            (
                plastic(Vec3::new(0.8, 0.3, 0.2), 1.49, 0.1, Distribution::Beckmann),
                [
                    (10.0, 180.0, Vec3::new(0.244328, 0.0918465, 0.0613502)),
                    (60.0, 90.0, Vec3::new(0.117357, 0.0440088, 0.0293392)),
                ],
            ),
            (
                glass(1.5, 0.25, Distribution::Ggx),
                [
                    (10.0, 180.0, Vec3::splat(0.016614)),
                    (150.0, 180.0, Vec3::splat(7.06345)),
                ],
            ),
            (
                glass(1.333, 0.1, Distribution::Beckmann),
                [
                    (10.0, 180.0, Vec3::splat(0.000189188)),
                    (150.0, 180.0, Vec3::splat(134.696)),
                ],
            ),
        ];
        let wo = dir(40.0, 0.0);
        for (surface, values) in cases {
            let bsdf = Bsdf::new(surface, true, Sampling::Cosine);
            for (t, p, want) in values {
                let got = bsdf.eval(wo, dir(t, p));
                assert!(
                    (got - want).abs().max_element() < 2e-3 * want.max_element(),
                    "{}: θ {t} φ {p}: {got} vs Mitsuba's {want}",
                    surface.name()
                );
            }
        }
    }

    /// Anisotropic roughness against Mitsuba 3.9.1 (`BSDF.eval`, and
    /// `BSDF.pdf` where both sample GGX's visible normals; wi at θ 40°
    /// φ 30°, alpha_u along the local x axis): roughconductor GGX (Al) and
    /// Beckmann, principled with `anisotropic`, roughdielectric GGX. The
    /// same with the frame turned about the normal and the tangent with it.
    #[test]
    fn anisotropic_lobes_evaluate_as_mitsuba() {
        let dir = |t: f32, p: f32| {
            let (t, p) = (t.to_radians(), p.to_radians());
            Vec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
        };
        let al = ComplexIor {
            eta: Vec3::new(1.657501, 0.880405, 0.521244),
            k: Vec3::new(9.223811, 6.269502, 4.837004),
        };
        let conductor = |alpha, alpha_v, distribution, fresnel| Surface::Conductor {
            reflectance: Vec3::ONE,
            alpha,
            alpha_v: Some(alpha_v),
            distribution,
            fresnel,
        };
        let principled = Surface::Principled {
            base_color: Vec3::new(0.9, 0.6, 0.3),
            params: Principled {
                roughness: 0.4,
                metallic: 0.8,
                anisotropic: 0.7,
                eta: 2.0 / (1.0 - (0.08f32 * 0.5).sqrt()) - 1.0,
                ..Principled::default()
            },
        };
        let glass = Surface::RoughDielectric {
            ior: 1.5,
            reflectance: Vec3::ONE,
            transmittance: Vec3::ONE,
            alpha: 0.1,
            alpha_v: Some(0.35),
            distribution: Distribution::Ggx,
        };
        #[allow(clippy::type_complexity)]
        let cases: [(&str, Surface, bool, [(f32, f32, [f32; 3], f32); 5]); 4] = [
            (
                "GGX Al",
                conductor(0.05, 0.3, Distribution::Ggx, Some(al)),
                true,
                [
                    (35.0, 210.0, [2.570337, 2.541639, 2.54512], 2.782824),
                    (40.0, 180.0, [0.923888, 0.913563, 0.914833], 0.997921),
                    (30.0, 250.0, [0.013104, 0.012958, 0.012975], 0.014227),
                    (60.0, 120.0, [0.11126, 0.110022, 0.110166], 0.12587),
                    (150.0, 200.0, [0.0; 3], 0.0),
                ],
            ),
            (
                "Beckmann",
                conductor(0.4, 0.1, Distribution::Beckmann, None),
                false,
                [
                    (35.0, 210.0, [2.463501; 3], 0.0),
                    (40.0, 180.0, [0.034261; 3], 0.0),
                    (30.0, 250.0, [0.906914; 3], 0.0),
                    (60.0, 120.0, [0.0; 3], 0.0),
                    (150.0, 200.0, [0.0; 3], 0.0),
                ],
            ),
            (
                "principled",
                principled,
                true,
                [
                    (35.0, 210.0, [2.594307, 1.740192, 0.886077], 2.975154),
                    (40.0, 180.0, [0.141907, 0.095023, 0.048138], 0.154036),
                    (30.0, 250.0, [0.510461, 0.342105, 0.17375], 0.573855),
                    (60.0, 120.0, [0.030151, 0.020107, 0.010062], 0.02822),
                    (150.0, 200.0, [0.0; 3], 0.0),
                ],
            ),
            (
                "glass",
                glass,
                true,
                [
                    (35.0, 210.0, [0.099036; 3], 0.099496),
                    (40.0, 180.0, [0.051416; 3], 0.051507),
                    (30.0, 250.0, [0.003158; 3], 0.003187),
                    (60.0, 120.0, [0.005763; 3], 0.006145),
                    (150.0, 200.0, [0.436709; 3], 0.984489),
                ],
            ),
        ];
        for turn in [0.0f32, 0.7] {
            let about_z = |w: Vec3| {
                let (s, c) = turn.sin_cos();
                Vec3::new(c * w.x - s * w.y, s * w.x + c * w.y, w.z)
            };
            for (name, surface, same_sampler, values) in cases {
                let bsdf =
                    Bsdf::new(surface, true, Sampling::Cosine).with_tangent(Vec2::from_angle(turn));
                let wo = about_z(dir(40.0, 30.0));
                for (t, phi, want, want_pdf) in values {
                    let wi = about_z(dir(t, phi));
                    let (got, want) = (bsdf.eval(wo, wi), Vec3::from(want));
                    assert!(
                        (got - want).abs().max_element() <= 2e-3 * want.max_element() + 1e-7,
                        "{name} turned {turn}: θ {t} φ {phi}: {got} vs Mitsuba's {want}"
                    );
                    let pdf = bsdf.pdf(wo, wi);
                    if same_sampler {
                        assert!(
                            (pdf - want_pdf).abs() <= 2e-3 * want_pdf + 1e-7,
                            "{name} turned {turn}: θ {t} φ {phi}: pdf {pdf} vs Mitsuba's {want_pdf}"
                        );
                    }
                }
            }
        }
    }
}
