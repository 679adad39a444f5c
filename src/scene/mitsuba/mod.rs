//! Mitsuba 3's XML scene format: the subset that published scenes use,
//! read into qtrace's triangles, materials, camera and render defaults.
//! Every plugin and parameter means what Mitsuba 3's documentation says;
//! anything qtrace cannot render as Mitsuba would is an error naming the
//! file and line, never a silently different image.

mod cie;
mod shapes;
mod sunsky;
mod textures;
mod xml;

use super::file::RenderDefaults;
use super::texture::{Pattern, Texture};
use super::{obj, ply, serialized};
use super::{
    Camera, Choice, ChoiceKind, FovAxis, Geometry, Loader, Material, NormalMap, Parts, PixelFilter,
    SceneError, Weight,
};
use crate::bsdf::{ComplexIor, Distribution, Surface};
use glam::{Mat4, Vec2, Vec3};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use xml::{plugin_name, Element, Props};

/// Reads the scene of `path`; `defines` are the command line's `-D name=value`.
pub(super) fn read(
    path: &Path,
    loader: &Loader<'_>,
    defines: &[(String, String)],
) -> Result<Parts, SceneError> {
    let elements = xml::read_scene(path, loader, defines)?;
    let mut b = Builder {
        loader,
        bsdfs: HashMap::new(),
        materials: Vec::new(),
        geometry: Geometry::default(),
        camera: None,
        defaults: RenderDefaults::default(),
        filter: PixelFilter::Gaussian { stddev: 0.5 },
        max_depth: None,
        delta_lights: Vec::new(),
        textures: textures::Textures::default(),
        groups: HashMap::new(),
        instance_to_world: Mat4::IDENTITY,
        environment: None,
        envmap: None,
        crop: None,
    };
    // Sensors first: a sphere is tessellated as finely as the camera sees it.
    for el in elements.iter().filter(|e| e.tag == "sensor") {
        b.top_level(el)?;
    }
    for el in elements.iter().filter(|e| e.tag != "sensor") {
        b.top_level(el)?;
    }
    let Some(camera) = b.camera else {
        return Err(SceneError::Invalid {
            path: path.to_path_buf(),
            message: "the scene has no <sensor>".into(),
        });
    };
    b.defaults.max_depth = b.max_depth;
    // NEE picks a directional light by the power it sends into the scene:
    // its irradiance over a disk as wide as the scene.
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for p in b.geometry.positions.iter().flatten() {
        (lo, hi) = (lo.min(*p), hi.max(*p));
    }
    let radius = if lo.x <= hi.x {
        0.5 * (hi - lo).length()
    } else {
        1.0
    };
    let delta_lights = b
        .delta_lights
        .iter()
        .map(|&(light, power)| {
            let directional = light.position[3] as u32 == crate::shaders::DELTA_DIRECTIONAL;
            let w = if directional {
                power * std::f32::consts::PI * radius * radius
            } else {
                power
            };
            (light, w.max(1e-30))
        })
        .collect();
    let environment = match (b.envmap, b.environment) {
        (Some(env), _) => Some(env),
        (None, Some(radiance)) if radiance.max_element() > 0.0 => {
            Some(super::environment::Environment::constant(radiance))
        }
        _ => None,
    };
    Ok(Parts {
        delta_lights,
        camera,
        drop_degenerate: true,
        defaults: b.defaults,
        guide_tables: Vec::new(),
        environment,
        materials: b.materials,
        textures: b.textures.used,
        geometry: b.geometry,
        filter: b.filter,
    })
}

/// A shape's triangles in world space, and its shading normals and
/// texture coordinates at their corners if it has them.
type Mesh = (
    Vec<[Vec3; 3]>,
    Option<Vec<[Vec3; 3]>>,
    Option<Vec<[Vec2; 3]>>,
);

/// Whether some of a mesh's corner normals differ from their faces' (a
/// light on it emits where they face: `Material::smooth_light`).
fn normals_differ((triangles, normals, _): &Mesh) -> bool {
    normals.as_ref().is_some_and(|normals| {
        triangles.iter().zip(normals).any(|(t, n)| {
            let face = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
            n.iter().any(|c| c.normalize().dot(face) < 1.0 - 1e-5)
        })
    })
}

/// Mesh attributes by name, at a shape's triangles' corners.
type Attributes = Vec<(String, Vec<[Vec3; 3]>)>;

/// A BSDF as a shape uses it: the surface, and whether its back is black
/// (Mitsuba's BSDFs reflect on the front only unless wrapped in `twosided`).
#[derive(Clone, Debug)]
struct BsdfDesc {
    name: String,
    surface: Surface,
    one_sided: bool,
    /// `null`: the shape is invisible to paths.
    null: bool,
    /// Its textures' indices among the scene's (`Material::textures`).
    textures: [Option<u32>; crate::scene::TEXTURE_SLOTS],
    /// A `normalmap` around it.
    normal_map: Option<NormalMap>,
    /// A `mask`, `blendbsdf` or `twosided` with two BSDFs: the BSDFs it
    /// chooses between (its own surface is then unused).
    choice: Option<Box<ChoiceDesc>>,
}

/// What a choice (`BsdfDesc::choice`) chooses between, and how.
#[derive(Clone, Debug)]
struct ChoiceDesc {
    /// How; its materials' indices are given as they are added.
    kind: ChoiceKind,
    first: BsdfDesc,
    second: BsdfDesc,
}

impl BsdfDesc {
    /// As `twosided` leaves it: both sides scatter, and a normal map inside
    /// sees the sides by the unmapped normal.
    fn two_sided(&mut self) {
        self.one_sided = false;
        if let Some(map) = &mut self.normal_map {
            map.in_twosided = true;
        }
        if let Some(c) = &mut self.choice {
            c.first.two_sided();
            c.second.two_sided();
        }
    }

    /// Whether it lets light through (Mitsuba's transmission lobes, its
    /// `null` and a mask's clear part), which `twosided` refuses.
    fn transmits(&self) -> bool {
        self.null
            || matches!(
                self.surface,
                Surface::Dielectric { .. } | Surface::Thin { .. } | Surface::RoughDielectric { .. }
            )
            // Mitsuba's principledthin always has a transmission lobe.
            || matches!(self.surface, Surface::Principled { params, .. } if params.thin.is_some())
            || self.surface.rough_transmission()
            || self
                .choice
                .as_ref()
                .is_some_and(|c| c.first.transmits() || c.second.transmits())
    }

    /// Whether it has a smooth (delta) lobe: a mirror, smooth glass, a
    /// plastic's smooth coat, `null` or a mask's clear part.
    fn has_delta_lobe(&self) -> bool {
        self.null
            || match self.surface {
                Surface::Conductor { alpha, .. } => alpha == 0.0,
                Surface::Dielectric { .. } | Surface::Thin { .. } | Surface::Plastic { .. } => true,
                _ => false,
            }
            || self
                .choice
                .as_ref()
                .is_some_and(|c| c.first.has_delta_lobe() || c.second.has_delta_lobe())
    }

    /// How many choices deep it is.
    fn choice_depth(&self) -> u32 {
        self.choice.as_ref().map_or(0, |c| {
            1 + c.first.choice_depth().max(c.second.choice_depth())
        })
    }

    /// With a `normalmap` around it: the map turns each BSDF it stands for
    /// (a `null` one passes paths straight on either way).
    fn map_normals(&mut self, el: &Element, map: NormalMap) -> Result<(), SceneError> {
        if let Some(c) = &mut self.choice {
            c.first.map_normals(el, map)?;
            return c.second.map_normals(el, map);
        }
        if self.null {
            return Ok(());
        }
        if self.normal_map.is_some() {
            return Err(el.error("a normalmap or bumpmap inside another is not supported"));
        }
        if matches!(self.surface, Surface::Thin { .. }) {
            return Err(
                el.error("a normalmap or bumpmap around a thindielectric BSDF is not supported")
            );
        }
        self.normal_map = Some(map);
        Ok(())
    }
}

struct Builder<'a, 'l> {
    loader: &'a Loader<'l>,
    /// BSDFs with an id, and the material a shape without an emitter shares.
    bsdfs: HashMap<String, (BsdfDesc, Option<u32>)>,
    materials: Vec<Material>,
    geometry: Geometry,
    camera: Option<Camera>,
    defaults: RenderDefaults,
    filter: PixelFilter,
    max_depth: Option<u32>,
    /// Point, spot and directional lights, each with its power (a
    /// directional light's per unit area, scaled at the end).
    delta_lights: Vec<(crate::shaders::DeltaLight, f32)>,
    textures: textures::Textures,
    /// Shapegroups' shapes, by id, and the transform of the instance being
    /// placed (identity outside one).
    groups: HashMap<String, std::rc::Rc<Vec<Element>>>,
    instance_to_world: Mat4,
    /// A `constant` emitter's radiance.
    environment: Option<Vec3>,
    /// An `envmap` or a `sunsky`.
    envmap: Option<crate::scene::environment::Environment>,
    /// The film's crop window, if it has one.
    crop: Option<crate::scene::Crop>,
}

impl Builder<'_, '_> {
    fn top_level(&mut self, el: &Element) -> Result<(), SceneError> {
        match el.tag.as_str() {
            "integrator" => self.integrator(el),
            "sensor" => self.sensor(el),
            "bsdf" => {
                let id = el
                    .attr("id")
                    .ok_or_else(|| el.error("a top-level <bsdf> needs an id"))?;
                let desc = bsdf(el, &mut self.textures, self.loader)?;
                self.bsdfs.insert(id.to_string(), (desc, None));
                Ok(())
            }
            "shape" => self.shape(el),
            "emitter" => self.emitter(el),
            "texture" => self.textures.declare(el, self.loader),
            "medium" | "phase" => Err(el.error(format!(
                "{}: participating media are not supported",
                plugin_name(el)
            ))),
            other => Err(el.error(format!(
                "<{other}> is not supported at the top level of a scene (see docs/mitsuba.md)"
            ))),
        }
    }

