//! Scenes: TOML + OBJ/MTL (+ procedural geometry) → triangles, materials,
//! lights, camera and a BVH ready for the GPU.

pub mod bvh;
pub mod file;
pub mod obj;
pub mod procedural;

use crate::bsdf::luminance;
use crate::shaders;
use file::{CameraDesc, RenderDefaults, SceneFile};
use glam::Vec3;
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
    pub albedo: Vec3,
    pub emission: Vec3,
}

/// Pinhole camera in the right-handed look-at convention of SPEC §3.
#[derive(Clone, Copy, Debug)]
pub struct Camera {
    pub position: Vec3,
    pub forward: Vec3,
    pub right: Vec3,
    pub up: Vec3,
    pub fov_y_degrees: f32,
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
            fov_y_degrees: d.fov_y,
        })
    }

    /// Direction through image point (x, y) in pixels (fractional), SPEC §3.
    pub fn ray_direction(&self, x: f32, y: f32, width: u32, height: u32) -> Vec3 {
        let t = (self.fov_y_degrees.to_radians() * 0.5).tan();
        let aspect = width as f32 / height as f32;
        let sx = 2.0 * x / width as f32 - 1.0;
        let sy = 1.0 - 2.0 * y / height as f32;
        (self.forward + sx * t * aspect * self.right + sy * t * self.up).normalize()
    }
}

