//! The GLSL building blocks against CPU references: BVH traversal against
//! brute force, the hemisphere map and the BSDF against their CPU twins.

mod common;

use common::Lcg;

use glam::{Vec2, Vec3};
use qtrace::bsdf::{ComplexIor, Distribution, Principled, RoughTable, Surface};
use qtrace::render::{probe, Sampling};
use qtrace::sampling;
use qtrace::scene::Material;

fn check_traversal(name: &str, count: usize) {
    let ctx = common::gpu();
    let scene = common::scene(name);
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for t in &scene.triangles {
        for p in [
            Vec3::from(t.v0),
            Vec3::from(t.v0) + Vec3::from(t.e1),
            Vec3::from(t.v0) + Vec3::from(t.e2),
        ] {
            lo = lo.min(p);
            hi = hi.max(p);
        }
    }
    let mut rng = Lcg(7);
    // Origins in a box a little larger than the scene, so some rays start outside.
    let margin = (hi - lo) * 0.1;
    let rays: Vec<(Vec3, Vec3)> = (0..count)
        .map(|_| {
            let u = Vec3::new(rng.next(), rng.next(), rng.next());
            (lo - margin + u * (hi - lo + 2.0 * margin), rng.unit())
        })
        .collect();
    let gpu = probe::trace_rays(&ctx, &scene, &rays).unwrap();
    common::assert_no_validation_errors(&ctx);
    let mut hits = 0;
    for (i, ((o, d), (closest, any))) in rays.iter().zip(&gpu).enumerate() {
        let reference = scene.intersect_brute(*o, *d);
        match (reference, closest) {
            (None, None) => {}
            (Some((t_ref, tri_ref)), Some((t, tri))) => {
                hits += 1;
                let tol = 1e-4 * t_ref.max(1.0);
                assert!(
                    (t - t_ref).abs() <= tol,
                    "ray {i}: t {t} vs brute force {t_ref} (triangles {tri} vs {tri_ref})"
                );
            }
            (r, g) => panic!("ray {i} from {o} along {d}: brute force {r:?}, GPU {g:?}"),
        }
        assert_eq!(*any, reference.is_some(), "ray {i}: any-hit disagrees");
    }
    // The test means something only if both outcomes occur.
    assert!(
        hits > count / 10 && hits < count,
        "{hits} of {count} rays hit"
    );
}

#[test]
fn bvh_traversal_equals_brute_force_cornell_box() {
    check_traversal("cornell-box", 20_000);
}

#[test]
fn bvh_traversal_equals_brute_force_131k_triangles() {
    check_traversal("complex-direct", 1_500);
}

/// The walk-only benchmark kernel, in each of its ways of handing lanes
/// their rays, finds what the trace kernel's walk finds.
#[test]
fn walk_benchmark_finds_the_trace_kernels_hits() {
    let ctx = common::gpu();
    let scene = common::scene("cornell-box");
    let mut rng = Lcg(11);
    let origin = Vec3::new(278.0, 273.0, 279.6);
    let rays: Vec<(Vec3, Vec3)> = (0..3000)
        .map(|_| (origin + 200.0 * (rng.unit() * 0.5), rng.unit()))
        .collect();
    let reference = probe::trace_rays(&ctx, &scene, &rays).unwrap();
    // Every other ray looks for any hit within 300 units.
    let walks: Vec<probe::WalkRay> = rays
        .iter()
        .enumerate()
        .map(|(i, &(o, d))| (o, d, if i % 2 == 1 { 300.0 } else { 3.0e38 }, i % 2 == 1))
        .collect();
    let near: Vec<bool> = rays
        .iter()
        .map(|&(o, d)| scene.intersect_brute(o, d).is_some_and(|(t, _)| t < 300.0))
        .collect();
    let within = near.iter().skip(1).step_by(2).filter(|&&n| n).count();
    assert!(
        within > 100 && within < 1400,
        "{within} of 1500 any-hit rays hit"
    );
    for refill in 0..3 {
        let (hits, _) = probe::walk_timed(&ctx, &scene, &walks, 7, refill, 0).unwrap();
        common::assert_no_validation_errors(&ctx);
        for (i, (&(t, tri), (closest, _))) in hits.iter().zip(&reference).enumerate() {
            if i % 2 == 1 {
                assert_eq!(tri != u32::MAX, near[i], "mode {refill}, ray {i}: any hit");
            } else {
                let found = (tri != u32::MAX).then_some((t, tri));
                assert_eq!(found, *closest, "mode {refill}, ray {i}");
            }
        }
    }
}