    /// A light only NEE reaches: `point`, `spot` or `directional`.
    fn emitter(&mut self, el: &Element) -> Result<(), SceneError> {
        use crate::shaders::{DELTA_DIRECTIONAL, DELTA_POINT, DELTA_SPOT};
        let kind = el.plugin()?;
        let p = Props::new(el);
        // How often Mitsuba's NEE picks the emitter: noise, not the image.
        p.ignore("sampling_weight");
        let to_world = p.transform("to_world")?.unwrap_or(Mat4::IDENTITY);
        let axis = to_world
            .transform_vector3(Vec3::Z)
            .try_normalize()
            .ok_or_else(|| el.error("the emitter's to_world is singular"))?;
        let mut light = crate::shaders::DeltaLight::default();
        let luminance = crate::bsdf::luminance;
        let power = match kind {
            "point" | "spot" => {
                let intensity = p.radiance("intensity")?.unwrap_or(Vec3::ONE);
                let position = match p.point("position")? {
                    Some(at) => at,
                    None => to_world.transform_point3(Vec3::ZERO),
                };
                light.position = position.extend(if kind == "point" { DELTA_POINT } else { DELTA_SPOT } as f32).into();
                if kind == "point" {
                    light.intensity = intensity.extend(0.0).into();
                    4.0 * std::f32::consts::PI * luminance(intensity)
                } else {
                    let axes = rigid_axes(el, "spot", to_world, true)?;
                    let cutoff = p.float_or("cutoff_angle", 20.0)?;
                    let beam = p.float_or("beam_width", cutoff * 0.75)?;
                    if !(cutoff > 0.0 && cutoff <= 90.0 && beam > 0.0 && beam < cutoff) {
                        return Err(el.error(format!(
                            "spot cutoff_angle {cutoff} and beam_width {beam}: need 0 < beam_width < cutoff_angle <= 90"
                        )));
                    }
                    let (c, w) = (cutoff.to_radians(), beam.to_radians());
                    light.intensity = intensity.extend(c.cos()).into();
                    light.axis = axis.extend(w.cos()).into();
                    light.falloff = [c, 1.0 / (c - w), 0.0, 0.0];
                    let mean = self.spot_image(el, &p, axes, &mut light)?;
                    2.0 * std::f32::consts::PI * (1.0 - c.cos()) * luminance(intensity * mean)
                }
            }
            "projector" => self.projector(el, &p, to_world, &mut light)?,
            "directional" => {
                let irradiance = p.radiance("irradiance")?.unwrap_or(Vec3::ONE);
                let direction = match p.point("direction")? {
                    Some(d) => d
                        .try_normalize()
                        .ok_or_else(|| el.error("the directional light's direction is zero"))?,
                    None => axis,
                };
                light.position = direction.extend(DELTA_DIRECTIONAL as f32).into();
                light.intensity = irradiance.extend(0.0).into();
                luminance(irradiance)
            }
            "constant" | "envmap" | "sunsky" if self.environment.is_some() || self.envmap.is_some() => {
                return Err(el.error(
                    "a scene has one environment emitter (constant, envmap or sunsky), as in Mitsuba",
                ))
            }
            "sunsky" => {
                let rotation = sky_rotation(el, to_world)?;
                let settings = sunsky_settings(&p, rotation)?;
                p.finish()?;
                let sky = sunsky::Sunsky::new(&settings);
                if !sky.is_day() {
                    log::warn!(
                        "{}:{}: the sun is below the horizon: Mitsuba's sunsky is black then",
                        el.file.display(),
                        el.line
                    );
                    return Ok(());
                }
                let (w, h, texels) = sky.bake(sunsky::BAKED_WIDTH);
                let env = crate::scene::environment::Environment::new(
                    "sunsky".into(),
                    w,
                    h,
                    texels,
                    rotation * sunsky::envmap_frame(),
                );
                self.envmap = Some(env.with_model(sky.words()));
                return Ok(());
            }
            "constant" => {
                // Light from every direction, uniformly.
                let radiance = p.radiance("radiance")?.unwrap_or(Vec3::ONE);
                if radiance.min_element() < 0.0 {
                    return Err(el.error("the constant emitter's radiance is negative"));
                }
                p.finish()?;
                self.environment = Some(radiance);
                return Ok(());
            }
            "envmap" => {
                let file = p
                    .string("filename")?
                    .ok_or_else(|| el.error("envmap needs a filename"))?;
                let scale = p.float_or("scale", 1.0)?;
                if !(scale >= 0.0 && scale.is_finite()) {
                    return Err(el.error(format!("envmap scale {scale} must be finite and non-negative")));
                }
                // How Mitsuba weighs its sampling: noise, not the image.
                p.ignore("mis_compensation");
                let rotation = sky_rotation(el, to_world)?;
                use crate::scene::texture::{Filter, Wrap};
                let pattern = textures::read_image(
                    el,
                    self.loader,
                    ("envmap", file),
                    Filter::Bilinear,
                    Wrap::Repeat,
                    false,
                )?;
                let crate::scene::texture::Pattern::Bitmap { width, height, texels, .. } = pattern else {
                    unreachable!("a bitmap reads as one")
                };
                let mut texels = texels.to_linear().into_iter().map(|t| t * scale).collect::<Vec<_>>();
                // Mitsuba reads a map of one row as the same at every
                // height, and one of two rows as its first row at the pole
                // turning into its second at the horizon, the second alone
                // below: with the last row repeated, rows at the poles and
                // evenly between, as in larger maps, give that.
                let height = match height {
                    0 => return Err(el.error(format!("the envmap '{file}' is empty"))),
                    1 | 2 => {
                        texels.extend_from_within((height - 1) * width..);
                        height + 1
                    }
                    h => h,
                };
                if texels.iter().any(|t| !t.is_finite() || t.min_element() < 0.0) {
                    return Err(el.error(format!("the envmap '{file}' has negative or non-finite texels")));
                }
                p.finish()?;
                self.envmap = Some(crate::scene::environment::Environment::new(
                    file.to_string(),
                    width,
                    height,
                    texels,
                    rotation,
                ));
                return Ok(());
            }
            other => {
                return Err(el.error(format!(
                    "emitter '{other}' is not supported; qtrace has area (on shapes), point, spot, directional, projector, constant, envmap and sunsky"
                )))
            }
        };
        if light.intensity[..3].iter().any(|v| *v < 0.0) {
            return Err(el.error("the emitter's intensity is negative"));
        }
        p.finish()?;
        self.delta_lights.push((light, power));
        Ok(())
    }

    /// A spot light's `texture`, the image Mitsuba spreads over its cone
    /// (the light's unit axes `axes`): into `light` (the image's texture
    /// and x axis); the image's mean, or one where it casts none.
    fn spot_image(
        &mut self,
        el: &Element,
        p: &Props,
        axes: [Vec3; 3],
        light: &mut crate::shaders::DeltaLight,
    ) -> Result<Vec3, SceneError> {
        if p.color("texture").is_ok_and(|c| c.is_some()) {
            return Err(el.error(
                "a spot light's texture must be a bitmap or checkerboard (as in Mitsuba; a colour belongs in its intensity)",
            ));
        }
        let slot = crate::shaders::TEXTURE_SLOT_COLOR as usize;
        let Some((texture, mean)) = self.textures.given(el, p, "spot", self.loader)?[slot] else {
            return Ok(Vec3::ONE);
        };
        let [x, y, z] = axes;
        // The image's x axis as an angle in the frame the kernels build
        // around the spot's axis: the 16 floats a light has are taken.
        let (t, b) = crate::sampling::make_frame(z);
        light.position[3] += (4 * (texture + 1)) as f32;
        light.falloff[2] = x.dot(b).atan2(x.dot(t));
        light.falloff[3] = if z.cross(x).dot(y) < 0.0 { -1.0 } else { 1.0 };
        Ok(mean)
    }

    /// A `projector` (a pinhole casting its `irradiance` image, as Mitsuba's
    /// perspective camera maps directions to its film) into `light`; its
    /// power for NEE's choice.
    fn projector(
        &mut self,
        el: &Element,
        p: &Props,
        to_world: Mat4,
        light: &mut crate::shaders::DeltaLight,
    ) -> Result<f32, SceneError> {
        let [x, y, z] = rigid_axes(el, "projector", to_world, false)?;
        let slot = crate::shaders::TEXTURE_SLOT_COLOR as usize;
        let given = self.textures.given(el, p, "projector", self.loader)?[slot];
        let (colour, texture, mean, aspect) = match given {
            Some((t, mean)) => {
                // Mitsuba sizes the image plane by the texture's
                // resolution (a checkerboard's is 1 by 1).
                let aspect = match &self.textures.used[t as usize].pattern {
                    Pattern::Bitmap { width, height, .. } => *width as f32 / *height as f32,
                    _ => 1.0,
                };
                (Vec3::ONE, t + 1, mean, aspect)
            }
            None => {
                let c = p.radiance("irradiance")?.ok_or_else(|| {
                    el.error("projector needs an irradiance (a texture or a colour)")
                })?;
                (c, 0, Vec3::ONE, 1.0)
            }
        };
        let scale = p.float_or("scale", 1.0)?;
        if !(scale >= 0.0 && scale.is_finite()) || mean.min_element() < 0.0 {
            return Err(el.error("the projector's scale and irradiance must not be negative"));
        }
        // Mitsuba's parse_fov: the tangent of half the field of view across.
        let (fov, axis) = match (p.float("fov")?, p.string("focal_length")?) {
            (Some(_), Some(_)) => return Err(el.error("give fov or focal_length, not both")),
            (Some(f), None) => (f, p.string("fov_axis")?.unwrap_or("x")),
            (None, focal) => (focal_fov(el, focal)?, "diagonal"),
        };
        if !(fov > 0.0 && fov < 180.0) {
            return Err(el.error(format!("fov {fov} must lie in (0, 180) degrees")));
        }
        let t = (0.5 * fov.to_radians()).tan();
        let across = match axis {
            "x" => t,
            "y" => t * aspect,
            "diagonal" => t / (1.0 + 1.0 / (aspect * aspect)).sqrt(),
            "smaller" if aspect > 1.0 => t * aspect,
            "smaller" => t,
            "larger" if aspect > 1.0 => t,
            "larger" => t * aspect,
            other => {
                return Err(el.error(format!(
                    "fov_axis '{other}' is not x, y, diagonal, smaller or larger"
                )))
            }
        };
        let pi = std::f32::consts::PI;
        let kind = crate::shaders::DELTA_PROJECTOR + 4 * texture;
        light.position = to_world.w_axis.truncate().extend(kind as f32).into();
        light.intensity = (pi * scale * colour).extend(1.0 / across).into();
        light.axis = z.extend(aspect).into();
        let mirrored = z.cross(x).dot(y) < 0.0;
        light.falloff = x.extend(if mirrored { -1.0 } else { 1.0 }).into();
        // Its flux: the irradiance over its image plane at distance 1.
        Ok(crate::bsdf::luminance(pi * scale * colour * mean) * 4.0 * across * across / aspect)
    }

    fn integrator(&mut self, el: &Element) -> Result<(), SceneError> {
        let kind = el.plugin()?;
        // aov and moment render their nested integrator's image (and more
        // channels, which qtrace does not write).
        if matches!(kind, "aov" | "moment") {
            let p = Props::new(el);
            p.ignore("aovs");
            let nested = p.nested("integrator");
            p.finish()?;
            if let Some(inner) = nested.first() {
                return self.integrator(inner);
            }
        }
        // Without media (qtrace has none) volpath and volpathmis converge to
        // path's image, as Mitsuba's differentiable prb, prb_basic and
        // prb_projective do; direct (and direct_projective) is path with one
        // bounce (their sample counts change noise only).
        let path_like = matches!(
            kind,
            "path" | "volpath" | "volpathmis" | "prb" | "prb_basic" | "prb_projective"
        );
        let direct = matches!(kind, "direct" | "direct_projective");
        if !(path_like || direct) {
            log::warn!(
                "{}:{}: integrator '{kind}': qtrace renders the scene with its own method (--method) instead",
                el.file.display(),
                el.line
            );
            return Ok(());
        }
        let p = Props::new(el);
        // How the projective integrators sample their boundary terms: noise.
        for n in [
            "sppc",
            "sppp",
            "sppi",
            "guiding",
            "guiding_rounds",
            "guiding_proj",
            "proj_seed_spp",
        ] {
            p.ignore(n);
        }
        if direct {
            self.max_depth = Some(1);
            // direct_projective keeps one bounce whatever it is told.
            for n in [
                "emitter_samples",
                "bsdf_samples",
                "shading_samples",
                "max_depth",
            ] {
                p.ignore(n);
            }
        }
        let max_depth = if direct {
            None
        } else {
            p.integer("max_depth")?
        };
        if let Some(d) = max_depth {
            self.max_depth = Some(match d {
                -1 => super::MITSUBA_UNLIMITED_DEPTH,
                d if d >= 1 && d <= 1 + crate::render::settings::MAX_DEPTH as i64 => (d - 1) as u32,
                d => {
                    return Err(el.error(format!(
                        "max_depth {d} must be -1 (unlimited) or 1..={}",
                        crate::render::settings::MAX_DEPTH + 1
                    )))
                }
            });
        }
        // Where Russian roulette starts changes noise, not the image.
        p.ignore("rr_depth");
        self.defaults.hide_emitters = p.boolean("hide_emitters")?.unwrap_or(false);
        p.finish()
    }

