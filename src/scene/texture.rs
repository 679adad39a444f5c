//! Textures as Mitsuba 3 evaluates them: `bitmap` (bilinear or nearest,
//! repeat, mirror or clamp, 8-bit images turned linear unless `raw`) and
//! `checkerboard`, each behind an optional `to_uv` transform; the CPU
//! twin of glsl/texture.glsl, and the packing of textures for it.

use crate::shaders;
use glam::{Mat3, Vec2, Vec3};
use std::path::Path;

/// How a bitmap interpolates between texels (Mitsuba's `filter_type`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Filter {
    Bilinear,
    Nearest,
}

/// What a lookup outside [0, 1]² reads (Mitsuba's `wrap_mode`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wrap {
    Repeat,
    Mirror,
    Clamp,
}

/// A bitmap's texels as stored, in rows from the image's top.
#[derive(Clone, Debug, PartialEq)]
pub enum Texels {
    /// 8 bits a channel (PNG, JPEG), turned linear at lookup where `srgb`:
    /// a quarter of the device memory of floats.
    Bytes { rgb: Vec<[u8; 3]>, srgb: bool },
    /// Linear values (OpenEXR, Radiance HDR, 16-bit PNG).
    Floats(Vec<Vec3>),
}

impl Texels {
    fn get(&self, i: usize) -> Vec3 {
        match self {
            Texels::Floats(v) => v[i],
            Texels::Bytes { rgb, srgb } => {
                let c = Vec3::from(rgb[i].map(|b| b as f32 / 255.0));
                if *srgb {
                    c.map(srgb_to_linear)
                } else {
                    c
                }
            }
        }
    }

    /// Every texel's linear value, in rows.
    pub fn to_linear(&self) -> Vec<Vec3> {
        (0..self.len()).map(|i| self.get(i)).collect()
    }

    fn len(&self) -> usize {
        match self {
            Texels::Floats(v) => v.len(),
            Texels::Bytes { rgb, .. } => rgb.len(),
        }
    }
}

/// A texture's values over the (u, v) plane.
#[derive(Clone, Debug, PartialEq)]
pub enum Pattern {
    /// Texels in rows from the image's top, which v = 0 reads.
    Bitmap {
        width: usize,
        height: usize,
        texels: Texels,
        filter: Filter,
        wrap: Wrap,
    },
    /// `color0` where the fractional parts of u and v lie on the same side
    /// of one half, else `color1`.
    Checkerboard { color0: Vec3, color1: Vec3 },
    /// Mitsuba's `mesh_attribute`: attribute `name` of the surface's mesh
    /// (`vertex_...`, interpolated across each triangle, or `face_...`)
    /// times `scale`. Its values live with the triangles (the scene's
    /// `attributes`), not here; `number` says whether a BSDF reads one
    /// number from it (Mitsuba's `eval_1`, which takes one channel only);
    /// `slot` is its place among the attributes each triangle holds, and
    /// `stride` their number (the scene's).
    Attribute {
        name: String,
        scale: f32,
        number: bool,
        slot: u32,
        stride: u32,
    },
}

/// A texture and the affine map from a surface's (u, v) to its own.
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    /// How errors name it: its file, or its kind.
    pub name: String,
    pub pattern: Pattern,
    pub to_uv: Mat3,
}

