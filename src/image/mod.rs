//! Images: linear float RGB, EXR and PNG files written atomically, error metrics.

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error("{path}: cannot write image: {message}")]
    Write { path: PathBuf, message: String },
    #[error("{path}: cannot read image: {message}")]
    Read { path: PathBuf, message: String },
    #[error("images differ in size: {a_path} is {a_w}x{a_h}, {b_path} is {b_w}x{b_h}")]
    SizeMismatch {
        a_path: String,
        a_w: usize,
        a_h: usize,
        b_path: String,
        b_w: usize,
        b_h: usize,
    },
}

/// What a render's EXR says of itself in its header, so parts rendered
/// apart can be merged (`qtrace merge`).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Provenance {
    /// Samples per pixel in the image.
    pub spp: u32,
    /// The method as `bench` names it (`pt`, `sarsa+nee`, ...).
    pub method: String,
    /// The scene file, as the render was given it.
    pub scene: String,
    /// The seed of each part the image holds.
    pub seeds: Vec<u32>,
}

const ATTR_SPP: &str = "qtraceSpp";
const ATTR_METHOD: &str = "qtraceMethod";
const ATTR_SCENE: &str = "qtraceScene";
const ATTR_SEEDS: &str = "qtraceSeeds";

/// Header text: characters an EXR string cannot hold become '?'.
fn exr_text(s: &str) -> exr::meta::attribute::Text {
    let latin1: String = s
        .chars()
        .map(|c| if (c as u32) < 256 { c } else { '?' })
        .collect();
    exr::meta::attribute::Text::new_or_none(&latin1).unwrap_or_default()
}

/// Linear RGB, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<[f32; 3]>,
}

/// Writes through a temporary file in the same directory, then renames it into
/// place, so an interrupted or failed write never leaves a half-written file.
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), String>,
) -> Result<(), ImageError> {
    let err = |message: String| ImageError::Write {
        path: path.to_path_buf(),
        message,
    };
    let name = path
        .file_name()
        .ok_or_else(|| err("not a file name".into()))?
        .to_string_lossy();
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    if !dir.is_dir() {
        return Err(err(format!("directory {} does not exist", dir.display())));
    }
    // Keep the extension last: the encoders pick the format from it.
    let tmp = dir.join(format!(".{}.{}.tmp.{name}", name, std::process::id()));
    let result = write(&tmp).and_then(|()| std::fs::rename(&tmp, path).map_err(|e| e.to_string()));
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(err)
}

