//! A mutation fuzzer for the scene loaders (TOML, OBJ, MTL; Mitsuba XML,
//! PLY, serialized), on stable
//! Rust and without dependencies: it starts from the shipped scenes, mutates
//! their files in memory, loads each mutant through [`Scene::load_with`]
//! and resolves its render settings, and reports any panic or slow input.
//! `examples/fuzz_scenes.rs` runs it at length with an allocation ceiling;
//! `tests/fuzz.rs` runs a short round.

use crate::guide::volumes::SplitMix;
use crate::render::{Overrides, RenderSettings};
use crate::scene::{Loader, Scene};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The triangle limit fuzz runs load with: the refusal of larger scenes is
/// exercised, and every input stays quick (a mutant that asks for a million
/// triangles is legitimate, and takes a second).
pub const MAX_TRIANGLES: usize = 1 << 16;

/// One scene's files, by the names its scene file and meshes use.
#[derive(Clone, Debug)]
pub struct Corpus {
    /// The scene file's text, loaded as `mem/{main_name}`.
    pub main: String,
    /// `scene.toml` or `scene.xml`: the format the loader reads it as.
    pub main_name: &'static str,
    /// Other files the scene reads (its OBJ, MTL, PLY, ...), by file name.
    pub files: Vec<(String, Vec<u8>)>,
}

/// The small shipped scenes (the procedural one reduced to a small sphere),
/// read from `scenes_dir`.
pub fn shipped(scenes_dir: &Path) -> std::io::Result<Vec<Corpus>> {
    let mut out = Vec::new();
    let mut entries: Vec<PathBuf> = std::fs::read_dir(scenes_dir)?
        .map(|e| e.map(|e| e.path()))
        .collect::<Result<_, _>>()?;
    entries.sort();
    for toml_path in entries
        .iter()
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
    {
        let mut toml = std::fs::read_to_string(toml_path)?;
        // A large procedural mesh takes a second to build: keep it small.
        toml = toml
            .replace("segments = 512", "segments = 8")
            .replace("rings = 256", "rings = 4");
        let stem = toml_path
            .file_stem()
            .unwrap_or_default()
            .to_string_lossy()
            .to_string();
        let mut files = Vec::new();
        for ext in ["obj", "mtl"] {
            let name = format!("{stem}.{ext}");
            if let Ok(bytes) = std::fs::read(scenes_dir.join(&name)) {
                files.push((name, bytes));
            }
        }
        out.push(Corpus {
            main: toml,
            main_name: "scene.toml",
            files,
        });
    }
    Ok(out)
}

/// The Mitsuba scenes the fuzzer starts from, relative to the repository:
/// the shipped ones and the test scenes, which between them use every
/// plugin and mesh format the reader knows.
pub fn mitsuba_scenes() -> Vec<PathBuf> {
    [
        "scenes/mitsuba/cornell-box/scene.xml",
        "scenes/mitsuba/veach-mis/scene.xml",
        "tests/fixtures/mitsuba/coverage-a.xml",
        "tests/fixtures/mitsuba/coverage-b.xml",
        "tests/fixtures/mitsuba/coverage-c.xml",
        "tests/fixtures/mitsuba/coverage-d.xml",
        "tests/fixtures/mitsuba/coverage-e.xml",
        "tests/fixtures/mitsuba/coverage-f.xml",
        "tests/fixtures/mitsuba/coverage-g.xml",
        "tests/fixtures/mitsuba/coverage-h.xml",
        "tests/fixtures/mitsuba/coverage-i.xml",
        "tests/fixtures/mitsuba/coverage-j.xml",
        "tests/fixtures/mitsuba/coverage-k.xml",
        "tests/fixtures/mitsuba/coverage-l.xml",
        "tests/fixtures/mitsuba/coverage-m.xml",
        "tests/fixtures/mitsuba/coverage-n.xml",
        "tests/fixtures/mitsuba/coverage-o.xml",
        "tests/fixtures/mitsuba/coverage-p.xml",
        "tests/fixtures/mitsuba/coverage-q.xml",
        "tests/fixtures/mitsuba/coverage-r.xml",
        "tests/fixtures/mitsuba/coverage-s.xml",
        "tests/fixtures/mitsuba/coverage-t.xml",
        "tests/fixtures/mitsuba/coverage-u.xml",
        "tests/fixtures/mitsuba/coverage-w.xml",
        "tests/fixtures/mitsuba/coverage-x.xml",
        "tests/fixtures/mitsuba/coverage-y.xml",
        "tests/fixtures/mitsuba/coverage-z.xml",
        "tests/fixtures/mitsuba/spot-image.xml",
        "tests/fixtures/mitsuba/principled-textures.xml",
        "tests/fixtures/mitsuba/blender-principled.xml",
        "tests/fixtures/mitsuba/crop.xml",
        "tests/fixtures/mitsuba/rfilters.xml",
        "tests/fixtures/mitsuba/choices.xml",
    ]
    .iter()
    .map(PathBuf::from)
    .collect()
}

