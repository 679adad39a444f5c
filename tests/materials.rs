//! Glossy and specular materials on lavapipe: furnaces with
//! analytic answers for every BSDF, a mirror's analytic image, and every
//! method converging to the same image on the shipped glossy scenes.

mod common;

use glam::{Vec2, Vec3};
use qtrace::bsdf::{Bsdf, Sampling, Surface};
use qtrace::guide::{Common, GuideSettings, NeuralSettings, SarsaGuide, SarsaSettings};
use qtrace::render::{Method, Overrides};
use qtrace::sampling;
use qtrace::Scene;
use std::path::Path;

/// Writes a scene of `obj` and `mtl` seen from `eye` looking at the origin
/// (y up) under a uniform environment `environment`, and loads it.
fn write_scene(dir: &Path, obj: &str, mtl: &str, eye: Vec3, fov_y: f32, environment: f32) -> Scene {
    std::fs::write(dir.join("s.obj"), format!("mtllib s.mtl\n{obj}")).unwrap();
    std::fs::write(dir.join("s.mtl"), mtl).unwrap();
    std::fs::write(
        dir.join("s.toml"),
        format!(
            "mesh = \"s.obj\"\nenvironment = [{environment}, {environment}, {environment}]\n\
             [camera]\nposition = [{}, {}, {}]\nlook_at = [0, 0, 0]\nup = [0, 1, 0]\nfov_y = {fov_y}\n",
            eye.x, eye.y, eye.z
        ),
    )
    .unwrap();
    Scene::load(dir.join("s.toml")).unwrap()
}

/// A square of side 2s in the plane z = 0, facing +z.
fn quad(s: f32) -> String {
    format!(
        "v {} {} 0\nv {s} {} 0\nv {s} {s} 0\nv {} {s} 0\nusemtl m\nf 1 2 3 4\n",
        -s, -s, -s, -s
    )
}

/// A cube of side 2s about the origin, faces outward.
fn cube(s: f32) -> String {
    let mut obj = String::new();
    for z in [-s, s] {
        for y in [-s, s] {
            for x in [-s, s] {
                obj += &format!("v {x} {y} {z}\n");
            }
        }
    }
    // Vertex (x, y, z) is 1 + (x > 0) + 2 (y > 0) + 4 (z > 0).
    obj += "usemtl m\nf 1 3 4 2\nf 5 6 8 7\nf 1 5 7 3\nf 2 4 8 6\nf 1 2 6 5\nf 3 7 8 4\n";
    obj
}

fn viewed_from(theta_degrees: f32, distance: f32) -> Vec3 {
    let t = theta_degrees.to_radians();
    Vec3::new(t.sin(), 0.0, t.cos()) * distance
}

