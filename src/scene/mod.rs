//! Scenes: TOML + OBJ/MTL (+ procedural geometry) → triangles, materials,
//! lights, camera and a BVH ready for the GPU.

pub mod bvh;
pub mod environment;
pub mod file;
mod mitsuba;
pub mod obj;
pub mod ply;
pub mod procedural;
pub mod serialized;
pub mod texture;

use crate::bsdf::{luminance, Distribution, Surface};
use crate::shaders;
use file::{CameraDesc, RenderDefaults, SceneFile};
use glam::{Vec2, Vec3};
use std::path::{Path, PathBuf};

/// Everything that can be wrong with a scene; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("{path}: cannot read scene: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}:{line}: {message}")]
    Toml {
        path: PathBuf,
        line: usize,
        message: String,
    },
    /// A problem at a line of an XML scene (or a file it includes).
    #[error("{path}:{line}: {message}")]
    At {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error("{path}: malformed OBJ: {message}")]
    Obj { path: PathBuf, message: String },
    #[error("{path}: {message}")]
    Mtl { path: PathBuf, message: String },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    #[error("{path}: the scene has no emitter (no material with Ke > 0 and no environment)")]
    NoEmitter { path: PathBuf },
}

/// A material as the renderer uses it.
#[derive(Clone, Debug)]
pub struct Material {
    pub name: String,
    pub surface: Surface,
    pub emission: Vec3,
    /// Black on the side the triangle's normal does not face (Mitsuba's
    /// BSDFs outside `twosided`); MTL materials reflect on both sides.
    pub one_sided: bool,
    /// The textures (indices into `Scene::textures`) that replace its
    /// colour, its second colour, its alpha and rough glass's alpha across
    /// its tangent (`TEXTURE_SLOT_*`); the surface holds each texture's
    /// mean there.
    pub textures: [Option<u32>; TEXTURE_SLOTS],
    /// Mitsuba's `normalmap`: the normals that turn its shading frame.
    pub normal_map: Option<NormalMap>,
    /// Mitsuba's `mask`, `blendbsdf` or two-sided `twosided`: the material
    /// stands for one of two others, taken at each hit, and its own
    /// surface goes unused.
    pub choice: Option<Choice>,
    /// An emitter on a mesh read from a Mitsuba scene (OBJ, PLY,
    /// serialized) some of whose corner normals differ from their faces':
    /// it emits on the side its shading normal faces, as Mitsuba's area
    /// lights do. (A TOML scene's emitters emit on their faces' side, and
    /// Mitsuba's own shapes, which qtrace tessellates, on their true
    /// surface's, which their faces follow.)
    pub smooth_light: bool,
}

/// A material that stands for one of two others (`Material::choice`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Choice {
    pub kind: ChoiceKind,
    /// The two materials (indices into `Scene::materials`).
    pub first: u32,
    pub second: u32,
}

/// How a choice takes its material.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ChoiceKind {
    /// Mitsuba's `mask`: the first passes paths straight through (`null`),
    /// the second, the masked material, is taken with probability
    /// `opacity`: a number in [0, 1], or the luminance of a texture
    /// (an index into `Scene::textures`) at the hit.
    Mask { opacity: Weight },
    /// Mitsuba's `blendbsdf`: the second taken with probability `weight`.
    Blend { weight: Weight },
    /// Mitsuba's `twosided` with two BSDFs: the first on the front of the
    /// shading normal, the second on the back.
    Sides,
}

/// A choice's probability of its second material.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Weight {
    Constant(f32),
    Texture(u32),
}

impl ChoiceKind {
    /// The probability of the second material, where a weight chooses.
    fn weight(self) -> Option<Weight> {
        match self {
            ChoiceKind::Mask { opacity: w } | ChoiceKind::Blend { weight: w } => Some(w),
            ChoiceKind::Sides => None,
        }
    }

    /// The texture that weight reads, if any.
    pub(crate) fn texture(self) -> Option<u32> {
        match self.weight() {
            Some(Weight::Texture(t)) => Some(t),
            _ => None,
        }
    }
}

impl Choice {
    fn weight(&self) -> Option<Weight> {
        self.kind.weight()
    }

    fn texture(&self) -> Option<u32> {
        self.kind.texture()
    }

    /// What users call it.
    pub fn name(&self) -> &'static str {
        match self.kind {
            ChoiceKind::Mask { .. } => "mask",
            ChoiceKind::Blend { .. } => "blend",
            ChoiceKind::Sides => "two-faced",
        }
    }
}

/// Mitsuba's `normalmap` around a material.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NormalMap {
    /// Its normals' texture, an index into `Scene::textures`.
    pub texture: u32,
    /// Whether a `twosided` lies around the map (the unmapped normal then
    /// tells the sides apart), else the map lies around the BSDF, which
    /// tells them by the mapped normal.
    pub in_twosided: bool,
    /// Mitsuba's `bumpmap`: the texture is a height field, whose gradient
    /// times this scale tilts the normal (else it holds the normals).
    pub bump: Option<f32>,
}

impl Material {
    pub fn diffuse(name: &str, albedo: Vec3) -> Self {
        Self {
            name: name.into(),
            surface: Surface::Diffuse { albedo },
            emission: Vec3::ZERO,
            one_sided: false,
            textures: [None; TEXTURE_SLOTS],
            normal_map: None,
            choice: None,
            smooth_light: false,
        }
    }

    /// Whether it reads texture coordinates: a texture, a normal or bump
    /// map, a textured choice, or a roughness that follows them.
    pub fn textured(&self) -> bool {
        self.textures.iter().any(Option::is_some)
            || self.normal_map.is_some()
            || self.choice.is_some_and(|c| c.texture().is_some())
            // Its roughness follows the texture coordinates' dp/du.
            || self.surface.anisotropic()
    }

    /// What users call its kind: its surface's, or its choice's; a sheet
    /// that lets all light straight through is Mitsuba's `null`.
    pub fn kind_name(&self) -> &'static str {
        match (self.choice, self.surface) {
            (Some(c), _) => c.name(),
            (
                None,
                Surface::Thin {
                    eta, reflectance, ..
                },
            ) if eta == 1.0 && reflectance == Vec3::ZERO => "null",
            _ => self.surface.name(),
        }
    }

    /// Whether it emits and its BSDF is Mitsuba's `null`: paths go on
    /// through it (other emitters end them).
    pub fn emitter_passes(&self) -> bool {
        let null = Surface::Thin {
            eta: 1.0,
            reflectance: Vec3::ZERO,
            transmittance: Vec3::ONE,
        };
        self.emission.max_element() > 0.0 && self.surface == null && self.choice.is_none()
    }

    /// Whether it emits and its BSDF scatters light (neither black nor
    /// null): paths are shaded there as on any surface, after gathering
    /// its emission.
    pub fn emitter_reflects(&self) -> bool {
        let black = matches!(self.surface, Surface::Diffuse { albedo } if albedo == Vec3::ZERO);
        self.emission.max_element() > 0.0
            && self.choice.is_none()
            && !black
            && !self.emitter_passes()
    }

    /// Its BSDF at texture coordinates `uv` (the CPU twin of `bsdf_of`
    /// then `bsdf_textured`).
    pub fn bsdf_at(
        &self,
        front: bool,
        uv: Vec2,
        textures: &[texture::Texture],
        sampling: crate::bsdf::Sampling,
    ) -> crate::bsdf::Bsdf {
        let bsdf = self.bsdf(front, sampling);
        if self.one_sided && !front {
            return bsdf;
        }
        let look = |slot: u32| self.textures[slot as usize].map(|t| textures[t as usize].eval(uv));
        if let Surface::Principled { params: own, .. } = self.surface {
            // Its textures' values enter both its sides' lobes.
            let surface = self
                .surface
                .with_means(
                    look(shaders::TEXTURE_SLOT_COLOR),
                    look(shaders::TEXTURE_SLOT_SECOND),
                    look(shaders::TEXTURE_SLOT_ALPHA).map(luminance),
                    None,
                )
                .with_weight_means(|s| look(s).map(luminance));
            // Where the texture of one that lets light through says
            // opaque, its back is black (as in Mitsuba).
            let opaque =
                matches!(surface, Surface::Principled { params, .. } if params.spec_trans <= 0.0);
            if !front && own.thin.is_none() && own.spec_trans > 0.0 && opaque {
                return crate::bsdf::Bsdf::new(
                    Surface::Diffuse { albedo: Vec3::ZERO },
                    true,
                    sampling,
                );
            }
            return crate::bsdf::Bsdf::new(surface, front, sampling);
        }
        bsdf.textured(
            look(shaders::TEXTURE_SLOT_COLOR),
            look(shaders::TEXTURE_SLOT_SECOND),
            look(shaders::TEXTURE_SLOT_ALPHA).map(luminance),
            look(shaders::TEXTURE_SLOT_ACROSS).map(luminance),
        )
    }

    /// Its BSDF for a path arriving on the front side or the back (the CPU
    /// twin of `bsdf_of` in glsl/bsdf.glsl).
    pub fn bsdf(&self, front: bool, sampling: crate::bsdf::Sampling) -> crate::bsdf::Bsdf {
        let bsdf = crate::bsdf::Bsdf::new(self.surface, front, sampling);
        match self.surface {
            // Its specular lobe does not scale with its base colour.
            Surface::Principled { .. } if self.one_sided && !front => {
                crate::bsdf::Bsdf::new(Surface::Diffuse { albedo: Vec3::ZERO }, true, sampling)
            }
            _ if self.one_sided && !front => bsdf.black(),
            _ => bsdf,
        }
    }

    /// The material as the kernels read it (`Material` of shared.h).
    pub fn gpu(&self) -> shaders::Material {
        if let Some(c) = self.choice {
            let at_random = match c.kind {
                ChoiceKind::Mask { .. } => shaders::CHOICE_MASK,
                _ => shaders::CHOICE_AT_RANDOM,
            };
            let (by, weight, texture) = match c.weight() {
                None => (shaders::CHOICE_BY_SIDE, 0.0, 0),
                Some(Weight::Constant(w)) => (at_random, w, 0),
                Some(Weight::Texture(t)) => (at_random, 0.0, t + 1),
            };
            return shaders::Material {
                color: [
                    weight,
                    texture as f32,
                    by as f32,
                    shaders::MATERIAL_CHOICE as f32,
                ],
                emission: [c.first as f32, c.second as f32, 0.0, 0.0],
                eta: [0.0; 4],
                k: [0.0; 4],
            };
        }
        let (color, parameter) = self.surface.color_and_parameter();
        let mut code = self.surface.kind();
        if self.one_sided {
            code |= shaders::MATERIAL_ONE_SIDED;
        }
        if self.emitter_passes() {
            code |= shaders::MATERIAL_EMITTER_PASSES;
        }
        if self.emitter_reflects() {
            code |= shaders::MATERIAL_EMITTER_REFLECTS;
        }
        if self.smooth_light {
            code |= shaders::MATERIAL_EMITTER_SMOOTH;
        }
        if let Some(map) = self.normal_map {
            code |= (map.texture + 1) << shaders::MATERIAL_NORMAL_MAP_SHIFT;
            if map.in_twosided {
                code |= shaders::MATERIAL_MAP_IN_TWOSIDED;
            }
            if map.bump.is_some() {
                code |= shaders::MATERIAL_MAP_BUMP;
            }
        }
        let (mut eta, mut k) = (Vec3::ZERO, Vec3::ZERO);
        if self.surface.distribution() == Some(Distribution::Beckmann) {
            code |= shaders::MATERIAL_BECKMANN;
        }
        if let Surface::Conductor {
            fresnel: Some(ior), ..
        } = self.surface
        {
            code |= shaders::MATERIAL_FRESNEL;
            (eta, k) = (ior.eta, ior.k);
        }
        if let Surface::Plastic { nonlinear, .. } | Surface::RoughPlastic { nonlinear, .. } =
            self.surface
        {
            if nonlinear {
                code |= shaders::MATERIAL_NONLINEAR;
            }
        }
        if let Some((specular, terms)) = self.surface.plastic_terms() {
            (eta, k) = (specular, terms);
        }
        if let Surface::Thin { reflectance, .. } | Surface::Dielectric { reflectance, .. } =
            self.surface
        {
            eta = reflectance;
        }
        if let Surface::RoughDielectric {
            reflectance, alpha, ..
        } = self.surface
        {
            (eta, k) = (reflectance, Vec3::new(0.0, 0.0, alpha));
        }
        if let Surface::Principled { params: p, .. } = self.surface {
            eta = Vec3::new(p.thin.unwrap_or(p.metallic), p.specular_tint, p.sheen);
            k = Vec3::new(p.sheen_tint, p.flatness, p.clearcoat);
        }
        // Three slots in eta.w's bits; rough glass's alpha across its
        // tangent in k.w.
        let slots = self.textures[..3]
            .iter()
            .enumerate()
            .fold(0, |acc, (s, t)| {
                let t = t.map_or(0, |t| t + 1);
                acc | t << (shaders::TEXTURE_SLOT_BITS * s as u32)
            });
        let slots = if slots == 0 {
            0.0
        } else {
            f32::from_bits(slots | shaders::TEXTURE_SLOT_MARK)
        };
        // A bump map's scale where the material emits nothing (an
        // emitter's BSDF goes unread).
        let emission = match self.normal_map.and_then(|m| m.bump) {
            Some(scale) if self.emission == Vec3::ZERO => Vec3::new(scale, 0.0, 0.0),
            _ => self.emission,
        };
        shaders::Material {
            color: color.extend(code as f32).into(),
            emission: emission.extend(parameter).into(),
            eta: eta.extend(slots).into(),
            k: k.extend(match self.textures[shaders::TEXTURE_SLOT_ACROSS as usize] {
                Some(t) => -(t as f32 + 1.0),
                None => self.surface.alpha_across().unwrap_or(0.0),
            })
            .into(),
        }
    }
}