/// Mitsuba XML scenes, each with every mesh and XML file beside it (what
/// it may read); spheres and disks are tessellated finely, so these load
/// more slowly than the TOML scenes.
pub fn mitsuba(scenes: &[PathBuf]) -> std::io::Result<Vec<Corpus>> {
    let mut out = Vec::new();
    for path in scenes {
        let mut main = std::fs::read_to_string(path)?;
        let dir = path.parent().unwrap_or(Path::new("."));
        let mut files = Vec::new();
        // Textures beside the scenes' folder, as if beside the scene: the
        // fuzzer's files lie in one folder.
        if main.contains("../textures/") {
            main = main.replace("../textures/", "");
            files.extend(folder_files(&dir.join("../textures"), |_| true)?);
        }
        files.extend(folder_files(dir, |p| {
            let ext = p.extension().and_then(|e| e.to_str()).unwrap_or("");
            ["obj", "ply", "serialized", "xml"].contains(&ext) && p != path.as_path()
        })?);
        out.push(Corpus {
            main,
            main_name: "scene.xml",
            files,
        });
    }
    Ok(out)
}

/// The files of folder `dir` that `keep` takes, by name, in name order.
fn folder_files(
    dir: &Path,
    keep: impl Fn(&Path) -> bool,
) -> std::io::Result<Vec<(String, Vec<u8>)>> {
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)?
        .map(|e| e.map(|e| e.path()))
        .collect::<Result<_, _>>()?;
    entries.sort();
    let mut files = Vec::new();
    for p in entries.into_iter().filter(|p| keep(p)) {
        let name = p
            .file_name()
            .unwrap_or_default()
            .to_string_lossy()
            .to_string();
        files.push((name, std::fs::read(&p)?));
    }
    Ok(files)
}

/// A reproducible stream (SplitMix64, as volume placement uses).
pub struct Rng(SplitMix);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(SplitMix(seed))
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0.next_u64()
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f32 {
        self.0.next_f32()
    }

    /// Uniform in 0..n (0 when n is 0).
    pub fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.next_u64() % n as u64) as usize
        }
    }
}

/// Values that find edge cases where a number was.
const NUMBERS: &[&str] = &[
    "0",
    "-0",
    "-1",
    "1",
    "2",
    "0.",
    ".",
    "-",
    "1e39",
    "-1e39",
    "1e-45",
    "NaN",
    "inf",
    "-inf",
    "4294967295",
    "4294967296",
    "-2147483648",
    "99999999999999999999",
    "65535",
    "65536",
    "3.4e38",
    "0x10",
    "1_000",
    "",
];