/// The sRGB transfer curve undone.
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// The sRGB transfer curve.
fn linear_to_srgb(c: f32) -> f32 {
    if c <= 0.0031308 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

/// Index `i` of a row or column of `n` texels, wrapped.
/// The four texels of a bitmap around point `p` (in texels, their centres
/// at half integers), wrapped: those at (x, y), (x + 1, y), (x, y + 1) and
/// (x + 1, y + 1), and p's place between them (the CPU twin of
/// `texture_cell`).
fn bilinear_cell(
    texels: &Texels,
    (width, height): (usize, usize),
    wrap: Wrap,
    p: Vec2,
) -> ([Vec3; 4], Vec2) {
    let texel = |x: i64, y: i64| {
        texels.get(wrap_index(y, height, wrap) * width + wrap_index(x, width, wrap))
    };
    let p = p - 0.5;
    let base = p.floor();
    let (x, y) = (base.x as i64, base.y as i64);
    let cell = [
        texel(x, y),
        texel(x + 1, y),
        texel(x, y + 1),
        texel(x + 1, y + 1),
    ];
    (cell, p - base)
}

fn wrap_index(i: i64, n: usize, wrap: Wrap) -> usize {
    let n = n as i64;
    match wrap {
        Wrap::Repeat => i.rem_euclid(n) as usize,
        Wrap::Clamp => i.clamp(0, n - 1) as usize,
        Wrap::Mirror => {
            let m = i.rem_euclid(2 * n);
            (if m >= n { 2 * n - m - 1 } else { m }) as usize
        }
    }
}

impl Texture {
    /// Reads an image file as a bitmap: PNG or JPEG (8 bits a channel,
    /// turned linear unless `raw`), Radiance HDR or OpenEXR (linear).
    pub fn read_bitmap(
        path: &Path,
        filter: Filter,
        wrap: Wrap,
        raw: bool,
    ) -> Result<Pattern, String> {
        let bytes = std::fs::read(path).map_err(|e| e.to_string())?;
        Self::bitmap_from_bytes(path, &bytes, filter, wrap, raw)
    }

    /// A bitmap from the bytes of image file `path` (its extension says
    /// whether it is OpenEXR or Targa; other formats, PNG, JPEG, Radiance
    /// HDR, BMP and PPM/PGM, tell by their contents).
    pub fn bitmap_from_bytes(
        path: &Path,
        bytes: &[u8],
        filter: Filter,
        wrap: Wrap,
        raw: bool,
    ) -> Result<Pattern, String> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .unwrap_or_default();
        let (width, height, texels) = if ext == "exr" {
            let img = crate::image::Image::exr_from_bytes(bytes)?;
            let texels = img.pixels.iter().map(|p| Vec3::from(*p)).collect();
            (img.width, img.height, Texels::Floats(texels))
        } else if bytes.starts_with(b"PF") || bytes.starts_with(b"Pf") {
            let (width, height, texels) = pfm_from_bytes(bytes)?;
            (width, height, Texels::Floats(texels))
        } else {
            // A Targa file has no magic number to tell it by; a Radiance
            // file's first line may name another program than RADIANCE
            // (Mitsuba writes `#?RGBE`), which the decoder refuses.
            let img = if ext == "tga" {
                image::load_from_memory_with_format(bytes, image::ImageFormat::Tga)
            } else if bytes.starts_with(b"#?") && !bytes.starts_with(b"#?RADIANCE") {
                let line = bytes
                    .iter()
                    .position(|&b| b == b'\n')
                    .unwrap_or(bytes.len());
                let renamed = [b"#?RADIANCE".as_slice(), &bytes[line..]].concat();
                image::load_from_memory_with_format(&renamed, image::ImageFormat::Hdr)
            } else {
                image::load_from_memory(bytes)
            }
            .map_err(|e| e.to_string())?;
            let (width, height) = (img.width() as usize, img.height() as usize);
            let texels = match img {
                image::DynamicImage::ImageLuma8(_)
                | image::DynamicImage::ImageLumaA8(_)
                | image::DynamicImage::ImageRgb8(_)
                | image::DynamicImage::ImageRgba8(_) => Texels::Bytes {
                    rgb: img.to_rgb8().pixels().map(|p| p.0).collect(),
                    srgb: !raw,
                },
                _ => {
                    // Radiance HDR is linear; 16-bit PNG is sRGB unless raw.
                    let hdr = matches!(
                        img,
                        image::DynamicImage::ImageRgb32F(_) | image::DynamicImage::ImageRgba32F(_)
                    );
                    let curve = |c: f32| if hdr || raw { c } else { srgb_to_linear(c) };
                    let rgb = img.to_rgb32f();
                    let floats = rgb.pixels().map(|p| Vec3::from(p.0.map(curve))).collect();
                    Texels::Floats(floats)
                }
            };
            (width, height, texels)
        };
        if width == 0 || height == 0 {
            return Err("the image has no pixels".into());
        }
        Ok(Pattern::Bitmap {
            width,
            height,
            texels,
            filter,
            wrap,
        })
    }

    /// The texture's value at a surface's (u, v); a mesh attribute, which
    /// no (u, v) tells, gives its placeholder mean.
    pub fn eval(&self, uv: Vec2) -> Vec3 {
        let uv = self.to_uv.transform_point2(uv);
        match &self.pattern {
            Pattern::Attribute { .. } => self.mean(),
            Pattern::Checkerboard { color0, color1 } => {
                let f = uv - uv.floor();
                if (f.x > 0.5) == (f.y > 0.5) {
                    *color0
                } else {
                    *color1
                }
            }
            Pattern::Bitmap {
                width,
                height,
                texels,
                filter,
                wrap,
            } => {
                let p = uv * Vec2::new(*width as f32, *height as f32);
                match filter {
                    Filter::Nearest => texels.get(
                        wrap_index(p.y.floor() as i64, *height, *wrap) * width
                            + wrap_index(p.x.floor() as i64, *width, *wrap),
                    ),
                    Filter::Bilinear => {
                        let ([t00, t10, t01, t11], w) =
                            bilinear_cell(texels, (*width, *height), *wrap, p);
                        t00.lerp(t10, w.x).lerp(t01.lerp(t11, w.x), w.y)
                    }
                }
            }
        }
    }

    /// The derivatives of its luminance along a surface's u and v, as its
    /// lookup varies (Mitsuba's `eval_1_grad`, which `bumpmap` reads): a
    /// bilinear bitmap's within the cell of four texels, 0 for a nearest
    /// one and a checkerboard (the CPU twin of `texture_gradient`).
    pub fn gradient(&self, uv: Vec2) -> Vec2 {
        let Pattern::Bitmap {
            width,
            height,
            texels,
            filter: Filter::Bilinear,
            wrap,
        } = &self.pattern
        else {
            return Vec2::ZERO;
        };
        let size = Vec2::new(*width as f32, *height as f32);
        let p = self.to_uv.transform_point2(uv) * size;
        let (cell, w) = bilinear_cell(texels, (*width, *height), *wrap, p);
        let [l00, l10, l01, l11] = cell.map(crate::bsdf::luminance);
        // Per texel, back through to_uv's linear part, then per unit of u
        // and v: Mitsuba scales by the resolution last, which differs from
        // the true derivative where a to_uv that turns meets a texture that
        // is not square.
        let g = Vec2::new(
            (l10 - l00) + (l11 - l01 - (l10 - l00)) * w.y,
            (l01 - l00) + (l11 - l10 - (l01 - l00)) * w.x,
        );
        Vec2::new(
            g.x * self.to_uv.x_axis.x + g.y * self.to_uv.x_axis.y,
            g.x * self.to_uv.y_axis.x + g.y * self.to_uv.y_axis.y,
        ) * size
    }
}