    fn sensor(&mut self, el: &Element) -> Result<(), SceneError> {
        // Mitsuba renders a scene's first sensor unless told otherwise.
        if self.camera.is_some() {
            log::warn!(
                "{}:{}: another <sensor>: qtrace renders the scene's first, as Mitsuba does by default",
                el.file.display(),
                el.line
            );
            return Ok(());
        }
        let kind = el.plugin()?;
        let (thin_lens, orthographic) = match kind {
            "perspective" => (false, false),
            "thinlens" => (true, false),
            "orthographic" => (false, true),
            _ => {
                return Err(el.error(format!(
                    "{} is not supported; qtrace has the 'perspective', 'thinlens' and 'orthographic' sensors",
                    plugin_name(el)
                )))
            }
        };
        let p = Props::new(el);
        let axis = match p.string("fov_axis")?.unwrap_or("x") {
            "x" => FovAxis::X,
            "y" => FovAxis::Y,
            "diagonal" => FovAxis::Diagonal,
            "smaller" => FovAxis::Smaller,
            "larger" => FovAxis::Larger,
            other => {
                return Err(el.error(format!(
                    "fov_axis '{other}' is not x, y, diagonal, smaller or larger"
                )))
            }
        };
        let (fov, axis) = match (p.float("fov")?, p.string("focal_length")?) {
            // (An orthographic camera has none: its to_world's scale says
            // how wide it sees.)
            (None, None) if orthographic => (90.0, axis),
            (Some(_), Some(_)) => return Err(el.error("give fov or focal_length, not both")),
            (Some(f), None) => (f, axis),
            (None, focal) => (focal_fov(el, focal)?, FovAxis::Diagonal),
        };
        if !(fov > 0.0 && fov < 180.0) {
            return Err(el.error(format!("fov {fov} must lie in (0, 180) degrees")));
        }
        let to_world = p.transform("to_world")?.unwrap_or(Mat4::IDENTITY);
        let scaled = [to_world.x_axis, to_world.y_axis, to_world.z_axis]
            .iter()
            .any(|c| (c.truncate().length_squared() - 1.0).abs() > 1e-3);
        if scaled && !orthographic {
            return Err(el.error(format!(
                "{kind}: its to_world must not scale (as in Mitsuba); a lookat or rotations place a camera"
            )));
        }
        // Clipping planes keep the scene in front of a pinhole whole; an
        // orthographic camera's rays start on its near plane.
        let near_clip = p.float_or("near_clip", 0.01)?;
        let orthographic = orthographic.then(|| crate::scene::Orthographic {
            half_width: to_world.x_axis.truncate().length(),
            half_height: to_world.y_axis.truncate().length(),
            near: near_clip * to_world.z_axis.truncate().length(),
        });
        let far_clip = p.float_or("far_clip", 10_000.0)?;
        // A pinhole's off-centre image, in fractions of its width and height.
        let shift = if kind == "perspective" {
            Vec2::new(
                p.float_or("principal_point_offset_x", 0.0)?,
                p.float_or("principal_point_offset_y", 0.0)?,
            )
        } else {
            Vec2::ZERO
        };
        let (aperture_radius, focus_distance) = if thin_lens {
            let radius = p
                .float("aperture_radius")?
                .ok_or_else(|| el.error("thinlens needs an aperture_radius"))?;
            // Mitsuba's default focus: as far as the far clipping plane.
            let focus = p.float_or("focus_distance", far_clip)?;
            if !(radius >= 0.0 && radius.is_finite()) {
                return Err(el.error(format!("aperture_radius {radius} must not be negative")));
            }
            if !(focus > 0.0 && focus.is_finite()) {
                return Err(el.error(format!("focus_distance {focus} must be positive")));
            }
            (radius, focus)
        } else {
            // A pinhole is in focus at every distance.
            p.ignore("focus_distance");
            (0.0, 1.0)
        };
        // No shape moves.
        p.ignore("shutter_open");
        p.ignore("shutter_close");
        for sampler in p.nested("sampler") {
            self.sampler(sampler)?;
        }
        for film in p.nested("film") {
            self.film(film)?;
        }
        p.finish()?;
        let frame = |v: Vec3| to_world.transform_vector3(v).try_normalize();
        let (Some(left), Some(up), Some(forward)) =
            (frame(Vec3::X), frame(Vec3::Y), frame(Vec3::Z))
        else {
            return Err(el.error("the sensor's to_world is singular"));
        };
        self.camera = Some(Camera {
            position: to_world.transform_point3(Vec3::ZERO),
            forward,
            right: -left,
            up,
            fov_degrees: fov,
            fov_axis: axis,
            aperture_radius,
            focus_distance,
            orthographic,
            shift,
            crop: self.crop,
        });
        Ok(())
    }

    fn sampler(&mut self, el: &Element) -> Result<(), SceneError> {
        match el.plugin()? {
            "independent" | "stratified" | "multijitter" | "orthogonal" | "ldsampler" => {}
            other => return Err(el.error(format!("sampler '{other}' is not a Mitsuba 3 sampler"))),
        }
        let p = Props::new(el);
        if let Some(n) = p.integer("sample_count")? {
            if n < 1 || n > crate::render::settings::MAX_SPP as i64 {
                return Err(el.error(format!(
                    "sample_count {n} must lie in 1..={}",
                    crate::render::settings::MAX_SPP
                )));
            }
            self.defaults.spp = Some(n as u32);
        }
        // Every sequence converges to the same image; qtrace draws its own.
        for k in ["seed", "jitter", "scramble_seed", "dimension"] {
            p.ignore(k);
        }
        p.finish()
    }

    fn film(&mut self, el: &Element) -> Result<(), SceneError> {
        if el.plugin()? != "hdrfilm" {
            return Err(el.error(format!(
                "{} is not supported; qtrace has 'hdrfilm'",
                plugin_name(el)
            )));
        }
        let p = Props::new(el);
        let size = |name: &str, default: u32| -> Result<u32, SceneError> {
            match p.integer(name)? {
                None => Ok(default),
                Some(v) if v >= 1 && v <= crate::render::settings::MAX_RESOLUTION as i64 => {
                    Ok(v as u32)
                }
                Some(v) => Err(el.error(format!(
                    "film {name} {v} must lie in 1..={}",
                    crate::render::settings::MAX_RESOLUTION
                ))),
            }
        };
        let (width, height) = (size("width", 768)?, size("height", 576)?);
        self.defaults.width = Some(width);
        self.defaults.height = Some(height);
        // A crop window: the image shows that part of the film.
        let at = |name: &str, default: u32| -> Result<u32, SceneError> {
            match p.integer(name)? {
                None => Ok(default),
                Some(v) if (0..=u32::MAX as i64).contains(&v) => Ok(v as u32),
                Some(v) => Err(el.error(format!("film {name} {v} must not be negative"))),
            }
        };
        let offset = (at("crop_offset_x", 0)?, at("crop_offset_y", 0)?);
        let crop = (
            at("crop_width", width.saturating_sub(offset.0))?,
            at("crop_height", height.saturating_sub(offset.1))?,
        );
        if crop.0 == 0
            || crop.1 == 0
            || offset.0 as u64 + crop.0 as u64 > width as u64
            || offset.1 as u64 + crop.1 as u64 > height as u64
        {
            return Err(el.error(format!(
                "the film's crop window ({}x{} at {}, {}) must lie within its {width}x{height}",
                crop.0, crop.1, offset.0, offset.1
            )));
        }
        self.crop = (crop != (width, height)).then(|| {
            self.defaults.width = Some(crop.0);
            self.defaults.height = Some(crop.1);
            crate::scene::Crop {
                film: (width, height),
                offset,
                size: crop,
            }
        });
        // What the file holds, not what the image shows.
        for k in [
            "file_format",
            "pixel_format",
            "component_format",
            "banner",
            "compensate",
        ] {
            p.ignore(k);
        }
        self.defaults.sample_border = p.boolean("sample_border")?.unwrap_or(false);
        for f in p.nested("rfilter") {
            let fp = Props::new(f);
            self.filter = match f.plugin()? {
                "box" => PixelFilter::Box,
                "tent" => PixelFilter::Tent {
                    radius: positive(f, "radius", fp.float_or("radius", 1.0)?)?,
                },
                "gaussian" => PixelFilter::Gaussian {
                    stddev: positive(f, "stddev", fp.float_or("stddev", 0.5)?)?,
                },
                "mitchell" => {
                    let (b, c) = (fp.float_or("B", 1.0 / 3.0)?, fp.float_or("C", 1.0 / 3.0)?);
                    // Every B and C keeps the cubic's integral at 1, but a
                    // render's weights grow as its value at 0 falls.
                    if !(b.abs() <= 4.0 && c.abs() <= 4.0) {
                        return Err(f.error(format!(
                            "mitchell B {b}, C {c}: qtrace takes B and C within [-4, 4]"
                        )));
                    }
                    PixelFilter::Cubic { b, c }
                }
                "catmullrom" => PixelFilter::Cubic { b: 0.0, c: 0.5 },
                "lanczos" => match fp.integer("lobes")?.unwrap_or(3) {
                    lobes @ 1..=16 => PixelFilter::Lanczos {
                        lobes: lobes as u32,
                    },
                    other => return Err(f.error(format!("lanczos lobes {other} must lie in 1..=16"))),
                },
                other => {
                    return Err(f.error(format!(
                        "rfilter '{other}' is not supported; qtrace has box, tent, gaussian, mitchell, catmullrom and lanczos"
                    )))
                }
            };
            fp.finish()?;
        }
        p.finish()
    }

    fn shape(&mut self, el: &Element) -> Result<(), SceneError> {
        let kind = el.plugin()?;
        match kind {
            "shapegroup" => return self.shape_group(el),
            "instance" => return self.instance(el),
            _ => {}
        }
        let p = Props::new(el);
        let emission = area_emission(&p, &mut self.textures, self.loader)?;
        let (desc, shared) = self.shape_bsdf(&p, emission.is_some())?;
        // An emitter's BSDF takes no textures; its radiance may be a mesh
        // attribute.
        let attributes = match emission {
            Some((_, Some(t))) => match &self.textures.used[t as usize].pattern {
                Pattern::Attribute { name, .. } => vec![(name.clone(), false)],
                _ => Vec::new(),
            },
            Some(_) => Vec::new(),
            None => self.attribute_read(&desc),
        };
        let (mesh, attributes) = self.shape_mesh(el, kind, &p, &attributes)?;
        p.finish()?;
        if desc.surface.anisotropic() && mesh.2.is_none() {
            log::warn!(
                "{}:{}: an anisotropic BSDF on a mesh without texture coordinates: its roughness follows each triangle's first edge in qtrace, Mitsuba's own frame about the face normal in Mitsuba (give the mesh texture coordinates)",
                el.file.display(),
                el.line
            );
        }
        let label = format!(
            "shape '{}' ({kind}) at line {}",
            el.attr("id").unwrap_or("unnamed"),
            el.line
        );
        if let Some((le, radiance_texture)) = emission {
            // Paths go on at an emitter as its BSDF says (through a null
            // one, scattered by others: Material::emitter_passes and
            // emitter_reflects), as in Mitsuba; but an emitter's material
            // has no room for textures, a normal map or a choice: those
            // end paths, as a black BSDF does.
            let faithful = desc.choice.is_none()
                && desc.normal_map.is_none()
                && desc.textures.iter().all(Option::is_none);
            if !faithful {
                log::warn!(
                    "{}:{}: an emitter with BSDF {} (textured, normal-mapped or a mask, blend or two-faced twosided): qtrace ends a path at such an emitter, where Mitsuba's also reflect from it",
                    el.file.display(),
                    el.line,
                    desc.name,
                );
            }
            let surface = if faithful {
                desc.surface
            } else {
                Surface::Diffuse { albedo: Vec3::ZERO }
            };
            let m = self.materials.len() as u32;
            self.materials.push(Material {
                name: label.clone(),
                surface,
                emission: le,
                one_sided: desc.one_sided,
                // The colour slot holds a radiance texture.
                textures: {
                    let mut t = [None; crate::scene::TEXTURE_SLOTS];
                    t[crate::shaders::TEXTURE_SLOT_COLOR as usize] = radiance_texture;
                    t
                },
                normal_map: None,
                choice: None,
                smooth_light: matches!(kind, "obj" | "ply" | "serialized") && normals_differ(&mesh),
            });
            self.add(el, &label, mesh, attributes, m);
            return Ok(());
        }
        let m = match shared {
            Some((_, Some(m))) => m,
            _ => {
                let m = self.add_material(&desc);
                if let Some((id, None)) = &shared {
                    if let Some(entry) = self.bsdfs.get_mut(id) {
                        entry.1 = Some(m);
                    }
                }
                m
            }
        };
        self.add(el, &label, mesh, attributes, m);
        Ok(())
    }