/// Lines that mean something to one of the formats.
const LINES: &[&str] = &[
    "f 1 2",
    "f 1 2 3 4 5 6",
    "f -1 -2 -3",
    "f 0 0 0",
    "f 1/2/3 4//5 6/7",
    "v",
    "v 1 2",
    "v 1e39 0 0",
    "vn 0 0 1",
    "o",
    "g group",
    "usemtl",
    "usemtl light",
    "usemtl nothing",
    "mtllib",
    "mtllib nothing.mtl",
    "mtllib cornell-box.mtl",
    "newmtl",
    "newmtl x",
    "Kd",
    "Kd 0.5",
    "Kd 2 2 2",
    "Kd -1 0 0",
    "Ke 1e39 0 0",
    "Ke NaN 1 1",
    "Ks 1 1",
    "Ns",
    "Ni 1.5",
    "d 0",
    "illum 2",
    "Kd spectral a.spd",
    "[render]",
    "width = 0",
    "height = 4294967295",
    "spp = 0",
    "max_depth = 99999",
    "[camera]",
    "fov_y = 180",
    "fov_y = 0",
    "up = [0, 0, 0]",
    "position = [1, 2]",
    "[sarsa]",
    "epsilon = 2",
    "grid = [0, 1]",
    "volumes = 0",
    "[neural]",
    "width = 6",
    "batch = 0",
    "[[procedural]]",
    "kind = \"bumpy-sphere\"",
    "segments = 3",
    "rings = 99999999",
    "environment = [1, 1, 1]",
    "mesh = \"\"",
    "mesh = \"/\"",
    "mesh = \"cornell-box.mtl\"",
    "[unknown]",
    "<shape type=\"sphere\"><float name=\"radius\" value=\"1e30\"/></shape>",
    "<shape type=\"ply\"><string name=\"filename\" value=\"torus.ply\"/></shape>",
    "<shape type=\"serialized\"><string name=\"filename\" value=\"shapes.serialized\"/><integer name=\"shape_index\" value=\"7\"/></shape>",
    "<include filename=\"scene.xml\"/>",
    "<path value=\"..\"/>",
    "<scene version=\"0.5.0\">",
    "<lookAt origin=\"0,0,0\" target=\"0,0,1\"/>",
    "<float name=\"uscale\" value=\"1e30\"/>",
    "<emitter type=\"sunsky\"><float name=\"hour\" value=\"1e30\"/></emitter>",
    "<emitter type=\"sunsky\"><integer name=\"year\" value=\"2147483647\"/><boolean name=\"complex_sun\" value=\"true\"/></emitter>",
    "<vector name=\"sun_direction\" x=\"0\" y=\"0\" z=\"-1\"/>",
    "<float name=\"sun_aperture\" value=\"179.9\"/>",
    "<path value=\"/\"/>",
    "<include filename=\"materials.xml\"/>",
    "<default name=\"res\" value=\"$res\"/>",
    "<bsdf type=\"twosided\" id=\"x\"><bsdf type=\"twosided\"/></bsdf>",
    "<ref id=\"x\"/>",
    "<alias id=\"x\" as=\"y\"/>",
    "<bsdf type=\"twosided\" id=\"y\"><ref id=\"y\"/></bsdf>",
    "<bsdf type=\"roughdielectric\"><float name=\"alpha\" value=\"1e-30\"/></bsdf>",
    "<bsdf type=\"roughplastic\"><float name=\"int_ior\" value=\"1e30\"/></bsdf>",
    "<transform name=\"to_world\"><scale value=\"0\"/></transform>",
    "<transform name=\"to_world\"><lookat origin=\"0,0,0\" target=\"0,0,0\"/></transform>",
    "<emitter type=\"area\"><rgb name=\"radiance\" value=\"1e39\"/></emitter>",
    "<rfilter type=\"gaussian\"><float name=\"stddev\" value=\"1e30\"/></rfilter>",
    "<integer name=\"max_depth\" value=\"-2\"/>",
    "</scene>",
    "<texture type=\"mesh_attribute\" name=\"reflectance\"><string name=\"name\" value=\"vertex_color\"/></texture>",
    "<texture type=\"mesh_attribute\" name=\"alpha\"><string name=\"name\" value=\"face_color\"/></texture>",
    "<integer name=\"crop_width\" value=\"4294967295\"/>",
    "<integer name=\"crop_offset_y\" value=\"-1\"/>",
    "<bsdf type=\"null\"/>",
    "<rfilter type=\"lanczos\"><integer name=\"lobes\" value=\"0\"/></rfilter>",
    "<spectrum name=\"reflectance\" type=\"blackbody\"><float name=\"temperature\" value=\"1e-30\"/></spectrum>",
    "<spectrum name=\"radiance\" type=\"regular\"><float name=\"wavelength_min\" value=\"830\"/><float name=\"wavelength_max\" value=\"831\"/><string name=\"values\" value=\"1 2\"/></spectrum>",
    "<spectrum name=\"reflectance\" type=\"irregular\"><string name=\"wavelengths\" value=\"1,1\"/><string name=\"values\" value=\"1,2\"/></spectrum>",
    "<texture type=\"srgb\" id=\"x\"><rgb name=\"color\" value=\"1e30\"/><boolean name=\"unbounded\" value=\"true\"/></texture>",
    "<spectrum name=\"radiance\" type=\"d65\"><float name=\"scale\" value=\"-1\"/></spectrum>",
    "property float r",
    "property uchar green",
    "property float q_0",
    "element vertex 4294967295",
    "element face 1",
    "property list uchar int vertex_indices",
    "property double x",
    "format binary_big_endian 1.0",
    "end_header",
];

