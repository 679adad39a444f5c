//! The GLSL building blocks against CPU references: BVH traversal against
//! brute force, the hemisphere map and the BSDF against their CPU twins.

mod common;

use common::Lcg;

use glam::{Vec2, Vec3};
use qtrace::bsdf::Bsdf;
use qtrace::render::{probe, Sampling};
use qtrace::sampling;

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

/// The GPU BSDF (glsl/bsdf.glsl) against its CPU twin (src/bsdf.rs), with
/// either sampler.
#[test]
fn gpu_bsdf_matches_its_cpu_twin() {
    let ctx = common::gpu();
    let scene = common::scene("cornell-box");
    let mut rng = Lcg(5);
    let uniforms: Vec<Vec2> = (0..4096)
        .map(|_| Vec2::new(rng.next(), rng.next()))
        .collect();
    for sampling in [Sampling::Cosine, Sampling::Uniform] {
        let out = probe::bsdf_samples(&ctx, &scene, 0.7, sampling, &uniforms).unwrap();
        common::assert_no_validation_errors(&ctx);
        let cpu = Bsdf {
            albedo: Vec3::splat(0.7),
            sampling,
        };
        for (u, g) in uniforms.iter().zip(&out) {
            let (wi, _) = cpu.sample(Vec3::Z, *u);
            let close = |a: Vec3, b: Vec3| (a - b).abs().max_element() < 1e-5;
            assert!(
                close(g.wi, wi),
                "{sampling:?} {u}: GPU {} vs CPU {wi}",
                g.wi
            );
            assert!(
                (g.pdf - cpu.pdf(Vec3::Z, wi)).abs() < 1e-5,
                "{sampling:?} {u}"
            );
            assert!(close(g.eval, cpu.eval(Vec3::Z, wi)), "{sampling:?} {u}");
            assert!((g.reflected - cpu.reflect(Vec3::Z, 1.0)).abs() < 1e-6);
        }
    }
}