    /// The mesh attributes the textures of `desc` (and of the BSDFs it
    /// chooses between) read, each once, and whether a number is read
    /// from it.
    fn attribute_read(&self, desc: &BsdfDesc) -> Vec<(String, bool)> {
        fn walk(desc: &BsdfDesc, textures: &[Texture], out: &mut Vec<(String, bool)>) {
            let weight = desc.choice.as_ref().and_then(|c| c.kind.texture());
            for t in desc.textures.iter().flatten().chain(weight.as_ref()) {
                if let Pattern::Attribute { name, number, .. } = &textures[*t as usize].pattern {
                    match out.iter_mut().find(|(n, _)| n == name) {
                        Some((_, num)) => *num |= number,
                        None => out.push((name.clone(), *number)),
                    }
                }
            }
            if let Some(c) = &desc.choice {
                walk(&c.first, textures, out);
                walk(&c.second, textures, out);
            }
        }
        let mut read = Vec::new();
        walk(desc, &self.textures.used, &mut read);
        read
    }

    /// A `shapegroup`: shapes kept by id until an `instance` places them.
    fn shape_group(&mut self, el: &Element) -> Result<(), SceneError> {
        let id = el
            .attr("id")
            .ok_or_else(|| el.error("a shapegroup needs an id"))?;
        for c in &el.children {
            if c.tag != "shape" {
                return Err(c.error(format!("a shapegroup holds shapes, not <{}>", c.tag)));
            }
            if matches!(c.plugin()?, "shapegroup" | "instance") {
                return Err(
                    c.error("a shapegroup inside a shapegroup is not permitted (as in Mitsuba)")
                );
            }
            if c.children.iter().any(|g| g.tag == "emitter") {
                return Err(c.error("instancing of emitters is not supported (as in Mitsuba)"));
            }
        }
        self.groups
            .insert(id.to_string(), std::rc::Rc::new(el.children.clone()));
        Ok(())
    }

    /// An `instance`: a shapegroup's shapes, placed by its `to_world`.
    fn instance(&mut self, el: &Element) -> Result<(), SceneError> {
        let p = Props::new(el);
        let to_world = p.transform("to_world")?.unwrap_or(Mat4::IDENTITY);
        let refs = p.nested("ref");
        p.finish()?;
        let [r] = refs[..] else {
            return Err(el.error("an instance names one shapegroup, by <ref id=...>"));
        };
        let id = r.required("id")?;
        let shapes = self.groups.get(id).cloned().ok_or_else(|| {
            r.error(format!(
                "no shapegroup has the id '{id}' (a shapegroup must come before its instances)"
            ))
        })?;
        let outer = self.instance_to_world;
        self.instance_to_world = outer * to_world;
        let placed = shapes.iter().try_for_each(|c| self.shape(c));
        self.instance_to_world = outer;
        placed
    }

    /// Segments around the equator of a sphere (at `center`, of `radius`,
    /// placed by `to_world` and the instance being placed) from the pixels
    /// its radius spans on the image, at the film's size or 1024 pixels
    /// wide if more (`--width` may render a film larger than it says); the
    /// most where the camera is inside it.
    fn sphere_segments(&self, to_world: Mat4, center: Vec3, radius: f32) -> u32 {
        let Some(camera) = &self.camera else {
            return shapes::SEGMENTS;
        };
        let world = self.instance_to_world * to_world;
        let centre = world.transform_point3(center);
        // Its largest radius in the world: a to_world may scale unevenly.
        let r = radius
            * [Vec3::X, Vec3::Y, Vec3::Z]
                .iter()
                .map(|&a| world.transform_vector3(a).length())
                .fold(0.0, f32::max);
        let distance = (centre - camera.position).length() - r;
        let (w, h) = (
            self.defaults.width.unwrap_or(768),
            self.defaults.height.unwrap_or(576),
        );
        let detail = (1024.0 / w as f32).max(1.0);
        shapes::sphere_segments(camera.pixels_across(r, distance, w, h) * detail)
    }

    /// A shape's triangles (with normals and UVs where it has them), in
    /// world space, turned over with `flip_normals`.
    /// With the values at its triangles' corners of the mesh attributes
    /// `attributes` name (each with whether a number is read from it).
    fn shape_mesh(
        &mut self,
        el: &Element,
        kind: &str,
        p: &Props,
        attributes: &[(String, bool)],
    ) -> Result<(Mesh, Attributes), SceneError> {
        let to_world = p.transform("to_world")?.unwrap_or(Mat4::IDENTITY);
        let flip = p.boolean("flip_normals")?.unwrap_or(false);
        let face_normals = p.boolean("face_normals")?.unwrap_or(false);
        // A mesh file's name; Mitsuba turns an OBJ's v over by default.
        let filename = || {
            p.string("filename")?
                .ok_or_else(|| el.error(format!("shape '{kind}' needs a filename")))
        };
        let flip_v = || -> Result<bool, SceneError> {
            Ok(p.boolean("flip_tex_coords")?.unwrap_or(kind == "obj"))
        };
        if let Some((name, _)) = attributes.first().filter(|_| kind != "ply") {
            return Err(el.error(format!(
                "shape '{kind}' has no mesh attribute '{name}' (qtrace reads them from PLY files, as Mitsuba)"
            )));
        }
        let mut corners = Vec::new();
        let (triangles, normals, uvs) = match kind {
            "rectangle" => {
                let (t, uv) = shapes::rectangle(to_world);
                (t, None, Some(uv))
            }
            "cube" => {
                let (t, uv) = shapes::cube(to_world);
                (t, None, Some(uv))
            }
            "disk" => {
                let (t, uv) = shapes::disk(to_world);
                (t, None, Some(uv))
            }
            "sphere" => {
                let center = p.point("center")?.unwrap_or(Vec3::ZERO);
                let radius = p.float_or("radius", 1.0)?;
                if radius <= 0.0 {
                    return Err(el.error(format!("sphere radius {radius} must be positive")));
                }
                let segments = self.sphere_segments(to_world, center, radius);
                let (t, n, uv) = shapes::sphere(to_world, center, radius, segments);
                (t, Some(n), Some(uv))
            }
            "cylinder" => {
                let p0 = p.point("p0")?.unwrap_or(Vec3::ZERO);
                let p1 = p.point("p1")?.unwrap_or(Vec3::Z);
                let radius = p.float_or("radius", 1.0)?;
                if radius <= 0.0 {
                    return Err(el.error(format!("cylinder radius {radius} must be positive")));
                }
                let (t, n, uv) = shapes::cylinder(to_world, p0, p1, radius)
                    .ok_or_else(|| el.error("cylinder p0 and p1 are the same point"))?;
                (t, Some(n), Some(uv))
            }
            "obj" => self.obj(el, filename()?, to_world, (face_normals, flip_v()?))?,
            "ply" => {
                let (mesh, a) = self.ply(
                    el,
                    filename()?,
                    to_world,
                    (face_normals, flip_v()?),
                    attributes,
                )?;
                corners = a;
                mesh
            }
            "serialized" => {
                let name = filename()?;
                let index = p.integer("shape_index")?.unwrap_or(0);
                if !(0..=u32::MAX as i64).contains(&index) {
                    return Err(el.error(format!("shape_index {index} is negative")));
                }
                if p.float("max_smooth_angle")?.is_some() {
                    return Err(el.error(
                        "max_smooth_angle is Mitsuba 0.6's; Mitsuba 3 does not read it (give the mesh its normals, or face_normals)",
                    ));
                }
                self.serialized(el, name, index as u32, to_world, (face_normals, flip_v()?))?
            }
            other => {
                return Err(el.error(format!(
                    "shape '{other}' is not supported; qtrace has obj, ply, serialized, rectangle, cube, disk, sphere and cylinder"
                )))
            }
        };
        let mesh = if flip {
            for (_, v) in &mut corners {
                v.iter_mut().for_each(|t| t.swap(1, 2));
            }
            (
                triangles.into_iter().map(|[a, b, c]| [a, c, b]).collect(),
                normals.map(|n| n.into_iter().map(|[a, b, c]| [-a, -c, -b]).collect()),
                uvs.map(|uv| uv.into_iter().map(|[a, b, c]| [a, c, b]).collect()),
            )
        } else {
            (triangles, normals, uvs)
        };
        Ok((placed_by_instance(mesh, self.instance_to_world), corners))
    }

    /// A shape's BSDF, nested or by reference (Mitsuba's default where it
    /// has none, black where it `emits`), and for a reference, its id and the material it made, if
    /// an earlier shape made one.
    #[allow(clippy::type_complexity)]
    fn shape_bsdf(
        &mut self,
        p: &Props,
        emits: bool,
    ) -> Result<(BsdfDesc, Option<(String, Option<u32>)>), SceneError> {
        let mut desc = None;
        let mut shared = None;
        for b in p.nested("bsdf") {
            if desc.is_some() {
                return Err(b.error("a shape has one BSDF"));
            }
            desc = Some(bsdf(b, &mut self.textures, self.loader)?);
        }
        for r in p.nested("ref") {
            if desc.is_some() {
                return Err(r.error("a shape has one BSDF"));
            }
            let id = r.required("id")?;
            let Some((d, m)) = self.bsdfs.get(id) else {
                return Err(r.error(format!(
                    "no BSDF has the id '{id}' (a BSDF must come before the shapes that use it)"
                )));
            };
            desc = Some(d.clone());
            shared = Some((id.to_string(), *m));
        }
        // Mitsuba's default: a one-sided diffuse surface of reflectance 0.5,
        // or 0 on an emitter.
        let desc = desc.unwrap_or(BsdfDesc {
            name: "default diffuse".into(),
            surface: Surface::Diffuse {
                albedo: Vec3::splat(if emits { 0.0 } else { 0.5 }),
            },
            one_sided: true,
            null: false,
            textures: [None; crate::scene::TEXTURE_SLOTS],
            normal_map: None,
            choice: None,
        });
        Ok((desc, shared))
    }

    /// Adds the material `desc` describes, and those it chooses between;
    /// returns its index.
    fn add_material(&mut self, desc: &BsdfDesc) -> u32 {
        let choice = desc.choice.as_ref().map(|c| Choice {
            kind: c.kind,
            first: self.add_material(&c.first),
            second: self.add_material(&c.second),
        });
        self.materials.push(Material {
            name: desc.name.clone(),
            surface: desc.surface,
            emission: Vec3::ZERO,
            one_sided: desc.one_sided,
            textures: desc.textures,
            normal_map: desc.normal_map,
            choice,
            smooth_light: false,
        });
        self.materials.len() as u32 - 1
    }

    fn add(
        &mut self,
        el: &Element,
        label: &str,
        (triangles, normals, uvs): Mesh,
        attributes: Attributes,
        material: u32,
    ) {
        let source = (el.file.as_ref().clone(), label.to_string());
        self.geometry
            .add(source, triangles, normals, uvs, attributes, material);
    }