/// The materials as the kernels read them: each one's `Material`, then the
/// rough plastics' transmittance tables, 4 records each, and the principled
/// materials' (eta, clearcoat gloss, spec_trans, anisotropic), a record each, which their `k.w`
/// points to (as a word of the buffer).
pub fn gpu_materials(materials: &[Material]) -> Vec<shaders::Material> {
    let mut out: Vec<shaders::Material> = materials.iter().map(Material::gpu).collect();
    for i in 0..materials.len() {
        if let Surface::RoughPlastic { table, .. } = materials[i].surface {
            out[i].k[3] = (4 * out.len()) as f32;
            for c in table.transmittance.chunks_exact(16) {
                out.push(shaders::Material {
                    color: c[0..4].try_into().unwrap(),
                    emission: c[4..8].try_into().unwrap(),
                    eta: c[8..12].try_into().unwrap(),
                    k: c[12..16].try_into().unwrap(),
                });
            }
        }
        if let Surface::Principled { params, .. } = materials[i].surface {
            out[i].k[3] = (4 * out.len()) as f32;
            // Its further textures' slots (TEXTURE_SLOT_HIGHLIGHT_TINT..).
            let slot = |s: u32| materials[i].textures[s as usize].map_or(0.0, |t| t as f32 + 1.0);
            out.push(shaders::Material {
                color: [
                    params.eta,
                    params.clearcoat_gloss,
                    params.spec_trans,
                    params.anisotropic,
                ],
                emission: [
                    slot(shaders::TEXTURE_SLOT_HIGHLIGHT_TINT),
                    slot(shaders::TEXTURE_SLOT_SHEEN),
                    slot(shaders::TEXTURE_SLOT_SHEEN_TINT),
                    slot(shaders::TEXTURE_SLOT_FLATNESS),
                ],
                eta: [
                    slot(shaders::TEXTURE_SLOT_CLEARCOAT),
                    slot(shaders::TEXTURE_SLOT_CLEARCOAT_GLOSS),
                    slot(shaders::TEXTURE_SLOT_ANISOTROPIC),
                    slot(shaders::TEXTURE_SLOT_TRANSMISSION),
                ],
                ..Default::default()
            });
        }
    }
    out
}

/// Which extent of the image a camera's field of view spans (Mitsuba's
/// `fov_axis`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FovAxis {
    X,
    Y,
    Diagonal,
    /// The shorter side of the image.
    Smaller,
    /// The longer side of the image.
    Larger,
}

/// How a sample's point in its pixel is drawn: from the reconstruction
/// filter, which converges to the image a renderer that splats with that
/// filter makes. Offsets are from the pixel's centre, in pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PixelFilter {
    /// Uniform over the pixel (qtrace's own scenes).
    Box,
    Tent {
        radius: f32,
    },
    Gaussian {
        stddev: f32,
    },
    /// Mitchell and Netravali's cubics of parameters `b` and `c` (radius
    /// 2; Catmull and Rom's is B = 0, C = 1/2), and Lanczos's windowed sinc
    /// of `lobes` lobes: filters with negative lobes, whose samples carry
    /// signed weights.
    Cubic {
        b: f32,
        c: f32,
    },
    Lanczos {
        lobes: u32,
    },
}

impl PixelFilter {
    /// Mitchell and Netravali's cubic of `b` and `c` at offset `x`, as
    /// Mitsuba 3 evaluates it (trace.comp's `signed_filter`).
    pub fn cubic(b: f32, c: f32, x: f32) -> f32 {
        let x = x.abs();
        let (x2, x3) = (x * x, x * x * x);
        let v = if x < 1.0 {
            (12.0 - 9.0 * b - 6.0 * c) * x3 + (-18.0 + 12.0 * b + 6.0 * c) * x2 + (6.0 - 2.0 * b)
        } else {
            (-b - 6.0 * c) * x3
                + (6.0 * b + 30.0 * c) * x2
                + (-12.0 * b - 48.0 * c) * x
                + (8.0 * b + 24.0 * c)
        };
        if x < 2.0 {
            v / 6.0
        } else {
            0.0
        }
    }

    /// A bound on the cubic's magnitude, under which the kernels draw its
    /// points by rejection: its largest over 4,096 steps, with room for
    /// what lies between them (its slope is at most 12 + 9|b| + 40|c|).
    pub fn cubic_bound(b: f32, c: f32) -> f32 {
        let steps = 4096;
        let most = (0..=steps)
            .map(|i| Self::cubic(b, c, 2.0 * i as f32 / steps as f32).abs())
            .fold(0.0f32, f32::max);
        let slope = 12.0 + 9.0 * b.abs() + 40.0 * c.abs();
        most + slope / steps as f32
    }
}

/// Pinhole camera. A TOML scene's follows the right-handed look-at
/// convention (docs/scenes.md); an XML scene's, its sensor's to_world.
#[derive(Clone, Copy, Debug)]
pub struct Camera {
    pub position: Vec3,
    pub forward: Vec3,
    /// The image's right and up, unit vectors.
    pub right: Vec3,
    pub up: Vec3,
    pub fov_degrees: f32,
    pub fov_axis: FovAxis,
    /// A thin lens's radius (0: a pinhole) and the distance along `forward`
    /// of the plane it brings into focus.
    pub aperture_radius: f32,
    pub focus_distance: f32,
    /// Mitsuba's `orthographic`: parallel rays along `forward` from the
    /// plane `near` ahead of `position`, `half_width` to either side and
    /// `half_width / aspect` up and down (its to_world's x and y scales).
    pub orthographic: Option<Orthographic>,
    /// Mitsuba's `principal_point_offset_x` and `_y`: the point the image is
    /// centred on moved right and down by these fractions of its width and
    /// height (a pinhole's view shifted, not turned).
    pub shift: Vec2,
    /// Mitsuba's film crop window: the image shows this part of the film.
    pub crop: Option<Crop>,
}

/// A crop window of a film (Mitsuba's `crop_offset_x`, `crop_width`, ...),
/// in the film's pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Crop {
    /// The whole film's width and height, which the field of view spans.
    pub film: (u32, u32),
    pub offset: (u32, u32),
    pub size: (u32, u32),
}

/// An orthographic camera's extent (see [`Camera::orthographic`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Orthographic {
    pub half_width: f32,
    pub half_height: f32,
    pub near: f32,
}

impl Camera {
    fn from_desc(d: &CameraDesc) -> Result<Self, String> {
        let vals = d.position.iter().chain(&d.look_at).chain(&d.up);
        if !vals.chain([&d.fov_y]).all(|v| v.is_finite()) {
            return Err("camera values must be finite".into());
        }
        if !(d.fov_y > 0.0 && d.fov_y < 180.0) {
            return Err(format!(
                "camera fov_y {} must lie in (0, 180) degrees",
                d.fov_y
            ));
        }
        if !(d.aperture_radius >= 0.0 && d.aperture_radius.is_finite()) {
            return Err(format!(
                "camera aperture_radius {} must be 0 (a pinhole) or more",
                d.aperture_radius
            ));
        }
        if let Some(f) = d.focus_distance.filter(|f| !(*f > 0.0 && f.is_finite())) {
            return Err(format!("camera focus_distance {f} must be positive"));
        }
        let position = Vec3::from(d.position);
        let to = Vec3::from(d.look_at) - position;
        if to.length() == 0.0 {
            return Err("camera look_at equals its position".into());
        }
        let forward = to.normalize();
        let right = forward.cross(Vec3::from(d.up));
        if right.length() < 1e-6 {
            return Err("camera up is zero or parallel to the view direction".into());
        }
        let right = right.normalize();
        Ok(Self {
            position,
            forward,
            right,
            up: right.cross(forward),
            fov_degrees: d.fov_y,
            fov_axis: FovAxis::Y,
            aperture_radius: d.aperture_radius,
            // In focus where the camera looks, unless told.
            focus_distance: d.focus_distance.unwrap_or(to.length()),
            orthographic: None,
            shift: Vec2::ZERO,
            crop: None,
        })
    }