/// A loaded scene, triangles already in BVH leaf order.
pub struct Scene {
    pub path: PathBuf,
    /// FNV-1a over the bytes of every file the scene was read from: parts
    /// of one render carry it, so `merge` refuses parts of another scene.
    pub fingerprint: u64,
    pub camera: Camera,
    pub defaults: RenderDefaults,
    /// The `[sarsa]` and `[neural]` tables, as written; render settings
    /// check and read them.
    pub guide_tables: [(&'static str, toml::Table); 2],
    pub environment: Vec3,
    pub materials: Vec<Material>,
    pub triangles: Vec<shaders::Triangle>,
    pub lights: Vec<shaders::Light>,
    pub nodes: Vec<shaders::BvhNode>,
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

    /// The scene's table of guide `name` (empty when it has none).
    pub fn guide_table(&self, name: &str) -> &toml::Table {
        static EMPTY: std::sync::OnceLock<toml::Table> = std::sync::OnceLock::new();
        self.guide_tables
            .iter()
            .find(|(n, _)| *n == name)
            .map_or_else(|| EMPTY.get_or_init(toml::Table::new), |(_, t)| t)
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

    /// Loads and validates a scene file and everything it names.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, SceneError> {
        Self::load_with(path.as_ref(), &Loader::default())
    }

    /// [`Scene::load`], reading files and bounding the scene's size as `loader` says.
    pub fn load_with(path: &Path, loader: &Loader<'_>) -> Result<Self, SceneError> {
        // Every file read goes into the scene's fingerprint.
        let fingerprint = std::cell::Cell::new(0xcbf2_9ce4_8422_2325u64);
        let hashing = |p: &Path| {
            let text = (loader.read)(p)?;
            let mut h = fingerprint.get();
            for &b in text.as_bytes() {
                h = (h ^ b as u64).wrapping_mul(0x0100_0000_01b3);
            }
            fingerprint.set(h);
            Ok(text)
        };
        let loader = &Loader {
            read: &hashing,
            max_triangles: loader.max_triangles,
        };
        let text = (loader.read)(path).map_err(|source| SceneError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let file: SceneFile = toml::from_str(&text).map_err(|e| toml_error(path, &text, e))?;
        let invalid = |message: String| SceneError::Invalid {
            path: path.to_path_buf(),
            message,
        };
        let camera = Camera::from_desc(&file.camera).map_err(invalid)?;
        let environment = check_color(path, "environment", file.environment.unwrap_or([0.0; 3]))?;

        let mut materials: Vec<Material> = Vec::new();
        let mut positions: Vec<[Vec3; 3]> = Vec::new();
        let mut material_of: Vec<u32> = Vec::new();
        // Where each triangle came from (index into `sources`), for error messages.
        let mut sources: Vec<(PathBuf, String)> = Vec::new();
        let mut source_of: Vec<u32> = Vec::new();

        if let Some(mesh) = &file.mesh {
            let obj_path = path.parent().unwrap_or(Path::new(".")).join(mesh);
            let mut geometry = Geometry {
                positions: &mut positions,
                material_of: &mut material_of,
                sources: &mut sources,
                source_of: &mut source_of,
            };
            load_obj(&obj_path, loader, &mut materials, &mut geometry)?;
        }
        for p in &file.procedural {
            procedural::validate(p).map_err(invalid)?;
            let count = procedural::triangle_count(p) as usize;
            if positions.len().saturating_add(count) > loader.max_triangles {
                return Err(invalid(format!(
                    "the scene would have more than {} triangles, the most a scene may have",
                    loader.max_triangles
                )));
            }
            let g = procedural::generate(p);
            let m = materials.len() as u32;
            materials.push(Material {
                name: g.name.clone(),
                albedo: check_color(path, "procedural albedo", g.albedo.into())?,
                emission: Vec3::ZERO,
            });
            sources.push((path.to_path_buf(), format!("procedural {}", g.name)));
            let src = sources.len() as u32 - 1;
            for t in g.triangles {
                positions.push(t);
                material_of.push(m);
                source_of.push(src);
            }
        }
        if file.mesh.is_none() && file.procedural.is_empty() {
            return Err(invalid(
                "the scene names no mesh and no procedural geometry".into(),
            ));
        }
        if positions.is_empty() {
            return Err(invalid("the scene has no triangles".into()));
        }

        // Bounds, for the relative zero-area test and the ray offset.
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
        let extent = (hi - lo).length().max(1e-6);
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
        if !has_emitter && environment.max_element() <= 0.0 {
            return Err(SceneError::NoEmitter {
                path: path.to_path_buf(),
            });
        }

        let bvh = bvh::build(&positions);
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
        let lights = build_lights(&mut triangles, &materials);
        Ok(Self {
            path: path.to_path_buf(),
            fingerprint: fingerprint.get(),
            camera,
            defaults: file.render,
            guide_tables: [("sarsa", file.sarsa), ("neural", file.neural)],
            environment,
            materials,
            triangles,
            lights,
            nodes: bvh.nodes,
            bvh_depth: bvh.depth,
            bounds: bvh.bounds,
            extent,
        })
    }

    /// Closest hit by testing every triangle: the reference for BVH tests.
    pub fn intersect_brute(&self, o: Vec3, d: Vec3) -> Option<(f32, u32)> {
        let mut best: Option<(f32, u32)> = None;
        for (i, t) in self.triangles.iter().enumerate() {
            let (v0, e1, e2) = (Vec3::from(t.v0), Vec3::from(t.e1), Vec3::from(t.e2));
            let p = d.cross(e2);
            let det = e1.dot(p);
            if det.abs() < 1e-12 {
                continue;
            }
            let inv = 1.0 / det;
            let s = o - v0;
            let u = s.dot(p) * inv;
            let q = s.cross(e1);
            let v = d.dot(q) * inv;
            let tt = e2.dot(q) * inv;
            if u >= 0.0 && v >= 0.0 && u + v <= 1.0 && tt > 0.0 && best.is_none_or(|b| tt < b.0) {
                best = Some((tt, i as u32));
            }
        }
        best
    }
}

/// Emissive triangles, chosen for next-event estimation in proportion to
/// area × luminance(Le); also stores each one's P(choose)/area on the triangle.
fn build_lights(
    triangles: &mut [shaders::Triangle],
    materials: &[Material],
) -> Vec<shaders::Light> {
    let weights: Vec<(u32, f32)> = triangles
        .iter()
        .enumerate()
        .filter_map(|(i, t)| {
            let w = t.area * luminance(materials[t.material as usize].emission);
            (w > 0.0).then_some((i as u32, w))
        })
        .collect();
    let total: f64 = weights.iter().map(|&(_, w)| w as f64).sum();
    let mut acc = 0.0f64;
    let mut lights = Vec::with_capacity(weights.len());
    for &(i, w) in &weights {
        acc += w as f64;
        let pdf = (w as f64 / total) as f32;
        triangles[i as usize].light_pdf = pdf / triangles[i as usize].area;
        lights.push(shaders::Light {
            triangle: i,
            cdf: (acc / total) as f32,
            pdf,
            pad: 0.0,
        });
    }
    if let Some(last) = lights.last_mut() {
        last.cdf = 1.0; // rounding must not leave a gap at the top
    }
    lights
}

/// Triangle lists being filled, with where each triangle came from.
struct Geometry<'a> {
    positions: &'a mut Vec<[Vec3; 3]>,
    material_of: &'a mut Vec<u32>,
    sources: &'a mut Vec<(PathBuf, String)>,
    source_of: &'a mut Vec<u32>,
}

/// How a scene's files are read, and how many triangles it may have.
pub struct Loader<'a> {
    pub read: &'a dyn Fn(&Path) -> std::io::Result<String>,
    pub max_triangles: usize,
}

/// Most triangles a scene may have: about 3 GiB of host memory while it
/// loads (BVH nodes are 128 bytes a triangle); devices allow fewer, and
/// the renderer says so.
pub const MAX_TRIANGLES: usize = 1 << 24;

impl Default for Loader<'_> {
    /// The file system, and [`MAX_TRIANGLES`].
    fn default() -> Self {
        Self {
            read: &|path| std::fs::read_to_string(path),
            max_triangles: MAX_TRIANGLES,
        }
    }
}

fn load_obj(
    obj_path: &Path,
    loader: &Loader<'_>,
    materials: &mut Vec<Material>,
    out: &mut Geometry<'_>,
) -> Result<(), SceneError> {
    let text = (loader.read)(obj_path).map_err(|source| SceneError::Read {
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
        (loader.read)(&dir.join(name))
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
        let albedo = check_color(
            obj_path,
            &format!("Kd of material '{}'", m.name),
            m.diffuse.unwrap_or([0.8; 3]),
        )?;
        if albedo.max_element() > 1.0 {
            return Err(SceneError::Invalid {
                path: obj_path.to_path_buf(),
                message: format!(
                    "Kd of material '{}' exceeds 1 (it would create energy)",
                    m.name
                ),
            });
        }
        materials.push(Material {
            name: m.name.clone(),
            albedo,
            emission: check_color(
                obj_path,
                &format!("Ke of material '{}'", m.name),
                m.emission.unwrap_or([0.0; 3]),
            )?,
        });
    }
    // Faces without a material get a neutral grey.
    let default_material = materials.len() as u32;
    materials.push(Material {
        name: "default".into(),
        albedo: Vec3::splat(0.8),
        emission: Vec3::ZERO,
    });
    for group in parsed.groups {
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