#[test]
fn gpu_hemisphere_map_matches_cpu_and_inverts() {
    let ctx = common::gpu();
    let scene = common::scene("cornell-box");
    let (a, b) = (12u32, 12u32);
    let n = 96;
    let points: Vec<Vec2> = (0..n * n)
        .map(|k| {
            Vec2::new(
                ((k % n) as f32 + 0.5) / n as f32,
                ((k / n) as f32 + 0.5) / n as f32,
            )
        })
        .collect();
    let out = probe::hemisphere(&ctx, &scene, &points, a, b).unwrap();
    common::assert_no_validation_errors(&ctx);
    for (u, (w, sector)) in points.iter().zip(&out) {
        let cpu = sampling::square_to_hemisphere(*u);
        assert!(
            (*w - cpu).abs().max_element() < 1e-5,
            "{u}: GPU {w} vs CPU {cpu}"
        );
        // The sector of map(u) is the grid cell u lies in: lookup inverts the map.
        let cell = (u.x * a as f32) as u32 + a * (u.y * b as f32) as u32;
        assert_eq!(*sector, cell, "point {u} direction {w}");
        assert_eq!(*sector, sampling::hemisphere_sector(cpu, a, b));
    }
}

/// A metal's complex index of refraction (copper's, roughly).
const METAL: ComplexIor = ComplexIor {
    eta: Vec3::new(0.2, 0.92, 1.1),
    k: Vec3::new(3.9, 2.45, 2.14),
};