    /// Tangents of half the horizontal and vertical fields of view of a
    /// `width` × `height` image (of its crop window, where the film has
    /// one, whatever the image's size).
    /// (An orthographic camera's half extents instead.)
    pub fn tan_half_fov(&self, width: u32, height: u32) -> (f32, f32) {
        match self.crop {
            None => self.film_tan_half_fov(width, height),
            Some(c) => {
                let (tx, ty) = self.film_tan_half_fov(c.film.0, c.film.1);
                (
                    tx * c.size.0 as f32 / c.film.0 as f32,
                    ty * c.size.1 as f32 / c.film.1 as f32,
                )
            }
        }
    }

    /// Pixels across a `width` × `height` image (of the whole film, where it
    /// has a crop window) that a length `size` spans at `distance` from the
    /// camera, seen square on (any distance, for an orthographic camera;
    /// at none, infinitely many): how finely a curved shape there is
    /// tessellated.
    pub fn pixels_across(&self, size: f32, distance: f32, width: u32, height: u32) -> f32 {
        let (w, h) = self.crop.map_or((width, height), |c| c.film);
        let (tx, _) = self.film_tan_half_fov(w, h);
        let per_pixel = 2.0 * tx / w as f32;
        if self.orthographic.is_some() {
            size / per_pixel
        } else if distance > 0.0 {
            size / (distance * per_pixel)
        } else {
            f32::INFINITY
        }
    }

    /// [`Camera::tan_half_fov`] of a whole film of `width` × `height`.
    fn film_tan_half_fov(&self, width: u32, height: u32) -> (f32, f32) {
        let aspect = width as f32 / height as f32;
        if let Some(o) = self.orthographic {
            return (o.half_width, o.half_height / aspect);
        }
        let t = (self.fov_degrees.to_radians() * 0.5).tan();
        let axis = match self.fov_axis {
            FovAxis::Smaller if width < height => FovAxis::X,
            FovAxis::Larger if width > height => FovAxis::X,
            FovAxis::Smaller | FovAxis::Larger => FovAxis::Y,
            a => a,
        };
        match axis {
            FovAxis::X => (t, t / aspect),
            FovAxis::Diagonal => {
                let ty = t / (1.0 + aspect * aspect).sqrt();
                (ty * aspect, ty)
            }
            _ => (t * aspect, t),
        }
    }

    /// Where a crop window's centre lies from the film's, along `right` and
    /// `up`, for the film's half-field tangents (fx, fy).
    fn crop_centre(&self, fx: f32, fy: f32) -> Vec3 {
        let Some(c) = self.crop else {
            return Vec3::ZERO;
        };
        let cx = (2 * c.offset.0 + c.size.0) as f32 / c.film.0 as f32 - 1.0;
        let cy = 1.0 - (2 * c.offset.1 + c.size.1) as f32 / c.film.1 as f32;
        cx * fx * self.right + cy * fy * self.up
    }

    /// The ray (origin, unit direction) through image point (x, y) in
    /// pixels (fractional), a thin lens's centre's; row 0 is the top of the
    /// image.
    pub fn ray(&self, x: f32, y: f32, width: u32, height: u32) -> (Vec3, Vec3) {
        let (tx, ty) = self.tan_half_fov(width, height);
        let sx = 2.0 * x / width as f32 - 1.0;
        let sy = 1.0 - 2.0 * y / height as f32;
        let across = sx * tx * self.right + sy * ty * self.up;
        match self.orthographic {
            Some(_) => (self.origin() + across, self.forward),
            None => (
                self.position,
                (self.centre_ray(tx, ty) + across).normalize(),
            ),
        }
    }

    /// The direction (not unit) of the ray through the image's centre, at
    /// the half-field tangents (tx, ty): `forward`, moved by the shift and
    /// to a crop window's centre (an orthographic camera's: `forward`).
    pub fn centre_ray(&self, tx: f32, ty: f32) -> Vec3 {
        if self.orthographic.is_some() {
            return self.forward;
        }
        let (fx, fy) = match self.crop {
            None => (tx, ty),
            Some(c) => self.film_tan_half_fov(c.film.0, c.film.1),
        };
        self.forward + 2.0 * self.shift.x * fx * self.right - 2.0 * self.shift.y * fy * self.up
            + self.crop_centre(fx, fy)
    }

    /// Where the kernels start camera rays: an orthographic camera's plane.
    pub fn origin(&self) -> Vec3 {
        let Some(o) = self.orthographic else {
            return self.position;
        };
        let centre = match self.crop {
            None => Vec3::ZERO,
            Some(c) => {
                let (fx, fy) = self.film_tan_half_fov(c.film.0, c.film.1);
                self.crop_centre(fx, fy)
            }
        };
        self.position + o.near * self.forward + centre
    }
}

/// A loaded scene, triangles already in BVH leaf order.
pub struct Scene {
    pub path: PathBuf,
    /// FNV-1a over the bytes of every file the scene was read from: parts
    /// of one render carry it, so `merge` refuses parts of another scene.
    pub fingerprint: u64,
    pub camera: Camera,
    pub filter: PixelFilter,
    pub defaults: RenderDefaults,
    /// The `[sarsa]` and `[neural]` tables, as written; render settings
    /// check and read them.
    pub guide_tables: Vec<(String, toml::Table)>,
    /// Light from beyond the scene, if any.
    pub environment: Option<environment::Environment>,
    pub materials: Vec<Material>,
    pub triangles: Vec<shaders::Triangle>,
    /// Shading normals at each triangle's corners, packed by
    /// [`pack_normal`] (the fourth word unused), in the triangles' order;
    /// empty where every triangle is shaded flat.
    pub normals: Vec<[u32; 4]>,
    /// Texture coordinates at each triangle's corners, in `triangles`'
    /// order; empty where no shape has them.
    pub uvs: Vec<[Vec2; 3]>,
    /// What textured materials' slots index.
    pub textures: Vec<texture::Texture>,
    /// The mesh attributes textures read, by name: per triangle, in
    /// `triangles`' order, the values at its corners (a one-channel
    /// attribute's value in all three channels; zeros where its shape has
    /// none).
    pub attributes: Vec<(String, Vec<[Vec3; 3]>)>,
    pub lights: Vec<shaders::Light>,
    /// Point, spot and directional lights, and the entries of NEE's light
    /// list that follow `lights` on the GPU: theirs (`LIGHT_DELTA | index`),
    /// then the environment's (`LIGHT_ENVIRONMENT`).
    pub delta_lights: Vec<shaders::DeltaLight>,
    pub delta_entries: Vec<shaders::Light>,
    pub nodes: std::sync::Arc<Vec<shaders::BvhNode>>,
    pub bvh_depth: u32,
    /// The box around every triangle.
    pub bounds: (Vec3, Vec3),
    /// Diagonal of the scene's bounding box.
    pub extent: f32,
}

fn toml_error(path: &Path, text: &str, e: toml::de::Error) -> SceneError {
    let line = e
        .span()
        .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1)
        .unwrap_or(1);
    SceneError::Toml {
        path: path.to_path_buf(),
        line,
        message: e.message().replace('\n', " "),
    }
}

fn check_color(path: &Path, what: &str, c: [f32; 3]) -> Result<Vec3, SceneError> {
    if c.iter().all(|v| v.is_finite() && *v >= 0.0) {
        Ok(Vec3::from(c))
    } else {
        Err(SceneError::Invalid {
            path: path.to_path_buf(),
            message: format!("{what} {c:?} must be finite and non-negative"),
        })
    }
}

impl Scene {
    /// How renders name the scene: its file's name and the fingerprint of
    /// its contents, the same on every machine.
    pub fn id(&self) -> String {
        let name = self.path.file_name().unwrap_or_default().to_string_lossy();
        format!("{name} {:016x}", self.fingerprint)
    }

    /// Whether a material is not diffuse (metal or glass).
    pub fn has_non_diffuse(&self) -> bool {
        self.materials
            .iter()
            .any(|m| m.surface.kind() != shaders::MATERIAL_DIFFUSE)
    }

    /// The conductor and plastic options (MATERIAL_BECKMANN, _FRESNEL,
    /// _NONLINEAR, FEATURE_PLASTIC) some material of the scene uses, as the
    /// kernels' CONSTANT_MATERIAL_FEATURES.
    pub fn material_features(&self) -> u32 {
        self.materials.iter().fold(0, |acc, m| {
            let code = m.gpu().color[3] as u32;
            let flags = shaders::MATERIAL_BECKMANN
                | shaders::MATERIAL_FRESNEL
                | shaders::MATERIAL_NONLINEAR;
            let feature = match m.surface {
                Surface::Plastic { .. } => shaders::FEATURE_PLASTIC,
                Surface::RoughPlastic { .. } => {
                    shaders::FEATURE_PLASTIC | shaders::FEATURE_ROUGH_PLASTIC
                }
                Surface::RoughDielectric { .. } => shaders::FEATURE_ROUGH_GLASS,
                Surface::Principled { params, .. } if params.thin.is_some() => {
                    shaders::FEATURE_PRINCIPLED | shaders::FEATURE_PRINCIPLED_THIN
                }
                // Its back is rough glass where it lets light through.
                Surface::Principled { params, .. } if params.transmits() => {
                    shaders::FEATURE_PRINCIPLED | shaders::FEATURE_ROUGH_GLASS
                }
                Surface::Principled { .. } => shaders::FEATURE_PRINCIPLED,
                _ => 0,
            };
            let textured = if m.textured() {
                shaders::FEATURE_TEXTURES
            } else {
                0
            };
            let mapped = if m.normal_map.is_some() {
                shaders::FEATURE_NORMAL_MAPS
            } else {
                0
            };
            let chooses = if m.choice.is_some() {
                shaders::FEATURE_CHOICES
            } else {
                0
            };
            let anisotropic = if m.surface.anisotropic() {
                shaders::FEATURE_ANISOTROPIC
            } else {
                0
            };
            // An emitter's colour slot holds its radiance's texture.
            let emits_image = m.emission.max_element() > 0.0
                && m.textures[shaders::TEXTURE_SLOT_COLOR as usize].is_some();
            let light = if emits_image {
                shaders::FEATURE_TEXTURED_LIGHTS
            } else {
                0
            } | if m.smooth_light {
                shaders::FEATURE_SMOOTH_LIGHTS
            } else {
                0
            };
            acc | (code & flags) | feature | textured | mapped | chooses | anisotropic | light
        }) | if self.attributes.is_empty() {
            0
        } else {
            shaders::FEATURE_ATTRIBUTES
        } | self.delta_lights.iter().fold(0, |acc, l| {
            // A projector, or a spot light casting an image, and its image.
            let code = l.position[3] as u32;
            let casts = delta_kind(l) == shaders::DELTA_SPOT && code >> 2 != 0;
            let projector = if delta_kind(l) == shaders::DELTA_PROJECTOR || casts {
                shaders::FEATURE_PROJECTORS
            } else {
                0
            };
            let image = if code >> 2 != 0 {
                shaders::FEATURE_TEXTURES
            } else {
                0
            };
            acc | projector | image
        }) | if self.materials.iter().any(Material::emitter_reflects) {
            shaders::FEATURE_EMITTERS_REFLECT
        } else {
            0
        }
    }