impl Texture {
    /// The mean over its texels (a bitmap) or its two colours: what
    /// Mitsuba's plastics weigh their lobes by. A mesh attribute has none
    /// (nor in Mitsuba, which refuses it in a plastic, as qtrace does): it
    /// gives half its scale, which only a BSDF's host-side estimates read.
    pub fn mean(&self) -> Vec3 {
        match &self.pattern {
            Pattern::Attribute { scale, .. } => Vec3::splat(0.5 * scale),
            Pattern::Checkerboard { color0, color1 } => 0.5 * (*color0 + *color1),
            Pattern::Bitmap { texels, .. } => {
                let n = texels.len();
                (0..n)
                    .map(|i| texels.get(i).as_dvec3())
                    .sum::<glam::DVec3>()
                    .as_vec3()
                    / n as f32
            }
        }
    }

    /// A bitmap's size and texels at half its width and height (rounded
    /// up): each texel the mean of the linear values of the 2×2 it replaces
    /// (clamped at the edges), 8-bit texels encoded as they were.
    fn halved(&self) -> Option<(usize, usize, Texels)> {
        let Pattern::Bitmap {
            width,
            height,
            texels,
            ..
        } = &self.pattern
        else {
            return None;
        };
        let (w, h) = (width.div_ceil(2), height.div_ceil(2));
        let mean = |x: usize, y: usize| {
            let at = |dx: usize, dy: usize| {
                let (sx, sy) = ((2 * x + dx).min(width - 1), (2 * y + dy).min(height - 1));
                texels.get(sy * width + sx)
            };
            0.25 * (at(0, 0) + at(1, 0) + at(0, 1) + at(1, 1))
        };
        let linear = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| mean(x, y));
        let texels = match texels {
            Texels::Floats(_) => Texels::Floats(linear.collect()),
            Texels::Bytes { srgb, .. } => {
                let encode = |c: f32| {
                    let c = if *srgb { linear_to_srgb(c) } else { c };
                    (c.clamp(0.0, 1.0) * 255.0).round() as u8
                };
                Texels::Bytes {
                    rgb: linear.map(|c| c.to_array().map(encode)).collect(),
                    srgb: *srgb,
                }
            }
        };
        Some((w, h, texels))
    }

    /// Whether `other` holds the same texels (one file read twice).
    fn same_texels(&self, other: &Texture) -> bool {
        match (&self.pattern, &other.pattern) {
            (
                Pattern::Bitmap {
                    width,
                    height,
                    texels,
                    ..
                },
                Pattern::Bitmap {
                    width: w,
                    height: h,
                    texels: t,
                    ..
                },
            ) => self.name == other.name && width == w && height == h && texels == t,
            _ => false,
        }
    }

    /// Words of the device's texture buffer its texels take (after the
    /// headers).
    fn words(&self) -> usize {
        match &self.pattern {
            Pattern::Attribute { .. } => 0,
            Pattern::Checkerboard { .. } => 2,
            Pattern::Bitmap {
                texels: Texels::Floats(v),
                ..
            } => v.len(),
            Pattern::Bitmap {
                texels: Texels::Bytes { rgb, .. },
                ..
            } => rgb.len().div_ceil(4),
        }
    }

    fn header(&self, offset: usize) -> [[u32; 4]; TEXTURE_HEADER_WORDS] {
        let (flags, width, height) = match &self.pattern {
            Pattern::Checkerboard { .. } => (shaders::TEXTURE_CHECKERBOARD, 0, 0),
            // Its scale where others' texels start.
            Pattern::Attribute { slot, stride, .. } => (shaders::TEXTURE_ATTRIBUTE, *slot, *stride),
            Pattern::Bitmap {
                width,
                height,
                texels,
                filter,
                wrap,
            } => {
                let mut flags = match texels {
                    Texels::Floats(_) => shaders::TEXTURE_FLOATS,
                    Texels::Bytes { srgb: true, .. } => {
                        shaders::TEXTURE_BYTES | shaders::TEXTURE_SRGB
                    }
                    Texels::Bytes { srgb: false, .. } => shaders::TEXTURE_BYTES,
                };
                if *filter == Filter::Nearest {
                    flags |= shaders::TEXTURE_NEAREST;
                }
                flags |= match wrap {
                    Wrap::Repeat => shaders::TEXTURE_REPEAT,
                    Wrap::Mirror => shaders::TEXTURE_MIRROR,
                    Wrap::Clamp => shaders::TEXTURE_CLAMP,
                };
                (flags, *width as u32, *height as u32)
            }
        };
        let m = self.to_uv;
        let row = |r: usize| [m.x_axis[r], m.y_axis[r], m.z_axis[r], 0.0].map(f32::to_bits);
        // An attribute's scale where others' texels start.
        let offset = match &self.pattern {
            Pattern::Attribute { scale, .. } => scale.to_bits(),
            _ => offset as u32,
        };
        [[flags, offset, width, height], row(0), row(1)]
    }

    fn push_texels(&self, out: &mut Vec<[u32; 4]>) {
        let bits = |c: Vec3| [c.x.to_bits(), c.y.to_bits(), c.z.to_bits(), 0];
        match &self.pattern {
            Pattern::Attribute { .. } => {}
            Pattern::Checkerboard { color0, color1 } => out.extend([bits(*color0), bits(*color1)]),
            Pattern::Bitmap {
                texels: Texels::Floats(v),
                ..
            } => out.extend(v.iter().map(|c| bits(*c))),
            Pattern::Bitmap {
                texels: Texels::Bytes { rgb, .. },
                ..
            } => out.extend(rgb.chunks(4).map(|c| {
                let mut w = [0u32; 4];
                for (w, p) in w.iter_mut().zip(c) {
                    *w = u32::from_le_bytes([p[0], p[1], p[2], 0]);
                }
                w
            })),
        }
    }
}