/// The GPU BSDF (glsl/bsdf.glsl) against its CPU twin (src/bsdf.rs): every
/// kind of surface, seen from either side, from directions all over the
/// hemisphere, with either diffuse sampler.
#[test]
fn gpu_bsdf_matches_its_cpu_twin() {
    let ctx = common::gpu();
    let scene = common::scene("cornell-box");
    let mut rng = Lcg(5);
    let surfaces = [
        Surface::Diffuse {
            albedo: Vec3::new(0.7, 0.5, 0.2),
        },
        Surface::conductor(Vec3::new(0.9, 0.6, 0.3), 0.0),
        Surface::conductor(Vec3::ONE, 0.04),
        Surface::conductor(Vec3::new(0.9, 0.6, 0.3), 0.36),
        Surface::conductor(Vec3::ONE, 1.0),
        Surface::Conductor {
            reflectance: Vec3::new(0.9, 0.8, 0.7),
            alpha: 0.05,
            alpha_v: None,
            distribution: Distribution::Beckmann,
            fresnel: Some(METAL),
        },
        Surface::Conductor {
            reflectance: Vec3::ONE,
            alpha: 0.4,
            alpha_v: None,
            distribution: Distribution::Beckmann,
            fresnel: None,
        },
        Surface::Conductor {
            reflectance: Vec3::ONE,
            alpha: 0.3,
            alpha_v: None,
            distribution: Distribution::Ggx,
            fresnel: Some(METAL),
        },
        Surface::Conductor {
            reflectance: Vec3::splat(0.8),
            alpha: 0.0,
            alpha_v: None,
            distribution: Distribution::Ggx,
            fresnel: Some(METAL),
        },
        Surface::Dielectric {
            ior: 1.5,
            transmittance: Vec3::new(1.0, 0.9, 0.8),
            reflectance: Vec3::ONE,
        },
        Surface::Dielectric {
            ior: 1.33,
            transmittance: Vec3::ONE,
            reflectance: Vec3::new(0.5, 0.7, 0.9),
        },
        Surface::Thin {
            eta: 1.45,
            reflectance: Vec3::new(0.9, 0.8, 1.0),
            transmittance: Vec3::new(0.7, 1.0, 0.9),
        },
        Surface::Plastic {
            diffuse: Vec3::new(0.8, 0.3, 0.1),
            specular: Vec3::splat(0.9),
            eta: 1.49,
            nonlinear: false,
        },
        Surface::Plastic {
            diffuse: Vec3::new(0.2, 0.6, 0.9),
            specular: Vec3::ONE,
            eta: 1.7,
            nonlinear: true,
        },
        Surface::RoughDielectric {
            ior: 1.5,
            reflectance: Vec3::new(0.9, 1.0, 0.8),
            transmittance: Vec3::new(1.0, 0.9, 0.8),
            alpha: 0.25,
            alpha_v: None,
            distribution: Distribution::Ggx,
        },
        Surface::RoughDielectric {
            ior: 1.33,
            reflectance: Vec3::ONE,
            transmittance: Vec3::ONE,
            alpha: 0.1,
            alpha_v: None,
            distribution: Distribution::Beckmann,
        },
        Surface::RoughPlastic {
            diffuse: Vec3::new(0.8, 0.3, 0.2),
            specular: Vec3::ONE,
            eta: 1.49,
            nonlinear: false,
            alpha: 0.1,
            distribution: Distribution::Beckmann,
            table: RoughTable::new(1.49, 0.1, Distribution::Beckmann),
        },
        Surface::RoughPlastic {
            diffuse: Vec3::new(0.2, 0.7, 0.3),
            specular: Vec3::splat(0.9),
            eta: 1.6,
            nonlinear: true,
            alpha: 0.4,
            distribution: Distribution::Ggx,
            table: RoughTable::new(1.6, 0.4, Distribution::Ggx),
        },
        Surface::Principled {
            base_color: Vec3::new(0.8, 0.4, 0.2),
            params: Principled {
                ..Principled::default()
            },
        },
        Surface::Principled {
            base_color: Vec3::new(0.9, 0.6, 0.3),
            params: Principled {
                roughness: 0.2,
                metallic: 0.7,
                specular_tint: 0.4,
                sheen: 0.3,
                sheen_tint: 0.8,
                clearcoat: 0.8,
                clearcoat_gloss: 0.6,
                eta: 1.7,
                ..Principled::default()
            },
        },
        Surface::Principled {
            base_color: Vec3::new(0.2, 0.5, 0.7),
            params: Principled {
                roughness: 0.9,
                metallic: 1.0,
                specular_tint: 1.0,
                sheen: 0.6,
                sheen_tint: 0.5,
                flatness: 0.6,
                eta: 0.8,
                ..Principled::default()
            },
        },
        Surface::Principled {
            base_color: Vec3::new(0.7, 0.8, 0.9),
            params: Principled {
                roughness: 0.4,
                metallic: 0.1,
                specular_tint: 0.3,
                sheen: 0.2,
                flatness: 0.3,
                clearcoat: 0.4,
                clearcoat_gloss: 0.5,
                spec_trans: 0.7,
                eta: 1.45,
                ..Principled::default()
            },
        },
        // Anisotropic: turned by each query's tangent.
        Surface::Conductor {
            reflectance: Vec3::new(0.9, 0.8, 0.7),
            alpha: 0.05,
            alpha_v: Some(0.4),
            distribution: Distribution::Ggx,
            fresnel: Some(METAL),
        },
        Surface::Conductor {
            reflectance: Vec3::ONE,
            alpha: 0.5,
            alpha_v: Some(0.2),
            distribution: Distribution::Beckmann,
            fresnel: None,
        },
        Surface::RoughDielectric {
            ior: 1.5,
            reflectance: Vec3::ONE,
            transmittance: Vec3::new(1.0, 0.9, 0.8),
            alpha: 0.3,
            alpha_v: Some(0.08),
            distribution: Distribution::Ggx,
        },
        Surface::Principled {
            base_color: Vec3::new(0.8, 0.6, 0.4),
            params: Principled {
                metallic: 0.3,
                sheen: 0.1,
                clearcoat: 0.2,
                clearcoat_gloss: 0.4,
                spec_trans: 0.5,
                anisotropic: 0.6,
                ..Principled::default()
            },
        },
        // Thin sheets (principledthin): diffuse through, glass, both and
        // anisotropic.
        Surface::Principled {
            base_color: Vec3::new(0.3, 0.6, 0.2),
            params: Principled {
                roughness: 0.4,
                sheen: 0.5,
                sheen_tint: 0.3,
                flatness: 0.3,
                thin: Some(0.4),
                ..Principled::default()
            },
        },
        Surface::Principled {
            base_color: Vec3::new(0.9, 0.8, 0.7),
            params: Principled {
                roughness: 0.3,
                spec_trans: 1.0,
                specular_tint: 0.4,
                thin: Some(0.0),
                ..Principled::default()
            },
        },
        Surface::Principled {
            base_color: Vec3::new(0.6, 0.7, 0.9),
            params: Principled {
                roughness: 0.6,
                spec_trans: 0.5,
                specular_tint: 0.2,
                sheen: 0.3,
                anisotropic: 0.5,
                eta: 1.33,
                thin: Some(0.6),
                ..Principled::default()
            },
        },
    ];
    let mut queries = Vec::new();
    for surface in surfaces {
        for _ in 0..512 {
            let (a, b) = (rng.next(), rng.next());
            // cos θ_o from 0.02 to 1: grazing directions included.
            let z = 0.02 + 0.98 * a;
            let r = (1.0 - z * z).sqrt();
            let phi = std::f32::consts::TAU * b;
            queries.push(probe::BsdfQuery {
                material: Material {
                    name: "probe".into(),
                    surface,
                    emission: Vec3::ZERO,
                    // Mitsuba's BSDFs outside `twosided` are black from behind.
                    one_sided: rng.next() < 0.25,
                    textures: [None; qtrace::scene::TEXTURE_SLOTS],
                    normal_map: None,
                    choice: None,
                    smooth_light: false,
                },
                front: rng.next() < 0.5,
                wo: Vec3::new(r * phi.cos(), r * phi.sin(), z),
                u: Vec3::new(rng.next(), rng.next(), rng.next()),
                tangent: std::f32::consts::TAU * rng.next(),
            });
        }
    }
    for sampling in [Sampling::Cosine, Sampling::Uniform] {
        let out = probe::bsdf_samples(&ctx, &scene, sampling, &queries).unwrap();
        common::assert_no_validation_errors(&ctx);
        for (q, g) in queries.iter().zip(&out) {
            let cpu = q
                .material
                .bsdf(q.front, sampling)
                .with_tangent(Vec2::from_angle(q.tangent));
            let what = format!(
                "{sampling:?} {:?} front {} wo {} u {}",
                q.material.surface, q.front, q.wo, q.u
            );
            // Relative closeness: a narrow GGX lobe's values reach 1e4.
            let close = |a: Vec3, b: Vec3| {
                (a - b).abs().max_element() <= 2e-4 * (1.0 + b.abs().max_element())
            };
            let share = cpu.delta_share(q.wo);
            assert!(
                (g.delta_share - share).abs() <= 1e-5,
                "{what}: GPU delta share {} vs CPU {share}",
                g.delta_share
            );
            if share > 0.0 && !cpu.is_delta() {
                let (_, weight) = cpu.sample_delta(q.wo, q.u.z);
                assert!(
                    close(g.delta_weight, weight),
                    "{what}: GPU coat weight {} vs CPU {weight}",
                    g.delta_weight
                );
            }
            if cpu.is_delta() {
                let (wi, weight) = cpu.sample_delta(q.wo, q.u.z);
                assert!(close(g.wi, wi), "{what}: GPU {} vs CPU {wi}", g.wi);
                assert!(
                    close(g.eval, weight),
                    "{what}: GPU weight {} vs CPU {weight}",
                    g.eval
                );
                assert_eq!(g.pdf, 0.0);
                continue;
            }
            let Some((wi, _)) = cpu.sample(q.wo, q.u) else {
                // Below the horizon: the GPU's pdf there is zero too.
                assert!(
                    g.wi.z <= 1e-5 && g.pdf == 0.0,
                    "{what}: GPU {} pdf {}",
                    g.wi,
                    g.pdf
                );
                continue;
            };
            assert!(close(g.wi, wi), "{what}: GPU {} vs CPU {wi}", g.wi);
            if wi.z.abs() < 1e-3 {
                continue; // grazing: pdf and f are too sensitive to the direction's last bits
            }
            let pdf = cpu.pdf(q.wo, wi);
            assert!(
                (g.pdf - pdf).abs() <= 2e-4 * (1.0 + pdf),
                "{what}: GPU pdf {} vs CPU {pdf}",
                g.pdf
            );
            assert!(
                close(g.eval, cpu.eval(q.wo, wi)),
                "{what}: GPU f cos {} vs CPU {}",
                g.eval,
                cpu.eval(q.wo, wi)
            );
            if matches!(q.material.surface, Surface::Diffuse { .. }) {
                assert!((g.reflected - cpu.reflect(q.wo, 1.0)).abs() < 1e-6);
            }
        }
    }
}