    /// An OBJ mesh in world space, with Mitsuba's shading normals unless
    /// `face_normals`: the file's `vn` where its faces give them, else each
    /// vertex's faces' normals weighted by their angles there.
    fn obj(
        &self,
        el: &Element,
        name: &str,
        to_world: Mat4,
        (face_normals, flip_v): (bool, bool),
    ) -> Result<Mesh, SceneError> {
        let (path, bytes) = self.mesh_file(el, name)?;
        let text = String::from_utf8(bytes)
            .map_err(|_| el.error(format!("the mesh '{name}' is not UTF-8 text")))?;
        let budget = self.triangle_budget();
        // The XML gives the materials; an OBJ's own MTL is not read.
        let parsed = obj::parse_obj(&text, budget, &mut |_| Ok(String::new())).map_err(|e| {
            SceneError::Obj {
                path: path.clone(),
                message: e.to_string(),
            }
        })?;
        let mut triangles = Vec::new();
        let mut corners = Vec::new();
        let mut normal_corners = Vec::new();
        let mut uv_corners = Vec::new();
        for g in parsed.groups {
            triangles.extend(
                g.triangles
                    .into_iter()
                    .map(|t| t.map(|v| to_world.transform_point3(v))),
            );
            corners.extend(g.corners);
            normal_corners.extend(g.normal_corners);
            uv_corners.extend(g.uv_corners);
        }
        // The file's vt where a face gives them (v turned over with
        // `flip_v`, as Mitsuba does by default), else barycentric.
        let uvs =
            (!parsed.uvs.is_empty()).then(|| obj::corner_uvs(&parsed.uvs, &uv_corners, flip_v));
        if face_normals {
            return Ok((triangles, None, uvs));
        }
        let normal_matrix = glam::Mat3::from_mat4(to_world).inverse().transpose();
        let file_normals: Vec<Vec3> = parsed
            .normals
            .iter()
            .map(|n| (normal_matrix * *n).normalize_or_zero())
            .collect();
        let smooth = smooth_normals(&triangles, &corners);
        let normals = normal_corners
            .iter()
            .zip(smooth)
            .map(|(nc, smooth)| {
                if nc.iter().all(|&i| i != obj::NO_NORMAL) {
                    nc.map(|i| file_normals[i as usize])
                } else {
                    smooth
                }
            })
            .collect();
        Ok((triangles, Some(normals), uvs))
    }
}

impl Builder<'_, '_> {
    /// A file a mesh shape names, and its path.
    fn mesh_file(&self, el: &Element, name: &str) -> Result<(PathBuf, Vec<u8>), SceneError> {
        el.read_file(self.loader, name)
            .map_err(|e| el.error(format!("cannot read the mesh '{name}': {e}")))
    }

    /// How many more triangles the scene may take.
    fn triangle_budget(&self) -> usize {
        self.loader
            .max_triangles
            .saturating_sub(self.geometry.positions.len())
    }

    /// A PLY mesh in world space, and the values at its triangles' corners
    /// of the attributes `attributes` name.
    fn ply(
        &self,
        el: &Element,
        name: &str,
        to_world: Mat4,
        (face_normals, flip_v): (bool, bool),
        attributes: &[(String, bool)],
    ) -> Result<(Mesh, Attributes), SceneError> {
        let (path, bytes) = self.mesh_file(el, name)?;
        let mesh = ply::parse_ply(&bytes, self.triangle_budget())
            .map_err(|m| malformed(&path, "PLY", &m, el))?;
        let corners = attributes
            .iter()
            .map(|(wanted, number)| {
                let values =
                    attribute_corners(&mesh, wanted, *number).map_err(|m| SceneError::Invalid {
                        path: path.clone(),
                        message: format!("{m} (the shape at {}:{})", el.file.display(), el.line),
                    })?;
                Ok((wanted.clone(), values))
            })
            .collect::<Result<_, SceneError>>()?;
        Ok((placed_mesh(&mesh, to_world, face_normals, flip_v), corners))
    }

    /// Shape `index` of a serialized file in world space; the file's own
    /// flag asks for face normals too.
    fn serialized(
        &self,
        el: &Element,
        name: &str,
        index: u32,
        to_world: Mat4,
        (face_normals, flip_v): (bool, bool),
    ) -> Result<Mesh, SceneError> {
        let (path, bytes) = self.mesh_file(el, name)?;
        let shape = serialized::parse_serialized(&bytes, index, self.triangle_budget())
            .map_err(|m| malformed(&path, "serialized mesh", &m, el))?;
        let flat = face_normals || shape.flags & serialized::FACE_NORMALS != 0;
        Ok(placed_mesh(&shape.mesh, to_world, flat, flip_v))
    }
}

/// The values at each triangle's corners of mesh attribute `name` (a
/// one-channel attribute's value in all three channels; a face's at all
/// three corners), checked as Mitsuba 3 evaluates it: colours from one or
/// three channels, numbers (`number`) from one.
fn attribute_corners(
    mesh: &ply::IndexedMesh,
    name: &str,
    number: bool,
) -> Result<Vec<[Vec3; 3]>, String> {
    let Some(a) = mesh.attributes.iter().find(|a| a.name == name) else {
        let names: Vec<&str> = mesh.attributes.iter().map(|a| a.name.as_str()).collect();
        return Err(format!(
            "the mesh has no attribute '{name}' ({})",
            if names.is_empty() {
                "it has none".to_string()
            } else {
                format!("it has {}", names.join(", "))
            }
        ));
    };
    match (a.channels, number) {
        (1, _) | (3, false) => {}
        (3, true) => {
            return Err(format!(
                "a number is read from attribute '{name}', which has 3 channels (Mitsuba reads numbers from attributes of one)"
            ))
        }
        (n, _) => {
            return Err(format!(
                "attribute '{name}' has {n} channels; Mitsuba evaluates attributes of 1 or 3"
            ))
        }
    }
    // A file of several vertex or face elements gives some items none.
    let items = if a.per_face() {
        mesh.triangles.len()
    } else {
        mesh.positions.len()
    };
    if a.values.len() != a.channels * items {
        return Err(format!(
            "attribute '{name}' is not given for every {}",
            if a.per_face() { "face" } else { "vertex" }
        ));
    }
    if a.integer {
        log::warn!(
            "mesh attribute '{name}' is stored in integers: Mitsuba and qtrace read them as they are (a byte's 255 is 255), not scaled to [0, 1]"
        );
    }
    let value = |k: usize| match a.channels {
        1 => Vec3::splat(a.values[k]),
        _ => Vec3::new(a.values[3 * k], a.values[3 * k + 1], a.values[3 * k + 2]),
    };
    Ok(if a.per_face() {
        (0..mesh.triangles.len()).map(|j| [value(j); 3]).collect()
    } else {
        mesh.triangles
            .iter()
            .map(|t| t.map(|i| value(i as usize)))
            .collect()
    })
}

/// A mesh file's problem, naming the file and the shape that reads it.
fn malformed(path: &Path, what: &str, message: &str, el: &Element) -> SceneError {
    SceneError::Invalid {
        path: path.to_path_buf(),
        message: format!(
            "malformed {what}: {message} (the shape at {}:{})",
            el.file.display(),
            el.line
        ),
    }
}

/// An indexed mesh in world space, with Mitsuba's shading normals unless
/// `face_normals`: the file's where it has them, else computed; and its
/// texture coordinates if it has them (v turned over with `flip_v`).
fn placed_mesh(mesh: &ply::IndexedMesh, to_world: Mat4, face_normals: bool, flip_v: bool) -> Mesh {
    let positions: Vec<Vec3> = mesh
        .positions
        .iter()
        .map(|p| to_world.transform_point3(*p))
        .collect();
    let triangles: Vec<[Vec3; 3]> = mesh
        .triangles
        .iter()
        .map(|t| t.map(|i| positions[i as usize]))
        .collect();
    let uvs = mesh.uvs.as_ref().map(|uv| {
        mesh.triangles
            .iter()
            .map(|t| {
                t.map(|i| {
                    let p = uv[i as usize];
                    if flip_v {
                        Vec2::new(p.x, 1.0 - p.y)
                    } else {
                        p
                    }
                })
            })
            .collect()
    });
    if face_normals {
        return (triangles, None, uvs);
    }
    let normals = match &mesh.normals {
        Some(n) => {
            let m = glam::Mat3::from_mat4(to_world).inverse().transpose();
            let world: Vec<Vec3> = n.iter().map(|v| (m * *v).normalize_or_zero()).collect();
            mesh.triangles
                .iter()
                .map(|t| t.map(|i| world[i as usize]))
                .collect()
        }
        None => smooth_normals(&triangles, &mesh.triangles),
    };
    (triangles, Some(normals), uvs)
}

/// Mitsuba's normals for a mesh without its own: at each vertex the sum of
/// its faces' normals, each weighted by the face's angle there (Thürmer and
/// Wüthrich), normalized. `corners` names each triangle's vertices.
fn smooth_normals(triangles: &[[Vec3; 3]], corners: &[[u32; 3]]) -> Vec<[Vec3; 3]> {
    let count = corners
        .iter()
        .flatten()
        .map(|&i| i as usize + 1)
        .max()
        .unwrap_or(0);
    let mut sum = vec![Vec3::ZERO; count];
    for (t, c) in triangles.iter().zip(corners) {
        let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
        for j in 0..3 {
            let d0 = (t[(j + 1) % 3] - t[j]).normalize_or_zero();
            let d1 = (t[(j + 2) % 3] - t[j]).normalize_or_zero();
            let angle = d0.dot(d1).clamp(-1.0, 1.0).acos();
            sum[c[j] as usize] += n * angle;
        }
    }
    corners
        .iter()
        .zip(triangles)
        .map(|(c, t)| {
            let face = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
            c.map(|i| sum[i as usize].try_normalize().unwrap_or(face))
        })
        .collect()
}

fn positive(el: &Element, name: &str, v: f32) -> Result<f32, SceneError> {
    if v > 0.0 {
        Ok(v)
    } else {
        Err(el.error(format!("{name} {v} must be positive")))
    }
}

/// A colour that may not exceed 1 (it would create energy).
fn reflectance(el: &Element, p: &Props, name: &str, default: f32) -> Result<Vec3, SceneError> {
    let c = p.color(name)?.unwrap_or(Vec3::splat(default));
    if c.min_element() < 0.0 || c.max_element() > 1.0 {
        return Err(el.error(format!("{} {name} {c} must lie in [0, 1]", plugin_name(el))));
    }
    Ok(c)
}