/// The directional albedo of `surface` toward wo, from the CPU twin's
/// sampler on a fine grid (its unit tests hold it to quadrature).
fn albedo(surface: Surface, wo: Vec3) -> f32 {
    let bsdf = Bsdf::new(surface, true, Sampling::Cosine);
    let n = 512;
    let mut sum = 0.0f64;
    for i in 0..n {
        for j in 0..n {
            let u = Vec2::new((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
            if let Some((wi, _)) = bsdf.sample(wo, u.extend(0.5)) {
                sum += (bsdf.eval(wo, wi).x / bsdf.pdf(wo, wi)) as f64;
            }
        }
    }
    (sum / (n * n) as f64) as f32
}

/// Image mean and its standard error from the per-pixel variances.
fn mean_and_error(out: &qtrace::RenderOutput) -> (f64, f64) {
    let n = (3 * out.image.pixels.len()) as f64;
    let var: f64 = out
        .variance
        .pixels
        .iter()
        .flatten()
        .map(|&v| v as f64)
        .sum();
    (
        out.image.mean(),
        (var / out.stats.image_spp as f64).sqrt() / n,
    )
}

fn render(scene: &Scene, method: Method, nee: bool, size: u32, spp: u32) -> qtrace::RenderOutput {
    let ctx = common::gpu();
    let guide = match method {
        Method::SARSA => Some(GuideSettings::from(SarsaSettings {
            volumes: Some(64),
            ..Default::default()
        })),
        _ => None,
    };
    common::render_with(
        &ctx,
        scene,
        Overrides {
            method: Some(method),
            spp: Some(spp),
            width: Some(size),
            height: Some(size),
            nee,
            seed: Some(11),
            guide,
            ..Default::default()
        },
    )
}

/// Furnaces: each BSDF under a uniform environment of radiance 1 returns
/// its directional albedo: 1 for smooth glass (a closed cube: what enters
/// leaves, Fresnel splits conserve energy and the η² of the way in is undone
/// on the way out), the reflectance for a mirror, and for rough GGX the
/// albedo its CPU twin integrates (below 1: single scattering loses energy).
/// Plain and guided sampling alike.
#[test]
fn every_bsdf_returns_its_albedo_in_a_furnace() {
    let dir = common::scratch("furnace-bsdf");
    let mut cases: Vec<(String, String, String, f32, f32)> = Vec::new();
    for (ni, theta) in [(1.5, 0.0), (1.5, 50.0), (2.4, 30.0)] {
        cases.push((
            format!("glass Ni {ni} at {theta}°"),
            cube(1.0),
            format!("newmtl m\nNi {ni}\nd 0\n"),
            theta,
            1.0,
        ));
    }
    cases.push((
        "mirror at 40°".into(),
        quad(10.0),
        "newmtl m\nPm 1\nKs 0.6\n".into(),
        40.0,
        0.6,
    ));
    for (pr, theta) in [(0.2, 0.0), (0.5, 60.0), (1.0, 30.0), (0.7, 80.0)] {
        let surface = Surface::conductor(Vec3::ONE, pr * pr);
        cases.push((
            format!("GGX Pr {pr} at {theta}°"),
            quad(10.0),
            format!("newmtl m\nPm 1\nPr {pr}\n"),
            theta,
            albedo(surface, viewed_from(theta, 1.0)),
        ));
    }
    for (what, obj, mtl, theta, expected) in cases {
        // A narrow view from afar: every pixel sees the object at about theta.
        let scene = write_scene(&dir, &obj, &mtl, viewed_from(theta, 40.0), 1.0, 1.0);
        for method in [Method::PT, Method::SARSA] {
            let out = render(&scene, method, false, 16, 256);
            let (mean, se) = mean_and_error(&out);
            assert!(
                (mean - expected as f64).abs() < 5.0 * se + 2e-3,
                "{what} ({method:?}): image mean {mean:.5} ± {se:.5}, expected {expected:.5}"
            );
        }
    }
}

/// A mirror (Ks 0.5) shows a light (Le 4) as an exact image: the light's
/// reflection is a rectangle of the image plane where every sample is 2,
/// and every sample elsewhere is 0. Each pixel's mean is 2 times the share
/// of it the rectangle covers, within binomial noise; with NEE (which a
/// delta lobe skips) and guided alike.
#[test]
fn a_mirror_shows_the_analytic_image_of_a_light() {
    let dir = common::scratch("mirror-image");
    // Light: x in [2, 3], y in [-0.5, 0.5] at z = 4, facing the mirror (-z).
    let obj = format!(
        "{}v 2 -0.5 4\nv 3 -0.5 4\nv 3 0.5 4\nv 2 0.5 4\nusemtl light\nf 5 8 7 6\n",
        quad(6.0)
    );
    let mtl = "newmtl m\nPm 1\nKs 0.5\nnewmtl light\nKd 0\nKe 4 4 4\n";
    let fov: f32 = 30.0;
    let scene = write_scene(&dir, &obj, mtl, Vec3::new(0.0, 0.0, 10.0), fov, 0.0);
    // The mirror image of the light lies at z = -4, 14 from the eye and
    // parallel to the image plane: a rectangle in normalised device
    // coordinates (x = 14 t ndc.x with t = tan(fov / 2)).
    let t = (fov.to_radians() / 2.0).tan();
    let (x0, x1) = (2.0 / (14.0 * t), 3.0 / (14.0 * t));
    let (y0, y1) = (-0.5 / (14.0 * t), 0.5 / (14.0 * t));
    let size = 32usize;
    let spp = 64u32;
    let overlap = |a0: f32, a1: f32, b0: f32, b1: f32| (a1.min(b1) - a0.max(b0)).max(0.0);
    for (method, nee) in [
        (Method::PT, false),
        (Method::PT, true),
        (Method::SARSA, false),
        (Method::SARSA, true),
    ] {
        let out = render(&scene, method, nee, size as u32, spp);
        let mut inside = 0;
        for py in 0..size {
            for px in 0..size {
                let step = 2.0 / size as f32;
                let (nx0, ny1) = (-1.0 + px as f32 * step, 1.0 - py as f32 * step);
                let cover = overlap(nx0, nx0 + step, x0, x1) * overlap(ny1 - step, ny1, y0, y1)
                    / (step * step);
                let got = out.image.pixels[py * size + px][1];
                let noise = 5.0 * (4.0 * cover * (1.0 - cover) / spp as f32).sqrt();
                assert!(
                    (got - 2.0 * cover).abs() <= noise + 1e-5,
                    "{method:?} nee {nee}: pixel ({px}, {py}) is {got}, expected {} (cover {cover})",
                    2.0 * cover
                );
                inside += (cover == 1.0) as usize;
            }
        }
        assert!(
            inside >= 8,
            "the light's image covers {inside} whole pixels"
        );
    }
}

/// Every method converges to pt+NEE's image on the glossy and glass scenes:
/// NEE's MIS against glossy lobes, delta vertices and the guides' mixtures
/// of BSDF and sector sampling add no bias.
#[test]
fn glossy_scenes_converge_to_the_same_image_for_every_method() {
    for (name, method, nee, spp) in [
        ("glossy-cornell", Method::PT, false, 4096),
        ("glossy-cornell", Method::SARSA, false, 2048),
        ("glossy-cornell", Method::SARSA, true, 1024),
        ("glossy-room", Method::PT, false, 2048),
        ("glossy-room", Method::SARSA, true, 1024),
        ("glass-cornell", Method::PT, false, 4096),
        ("glass-cornell", Method::SARSA, false, 2048),
    ] {
        let guide = (method == Method::SARSA).then(|| {
            GuideSettings::from(SarsaSettings {
                volumes: Some(512),
                ..Default::default()
            })
        });
        common::assert_converges_to_pt(
            &format!("{name}-{method:?}-nee{nee}"),
            &common::scene(name),
            Overrides {
                method: Some(method),
                spp: Some(spp),
                nee,
                seed: Some(400),
                guide,
                ..Default::default()
            },
        );
    }
}

/// `neural` too: on rough metal without NEE, and with NEE past a mirror
/// and through glass (delta vertices, where it infers and learns but does
/// not sample).
#[test]
fn neural_converges_to_pt_on_glossy_and_glass_scenes() {
    for (name, nee) in [("glossy-cornell", false), ("glass-cornell", true)] {
        let settings = NeuralSettings {
            width: 16,
            batch: Some(1024),
            ..Default::default()
        };
        common::assert_converges_to_pt(
            &format!("{name}-neural-nee{nee}"),
            &common::scene(name),
            Overrides {
                method: Some(Method::NEURAL),
                spp: Some(1024),
                nee,
                seed: Some(401),
                guide: Some(GuideSettings::from(settings)),
                ..Default::default()
            },
        );
    }
}

/// A box [x0, x1] × [y0, y1] × [z0, z1] with faces outward, whose vertices
/// follow `first - 1` earlier ones.
fn box_faces(lo: Vec3, hi: Vec3, first: u32) -> String {
    let mut obj = String::new();
    for z in [lo.z, hi.z] {
        for y in [lo.y, hi.y] {
            for x in [lo.x, hi.x] {
                obj += &format!("v {x} {y} {z}\n");
            }
        }
    }
    // As cube(): vertex (x, y, z) is first + (x high) + 2 (y high) + 4 (z high).
    for face in [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
    ] {
        let [a, b, c, d] = face.map(|i| i + first);
        obj += &format!("f {a} {b} {c} {d}\n");
    }
    obj
}

/// Light reaches the floor under a glass slab only through it: a light
/// (Le 10, facing down) above the slab, whose light passes two smooth
/// interfaces (about 0.92 of it straight down). The guide at the floor learns
/// that: a transition into glass takes its target from where the path next
/// reaches a surface that is not delta (here the light), not from the
/// guide's estimate at the glass, which sees only the floor from outside.
#[test]
fn the_guide_learns_light_that_arrives_through_glass() {
    let dir = common::scratch("through-glass");
    let mut obj = String::from("v -5 0 -5\nv -5 0 5\nv 5 0 5\nv 5 0 -5\nusemtl floor\nf 1 2 3 4\n");
    obj += "v -1 2 -1\nv 1 2 -1\nv 1 2 1\nv -1 2 1\nusemtl light\nf 5 6 7 8\n";
    obj += "usemtl glass\n";
    obj += &box_faces(Vec3::new(-2.0, 1.0, -2.0), Vec3::new(2.0, 1.5, 2.0), 9);
    let mtl = "newmtl floor\nKd 0.5 0.5 0.5\nnewmtl light\nKd 0\nKe 10 10 10\nnewmtl glass\nNi 1.5\nd 0\n";
    let scene = write_scene(&dir, &obj, mtl, Vec3::new(0.0, 4.0, 6.0), 40.0, 0.0);
    let guide = GuideSettings::from(SarsaSettings {
        volumes: Some(512),
        common: Common {
            stand_back: Some(false),
            ..Default::default()
        },
        ..Default::default()
    });
    let renderer = common::run_renderer(
        &common::gpu(),
        &scene,
        Overrides {
            method: Some(Method::SARSA),
            spp: Some(128),
            width: Some(64),
            height: Some(64),
            seed: Some(402),
            guide: Some(guide),
            ..Default::default()
        },
    );
    let sarsa = renderer
        .guide()
        .and_then(|g| g.downcast::<SarsaGuide>())
        .expect("a Sarsa guide");
    let q = sarsa.download_q().unwrap();
    let [a, b] = sarsa.settings.common.grid;
    let n = (a * b) as usize;
    // The four sectors about the zenith (within about 14 degrees of it),
    // which from within 0.5 of the light's middle see only the light (2 by
    // 2, 2 above) through the slab.
    let up: Vec<usize> = (0..n as u32)
        .filter(|&k| sampling::sector_cos(k, a, b) > 0.97)
        .map(|k| k as usize)
        .collect();
    assert_eq!(up.len(), 4, "sectors about the zenith");
    let under: Vec<usize> = (0..sarsa.volumes.len())
        .filter(|&v| {
            let volume = &sarsa.volumes[v];
            let [x, y, z] = volume.position;
            volume.normal[1] > 0.9 && y.abs() < 0.1 && x.abs() < 0.5 && z.abs() < 0.5
        })
        .collect();
    assert!(!under.is_empty(), "no volume on the floor under the light");
    // Sectors no path took still hold the initial Q.
    let initial = sarsa.settings.common.initial_q;
    let learned: Vec<f32> = under
        .iter()
        .flat_map(|&v| up.iter().map(move |&k| v * n + k))
        .map(|i| q[i])
        .filter(|&x| x != initial)
        .collect();
    assert!(
        learned.len() >= 4,
        "{} sectors learned: {learned:?}",
        learned.len()
    );
    let mean = learned.iter().sum::<f32>() / learned.len() as f32;
    assert!(
        mean > 6.0,
        "Q toward the light through the glass, {} sectors of {} volumes under it: {learned:?} (Le 10)",
        learned.len(),
        under.len()
    );
}