/// Applies one random mutation to `data`.
pub fn mutate(rng: &mut Rng, data: &mut Vec<u8>) {
    let len = data.len();
    match rng.below(9) {
        // Overwrite a byte.
        0 if len > 0 => {
            let i = rng.below(len);
            data[i] = match rng.below(4) {
                0 => rng.next_u64() as u8,
                1 => b"0123456789.-e "[rng.below(14)],
                2 => b"\n#/=[]\"{}"[rng.below(9)],
                _ => data[rng.below(len)],
            };
        }
        // Delete a range.
        1 if len > 0 => {
            let i = rng.below(len);
            let n = 1 + rng.below(16.min(len - i));
            data.drain(i..i + n);
        }
        // Duplicate a range elsewhere.
        2 if len > 0 => {
            let i = rng.below(len);
            let n = 1 + rng.below(64.min(len - i));
            let piece = data[i..i + n].to_vec();
            let at = rng.below(len + 1);
            data.splice(at..at, piece);
        }
        // Truncate.
        3 => data.truncate(rng.below(len + 1)),
        // Replace a number with an edge case.
        4 | 5 => {
            let starts: Vec<usize> = (0..len)
                .filter(|&i| {
                    data[i].is_ascii_digit() && (i == 0 || !data[i - 1].is_ascii_alphanumeric())
                })
                .collect();
            if let Some(&i) = starts.get(rng.below(starts.len())) {
                let mut j = i;
                while j < len && (data[j].is_ascii_digit() || data[j] == b'.') {
                    j += 1;
                }
                let with = NUMBERS[rng.below(NUMBERS.len())].as_bytes().to_vec();
                data.splice(i..j, with);
            }
        }
        // Insert a meaningful line at a line start.
        6 | 7 => {
            let starts: Vec<usize> = std::iter::once(0)
                .chain((0..len).filter(|&i| data[i] == b'\n').map(|i| i + 1))
                .collect();
            let at = starts[rng.below(starts.len())];
            let line = format!("{}\n", LINES[rng.below(LINES.len())]);
            data.splice(at..at, line.into_bytes());
        }
        // Swap two lines.
        _ => {
            let text = String::from_utf8_lossy(data).to_string();
            let mut lines: Vec<&str> = text.split('\n').collect();
            if lines.len() > 1 {
                let (a, b) = (rng.below(lines.len()), rng.below(lines.len()));
                lines.swap(a, b);
                *data = lines.join("\n").into_bytes();
            }
        }
    }
}

/// What one input did.
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome {
    Loaded,
    /// The loader refused it with this one-line error.
    Refused(String),
    Panicked(String),
}