/// Mitsuba 3's named conductors as its RGB variants see them: η and k per
/// channel, read from Mitsuba 3.9.1 (`mi.traverse` of each `material`).
#[rustfmt::skip]
#[allow(clippy::excessive_precision)] // as Mitsuba printed them
const CONDUCTOR_TABLE: &[(&str, [f32; 3], [f32; 3])] = &[
    ("none", [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]),
    ("a-C", [2.944046, 2.227136, 1.968162], [0.887465, 0.799299, 0.815290]),
    ("Ag", [0.155276, 0.116728, 0.138388], [4.828354, 3.122222, 2.146901]),
    ("Al", [1.657501, 0.880405, 0.521244], [9.223811, 6.269502, 4.837004]),
    ("AlAs", [3.605296, 3.232938, 2.216319], [0.000679, 0.000000, 0.007513]),
    ("AlAs_palik", [3.605296, 3.232938, 2.216319], [0.000679, 0.000000, 0.007513]),
    ("AlSb", [0.000000, 4.139375, 4.669254], [0.000000, 0.094009, 1.300570]),
    ("AlSb_palik", [0.000000, 4.139375, 4.669254], [0.000000, 0.094009, 1.300570]),
    ("Au", [0.143036, 0.375307, 1.442045], [3.982997, 2.385556, 1.603359]),
    ("Be", [4.185012, 3.185029, 2.784061], [3.835466, 3.010122, 2.868994]),
    ("Be_palik", [4.185012, 3.185029, 2.784061], [3.835466, 3.010122, 2.868994]),
    ("Cr", [4.369668, 2.916505, 1.654905], [5.206547, 4.231306, 3.754699]),
    ("CsI", [2.144900, 1.702319, 1.662427], [0.000000, 0.000000, 0.000000]),
    ("CsI_palik", [2.144900, 1.702319, 1.662427], [0.000000, 0.000000, 0.000000]),
    ("Cu", [0.201005, 0.923750, 1.102215], [3.913262, 2.453045, 2.142090]),
    ("Cu_palik", [0.213229, 0.919715, 1.102411], [3.921873, 2.457332, 2.136584]),
    ("Cu2O", [3.551773, 2.949870, 2.751875], [0.114207, 0.193897, 0.606134]),
    ("Cu2O_palik", [3.551773, 2.949870, 2.751875], [0.114207, 0.193897, 0.606134]),
    ("CuO", [3.247541, 2.447805, 2.210220], [0.521090, 0.570031, 0.722179]),
    ("CuO_palik", [3.247541, 2.447805, 2.210220], [0.521090, 0.570031, 0.722179]),
    ("d-C", [2.708720, 2.318826, 2.228898], [0.000000, 0.000000, 0.000000]),
    ("d-C_palik", [2.708720, 2.318826, 2.228898], [0.000000, 0.000000, 0.000000]),
    ("Hg", [2.398939, 1.440028, 0.909570], [6.327587, 4.371925, 3.421764]),
    ("Hg_palik", [2.398939, 1.440028, 0.909570], [6.327587, 4.371925, 3.421764]),
    ("HgTe", [4.779040, 3.231196, 2.659901], [1.631613, 1.580810, 1.729287]),
    ("HgTe_palik", [4.779040, 3.231196, 2.659901], [1.631613, 1.580810, 1.729287]),
    ("Ir", [3.086300, 2.082191, 1.617915], [5.592153, 4.067088, 3.267312]),
    ("Ir_palik", [3.086300, 2.082191, 1.617915], [5.592153, 4.067088, 3.267312]),
    ("K", [0.064043, 0.046410, 0.038185], [2.104200, 1.348940, 0.913126]),
    ("K_palik", [0.064043, 0.046410, 0.038185], [2.104200, 1.348940, 0.913126]),
    ("Li", [0.265791, 0.195618, 0.220949], [3.540155, 2.311123, 1.668607]),
    ("Li_palik", [0.265791, 0.195618, 0.220949], [3.540155, 2.311123, 1.668607]),
    ("MgO", [2.089584, 1.650723, 1.594879], [0.000000, 0.000000, 0.000000]),
    ("MgO_palik", [2.089584, 1.650723, 1.594879], [0.000000, 0.000000, 0.000000]),
    ("Mo", [4.483974, 3.525131, 2.776310], [4.111437, 3.420827, 3.150607]),
    ("Mo_palik", [4.483974, 3.525131, 2.776310], [4.111437, 3.420827, 3.150607]),
    ("Na_palik", [0.060269, 0.056141, 0.061988], [3.179273, 2.112490, 1.579041]),
    ("Nb", [3.420074, 2.790093, 2.395629], [3.441395, 2.737666, 2.579746]),
    ("Nb_palik", [3.420074, 2.790093, 2.395629], [3.441395, 2.737666, 2.579746]),
    ("Ni_palik", [2.367305, 1.663373, 1.467078], [4.498812, 3.050153, 2.345439]),
    ("Rh", [2.585793, 1.860216, 1.554263], [6.782260, 4.702987, 3.976073]),
    ("Rh_palik", [2.585793, 1.860216, 1.554263], [6.782260, 4.702987, 3.976073]),
    ("Se", [4.058311, 2.842935, 2.820853], [0.754050, 0.638444, 0.521808]),
    ("Se_palik", [4.058311, 2.842935, 2.820853], [0.754050, 0.638444, 0.521808]),
    ("SiC", [3.172342, 2.525972, 2.479371], [0.000001, 0.000000, 0.000010]),
    ("SiC_palik", [3.172342, 2.525972, 2.479371], [0.000001, 0.000000, 0.000010]),
    ("SnTe", [4.524250, 1.981645, 1.281591], [0.000000, 0.000000, 0.000000]),
    ("SnTe_palik", [4.524250, 1.981645, 1.281591], [0.000000, 0.000000, 0.000000]),
    ("Ta", [2.062721, 2.392939, 2.627929], [2.408360, 1.741486, 1.947028]),
    ("Ta_palik", [2.062721, 2.392939, 2.627929], [2.408360, 1.741486, 1.947028]),
    ("Te", [7.390234, 4.482105, 2.637106], [3.256022, 3.527059, 3.292054]),
    ("Te_palik", [7.390234, 4.482105, 2.637106], [3.256022, 3.527059, 3.292054]),
    ("ThF4", [1.830714, 1.442229, 1.387648], [0.000000, 0.000000, 0.000000]),
    ("ThF4_palik", [1.830714, 1.442229, 1.387648], [0.000000, 0.000000, 0.000000]),
    ("TiC", [3.700528, 2.837422, 2.582287], [3.265635, 2.351589, 2.172791]),
    ("TiC_palik", [3.700528, 2.837422, 2.582287], [3.265635, 2.351589, 2.172791]),
    ("TiN", [1.648450, 1.150516, 1.379823], [3.368328, 1.943498, 1.102068]),
    ("TiN_palik", [1.648450, 1.150516, 1.379823], [3.368328, 1.943498, 1.102068]),
    ("TiO2", [3.456610, 2.801736, 2.905175], [0.000105, 0.000000, 0.000653]),
    ("TiO2_palik", [3.456610, 2.801736, 2.905175], [0.000105, 0.000000, 0.000653]),
    ("VC", [3.657566, 2.752736, 2.532672], [3.068301, 2.198687, 1.963193]),
    ("VC_palik", [3.657566, 2.752736, 2.532672], [3.068301, 2.198687, 1.963193]),
    ("V_palik", [4.277582, 3.512949, 2.761071], [3.491301, 2.889455, 3.111522]),
    ("VN", [2.865602, 2.119189, 1.940091], [3.032243, 2.056116, 1.616306]),
    ("VN_palik", [2.865602, 2.119189, 1.940091], [3.032243, 2.056116, 1.616306]),
    ("W", [4.370817, 3.300246, 2.998407], [3.500641, 2.604874, 2.273233]),
];

/// Mitsuba's named indices of refraction.
const IOR_TABLE: &[(&str, f32)] = &[
    ("vacuum", 1.0),
    ("helium", 1.000036),
    ("hydrogen", 1.000132),
    ("air", 1.000277),
    ("carbon dioxide", 1.00045),
    ("water", 1.3330),
    ("acetone", 1.36),
    ("ethanol", 1.361),
    ("carbon tetrachloride", 1.461),
    ("glycerol", 1.4729),
    ("benzene", 1.501),
    ("silicone oil", 1.52045),
    ("bromine", 1.661),
    ("water ice", 1.31),
    ("fused quartz", 1.458),
    ("pyrex", 1.470),
    ("acrylic glass", 1.49),
    ("polypropylene", 1.49),
    ("bk7", 1.5046),
    ("sodium chloride", 1.544),
    ("amber", 1.55),
    ("pet", 1.5750),
    ("diamond", 2.419),
];

/// An index of refraction given as a number or a name from Mitsuba's table.
fn ior(el: &Element, p: &Props, name: &str, default: &str) -> Result<f32, SceneError> {
    let text = match p.number_or_string(name)? {
        Some(Ok(v)) => return positive(el, name, v),
        Some(Err(s)) => s,
        None => default,
    };
    if let Some(v) = xml::parse_f32(text) {
        return positive(el, name, v);
    }
    IOR_TABLE
        .iter()
        .find(|(n, _)| *n == text)
        .map(|(_, v)| *v)
        .ok_or_else(|| {
            el.error(format!(
                "{name} '{text}' is not a number or a material of Mitsuba's IOR table"
            ))
        })
}

/// A shapegroup's mesh placed by an instance's `m`, as Mitsuba places it:
/// points transformed, normals transformed as normals, so that a mirroring
/// `m` keeps each face's side (a mesh's own `to_world` does not).
fn placed_by_instance((triangles, normals, uvs): Mesh, m: Mat4) -> Mesh {
    if m == Mat4::IDENTITY {
        return (triangles, normals, uvs);
    }
    (
        shapes::placed(m, triangles),
        normals.map(|n| shapes::placed_normals(m, &n)),
        uvs.map(|uv| shapes::placed_uvs(m, uv)),
    )
}

/// The diagonal field of view, in degrees, of a focal length on 35 mm film
/// (Mitsuba's `focal_length`, 50mm where not given).
fn focal_fov(el: &Element, focal: Option<&str>) -> Result<f32, SceneError> {
    let text = focal.unwrap_or("50mm");
    let mm = text
        .trim()
        .strip_suffix("mm")
        .and_then(xml::parse_f32)
        .filter(|v| *v > 0.0)
        .ok_or_else(|| el.error(format!("focal_length '{text}' is not a length like 50mm")))?;
    let diagonal = (36.0f32 * 36.0 + 24.0 * 24.0).sqrt();
    Ok(2.0 * (diagonal / (2.0 * mm)).atan().to_degrees())
}

/// The radiance of a shape's nested `area` emitter, if it has one.
fn area_emission(
    p: &Props,
    textures: &mut textures::Textures,
    loader: &Loader<'_>,
) -> Result<Option<(Vec3, Option<u32>)>, SceneError> {
    let mut emission = None;
    let mut emitters = 0;
    for e in p.nested("emitter") {
        emitters += 1;
        if emitters > 1 {
            return Err(e.error("a shape has one emitter, as in Mitsuba"));
        }
        if e.plugin()? == "directionalarea" {
            // It emits along its normal alone, a direction no path from
            // the camera meets: Mitsuba's `path` never sees it either.
            let ep = Props::new(e);
            if ep.transform("to_world")?.is_some() {
                return Err(e.error(
                    "a directionalarea emitter takes its shape's to_world, not its own (as in Mitsuba)",
                ));
            }
            ep.textures();
            ep.ignore("radiance");
            ep.ignore("sampling_weight");
            ep.finish()?;
            log::warn!(
                "{}:{}: a directionalarea emitter emits only along its shape's normal, which no path from the camera meets: it adds no light (as in Mitsuba's path integrator)",
                e.file.display(),
                e.line
            );
            continue;
        }
        if e.plugin()? != "area" {
            return Err(e.error(format!(
                "{} inside a shape: a shape emits with 'area' (or 'directionalarea')",
                plugin_name(e)
            )));
        }
        let ep = Props::new(e);
        ep.ignore("sampling_weight");
        // A radiance texture: its mean weighs the light for NEE's choice.
        let given =
            textures.given(e, &ep, "area", loader)?[crate::shaders::TEXTURE_SLOT_COLOR as usize];
        let radiance = match given {
            Some((_, mean)) => mean,
            None => ep
                .radiance("radiance")?
                .ok_or_else(|| e.error("emitter 'area' needs a radiance"))?,
        };
        if radiance.min_element() < 0.0 {
            return Err(e.error("the area emitter's radiance is negative"));
        }
        ep.finish()?;
        emission = Some((radiance, given.map(|(i, _)| i)));
    }
    Ok(emission)
}