/// Words of the texture buffer's header of one texture.
const TEXTURE_HEADER_WORDS: usize = shaders::TEXTURE_HEADER_WORDS as usize;

/// The textures as glsl/texture.glsl reads them: the sRGB table, a header
/// of three words each (flags, first word of its texels, width, height; the
/// two rows of `to_uv`), then their texels; or the first texture that takes
/// the buffer past `limit` bytes.
pub fn pack(textures: &[Texture], limit: u64) -> Result<Vec<[u32; 4]>, TextureTooLarge> {
    let table = shaders::TEXTURE_TABLE_WORDS as usize;
    let mut offset = table + TEXTURE_HEADER_WORDS * textures.len();
    let mut out = Vec::with_capacity(offset);
    out.extend(
        (0..table)
            .map(|w| [0, 1, 2, 3].map(|k| srgb_to_linear((4 * w + k) as f32 / 255.0).to_bits())),
    );
    // A file read with other filters, wraps or transforms shares its texels.
    let mut first_of: Vec<usize> = Vec::with_capacity(textures.len());
    let mut offsets: Vec<usize> = Vec::with_capacity(textures.len());
    for (k, t) in textures.iter().enumerate() {
        let first = (0..k)
            .find(|&j| first_of[j] == j && textures[j].same_texels(t))
            .unwrap_or(k);
        first_of.push(first);
        let at = if first == k {
            offset += t.words();
            offset - t.words()
        } else {
            offsets[first]
        };
        offsets.push(at);
        out.extend(t.header(at));
        if 16 * offset as u64 > limit {
            return Err(TextureTooLarge {
                name: t.name.clone(),
                bytes: 16 * offset as u64,
                limit,
            });
        }
    }
    for (k, t) in textures.iter().enumerate() {
        if first_of[k] == k {
            t.push_texels(&mut out);
        }
    }
    Ok(out)
}

/// Bytes of the device's texture buffer [`pack`] would fill.
fn packed_bytes(textures: &[Texture]) -> u64 {
    let mut words = shaders::TEXTURE_TABLE_WORDS as usize + TEXTURE_HEADER_WORDS * textures.len();
    for (k, t) in textures.iter().enumerate() {
        if !textures[..k].iter().any(|o| o.same_texels(t)) {
            words += t.words();
        }
    }
    16 * words as u64
}

