//! Mitsuba's `<texture>` plugins (`bitmap`, `checkerboard`,
//! `mesh_attribute`), given nested in a BSDF or at the top level with an id
//! and named by `<ref>`.

use super::xml::{Element, Props};
use super::{Loader, SceneError};
use crate::scene::texture::{Filter, Pattern, Texture, Wrap};
use crate::shaders::{
    TEXTURE_SLOT_ACROSS, TEXTURE_SLOT_ALPHA, TEXTURE_SLOT_ANISOTROPIC, TEXTURE_SLOT_BITS,
    TEXTURE_SLOT_CLEARCOAT, TEXTURE_SLOT_CLEARCOAT_GLOSS, TEXTURE_SLOT_COLOR,
    TEXTURE_SLOT_FLATNESS, TEXTURE_SLOT_HIGHLIGHT_TINT, TEXTURE_SLOT_SECOND, TEXTURE_SLOT_SHEEN,
    TEXTURE_SLOT_SHEEN_TINT, TEXTURE_SLOT_TRANSMISSION,
};
use glam::{Mat3, Vec3};
use std::collections::HashMap;

/// The scene's textures: those declared at the top level by id, and those
/// its materials use, each once, in the order the device holds them.
#[derive(Default)]
pub struct Textures {
    pub used: Vec<Texture>,
    declared: HashMap<String, Texture>,
    /// Where a texture (by what it reads and how) sits in `used`.
    index: HashMap<String, u32>,
}

/// The BSDF (or area emitter) parameters a texture may give, and the
/// material slot it fills.
pub fn slots(kind: &str) -> &'static [(&'static str, u32)] {
    const COLOR: u32 = TEXTURE_SLOT_COLOR;
    const SECOND: u32 = TEXTURE_SLOT_SECOND;
    const ALPHA: u32 = TEXTURE_SLOT_ALPHA;
    const ACROSS: u32 = TEXTURE_SLOT_ACROSS;
    match kind {
        "diffuse" => &[("reflectance", COLOR)],
        "conductor" => &[("specular_reflectance", COLOR)],
        // Anisotropic: alpha_u in the alpha slot, alpha_v in the second.
        "roughconductor" => &[
            ("specular_reflectance", COLOR),
            ("alpha", ALPHA),
            ("alpha_u", ALPHA),
            ("alpha_v", SECOND),
        ],
        "dielectric" => &[
            ("specular_transmittance", COLOR),
            ("specular_reflectance", SECOND),
        ],
        "thindielectric" => &[
            ("specular_transmittance", COLOR),
            ("specular_reflectance", SECOND),
        ],
        // Anisotropic: alpha_u in the alpha slot, alpha_v in its own (the
        // second holds the reflectance).
        "roughdielectric" => &[
            ("specular_transmittance", COLOR),
            ("specular_reflectance", SECOND),
            ("alpha", ALPHA),
            ("alpha_u", ALPHA),
            ("alpha_v", ACROSS),
        ],
        "plastic" | "roughplastic" => &[
            ("diffuse_reflectance", COLOR),
            ("specular_reflectance", SECOND),
        ],
        // Read as numbers: all but the base colour.
        "principled" => &[
            ("base_color", COLOR),
            ("metallic", SECOND),
            ("roughness", ALPHA),
            ("spec_tint", TEXTURE_SLOT_HIGHLIGHT_TINT),
            ("sheen", TEXTURE_SLOT_SHEEN),
            ("sheen_tint", TEXTURE_SLOT_SHEEN_TINT),
            ("flatness", TEXTURE_SLOT_FLATNESS),
            ("clearcoat", TEXTURE_SLOT_CLEARCOAT),
            ("clearcoat_gloss", TEXTURE_SLOT_CLEARCOAT_GLOSS),
            ("anisotropic", TEXTURE_SLOT_ANISOTROPIC),
            ("spec_trans", TEXTURE_SLOT_TRANSMISSION),
        ],
        // Its diffuse transmission in metallic's place.
        "principledthin" => &[
            ("base_color", COLOR),
            ("diff_trans", SECOND),
            ("roughness", ALPHA),
            ("spec_tint", TEXTURE_SLOT_HIGHLIGHT_TINT),
            ("sheen", TEXTURE_SLOT_SHEEN),
            ("sheen_tint", TEXTURE_SLOT_SHEEN_TINT),
            ("flatness", TEXTURE_SLOT_FLATNESS),
            ("anisotropic", TEXTURE_SLOT_ANISOTROPIC),
            ("spec_trans", TEXTURE_SLOT_TRANSMISSION),
        ],
        // A normal map's texture, and a mask's or blend's weight, which
        // they keep apart from the slots.
        "normalmap" => &[("normalmap", COLOR)],
        "bumpmap" => &[("height field", COLOR)],
        "mask" => &[("opacity", COLOR)],
        "blendbsdf" => &[("weight", COLOR)],
        // An emitter's material: paths end there, so its colour slot holds
        // the radiance.
        "area" => &[("radiance", COLOR)],
        // A projector's image, and a spot light's.
        "projector" => &[("irradiance", COLOR)],
        "spot" => &[("texture", COLOR)],
        _ => &[],
    }
}