/// A rough BSDF's `alpha` (or `alpha_u` and `alpha_v`, rendered isotropic
/// with a warning) and `distribution`, Mitsuba's defaults 0.1 and Beckmann.
/// A rough BSDF's alpha (along the surface's tangent where `alpha_u` and
/// `alpha_v` differ, then with the alpha across it) and distribution.
fn roughness(el: &Element, p: &Props) -> Result<(f32, Option<f32>, Distribution), SceneError> {
    let distribution = match p.string("distribution")?.unwrap_or("beckmann") {
        "beckmann" => Distribution::Beckmann,
        "ggx" => Distribution::Ggx,
        other => return Err(el.error(format!("distribution '{other}' is not beckmann or ggx"))),
    };
    // Sampling visible normals or all of them changes noise only.
    p.ignore("sample_visible");
    // A roughness given as a texture (roughconductor's) takes the
    // texture's mean here (Surface::with_means); 0.1 holds its place. A
    // colour or spectrum is a texture to Mitsuba, which reads a roughness
    // from it as the mean of its channels.
    let textured = |name: &str| {
        el.children
            .iter()
            .any(|c| (c.tag == "texture" || c.tag == "ref") && c.attr("name") == Some(name))
    };
    let value = |name: &str| -> Result<Option<f32>, SceneError> {
        Ok(p.mean_number(name)?.or(textured(name).then_some(0.1)))
    };
    let (u, v) = (value("alpha_u")?, value("alpha_v")?);
    let (a, across) = match (value("alpha")?, u, v) {
        (Some(a), None, None) => (a, None),
        (None, None, None) => (0.1, None),
        (None, Some(u), Some(v)) if u == v && !textured("alpha_u") && !textured("alpha_v") => {
            (u, None)
        }
        (None, Some(u), Some(v)) => (u, Some(v)),
        _ => return Err(el.error("give alpha, or alpha_u and alpha_v together, not both")),
    };
    for a in std::iter::once(a).chain(across) {
        if !(a > 0.0 && a <= 1.0) {
            return Err(el.error(format!("alpha {a} must lie in (0, 1]")));
        }
    }
    Ok((a, across, distribution))
}

/// A `conductor` or `roughconductor`: its Fresnel term (a named metal, or
/// eta and k), reflectance and roughness.
fn conductor(el: &Element, p: &Props, kind: &str) -> Result<Surface, SceneError> {
    let material = p.string("material")?;
    let (eta, k) = (p.color("eta")?, p.color("k")?);
    // Mitsuba's default, and material "none", is η 0, k 1: a
    // Fresnel term of 1 at every angle.
    let fresnel = match (material, eta, k) {
        (None | Some("none"), None, None) => None,
        (Some(name), None, None) => {
            let Some((_, eta, k)) = CONDUCTOR_TABLE.iter().find(|(n, _, _)| *n == name) else {
                return Err(el.error(format!(
                    "{kind} material '{name}' is not one of Mitsuba's conductors"
                )));
            };
            Some(ComplexIor {
                eta: Vec3::from(*eta),
                k: Vec3::from(*k),
            })
        }
        (Some(name), _, _) => {
            return Err(el.error(format!(
                "{kind}: give material '{name}' or eta and k, not both"
            )))
        }
        (None, eta, k) => {
            let eta = eta.unwrap_or(Vec3::ZERO);
            let k = k.unwrap_or(Vec3::ONE);
            if eta.min_element() < 0.0 || k.min_element() < 0.0 {
                return Err(el.error(format!("{kind}: eta and k must be non-negative")));
            }
            Some(ComplexIor { eta, k })
        }
    };
    let reflectance = reflectance(el, p, "specular_reflectance", 1.0)?;
    let (alpha, alpha_v, distribution) = if kind == "roughconductor" {
        roughness(el, p)?
    } else {
        (0.0, None, Distribution::Ggx)
    };
    Ok(Surface::Conductor {
        reflectance,
        alpha,
        alpha_v,
        distribution,
        fresnel,
    })
}

/// A rough interface between equal indices bends nothing: every
/// microfacet passes light straight on, a delta lobe no rough model has
/// (Mitsuba refuses it too).
fn distinct_iors(el: &Element, kind: &str, int: f32, ext: f32) -> Result<(), SceneError> {
    if int == ext {
        return Err(el.error(format!(
            "{kind}: int_ior and ext_ior are both {int}; they must differ"
        )));
    }
    Ok(())
}

/// A `roughplastic`: `plastic` under a microfacet coat.
fn rough_plastic(el: &Element, p: &Props) -> Result<Surface, SceneError> {
    let int = ior(el, p, "int_ior", "polypropylene")?;
    let ext = ior(el, p, "ext_ior", "air")?;
    distinct_iors(el, "roughplastic", int, ext)?;
    if p.float("alpha_u")?.is_some() || p.float("alpha_v")?.is_some() {
        return Err(el.error(
            "roughplastic is isotropic (as in Mitsuba): give alpha, not alpha_u and alpha_v",
        ));
    }
    let (alpha, _, distribution) = roughness(el, p)?;
    let diffuse = reflectance(el, p, "diffuse_reflectance", 0.5)?;
    let specular = p.color("specular_reflectance")?.unwrap_or(Vec3::ONE);
    if specular.min_element() < 0.0 {
        return Err(el.error("roughplastic specular_reflectance must not be negative"));
    }
    let eta = int / ext;
    Ok(Surface::RoughPlastic {
        diffuse,
        specular,
        eta,
        nonlinear: p.boolean("nonlinear")?.unwrap_or(false),
        alpha,
        distribution,
        table: crate::bsdf::RoughTable::new(eta, alpha, distribution),
    })
}

/// A `principled` as Mitsuba reads it (each weight in [0, 1]), or its
/// thin sibling `principledthin` (`thin`: no metallic, clearcoat or
/// `specular`; `diff_trans` in [0, 2]).
fn principled(el: &Element, p: &Props, thin: bool) -> Result<Surface, SceneError> {
    let kind = if thin { "principledthin" } else { "principled" };
    // Mitsuba reads each as a texture's eval_1: a colour by its mean.
    let ranged = |name: &str, default: f32, most: f32| -> Result<f32, SceneError> {
        let v = p.mean_number(name)?.unwrap_or(default);
        if !(0.0..=most).contains(&v) {
            return Err(el.error(format!("{kind} {name} {v} must lie in [0, {most}]")));
        }
        Ok(v)
    };
    let weight = |name: &str, default: f32| ranged(name, default, 1.0);
    let spec_trans = weight("spec_trans", 0.0)?;
    // A texture's spec_trans refracts where it is above 0.
    let transmits = spec_trans > 0.0
        || el.children.iter().any(|c| {
            (c.tag == "texture" || c.tag == "ref") && c.attr("name") == Some("spec_trans")
        });
    let anisotropic = weight("anisotropic", 0.0)?;
    let roughness = weight("roughness", 0.5)?;
    let eta = if thin {
        positive(el, "eta", p.mean_number("eta")?.unwrap_or(1.5))?
    } else {
        match (p.float("eta")?, p.float("specular")?) {
            (Some(_), Some(_)) => {
                return Err(el.error("principled: give eta or specular, not both (as in Mitsuba)"))
            }
            // Mitsuba moves an index of 1, which refracts nothing, off 1
            // where the BSDF refracts.
            (Some(eta), None) if eta == 1.0 && transmits => 1.001,
            (Some(eta), None) => positive(el, "eta", eta)?,
            (None, specular) => {
                let s = match specular.unwrap_or(0.5) {
                    0.0 if transmits => 1e-3,
                    s => s,
                };
                if !(0.0..12.5).contains(&s) {
                    return Err(el.error(format!(
                        "principled specular {s} must lie in [0, 12.5) (an index of refraction)"
                    )));
                }
                2.0 / (1.0 - (0.08 * s).sqrt()) - 1.0
            }
        }
    };
    // How often Mitsuba samples each lobe: no part of the image.
    let rates: &[&str] = if thin {
        &[
            "diffuse_reflectance_sampling_rate",
            "specular_reflectance_sampling_rate",
            "specular_transmittance_sampling_rate",
            "diffuse_transmittance_sampling_rate",
        ]
    } else {
        &[
            "diffuse_reflectance_sampling_rate",
            "main_specular_sampling_rate",
            "clearcoat_sampling_rate",
        ]
    };
    for rate in rates {
        p.float(rate)?;
    }
    let thick = |name: &str, default: f32| {
        if thin {
            Ok(0.0)
        } else {
            weight(name, default)
        }
    };
    Ok(Surface::Principled {
        base_color: reflectance(el, p, "base_color", 0.5)?,
        params: crate::bsdf::Principled {
            roughness,
            metallic: thick("metallic", 0.0)?,
            specular_tint: weight("spec_tint", 0.0)?,
            sheen: weight("sheen", 0.0)?,
            sheen_tint: weight("sheen_tint", 0.0)?,
            flatness: weight("flatness", 0.0)?,
            clearcoat: thick("clearcoat", 0.0)?,
            clearcoat_gloss: thick("clearcoat_gloss", 0.0)?,
            spec_trans,
            anisotropic,
            eta,
            thin: if thin {
                Some(0.5 * ranged("diff_trans", 0.0, 2.0)?)
            } else {
                None
            },
        },
    })
}

/// Mitsuba's `null` as its path tracer treats it: paths pass straight
/// through (a bounce of a delta lobe, counted in the depth), shadow rays
/// stop at it.
fn null_bsdf() -> BsdfDesc {
    BsdfDesc {
        name: "null".into(),
        surface: Surface::Thin {
            eta: 1.0,
            reflectance: Vec3::ZERO,
            transmittance: Vec3::ONE,
        },
        one_sided: false,
        null: true,
        textures: [None; crate::scene::TEXTURE_SLOTS],
        normal_map: None,
        choice: None,
    }
}