/// `textures` made to fit `limit` bytes of the device's buffer: while they
/// do not, the bitmap whose texels take the most room (every texture that
/// reads them) is halved in width and height, each texel the mean of the
/// 2×2 it replaces, with a warning naming it. `None` where they fit as they
/// are.
pub fn fit(textures: &[Texture], limit: u64) -> Result<Option<Vec<Texture>>, TextureTooLarge> {
    if packed_bytes(textures) <= limit {
        return Ok(None);
    }
    let mut out = textures.to_vec();
    loop {
        let bytes = packed_bytes(&out);
        if bytes <= limit {
            break;
        }
        let largest = (0..out.len())
            .filter(|&i| matches!(out[i].pattern, Pattern::Bitmap { width, height, .. } if width * height > 1))
            .max_by_key(|&i| out[i].words());
        let Some(i) = largest else {
            return Err(TextureTooLarge {
                name: out.last().map_or(String::new(), |t| t.name.clone()),
                bytes,
                limit,
            });
        };
        let Some(shrunk) = out[i].halved() else {
            unreachable!("only bitmaps are halved")
        };
        let same: Vec<usize> = (0..out.len())
            .filter(|&j| out[j].same_texels(&out[i]))
            .collect();
        for j in same {
            // Each reader keeps its own filter and wrap.
            if let Pattern::Bitmap {
                width,
                height,
                texels,
                ..
            } = &mut out[j].pattern
            {
                (*width, *height, *texels) = shrunk.clone();
            }
        }
    }
    let mut warned = std::collections::HashSet::new();
    for (before, after) in textures.iter().zip(&out) {
        if let (
            Pattern::Bitmap {
                width: w0,
                height: h0,
                ..
            },
            Pattern::Bitmap { width, height, .. },
        ) = (&before.pattern, &after.pattern)
        {
            if (w0, h0) != (width, height) && warned.insert(&before.name) {
                log::warn!(
                    "texture '{}' ({w0}x{h0}) halved to {width}x{height}: the scene's textures fit the {} MiB one device buffer may hold here no other way",
                    before.name,
                    limit >> 20
                );
            }
        }
    }
    Ok(Some(out))
}

/// The scene's textures do not fit the device's buffer.
#[derive(Debug, thiserror::Error)]
#[error(
    "textures need {} MiB of device memory up to '{name}', over the {} MiB one buffer may hold here (textures of 8 bits a channel take 4 bytes a texel, others 16)",
    bytes.div_ceil(1 << 20),
    limit >> 20
)]
pub struct TextureTooLarge {
    pub name: String,
    pub bytes: u64,
    pub limit: u64,
}

/// A Portable Float Map (`PF` colour, `Pf` grey), as Mitsuba reads one:
/// little-endian where its scale is negative, rows from the bottom up, and
/// every value times the scale's magnitude.
fn pfm_from_bytes(bytes: &[u8]) -> Result<(usize, usize, Vec<Vec3>), String> {
    let bad = || "not a PFM file (header: PF or Pf, width, height, scale)".to_string();
    // Three whitespace-separated tokens after the magic, then one byte of
    // whitespace and the floats.
    let mut at = 2;
    let mut tokens = Vec::new();
    while tokens.len() < 3 {
        while bytes.get(at).is_some_and(u8::is_ascii_whitespace) {
            at += 1;
        }
        let start = at;
        while bytes.get(at).is_some_and(|b| !b.is_ascii_whitespace()) {
            at += 1;
        }
        if start == at || at >= bytes.len() {
            return Err(bad());
        }
        tokens.push(std::str::from_utf8(&bytes[start..at]).map_err(|_| bad())?);
    }
    let data = &bytes[at + 1..];
    let (w, h, scale): (usize, usize, f32) =
        match (tokens[0].parse(), tokens[1].parse(), tokens[2].parse()) {
            (Ok(w), Ok(h), Ok(s)) => (w, h, s),
            _ => return Err(bad()),
        };
    if !scale.is_finite() || scale == 0.0 {
        return Err(format!(
            "the PFM scale {} must be finite and not zero",
            tokens[2]
        ));
    }
    let channels = if bytes[1] == b'F' { 3 } else { 1 };
    w.checked_mul(h)
        .and_then(|n| n.checked_mul(channels * 4))
        .filter(|&n| n <= data.len())
        .ok_or_else(|| format!("the PFM file holds less than its {w}x{h} pixels"))?;
    let word = |i: usize| {
        let b: [u8; 4] = data[4 * i..4 * i + 4].try_into().expect("four bytes");
        let v = if scale < 0.0 {
            f32::from_le_bytes(b)
        } else {
            f32::from_be_bytes(b)
        };
        v * scale.abs()
    };
    let mut texels = Vec::with_capacity(w * h);
    for y in (0..h).rev() {
        for x in 0..w {
            let i = (y * w + x) * channels;
            texels.push(if channels == 3 {
                Vec3::new(word(i), word(i + 1), word(i + 2))
            } else {
                Vec3::splat(word(i))
            });
        }
    }
    Ok((w, h, texels))
}

#[cfg(test)]
mod tests {