/// What textures give a BSDF: per slot, the texture's index and mean.
pub type Given = [Option<(u32, Vec3)>; crate::scene::TEXTURE_SLOTS];

impl Textures {
    /// A top-level `<texture id>`.
    pub fn declare(&mut self, el: &Element, loader: &Loader<'_>) -> Result<(), SceneError> {
        let id = el
            .attr("id")
            .ok_or_else(|| el.error("a top-level <texture> needs an id"))?;
        let t = read(el, loader)?;
        self.declared.insert(id.to_string(), t);
        Ok(())
    }

    /// The textures BSDF `el` (of plugin `kind`) is given, its parameters
    /// marked used in `p`; a texture where `kind` takes none is an error.
    pub fn given(
        &mut self,
        el: &Element,
        p: &Props,
        kind: &str,
        loader: &Loader<'_>,
    ) -> Result<Given, SceneError> {
        let mut out: Given = [None; crate::scene::TEXTURE_SLOTS];
        for c in p.textures() {
            let name = c.required("name")?;
            // A bump map's height field may have any name.
            let bump = kind == "bumpmap";
            let Some(&(_, slot)) = slots(kind).iter().find(|(n, _)| *n == name || bump) else {
                let takes: Vec<&str> = slots(kind).iter().map(|(n, _)| *n).collect();
                return Err(c.error(format!(
                    "{kind}'s '{name}' cannot be a texture in qtrace ({})",
                    if takes.is_empty() {
                        format!("{kind} takes none")
                    } else {
                        format!("{kind} takes one for {}", takes.join(", "))
                    }
                )));
            };
            let texture = if c.tag == "ref" {
                let id = c.required("id")?;
                self.declared.get(id).cloned().ok_or_else(|| {
                    c.error(format!(
                        "no texture has the id '{id}' (a texture must come before the BSDFs that use it)"
                    ))
                })?
            } else {
                read(c, loader)?
            };
            if bump && matches!(texture.pattern, Pattern::Checkerboard { .. }) {
                return Err(c.error(
                    "a bumpmap's height field must be a bitmap (Mitsuba takes no checkerboard's gradient)",
                ));
            }
            if let Pattern::Attribute { name: a, .. } = &texture.pattern {
                // Mitsuba has no mean of a mesh attribute (which its
                // plastics weigh their lobes by) and no gradient.
                if matches!(
                    kind,
                    "plastic" | "roughplastic" | "normalmap" | "bumpmap" | "projector" | "spot"
                ) {
                    return Err(c.error(format!(
                        "{kind}'s '{name}' cannot be a mesh attribute ('{a}'), as in Mitsuba"
                    )));
                }
            }
            if bump && out[slot as usize].is_some() {
                return Err(c.error("a bumpmap takes one texture"));
            }
            let number = slot == TEXTURE_SLOT_ALPHA
                || slot >= TEXTURE_SLOT_ACROSS
                || matches!(kind, "mask" | "blendbsdf")
                || (matches!(kind, "principled" | "principledthin" | "roughconductor")
                    && slot == TEXTURE_SLOT_SECOND);
            let texture = if number {
                read_as_number(texture)
            } else {
                texture
            };
            out[slot as usize] = Some(self.add(el, texture)?);
        }
        Ok(out)
    }

    /// Index and mean of a texture, added where it is new.
    fn add(&mut self, el: &Element, t: Texture) -> Result<(u32, Vec3), SceneError> {
        let mean = t.mean();
        let key = format!("{}|{:?}|{:?}", t.name, t.to_uv, pattern_key(&t.pattern));
        if let Some(&i) = self.index.get(&key) {
            return Ok((i, mean));
        }
        let i = self.used.len() as u32;
        if i + 1 >= 1 << TEXTURE_SLOT_BITS {
            return Err(el.error(format!(
                "the scene uses more than {} textures, the most qtrace holds",
                (1 << TEXTURE_SLOT_BITS) - 2
            )));
        }
        self.used.push(t);
        self.index.insert(key, i);
        Ok((i, mean))
    }
}

/// A texture as Mitsuba 3 reads one number from it (`eval_1`, for an alpha,
/// an opacity or a weight): a bitmap's luminance, as the kernels read it,
/// but a checkerboard's colours swapped, each read as its channels' mean
/// (measured in Mitsuba 3.9.1, unlike its colour lookup).
fn read_as_number(mut t: Texture) -> Texture {
    if let Pattern::Attribute { number, .. } = &mut t.pattern {
        *number = true;
    }
    if let Pattern::Checkerboard { color0, color1 } = t.pattern {
        let mean = |c: Vec3| Vec3::splat(c.element_sum() / 3.0);
        t.pattern = Pattern::Checkerboard {
            color0: mean(color1),
            color1: mean(color0),
        };
    }
    t
}