    /// The scene's table of guide `name` (empty when it has none).
    pub fn guide_table(&self, name: &str) -> &toml::Table {
        static EMPTY: std::sync::OnceLock<toml::Table> = std::sync::OnceLock::new();
        self.guide_tables
            .iter()
            .find(|(n, _)| *n == name)
            .map_or_else(|| EMPTY.get_or_init(toml::Table::new), |(_, t)| t)
    }

    /// NEE's list: its emitting triangles, then delta lights and the sky.
    pub fn nee_entries(&self) -> impl Iterator<Item = &shaders::Light> {
        self.lights.iter().chain(&self.delta_entries)
    }

    /// How many lights NEE's entries make (`Light::group`): an emitter's
    /// connected triangles, a delta light, the sky.
    pub fn light_group_count(&self) -> usize {
        self.nee_entries()
            .map(|l| l.group as usize + 1)
            .max()
            .unwrap_or(0)
    }

    /// A name for each light NEE's entries make (`Light::group`): its
    /// emitters' material name (the first's, and how many more where nearby
    /// ones go together), the kind of delta light, or the sky; with where it
    /// is (its members' centre by power) wherever a name would not tell it
    /// apart from another light's.
    pub fn light_names(&self) -> Vec<String> {
        use shaders::{DELTA_DIRECTIONAL, DELTA_POINT, DELTA_SPOT, LIGHT_DELTA, LIGHT_ENVIRONMENT};
        let count = self.light_group_count();
        // Per light: its members' names (each once, in order), centre weight and sum.
        let mut kinds: Vec<Vec<String>> = vec![Vec::new(); count];
        let mut centres = vec![(0.0f64, Vec3::ZERO); count];
        for (i, entry) in self.nee_entries().enumerate() {
            let g = entry.group as usize;
            let (name, at) = if let Some(light) = self.lights.get(i) {
                let t = &self.triangles[light.triangle as usize];
                (
                    self.materials[t.material as usize].name.clone(),
                    Some(triangle_centre(t)),
                )
            } else if entry.triangle == LIGHT_ENVIRONMENT {
                ("the sky".to_string(), None)
            } else if entry.triangle == LIGHT_ENVIRONMENT | 1 {
                ("the sky's brightest part".to_string(), None)
            } else {
                let d = &self.delta_lights[(entry.triangle & !LIGHT_DELTA) as usize];
                let name = match delta_kind(d) {
                    DELTA_POINT => "point light",
                    DELTA_SPOT => "spot light",
                    DELTA_DIRECTIONAL => "directional light",
                    _ => "projector",
                };
                (name.to_string(), delta_place(d))
            };
            if !kinds[g].contains(&name) {
                kinds[g].push(name);
            }
            if let Some(at) = at {
                let w = f64::from(entry.pdf).max(1e-12);
                centres[g].0 += w;
                centres[g].1 += at * w as f32;
            }
        }
        let names: Vec<String> = kinds
            .iter()
            .map(|k| match k.len() {
                1 => k[0].clone(),
                n => format!("{} and {} more", k[0], n - 1),
            })
            .collect();
        names
            .iter()
            .enumerate()
            .map(|(g, name)| {
                let (w, sum) = centres[g];
                let shared = names.iter().filter(|n| *n == name).count() > 1;
                if shared && w > 0.0 {
                    let c = sum / w as f32;
                    format!("{name} near ({:.2}, {:.2}, {:.2})", c.x, c.y, c.z)
                } else {
                    name.clone()
                }
            })
            .collect()
    }

    /// Whether the guides may pick NEE's light: where there are at least
    /// two lights and at most MAX_GUIDED_LIGHTS.
    pub fn lights_to_pick(&self) -> bool {
        (2..=shaders::MAX_GUIDED_LIGHTS as usize).contains(&self.light_group_count())
    }

    /// The lights (`LightGroup`) and their members, each light's together,
    /// as the device reads them after NEE's list where the guides may pick
    /// NEE's light; none elsewhere.
    pub fn light_groups(&self) -> (Vec<shaders::LightGroup>, Vec<shaders::LightMember>) {
        if !self.lights_to_pick() {
            return (Vec::new(), Vec::new());
        }
        let mut members: Vec<Vec<(u32, f32)>> = vec![Vec::new(); self.light_group_count()];
        for (i, l) in self.nee_entries().enumerate() {
            members[l.group as usize].push((i as u32, l.pdf));
        }
        let mut groups = Vec::with_capacity(members.len());
        let mut list = Vec::new();
        for entries in &members {
            let power: f64 = entries.iter().map(|&(_, p)| p as f64).sum();
            groups.push(shaders::LightGroup {
                first: list.len() as u32,
                count: entries.len() as u32,
                power: power as f32,
                pad: 0,
            });
            let mut acc = 0.0f64;
            for &(light, p) in entries {
                acc += p as f64;
                list.push(shaders::LightMember {
                    light,
                    cdf: (acc / power) as f32,
                    ..Default::default()
                });
            }
            // Rounding must leave no gap at the top.
            list.last_mut().unwrap().cdf = 1.0;
        }
        (groups, list)
    }

    /// The probability NEE picks the environment (0 without one).
    pub fn environment_pick(&self) -> f32 {
        self.delta_entries
            .iter()
            .filter(|l| l.triangle & !1 == shaders::LIGHT_ENVIRONMENT)
            .map(|l| l.pdf)
            .sum()
    }

    /// How far rays start off the surface they leave: small against the
    /// scene, large against float error.
    pub fn ray_offset(&self) -> f32 {
        self.extent * 1e-5
    }

    /// The box around every triangle.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.bounds
    }

    /// Loads and validates a scene file and everything it names: qtrace's
    /// TOML, or Mitsuba 3's XML for a `.xml` file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, SceneError> {
        Self::load_with(path.as_ref(), &Loader::default())
    }

    /// [`Scene::load`] with Mitsuba's `-D name=value` parameters for an XML scene.
    pub fn load_defined(
        path: impl AsRef<Path>,
        defines: &[(String, String)],
    ) -> Result<Self, SceneError> {
        let loader = Loader {
            defines,
            ..Loader::default()
        };
        Self::load_with(path.as_ref(), &loader)
    }

    /// [`Scene::load`], reading files and bounding the scene's size as `loader` says.
    pub fn load_with(path: &Path, loader: &Loader<'_>) -> Result<Self, SceneError> {
        // Every file read, and every -D, goes into the scene's fingerprint.
        let fingerprint = std::cell::Cell::new(0xcbf2_9ce4_8422_2325u64);
        let hash = |bytes: &[u8]| {
            let mut h = fingerprint.get();
            for &b in bytes {
                h = (h ^ b as u64).wrapping_mul(0x0100_0000_01b3);
            }
            fingerprint.set(h);
        };
        for (k, v) in loader.defines {
            hash(format!("-D {k}={v}\n").as_bytes());
        }
        let hashing = |p: &Path| {
            let bytes = (loader.read)(p)?;
            hash(&bytes);
            Ok(bytes)
        };
        let loader = &Loader {
            read: &hashing,
            max_triangles: loader.max_triangles,
            defines: loader.defines,
        };
        let xml = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("xml"));
        let start = std::time::Instant::now();
        let parts = if xml {
            mitsuba::read(path, loader, loader.defines)?
        } else {
            if !loader.defines.is_empty() {
                return Err(SceneError::Invalid {
                    path: path.to_path_buf(),
                    message: "-D parameters are for Mitsuba XML scenes".into(),
                });
            }
            read_toml(path, loader)?
        };
        log::info!(
            "{}: read in {:.2} s",
            path.display(),
            start.elapsed().as_secs_f64()
        );
        Self::assemble(path, parts, fingerprint.get(), loader.max_triangles)
    }

    /// Checks what a reader made and builds the BVH and the light list.
    fn assemble(
        path: &Path,
        parts: Parts,
        fingerprint: u64,
        max_triangles: usize,
    ) -> Result<Self, SceneError> {
        let invalid = |message: String| SceneError::Invalid {
            path: path.to_path_buf(),
            message,
        };
        let Parts {
            camera,
            filter,
            drop_degenerate,
            defaults,
            guide_tables,
            environment,
            materials,
            textures,
            geometry,
            delta_lights,
        } = parts;
        let Geometry {
            positions,
            normals,
            uvs,
            attributes,
            material_of,
            sources,
            source_of,
        } = geometry;
        if positions.is_empty() {
            return Err(invalid("the scene has no triangles".into()));
        }
        if positions.len() > max_triangles {
            return Err(invalid(format!(
                "the scene has more than {max_triangles} triangles, the most a scene may have"
            )));
        }
        // Texture coordinates serve only textures: a large mesh's would
        // cost memory for nothing.
        let uvs = if materials.iter().any(Material::textured) {
            uvs
        } else {
            Vec::new()
        };
        let extent = extent_of(&positions, &sources, &source_of)?;
        let zero_area = |t: &[Vec3; 3]| {
            0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length() <= 1e-12 * extent * extent
        };
        let (positions, (normals, uvs, attributes), material_of, source_of) = if drop_degenerate {
            drop_zero_area(
                positions,
                (normals, uvs, attributes),
                material_of,
                source_of,
                &sources,
                zero_area,
            )
        } else {
            (
                positions,
                (normals, uvs, attributes),
                material_of,
                source_of,
            )
        };
        if positions.is_empty() {
            return Err(invalid(
                "the scene has no triangles of non-zero area".into(),
            ));
        }
        for (i, t) in positions.iter().enumerate() {
            let area = 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length();
            if area <= 1e-12 * extent * extent {
                let (src, what) = &sources[source_of[i] as usize];
                return Err(SceneError::Invalid {
                    path: src.clone(),
                    message: format!("triangle {i} ({what}) has zero area"),
                });
            }
        }
        let has_emitter = material_of
            .iter()
            .any(|&m| materials[m as usize].emission.max_element() > 0.0);
        let sky = environment.as_ref().is_some_and(|e| e.power > 0.0);
        if !has_emitter && !sky && delta_lights.is_empty() {
            return Err(SceneError::NoEmitter {
                path: path.to_path_buf(),
            });
        }

        // Packed before the BVH, and each table dropped once the device's
        // form is made: a 10M-triangle scene's peak memory is set here.
        let normals = pack_normals(normals);
        let start = std::time::Instant::now();
        let bvh = bvh::build(&positions);
        log::info!(
            "BVH over {} triangles, depth {}, built in {:.2} s",
            positions.len(),
            bvh.depth,
            start.elapsed().as_secs_f64()
        );
        let normals = in_order(normals, &bvh.order);
        let mut triangles: Vec<shaders::Triangle> = bvh
            .order
            .iter()
            .map(|&i| {
                let [a, b, c] = positions[i as usize];
                let (e1, e2) = (b - a, c - a);
                shaders::Triangle {
                    v0: a.into(),
                    material: material_of[i as usize],
                    e1: e1.into(),
                    light_pdf: 0.0,
                    e2: e2.into(),
                    area: 0.5 * e1.cross(e2).length(),
                }
            })
            .collect();
        let parts = emitter_parts(&positions, &material_of, &materials, &bvh.order);
        drop(positions);
        // NEE weighs the sky by the power it sends into the scene: its
        // radiance over a disk as wide as the scene.
        // Its parts (a sun and the rest) are lights of their own.
        let sky_weights: Vec<f32> = environment
            .iter()
            .filter(|e| e.power > 0.0)
            .flat_map(|e| {
                let power = e.power * std::f32::consts::PI * 0.25 * extent * extent;
                e.shares[..e.parts()].iter().map(move |s| power * s)
            })
            .collect();
        let attributes: Attributes = attributes
            .into_iter()
            .map(|(n, v)| (n, in_order(v, &bvh.order)))
            .collect();
        let (lights, delta_entries) = build_lights(
            &mut triangles,
            &parts,
            &materials,
            &emitted_means(&materials, &textures, &attributes),
            &delta_lights,
            &sky_weights,
        );
        // Each attribute texture reads its values at its place among
        // the triangle's.
        let mut textures = textures;
        for t in &mut textures {
            if let texture::Pattern::Attribute {
                name, slot, stride, ..
            } = &mut t.pattern
            {
                *slot = attributes.iter().position(|(n, _)| n == name).unwrap_or(0) as u32;
                *stride = attributes.len() as u32;
            }
        }
        let mut uvs = in_order(uvs, &bvh.order);
        if uvs.is_empty() && materials.iter().any(Material::textured) {
            uvs = vec![BARYCENTRIC_UVS; triangles.len()];
        }
        Ok(Self {
            path: path.to_path_buf(),
            fingerprint,
            camera,
            filter,
            defaults,
            guide_tables,
            environment,
            materials,
            textures,
            attributes,
            triangles,
            normals,
            uvs,
            lights,
            delta_lights: delta_lights.into_iter().map(|(l, _)| l).collect(),
            delta_entries,
            nodes: std::sync::Arc::new(bvh.nodes),
            bvh_depth: bvh.depth,
            bounds: bvh.bounds,
            extent,
        })
    }

    /// Closest hit by testing every triangle: the reference for BVH tests.
    pub fn intersect_brute(&self, o: Vec3, d: Vec3) -> Option<(f32, u32)> {
        let mut best: Option<(f32, u32)> = None;
        for (i, t) in self.triangles.iter().enumerate() {
            if let Some(tt) = ray_triangle(o, d, t) {
                if best.is_none_or(|b| tt < b.0) {
                    best = Some((tt, i as u32));
                }
            }
        }
        best
    }
}