impl Image {
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            pixels: vec![[0.0; 3]; width * height],
        }
    }

    /// Linear float RGB OpenEXR.
    pub fn write_exr(&self, path: &Path) -> Result<(), ImageError> {
        self.write_exr_with(path, None)
    }

    /// Linear float RGB OpenEXR, with the render's provenance in its header.
    pub fn write_exr_with(
        &self,
        path: &Path,
        provenance: Option<&Provenance>,
    ) -> Result<(), ImageError> {
        use exr::prelude::*;
        let mut attributes = LayerAttributes::default();
        if let Some(p) = provenance {
            let seeds: Vec<String> = p.seeds.iter().map(|s| s.to_string()).collect();
            for (key, value) in [
                (ATTR_SPP, p.spp.to_string()),
                (ATTR_METHOD, p.method.clone()),
                (ATTR_SCENE, p.scene.clone()),
                (ATTR_SEEDS, seeds.join(",")),
            ] {
                attributes
                    .other
                    .insert(Text::from(key), AttributeValue::Text(exr_text(&value)));
            }
        }
        let layer = Layer::new(
            (self.width, self.height),
            attributes,
            Encoding::FAST_LOSSLESS,
            SpecificChannels::rgb(|pos: Vec2<usize>| {
                let p = self.pixels[pos.y() * self.width + pos.x()];
                (p[0], p[1], p[2])
            }),
        );
        write_atomically(path, |tmp| {
            exr::image::Image::from_layer(layer)
                .write()
                .to_file(tmp)
                .map_err(|e| e.to_string())
        })
    }

    /// The provenance a qtrace render wrote into an EXR's header, if any.
    pub fn read_provenance(path: &Path) -> Result<Option<Provenance>, ImageError> {
        let meta =
            exr::meta::MetaData::read_from_file(path, false).map_err(|e| ImageError::Read {
                path: path.to_path_buf(),
                message: e.to_string(),
            })?;
        let Some(header) = meta.headers.first() else {
            return Ok(None);
        };
        let text = |key: &str| match header.own_attributes.other.get(&exr_text(key)) {
            Some(exr::meta::attribute::AttributeValue::Text(t)) => Some(t.to_string()),
            _ => None,
        };
        let bad = |what: &str| ImageError::Read {
            path: path.to_path_buf(),
            message: format!("its qtrace header has a malformed {what}"),
        };
        let Some(spp) = text(ATTR_SPP) else {
            return Ok(None);
        };
        let seeds = text(ATTR_SEEDS).unwrap_or_default();
        Ok(Some(Provenance {
            spp: spp.parse().map_err(|_| bad("sample count"))?,
            method: text(ATTR_METHOD).ok_or_else(|| bad("method"))?,
            scene: text(ATTR_SCENE).ok_or_else(|| bad("scene"))?,
            seeds: seeds
                .split(',')
                .filter(|s| !s.is_empty())
                .map(|s| s.parse().map_err(|_| bad("seed list")))
                .collect::<Result<_, _>>()?,
        }))
    }

    /// 8-bit sRGB PNG; values are clamped to [0, 1] before the sRGB curve.
    pub fn write_png(&self, path: &Path) -> Result<(), ImageError> {
        let bytes: Vec<u8> = self
            .pixels
            .iter()
            .flat_map(|p| p.map(|v| (linear_to_srgb(v) * 255.0 + 0.5) as u8))
            .collect();
        write_atomically(path, |tmp| {
            image::save_buffer_with_format(
                tmp,
                &bytes,
                self.width as u32,
                self.height as u32,
                image::ExtendedColorType::Rgb8,
                image::ImageFormat::Png,
            )
            .map_err(|e| e.to_string())
        })
    }

    /// Reads the first RGB(A) layer of an OpenEXR file.
    pub fn read_exr(path: &Path) -> Result<Self, ImageError> {
        let image = exr::prelude::read_first_rgba_layer_from_file(
            path,
            |size, _| Image::new(size.width(), size.height()),
            |img: &mut Image, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                let w = img.width;
                img.pixels[pos.y() * w + pos.x()] = [r, g, b];
            },
        )
        .map_err(|e| ImageError::Read {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        Ok(image.layer_data.channel_data.pixels)
    }

    /// Reads the first RGB(A) layer of OpenEXR bytes; a layer of more than
    /// MAX_IMAGE_BYTES of RGB floats is an error before anything is
    /// allocated for it (a damaged header can claim any size).
    pub fn exr_from_bytes(bytes: &[u8]) -> Result<Self, String> {
        use exr::prelude::{read, ReadChannels, ReadLayers, ReadSpecificChannel};
        let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(bytes), false)
            .map_err(|e| e.to_string())?;
        for h in &meta.headers {
            let (w, t) = (h.layer_size.width(), h.layer_size.height());
            if w.saturating_mul(t).saturating_mul(12) > MAX_IMAGE_BYTES {
                return Err(format!(
                    "the image is {w}x{t}, over the {} MiB of pixels qtrace reads",
                    MAX_IMAGE_BYTES >> 20
                ));
            }
        }
        let rgb = read()
            .no_deep_data()
            .largest_resolution_level()
            .rgba_channels(
                |size, _| Image::new(size.width(), size.height()),
                |img: &mut Image, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                    let w = img.width;
                    img.pixels[pos.y() * w + pos.x()] = [r, g, b];
                },
            )
            .first_valid_layer()
            .all_attributes()
            .from_buffered(std::io::Cursor::new(bytes));
        let rgb_error = match rgb {
            Ok(image) => return Ok(image.layer_data.channel_data.pixels),
            Err(e) => e.to_string(),
        };
        // A luminance image (a Y channel, as Mitsuba writes grey ones).
        let grey = read()
            .no_deep_data()
            .largest_resolution_level()
            .specific_channels()
            .required("Y")
            .collect_pixels(
                |size, _| Image::new(size.width(), size.height()),
                |img: &mut Image, pos, (y,): (f32,)| {
                    let w = img.width;
                    img.pixels[pos.y() * w + pos.x()] = [y; 3];
                },
            )
            .first_valid_layer()
            .all_attributes()
            .from_buffered(std::io::Cursor::new(bytes));
        match grey {
            Ok(image) => Ok(image.layer_data.channel_data.pixels),
            Err(_) => Err(format!("{rgb_error} (qtrace reads R, G, B or Y channels)")),
        }
    }

    /// Mean over pixels and channels.
    pub fn mean(&self) -> f64 {
        let sum: f64 = self.pixels.iter().flatten().map(|&v| v as f64).sum();
        sum / (3 * self.pixels.len()).max(1) as f64
    }
}

