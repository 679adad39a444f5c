//! Mitsuba 3 XML scenes: what the reader makes of them, the errors it gives,
//! and agreement with Mitsuba 3's own renders of the same files (references
//! rendered by scripts/mitsuba_reference.py, kept in tests/fixtures/mitsuba/
//! with how they were made, so no test needs Mitsuba).

mod common;

use glam::{Vec2, Vec3};
use qtrace::image::Image;
use qtrace::render::{Method, Overrides, RenderOutput};
use qtrace::scene::{FovAxis, Loader, PixelFilter};
use qtrace::Scene;
use std::path::{Path, PathBuf};

fn cornell() -> PathBuf {
    common::repo("scenes/mitsuba/cornell-box/scene.xml")
}

#[test]
fn bitterli_cornell_box_reads_as_mitsuba_reads_it() {
    let scene = Scene::load(cornell()).unwrap();
    let d = &scene.defaults;
    assert_eq!(
        (d.width, d.height, d.spp),
        (Some(1024), Some(1024), Some(64))
    );
    // Mitsuba's max_depth 30 counts the camera ray: 29 bounces.
    assert_eq!(d.max_depth, Some(29));
    // Five rectangles, two cubes and the light.
    assert_eq!(scene.triangles.len(), 5 * 2 + 2 * 12 + 2);
    assert_eq!(scene.lights.len(), 2);
    let light =
        &scene.materials[scene.triangles[scene.lights[0].triangle as usize].material as usize];
    assert_eq!(light.emission, Vec3::new(17.0, 12.0, 4.0));
    // The light faces down.
    let t = &scene.triangles[scene.lights[0].triangle as usize];
    let n = Vec3::from(t.e1).cross(Vec3::from(t.e2));
    assert!(n.normalize().y < -0.999, "{n}");
    let c = &scene.camera;
    assert!((c.position - Vec3::new(0.0, 1.0, 6.8)).length() < 1e-5);
    assert!((c.forward - Vec3::new(0.0, 0.0, -1.0)).length() < 1e-5);
    assert!((c.right - Vec3::new(1.0, 0.0, 0.0)).length() < 1e-5);
    assert_eq!((c.fov_degrees, c.fov_axis), (19.5, FovAxis::X));
    assert_eq!(scene.filter, PixelFilter::Tent { radius: 1.0 });
}

#[test]
fn defines_override_the_scene_defaults() {
    let defines = [
        ("resx".to_string(), "48".to_string()),
        ("max_depth".to_string(), "-1".to_string()),
    ];
    let scene = Scene::load_defined(cornell(), &defines).unwrap();
    assert_eq!(scene.defaults.width, Some(48));
    assert_eq!(scene.defaults.height, Some(1024));
    assert_eq!(
        scene.defaults.max_depth,
        Some(qtrace::scene::MITSUBA_UNLIMITED_DEPTH)
    );
    // A define is part of what the scene is.
    assert_ne!(
        scene.fingerprint,
        Scene::load(cornell()).unwrap().fingerprint
    );
}