/// The GPU's texture lookups (`bsdf_textured` in glsl/texture.glsl) against
/// the CPU twin: 8-bit sRGB and raw bitmaps, float texels, a checkerboard,
/// every filter and wrap mode, `to_uv`, in every slot of the BSDFs that
/// take textures, on both sides of one-sided and two-sided materials.
#[test]
fn gpu_textures_match_their_cpu_twin() {
    use qtrace::scene::texture::{Filter, Pattern, Texels, Texture, Wrap};
    let ctx = common::gpu();
    let scene = common::scene("cornell-box");
    let png = common::repo("tests/fixtures/textures/small.png");
    let bitmap = |filter, wrap, raw| Texture {
        name: "small.png".into(),
        pattern: Texture::read_bitmap(&png, filter, wrap, raw).unwrap(),
        to_uv: glam::Mat3::IDENTITY,
    };
    let mut rng = Lcg(11);
    let floats = (0..5 * 7)
        .map(|_| Vec3::new(rng.next(), 2.0 * rng.next(), 0.5 * rng.next()))
        .collect();
    let textures = vec![
        bitmap(Filter::Bilinear, Wrap::Repeat, false),
        bitmap(Filter::Nearest, Wrap::Mirror, true),
        Texture {
            to_uv: glam::Mat3::from_scale(Vec2::new(2.0, 3.0))
                * glam::Mat3::from_translation(Vec2::new(0.1, 0.2)),
            ..bitmap(Filter::Bilinear, Wrap::Clamp, false)
        },
        Texture {
            name: "floats".into(),
            pattern: Pattern::Bitmap {
                width: 5,
                height: 7,
                texels: Texels::Floats(floats),
                filter: Filter::Bilinear,
                wrap: Wrap::Mirror,
            },
            to_uv: glam::Mat3::IDENTITY,
        },
        Texture {
            name: "checkerboard".into(),
            pattern: Pattern::Checkerboard {
                color0: Vec3::new(0.1, 0.2, 0.3),
                color1: Vec3::new(0.8, 0.7, 0.6),
            },
            to_uv: glam::Mat3::from_scale(Vec2::splat(4.0)),
        },
    ];
    let surfaces = [
        Surface::Diffuse { albedo: Vec3::ONE },
        Surface::conductor(Vec3::ONE, 0.2),
        Surface::Plastic {
            diffuse: Vec3::splat(0.5),
            specular: Vec3::ONE,
            eta: 1.5,
            nonlinear: false,
        },
        Surface::Thin {
            eta: 1.5,
            reflectance: Vec3::ONE,
            transmittance: Vec3::ONE,
        },
        Surface::RoughDielectric {
            ior: 1.5,
            reflectance: Vec3::ONE,
            transmittance: Vec3::ONE,
            alpha: 0.3,
            alpha_v: None,
            distribution: Distribution::Ggx,
        },
        Surface::RoughDielectric {
            ior: 1.5,
            reflectance: Vec3::ONE,
            transmittance: Vec3::ONE,
            alpha: 0.3,
            alpha_v: Some(0.05),
            distribution: Distribution::Beckmann,
        },
        Surface::Principled {
            base_color: Vec3::splat(0.6),
            params: Principled {
                sheen: 0.3,
                clearcoat: 0.2,
                clearcoat_gloss: 0.4,
                anisotropic: 0.5,
                ..Principled::default()
            },
        },
        Surface::Principled {
            base_color: Vec3::splat(0.6),
            params: Principled {
                spec_trans: 0.5,
                ..Principled::default()
            },
        },
        // A thin sheet: its second slot is its diffuse transmission.
        Surface::Principled {
            base_color: Vec3::splat(0.6),
            params: Principled {
                spec_trans: 0.3,
                thin: Some(0.2),
                ..Principled::default()
            },
        },
    ];
    let mut queries = Vec::new();
    for _ in 0..450 {
        let surface = surfaces[(rng.next() * surfaces.len() as f32) as usize % surfaces.len()];
        let mut pick = || {
            let t = (rng.next() * 7.0) as u32;
            (t < textures.len() as u32).then_some(t)
        };
        let mut slots = [None; qtrace::scene::TEXTURE_SLOTS];
        for s in &mut slots {
            *s = pick();
        }
        if surface.kind() == qtrace::shaders::MATERIAL_PLASTIC {
            slots[2] = None;
        }
        // Only rough glass has an alpha across its tangent of its own, and
        // only a principled material the weights after it.
        if !matches!(surface, Surface::RoughDielectric { .. }) {
            slots[3] = None;
        }
        if !matches!(surface, Surface::Principled { .. }) {
            slots[4..].fill(None);
        }
        // A thin one has no clearcoat.
        if surface.kind() == qtrace::shaders::MATERIAL_PRINCIPLED_THIN {
            slots[qtrace::shaders::TEXTURE_SLOT_CLEARCOAT as usize] = None;
            slots[qtrace::shaders::TEXTURE_SLOT_CLEARCOAT_GLOSS as usize] = None;
        }
        queries.push(probe::TextureQuery {
            material: Material {
                name: "probe".into(),
                surface,
                emission: Vec3::ZERO,
                one_sided: rng.next() < 0.3,
                textures: slots,
                normal_map: None,
                choice: None,
                smooth_light: false,
            },
            front: rng.next() < 0.7,
            uv: Vec2::new(4.0 * rng.next() - 1.5, 4.0 * rng.next() - 1.5),
        });
    }
    let gpu = probe::texture_lookups(&ctx, &scene, &textures, &queries).unwrap();
    common::assert_no_validation_errors(&ctx);
    let mut textured = 0;
    let mut across = 0;
    let mut weights = 0;
    for (q, g) in queries.iter().zip(gpu) {
        let (color, second, alpha, alpha_v) = (g.color, g.second, g.alpha, g.alpha_v);
        let cpu = q
            .material
            .bsdf_at(q.front, q.uv, &textures, Sampling::Cosine);
        let close =
            |a: Vec3, b: Vec3| (a - b).abs().max_element() <= 1e-5 * b.max_element().max(1.0);
        let what = format!("{:?} at {} front {}", q.material, q.uv, q.front);
        assert!(
            close(color, cpu.color),
            "{what}: colour {color} vs CPU {}",
            cpu.color
        );
        if let Some(s) = cpu.second_color() {
            assert!(
                close(second, s),
                "{what}: second colour {second} vs CPU {s}"
            );
        }
        if let Some(a) = cpu.alpha() {
            assert!(
                (alpha - a).abs() <= 1e-5,
                "{what}: alpha {alpha} vs CPU {a}"
            );
        }
        // (A one-sided material's black back is not textured; rough glass
        // whose alpha across holds a texture has no number there.)
        let lit = q.front || !q.material.one_sided;
        if let Some(a) = cpu.alpha_across().filter(|_| lit) {
            assert!(
                (alpha_v - a).abs() <= 1e-5,
                "{what}: alpha across {alpha_v} vs CPU {a}"
            );
        }
        across += usize::from(q.material.textures[3].is_some() && lit);
        if let Some((eta, k)) = cpu.principled_weights() {
            assert!(
                close(second, eta) && close(g.k, k),
                "{what}: principled weights {second} {} vs CPU {eta} {k}",
                g.k
            );
            let extra = cpu.principled_extra().unwrap();
            assert!(
                close(g.extra, extra),
                "{what}: clearcoat gloss, spec_trans, anisotropic {} vs CPU {extra}",
                g.extra
            );
            weights += usize::from(q.material.textures[4..].iter().any(Option::is_some) && lit);
        }
        textured += usize::from(q.material.textured() && (q.front || !q.material.one_sided));
    }
    assert!(textured > 200, "only {textured} textured lookups");
    assert!(across > 20, "only {across} textured alphas across");
    assert!(weights > 20, "only {weights} textured principled weights");
}