    /// Grey OpenEXR (a Y channel, as Mitsuba writes one) and Radiance files
    /// whose first line names another program (Mitsuba's `#?RGBE`) read as
    /// Mitsuba reads them.
    #[test]
    fn grey_exr_and_rgbe_headers_read() {
        use exr::prelude::*;
        let dir = std::env::temp_dir().join(format!("qtrace-grey-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("y.exr");
        let values = [0.25f32, 0.5, 0.75, 2.0];
        let channels = SpecificChannels::build()
            .with_channel("Y")
            .with_pixel_fn(|p: Vec2<usize>| (values[p.y() * 2 + p.x()],));
        Image::from_channels((2, 2), channels)
            .write()
            .to_file(&path)
            .unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let Ok(Pattern::Bitmap {
            texels: Texels::Floats(t),
            ..
        }) = Texture::bitmap_from_bytes(&path, &bytes, Filter::Nearest, Wrap::Repeat, false)
        else {
            panic!("grey EXR")
        };
        assert_eq!(t, values.map(Vec3::splat));
        std::fs::remove_dir_all(&dir).unwrap();
        // One 1x1 pixel of (1, 0.5, 0.25): mantissas 128, 64, 32, exponent 129.
        let hdr = |first: &str| {
            let mut b = format!("{first}\nFORMAT=32-bit_rle_rgbe\n\n-Y 1 +X 1\n").into_bytes();
            b.extend([128, 64, 32, 129]);
            Texture::bitmap_from_bytes(Path::new("s.hdr"), &b, Filter::Nearest, Wrap::Repeat, false)
        };
        for first in ["#?RADIANCE", "#?RGBE"] {
            let Ok(Pattern::Bitmap {
                texels: Texels::Floats(t),
                ..
            }) = hdr(first)
            else {
                panic!("{first}")
            };
            assert_eq!(t, [Vec3::new(1.0, 0.5, 0.25)], "{first}");
        }
    }

    /// PFM as Mitsuba reads it: byte order by the scale's sign, the bottom
    /// row first, values times |scale|, grey spread over the channels.
    #[test]
    fn pfm_files_read_as_mitsuba_reads_them() {
        let file = |magic: &str, scale: &str, values: &[f32], le: bool| {
            let mut b = format!("{magic}\n2 2\n{scale}\n").into_bytes();
            for v in values {
                b.extend(if le { v.to_le_bytes() } else { v.to_be_bytes() });
            }
            Texture::bitmap_from_bytes(Path::new("t.pfm"), &b, Filter::Nearest, Wrap::Repeat, false)
        };
        let grey = [1.0, 2.0, 3.0, 4.0];
        for (scale, le, k) in [("-1", true, 1.0), ("1.0", false, 1.0), ("-2.5", true, 2.5)] {
            let Ok(Pattern::Bitmap {
                width: 2,
                height: 2,
                texels: Texels::Floats(t),
                ..
            }) = file("Pf", scale, &grey, le)
            else {
                panic!("{scale}")
            };
            // The file's first row is the image's bottom one.
            let want = [3.0, 4.0, 1.0, 2.0].map(|v| Vec3::splat(v * k));
            assert_eq!(t, want, "{scale}");
        }
        let rgb: Vec<f32> = (0..12).map(|i| i as f32).collect();
        let Ok(Pattern::Bitmap {
            texels: Texels::Floats(t),
            ..
        }) = file("PF", "-1", &rgb, true)
        else {
            panic!("PF")
        };
        assert_eq!(t[0], Vec3::new(6.0, 7.0, 8.0));
        assert_eq!(t[3], Vec3::new(3.0, 4.0, 5.0));
        assert!(file("PF", "-1", &grey, true).is_err(), "too short");
        assert!(file("PF", "0", &rgb, true).is_err(), "scale 0");
        assert!(file("Pf", "x", &grey, true).is_err(), "no scale");
    }

    use super::*;

    const UVS: [(f32, f32); 5] = [
        (0.1, 0.2),
        (0.5, 0.5),
        (0.9, 0.95),
        (1.3, -0.2),
        (-0.45, 2.7),
    ];

    fn small(filter: Filter, wrap: Wrap, raw: bool) -> Texture {
        let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures/textures/small.png");
        Texture {
            name: "small.png".into(),
            pattern: Texture::read_bitmap(&path, filter, wrap, raw).unwrap(),
            to_uv: Mat3::IDENTITY,
        }
    }

    fn assert_values(what: &str, t: &Texture, want: [[f32; 3]; 5]) {
        for ((u, v), w) in UVS.into_iter().zip(want) {
            let got = t.eval(Vec2::new(u, v));
            assert!(
                (got - Vec3::from(w)).abs().max_element() < 2e-5,
                "{what} at ({u}, {v}): {got} vs Mitsuba's {w:?}"
            );
        }
    }

    /// Mitsuba 3.9.1's `bitmap` (scalar_rgb) on a 4×3 PNG of random sRGB
    /// bytes, at the same points, for every filter, wrap mode and `raw`.
    #[test]
    fn bitmaps_look_up_as_mitsuba() {
        use Filter::*;
        use Wrap::*;
        let cases = [
            (
                Bilinear,
                Repeat,
                false,
                [
                    [0.819942, 0.545152, 0.456753],
                    [0.099056, 0.032105, 0.704962],
                    [0.241988, 0.295608, 0.04356],
                    [0.468162, 0.039047, 0.314572],
                    [0.180744, 0.14567, 0.314154],
                ],
            ),
            (
                Bilinear,
                Repeat,
                true,
                [
                    [0.867216, 0.757255, 0.683569],
                    [0.331373, 0.196078, 0.852941],
                    [0.338274, 0.374118, 0.138765],
                    [0.603647, 0.181529, 0.586078],
                    [0.317804, 0.361569, 0.455686],
                ],
            ),
            (
                Bilinear,
                Mirror,
                false,
                [
                    [0.844969, 0.519248, 0.498096],
                    [0.099056, 0.032105, 0.704962],
                    [0.004777, 0.008023, 0.003035],
                    [0.722646, 0.240123, 0.640631],
                    [0.338234, 0.08489, 0.424914],
                ],
            ),
            (
                Bilinear,
                Clamp,
                false,
                [
                    [0.844969, 0.519248, 0.498096],
                    [0.099056, 0.032105, 0.704962],
                    [0.004777, 0.008023, 0.003035],
                    [0.651406, 0.863157, 0.026241],
                    [0.017642, 0.002125, 0.238397],
                ],
            ),
            (
                Nearest,
                Repeat,
                false,
                [
                    [0.938686, 0.53948, 0.514918],
                    [0.152926, 0.027321, 0.571125],
                    [0.004777, 0.008023, 0.003035],
                    [0.730461, 0.040915, 0.287441],
                    [0.002428, 0.300544, 0.004391],
                ],
            ),
            (
                Nearest,
                Mirror,
                true,
                [
                    [0.972549, 0.760784, 0.745098],
                    [0.427451, 0.180392, 0.780392],
                    [0.058824, 0.086275, 0.039216],
                    [0.929412, 0.082353, 0.960784],
                    [0.870588, 0.223529, 0.572549],
                ],
            ),
            (
                Nearest,
                Clamp,
                false,
                [
                    [0.938686, 0.53948, 0.514918],
                    [0.152926, 0.027321, 0.571125],
                    [0.004777, 0.008023, 0.003035],
                    [0.651406, 0.863157, 0.026241],
                    [0.017642, 0.002125, 0.238397],
                ],
            ),
        ];
        for (filter, wrap, raw, want) in cases {
            assert_values(
                &format!("{filter:?} {wrap:?} raw {raw}"),
                &small(filter, wrap, raw),
                want,
            );
        }
        // to_uv: Mitsuba's `Transform4f().scale([2, 3, 1]).translate([0.1,
        // 0.2, 0])`, which translates first.
        let mut t = small(Bilinear, Repeat, false);
        t.to_uv =
            Mat3::from_scale(Vec2::new(2.0, 3.0)) * Mat3::from_translation(Vec2::new(0.1, 0.2));
        assert_values(
            "to_uv",
            &t,
            [
                [0.587223, 0.240602, 0.171749],
                [0.721712, 0.374886, 0.341455],
                [0.155761, 0.254631, 0.447397],
                [0.357059, 0.351119, 0.14787],
                [0.322803, 0.068356, 0.440105],
            ],
        );
    }

    /// BMP, Targa and PPM files (Mitsuba reads them too) read as PNG does:
    /// 8 bits a channel, sRGB unless raw.
    #[test]
    fn bmp_targa_and_ppm_read_as_png_does() {
        let mut img = image::RgbImage::new(3, 2);
        for (i, p) in img.pixels_mut().enumerate() {
            *p = image::Rgb([40 * i as u8, 255 - 30 * i as u8, 7 * i as u8]);
        }
        let encode = |format| {
            let mut out = std::io::Cursor::new(Vec::new());
            img.write_to(&mut out, format).unwrap();
            out.into_inner()
        };
        let want: Vec<[u8; 3]> = img.pixels().map(|p| p.0).collect();
        for (name, format) in [
            ("a.bmp", image::ImageFormat::Bmp),
            ("a.tga", image::ImageFormat::Tga),
            ("a.ppm", image::ImageFormat::Pnm),
        ] {
            let pattern = Texture::bitmap_from_bytes(
                Path::new(name),
                &encode(format),
                Filter::Nearest,
                Wrap::Repeat,
                false,
            )
            .unwrap();
            let Pattern::Bitmap {
                width: 3,
                height: 2,
                texels: Texels::Bytes { rgb, srgb: true },
                ..
            } = pattern
            else {
                panic!("{name}: {pattern:?}");
            };
            assert_eq!(rgb, want, "{name}");
        }
    }

    /// Mitsuba 3.9.1's `eval_1_grad` of the same PNG under an affine to_uv
    /// (rows (2, 0.5, 0.1) and (-0.3, 3, -0.2)), at nearly the same points.
    #[test]
    fn gradients_are_mitsubas() {
        let cases = [
            (
                Wrap::Repeat,
                [
                    [-0.0147631, -2.18753],
                    [-2.27836, 1.26182],
                    [-1.25324, -3.07159],
                    [-0.0696642, 1.10431],
                    [-0.485398, 0.517311],
                ],
            ),
            (
                Wrap::Mirror,
                [
                    [-0.0147631, -2.18753],
                    [1.67038, 0.313196],
                    [-1.25324, -3.07159],
                    [-0.0696642, 1.10431],
                    [-0.725926, -0.136111],
                ],
            ),
            (
                Wrap::Clamp,
                [
                    [-0.0147631, -2.18753],
                    [0.0, 0.0],
                    [0.0, 0.0],
                    [0.0, 0.0],
                    [0.0833374, 0.0156258],
                ],
            ),
        ];
        for (wrap, want) in cases {
            let mut t = small(Filter::Bilinear, wrap, false);
            t.to_uv = Mat3::from_cols(
                glam::Vec3::new(2.0, -0.3, 0.0),
                glam::Vec3::new(0.5, 3.0, 0.0),
                glam::Vec3::new(0.1, -0.2, 1.0),
            );
            // UVS but (0.83, 0.95) for (0.9, 0.95), where the lookup sits on
            // a texel's edge and the derivative is one-sided.
            let uvs = UVS.map(|p| if p == (0.9, 0.95) { (0.83, 0.95) } else { p });
            for ((u, v), w) in uvs.into_iter().zip(want) {
                let got = t.gradient(Vec2::new(u, v));
                assert!(
                    (got - Vec2::from(w)).abs().max_element() < 1e-3 * (1.0 + got.length()),
                    "{wrap:?} at ({u}, {v}): {got} vs Mitsuba's {w:?}"
                );
            }
        }
        let nearest = small(Filter::Nearest, Wrap::Repeat, false);
        assert_eq!(nearest.gradient(Vec2::new(0.3, 0.4)), Vec2::ZERO);
    }

    #[test]
    fn checkerboard_alternates_as_mitsuba() {
        let (a, b) = ([0.1, 0.2, 0.3], [0.8, 0.7, 0.6]);
        let t = Texture {
            name: "checkerboard".into(),
            pattern: Pattern::Checkerboard {
                color0: Vec3::from(a),
                color1: Vec3::from(b),
            },
            to_uv: Mat3::IDENTITY,
        };
        assert_values("checkerboard", &t, [a, a, a, b, a]);
    }

    #[test]
    fn textures_too_large_for_a_buffer_are_halved_to_fit() {
        let mut rng = crate::fuzz::Rng::new(3);
        let bytes = |n: usize, rng: &mut crate::fuzz::Rng| -> Vec<[u8; 3]> {
            (0..n)
                .map(|_| [0, 1, 2].map(|_| (rng.next_u64() >> 56) as u8))
                .collect()
        };
        let bitmap = |name: &str, w: usize, h: usize, texels: Texels, wrap: Wrap| Texture {
            name: name.into(),
            pattern: Pattern::Bitmap {
                width: w,
                height: h,
                texels,
                filter: Filter::Bilinear,
                wrap,
            },
            to_uv: Mat3::IDENTITY,
        };
        let big = Texels::Bytes {
            rgb: bytes(64 * 48, &mut rng),
            srgb: true,
        };
        let floats = Texels::Floats(
            (0..33 * 17)
                .map(|i| Vec3::splat(i as f32 / 561.0))
                .collect(),
        );
        let textures = vec![
            bitmap("big.png", 64, 48, big.clone(), Wrap::Repeat),
            bitmap("floats.exr", 33, 17, floats, Wrap::Clamp),
            // The same file read with another wrap shares its texels.
            bitmap("big.png", 64, 48, big, Wrap::Mirror),
        ];
        let all = packed_bytes(&textures);
        assert!(fit(&textures, all).unwrap().is_none());
        // Room for all but a quarter of the largest: it alone is halved,
        // both its readers, which still share their texels.
        let fitted = fit(&textures, all - 16 * 64 * 48 / 16).unwrap().unwrap();
        let size = |t: &Texture| match t.pattern {
            Pattern::Bitmap { width, height, .. } => (width, height),
            _ => unreachable!(),
        };
        assert_eq!(
            fitted.iter().map(size).collect::<Vec<_>>(),
            [(32, 24), (33, 17), (32, 24)]
        );
        assert!(fitted[0].same_texels(&fitted[2]));
        assert!(matches!(
            fitted[2].pattern,
            Pattern::Bitmap {
                wrap: Wrap::Mirror,
                ..
            }
        ));
        assert!((fitted[0].mean() - textures[0].mean()).abs().max_element() < 0.01);
        // Less room still: the floats too, to 17 x 9.
        let fitted = fit(&textures, packed_bytes(&fitted) - 16 * 300)
            .unwrap()
            .unwrap();
        assert!(fitted.iter().any(|t| size(t) == (17, 9)));
        assert!(packed_bytes(&fitted) <= packed_bytes(&textures));
    }
}