/// The most bytes of RGB floats an image read as a texture or a sky may
/// take (as the `image` crate's own default limit for PNG, JPEG and HDR).
pub const MAX_IMAGE_BYTES: usize = 512 << 20;

pub fn linear_to_srgb(v: f32) -> f32 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// Error of an image against a reference (docs/benchmark.md).
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct ErrorMetrics {
    pub mse: f64,
    /// Mean of (a − b)² / (b² + 0.01).
    pub rel_mse: f64,
    /// Mean of |a − b| / (|b| + 0.01).
    pub mape: f64,
}

/// The relMSE a mean of `spp` samples per pixel is expected to have against
/// the true image, from each pixel's sample `variance` (per path): what a
/// reference rendered so adds to every error measured against it.
pub fn expected_rel_mse(mean: &Image, variance: &Image, spp: u32) -> f64 {
    let mut rel = 0.0f64;
    for (m, v) in mean.pixels.iter().zip(&variance.pixels) {
        for c in 0..3 {
            let y = m[c] as f64;
            rel += v[c] as f64 / spp.max(1) as f64 / (y * y + 0.01);
        }
    }
    rel / (3 * mean.pixels.len()).max(1) as f64
}

pub fn compare(image: &Image, reference: &Image) -> Result<ErrorMetrics, ImageError> {
    compare_named(image, "image", reference, "reference")
}