/// The GPU's environment (glsl/environment.glsl) against the CPU twin:
/// radiance and NEE's density in directions all over the sphere, and the
/// directions NEE draws with their densities, on a turned envmap with a sun.
#[test]
fn gpu_environment_matches_its_cpu_twin() {
    let ctx = common::gpu();
    let scene =
        qtrace::scene::Scene::load(common::repo("tests/fixtures/mitsuba/coverage-f.xml")).unwrap();
    let env = scene.environment.as_ref().expect("an envmap");
    let mut rng = Lcg(13);
    let queries: Vec<(Vec3, glam::Vec4)> = (0..2000)
        .map(|_| {
            let u = glam::Vec4::new(rng.next(), rng.next(), rng.next(), rng.next());
            (rng.unit(), u)
        })
        .collect();
    for dense in [false, true] {
        let gpu = probe::environment_lookups(&ctx, &scene, &queries, dense).unwrap();
        common::assert_no_validation_errors(&ctx);
        check_environment(env, &queries, gpu, dense);
    }
}

/// Mitsuba's sunsky on the GPU against the CPU twin: the sky model's
/// radiance all over the sphere and on and around the sun's disk (its
/// limb darkened and not), NEE's density, and the directions NEE draws.
#[test]
fn gpu_sky_model_matches_its_cpu_twin() {
    let ctx = common::gpu();
    for limb in ["true", "false"] {
        let scene = qtrace::scene::Scene::load_defined(
            common::repo("tests/fixtures/mitsuba/coverage-t.xml"),
            &[("limb".into(), limb.into())],
        )
        .unwrap();
        let env = scene.environment.as_ref().expect("a sunsky");
        assert!(env.model.is_some(), "the sky is evaluated, not looked up");
        // The sun: the brightest direction NEE draws.
        let mut rng = Lcg(17);
        let sun = (0..4000)
            .map(|_| {
                let u = [rng.next(), rng.next(), rng.next(), rng.next()];
                env.sample(u).0
            })
            .max_by(|a, b| {
                let l = |d: &Vec3| env.eval(*d).element_sum();
                l(a).total_cmp(&l(b))
            })
            .unwrap();
        assert!(env.eval(sun).max_element() > 100.0, "no sun found");
        let queries: Vec<(Vec3, glam::Vec4)> = (0..2000)
            .map(|i| {
                let u = glam::Vec4::new(rng.next(), rng.next(), rng.next(), rng.next());
                // Half of them within about 1.3 of the sun's radii.
                let d = if i % 2 == 0 {
                    rng.unit()
                } else {
                    (sun + 0.006 * rng.unit()).normalize()
                };
                (d, u)
            })
            .collect();
        let on_disk = queries
            .iter()
            .filter(|(d, _)| env.eval(*d).max_element() > 100.0)
            .count();
        assert!(
            on_disk > 100,
            "limb {limb}: only {on_disk} lookups on the sun"
        );
        let gpu = probe::environment_lookups(&ctx, &scene, &queries, false).unwrap();
        common::assert_no_validation_errors(&ctx);
        check_environment(env, &queries, gpu, false);
    }
}