/// Loads `text` as `mem/s.xml` (with `mem/m.obj`, a triangle, and
/// `mem/inc.xml`, an include with one BSDF, beside it).
fn load_text(text: &str) -> Result<Scene, String> {
    let owned = text.to_string();
    let read = move |p: &Path| -> std::io::Result<Vec<u8>> {
        match p.file_name().and_then(|n| n.to_str()) {
            Some("s.xml") => Ok(owned.clone().into_bytes()),
            Some("m.obj") => Ok(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n".to_vec()),
            // The same triangle, its normals against its winding.
            Some("vn.obj") => Ok(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 -1\nf 1//1 2//1 3//1\n".to_vec()),
            // One triangle of zero area among two.
            Some("d.obj") => Ok(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\n".to_vec()),
            // Quads with texture coordinates.
            Some("qt.obj") => Ok(b"v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n".to_vec()),
            Some("q.ply") => Ok(b"ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nproperty float u\nproperty float v\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n-1 -1 0 0 0\n1 -1 0 1 0\n1 1 0 1 1\n-1 1 0 0 1\n3 0 1 2\n3 0 2 3\n".to_vec()),
            // A triangle with an RGBA colour and a weight per vertex and a
            // colour per face.
            Some("c.ply") => Ok(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nproperty float r\nproperty float g\nproperty float b\nproperty float a\nproperty float w_0\nelement face 1\nproperty list uchar int vertex_indices\nproperty float k_r\nproperty float k_g\nproperty float k_b\nend_header\n0 0 0 1 0 0 1 0.2\n1 0 0 0 1 0 1 0.5\n0 1 0 0 0 1 1 0.9\n3 0 1 2 0.1 0.2 0.3\n".to_vec()),
            // A spectrum file, as Mitsuba writes them.
            Some("s.spd") => Ok(b"# reflectance\n400 0.5\n500 0.7\n\n600 0.2\n700 0.9 # red\n".to_vec()),
            Some("small.png") => std::fs::read(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/tests/fixtures/textures/small.png"
            )),
            Some("inc.xml") => {
                Ok(br#"<scene version="3.0.0"><bsdf type="diffuse" id="inc"/></scene>"#.to_vec())
            }
            _ => Err(std::io::Error::new(
                std::io::ErrorKind::NotFound,
                "not found",
            )),
        }
    };
    Scene::load_with(
        Path::new("mem/s.xml"),
        &Loader {
            read: &read,
            max_triangles: 100_000,
            defines: &[],
        },
    )
    .map_err(|e| e.to_string())
}

/// `m.obj`'s triangle in a scene of `with_body` whose shape also holds
/// `inside`: the one with a corner at the origin (the light's rectangle
/// has its corners at (±1, ±1, 0)).
fn m_obj_triangle(inside: &str) -> qtrace::shaders::Triangle {
    let scene = load_text(&with_body(&format!(
        "<shape type=\"obj\"><string name=\"filename\" value=\"m.obj\"/>{inside}</shape>"
    )))
    .unwrap();
    *scene
        .triangles
        .iter()
        .find(|t| Vec3::from(t.v0) == Vec3::ZERO)
        .unwrap()
}

/// A scene with a camera and a light, and `body` after them (from line 5 on).
fn with_body(body: &str) -> String {
    format!(
        "<scene version=\"3.0.0\">\n<sensor type=\"perspective\"/>\n\
         <shape type=\"rectangle\"><emitter type=\"area\"><rgb name=\"radiance\" value=\"1\"/></emitter></shape>\n\
         <default name=\"x\" value=\"0.5\"/>\n{body}\n</scene>\n"
    )
}

/// The sensor, film, integrator and emitter parameters that exporters write
/// and that do not change the image (a pinhole's focus and shutter, how often
/// NEE picks an emitter) load without a word (Mitsuba 3.9.1 loads this
/// scene too).
#[test]
fn an_exporters_sensor_and_film_load() {
    let scene = load_text(
        r#"<scene version="3.0.0">
<integrator type="path"><integer name="max_depth" value="65"/><boolean name="hide_emitters" value="false"/></integrator>
<sensor type="perspective">
  <string name="fov_axis" value="smaller"/>
  <float name="near_clip" value="0.001"/><float name="far_clip" value="100.0"/>
  <float name="focus_distance" value="1000"/>
  <float name="shutter_open" value="0"/><float name="shutter_close" value="0"/>
  <float name="fov" value="39.3077"/>
  <transform name="to_world"><lookat origin="0, 1, 6.8" target="0, 1, 0" up="0, 1, 0"/></transform>
  <sampler type="independent"><integer name="sample_count" value="64"/><integer name="seed" value="3"/></sampler>
  <film type="hdrfilm">
    <integer name="width" value="64"/><integer name="height" value="48"/>
    <string name="file_format" value="openexr"/><string name="pixel_format" value="rgb"/>
    <string name="component_format" value="float16"/><boolean name="sample_border" value="false"/><boolean name="compensate" value="true"/>
    <rfilter type="tent"/>
  </film>
</sensor>
<shape type="rectangle"><emitter type="area"><rgb name="radiance" value="1"/><float name="sampling_weight" value="2"/></emitter></shape>
<emitter type="point"><float name="sampling_weight" value="0.5"/></emitter>
<shape type="sphere"><bsdf type="diffuse"><texture type="bitmap" name="reflectance">
  <string name="filename" value="small.png"/><string name="format" value="fp16"/><boolean name="accel" value="false"/>
</texture></bsdf></shape>
</scene>"#,
    )
    .unwrap();
    assert_eq!(scene.camera.fov_degrees, 39.3077);
}

/// Without media, volpath and volpathmis are path; direct is path with one
/// bounce; other integrators leave qtrace's default depth.
#[test]
fn integrators_that_path_tracing_equals_keep_their_depth() {
    for (integrator, want) in [
        ("<integrator type=\"volpath\"><integer name=\"max_depth\" value=\"5\"/></integrator>", Some(4)),
        ("<integrator type=\"volpathmis\"><integer name=\"max_depth\" value=\"3\"/><integer name=\"rr_depth\" value=\"9\"/></integrator>", Some(2)),
        ("<integrator type=\"direct\"><integer name=\"emitter_samples\" value=\"4\"/></integrator>", Some(1)),
        ("<integrator type=\"aov\"/>", None),
        // The differentiable and wrapping integrators estimate path's image.
        ("<integrator type=\"prb\"><integer name=\"max_depth\" value=\"4\"/></integrator>", Some(3)),
        ("<integrator type=\"prb_projective\"><integer name=\"max_depth\" value=\"6\"/><integer name=\"sppc\" value=\"8\"/></integrator>", Some(5)),
        ("<integrator type=\"direct_projective\"><integer name=\"max_depth\" value=\"6\"/></integrator>", Some(1)),
        ("<integrator type=\"aov\"><string name=\"aovs\" value=\"dd.y:depth\"/><integrator type=\"path\"><integer name=\"max_depth\" value=\"3\"/></integrator></integrator>", Some(2)),
        ("<integrator type=\"moment\"><integrator type=\"prb_basic\"><integer name=\"max_depth\" value=\"2\"/></integrator></integrator>", Some(1)),
    ] {
        let scene = load_text(&with_body(integrator)).unwrap();
        assert_eq!(scene.defaults.max_depth, want, "{integrator}");
    }
}

/// Mitsuba 3.9.1's `sample_ray` through a perspective sensor with a
/// principal point offset (0.25, -0.1) on a 64x128 film, fov 90 along x:
/// at the image's centre the ray's tangents are (-0.5, 0.4) in the camera's
/// frame (x to the image's left), at the middle of its right edge (-1.5,
/// 0.4), at the middle of its bottom edge (-0.5, -1.6).
#[test]
fn a_principal_point_offset_shifts_the_view_as_mitsubas() {
    let text = with_body("").replace(
        "<sensor type=\"perspective\"/>",
        "<sensor type=\"perspective\"><float name=\"fov\" value=\"90\"/><float name=\"principal_point_offset_x\" value=\"0.25\"/><float name=\"principal_point_offset_y\" value=\"-0.1\"/></sensor>",
    );
    let scene = load_text(&text).unwrap();
    for ((x, y), want) in [
        ((32.0, 64.0), Vec2::new(-0.5, 0.4)),
        ((64.0, 64.0), Vec2::new(-1.5, 0.4)),
        ((32.0, 128.0), Vec2::new(-0.5, -1.6)),
    ] {
        let (_, d) = scene.camera.ray(x, y, 64, 128);
        let got = Vec2::new(d.x, d.y) / d.z;
        assert!(
            (got - want).abs().max_element() < 1e-4,
            "({x}, {y}): {got} vs {want}"
        );
    }
}

#[test]
fn a_scene_with_every_supported_shape_and_bsdf_loads() {
    let scene = load_text(&with_body(
        r#"<include filename="inc.xml"/>
<shape type="obj"><string name="filename" value="m.obj"/><ref id="inc"/></shape>
<shape type="cube"><bsdf type="roughconductor"><string name="material" value="Au"/></bsdf></shape>
<shape type="cube"><bsdf type="plastic"><boolean name="nonlinear" value="true"/></bsdf></shape>
<shape type="sphere"><bsdf type="dielectric"/></shape>
<shape type="cylinder"><float name="radius" value="0.5"/></shape>
<shape type="shapegroup" id="g"><shape type="sphere"/><shape type="cube"><ref id="inc"/></shape></shape>
<shape type="instance"><ref id="g"/><transform name="to_world"><translate x="5"/></transform></shape>
<shape type="instance"><ref id="g"/></shape>
<shape type="cube"><bsdf type="roughdielectric"><float name="alpha_u" value="0.1"/><float name="alpha_v" value="0.3"/></bsdf></shape>
<shape type="cube"><bsdf type="roughplastic"><string name="distribution" value="ggx"/></bsdf></shape>
<shape type="disk"><bsdf type="twosided"><bsdf type="diffuse"><rgb name="reflectance" value="$x"/></bsdf></bsdf></shape>
<shape type="sphere"><bsdf type="null"/><emitter type="area"><rgb name="radiance" value="2"/></emitter></shape>"#,
    ))
    .unwrap();
    // The spheres and the disk are tessellated.
    assert!(scene.triangles.len() > 2 + 1 + 12 + 2000);
    assert!(scene.has_non_diffuse());
}

/// The texture coordinates of the built-in shapes and of PLY and OBJ meshes are
/// Mitsuba's: 3.9.1's `si.uv` where a ray meets each (the curved shapes'
/// interpolated across their tessellation, so nearly).
#[test]
fn texture_coordinates_are_mitsubas() {
    let moved = r#"<transform name="to_world"><translate x="10"/></transform>"#;
    let cases: [(&str, Vec3, Vec3, [f32; 2], f32); 17] = [
        ("<shape type=\"rectangle\">{}</shape>", Vec3::new(0.3, -0.6, 2.0), -Vec3::Z, [0.65, 0.2], 1e-5),
        ("<shape type=\"disk\">{}</shape>", Vec3::new(0.3, -0.4, 2.0), -Vec3::Z, [0.5, 0.85242], 2e-3),
        ("<shape type=\"sphere\">{}</shape>", Vec3::new(0.3, -0.4, 3.0), -Vec3::Z, [0.85242, 0.16667], 2e-3),
        ("<shape type=\"sphere\">{}</shape>", Vec3::new(3.0, 0.2, 0.5), -Vec3::X, [0.03709, 0.33333], 2e-3),
        ("<shape type=\"cylinder\">{}</shape>", Vec3::new(3.0, 0.2, 0.5), -Vec3::X, [0.03205, 0.5], 2e-3),
        ("<shape type=\"cylinder\">{}</shape>", Vec3::new(-0.3, -3.0, 0.25), Vec3::Y, [0.70151, 0.25], 2e-3),
        ("<shape type=\"cylinder\"><point name=\"p0\" x=\"-0.9\" y=\"0.15\" z=\"0.9\"/><point name=\"p1\" x=\"-0.1\" y=\"0.3\" z=\"0.5\"/><float name=\"radius\" value=\"0.15\"/>{}</shape>", Vec3::new(-0.5, 2.0, 0.7), -Vec3::Y, [0.73363, 0.52774], 2e-3),
        ("<shape type=\"cube\">{}</shape>", Vec3::new(0.3, -0.6, 3.0), -Vec3::Z, [0.2, 0.65], 1e-5),
        ("<shape type=\"cube\">{}</shape>", Vec3::new(3.0, 0.3, -0.6), -Vec3::X, [0.65, 0.8], 1e-5),
        ("<shape type=\"cube\">{}</shape>", Vec3::new(0.3, 3.0, -0.6), -Vec3::Y, [0.35, 0.8], 1e-5),
        ("<shape type=\"cube\">{}</shape>", Vec3::new(0.3, -0.6, -3.0), Vec3::Z, [0.8, 0.65], 1e-5),
        ("<shape type=\"cube\">{}</shape>", Vec3::new(-3.0, 0.3, -0.6), Vec3::X, [0.65, 0.2], 1e-5),
        ("<shape type=\"cube\">{}</shape>", Vec3::new(0.3, -3.0, -0.6), Vec3::Y, [0.2, 0.65], 1e-5),
        ("<shape type=\"ply\"><string name=\"filename\" value=\"q.ply\"/>{}</shape>", Vec3::new(0.3, -0.6, 2.0), -Vec3::Z, [0.65, 0.2], 1e-5),
        ("<shape type=\"obj\"><string name=\"filename\" value=\"qt.obj\"/>{}</shape>", Vec3::new(0.3, -0.6, 2.0), -Vec3::Z, [0.65, 0.8], 1e-5),
        ("<shape type=\"obj\"><string name=\"filename\" value=\"qt.obj\"/><boolean name=\"flip_tex_coords\" value=\"false\"/>{}</shape>", Vec3::new(0.3, -0.6, 2.0), -Vec3::Z, [0.65, 0.2], 1e-5),
        ("<shape type=\"ply\"><string name=\"filename\" value=\"q.ply\"/><boolean name=\"flip_tex_coords\" value=\"true\"/>{}</shape>", Vec3::new(0.3, -0.6, 2.0), -Vec3::Z, [0.65, 0.8], 1e-5),
    ];
    for (shape, o, d, want, tolerance) in cases {
        // Textured, as a scene keeps texture coordinates only for textures.
        let textured = format!(
            "{moved}<bsdf type=\"diffuse\"><texture type=\"checkerboard\" name=\"reflectance\"/></bsdf>"
        );
        let body = shape.replace("{}", &textured);
        let scene = load_text(&with_body(&body)).unwrap();
        let o = o + Vec3::new(10.0, 0.0, 0.0);
        let (t, i) = scene.intersect_brute(o, d).unwrap();
        let tri = &scene.triangles[i as usize];
        let p = o + t * d - Vec3::from(tri.v0);
        let (e1, e2) = (Vec3::from(tri.e1), Vec3::from(tri.e2));
        // Barycentric coordinates of p in the triangle.
        let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
        let (p1, p2) = (p.dot(e1), p.dot(e2));
        let det = d11 * d22 - d12 * d12;
        let (b1, b2) = ((d22 * p1 - d12 * p2) / det, (d11 * p2 - d12 * p1) / det);
        let [a, b, c] = scene.uvs[i as usize];
        let uv = a * (1.0 - b1 - b2) + b * b1 + c * b2;
        assert!(
            (uv - Vec2::from(want)).abs().max_element() < tolerance,
            "{body}: {uv} vs Mitsuba's {want:?}"
        );
    }
}

/// wavelength:value spectra become the RGB Mitsuba 3.9.1's RGB variants
/// make of them (values read from `mi.traverse`): lit by D65 and bounded
/// for a reflectance, as they are for a radiance.
#[test]
fn spectra_turn_into_mitsubas_rgb() {
    let case = |reflectance: &str, radiance: &str| {
        let body = format!(
            "<shape type=\"cube\"><bsdf type=\"diffuse\"><spectrum name=\"reflectance\" value=\"{reflectance}\"/></bsdf>\
             <emitter type=\"area\"><spectrum name=\"radiance\" value=\"{radiance}\"/></emitter></shape>"
        );
        let scene = load_text(&with_body(&body)).unwrap();
        let m = scene.materials.last().unwrap();
        let qtrace::bsdf::Surface::Diffuse { albedo } = m.surface else {
            panic!("{:?}", m.surface)
        };
        (albedo, m.emission)
    };
    let close = |a: Vec3, b: [f32; 3]| (a - Vec3::from(b)).abs().max_element() < 2e-4;
    let (a, e) = case("400:0.5, 700:0.5", "400:1, 700:1");
    assert!(close(a, [0.497671, 0.499878, 0.497455]), "{a}");
    assert!(close(e, [1.19969, 0.949521, 0.903443]), "{e}");
    // One value: a grey reflectance, but an emitted flat spectrum's colour.
    let (a, e) = case("0.5", "5");
    assert!(close(a, [0.5; 3]), "{a}");
    assert!(close(e, [6.02397, 4.74146, 4.54458]), "{e}");
    let s = "400:0.1, 500:0.5, 600:0.9, 700:0.2";
    let (a, e) = case(s, s);
    assert!(close(a, [0.833828, 0.68912, 0.265243]), "{a}");
    assert!(close(e, [0.974324, 0.661608, 0.229711]), "{e}");
    // From a file (Mitsuba 3.9.1 reads this one as 0.219942, 0.493022,
    // 0.626373).
    let scene = load_text(&with_body(
        "<shape type=\"cube\"><bsdf type=\"diffuse\"><spectrum name=\"reflectance\" filename=\"s.spd\"/></bsdf></shape>",
    ))
    .unwrap();
    let qtrace::bsdf::Surface::Diffuse { albedo } = scene.materials.last().unwrap().surface else {
        panic!("not diffuse")
    };
    assert!(close(albedo, [0.219942, 0.493022, 0.626373]), "{albedo}");
}

/// Spectrum plugins that are one colour in Mitsuba's RGB variants
/// (`uniform`, `d65`, `srgb`: values from `mi.traverse`, Mitsuba 3.9.1), and
/// those its RGB variants cannot evaluate (`irregular`, `regular`,
/// `blackbody`) as their wavelength:value pairs; a blackbody light as
/// Mitsuba's `scalar_spectral` renders it (8 x 1024 spp of a sky seen
/// directly: 733.76, 349.93, 112.79 at 3000 K, standard errors under 0.2).
#[test]
fn spectrum_plugins_turn_into_mitsubas_rgb() {
    let case = |reflectance: &str, radiance: &str| {
        let body = format!(
            "<shape type=\"cube\"><bsdf type=\"diffuse\">{}</bsdf>\
             <emitter type=\"area\">{}</emitter></shape>",
            reflectance.replace("NAME", "reflectance"),
            radiance.replace("NAME", "radiance")
        );
        let scene = load_text(&with_body(&body)).unwrap();
        let m = scene.materials.last().unwrap();
        let qtrace::bsdf::Surface::Diffuse { albedo } = m.surface else {
            panic!("{:?}", m.surface)
        };
        (albedo, m.emission)
    };
    let close = |a: Vec3, b: [f32; 3], tolerance: f32| {
        (a - Vec3::from(b)).abs().max_element() <= tolerance * Vec3::from(b).max_element()
    };
    let uniform =
        "<spectrum name=\"NAME\" type=\"uniform\"><float name=\"value\" value=\"0.3\"/></spectrum>";
    let (a, e) = case(uniform, uniform);
    assert!(
        close(a, [0.3; 3], 1e-6) && close(e, [0.3; 3], 1e-6),
        "{a} {e}"
    );
    let d65 = "<spectrum name=\"NAME\" type=\"d65\"><rgb name=\"color\" value=\"0.5, 0.2, 0.1\"/><float name=\"scale\" value=\"1.5\"/></spectrum>";
    let srgb = "<texture name=\"NAME\" type=\"srgb\"><rgb name=\"color\" value=\"0.5, 0.2, 0.1\"/></texture>";
    let (a, e) = case(srgb, d65);
    assert!(
        close(a, [0.5, 0.2, 0.1], 1e-6) && close(e, [0.75, 0.3, 0.15], 1e-6),
        "{a} {e}"
    );
    let (_, e) = case("", "<spectrum name=\"NAME\" type=\"d65\"/>");
    assert!(close(e, [1.0; 3], 1e-6), "{e}");
    // The same spectrum three ways.
    let pairs = "<spectrum name=\"NAME\" value=\"400:0.1, 500:0.5, 600:0.9, 700:0.2\"/>";
    let irregular = "<spectrum name=\"NAME\" type=\"irregular\"><string name=\"wavelengths\" value=\"400, 500, 600, 700\"/><string name=\"values\" value=\"0.1, 0.5, 0.9, 0.2\"/></spectrum>";
    let regular = "<spectrum name=\"NAME\" type=\"regular\"><float name=\"wavelength_min\" value=\"400\"/><float name=\"wavelength_max\" value=\"700\"/><string name=\"values\" value=\"0.1 0.5 0.9 0.2\"/></spectrum>";
    let want = case(pairs, pairs);
    assert!(
        close(want.0, [0.833828, 0.68912, 0.265243], 2e-4),
        "{want:?}"
    );
    assert_eq!(case(irregular, irregular), want);
    assert_eq!(case(regular, regular), want);
    let blackbody = "<spectrum name=\"NAME\" type=\"blackbody\"><float name=\"temperature\" value=\"3000\"/></spectrum>";
    let (_, e) = case("", blackbody);
    assert!(close(e, [733.76, 349.93, 112.79], 2e-3), "{e}");
    // A top-level one, named by a <ref>.
    let scene = load_text(&with_body(
        "<texture type=\"srgb\" id=\"c\"><rgb name=\"color\" value=\"0.2, 0.4, 0.6\"/></texture>\
         <shape type=\"cube\"><bsdf type=\"diffuse\"><ref name=\"reflectance\" id=\"c\"/></bsdf></shape>",
    ))
    .unwrap();
    let qtrace::bsdf::Surface::Diffuse { albedo } = scene.materials.last().unwrap().surface else {
        panic!("not diffuse")
    };
    assert!(close(albedo, [0.2, 0.4, 0.6], 1e-6), "{albedo}");
    // What Mitsuba refuses, qtrace refuses.
    for (body, want) in [
        ("<texture name=\"reflectance\" type=\"srgb\"><rgb name=\"color\" value=\"1.5, 0.2, 0.1\"/></texture>", "lies outside [0, 1]"),
        ("<spectrum name=\"reflectance\" type=\"uniform\"/>", "needs the property 'value'"),
        ("<spectrum name=\"reflectance\" type=\"irregular\"><string name=\"wavelengths\" value=\"400, 500\"/><string name=\"values\" value=\"0.1\"/></spectrum>", "2 wavelengths and 1 values"),
        ("<spectrum name=\"reflectance\" type=\"d65\"><float name=\"gamma\" value=\"2\"/></spectrum>", "'gamma', which qtrace does not support"),
    ] {
        let Err(e) = load_text(&with_body(&format!(
            "<shape type=\"cube\"><bsdf type=\"diffuse\">{body}</bsdf></shape>"
        ))) else {
            panic!("{body} loaded")
        };
        assert!(e.contains(want) && e.contains(":5:"), "{body}: {e}");
    }
}

/// A mirrored envmap (Blender's mapping node with a negative scale) turns
/// the sky over as Mitsuba does (its image within 0.02% of Mitsuba's mean
/// on coverage-f with `<scale x="-1"/>`, 2026-12-06); a scale is refused.
#[test]
fn a_mirrored_envmap_turns_the_sky_over() {
    let env = |transform: &str| {
        load_text(&with_body(&format!(
            "<emitter type=\"envmap\"><string name=\"filename\" value=\"small.png\"/><transform name=\"to_world\">{transform}</transform></emitter>"
        )))
        .map(|s| s.environment.unwrap())
    };
    let plain = env("").unwrap();
    let mirrored = env("<scale x=\"-1\"/>").unwrap();
    for d in [Vec3::new(0.3, 0.5, -0.8), Vec3::new(-0.9, -0.1, 0.4)] {
        let d = d.normalize();
        let m = Vec3::new(-d.x, d.y, d.z);
        assert_eq!(mirrored.to_local * d, plain.to_local * m);
    }
    assert!(env("<scale value=\"2\"/>").is_err());
}

/// Each BSDF evaluates as Mitsuba's does: f cos at 64 pairs of directions
/// (the CPU twin, which the GPU probes hold the kernels to) against
/// Mitsuba 3.9.1's `eval` (`scripts/mitsuba_bsdf_evals.py` wrote the
/// fixture), within 10⁻⁴ of the larger of the value and 10⁻³; rough
/// plastic within 1%: its diffuse term divides by the rough interface's
/// transmittance, which both renderers integrate numerically.
#[test]
fn bsdfs_evaluate_as_mitsubas() {
    let dir = common::scratch("mitsuba-bsdf-evals");
    let xml = dir.join("s.xml");
    let blocks = fixture_blocks("tests/fixtures/mitsuba/bsdf-evals.txt", "bsdf ");
    assert_eq!(blocks.len(), 15);
    for (case, lines) in blocks {
        std::fs::write(
            &xml,
            with_body(&format!("<shape type=\"rectangle\">{case}</shape>")),
        )
        .unwrap();
        let scene = Scene::load(&xml).unwrap_or_else(|e| panic!("{case}: {e}"));
        let m = scene
            .materials
            .iter()
            .find(|m| m.emission == Vec3::ZERO)
            .unwrap();
        let bsdf = m.bsdf(true, qtrace::bsdf::Sampling::Cosine);
        let tolerance = if case.contains("roughplastic") {
            1e-2
        } else {
            1e-4
        };
        for v in lines {
            let (wo, wi, want) = (
                Vec3::new(v[0], v[1], v[2]),
                Vec3::new(v[3], v[4], v[5]),
                Vec3::new(v[6], v[7], v[8]),
            );
            let got = bsdf.eval(wo, wi);
            let off = (got - want).abs().max_element() / want.abs().max_element().max(1e-3);
            assert!(
                off < tolerance,
                "{case}\nwo {wo}, wi {wi}: {got} against Mitsuba's {want}"
            );
        }
    }
}

/// The fixture's blocks: a header line `{prefix}<its XML>`, then lines of
/// numbers.
fn fixture_blocks(file: &str, prefix: &str) -> Vec<(String, Vec<Vec<f32>>)> {
    let text = std::fs::read_to_string(common::repo(file)).unwrap();
    let mut blocks: Vec<(String, Vec<Vec<f32>>)> = Vec::new();
    for line in text.lines() {
        match line.strip_prefix(prefix) {
            Some(xml) => blocks.push((xml.to_string(), Vec::new())),
            None => blocks.last_mut().unwrap().1.push(
                line.split_whitespace()
                    .map(|x| x.parse().unwrap())
                    .collect(),
            ),
        }
    }
    blocks
}

/// Loads `body` as a scene under a constant sky (a scene needs a light).
fn load_under_sky(dir: &Path, body: &str) -> Scene {
    let xml = dir.join("s.xml");
    std::fs::write(
        &xml,
        format!(r#"<scene version="3.0.0">{body}<emitter type="constant"/></scene>"#),
    )
    .unwrap();
    Scene::load(&xml).unwrap_or_else(|e| panic!("{body}: {e}"))
}

/// Camera rays through points of the film against Mitsuba's
/// `Sensor.sample_ray` (scripts/mitsuba_geometry_probes.py): every
/// `fov_axis`, `focal_length`, principal point offsets, crop windows, a thin
/// lens's centre and orthographic extents, on films of several shapes.
#[test]
fn cameras_cast_rays_as_mitsubas() {
    let dir = common::scratch("mitsuba-camera-rays");
    let blocks = fixture_blocks("tests/fixtures/mitsuba/camera-rays.txt", "sensor ");
    assert_eq!(blocks.len(), 16);
    for (xml, rays) in blocks {
        // A scene needs a shape too.
        let scene = load_under_sky(&dir, &format!("{xml}<shape type=\"rectangle\"/>"));
        let (w, h) = (
            scene.defaults.width.unwrap(),
            scene.defaults.height.unwrap(),
        );
        for v in rays {
            let (o, d) = scene.camera.ray(v[0], v[1], w, h);
            let (mo, md) = (Vec3::new(v[2], v[3], v[4]), Vec3::new(v[5], v[6], v[7]));
            // Mitsuba starts the ray at the near clip plane: the origins lie
            // on one line.
            let off = (o - mo).reject_from(md).length();
            assert!(
                (d - md).length() < 1e-5 && off < 1e-5,
                "{xml}\nat ({}, {}): ray {o} {d} against Mitsuba's {mo} {md}",
                v[0],
                v[1]
            );
        }
    }
}

/// Rays at Mitsuba's built-in shapes against its `Scene.ray_intersect`
/// (scripts/mitsuba_geometry_probes.py): where they hit, the texture
/// coordinates, normals and tangent (dp/du) there, for spheres, cylinders,
/// disks, rectangles and cubes, moved, stretched and with flipped normals.
/// qtrace tessellates the curved ones, whose hits and normals are then
/// within the tessellation's error.
#[test]
fn built_in_shapes_are_parameterised_as_mitsubas() {
    let dir = common::scratch("mitsuba-shape-hits");
    let blocks = fixture_blocks("tests/fixtures/mitsuba/shape-hits.txt", "shape ");
    assert_eq!(blocks.len(), 13);
    // The camera sets how finely spheres are tessellated.
    let sensor = r#"<sensor type="perspective"><transform name="to_world"><lookat origin="0, 0, 6" target="0, 0, 0" up="0, 1, 0"/></transform><film type="hdrfilm"><integer name="width" value="256"/><integer name="height" value="256"/></film></sensor>"#;
    // A texture, so that the scene keeps its texture coordinates.
    let bsdf = r#"<bsdf type="diffuse"><texture type="checkerboard" name="reflectance"/></bsdf>"#;
    for (xml, rays) in blocks {
        let textured = match xml.strip_suffix("/>") {
            Some(open) => format!("{open}>{bsdf}</shape>"),
            None => xml.replace("</shape>", &format!("{bsdf}</shape>")),
        };
        let scene = load_under_sky(&dir, &format!("{sensor}{textured}"));
        let curved = ["sphere", "cylinder", "disk"]
            .iter()
            .any(|k| xml.contains(k));
        for v in rays {
            let (o, d) = (Vec3::new(v[0], v[1], v[2]), Vec3::new(v[3], v[4], v[5]));
            let (t, k) = scene
                .triangles
                .iter()
                .enumerate()
                .filter_map(|(k, tri)| qtrace::scene::ray_triangle(o, d, tri).map(|t| (t, k)))
                .min_by(|a, b| a.0.total_cmp(&b.0))
                .unwrap_or_else(|| panic!("{xml}: the ray {o} {d} misses"));
            let tri = &scene.triangles[k];
            let (v0, e1, e2) = (Vec3::from(tri.v0), Vec3::from(tri.e1), Vec3::from(tri.e2));
            let r = o + t * d - v0;
            let (a, b, c) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
            let det = a * c - b * b;
            let b1 = (c * r.dot(e1) - b * r.dot(e2)) / det;
            let b2 = (a * r.dot(e2) - b * r.dot(e1)) / det;
            let mix = |x: [Vec3; 3]| (1.0 - b1 - b2) * x[0] + b1 * x[1] + b2 * x[2];
            let uvs = scene.uvs[k];
            let uv = (1.0 - b1 - b2) * uvs[0] + b1 * uvs[1] + b2 * uvs[2];
            let geometric = e1.cross(e2).normalize();
            let shading = if scene.normals.is_empty() {
                geometric
            } else {
                let n = scene.normals[k];
                mix([0, 1, 2].map(|i| qtrace::scene::unpack_normal(n[i]))).normalize()
            };
            // The tangent: dp/du of the triangle's own coordinates.
            let (du1, du2) = (uvs[1] - uvs[0], uvs[2] - uvs[0]);
            let tangent = ((e1 * du2.y - e2 * du1.y) / (du1.x * du2.y - du1.y * du2.x)).normalize();
            let mitsuba_uv = Vec2::new(v[7], v[8]);
            let (mn, mg, mdp) = (
                Vec3::new(v[9], v[10], v[11]),
                Vec3::new(v[12], v[13], v[14]),
                Vec3::new(v[15], v[16], v[17]),
            );
            // A sphere's u wraps around at its seam.
            let du = (uv.x - mitsuba_uv.x).abs();
            let uv_off = du.min(1.0 - du).max((uv.y - mitsuba_uv.y).abs());
            let (near, facet, uv_near) = if curved {
                (0.01, 0.05, 5e-3)
            } else {
                (1e-4, 1e-4, 1e-4)
            };
            let ok = (t - v[6]).abs() < near
                && uv_off < uv_near
                && (shading - mn).length() < near
                && (geometric - mg).length() < facet
                && (tangent - mdp.normalize().reject_from(shading).normalize()).length()
                    < 2.0 * facet;
            assert!(
                ok,
                "{xml}\nray {o} {d}: t {t}, uv {uv}, normals {shading} {geometric}, tangent {tangent}; Mitsuba's t {}, uv {mitsuba_uv}, normals {mn} {mg}, dp/du {mdp}",
                v[6]
            );
        }
    }
}

/// `<rotate>` turns about its axis as given, as Mitsuba 3 does: about an
/// axis not of unit length it also stretches (Mitsuba 3.9.1 maps a mesh
/// by `<rotate x="1" y="1" angle="90"/>` with the matrix rows (1, 1, 1),
/// (1, 1, -1), (-1, 1, 0)).
#[test]
fn a_rotate_about_a_long_axis_stretches_as_mitsubas() {
    let edges = |rotate: &str| {
        let t = m_obj_triangle(&format!(
            "<transform name=\"to_world\">{rotate}</transform>"
        ));
        (Vec3::from(t.e1), Vec3::from(t.e2))
    };
    let (e1, e2) = edges("<rotate x=\"1\" y=\"1\" angle=\"90\"/>");
    assert!(e1.abs_diff_eq(Vec3::new(1.0, 1.0, -1.0), 1e-6), "{e1}");
    assert!(e2.abs_diff_eq(Vec3::new(1.0, 1.0, 1.0), 1e-6), "{e2}");
    let (e1, e2) = edges("<rotate z=\"1\" angle=\"90\"/>");
    assert!(
        e1.abs_diff_eq(Vec3::Y, 1e-6) && e2.abs_diff_eq(-Vec3::X, 1e-6),
        "{e1} {e2}"
    );
}

/// Maps of one and two rows read as Mitsuba reads them: the radiance down
/// a meridian of maps whose row j is j + 1, at nine heights from the +y pole
/// to the -y pole, is Mitsuba 3.9.1's (`envmap`'s `eval`, `scalar_rgb`):
/// one row is the same everywhere, two rows turn from the first to the
/// second by the horizon, three lie at the poles and the horizon.
#[test]
fn envmaps_of_one_and_two_rows_read_as_mitsubas() {
    let dir = common::scratch("mitsuba-thin-envmaps");
    let mitsubas: [(usize, [f32; 9]); 3] = [
        (1, [1.0; 9]),
        (2, [1.0, 1.25, 1.5, 1.75, 2.0, 2.0, 2.0, 2.0, 2.0]),
        (3, [1.0, 1.25, 1.5, 1.75, 2.0, 2.25, 2.5, 2.75, 3.0]),
    ];
    for (rows, want) in mitsubas {
        let mut map = Image::new(4, rows);
        for (i, p) in map.pixels.iter_mut().enumerate() {
            *p = [(i / 4 + 1) as f32; 3];
        }
        map.write_exr(&dir.join("sky.exr")).unwrap();
        let xml = dir.join("s.xml");
        std::fs::write(
            &xml,
            with_body(
                "<emitter type=\"envmap\"><string name=\"filename\" value=\"sky.exr\"/></emitter>",
            ),
        )
        .unwrap();
        let scene = Scene::load(&xml).unwrap();
        let sky = scene.environment.as_ref().unwrap();
        for (k, want) in want.iter().enumerate() {
            let theta = std::f32::consts::PI * k as f32 / 8.0;
            let got = sky.eval(Vec3::new(0.0, theta.cos(), -theta.sin()));
            assert!(
                (got.x - want).abs() < 1e-4,
                "{rows} rows, theta {theta}: {got} against Mitsuba's {want}"
            );
        }
    }
}

/// Files are looked for as Mitsuba's resolver looks: in each `<path>`
/// directory (relative to the file that names it, the latest first), then
/// the main scene's directory, which is also where an included file in a
/// subdirectory finds its meshes; qtrace also looks beside the including
/// file, where Mitsuba would not.
#[test]
fn files_are_found_where_mitsuba_looks() {
    let dir = common::scratch("mitsuba-path");
    let fixture = |name: &str| common::repo(&format!("tests/fixtures/textures/{name}"));
    for d in ["assets", "more", "inc"] {
        std::fs::create_dir_all(dir.join(d)).unwrap();
    }
    // t.png beside the scene is small.png, under assets/ tiles.png.
    std::fs::copy(fixture("small.png"), dir.join("t.png")).unwrap();
    std::fs::copy(fixture("tiles.png"), dir.join("assets/t.png")).unwrap();
    std::fs::write(dir.join("m.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    std::fs::write(dir.join("more/s.spd"), "400 0.5\n700 0.5\n").unwrap();
    std::fs::write(
        dir.join("inc/shapes.xml"),
        "<scene version=\"3.0.0\"><shape type=\"obj\"><string name=\"filename\" value=\"m.obj\"/>\
         <bsdf type=\"diffuse\"><spectrum name=\"reflectance\" filename=\"s.spd\"/></bsdf></shape></scene>",
    )
    .unwrap();
    let scene = |paths: &str| {
        std::fs::write(
            dir.join("s.xml"),
            format!(
                "<scene version=\"3.0.0\">{paths}<sensor type=\"perspective\"/>\
                 <shape type=\"rectangle\"><bsdf type=\"diffuse\"><texture type=\"bitmap\" name=\"reflectance\">\
                 <string name=\"filename\" value=\"t.png\"/></texture></bsdf>\
                 <emitter type=\"area\"><rgb name=\"radiance\" value=\"1\"/></emitter></shape>\
                 <include filename=\"inc/shapes.xml\"/></scene>"
            ),
        )
        .unwrap();
        Scene::load(dir.join("s.xml"))
    };
    let texture_width = |s: &Scene| match &s.textures[0].pattern {
        qtrace::scene::texture::Pattern::Bitmap { width, .. } => *width,
        p => panic!("{p:?}"),
    };
    let tiles = image::open(fixture("tiles.png")).unwrap().width() as usize;
    let smallw = image::open(fixture("small.png")).unwrap().width() as usize;
    assert_ne!(tiles, smallw);
    // Without <path>, the spectrum file under more/ is not found.
    let err = scene("").err().unwrap().to_string();
    assert!(err.contains("s.spd"), "{err}");
    let s = scene("<path value=\"more\"/>").unwrap();
    assert_eq!(texture_width(&s), smallw);
    let s = scene("<path value=\"more\"/><path value=\"assets\"/>").unwrap();
    assert_eq!(texture_width(&s), tiles);
    assert_eq!(s.triangles.len(), 3);
}

/// Of several sensors, the first is rendered, as Mitsuba renders by
/// default, with a warning.
#[test]
fn the_first_of_several_sensors_is_rendered() {
    let sensor = |x: f32, width: u32| {
        format!(
            "<sensor type=\"perspective\"><transform name=\"to_world\"><lookat origin=\"{x}, 0, 5\" target=\"0, 0, 0\"/></transform>\
             <film type=\"hdrfilm\"><integer name=\"width\" value=\"{width}\"/></film></sensor>"
        )
    };
    let scene = load_text(&format!(
        "<scene version=\"3.0.0\">{}{}<shape type=\"rectangle\"><emitter type=\"area\"><rgb name=\"radiance\" value=\"1\"/></emitter></shape></scene>",
        sensor(1.0, 40),
        sensor(-3.0, 80)
    ))
    .unwrap();
    assert_eq!(scene.camera.position, Vec3::new(1.0, 0.0, 5.0));
    assert_eq!(scene.defaults.width, Some(40));
}

/// Booleans in any case, as Mitsuba reads them ("True", as Python writes).
#[test]
fn booleans_read_in_any_case() {
    let normal = |v: &str| {
        let t = m_obj_triangle(&format!("<boolean name=\"flip_normals\" value=\"{v}\"/>"));
        Vec3::from(t.e1).cross(Vec3::from(t.e2)).z
    };
    assert!(normal("true") < 0.0 && normal("false") > 0.0);
    assert_eq!(normal("True"), normal("true"));
    assert_eq!(normal("FALSE"), normal("false"));
    assert!(load_text(&with_body(
        "<shape type=\"obj\"><string name=\"filename\" value=\"m.obj\"/><boolean name=\"flip_normals\" value=\"1\"/></shape>"
    ))
    .is_err());
}

/// A Mitsuba 0.x scene is read as Mitsuba 3 upgrades it: camelCase
/// names, `<lookAt>`, a diffuse BSDF's `diffuseReflectance`, a texture's
/// `uoffset`/`uscale`, ids that begin with `_`.
#[test]
fn mitsuba_0_scenes_are_upgraded_as_mitsuba_3_upgrades_them() {
    let scene = |version: &str, body: &str| {
        load_text(&format!(
            "<scene version=\"{version}\">\n{body}\n<shape type=\"rectangle\"><emitter type=\"area\"><rgb name=\"radiance\" value=\"1\"/></emitter></shape></scene>"
        ))
    };
    let old = scene(
        "0.5.0",
        "<integrator type=\"path\"><integer name=\"maxDepth\" value=\"7\"/><boolean name=\"hideEmitters\" value=\"true\"/></integrator>\
         <sensor type=\"perspective\"><string name=\"fovAxis\" value=\"x\"/><transform name=\"toWorld\"><lookAt origin=\"1, 2, 3\" target=\"0, 0, 0\" up=\"0, 1, 0\"/></transform></sensor>\
         <bsdf type=\"diffuse\" id=\"_wall\"><rgb name=\"diffuseReflectance\" value=\"0.2, 0.3, 0.4\"/></bsdf>\
         <shape type=\"obj\"><string name=\"filename\" value=\"m.obj\"/><ref id=\"_wall\"/></shape>\
         <shape type=\"obj\"><string name=\"filename\" value=\"qt.obj\"/><bsdf type=\"roughplastic\"><float name=\"intIOR\" value=\"1.6\"/>\
         <texture type=\"checkerboard\" name=\"diffuseReflectance\"><float name=\"uscale\" value=\"2\"/><float name=\"uoffset\" value=\"0.25\"/><float name=\"voffset\" value=\"0.25\"/></texture></bsdf></shape>",
    )
    .unwrap();
    let new = scene(
        "3.0.0",
        "<integrator type=\"path\"><integer name=\"max_depth\" value=\"7\"/><boolean name=\"hide_emitters\" value=\"true\"/></integrator>\
         <sensor type=\"perspective\"><string name=\"fov_axis\" value=\"x\"/><transform name=\"to_world\"><lookat origin=\"1, 2, 3\" target=\"0, 0, 0\" up=\"0, 1, 0\"/></transform></sensor>\
         <bsdf type=\"diffuse\" id=\"wall\"><rgb name=\"reflectance\" value=\"0.2, 0.3, 0.4\"/></bsdf>\
         <shape type=\"obj\"><string name=\"filename\" value=\"m.obj\"/><ref id=\"wall\"/></shape>\
         <shape type=\"obj\"><string name=\"filename\" value=\"qt.obj\"/><bsdf type=\"roughplastic\"><float name=\"int_ior\" value=\"1.6\"/>\
         <texture type=\"checkerboard\" name=\"diffuse_reflectance\"><transform name=\"to_uv\"><translate x=\"0.25\" y=\"0.25\"/><scale x=\"2\" y=\"1\"/></transform></texture></bsdf></shape>",
    )
    .unwrap();
    assert_eq!(old.camera.position, new.camera.position);
    assert_eq!(old.camera.fov_axis, new.camera.fov_axis);
    assert_eq!(old.defaults.max_depth, new.defaults.max_depth);
    assert!(old.defaults.hide_emitters);
    let looks = |s: &Scene| -> Vec<String> {
        s.materials
            .iter()
            .map(|m| format!("{:?} {:?} {:?}", m.surface, m.emission, m.textures))
            .collect()
    };
    assert_eq!(looks(&old), looks(&new));
    assert_eq!(old.materials[0].name, "ID_wall__UPGR");
    assert_eq!(old.textures[0].to_uv, new.textures[0].to_uv);
    // Mitsuba 3.9.1's to_uv of uscale 2, uoffset 0.25: u' = 2u + 0.5.
    assert_eq!(old.textures[0].to_uv.z_axis.x, 0.5);
    // Not a version qtrace reads.
    let err = scene("4.0.0", "").err().unwrap();
    assert!(err.contains("scene version 4.0.0"), "{err}");
}

/// Blender 4's exporter writes principled's tints as colours; Mitsuba
/// reads every principled weight from a texture by the mean of its
/// channels (its `eval` with `<rgb name="spec_tint" value="0.2, 0.5, 0.8"/>`
/// equals that with `<float ... value="0.5"/>`, 2026-12-06).
#[test]
fn principled_weights_given_as_colours_read_as_their_mean() {
    let params = |tints: &str| {
        let scene = load_text(&with_body(&format!(
            "<shape type=\"cube\"><bsdf type=\"principled\"><float name=\"sheen\" value=\"0.5\"/>{tints}</bsdf></shape>"
        )))
        .unwrap();
        match scene.materials.last().unwrap().surface {
            qtrace::bsdf::Surface::Principled { params, .. } => params,
            ref s => panic!("{s:?}"),
        }
    };
    let colours = params(
        "<rgb name=\"spec_tint\" value=\"0.2, 0.5, 0.8\"/><rgb name=\"sheen_tint\" value=\"1, 1, 1\"/><spectrum name=\"clearcoat\" value=\"0.25\"/>",
    );
    let numbers = params(
        "<float name=\"spec_tint\" value=\"0.5\"/><float name=\"sheen_tint\" value=\"1\"/><float name=\"clearcoat\" value=\"0.25\"/>",
    );
    assert_eq!(format!("{colours:?}"), format!("{numbers:?}"));
}

/// Mitsuba takes a colour or a spectrum wherever it takes a texture, and
/// reads a number from it (a rough BSDF's alphas, a mask's opacity, a
/// blend's weight) by the mean of its channels: its `eval` and `pdf` with
/// `<rgb name="alpha" value="0.1, 0.2, 0.6"/>` or `<spectrum name="alpha"
/// value="0.3"/>` equal those with `<float ... value="0.3"/>` (3.9.1,
/// 2026-12-06). qtrace reads them so, where it refused them before.
#[test]
fn numbers_given_as_colours_read_as_their_mean() {
    let looks = |body: &str| -> Vec<String> {
        let scene = load_text(&with_body(body)).unwrap_or_else(|e| panic!("{body}: {e}"));
        scene
            .materials
            .iter()
            .map(|m| format!("{:?} {:?}", m.surface, m.choice))
            .collect()
    };
    let inner = "<bsdf type=\"diffuse\"/><bsdf type=\"roughconductor\"/>";
    for (kind, value, rest) in [
        ("roughconductor", "alpha", ""),
        ("roughdielectric", "alpha", ""),
        (
            "roughconductor",
            "alpha_u",
            "<float name=\"alpha_v\" value=\"0.05\"/>",
        ),
        ("mask", "opacity", "<bsdf type=\"diffuse\"/>"),
        ("blendbsdf", "weight", inner),
    ] {
        let shape = |given: &str| {
            format!("<shape type=\"cube\"><bsdf type=\"{kind}\">{given}{rest}</bsdf></shape>")
        };
        let number = looks(&shape(&format!("<float name=\"{value}\" value=\"0.5\"/>")));
        for colour in [
            format!("<rgb name=\"{value}\" value=\"0.25, 0.5, 0.75\"/>"),
            format!("<spectrum name=\"{value}\" value=\"0.5\"/>"),
        ] {
            assert_eq!(looks(&shape(&colour)), number, "{kind} {colour}");
        }
    }
}

/// A BSDF nested in another (twosided, mask, blendbsdf) may be a `<ref>` to
/// one defined at the top level, and `<alias>` gives an object a second
/// id, as in Mitsuba.
#[test]
fn nested_bsdfs_may_be_references_and_ids_aliases() {
    let looks = |body: &str| -> Vec<String> {
        let scene = load_text(&with_body(body)).unwrap_or_else(|e| panic!("{body}: {e}"));
        scene
            .materials
            .iter()
            .map(|m| format!("{:?} {:?} {:?}", m.surface, m.one_sided, m.choice))
            .collect()
    };
    let red = "<bsdf type=\"diffuse\"><rgb name=\"reflectance\" value=\"0.6, 0.1, 0.1\"/></bsdf>";
    let grey = "<bsdf type=\"roughconductor\"/>";
    let by_ref = looks(
        "<bsdf type=\"diffuse\" id=\"red\"><rgb name=\"reflectance\" value=\"0.6, 0.1, 0.1\"/></bsdf>\
         <bsdf type=\"roughconductor\" id=\"metal\"/>\
         <alias id=\"metal\" as=\"steel\"/>\
         <bsdf type=\"twosided\" id=\"both\"><ref id=\"red\"/></bsdf>\
         <shape type=\"cube\"><ref id=\"both\"/></shape>\
         <shape type=\"cube\"><bsdf type=\"blendbsdf\"><float name=\"weight\" value=\"0.3\"/><ref id=\"both\"/><ref name=\"bsdf_1\" id=\"steel\"/></bsdf></shape>",
    );
    let inline = looks(&format!(
        "<shape type=\"cube\"><bsdf type=\"twosided\">{red}</bsdf></shape>\
         <shape type=\"cube\"><bsdf type=\"blendbsdf\"><float name=\"weight\" value=\"0.3\"/><bsdf type=\"twosided\">{red}</bsdf>{grey}</bsdf></shape>"
    ));
    assert_eq!(by_ref, inline);
    let Err(e) = load_text(&with_body("<alias id=\"nothing\" as=\"x\"/>")) else {
        panic!("an alias of nothing loaded")
    };
    assert!(
        e.contains(":5:") && e.contains("no object has the id 'nothing'"),
        "{e}"
    );
}

#[test]
fn triangles_of_zero_area_in_a_mesh_are_left_out() {
    let with = |file: &str| {
        load_text(&with_body(&format!(
            "<shape type=\"obj\"><string name=\"filename\" value=\"{file}\"/></shape>"
        )))
        .unwrap()
        .triangles
        .len()
    };
    assert_eq!(with("d.obj"), with("m.obj"));
}

#[test]
fn bad_scenes_get_one_line_naming_file_and_line() {
    for (body, line, want) in [
        ("<shape type=\"serialized\"/>", 5, "shape 'serialized' needs a filename"),
        ("<shape type=\"hair\"/>", 5, "shape 'hair' is not supported"),

        (
            "<shape type=\"cube\"><bsdf type=\"roughplastic\"><float name=\"alpha_u\" value=\"0.1\"/></bsdf></shape>",
            5,
            "roughplastic is isotropic",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"roughdielectric\"><float name=\"int_ior\" value=\"1.000277\"/></bsdf></shape>",
            5,
            "they must differ",
        ),
        (
            "<shape type=\"cube\">\n<bsdf type=\"diffuse\"><float name=\"roughness\" value=\"1\"/></bsdf></shape>",
            6,
            "parameter 'roughness'",
        ),
        ("<shape type=\"cube\"><ref id=\"nope\"/></shape>", 5, "no BSDF has the id 'nope'"),
        (
            "<shape type=\"cube\"><bsdf type=\"twosided\">\n<bsdf type=\"dielectric\"/></bsdf></shape>",
            6,
            "twosided takes only BSDFs that let no light through",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"mask\"><bsdf type=\"diffuse\"/><bsdf type=\"diffuse\"/></bsdf></shape>",
            5,
            "mask needs one nested <bsdf>",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"blendbsdf\"><bsdf type=\"diffuse\"/></bsdf></shape>",
            5,
            "blendbsdf needs two nested <bsdf>",
        ),
        (
            format!(
                "<shape type=\"cube\">{}<bsdf type=\"diffuse\"/>{}</shape>",
                "<bsdf type=\"mask\">".repeat(5),
                "</bsdf>".repeat(5)
            )
            .as_str(),
            5,
            "nest at most 4 deep",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"bumpmap\"><bsdf type=\"diffuse\"/></bsdf></shape>",
            5,
            "bumpmap needs a nested <texture>, its height field",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"bumpmap\">\n<texture type=\"checkerboard\" name=\"h\"/><bsdf type=\"diffuse\"/></bsdf></shape>",
            6,
            "a bumpmap's height field must be a bitmap",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"hair\"/></shape>",
            5,
            "bsdf 'hair' is not supported",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"twosided\">\n<bsdf type=\"principledthin\"/></bsdf></shape>",
            6,
            "twosided takes only BSDFs that let no light through",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"principledthin\">\n<float name=\"diff_trans\" value=\"2.5\"/></bsdf></shape>",
            5,
            "principledthin diff_trans 2.5 must lie in [0, 2]",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"principledthin\">\n<float name=\"metallic\" value=\"0.5\"/></bsdf></shape>",
            6,
            "metallic",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"principled\">\n<float name=\"eta\" value=\"1.4\"/><float name=\"specular\" value=\"0.5\"/></bsdf></shape>",
            5,
            "give eta or specular, not both",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"twosided\">\n<bsdf type=\"principled\"><float name=\"spec_trans\" value=\"0.5\"/></bsdf></bsdf></shape>",
            6,
            "twosided takes only BSDFs that let no light through",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"principled\"><float name=\"metallic\" value=\"1.5\"/></bsdf></shape>",
            5,
            "principled metallic 1.5 must lie in [0, 1]",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"principled\">\n<texture type=\"checkerboard\" name=\"eta\"/></bsdf></shape>",
            6,
            "principled's 'eta' cannot be a texture in qtrace",
        ),
        (
            "<shape type=\"obj\"><string name=\"filename\" value=\"gone.obj\"/></shape>",
            5,
            "cannot read the mesh 'gone.obj'",
        ),
        ("<shape type=\"sphere\"><float name=\"radius\" value=\"$y\"/></shape>", 5, "$y is not defined"),
        ("<shape type=\"sphere\"><float name=\"radius\" value=\"big\"/></shape>", 5, "'big' is not a number"),
        ("<emitter type=\"envmap\"/>", 5, "envmap needs a filename"),
        (
            "<emitter type=\"envmap\"><string name=\"filename\" value=\"sky.exr\"/></emitter>",
            5,
            "cannot read the envmap 'sky.exr'",
        ),
        (
            "<emitter type=\"constant\"/><emitter type=\"constant\"/>",
            5,
            "one environment emitter",
        ),
        (
            "<emitter type=\"envmap\"><string name=\"filename\" value=\"sky.exr\"/><transform name=\"to_world\"><scale value=\"2\"/></transform></emitter>",
            5,
            "must be a rotation",
        ),
        (
            "<emitter type=\"sunsky\"><vector name=\"sun_direction\" x=\"0\" y=\"1\" z=\"1\"/><float name=\"hour\" value=\"9\"/></emitter>",
            5,
            "sunsky takes sun_direction or a place and time ('hour'), not both",
        ),
        (
            "<emitter type=\"sunsky\"><float name=\"turbidity\" value=\"12\"/></emitter>",
            5,
            "sunsky turbidity 12 is outside [1, 10]",
        ),
        (
            "<emitter type=\"sunsky\"><rgb name=\"albedo\" value=\"0.5, 1.5, 0.5\"/></emitter>",
            5,
            "sunsky albedo",
        ),
        (
            "<emitter type=\"sunsky\"/><emitter type=\"constant\"/>",
            5,
            "one environment emitter",
        ),
        (
            "<emitter type=\"sunsky\"><float name=\"sun_aperture\" value=\"0\"/></emitter>",
            5,
            "sun_aperture 0 must lie in (0, 180)",
        ),
        ("<emitter type=\"spot\"><float name=\"beam_width\" value=\"30\"/></emitter>", 5, "beam_width"),
        ("<emitter type=\"projector\"/>", 5, "projector needs an irradiance"),
        (
            "<emitter type=\"projector\"><rgb name=\"irradiance\" value=\"1\"/><transform name=\"to_world\"><scale value=\"2\"/></transform></emitter>",
            5,
            "projector: its to_world must not scale",
        ),
        (
            "<emitter type=\"projector\"><rgb name=\"irradiance\" value=\"1\"/><float name=\"fov\" value=\"180\"/></emitter>",
            5,
            "fov 180 must lie in (0, 180)",
        ),
        (
            "<bsdf type=\"twosided\" id=\"b\"><bsdf type=\"principled\"><texture type=\"checkerboard\" name=\"spec_trans\"/></bsdf></bsdf>",
            5,
            "twosided",
        ),
        (
            "<bsdf type=\"principledthin\" id=\"b\"><texture type=\"checkerboard\" name=\"eta\"/></bsdf>",
            5,
            "principledthin's 'eta' cannot be a texture",
        ),
        (
            "<emitter type=\"spot\"><rgb name=\"texture\" value=\"1\"/></emitter>",
            5,
            "a spot light's texture must be a bitmap or checkerboard",
        ),
        (
            "<emitter type=\"spot\"><texture type=\"checkerboard\" name=\"texture\"/><transform name=\"to_world\"><scale x=\"2\"/></transform></emitter>",
            5,
            "spot: its to_world must not stretch or shear",
        ),
        (
            "<emitter type=\"spot\"><transform name=\"to_world\"><scale value=\"2\"/><lookat origin=\"0,0,0\" target=\"1,0,0\"/></transform></emitter>\n<emitter type=\"spot\"><transform name=\"to_world\"><scale z=\"3\"/></transform></emitter>",
            6,
            "spot: its to_world must not stretch or shear",
        ),
        (
            "<emitter type=\"point\"><texture type=\"checkerboard\" name=\"texture\"/></emitter>",
            5,
            "emitter 'point' has <texture type=\"checkerboard\">",
        ),
        (
            "<shape type=\"cube\"><emitter type=\"directionalarea\"><transform name=\"to_world\"/></emitter></shape>",
            5,
            "a directionalarea emitter takes its shape's to_world",
        ),
        (
            "<shape type=\"cube\"><emitter type=\"directionalarea\"/>\n<emitter type=\"area\"/></shape>",
            6,
            "a shape has one emitter",
        ),
        ("<texture type=\"bitmap\"/>", 5, "a top-level <texture> needs an id"),
        ("<texture type=\"bitmap\" id=\"t\"/>", 5, "bitmap needs a filename"),
        ("<texture type=\"noise\" id=\"t\"/>", 5, "texture 'noise' is not supported"),
        (
            "<shape type=\"cube\">\n<bsdf type=\"diffuse\">\n<texture name=\"reflectance\" type=\"bitmap\"><string name=\"filename\" value=\"gone.png\"/></texture></bsdf></shape>",
            7,
            "cannot read the texture 'gone.png'",
        ),
        (
            "<shape type=\"cube\">\n<bsdf type=\"diffuse\">\n<texture name=\"reflectance\" type=\"bitmap\"><string name=\"filename\" value=\"m.obj\"/></texture></bsdf></shape>",
            7,
            "cannot read the texture 'm.obj'",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"roughplastic\"><ref name=\"alpha\" id=\"t\"/></bsdf></shape>",
            5,
            "roughplastic's 'alpha' cannot be a texture",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"diffuse\"><ref name=\"reflectance\" id=\"t\"/></bsdf></shape>",
            5,
            "no texture has the id 't'",
        ),
        (
            "<shape type=\"cube\"><emitter type=\"area\"><ref name=\"scale\" id=\"t\"/></emitter></shape>",
            5,
            "area's 'scale' cannot be a texture in qtrace (area takes one for radiance)",
        ),
        (
            "<emitter type=\"point\"><ref name=\"intensity\" id=\"t\"/></emitter>",
            5,
            "emitter 'point'",
        ),
        (
            "<shape type=\"shapegroup\" id=\"g\">\n<shape type=\"cube\"><emitter type=\"area\"/></shape></shape>",
            6,
            "instancing of emitters is not supported",
        ),
        (
            "<shape type=\"shapegroup\" id=\"g\">\n<shape type=\"shapegroup\" id=\"h\"/></shape>",
            6,
            "a shapegroup inside a shapegroup",
        ),
        ("<shape type=\"shapegroup\"/>", 5, "a shapegroup needs an id"),
        ("<shape type=\"instance\">\n<ref id=\"g\"/></shape>", 6, "no shapegroup has the id 'g'"),
        (
            "<shape type=\"shapegroup\" id=\"g\"/><shape type=\"instance\"><ref id=\"g\"/><bsdf type=\"diffuse\"/></shape>",
            5,
            "bsdf",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"normalmap\"><bsdf type=\"diffuse\"/></bsdf></shape>",
            5,
            "normalmap needs a texture named 'normalmap'",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"normalmap\"><texture type=\"checkerboard\" name=\"normalmap\"/></bsdf></shape>",
            5,
            "normalmap needs one nested <bsdf>",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"normalmap\"><texture type=\"checkerboard\" name=\"normalmap\"/>\n<bsdf type=\"thindielectric\"/></bsdf></shape>",
            6,
            "a normalmap or bumpmap around a thindielectric BSDF",
        ),
        (
            "<shape type=\"ply\"><string name=\"filename\" value=\"c.ply\"/><bsdf type=\"plastic\"><texture type=\"mesh_attribute\" name=\"diffuse_reflectance\"><string name=\"name\" value=\"face_k_color\"/></texture></bsdf></shape>",
            5,
            "plastic's 'diffuse_reflectance' cannot be a mesh attribute ('face_k_color'), as in Mitsuba",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"diffuse\"><texture type=\"mesh_attribute\" name=\"reflectance\"><string name=\"name\" value=\"vertex_w\"/></texture></bsdf></shape>",
            5,
            "shape 'cube' has no mesh attribute 'vertex_w'",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"diffuse\"><texture type=\"mesh_attribute\" name=\"reflectance\"><string name=\"name\" value=\"color\"/></texture></bsdf></shape>",
            5,
            "mesh attribute 'color' must start with 'vertex_' or 'face_'",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"diffuse\"><spectrum name=\"reflectance\" filename=\"gone.spd\"/></bsdf></shape>",
            5,
            "cannot read the spectrum 'gone.spd'",
        ),
        (
            "<shape type=\"cube\"><bsdf type=\"diffuse\"><spectrum name=\"reflectance\" filename=\"m.obj\"/></bsdf></shape>",
            5,
            "the spectrum 'm.obj', line 1: 'v 0 0 0' is not a wavelength and a value",
        ),
        ("<include filename=\"missing.xml\"/>", 5, "missing.xml"),
        ("<shape type=\"cube\"><transform name=\"to_world\"><skew/></transform></shape>", 5, "<skew>"),
        ("<shape type=\"cube\"", 6, "malformed XML"),
    ] {
        let Err(err) = load_text(&with_body(body)) else {
            panic!("{body} loaded");
        };
        let prefix = format!("mem/s.xml:{line}: ");
        assert!(
            err.starts_with(&prefix) && err.contains(want) && !err.contains('\n'),
            "{body}: {err}"
        );
    }
    // A malformed mesh is named, with the shape that reads it.
    let Err(err) = load_text(&with_body(
        "<shape type=\"ply\"><string name=\"filename\" value=\"m.obj\"/></shape>",
    )) else {
        panic!("an OBJ read as PLY loaded");
    };
    assert_eq!(
        err,
        "mem/m.obj: malformed PLY: not a PLY file (it does not start with 'ply') (the shape at mem/s.xml:5)"
    );
    // A mesh attribute the mesh lacks, or cannot give as Mitsuba reads it.
    let ply = |bsdf: &str| {
        with_body(&format!(
            "<shape type=\"ply\"><string name=\"filename\" value=\"c.ply\"/>{bsdf}</shape>"
        ))
    };
    let attribute = |param: &str, name: &str| {
        format!("<texture type=\"mesh_attribute\" name=\"{param}\"><string name=\"name\" value=\"{name}\"/></texture>")
    };
    for (bsdf, want) in [
        (
            format!("<bsdf type=\"diffuse\">{}</bsdf>", attribute("reflectance", "vertex_gone")),
            "mem/c.ply: the mesh has no attribute 'vertex_gone' (it has vertex_color, vertex_w, face_k_color) (the shape at mem/s.xml:5)",
        ),
        (
            format!("<bsdf type=\"roughconductor\">{}</bsdf>", attribute("alpha", "face_k_color")),
            "mem/c.ply: a number is read from attribute 'face_k_color', which has 3 channels (Mitsuba reads numbers from attributes of one) (the shape at mem/s.xml:5)",
        ),
        (
            format!("<bsdf type=\"diffuse\">{}</bsdf>", attribute("reflectance", "vertex_color")),
            "mem/c.ply: attribute 'vertex_color' has 4 channels; Mitsuba evaluates attributes of 1 or 3 (the shape at mem/s.xml:5)",
        ),
    ] {
        assert_eq!(load_text(&ply(&bsdf)).err().as_deref(), Some(want), "{bsdf}");
    }
    // Two attributes, one read as a number: each triangle holds both.
    let scene = load_text(&ply(&format!(
        "<bsdf type=\"blendbsdf\">{}<bsdf type=\"diffuse\">{}</bsdf><bsdf type=\"diffuse\"/></bsdf>",
        attribute("weight", "vertex_w"),
        attribute("reflectance", "face_k_color")
    )))
    .unwrap();
    let names: Vec<&str> = scene.attributes.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["vertex_w", "face_k_color"]);
    let last = scene
        .attributes
        .iter()
        .map(|(_, v)| v.iter().find(|c| c[0] != Vec3::ZERO));
    let values: Vec<_> = last.map(|c| c.map(|c| c.map(|v| v.x))).collect();
    assert_eq!(values, [Some([0.2, 0.5, 0.9]), Some([0.1, 0.1, 0.1])]);
}

/// A Mitsuba reference: its image and the variance of each pixel's mean.
fn reference(name: &str) -> (Image, Image) {
    let dir = common::repo("tests/fixtures/mitsuba");
    let read = |f: String| Image::read_exr(&dir.join(&f)).unwrap_or_else(|e| panic!("{f}: {e}"));
    (read(format!("{name}.exr")), read(format!("{name}.var.exr")))
}

/// qtrace's render agrees with Mitsuba's: the image means within 0.5% (and
/// within their noise), and no 8×8 block, per channel, further off than
/// five standard errors of the two renders' noise (or 0.005% of its value).
fn assert_agrees(name: &str, out: &RenderOutput, (mean, var): &(Image, Image)) {
    let (w, h) = (out.image.width, out.image.height);
    assert_eq!((w, h), (mean.width, mean.height), "{name}: size");
    let n = out.stats.image_spp as f64;
    let block = |x0: usize, y0: usize, bw: usize, bh: usize, c: usize| {
        let (mut d, mut se2, mut sum) = (0.0f64, 0.0f64, 0.0f64);
        for y in y0..y0 + bh {
            for x in x0..x0 + bw {
                let i = y * w + x;
                d += out.image.pixels[i][c] as f64 - mean.pixels[i][c] as f64;
                sum += mean.pixels[i][c] as f64;
                se2 += out.variance.pixels[i][c] as f64 / n + var.pixels[i][c] as f64;
            }
        }
        // A sky seen directly has next to no noise: there the two
        // renderers' float rounding (a few parts in a million) is the
        // difference, which no error of either is.
        (d, se2.sqrt().max(1e-5 * sum.abs()), sum)
    };
    let mut worst = (0.0f64, 0, 0, 0);
    for by in (0..h).step_by(8) {
        for bx in (0..w).step_by(8) {
            for c in 0..3 {
                let (d, se, _) = block(bx, by, 8.min(w - bx), 8.min(h - by), c);
                let z = if se > 0.0 {
                    d / se
                } else if d.abs() < 1e-6 {
                    0.0
                } else {
                    f64::INFINITY
                };
                if z.abs() > worst.0.abs() {
                    worst = (z, bx, by, c);
                }
            }
        }
    }
    let (mut rel, mut z_mean, mut noise) = (0.0f64, 0.0f64, 0.0f64);
    for c in 0..3 {
        let (d, se, sum) = block(0, 0, w, h, c);
        rel = rel.max((d / sum).abs());
        z_mean = z_mean.max((d / se).abs());
        noise = noise.max(se / sum);
    }
    // Where the two means are known to 0.125% (a quarter of 0.5%) or
    // better, they must lie within 0.5%; where noise is larger (a tiny,
    // bright light seen directly), the z-tests alone speak, and
    // docs/mitsuba.md gives a longer render's figure.
    let ok = worst.0.abs() < 5.0 && z_mean < 5.0 && (rel < 0.005 || noise > 0.00125);
    eprintln!(
        "{name}: means {:.3}% apart ({z_mean:.1} sigma, noise {:.3}%), worst 8x8 block {:.1} sigma at ({}, {})",
        100.0 * rel,
        100.0 * noise,
        worst.0,
        worst.1,
        worst.2
    );
    if !ok {
        common::save_failure_images(name, &[("qtrace", &out.image), ("mitsuba", mean)]);
    }
    assert!(
        ok,
        "{name}: image means {:.3}% apart ({z_mean:.1} sigma, noise {:.3}%); worst 8x8 block ({}, {}) channel {} at {:.1} sigma",
        100.0 * rel,
        100.0 * noise,
        worst.1,
        worst.2,
        worst.3,
        worst.0
    );
}

/// Renders `scene` (XML, with `defines`) as `o` says and compares it with
/// Mitsuba's reference `name`.
fn check(name: &str, scene: &Path, defines: &[(&str, &str)], o: Overrides) {
    let label = format!("{name} {}", o.method.unwrap_or(Method::PT).label(o.nee));
    let defines: Vec<(String, String)> = defines
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
    let scene = Scene::load_defined(scene, &defines).unwrap();
    let ctx = common::gpu();
    let out = common::render_with(&ctx, &scene, o);
    assert_agrees(&label, &out, &reference(name));
}

/// `check` at 64×64 and 1024 spp with every method with NEE, and plain
/// path tracing without it.
fn check_every_method(name: &str, scene: &Path) {
    for (m, nee) in [
        (Method::PT, true),
        (Method::PT, false),
        (Method::SARSA, true),
        (Method::NEURAL, true),
    ] {
        check(name, scene, &[("res", "64")], method(m, nee, 1024));
    }
}

fn method(m: Method, nee: bool, spp: u32) -> Overrides {
    Overrides {
        method: Some(m),
        nee,
        spp: Some(spp),
        seed: Some(3),
        ..Default::default()
    }
}

const SQUARE: [(&str, &str); 2] = [("resx", "64"), ("resy", "64")];

#[test]
fn cornell_box_agrees_with_mitsuba() {
    // pt+nee long enough that the means are known to the 0.5% checked.
    for (m, nee, spp) in [
        (Method::PT, true, 4096),
        (Method::PT, false, 1024),
        (Method::SARSA, true, 1024),
        (Method::NEURAL, true, 1024),
    ] {
        let name = format!("cornell-box {m:?} nee {nee}");
        let scene = Scene::load_defined(
            cornell(),
            &SQUARE.map(|(k, v)| (k.to_string(), v.to_string())),
        )
        .unwrap();
        let ctx = common::gpu();
        let out = common::render_with(&ctx, &scene, method(m, nee, spp));
        assert_agrees(&name, &out, &reference("cornell-box"));
    }
}

#[test]
fn veach_mis_agrees_with_mitsuba() {
    let scene = common::repo("scenes/mitsuba/veach-mis/scene.xml");
    let size = [("resx", "96"), ("resy", "54")];
    // Twice the samples of the other scenes: its tiny, bright lights make
    // rare, large samples, whose noise 1024 spp estimates poorly.
    for (m, nee) in [
        (Method::PT, true),
        (Method::SARSA, true),
        (Method::NEURAL, true),
    ] {
        check("veach-mis", &scene, &size, method(m, nee, 2048));
    }
}

#[test]
fn coverage_scenes_agree_with_mitsuba() {
    let dir = common::repo("tests/fixtures/mitsuba");
    // Every method: the guides learn through every lobe here.
    for m in [Method::PT, Method::SARSA, Method::NEURAL] {
        check(
            "coverage-a",
            &dir.join("coverage-a.xml"),
            &[("res", "64")],
            method(m, true, 1024),
        );
    }
    check(
        "coverage-b",
        &dir.join("coverage-b.xml"),
        &[("width", "96"), ("height", "64")],
        method(Method::PT, true, 2048),
    );
    // Rough glass and rough plastic, a light reached only through rough
    // glass: every method, and plain path tracing without NEE.
    check_every_method("coverage-d", &dir.join("coverage-d.xml"));
    // Point, spot and directional lights (NEE's alone), and a lookat
    // without an up, with a plain and a guided method.
    for m in [Method::PT, Method::SARSA, Method::NEURAL] {
        check(
            "coverage-c",
            &dir.join("coverage-c.xml"),
            &[("res", "64")],
            method(m, true, 1024),
        );
    }
}

#[test]
fn textured_scene_agrees_with_mitsuba() {
    // Bitmaps and checkerboards in every slot qtrace reads, under a
    // constant sky and a panel: every method, and pt without NEE.
    let scene = common::repo("tests/fixtures/mitsuba/coverage-e.xml");
    check_every_method("coverage-e", &scene);
}

#[test]
fn textured_lights_agree_with_mitsuba() {
    // Area lights whose radiance is a bitmap and a checkerboard: what a
    // camera ray sees of them, and what NEE and BSDF sampling bring of
    // them; sarsa learns from them.
    let scene = common::repo("tests/fixtures/mitsuba/coverage-g.xml");
    for (m, nee, spp) in [
        (Method::PT, true, 1024),
        (Method::PT, false, 2048),
        (Method::SARSA, true, 1024),
    ] {
        check("coverage-g", &scene, &[("res", "64")], method(m, nee, spp));
    }
}

/// A textured square under a constant sky, direct light only: every path
/// without NEE returns the albedo of the point it hits, so each pixel is
/// the texel behind it; with NEE (which draws the sky) each 2x2 block of
/// pixels, one texel, converges to it.
#[test]
fn a_textured_plane_shows_its_texels() {
    use qtrace::scene::texture::{Filter, Texture, Wrap};
    let scene = Scene::load(common::repo("tests/fixtures/mitsuba/textured-plane.xml")).unwrap();
    let texels = Texture {
        name: "tiles.png".into(),
        pattern: Texture::read_bitmap(
            &common::repo("tests/fixtures/textures/tiles.png"),
            Filter::Nearest,
            Wrap::Repeat,
            false,
        )
        .unwrap(),
        to_uv: glam::Mat3::IDENTITY,
    };
    let ctx = common::gpu();
    for (nee, spp, tolerance) in [(false, 4, 1e-4), (true, 1024, 0.02)] {
        let out = common::render_with(&ctx, &scene, method(Method::PT, nee, spp));
        let (w, h) = (out.image.width, out.image.height);
        for y in (0..h).step_by(2) {
            for x in (0..w).step_by(2) {
                // The rectangle's (u, v) is its (x, y) from [-1, 1] to [0, 1].
                let u = (x as f32 + 1.0) / w as f32;
                let v = 1.0 - (y as f32 + 1.0) / h as f32;
                let want = texels.eval(glam::Vec2::new(u, v));
                let got = [(0, 0), (1, 0), (0, 1), (1, 1)]
                    .iter()
                    .map(|(dx, dy)| glam::Vec3::from(out.image.pixels[(y + dy) * w + x + dx]))
                    .sum::<glam::Vec3>()
                    / 4.0;
                assert!(
                    (got - want).abs().max_element() < tolerance * want.max_element().max(0.1),
                    "nee {nee}: pixels ({x}, {y}) are {got}, their texel {want}"
                );
            }
        }
    }
}

/// Masks, blends and a twosided with two BSDFs under a constant sky, each
/// square's pixels at their analytic values (choices.xml says which).
#[test]
fn masks_blends_and_two_faced_squares_show_their_analytic_values() {
    let scene = Scene::load(common::repo("tests/fixtures/mitsuba/choices.xml")).unwrap();
    // Mitsuba reads a checkerboard's number with its colours swapped:
    // opacity 0.2 (0.9) where its colour is 0.6, in the top left quadrant.
    let want = |x: usize, y: usize| -> f32 {
        if !(2..14).contains(&y) || (x - 2) % 16 >= 12 {
            return 1.0;
        }
        match (x - 2) / 16 {
            0 => 0.85,
            1 => 0.35,
            2 => 0.7,
            _ => {
                if (x < 56) == (y < 8) {
                    0.9
                } else {
                    0.7
                }
            }
        }
    };
    let ctx = common::gpu();
    for (m, nee) in [
        (Method::PT, false),
        (Method::PT, true),
        (Method::SARSA, true),
        (Method::NEURAL, true),
    ] {
        let out = common::render_with(&ctx, &scene, method(m, nee, 256));
        let (w, n) = (out.image.width, out.stats.spp as f32);
        let mut far = 0;
        for (i, (p, v)) in out
            .image
            .pixels
            .iter()
            .zip(&out.variance.pixels)
            .enumerate()
        {
            let (x, y) = (i % w, i / w);
            let err = (p[0] - want(x, y)).abs();
            let se = (v[0] / n).sqrt();
            assert!(
                err < 0.1,
                "{m:?} nee {nee}: pixel ({x}, {y}) is {}, not {}",
                p[0],
                want(x, y)
            );
            far += usize::from(err > 4.0 * se + 1e-4);
        }
        assert!(far <= 4, "{m:?} nee {nee}: {far} pixels beyond 4 sigma");
    }
}

#[test]
fn environment_scene_agrees_with_mitsuba() {
    // An envmap with a small sun, turned and scaled, a constant sky added:
    // every method, and pt without NEE (which must find the sun by itself).
    let scene = common::repo("tests/fixtures/mitsuba/coverage-f.xml");
    check_every_method("coverage-f", &scene);
}

#[test]
fn hidden_emitters_agree_with_mitsuba() {
    // hide_emitters: lights and the sky hidden from the camera, the sky
    // through a null pane and a thin sheet too, and seen everywhere else.
    // (Without NEE the sun's rare hits make a short render's noise estimate
    // too low for this test: docs/mitsuba.md has a long render's figures.)
    let scene = common::repo("tests/fixtures/mitsuba/coverage-h.xml");
    for m in [Method::PT, Method::SARSA, Method::NEURAL] {
        check(
            "coverage-h",
            &scene,
            &[("res", "64")],
            method(m, true, 1024),
        );
    }
}

#[test]
fn thin_lens_agrees_with_mitsuba() {
    // Depth of field: spheres before, at and behind the plane in focus.
    let scene = common::repo("tests/fixtures/mitsuba/coverage-i.xml");
    for m in [Method::PT, Method::SARSA] {
        check(
            "coverage-i",
            &scene,
            &[("res", "64")],
            method(m, true, 1024),
        );
    }
}

#[test]
fn orthographic_camera_agrees_with_mitsuba() {
    // Scaled by its to_world, on a wide image.
    let scene = common::repo("tests/fixtures/mitsuba/coverage-k.xml");
    for m in [Method::PT, Method::SARSA] {
        check(
            "coverage-k",
            &scene,
            &[("res", "96"), ("resy", "64")],
            method(m, true, 1024),
        );
    }
}

#[test]
fn a_thin_lens_needs_its_aperture_and_no_camera_scales() {
    let text = with_body("").replace("type=\"perspective\"", "type=\"thinlens\"");
    let Err(err) = load_text(&text) else {
        panic!("loaded")
    };
    assert_eq!(err, "mem/s.xml:2: thinlens needs an aperture_radius");
    let text = with_body("").replace(
        "<sensor type=\"perspective\"/>",
        "<sensor type=\"thinlens\"><float name=\"aperture_radius\" value=\"0.1\"/><float name=\"focus_distance\" value=\"-1\"/></sensor>",
    );
    let Err(err) = load_text(&text) else {
        panic!("loaded")
    };
    assert_eq!(err, "mem/s.xml:2: focus_distance -1 must be positive");
    // Mitsuba refuses a pinhole or lens that its to_world scales.
    let text = with_body("").replace(
        "<sensor type=\"perspective\"/>",
        "<sensor type=\"perspective\"><transform name=\"to_world\"><scale x=\"1.01\"/></transform></sensor>",
    );
    let Err(err) = load_text(&text) else {
        panic!("loaded")
    };
    assert!(
        err.starts_with("mem/s.xml:2: perspective: its to_world must not scale"),
        "{err}"
    );
}

#[test]
fn normal_maps_agree_with_mitsuba() {
    // Bumps on diffuse, rough metal, plastic and a mirror, the map outside
    // twosided and inside it.
    let scene = common::repo("tests/fixtures/mitsuba/coverage-j.xml");
    for m in [Method::PT, Method::SARSA, Method::NEURAL] {
        check(
            "coverage-j",
            &scene,
            &[("res", "64")],
            method(m, true, 1024),
        );
    }
}

#[test]
fn masks_and_blends_agree_with_mitsuba() {
    // Leaves cut out by an opacity map, blends by a bitmap and by a number,
    // a card with two faces, a checkerboard roughness and a normal map
    // around a blend.
    let scene = common::repo("tests/fixtures/mitsuba/coverage-l.xml");
    check_every_method("coverage-l", &scene);
}

/// Mitsuba's path tracer keeps a sample's light only if its path scattered
/// somewhere, began under a visible sky or ended on an emitter at its last
/// allowed vertex: tiny scenes of `null` panes, thin sheets and masks before
/// lights, lit squares, a sky or nothing, at every depth limit and with
/// `hide_emitters` off and on, against Mitsuba's images
/// (scripts/mitsuba_pass_through_probes.py). Without NEE only where there is
/// no point light, which paths cannot hit, and no mask: there Mitsuba's
/// image depends on its sampler (it counts the mask's NEE only where the
/// path scatters later), which `pt --nee` shares.
#[test]
fn paths_that_only_pass_through_count_as_in_mitsuba() {
    let dir = common::scratch("mitsuba-pass-through");
    let blocks = fixture_blocks("tests/fixtures/mitsuba/pass-through.txt", "scene ");
    assert_eq!(blocks.len(), 9);
    let ctx = common::gpu();
    let (mut checked, mut failed) = (0, Vec::new());
    for (k, (xml, lines)) in blocks.iter().enumerate() {
        let file = dir.join(format!("s{k}.xml"));
        std::fs::write(&file, xml).unwrap();
        for v in lines {
            let (depth, hide, want, err) = (v[0] as i32, v[1] != 0.0, v[2] as f64, v[3] as f64);
            let defines = [
                ("max_depth".to_string(), depth.to_string()),
                ("hide".to_string(), hide.to_string()),
            ];
            let scene = Scene::load_defined(&file, &defines).unwrap();
            let mut methods = vec![(Method::PT, true)];
            if depth == -1 {
                methods.extend([(Method::SARSA, true), (Method::NEURAL, true)]);
            }
            if !xml.contains("\"point\"") && !xml.contains("\"mask\"") {
                methods.push((Method::PT, false));
            }
            for (m, nee) in methods {
                let out = common::render_with(&ctx, &scene, method(m, nee, 1024));
                let n = out.stats.image_spp as f64;
                let count = out.image.pixels.len() as f64;
                let mean = out.image.mean();
                let se = (out.variance.mean() * count / n).sqrt() / count;
                // (Mitsuba's noiseless images differ from qtrace's by its
                // float rounding: a constant sky of 0.1 seen reads 0.099985.)
                let allowed = 5.0 * (se * se + err * err).sqrt() + 5e-4 * want + 1e-6;
                if (mean - want).abs() > allowed {
                    failed.push(format!(
                        "scene {k} ({}) at max_depth {depth}, hide_emitters {hide}: {} gives {mean:.6}, Mitsuba {want:.6} (allowed {allowed:.2e})",
                        xml.split("</sensor>").nth(1).unwrap_or(xml),
                        m.label(nee)
                    ));
                }
                checked += 1;
            }
        }
    }
    assert!(
        failed.is_empty(),
        "{} of {checked} renders differ:\n{}",
        failed.len(),
        failed.join("\n")
    );
}

#[test]
fn bump_maps_agree_with_mitsuba() {
    // Height fields on diffuse, rough gold, a low torus and a blend, inside
    // and outside twosided.
    let scene = common::repo("tests/fixtures/mitsuba/coverage-m.xml");
    for m in [Method::PT, Method::SARSA, Method::NEURAL] {
        check(
            "coverage-m",
            &scene,
            &[("res", "64")],
            method(m, true, 1024),
        );
    }
}

#[test]
fn anisotropic_roughness_agrees_with_mitsuba() {
    // Brushed metal (GGX and Beckmann), an anisotropic principled torus and
    // rough glass, each along its surface's dp/du.
    let scene = common::repo("tests/fixtures/mitsuba/coverage-o.xml");
    for m in [Method::PT, Method::SARSA, Method::NEURAL] {
        check(
            "coverage-o",
            &scene,
            &[("res", "64")],
            method(m, true, 1024),
        );
    }
}

#[test]
fn textured_anisotropic_rough_glass_agrees_with_mitsuba() {
    // Rough glass whose alpha_u and alpha_v are both textures, and whose
    // alpha_v alone is; a rough metal's alpha given as a colour and a
    // mask's opacity as a spectrum.
    let scene = common::repo("tests/fixtures/mitsuba/coverage-u.xml");
    for m in [Method::PT, Method::SARSA, Method::NEURAL] {
        check(
            "coverage-u",
            &scene,
            &[("res", "64")],
            method(m, true, 1024),
        );
    }
}

#[test]
fn principled_weights_as_textures_agree_with_mitsuba() {
    // Clearcoat, sheen, sheen tint, specular tint and flatness given as
    // bitmaps and checkerboards.
    let scene = common::repo("tests/fixtures/mitsuba/coverage-w.xml");
    for m in [Method::PT, Method::SARSA, Method::NEURAL] {
        check(
            "coverage-w",
            &scene,
            &[("res", "64")],
            method(m, true, 1024),
        );
    }
}

#[test]
fn thin_principled_sheets_agree_with_mitsuba() {
    // principledthin: diffuse transmission from a bitmap, thin rough glass,
    // and a sheet passing light both ways, anisotropic.
    let scene = common::repo("tests/fixtures/mitsuba/coverage-x.xml");
    for m in [Method::PT, Method::SARSA, Method::NEURAL] {
        check(
            "coverage-x",
            &scene,
            &[("res", "64")],
            method(m, true, 1024),
        );
    }
}

/// Which lights read their normals to know their side: those on meshes
/// whose normals differ from their faces', not Mitsuba's own shapes.
#[test]
fn lights_on_meshes_with_their_own_normals_take_their_side_from_them() {
    let light = r#"<emitter type="area"><rgb name="radiance" value="1"/></emitter>"#;
    for (shape, smooth) in [
        (
            r#"<shape type="obj"><string name="filename" value="vn.obj"/>"#,
            true,
        ),
        (
            r#"<shape type="obj"><string name="filename" value="m.obj"/>"#,
            false,
        ),
        (r#"<shape type="sphere">"#, false),
        (r#"<shape type="rectangle">"#, false),
    ] {
        let scene = load_text(&with_body(&format!("{shape}{light}</shape>"))).unwrap();
        // (with_body's own light, a rectangle, comes first.)
        let mut lights = scene
            .materials
            .iter()
            .filter(|m| m.emission.max_element() > 0.0);
        assert_eq!(lights.next_back().unwrap().smooth_light, smooth, "{shape}");
    }
}

#[test]
fn lights_on_smooth_meshes_emit_where_their_normals_face() {
    // A low-poly bulb whose silhouette triangles face the camera while
    // their normals turn away, and a panel whose normals oppose its
    // winding: Mitsuba's area lights emit on the side the interpolated
    // normal faces.
    let scene = common::repo("tests/fixtures/mitsuba/smooth-lights.xml");
    check_every_method("smooth-lights", &scene);
}

#[test]
fn lights_whose_radiance_is_a_mesh_attribute_pick_triangles_by_their_own() {
    // NEE's probability of a triangle over its area is its own mean
    // radiance's luminance over the total: the same ratio on every triangle
    // of both lights, and those of the wall's faces differ.
    use qtrace::scene::texture::Pattern;
    let scene = Scene::load(common::repo("tests/fixtures/mitsuba/coverage-y.xml")).unwrap();
    let (mut ratios, mut pdfs) = (Vec::new(), Vec::new());
    for (i, t) in scene.triangles.iter().enumerate() {
        let m = &scene.materials[t.material as usize];
        let Some(slot) = m.textures[qtrace::shaders::TEXTURE_SLOT_COLOR as usize] else {
            continue;
        };
        let Pattern::Attribute { name, scale, .. } = &scene.textures[slot as usize].pattern else {
            continue;
        };
        let (_, corners) = scene.attributes.iter().find(|(n, _)| n == name).unwrap();
        let [a, b, c] = corners[i];
        let le = scale * qtrace::bsdf::luminance((a + b + c) / 3.0);
        assert!(t.light_pdf > 0.0, "triangle {i} of '{name}' is no light");
        ratios.push(t.light_pdf / le);
        pdfs.push(t.light_pdf);
    }
    assert!(ratios.len() > 1000, "{} emitting triangles", ratios.len());
    let first = ratios[0];
    for r in &ratios {
        assert!((r / first - 1.0).abs() < 1e-4, "{r} vs {first}");
    }
    let (lo, hi) = pdfs
        .iter()
        .fold((f32::MAX, 0.0f32), |(lo, hi), &p| (lo.min(p), hi.max(p)));
    assert!(hi > 3.0 * lo, "densities {lo} to {hi}");
}

#[test]
fn lights_whose_radiance_is_a_mesh_attribute_agree_with_mitsuba() {
    // A sphere glowing in its vertex colours, a wall of tiles each in its
    // face colour: seen, reached by NEE (each triangle weighed by its own
    // radiance) and learned by the guides.
    let scene = common::repo("tests/fixtures/mitsuba/coverage-y.xml");
    for m in [Method::PT, Method::SARSA, Method::NEURAL] {
        check(
            "coverage-y",
            &scene,
            &[("res", "64")],
            method(m, true, 1024),
        );
    }
}

#[test]
fn many_lights_agree_with_mitsuba() {
    // 24 lights in four rooms, more than the guides choose among one by
    // one: they choose among nearby ones together.
    let scene = common::repo("tests/fixtures/mitsuba/many-lights.xml");
    for m in [Method::PT, Method::SARSA, Method::NEURAL] {
        check(
            "many-lights",
            &scene,
            &[("res", "64")],
            method(m, true, 1024),
        );
    }
}

#[test]
fn projectors_agree_with_mitsuba() {
    // A bitmap cast from above the camera, a flat colour from the side.
    let scene = common::repo("tests/fixtures/mitsuba/coverage-z.xml");
    for m in [Method::PT, Method::SARSA] {
        check(
            "coverage-z",
            &scene,
            &[("res", "64")],
            method(m, true, 1024),
        );
    }
}

#[test]
fn principled_lobes_shaped_by_textures_agree_with_mitsuba() {
    // Clearcoat gloss, anisotropy and spec_trans as textures, on the
    // principled BSDF and its thin sibling.
    let scene = common::repo("tests/fixtures/mitsuba/principled-textures.xml");
    for m in [Method::PT, Method::SARSA] {
        check(
            "principled-textures",
            &scene,
            &[("res", "64")],
            method(m, true, 1024),
        );
    }
}

#[test]
fn principled_materials_as_blenders_exporter_writes_them_agree_with_mitsuba() {
    // mitsuba-blender's shapes: a twosided principled with `specular`, a
    // bumpmap (`bumpmap_tex`) around one with bitmaps in four inputs.
    let scene = common::repo("tests/fixtures/mitsuba/blender-principled.xml");
    for m in [Method::PT, Method::NEURAL] {
        check(
            "blender-principled",
            &scene,
            &[("res", "64")],
            method(m, true, 1024),
        );
    }
}

#[test]
fn spot_lights_that_cast_an_image_agree_with_mitsuba() {
    // A bitmap cast from above, a checkerboard from the side through a
    // mirrored, turned frame, a plain spot; a directionalarea panel that
    // no path reaches.
    let scene = common::repo("tests/fixtures/mitsuba/spot-image.xml");
    for m in [Method::PT, Method::NEURAL] {
        check(
            "spot-image",
            &scene,
            &[("res", "64")],
            method(m, true, 1024),
        );
    }
}

#[test]
fn point_clouds_of_small_spheres_agree_with_mitsuba() {
    // 150 small spheres, tessellated as finely as the camera sees them,
    // and a large one.
    let scene = common::repo("tests/fixtures/mitsuba/coverage-v.xml");
    for m in [Method::PT, Method::SARSA] {
        check(
            "coverage-v",
            &scene,
            &[("res", "64")],
            method(m, true, 1024),
        );
    }
}

/// The usual Mitsuba template for a point cloud: thousands of small
/// spheres seen from afar at 1600×1200. At 128 segments each (16,256
/// triangles) 2048 of them passed the scene's triangle limit; tessellated
/// as finely as the camera sees them they take about 1,800 each, while a
/// sphere that fills the view keeps 128 segments, and both keep their
/// true area.
#[test]
fn spheres_are_tessellated_as_finely_as_the_camera_sees_them() {
    let sensor = r#"<sensor type="perspective"><float name="fov" value="25"/>
<transform name="to_world"><lookat origin="3,3,3" target="0,0,0" up="0,0,1"/></transform>
<film type="hdrfilm"><integer name="width" value="1600"/><integer name="height" value="1200"/></film></sensor>
<emitter type="constant"/>"#;
    let ball = |r: f32, at: f32| {
        format!(
            "<shape type=\"sphere\"><float name=\"radius\" value=\"{r}\"/><transform name=\"to_world\"><translate x=\"{at}\"/></transform></shape>"
        )
    };
    let triangles = |body: &str, sensor_after: bool| {
        let text = if sensor_after {
            format!("<scene version=\"3.0.0\">{body}{sensor}</scene>")
        } else {
            format!("<scene version=\"3.0.0\">{sensor}{body}</scene>")
        };
        let scene = load_text(&text).unwrap();
        let area: f32 = scene.triangles.iter().map(|t| t.area).sum();
        (scene.triangles.len(), area)
    };
    let pi = std::f32::consts::PI;
    // 0.025 across at 5.2 units: 18 pixels of radius at 1600 wide.
    let (small, area) = triangles(&ball(0.025, 0.0), false);
    assert_eq!(small, 44 * 21 * 2, "a small sphere's triangles");
    assert!((area / (4.0 * pi * 0.025 * 0.025) - 1.0).abs() < 1e-3);
    // The sensor after the shapes sees them the same.
    assert_eq!(triangles(&ball(0.025, 0.0), true).0, small);
    let (large, area) = triangles(&ball(1.0, 0.0), false);
    assert_eq!(large, 128 * 63 * 2, "a large sphere's triangles");
    assert!((area / (4.0 * pi) - 1.0).abs() < 1e-3);
    // The camera inside a sphere: the most.
    assert_eq!(triangles(&ball(10.0, 0.0), false).0, large);
    // 48 of them load within this loader's 100,000 triangles (at 128
    // segments they would take 774,144).
    let cloud: String = (0..48).map(|i| ball(0.025, i as f32 * 0.01)).collect();
    assert!(triangles(&cloud, false).0 < 48 * 2000);
}

#[test]
fn mesh_attributes_agree_with_mitsuba() {
    // PLY vertex and face colours and one-channel attributes in diffuse,
    // principled, rough metal (scaled) and a blend's weight, through a
    // shared BSDF and flipped normals.
    let scene = common::repo("tests/fixtures/mitsuba/coverage-p.xml");
    for m in [Method::PT, Method::SARSA, Method::NEURAL] {
        check(
            "coverage-p",
            &scene,
            &[("res", "64")],
            method(m, true, 1024),
        );
    }
}

#[test]
fn lights_with_a_null_bsdf_agree_with_mitsuba() {
    // As exporters write Blender's lights: paths pass through them, seen
    // from the front with the sky behind, from behind, and in a mirror.
    let scene = common::repo("tests/fixtures/mitsuba/coverage-q.xml");
    check_every_method("coverage-q", &scene);
}

#[test]
fn lights_whose_bsdf_scatters_agree_with_mitsuba() {
    // Lights of diffuse and rough metal reflect the room's light (and NEE
    // runs at them); a lamp given no BSDF is black, as Mitsuba makes it.
    let scene = common::repo("tests/fixtures/mitsuba/coverage-r.xml");
    check_every_method("coverage-r", &scene);
    // Hidden from the camera, as in Mitsuba, the camera's ray passes them
    // by, whatever their BSDF.
    check(
        "coverage-r-hidden",
        &scene,
        &[("res", "64"), ("hide", "true")],
        method(Method::PT, true, 1024),
    );
}

#[test]
fn crop_windows_agree_with_mitsuba() {
    // Parts of a thin lens's film and of an orthographic camera's.
    for name in ["crop", "crop-orthographic"] {
        let scene = common::repo(&format!("tests/fixtures/mitsuba/{name}.xml"));
        check(name, &scene, &[], method(Method::PT, true, 1024));
    }
}

#[test]
fn a_films_crop_window_and_filter_read_as_mitsubas() {
    let film = |crop: &str| {
        with_body("").replace(
            "<sensor type=\"perspective\"/>",
            &format!("<sensor type=\"perspective\"><film type=\"hdrfilm\"><integer name=\"width\" value=\"64\"/><integer name=\"height\" value=\"48\"/>{crop}</film></sensor>"),
        )
    };
    let scene = load_text(&film(
        "<integer name=\"crop_offset_x\" value=\"14\"/><integer name=\"crop_width\" value=\"40\"/>",
    ))
    .unwrap();
    assert_eq!(
        (scene.defaults.width, scene.defaults.height),
        (Some(40), Some(48))
    );
    assert_eq!(
        scene.camera.crop,
        Some(qtrace::scene::Crop {
            film: (64, 48),
            offset: (14, 0),
            size: (40, 48)
        })
    );
    // Filters qtrace takes as Mitsuba does, or refuses in one line.
    let scene = load_text(&film(
        "<rfilter type=\"lanczos\"><integer name=\"lobes\" value=\"2\"/></rfilter>",
    ))
    .unwrap();
    assert_eq!(scene.filter, PixelFilter::Lanczos { lobes: 2 });
    for (f, want) in [
        (
            "<rfilter type=\"mitchell\"><float name=\"B\" value=\"5\"/></rfilter>",
            "mem/s.xml:2: mitchell B 5, C 0.33333334: qtrace takes B and C within [-4, 4]",
        ),
        (
            "<rfilter type=\"lanczos\"><integer name=\"lobes\" value=\"0\"/></rfilter>",
            "mem/s.xml:2: lanczos lobes 0 must lie in 1..=16",
        ),
    ] {
        assert_eq!(load_text(&film(f)).err().as_deref(), Some(want));
    }
    let err = load_text(&film("<integer name=\"crop_offset_y\" value=\"10\"/><integer name=\"crop_height\" value=\"40\"/>")).err();
    assert_eq!(
        err.as_deref(),
        Some("mem/s.xml:2: the film's crop window (64x40 at 0, 10) must lie within its 64x48")
    );
}

#[test]
fn filters_with_negative_lobes_agree_with_mitsuba() {
    // Mitchell-Netravali, Catmull-Rom and Lanczos: signed sample weights,
    // cut at the image's border as Mitsuba's splatting cuts them.
    let scene = common::repo("tests/fixtures/mitsuba/rfilters.xml");
    for f in ["mitchell", "catmullrom", "lanczos"] {
        check(
            &format!("rfilters-{f}"),
            &scene,
            &[("res", "64"), ("filter", f)],
            method(Method::PT, true, 1024),
        );
    }
}

/// A light's straight edge down the middle of a 16x2 image, seen through
/// cubic filters (Mitsuba's default mitchell, catmullrom and a mitchell of
/// other B and C): each column converges to the filter's integral over the
/// lit side within the image, over its integral within the image, times
/// what the kernels' midpoint sums of 64 steps make of that ratio; with
/// the film's `sample_border`, over the filter's whole support (the light
/// goes on beyond the image's left edge). Mitsuba's own columns agree with
/// both within 0.006 at 65,536 spp (2026-12-06).
#[test]
fn cubic_filters_see_an_edge_as_their_integral() {
    let integral = |b: f32, c: f32, lo: f64, hi: f64, steps: usize| -> (f64, f64) {
        let dx = (hi - lo) / steps as f64;
        (0..steps).fold((0.0, 0.0), |(t, m), k| {
            let f = PixelFilter::cubic(b, c, (lo + (k as f64 + 0.5) * dx) as f32) as f64 * dx;
            (t + f, m + f.abs())
        })
    };
    // E[weight x lit] along one axis: sampled from |f| (exact integral M),
    // weighed by sign x the midpoint sums' M / T.
    let axis = |(b, c, border): (f32, f32, bool), centre: f64, size: f64, lit: f64| -> f64 {
        let (lo, hi) = if border {
            (-2.0, 2.0)
        } else {
            ((-centre).max(-2.0), (size - centre).min(2.0))
        };
        let (t64, m64) = integral(b, c, lo, hi, 64);
        let (_, m) = integral(b, c, lo, hi, 200_000);
        let (t_lit, _) = integral(b, c, lo, (lit - centre).clamp(lo, hi), 200_000);
        m64 / t64 / m * t_lit
    };
    let cubic = "<rfilter type=\"mitchell\"><float name=\"B\" value=\"0\"/><float name=\"C\" value=\"1\"/></rfilter>";
    let border = "<boolean name=\"sample_border\" value=\"true\"/>";
    // The edge down the middle, or at the image's right edge (the light
    // ending there), which the filter crosses only with the border sampled.
    for (rfilter, (b, c, sampled), edge) in [
        (
            "<rfilter type=\"mitchell\"/>".to_string(),
            (1.0 / 3.0, 1.0 / 3.0, false),
            8.0,
        ),
        (
            "<rfilter type=\"catmullrom\"/>".to_string(),
            (0.0, 0.5, false),
            8.0,
        ),
        (cubic.to_string(), (0.0, 1.0, false), 8.0),
        (cubic.to_string(), (0.0, 1.0, false), 16.0),
        (format!("{cubic}{border}"), (0.0, 1.0, true), 16.0),
    ] {
        // Image column `edge` is world x = (2 edge / 16 - 1) tan 30°.
        let x = -50.0 + (2.0 * edge / 16.0 - 1.0) * 30f64.to_radians().tan();
        let scene = load_text(&format!(
            "<scene version=\"3.0.0\">\n\
             <sensor type=\"perspective\"><float name=\"fov\" value=\"60\"/>\
             <transform name=\"to_world\"><lookat origin=\"0, 0, 0\" target=\"0, 0, -1\" up=\"0, 1, 0\"/></transform>\
             <film type=\"hdrfilm\"><integer name=\"width\" value=\"16\"/><integer name=\"height\" value=\"2\"/>{rfilter}</film></sensor>\n\
             <shape type=\"rectangle\"><transform name=\"to_world\"><scale x=\"50\" y=\"50\"/><translate x=\"{x}\" z=\"-1\"/></transform>\
             <emitter type=\"area\"><rgb name=\"radiance\" value=\"1\"/></emitter></shape>\n</scene>"
        ))
        .unwrap();
        assert_eq!(scene.filter, PixelFilter::Cubic { b, c }, "{rfilter}");
        assert_eq!(scene.defaults.sample_border, sampled);
        let f = (b, c, sampled);
        let out = common::render_with(&common::gpu(), &scene, method(Method::PT, false, 16384));
        // World -x is the image's left (Mitsuba's look-at): columns left of
        // the edge lit.
        let rows = axis(f, 0.5, 2.0, 2.0) + axis(f, 1.5, 2.0, 2.0);
        for x in 0..16 {
            let want = axis(f, x as f64 + 0.5, 16.0, edge) * rows / 2.0;
            let (mut got, mut var) = (0.0, 0.0);
            for y in 0..2 {
                got += out.image.pixels[y * 16 + x][1] as f64 / 2.0;
                var += out.variance.pixels[y * 16 + x][1] as f64 / 4.0 / 16384.0;
            }
            let z = (got - want) / var.sqrt().max(1e-4);
            assert!(
                z.abs() < 5.0,
                "{rfilter}, edge {edge}, column {x}: {got} against {want} ({z:.1} sigma)"
            );
        }
    }
}

#[test]
fn a_mitsuba_0_6_scene_with_what_scenes_carry_agrees_with_mitsuba() {
    // Mitsuba 0.6's names, a <path>, a mirrored sky, spectrum plugins,
    // colour tints, nested references and an alias, a mitchell of other B
    // and C, the prb integrator.
    // 2048 samples: the block at (32, 32) has rare, bright paths (four
    // renders of 4096 samples put it 6.9% under, 0.8% under, 0.04% and 0.8%
    // over Mitsuba's), and at 1024 the draws of `sarsa`'s image at seed 3
    // since the sun's part of the sky is a light of its own put it 6.6 sigma
    // off by its own noise estimate.
    let scene = common::repo("tests/fixtures/mitsuba/coverage-s.xml");
    for m in [Method::PT, Method::SARSA, Method::NEURAL] {
        check(
            "coverage-s",
            &scene,
            &[("res", "64")],
            method(m, true, 2048),
        );
    }
}

#[test]
fn a_sun_and_sky_agree_with_mitsuba() {
    // sunsky by place and time, turned to y up, with turbidity, a coloured
    // ground albedo, limb darkening and both scales.
    // 2048 samples: the sun's part of the sky is a light of its own, and at
    // 1024 one block of `sarsa`'s image at seed 3 lay 5.0 sigma off, where
    // renders of 4096 samples at other seeds scatter both ways (+0.35%,
    // -0.10%).
    let scene = common::repo("tests/fixtures/mitsuba/coverage-t.xml");
    for m in [Method::PT, Method::SARSA, Method::NEURAL] {
        check(
            "coverage-t",
            &scene,
            &[("res", "64")],
            method(m, true, 2048),
        );
    }
}

#[test]
fn principled_materials_agree_with_mitsuba() {
    // Textured base colour and roughness, metallic with tint and clearcoat,
    // sheen with flatness, a bitmap's metallic weight, a one-sided sphere.
    let scene = common::repo("tests/fixtures/mitsuba/coverage-n.xml");
    for m in [Method::PT, Method::SARSA, Method::NEURAL] {
        check(
            "coverage-n",
            &scene,
            &[("res", "64")],
            method(m, true, 1024),
        );
    }
}