/// What tells two textures of one file apart (their texels are the same).
fn pattern_key(p: &Pattern) -> String {
    match p {
        Pattern::Bitmap {
            filter,
            wrap,
            texels,
            ..
        } => format!(
            "{filter:?} {wrap:?} {}",
            matches!(
                texels,
                crate::scene::texture::Texels::Bytes { srgb: true, .. }
            )
        ),
        Pattern::Checkerboard { color0, color1 } => format!("{color0} {color1}"),
        Pattern::Attribute {
            name,
            scale,
            number,
            ..
        } => format!("{name} {scale} {number}"),
    }
}

/// Image file `file` (relative to `el`'s scene file) as a bitmap; `what`
/// names it in errors.
pub fn read_image(
    el: &Element,
    loader: &Loader<'_>,
    (what, file): (&str, &str),
    filter: Filter,
    wrap: Wrap,
    raw: bool,
) -> Result<Pattern, SceneError> {
    let unreadable = |e: String| el.error(format!("cannot read the {what} '{file}': {e}"));
    let (path, bytes) = el
        .read_file(loader, file)
        .map_err(|e| unreadable(e.to_string()))?;
    Texture::bitmap_from_bytes(&path, &bytes, filter, wrap, raw).map_err(unreadable)
}

/// A `<texture>` element.
fn read(el: &Element, loader: &Loader<'_>) -> Result<Texture, SceneError> {
    let kind = el.plugin()?;
    let p = Props::new(el);
    // Mitsuba's to_uv is a 4x4 transform of which (u, v) sees the x and y
    // rows and the translation.
    let m = p.transform("to_uv")?.unwrap_or(glam::Mat4::IDENTITY);
    let (c0, c1, c3) = (m.col(0), m.col(1), m.col(3));
    let to_uv = Mat3::from_cols(
        Vec3::new(c0.x, c0.y, c0.w),
        Vec3::new(c1.x, c1.y, c1.w),
        Vec3::new(c3.x, c3.y, c3.w),
    );
    let texture = match kind {
        "bitmap" => {
            let file = p
                .string("filename")?
                .ok_or_else(|| el.error("bitmap needs a filename"))?;
            let filter = match p.string("filter_type")?.unwrap_or("bilinear") {
                "bilinear" => Filter::Bilinear,
                "nearest" => Filter::Nearest,
                other => {
                    return Err(
                        el.error(format!("filter_type '{other}' is not bilinear or nearest"))
                    )
                }
            };
            let wrap = match p.string("wrap_mode")?.unwrap_or("repeat") {
                "repeat" => Wrap::Repeat,
                "mirror" => Wrap::Mirror,
                "clamp" => Wrap::Clamp,
                other => {
                    return Err(el.error(format!(
                        "wrap_mode '{other}' is not repeat, mirror or clamp"
                    )))
                }
            };
            let raw = p.boolean("raw")?.unwrap_or(false);
            // How Mitsuba speeds its own lookups up, and the precision it
            // stores texels in (`format`: half floats round an 8-bit texel
            // by at most 0.05%): no change to the image worth a refusal.
            p.ignore("accel");
            p.ignore("format");
            let pattern = read_image(el, loader, ("texture", file), filter, wrap, raw)?;
            Texture {
                name: file.to_string(),
                pattern,
                to_uv,
            }
        }
        "mesh_attribute" => {
            if m != glam::Mat4::IDENTITY {
                return Err(el.error("mesh_attribute takes no to_uv"));
            }
            let name = p
                .string("name")?
                .ok_or_else(|| el.error("mesh_attribute needs a name"))?;
            if !(name.starts_with("vertex_") || name.starts_with("face_")) {
                return Err(el.error(format!(
                    "mesh attribute '{name}' must start with 'vertex_' or 'face_' (as in Mitsuba)"
                )));
            }
            let scale = p.float_or("scale", 1.0)?;
            if !scale.is_finite() {
                return Err(el.error(format!("mesh_attribute scale {scale} is not finite")));
            }
            Texture {
                name: format!("mesh attribute '{name}'"),
                pattern: Pattern::Attribute {
                    name: name.to_string(),
                    scale,
                    number: false,
                    slot: 0,
                    stride: 0,
                },
                to_uv,
            }
        }
        "checkerboard" => {
            let color = |name, default| {
                if p.textures().iter().any(|c| c.attr("name") == Some(name)) {
                    return Err(el.error(format!(
                        "checkerboard's {name} must be a colour, not a texture"
                    )));
                }
                Ok(p.color(name)?.unwrap_or(Vec3::splat(default)))
            };
            Texture {
                name: "checkerboard".into(),
                pattern: Pattern::Checkerboard {
                    color0: color("color0", 0.4)?,
                    color1: color("color1", 0.2)?,
                },
                to_uv,
            }
        }
        other => {
            return Err(el.error(format!(
                "texture '{other}' is not supported; qtrace has bitmap, checkerboard and mesh_attribute"
            )))
        }
    };
    p.finish()?;
    if !texture.to_uv.is_finite() {
        return Err(el.error("the texture's to_uv is not finite"));
    }
    Ok(texture)
}