/// What a scene reader hands on: everything before the checks and the BVH.
struct Parts {
    camera: Camera,
    filter: PixelFilter,
    /// Leave out triangles of zero area with a warning (meshes made by
    /// other tools have them, and Mitsuba never hits them) rather than
    /// refuse the scene.
    drop_degenerate: bool,
    defaults: RenderDefaults,
    guide_tables: Vec<(String, toml::Table)>,
    environment: Option<environment::Environment>,
    materials: Vec<Material>,
    textures: Vec<texture::Texture>,
    geometry: Geometry,
    /// Lights only NEE reaches, each with its weight in NEE's choice.
    delta_lights: Vec<(shaders::DeltaLight, f32)>,
}

/// A qtrace TOML scene and the OBJ/MTL it names.
fn read_toml(path: &Path, loader: &Loader<'_>) -> Result<Parts, SceneError> {
    let text = loader.text(path).map_err(|source| SceneError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let file: SceneFile = toml::from_str(&text).map_err(|e| toml_error(path, &text, e))?;
    let invalid = |message: String| SceneError::Invalid {
        path: path.to_path_buf(),
        message,
    };
    let camera = Camera::from_desc(&file.camera).map_err(invalid)?;
    let sky = check_color(path, "environment", file.environment.unwrap_or([0.0; 3]))?;
    let environment = (sky.max_element() > 0.0).then(|| environment::Environment::constant(sky));

    let mut materials: Vec<Material> = Vec::new();
    let mut textures = Vec::new();
    let mut geometry = Geometry::default();
    if let Some(mesh) = &file.mesh {
        let obj_path = path.parent().unwrap_or(Path::new(".")).join(mesh);
        load_obj(
            &obj_path,
            loader,
            (&mut materials, &mut textures),
            &mut geometry,
        )?;
    }
    for p in &file.procedural {
        procedural::validate(p).map_err(invalid)?;
        let count = procedural::triangle_count(p) as usize;
        if geometry.positions.len().saturating_add(count) > loader.max_triangles {
            return Err(invalid(format!(
                "the scene would have more than {} triangles, the most a scene may have",
                loader.max_triangles
            )));
        }
        let g = procedural::generate(p);
        let m = materials.len() as u32;
        materials.push(Material::diffuse(
            &g.name,
            check_color(path, "procedural albedo", g.albedo.into())?,
        ));
        geometry
            .sources
            .push((path.to_path_buf(), format!("procedural {}", g.name)));
        let src = geometry.sources.len() as u32 - 1;
        for t in g.triangles {
            geometry.positions.push(t);
            geometry.material_of.push(m);
            geometry.source_of.push(src);
        }
    }
    if file.mesh.is_none() && file.procedural.is_empty() {
        return Err(invalid(
            "the scene names no mesh and no procedural geometry".into(),
        ));
    }

    if !geometry.uvs.is_empty() {
        let missing = geometry.positions.len() - geometry.uvs.len();
        geometry
            .uvs
            .extend(std::iter::repeat_n(BARYCENTRIC_UVS, missing));
    }
    Ok(Parts {
        camera,
        filter: PixelFilter::Box,
        drop_degenerate: false,
        defaults: file.render,
        guide_tables: file.guides,
        environment,
        materials,
        textures,
        geometry,
        delta_lights: Vec::new(),
    })
}

/// The length of the scene's bounding box diagonal (the scale of the
/// relative zero-area test and the ray offset); an error names a triangle
/// with a NaN or infinite vertex.
fn extent_of(
    positions: &[[Vec3; 3]],
    sources: &[(PathBuf, String)],
    source_of: &[u32],
) -> Result<f32, SceneError> {
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for (i, t) in positions.iter().enumerate() {
        if !t.iter().all(|p| p.is_finite()) {
            let (src, what) = &sources[source_of[i] as usize];
            return Err(SceneError::Invalid {
                path: src.clone(),
                message: format!("triangle {i} ({what}) has a NaN or infinite vertex"),
            });
        }
        for p in t {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
    }
    Ok((hi - lo).length().max(1e-6))
}

/// Per-vertex normals packed for the device; none where every triangle is
/// flat (the kernels then shade with the faces' normals).
fn pack_normals(normals: Vec<[Vec3; 3]>) -> Vec<[u32; 4]> {
    if normals.iter().all(|n| n[0] == n[1] && n[1] == n[2]) {
        return Vec::new();
    }
    normals
        .iter()
        .map(|n| {
            let [a, b, c] = n.map(pack_normal);
            [a, b, c, 0]
        })
        .collect()
}

/// `items` (one per triangle, or none) in the BVH's order: `k`-th is the
/// old `items[order[k]]`.
fn in_order<T: Copy>(items: Vec<T>, order: &[u32]) -> Vec<T> {
    if items.is_empty() {
        return items;
    }
    order.iter().map(|&i| items[i as usize]).collect()
}

/// The triangles without those `zero_area` says have none, and one warning
/// per source that had some.
#[allow(clippy::type_complexity)]
fn drop_zero_area(
    positions: Vec<[Vec3; 3]>,
    (normals, uvs, attributes): (Vec<[Vec3; 3]>, Vec<[Vec2; 3]>, Attributes),
    material_of: Vec<u32>,
    source_of: Vec<u32>,
    sources: &[(PathBuf, String)],
    zero_area: impl Fn(&[Vec3; 3]) -> bool,
) -> (
    Vec<[Vec3; 3]>,
    (Vec<[Vec3; 3]>, Vec<[Vec2; 3]>, Attributes),
    Vec<u32>,
    Vec<u32>,
) {
    let mut dropped = vec![0usize; sources.len()];
    let keep: Vec<bool> = positions
        .iter()
        .zip(&source_of)
        .map(|(t, &s)| {
            let zero = zero_area(t);
            dropped[s as usize] += zero as usize;
            !zero
        })
        .collect();
    if dropped.iter().all(|&n| n == 0) {
        return (
            positions,
            (normals, uvs, attributes),
            material_of,
            source_of,
        );
    }
    for ((path, what), &n) in sources.iter().zip(&dropped) {
        if n > 0 {
            log::warn!(
                "{}: {what}: left out {n} triangle{} of zero area",
                path.display(),
                if n == 1 { "" } else { "s" }
            );
        }
    }
    fn filter<T>(v: Vec<T>, keep: &[bool]) -> Vec<T> {
        v.into_iter()
            .zip(keep)
            .filter_map(|(x, &k)| k.then_some(x))
            .collect()
    }
    let normals = if normals.is_empty() {
        normals
    } else {
        filter(normals, &keep)
    };
    let uvs = if uvs.is_empty() {
        uvs
    } else {
        filter(uvs, &keep)
    };
    let attributes = attributes
        .into_iter()
        .map(|(n, v)| (n, filter(v, &keep)))
        .collect();
    (
        filter(positions, &keep),
        (normals, uvs, attributes),
        filter(material_of, &keep),
        filter(source_of, &keep),
    )
}

/// Distance along the ray (o, d) to triangle `t` (Möller-Trumbore, as the
/// trace kernel tests it), if the ray meets it ahead.
pub fn ray_triangle(o: Vec3, d: Vec3, t: &shaders::Triangle) -> Option<f32> {
    let (v0, e1, e2) = (Vec3::from(t.v0), Vec3::from(t.e1), Vec3::from(t.e2));
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-12 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - v0;
    let u = s.dot(p) * inv;
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    let tt = e2.dot(q) * inv;
    (u >= 0.0 && v >= 0.0 && u + v <= 1.0 && tt > 0.0).then_some(tt)
}

/// A light's radiance as a mesh attribute: its corners per triangle, in the
/// triangles' order, and its scale.
type EmittedAttribute<'a> = Option<(&'a [[Vec3; 3]], f32)>;

/// Per material whose radiance is a mesh attribute, that attribute: such a
/// light's triangles are weighed by their own mean radiance, the mean of
/// their corners', as the kernels interpolate them.
fn emitted_means<'a>(
    materials: &[Material],
    textures: &[texture::Texture],
    attributes: &'a Attributes,
) -> Vec<EmittedAttribute<'a>> {
    materials
        .iter()
        .map(|m| {
            let t = m.textures[shaders::TEXTURE_SLOT_COLOR as usize]?;
            match &textures[t as usize].pattern {
                texture::Pattern::Attribute { name, scale, .. } if m.emission != Vec3::ZERO => {
                    let (_, corners) = attributes.iter().find(|(n, _)| n == name)?;
                    Some((corners.as_slice(), *scale))
                }
                _ => None,
            }
        })
        .collect()
}