/// Loads a scene whose files are `files` (its scene file, `main`, as
/// `mem/{main_name}`) and resolves its default render settings, catching
/// any panic.
pub fn load(
    main: &[u8],
    main_name: &str,
    files: &HashMap<String, Vec<u8>>,
    max_triangles: usize,
) -> Outcome {
    let read = |path: &Path| -> std::io::Result<Vec<u8>> {
        let name = path.file_name().map(|n| n.to_string_lossy().to_string());
        let bytes = match name.as_deref() {
            Some(n) if n == main_name && path.parent() == Some(Path::new("mem")) => main,
            Some(n) if path.parent() == Some(Path::new("mem")) => match files.get(n) {
                Some(b) => b,
                None => return Err(std::io::ErrorKind::NotFound.into()),
            },
            _ => return Err(std::io::ErrorKind::NotFound.into()),
        };
        Ok(bytes.to_vec())
    };
    let loader = Loader {
        read: &read,
        max_triangles,
        defines: &[],
    };
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let scene = Scene::load_with(&Path::new("mem").join(main_name), &loader)
            .map_err(|e| e.to_string())?;
        RenderSettings::resolve(&scene, &Overrides::default()).map_err(|e| e.to_string())?;
        Ok::<(), String>(())
    }));
    match result {
        Ok(Ok(())) => Outcome::Loaded,
        Ok(Err(e)) => Outcome::Refused(e),
        Err(p) => Outcome::Panicked(
            p.downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default(),
        ),
    }
}

/// An input worth keeping: it panicked, or took longer than the limit.
#[derive(Clone, Debug)]
pub struct Finding {
    pub input: usize,
    pub what: String,
    /// The scene file, named `main_name`.
    pub main: Vec<u8>,
    pub main_name: &'static str,
    pub files: HashMap<String, Vec<u8>>,
}

#[derive(Clone, Debug, Default)]
pub struct Report {
    pub inputs: usize,
    pub loaded: usize,
    pub refused: usize,
    pub findings: Vec<Finding>,
    pub slowest: Duration,
    /// Errors that were not one line, and the first of them.
    pub multiline: usize,
    pub multiline_example: Option<String>,
}

/// Runs `inputs` mutants of `corpus` from `seed`; `slow` is how long one may
/// take; `after` sees each input's index and outcome (for progress and
/// allocation checks) and may add a finding by returning it.
pub fn run(
    corpus: &[Corpus],
    seed: u64,
    inputs: usize,
    max_triangles: usize,
    slow: Duration,
    after: &mut dyn FnMut(usize, &Outcome) -> Option<String>,
) -> Report {
    let mut rng = Rng::new(seed);
    let mut report = Report::default();
    // Panics are caught and reported; their default message would flood the output.
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    for input in 0..inputs {
        let base = &corpus[rng.below(corpus.len())];
        let mut main = base.main.clone().into_bytes();
        let mut files: HashMap<String, Vec<u8>> = base.files.iter().cloned().collect();
        let names: Vec<String> = {
            let mut n: Vec<String> = files.keys().cloned().collect();
            n.sort();
            n
        };
        for _ in 0..1 + rng.below(4) {
            let pick = rng.below(names.len() + 1);
            match names.get(pick) {
                Some(n) => mutate(&mut rng, files.get_mut(n).expect("a corpus file")),
                None => mutate(&mut rng, &mut main),
            }
        }
        let start = Instant::now();
        let outcome = load(&main, base.main_name, &files, max_triangles);
        let took = start.elapsed();
        report.slowest = report.slowest.max(took);
        let mut what = match &outcome {
            Outcome::Loaded => {
                report.loaded += 1;
                None
            }
            Outcome::Refused(e) => {
                report.refused += 1;
                if e.contains('\n') {
                    report.multiline += 1;
                    report.multiline_example.get_or_insert_with(|| e.clone());
                }
                None
            }
            Outcome::Panicked(m) => Some(format!("panicked: {m}")),
        };
        if took > slow {
            what = Some(format!("took {:.2} s", took.as_secs_f64()));
        }
        if let Some(extra) = after(input, &outcome) {
            what = Some(extra);
        }
        if let Some(what) = what {
            report.findings.push(Finding {
                input,
                what,
                main: main.clone(),
                main_name: base.main_name,
                files: files.clone(),
            });
        }
        report.inputs += 1;
    }
    std::panic::set_hook(hook);
    report
}