fn check_environment(
    env: &qtrace::scene::environment::Environment,
    queries: &[(Vec3, glam::Vec4)],
    gpu: Vec<probe::EnvironmentProbe>,
    dense: bool,
) {
    let close =
        |a: Vec3, b: Vec3, tol: f32| (a - b).abs().max_element() <= tol * b.max_element().max(1.0);
    let mut misses = 0;
    for ((d, u), ((le, pdf), (w, w_pdf), (w_le, w_back))) in queries.iter().zip(gpu) {
        // Directions on a cell's edge may land in its neighbour on one
        // side and not the other: a handful are allowed.
        let ok = close(le, env.eval(*d), 1e-3) && (pdf - env.pdf(*d)).abs() <= 1e-3 * pdf.max(1e-3);
        let (cw, cpdf) = env.sample(u.to_array());
        let drawn = (w - cw).length() < 1e-3 && (w_pdf - cpdf).abs() <= 1e-4 * cpdf;
        // Drawn directions crowd at the sun's edge, where radiance changes
        // by 6500 a radian: float error in the angles shows there.
        let back = (w_back - w_pdf).abs() <= 1e-3 * w_pdf && close(w_le, env.eval(w), 2e-2);
        if !(ok && drawn && back) {
            misses += 1;
            eprintln!(
                "{d} / {u}: GPU {le} {pdf}, CPU {} {}; drew {w} {w_pdf} (CPU {cw} {cpdf}), there {w_le} {w_back} (CPU {})",
                env.eval(*d),
                env.pdf(*d),
                env.eval(w)
            );
        }
    }
    assert!(
        misses <= 4,
        "dense {dense}: {misses} of {} lookups disagree",
        queries.len()
    );
}

/// An upload larger than the staging buffer goes in pieces, each to its
/// place: a large scene's tables arrive whole (on a GPU; a CPU device's
/// memory takes them in place).
#[test]
fn uploads_larger_than_the_staging_buffer_arrive_whole() {
    use qtrace::gpu::{Buffer, STAGING_BYTES};
    let ctx = common::gpu();
    let words = STAGING_BYTES as u32 / 4 + 1234;
    let data: Vec<u32> = (0..words).map(|i| i.wrapping_mul(2_654_435_761)).collect();
    let buffer = Buffer::gpu_only(&ctx, "two pieces", 4 * words as u64).unwrap();
    buffer.stage(&data).unwrap();
    assert!(buffer.download::<u32>().unwrap() == data);
    common::assert_no_validation_errors(&ctx);
}