/// A `<bsdf>` element as qtrace renders it.
fn bsdf(
    el: &Element,
    tex: &mut textures::Textures,
    loader: &Loader<'_>,
) -> Result<BsdfDesc, SceneError> {
    let kind = el.plugin()?;
    let p = Props::new(el);
    let mut given = tex.given(el, &p, kind, loader)?;
    let name = el.attr("id").unwrap_or(kind).to_string();
    let one = |surface: Surface| BsdfDesc {
        name: name.clone(),
        surface,
        one_sided: true,
        null: false,
        textures: [None; crate::scene::TEXTURE_SLOTS],
        normal_map: None,
        choice: None,
    };
    // A choice between BSDFs a and b, its own surface black (unused).
    let choose = |kind: ChoiceKind, first: BsdfDesc, second: BsdfDesc| BsdfDesc {
        choice: Some(Box::new(ChoiceDesc {
            kind,
            first,
            second,
        })),
        ..one(Surface::Diffuse { albedo: Vec3::ZERO })
    };
    let desc = match kind {
        "twosided" => {
            let inner = p.nested("bsdf");
            if !(1..=2).contains(&inner.len()) {
                return Err(el.error("twosided needs one or two nested <bsdf>"));
            }
            let mut sides = Vec::new();
            for b in inner {
                let mut d = bsdf(b, tex, loader)?;
                if d.transmits() {
                    return Err(b.error(
                        "twosided takes only BSDFs that let no light through (as in Mitsuba)",
                    ));
                }
                d.two_sided();
                sides.push(d);
            }
            let front = sides.remove(0);
            match sides.pop() {
                // Each BSDF sees its side as its front, as in Mitsuba.
                Some(back) => choose(ChoiceKind::Sides, front, back),
                None => BsdfDesc {
                    name: name.clone(),
                    ..front
                },
            }
        }
        "mask" | "blendbsdf" => {
            let (param, default) = if kind == "mask" {
                ("opacity", 0.5)
            } else {
                ("weight", 0.5)
            };
            // Mitsuba clamps the weight to [0, 1] where it reads it.
            let slot = crate::shaders::TEXTURE_SLOT_COLOR as usize;
            let weight = match given[slot].take() {
                Some((t, _)) => Weight::Texture(t),
                None => Weight::Constant(p.mean_number(param)?.unwrap_or(default).clamp(0.0, 1.0)),
            };
            let inner = p.nested("bsdf");
            match (kind, &inner[..]) {
                ("mask", [b]) => {
                    let null = BsdfDesc {
                        name: format!("{name} (clear)"),
                        ..null_bsdf()
                    };
                    choose(ChoiceKind::Mask { opacity: weight }, null, bsdf(b, tex, loader)?)
                }
                ("blendbsdf", [a, b]) => {
                    let (a, b) = (bsdf(a, tex, loader)?, bsdf(b, tex, loader)?);
                    if a.has_delta_lobe() || b.has_delta_lobe() {
                        // Measured: a smooth plastic's coat 1.7x as bright
                        // in a 0.6 blend with diffuse.
                        log::warn!(
                            "{}:{}: a blendbsdf of a smooth (delta) lobe: Mitsuba 3.9.1 samples that lobe as if mixed with the other BSDF's density and overstates it; qtrace blends the two exactly, so the surface renders darker than in Mitsuba",
                            el.file.display(),
                            el.line
                        );
                    }
                    choose(ChoiceKind::Blend { weight }, a, b)
                }
                ("mask", _) => return Err(el.error("mask needs one nested <bsdf>")),
                _ => return Err(el.error("blendbsdf needs two nested <bsdf>")),
            }
        }
        "diffuse" => one(Surface::Diffuse {
            albedo: reflectance(el, &p, "reflectance", 0.5)?,
        }),
        "conductor" | "roughconductor" => one(conductor(el, &p, kind)?),
        "dielectric" => {
            let int = ior(el, &p, "int_ior", "bk7")?;
            let ext = ior(el, &p, "ext_ior", "air")?;
            let transmittance = reflectance(el, &p, "specular_transmittance", 1.0)?;
            let mut d = one(Surface::Dielectric {
                ior: int / ext,
                transmittance,
                reflectance: reflectance(el, &p, "specular_reflectance", 1.0)?,
            });
            d.one_sided = false;
            d
        }
        "null" => BsdfDesc {
            name: name.clone(),
            ..null_bsdf()
        },
        "plastic" => {
            let int = ior(el, &p, "int_ior", "polypropylene")?;
            let ext = ior(el, &p, "ext_ior", "air")?;
            let diffuse = reflectance(el, &p, "diffuse_reflectance", 0.5)?;
            let specular = p.color("specular_reflectance")?.unwrap_or(Vec3::ONE);
            if specular.min_element() < 0.0 {
                return Err(el.error("plastic specular_reflectance must not be negative"));
            }
            one(Surface::Plastic {
                diffuse,
                specular,
                eta: int / ext,
                nonlinear: p.boolean("nonlinear")?.unwrap_or(false),
            })
        }
        "thindielectric" => {
            let int = ior(el, &p, "int_ior", "bk7")?;
            let ext = ior(el, &p, "ext_ior", "air")?;
            let mut d = one(Surface::Thin {
                eta: int / ext,
                reflectance: reflectance(el, &p, "specular_reflectance", 1.0)?,
                transmittance: reflectance(el, &p, "specular_transmittance", 1.0)?,
            });
            d.one_sided = false;
            d
        }
        "roughdielectric" => {
            let int = ior(el, &p, "int_ior", "bk7")?;
            let ext = ior(el, &p, "ext_ior", "air")?;
            distinct_iors(el, kind, int, ext)?;
            let (alpha, alpha_v, distribution) = roughness(el, &p)?;
            let mut d = one(Surface::RoughDielectric {
                ior: int / ext,
                reflectance: reflectance(el, &p, "specular_reflectance", 1.0)?,
                transmittance: reflectance(el, &p, "specular_transmittance", 1.0)?,
                alpha,
                alpha_v,
                distribution,
            });
            d.one_sided = false;
            d
        }
        "roughplastic" => one(rough_plastic(el, &p)?),
        "principled" | "principledthin" => {
            // Where it lets light through, its back is its dielectric's; a
            // thin one is the same on both sides.
            let thin = kind == "principledthin";
            let surface = principled(el, &p, thin)?;
            BsdfDesc {
                one_sided: !thin && !surface.rough_transmission(),
                ..one(surface)
            }
        }
        "normalmap" | "bumpmap" => {
            // The texture is the normals' (or the heights'), not a colour
            // of the BSDF's.
            let slot = crate::shaders::TEXTURE_SLOT_COLOR as usize;
            let Some((texture, _)) = given[slot].take() else {
                return Err(el.error(if kind == "normalmap" {
                    "normalmap needs a texture named 'normalmap'"
                } else {
                    "bumpmap needs a nested <texture>, its height field"
                }));
            };
            let bump = if kind == "bumpmap" {
                Some(p.float("scale")?.unwrap_or(1.0))
            } else {
                None
            };
            let inner = p.nested("bsdf");
            let [b] = inner[..] else {
                return Err(el.error(format!("{kind} needs one nested <bsdf>")));
            };
            let mut d = bsdf(b, tex, loader)?;
            if d.null {
                return Err(b.error(format!("a {kind} around a null BSDF is not supported")));
            }
            let map = NormalMap {
                texture,
                in_twosided: false,
                bump,
            };
            d.map_normals(b, map)?;
            d
        }
        "pplastic" | "hair" | "measured" | "polarizer" | "retarder" | "circular" => {
            return Err(el.error(format!(
                "bsdf '{kind}' is not supported; qtrace has diffuse, conductor, roughconductor, dielectric, roughdielectric, thindielectric, plastic, roughplastic, principled, principledthin, twosided, normalmap, bumpmap, mask, blendbsdf and null"
            )))
        }
        other => return Err(el.error(format!("'{other}' is not a Mitsuba 3 BSDF"))),
    };
    p.finish()?;
    if desc.choice_depth() > crate::shaders::MAX_CHOICE_DEPTH {
        return Err(el.error(format!(
            "masks, blends and two-faced twosided nest at most {} deep in qtrace",
            crate::shaders::MAX_CHOICE_DEPTH
        )));
    }
    let mut desc = desc;
    if given.iter().any(Option::is_some) {
        let mean = |s: u32| given[s as usize].map(|(_, m)| m);
        desc.surface = desc.surface.with_means(
            mean(crate::shaders::TEXTURE_SLOT_COLOR),
            mean(crate::shaders::TEXTURE_SLOT_SECOND),
            mean(crate::shaders::TEXTURE_SLOT_ALPHA)
                .map(|a| crate::bsdf::luminance(a).clamp(1e-4, 1.0)),
            mean(crate::shaders::TEXTURE_SLOT_ACROSS)
                .map(|a| crate::bsdf::luminance(a).clamp(1e-4, 1.0)),
        );
        desc.surface = desc
            .surface
            .with_weight_means(|s| mean(s).map(crate::bsdf::luminance));
        desc.textures = given.map(|g| g.map(|(i, _)| i));
        // A principled material whose spec_trans is a texture lets light
        // through: its back is its dielectric's.
        if matches!(desc.surface, Surface::Principled { params, .. } if params.thin.is_none())
            && desc.surface.rough_transmission()
        {
            desc.one_sided = false;
        }
    }
    Ok(desc)
}

/// The unit axes of a light's to_world, which must place it without a
/// stretch or shear (a spot's cone would turn elliptical in Mitsuba, and a
/// projector's image), or, `uniform`, any scale.
fn rigid_axes(
    el: &Element,
    kind: &str,
    to_world: Mat4,
    uniform: bool,
) -> Result<[Vec3; 3], SceneError> {
    let axes = [to_world.x_axis, to_world.y_axis, to_world.z_axis].map(|a| a.truncate());
    let scale = if uniform { axes[2].length() } else { 1.0 };
    let unit = axes.map(|a| a / scale);
    let [x, y, z] = unit;
    let rigid = scale > 0.0
        && unit.iter().all(|a| (a.length() - 1.0).abs() < 1e-3)
        && x.dot(y).abs() < 1e-3
        && y.dot(z).abs() < 1e-3
        && z.dot(x).abs() < 1e-3;
    if !rigid {
        return Err(el.error(if uniform {
            format!("{kind}: its to_world must not stretch or shear (Mitsuba's cone would turn elliptical); rotations, a lookat and a uniform scale place it")
        } else {
            format!("{kind}: its to_world must not scale or shear where it casts an image (rotations and a lookat place it)")
        }));
    }
    Ok(unit)
}

/// An environment's to_world as a rotation: a mirror turns the sky over as
/// Mitsuba does; a scale would leave Mitsuba looking the sky up by an
/// unnormalized direction.
fn sky_rotation(el: &Element, to_world: Mat4) -> Result<glam::Mat3, SceneError> {
    let rotation = glam::Mat3::from_mat4(to_world);
    let orthonormal = (rotation * rotation.transpose() - glam::Mat3::IDENTITY)
        .to_cols_array()
        .iter()
        .all(|v| v.abs() < 1e-4);
    if !orthonormal {
        return Err(el.error(format!(
            "the {}'s to_world must be a rotation, or a rotation and a mirror (Mitsuba looks the sky up by a direction a scale would stretch)",
            el.attr("type").unwrap_or("sky")
        )));
    }
    Ok(rotation)
}

/// A `sunsky` element's parameters, with Mitsuba's defaults and checks.
fn sunsky_settings(p: &Props, rotation: glam::Mat3) -> Result<sunsky::Settings, SceneError> {
    let el = p.el;
    const WHEN: [&str; 9] = [
        "latitude",
        "longitude",
        "timezone",
        "year",
        "month",
        "day",
        "hour",
        "minute",
        "second",
    ];
    let sun = match p.point("sun_direction")? {
        Some(d) => {
            if let Some(name) = WHEN
                .iter()
                .find(|n| el.children.iter().any(|c| c.attr("name") == Some(**n)))
            {
                return Err(el.error(format!(
                    "sunsky takes sun_direction or a place and time ('{name}'), not both, as in Mitsuba"
                )));
            }
            // Given in the world; the model works in the emitter's frame.
            let local = rotation.inverse() * d;
            local
                .try_normalize()
                .ok_or_else(|| el.error("sunsky's sun_direction is zero"))?
                .as_dvec3()
        }
        None => {
            let d = sunsky::When::default();
            // Mitsuba's are 32-bit integers.
            let int = |name: &str, default: i64| -> Result<i64, SceneError> {
                let v = p.integer(name)?.unwrap_or(default);
                if i32::try_from(v).is_err() {
                    return Err(el.error(format!("sunsky {name} {v} is not a 32-bit integer")));
                }
                Ok(v)
            };
            let when = sunsky::When {
                latitude: p.float_or("latitude", d.latitude as f32)? as f64,
                longitude: p.float_or("longitude", d.longitude as f32)? as f64,
                timezone: p.float_or("timezone", d.timezone)?,
                year: int("year", d.year)?,
                month: int("month", d.month)?,
                day: int("day", d.day)?,
                hour: p.float_or("hour", d.hour)?,
                minute: p.float_or("minute", d.minute)?,
                second: p.float_or("second", d.second)?,
            };
            when.sun()
        }
    };
    let turbidity = p.float_or("turbidity", 3.0)?;
    if !(1.0..=10.0).contains(&turbidity) {
        return Err(el.error(format!(
            "sunsky turbidity {turbidity} is outside [1, 10], as in Mitsuba"
        )));
    }
    let albedo = p.color("albedo")?.unwrap_or(Vec3::splat(0.3));
    if albedo.min_element() < 0.0 || albedo.max_element() > 1.0 {
        return Err(el.error(format!(
            "sunsky albedo {albedo} is outside [0, 1], as in Mitsuba"
        )));
    }
    let scale = |name: &str| -> Result<f64, SceneError> {
        let v = p.float_or(name, 1.0)?;
        if !(v >= 0.0 && v.is_finite()) {
            return Err(el.error(format!("sunsky {name} {v} must be finite and non-negative")));
        }
        Ok(v as f64)
    };
    let (sun_scale, sky_scale) = (scale("sun_scale")?, scale("sky_scale")?);
    let sun_aperture = p.float_or("sun_aperture", 0.5358)?;
    if !(sun_aperture > 0.0 && sun_aperture < 180.0) {
        return Err(el.error(format!(
            "sunsky sun_aperture {sun_aperture} must lie in (0, 180) degrees"
        )));
    }
    Ok(sunsky::Settings {
        sun,
        turbidity: turbidity as f64,
        albedo: albedo.as_dvec3().to_array(),
        sun_scale,
        sky_scale,
        sun_aperture,
        complex_sun: p.boolean("complex_sun")?.unwrap_or(false),
    })
}