/// For the emitting triangles (by index in `order`, the device's order),
/// the part of an emitter each is: triangles of one material that share a
/// corner are one part (a quad's two halves, a sphere's whole surface).
fn emitter_parts(
    positions: &[[Vec3; 3]],
    material_of: &[u32],
    materials: &[Material],
    order: &[u32],
) -> std::collections::HashMap<u32, u32> {
    use std::collections::hash_map::Entry;
    let emitting: Vec<u32> = (0..order.len() as u32)
        .filter(|&k| {
            let m = material_of[order[k as usize] as usize];
            materials[m as usize].emission.max_element() > 0.0
        })
        .collect();
    fn root(parent: &mut [u32], mut i: u32) -> u32 {
        while parent[i as usize] != i {
            let up = parent[parent[i as usize] as usize];
            parent[i as usize] = up;
            i = up;
        }
        i
    }
    let mut parent: Vec<u32> = (0..emitting.len() as u32).collect();
    let mut corners: std::collections::HashMap<(u32, [u32; 3]), u32> = Default::default();
    for (e, &k) in emitting.iter().enumerate() {
        let i = order[k as usize] as usize;
        for corner in positions[i] {
            // + 0.0 makes -0.0 the same corner as 0.0.
            let key = (material_of[i], (corner + 0.0).to_array().map(f32::to_bits));
            match corners.entry(key) {
                Entry::Occupied(first) => {
                    let (a, b) = (root(&mut parent, *first.get()), root(&mut parent, e as u32));
                    parent[a.max(b) as usize] = a.min(b);
                }
                Entry::Vacant(slot) => {
                    slot.insert(e as u32);
                }
            }
        }
    }
    (0..emitting.len())
        .map(|e| (emitting[e], root(&mut parent, e as u32)))
        .collect()
}

/// A triangle's centre.
fn triangle_centre(t: &shaders::Triangle) -> Vec3 {
    Vec3::from(t.v0) + (Vec3::from(t.e1) + Vec3::from(t.e2)) / 3.0
}

/// A delta light's kind (`shaders::DELTA_*`), from its position's w.
fn delta_kind(d: &shaders::DeltaLight) -> u32 {
    d.position[3] as u32 & 3
}

/// Where a delta light is; none for a directional light.
fn delta_place(d: &shaders::DeltaLight) -> Option<Vec3> {
    (delta_kind(d) != shaders::DELTA_DIRECTIONAL).then(|| Vec3::from_slice(&d.position[..3]))
}

/// Points split into at most `groups` groups of nearby ones: in turn the
/// group spread widest is split at its median along its longest axis. For
/// each point, its group.
fn nearby(points: &[Vec3], groups: usize) -> Vec<u32> {
    let mut clusters: Vec<Vec<usize>> = vec![(0..points.len()).collect()];
    while clusters.len() < groups {
        let spread = |c: &Vec<usize>| {
            let (lo, hi) = c
                .iter()
                .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), &i| {
                    (lo.min(points[i]), hi.max(points[i]))
                });
            hi - lo
        };
        let widest = clusters
            .iter()
            .enumerate()
            .map(|(k, c)| {
                let e = spread(c);
                let axis = if e.x >= e.y && e.x >= e.z {
                    0
                } else if e.y >= e.z {
                    1
                } else {
                    2
                };
                (k, axis, e[axis])
            })
            .filter(|&(_, _, width)| width > 0.0)
            .max_by(|a, b| a.2.total_cmp(&b.2));
        let Some((k, axis, _)) = widest else {
            break;
        };
        let mut c = clusters.swap_remove(k);
        c.sort_by(|&a, &b| points[a][axis].total_cmp(&points[b][axis]));
        let far = c.split_off(c.len() / 2);
        clusters.push(c);
        clusters.push(far);
    }
    let mut of = vec![0; points.len()];
    for (k, c) in clusters.iter().enumerate() {
        for &i in c {
            of[i] = k as u32;
        }
    }
    of
}

/// Emissive triangles, chosen for next-event estimation in proportion to
/// area × luminance(Le) (a mesh attribute's: the triangle's own mean, at
/// least a thousandth of its light's, so that every triangle of a light
/// stays one), and the delta lights by their weights; also stores each
/// triangle's P(choose)/area on it. The delta lights' entries follow the
/// triangles' in the one list NEE draws from. Each entry names the light
/// it is part of (`Light::group`, see `shaders::LightGroup`): an emitter's
/// part (`parts`), each delta light, the sky; where those are more than the
/// guides pick among, nearby parts and delta lights together (`nearby`).
fn build_lights(
    triangles: &mut [shaders::Triangle],
    parts: &std::collections::HashMap<u32, u32>,
    materials: &[Material],
    attributes: &[EmittedAttribute<'_>],
    delta: &[(shaders::DeltaLight, f32)],
    sky: &[f32],
) -> (Vec<shaders::Light>, Vec<shaders::Light>) {
    let weights: Vec<(u32, f32)> = triangles
        .iter()
        .enumerate()
        .filter_map(|(i, t)| {
            let mean = luminance(materials[t.material as usize].emission);
            let le = match attributes[t.material as usize] {
                Some((corners, scale)) => {
                    let [a, b, c] = corners[i];
                    (scale * luminance((a + b + c) / 3.0)).max(1e-3 * mean)
                }
                None => mean,
            };
            let w = t.area * le;
            (w > 0.0).then_some((i as u32, w))
        })
        .chain(
            delta
                .iter()
                .enumerate()
                .map(|(i, &(_, w))| (shaders::LIGHT_DELTA | i as u32, w)),
        )
        .chain(
            sky.iter()
                .enumerate()
                .map(|(k, &w)| (shaders::LIGHT_ENVIRONMENT | k as u32, w)),
        )
        .collect();
    let total: f64 = weights.iter().map(|&(_, w)| w as f64).sum();
    let mut acc = 0.0f64;
    let mut lights = Vec::with_capacity(weights.len());
    for &(i, w) in &weights {
        acc += w as f64;
        let pdf = (w as f64 / total) as f32;
        if i & (shaders::LIGHT_DELTA | shaders::LIGHT_ENVIRONMENT) == 0 {
            triangles[i as usize].light_pdf = pdf / triangles[i as usize].area;
        }
        lights.push(shaders::Light {
            triangle: i,
            cdf: (acc / total) as f32,
            pdf,
            group: 0,
        });
    }
    // Lights numbered as NEE's list first meets them; `key` None: a light
    // of its own.
    let number = |lights: &mut [shaders::Light], key: &dyn Fn(u32) -> Option<u32>| {
        let mut seen = std::collections::HashMap::new();
        let mut count = 0;
        for l in lights.iter_mut() {
            l.group = match key(l.triangle) {
                Some(k) => *seen.entry(k).or_insert(count),
                None => count,
            };
            count = count.max(l.group + 1);
        }
        count as usize
    };
    let emits = |t: u32| t & (shaders::LIGHT_DELTA | shaders::LIGHT_ENVIRONMENT) == 0;
    let part = |t: u32| parts.get(&t).copied().unwrap_or(u32::MAX);
    let max = shaders::MAX_GUIDED_LIGHTS as usize;
    if number(&mut lights, &|t| emits(t).then(|| part(t))) > max {
        // More than the guides choose among: nearby ones together (the
        // emitters' parts, and the delta lights that have a place).
        let mut places: Vec<(Vec3, f32)> = Vec::new();
        let mut item: std::collections::HashMap<u32, u32> = Default::default();
        for l in &lights {
            // Its item, and its place (an emitter's, area-weighted).
            let (key, at, weight) = if emits(l.triangle) {
                let t = &triangles[l.triangle as usize];
                (part(l.triangle), triangle_centre(t) * t.area, t.area)
            } else if l.triangle & shaders::LIGHT_DELTA != 0 {
                let d = &delta[(l.triangle & !shaders::LIGHT_DELTA) as usize].0;
                let Some(place) = delta_place(d) else {
                    continue;
                };
                (l.triangle, place, 1.0)
            } else {
                continue;
            };
            let i = *item.entry(key).or_insert_with(|| {
                places.push((Vec3::ZERO, 0.0));
                places.len() as u32 - 1
            });
            places[i as usize].0 += at;
            places[i as usize].1 += weight;
        }
        let on_their_own = lights.len()
            - lights
                .iter()
                .filter(|l| emits(l.triangle) || item.contains_key(&l.triangle))
                .count();
        if max > on_their_own + 1 {
            let centres: Vec<Vec3> = places
                .iter()
                .map(|&(at, w)| at / w.max(f32::MIN_POSITIVE))
                .collect();
            let near = nearby(&centres, max - on_their_own);
            let key = |t: u32| {
                let k = if emits(t) { part(t) } else { t };
                item.get(&k).map(|&i| near[i as usize])
            };
            number(&mut lights, &key);
        }
    }
    if let Some(last) = lights.last_mut() {
        last.cdf = 1.0; // rounding must not leave a gap at the top
    }
    let first_delta = lights.len() - delta.len() - sky.len();
    let delta_entries = lights.split_off(first_delta);
    (lights, delta_entries)
}

/// Triangles with their materials, and where each came from (an index
/// into `sources`), for error messages.
#[derive(Default)]
struct Geometry {
    positions: Vec<[Vec3; 3]>,
    /// Shading normals at each triangle's corners; empty while every
    /// triangle is shaded flat (then faces' normals fill in for them).
    normals: Vec<[Vec3; 3]>,
    /// Texture coordinates at each triangle's corners; empty while no shape
    /// has them (then a triangle's barycentric coordinates, as in
    /// Mitsuba, fill in for them).
    uvs: Vec<[Vec2; 3]>,
    /// The mesh attributes materials read, by name, at each triangle's
    /// corners (zeros where its shape's material reads none).
    attributes: Vec<(String, Vec<[Vec3; 3]>)>,
    material_of: Vec<u32>,
    sources: Vec<(PathBuf, String)>,
    source_of: Vec<u32>,
}

/// Mesh attributes by name, at each triangle's corners.
type Attributes = Vec<(String, Vec<[Vec3; 3]>)>;

/// A triangle's texture coordinates where its shape has none: Mitsuba's,
/// the barycentric coordinates of its corners.
const BARYCENTRIC_UVS: [Vec2; 3] = [Vec2::ZERO, Vec2::X, Vec2::Y];

/// A triangle's own normal at each corner: flat shading.
fn face_normals(t: &[Vec3; 3]) -> [Vec3; 3] {
    [(t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero(); 3]
}

impl Geometry {
    /// Adds the triangles of one shape, with its shading normals if it has
    /// them; `source` names it in error messages.
    fn add(
        &mut self,
        source: (PathBuf, String),
        triangles: Vec<[Vec3; 3]>,
        normals: Option<Vec<[Vec3; 3]>>,
        uvs: Option<Vec<[Vec2; 3]>>,
        attributes: Vec<(String, Vec<[Vec3; 3]>)>,
        material: u32,
    ) {
        for (name, values) in attributes {
            match self.attributes.iter_mut().find(|(n, _)| *n == name) {
                Some((_, v)) => v.extend(values),
                None => {
                    let mut v = vec![[Vec3::ZERO; 3]; self.positions.len()];
                    v.extend(values);
                    self.attributes.push((name, v));
                }
            }
        }
        let count = self.positions.len() + triangles.len();
        for (_, v) in &mut self.attributes {
            v.resize(count, [Vec3::ZERO; 3]);
        }
        match uvs {
            Some(uv) => {
                if self.uvs.is_empty() {
                    self.uvs = vec![BARYCENTRIC_UVS; self.positions.len()];
                }
                self.uvs.extend(uv);
            }
            None if !self.uvs.is_empty() => self
                .uvs
                .extend(std::iter::repeat_n(BARYCENTRIC_UVS, triangles.len())),
            None => {}
        }
        if normals.is_some() && self.normals.is_empty() {
            self.normals = self.positions.iter().map(face_normals).collect();
        }
        match normals {
            // A scene's one large mesh moves in without a copy.
            Some(n) if self.normals.is_empty() => self.normals = n,
            Some(n) => self.normals.extend(n),
            None if !self.normals.is_empty() => {
                self.normals.extend(triangles.iter().map(face_normals))
            }
            None => {}
        }
        self.sources.push(source);
        let src = self.sources.len() as u32 - 1;
        self.material_of
            .extend(std::iter::repeat_n(material, triangles.len()));
        self.source_of
            .extend(std::iter::repeat_n(src, triangles.len()));
        if self.positions.is_empty() {
            self.positions = triangles;
        } else {
            self.positions.extend(triangles);
        }
    }
}

/// A unit normal in 32 bits: the octahedral map's point as two 16-bit
/// signed fractions, x in the low half (GLSL's unpackSnorm2x16).
pub fn pack_normal(n: Vec3) -> u32 {
    let n = n / (n.x.abs() + n.y.abs() + n.z.abs()).max(1e-30);
    let (x, y) = if n.z >= 0.0 {
        (n.x, n.y)
    } else {
        (
            (1.0 - n.y.abs()) * n.x.signum(),
            (1.0 - n.x.abs()) * n.y.signum(),
        )
    };
    let q = |v: f32| ((v.clamp(-1.0, 1.0) * 32767.0).round() as i16) as u16 as u32;
    q(x) | (q(y) << 16)
}

/// The unit normal [`pack_normal`] packed (the CPU twin of the trace
/// kernel's `unpack_normal`).
pub fn unpack_normal(p: u32) -> Vec3 {
    let f = |v: u32| ((v as u16 as i16) as f32 / 32767.0).clamp(-1.0, 1.0);
    let (x, y) = (f(p & 0xffff), f(p >> 16));
    let z = 1.0 - x.abs() - y.abs();
    let t = (-z).max(0.0);
    let x = x + if x >= 0.0 { -t } else { t };
    let y = y + if y >= 0.0 { -t } else { t };
    Vec3::new(x, y, z).normalize()
}

/// How a scene's files are read, and how many triangles it may have.
pub struct Loader<'a> {
    /// A file's bytes.
    pub read: &'a dyn Fn(&Path) -> std::io::Result<Vec<u8>>,
    pub max_triangles: usize,
    /// An XML scene's `-D name=value` parameters.
    pub defines: &'a [(String, String)],
}

/// The most bounces a render of an XML scene whose integrator says
/// `max_depth -1` (unlimited) takes: beyond it Russian roulette has ended
/// all but a vanishing share of paths.
pub const MITSUBA_UNLIMITED_DEPTH: u32 = 1024;

/// Texture slots a material has (`TEXTURE_SLOT_*`).
pub const TEXTURE_SLOTS: usize = shaders::TEXTURE_SLOT_TRANSMISSION as usize + 1;

/// Most triangles a scene may have: about 3 GiB of host memory while it
/// loads (BVH nodes are 128 bytes a triangle); devices allow fewer, and
/// the renderer says so.
pub const MAX_TRIANGLES: usize = 1 << 24;

impl Loader<'_> {
    /// A text file's contents; not UTF-8 is an error.
    pub fn text(&self, path: &Path) -> std::io::Result<String> {
        String::from_utf8((self.read)(path)?).map_err(|_| {
            std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                "the file is not UTF-8 text",
            )
        })
    }
}