pub fn compare_named(
    a: &Image,
    a_name: &str,
    b: &Image,
    b_name: &str,
) -> Result<ErrorMetrics, ImageError> {
    if (a.width, a.height) != (b.width, b.height) {
        return Err(ImageError::SizeMismatch {
            a_path: a_name.into(),
            a_w: a.width,
            a_h: a.height,
            b_path: b_name.into(),
            b_w: b.width,
            b_h: b.height,
        });
    }
    let (mut mse, mut rel, mut mape) = (0.0f64, 0.0f64, 0.0f64);
    for (p, q) in a.pixels.iter().zip(&b.pixels) {
        for c in 0..3 {
            let (x, y) = (p[c] as f64, q[c] as f64);
            let d = x - y;
            mse += d * d;
            rel += d * d / (y * y + 0.01);
            mape += d.abs() / (y.abs() + 0.01);
        }
    }
    let n = (3 * a.pixels.len()).max(1) as f64;
    Ok(ErrorMetrics {
        mse: mse / n,
        rel_mse: rel / n,
        mape: mape / n,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exr_round_trips_and_metrics_are_zero_on_equal_images() {
        let dir = std::env::temp_dir().join(format!("qtrace-img-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut img = Image::new(5, 3);
        for (i, p) in img.pixels.iter_mut().enumerate() {
            *p = [i as f32, 0.5, 1e-3 * i as f32];
        }
        let path = dir.join("a.exr");
        img.write_exr(&path).unwrap();
        let back = Image::read_exr(&path).unwrap();
        assert_eq!(back, img);
        let m = compare(&img, &back).unwrap();
        assert_eq!((m.mse, m.rel_mse, m.mape), (0.0, 0.0, 0.0));
        // Only the final file remains: no temporary left behind.
        let names: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names.len(), 1, "{names:?}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn metrics_match_hand_computation() {
        let a = Image {
            width: 1,
            height: 1,
            pixels: vec![[1.0, 0.0, 0.0]],
        };
        let b = Image {
            width: 1,
            height: 1,
            pixels: vec![[0.0, 0.0, 0.0]],
        };
        let m = compare(&a, &b).unwrap();
        assert!((m.mse - 1.0 / 3.0).abs() < 1e-12);
        assert!((m.rel_mse - 100.0 / 3.0).abs() < 1e-9);
        // Variance 0.04 per path over 4 samples: 0.01 per pixel and channel.
        let mut var = Image::new(1, 1);
        var.pixels[0] = [0.04; 3];
        let mut mean = Image::new(1, 1);
        mean.pixels[0] = [0.3; 3];
        assert!((expected_rel_mse(&mean, &var, 4) - 0.01 / 0.1).abs() < 1e-6);
        assert!((m.mape - 100.0 / 3.0).abs() < 1e-9);
    }
}

/// One part of a render split across processes or machines.
#[derive(Clone, Debug)]
pub struct Part {
    pub path: PathBuf,
    pub image: Image,
    pub provenance: Provenance,
}

impl Part {
    /// Reads an EXR a qtrace render wrote; one without a qtrace header is an error.
    pub fn read(path: &Path) -> Result<Self, ImageError> {
        let provenance = Image::read_provenance(path)?.ok_or_else(|| ImageError::Read {
            path: path.to_path_buf(),
            message: "no qtrace header (sample count, method, scene): not a qtrace render".into(),
        })?;
        Ok(Self {
            path: path.to_path_buf(),
            image: Image::read_exr(path)?,
            provenance,
        })
    }
}

/// Averages parts weighted by their sample counts. Parts must share size,
/// scene and method, and no seed may appear twice (the same seed gives the
/// same samples, which would count twice).
pub fn merge(parts: &[Part]) -> Result<(Image, Provenance), String> {
    let first = parts.first().ok_or("merge needs at least one part")?;
    let mut seen: Vec<(u32, &Path)> = Vec::new();
    let mut total = 0u64;
    for p in parts {
        let (a, b) = (&first.provenance, &p.provenance);
        let name = p.path.display();
        if (p.image.width, p.image.height) != (first.image.width, first.image.height) {
            return Err(format!(
                "{name} is {}x{}, {} is {}x{}",
                p.image.width,
                p.image.height,
                first.path.display(),
                first.image.width,
                first.image.height
            ));
        }
        if b.scene != a.scene {
            return Err(format!(
                "{name} renders scene {}, {} renders {}",
                b.scene,
                first.path.display(),
                a.scene
            ));
        }
        if b.method != a.method {
            return Err(format!(
                "{name} was rendered with {}, {} with {}",
                b.method,
                first.path.display(),
                a.method
            ));
        }
        for &s in &b.seeds {
            if let Some((_, other)) = seen.iter().find(|(t, _)| *t == s) {
                return Err(format!(
                    "{name} and {} both hold seed {s}: the same samples would count twice; render parts with different --seed values",
                    other.display()
                ));
            }
            seen.push((s, &p.path));
        }
        total += b.spp as u64;
    }
    let spp = u32::try_from(total).map_err(|_| {
        format!("the parts hold {total} samples per pixel in all, more than one image can count")
    })?;
    let mut image = Image::new(first.image.width, first.image.height);
    for p in parts {
        let w = p.provenance.spp as f64 / total.max(1) as f64;
        for (out, px) in image.pixels.iter_mut().zip(&p.image.pixels) {
            for c in 0..3 {
                out[c] = (out[c] as f64 + w * px[c] as f64) as f32;
            }
        }
    }
    let provenance = Provenance {
        spp,
        method: first.provenance.method.clone(),
        scene: first.provenance.scene.clone(),
        seeds: seen.iter().map(|(s, _)| *s).collect(),
    };
    Ok((image, provenance))
}