impl Default for Loader<'_> {
    /// The file system, and [`MAX_TRIANGLES`].
    fn default() -> Self {
        Self {
            read: &|path| std::fs::read(path),
            max_triangles: MAX_TRIANGLES,
            defines: &[],
        }
    }
}

/// The surface an MTL material describes (docs/scenes.md): glass for
/// `d 0` with `Ni` > 1, a conductor for `Pm 1`, else diffuse. Keys the
/// chosen surface does not use draw one warning per material; values out of
/// range are errors naming the file and the material.
fn surface_of(obj_path: &Path, m: &obj::MtlMaterial) -> Result<Surface, SceneError> {
    let fail = |message: String| SceneError::Invalid {
        path: obj_path.to_path_buf(),
        message: format!("material '{}': {message}", m.name),
    };
    let unit = |key: &str, c: Option<[f32; 3]>, default: f32| -> Result<Vec3, SceneError> {
        let c = check_color(
            obj_path,
            &format!("{key} of material '{}'", m.name),
            c.unwrap_or([default; 3]),
        )?;
        if c.max_element() > 1.0 {
            return Err(fail(format!("{key} exceeds 1 (it would create energy)")));
        }
        Ok(c)
    };
    let in_unit = |key: &str, v: Option<f32>| match v {
        Some(x) if !(0.0..=1.0).contains(&x) => Err(fail(format!("{key} {x} is outside [0, 1]"))),
        _ => Ok(()),
    };
    in_unit("Pm", m.metallic)?;
    in_unit("Pr", m.roughness)?;
    in_unit("d", m.dissolve)?;
    if let Some(ior) = m.ior {
        if !ior.is_finite() || ior <= 0.0 {
            return Err(fail(format!("Ni {ior} must be a positive number")));
        }
    }
    let metallic = m.metallic.unwrap_or(0.0);
    if metallic > 0.0 && metallic < 1.0 {
        return Err(fail(format!(
            "Pm {metallic}: a material is a conductor (Pm 1) or not (Pm 0); blends are not supported"
        )));
    }
    let glass = m.dissolve == Some(0.0);
    let mut ignored: Vec<&str> = Vec::new();
    let surface = if glass {
        let ior = m.ior.unwrap_or(1.0);
        if ior <= 1.0 {
            return Err(fail(format!("d 0 (glass) needs Ni above 1, not {ior}")));
        }
        if metallic == 1.0 {
            return Err(fail(
                "Pm 1 (a conductor) and d 0 (glass) contradict each other".into(),
            ));
        }
        ignored.extend(m.diffuse.map(|_| "Kd"));
        ignored.extend(m.diffuse_map.as_ref().map(|_| "map_Kd"));
        ignored.extend(m.specular.map(|_| "Ks"));
        ignored.extend(m.roughness.map(|_| "Pr"));
        Surface::Dielectric {
            ior,
            transmittance: unit("Tf", m.transmission, 1.0)?,
            reflectance: Vec3::ONE,
        }
    } else if metallic == 1.0 {
        let roughness = m.roughness.unwrap_or(0.0);
        ignored.extend(m.diffuse.map(|_| "Kd"));
        ignored.extend(m.diffuse_map.as_ref().map(|_| "map_Kd"));
        Surface::conductor(unit("Ks", m.specular, 1.0)?, roughness * roughness)
    } else {
        ignored.extend(m.specular.map(|_| "Ks"));
        ignored.extend(m.roughness.map(|_| "Pr"));
        ignored.extend(m.transmission.map(|_| "Tf"));
        if m.dissolve.is_some_and(|d| d < 1.0) {
            ignored.push("d");
        }
        Surface::Diffuse {
            albedo: unit("Kd", m.diffuse, 0.8)?,
        }
    };
    ignored.extend(m.phong_keys.iter().copied());
    ignored.dedup();
    if !ignored.is_empty() {
        log::warn!(
            "{}: material '{}' ({}): ignoring {} (see docs/scenes.md)",
            obj_path.display(),
            m.name,
            surface.name(),
            ignored.join(", ")
        );
    }
    Ok(surface)
}

fn load_obj(
    obj_path: &Path,
    loader: &Loader<'_>,
    (materials, textures): (&mut Vec<Material>, &mut Vec<texture::Texture>),
    out: &mut Geometry,
) -> Result<(), SceneError> {
    let text = loader.text(obj_path).map_err(|source| SceneError::Read {
        path: obj_path.to_path_buf(),
        source: match source.kind() {
            std::io::ErrorKind::NotFound => {
                std::io::Error::new(std::io::ErrorKind::NotFound, "mesh file not found")
            }
            _ => source,
        },
    })?;
    let dir = obj_path.parent().unwrap_or(Path::new("."));
    let budget = loader.max_triangles.saturating_sub(out.positions.len());
    let parsed = obj::parse_obj(&text, budget, &mut |name| {
        loader
            .text(&dir.join(name))
            .map_err(|e| format!("cannot read the MTL file '{name}' that mtllib names: {e}"))
    })
    .map_err(|e| match &e.mtl {
        Some(name) => SceneError::Mtl {
            path: dir.join(name),
            message: format!("malformed MTL: line {}: {}", e.line, e.message),
        },
        None if e.message.contains("the MTL file") => SceneError::Mtl {
            path: obj_path.to_path_buf(),
            message: e.to_string(),
        },
        None => SceneError::Obj {
            path: obj_path.to_path_buf(),
            message: e.to_string(),
        },
    })?;
    for name in &parsed.unknown_materials {
        log::warn!(
            "{}: usemtl '{name}' names no material of its MTL files; its faces are grey",
            obj_path.display()
        );
    }
    let base = materials.len() as u32;
    for m in &parsed.materials {
        let mut material = Material {
            name: m.name.clone(),
            surface: surface_of(obj_path, m)?,
            emission: check_color(
                obj_path,
                &format!("Ke of material '{}'", m.name),
                m.emission.unwrap_or([0.0; 3]),
            )?,
            one_sided: false,
            textures: [None; TEXTURE_SLOTS],
            normal_map: None,
            choice: None,
            smooth_light: false,
        };
        let emits = material.emission.max_element() > 0.0;
        if emits && m.diffuse_map.is_some() {
            // Its colour slot would hold its radiance's texture.
            log::warn!(
                "{}: material '{}' emits: ignoring map_Kd (an emitter ends paths, as a black surface would)",
                obj_path.display(),
                m.name
            );
        }
        if let (Some(file), Surface::Diffuse { .. }, false) =
            (&m.diffuse_map, material.surface, emits)
        {
            let t = diffuse_map(dir, file, loader).map_err(|message| SceneError::Mtl {
                path: obj_path.to_path_buf(),
                message: format!("material '{}': {message}", m.name),
            })?;
            material.surface = material
                .surface
                .with_means(Some(t.mean()), None, None, None);
            material.textures[shaders::TEXTURE_SLOT_COLOR as usize] = Some(textures.len() as u32);
            textures.push(t);
        }
        // An emitter of a TOML scene ends paths (docs/scenes.md), as a black
        // BSDF would; Mitsuba's scatter them as their BSDF says.
        if emits {
            material.surface = Surface::Diffuse { albedo: Vec3::ZERO };
        }
        materials.push(material);
    }
    // Faces without a material get a neutral grey.
    let default_material = materials.len() as u32;
    materials.push(Material::diffuse("default", Vec3::splat(0.8)));
    // Texture coordinates: v turned over, as OBJ's v runs up the image.
    let with_uvs = !parsed.uvs.is_empty() || !out.uvs.is_empty();
    if with_uvs && out.uvs.is_empty() {
        out.uvs = vec![BARYCENTRIC_UVS; out.positions.len()];
    }
    for group in parsed.groups {
        if with_uvs {
            out.uvs
                .extend(obj::corner_uvs(&parsed.uvs, &group.uv_corners, true));
        }
        out.sources
            .push((obj_path.to_path_buf(), format!("object '{}'", group.name)));
        let src = out.sources.len() as u32 - 1;
        for (t, m) in group.triangles.into_iter().zip(group.material) {
            out.positions.push(t);
            out.material_of
                .push(m.map_or(default_material, |id| base + id as u32));
            out.source_of.push(src);
        }
    }
    Ok(())
}

/// An MTL's `map_Kd` image (file names relative to the OBJ's folder), as
/// a bilinear, repeating sRGB texture, as other renderers read it.
fn diffuse_map(dir: &Path, file: &str, loader: &Loader<'_>) -> Result<texture::Texture, String> {
    let path = dir.join(file);
    let bytes = (loader.read)(&path).map_err(|e| format!("cannot read map_Kd '{file}': {e}"))?;
    let pattern = texture::Texture::bitmap_from_bytes(
        &path,
        &bytes,
        texture::Filter::Bilinear,
        texture::Wrap::Repeat,
        false,
    )
    .map_err(|e| format!("cannot read map_Kd '{file}': {e}"))?;
    Ok(texture::Texture {
        name: file.to_string(),
        pattern,
        to_uv: glam::Mat3::IDENTITY,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Loads a one-triangle scene lit by its environment whose material
    /// is `mtl`.
    fn load(mtl: &str) -> Result<Scene, SceneError> {
        let read = |p: &Path| -> std::io::Result<Vec<u8>> {
            Ok(match p.file_name().unwrap().to_str().unwrap() {
                "s.toml" => "mesh = \"s.obj\"\nenvironment = [1, 1, 1]\n[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\nup = [0, 1, 0]\nfov_y = 40\n".into(),
                "s.obj" => "mtllib s.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl m\nf 1 2 3\n".into(),
                _ => format!("newmtl m\n{mtl}").into_bytes(),
            })
        };
        Scene::load_with(
            Path::new("s.toml"),
            &Loader {
                read: &read,
                max_triangles: 10,
                defines: &[],
            },
        )
    }

    /// A TOML scene's emitter emits on its faces' side, whatever its
    /// normals say (Mitsuba's scenes: Material::smooth_light).
    #[test]
    fn a_toml_scenes_lights_take_their_side_from_their_faces() {
        let read = |p: &Path| -> std::io::Result<Vec<u8>> {
            Ok(match p.file_name().unwrap().to_str().unwrap() {
                "s.toml" => "mesh = \"s.obj\"\n[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\nup = [0, 1, 0]\nfov_y = 40\n".into(),
                "s.obj" => "mtllib s.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 -1\nusemtl m\nf 1//1 2//1 3//1\n".into(),
                _ => "newmtl m\nKe 1 1 1\n".into(),
            })
        };
        let loader = Loader {
            read: &read,
            max_triangles: 10,
            defines: &[],
        };
        let scene = Scene::load_with(Path::new("s.toml"), &loader).unwrap();
        assert!(scene.materials.iter().all(|m| !m.smooth_light));
    }

    /// map_Kd: the diffuse reflectance from an image, read through the
    /// OBJ's vt with v turned over; errors name the MTL and the material.
    #[test]
    fn map_kd_textures_a_diffuse_material() {
        let png = std::fs::read(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/textures/tiles.png"),
        )
        .unwrap();
        let load = |mtl: &'static str| {
            let png = png.clone();
            let read = move |p: &Path| -> std::io::Result<Vec<u8>> {
                Ok(match p.file_name().unwrap().to_str().unwrap() {
                    "s.toml" => "mesh = \"s.obj\"\nenvironment = [1, 1, 1]\n[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\nup = [0, 1, 0]\nfov_y = 40\n".into(),
                    "s.obj" => "mtllib s.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0.25\nvt 0 1\nusemtl m\nf 1/1 2/2 3/3\n".into(),
                    "t.png" => png.clone(),
                    "s.mtl" => format!("newmtl m\n{mtl}").into_bytes(),
                    _ => return Err(std::io::ErrorKind::NotFound.into()),
                })
            };
            Scene::load_with(
                Path::new("s.toml"),
                &Loader {
                    read: &read,
                    max_triangles: 10,
                    defines: &[],
                },
            )
        };
        let scene = load("Kd 0.5\nmap_Kd t.png\n").unwrap();
        let m = &scene.materials[0];
        let mut slots = [None; TEXTURE_SLOTS];
        slots[0] = Some(0);
        assert_eq!(m.textures, slots);
        let mean = scene.textures[0].mean();
        assert_eq!(m.surface, Surface::Diffuse { albedo: mean });
        assert_eq!(
            scene.uvs[0],
            [
                Vec2::new(0.0, 1.0),
                Vec2::new(1.0, 0.75),
                Vec2::new(0.0, 0.0)
            ]
        );
        assert_eq!(
            scene.material_features() & shaders::FEATURE_TEXTURES,
            shaders::FEATURE_TEXTURES
        );
        let err = |mtl| load(mtl).err().unwrap().to_string();
        assert_eq!(
            err("map_Kd gone.png\n"),
            "s.obj: material 'm': cannot read map_Kd 'gone.png': entity not found"
        );
        assert!(
            err("map_Kd -s 2 2 t.png\n").contains("line 2: map_Kd options (-s) are not supported")
        );
        // Not a diffuse material: ignored with a warning, as Kd is.
        let metal = load("Pm 1\nmap_Kd t.png\n").unwrap();
        assert_eq!(metal.materials[0].textures, [None; TEXTURE_SLOTS]);
        // An emitter's: ignored, or the device would read the image as its
        // radiance.
        let lamp = load("Kd 0.5\nKe 4 4 4\nmap_Kd t.png\n").unwrap();
        assert_eq!(lamp.materials[0].textures, [None; TEXTURE_SLOTS]);
        assert_eq!(lamp.materials[0].emission, Vec3::splat(4.0));
    }

    #[test]
    fn mtl_keys_make_the_surfaces_of_spec() {
        let surface = |mtl: &str| load(mtl).unwrap().materials[0].surface;
        assert_eq!(
            surface("Pm 1\nKs 0.9 0.8 0.7\nPr 0.5\nKd 0.1 0.1 0.1\n"),
            Surface::conductor(Vec3::new(0.9, 0.8, 0.7), 0.25)
        );
        assert_eq!(surface("Pm 1\n"), Surface::conductor(Vec3::ONE, 0.0));
        assert_eq!(
            surface("Ni 1.5\nd 0\nTf 1 0.9 0.8\n"),
            Surface::Dielectric {
                ior: 1.5,
                transmittance: Vec3::new(1.0, 0.9, 0.8),
                reflectance: Vec3::ONE,
            }
        );
        assert_eq!(
            surface("Ni 1.33\nTr 1\n"),
            Surface::Dielectric {
                ior: 1.33,
                transmittance: Vec3::ONE,
                reflectance: Vec3::ONE,
            }
        );
        // An exporter's leftovers on a diffuse material: warned of, ignored.
        assert_eq!(
            surface("Ns 250\nKa 1 1 1\nKd 0.5 0.5 0.5\nKs 0.5 0.5 0.5\nNi 1.45\nd 1\nillum 2\n"),
            Surface::Diffuse {
                albedo: Vec3::splat(0.5)
            }
        );
    }

    #[test]
    fn out_of_range_material_values_name_file_and_material() {
        for (mtl, want) in [
            ("Pm 1\nPr 1.5\n", "material 'm': Pr 1.5 is outside [0, 1]"),
            ("Pm 1\nPr -0.1\n", "Pr -0.1 is outside [0, 1]"),
            ("Ni 1\nd 0\n", "d 0 (glass) needs Ni above 1, not 1"),
            ("d 0\n", "needs Ni above 1"),
            ("Ni 0.8\nd 0\n", "needs Ni above 1, not 0.8"),
            ("Ni -2\n", "Ni -2 must be a positive number"),
            ("Pm 0.5\n", "blends are not supported"),
            ("Pm 2\n", "Pm 2 is outside [0, 1]"),
            ("Pm 1\nKs 1.2 1 1\n", "Ks exceeds 1"),
            ("Ni 1.5\nd 0\nTf -1 1 1\n", "Tf of material 'm'"),
            ("Pm 1\nNi 1.5\nd 0\n", "contradict"),
            ("d 1.5\n", "d 1.5 is outside [0, 1]"),
        ] {
            let Err(e) = load(mtl) else {
                panic!("{mtl:?} loaded");
            };
            let e = e.to_string();
            assert!(e.contains(want) && e.contains("s.obj"), "{mtl:?}: {e}");
        }
    }
}
