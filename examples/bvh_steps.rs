//! How many steps the trace kernel's BVH walk takes on a scene: a CPU
//! replica of `walk_bvh` (glsl/scene.glsl: one node per step, both children
//! visited, a stack of three in registers, escape links once it overflowed)
//! over the scene's flattened tree. Rays: a camera ray through each pixel
//! of a W×W image, a cosine-distributed bounce from each hit, and a shadow
//! ray from each hit to a point on a light. It prints the mean steps per ray
//! and the mean of the longest walk among each 8 consecutive rays (a SIMD
//! group on lavapipe waits for its longest), so a change to the tree's
//! builder can be judged without a timing. Every 97th camera ray is checked
//! against a test of every triangle. With `--gpu` it also times the walk
//! alone on the device (glsl/walk_bench.comp) for each kind of ray: lanes
//! waiting for their SIMD group's longest walk, as in the trace kernel
//! ("rounds"), lanes starting their next ray as soon as theirs ends
//! ("refill"), and lanes starting theirs once half the group waits
//! ("refill/2"); each must find the replica's hits. A last row walks camera
//! rays and bounces interleaved, as the trace kernel's walk for the closest
//! hit meets them once its lanes' paths drift apart. Run from the
//! repository root:
//!
//!   cargo run --release --example bvh_steps -- scenes/door-ajar.toml [W=128] [--gpu]
//!
//! A measurement for the README, not a test.
use glam::Vec3;
use qtrace::render::probe::{walk_timed, WalkRay};
use qtrace::scene::ray_triangle;
use qtrace::shaders::{BvhNode, Triangle, BVH_LEAF, BVH_NO_CHILD};
use qtrace::Scene;

const FAR: f32 = 3.0e38;

/// The GPU's triangle test: t in (0, tmax), or -1.
fn intersect_triangle(o: Vec3, d: Vec3, v0: Vec3, e1: Vec3, e2: Vec3, tmax: f32) -> f32 {
    let tri = Triangle {
        v0: v0.into(),
        e1: e1.into(),
        e2: e2.into(),
        ..Default::default()
    };
    ray_triangle(o, d, &tri)
        .filter(|&t| t < tmax)
        .unwrap_or(-1.0)
}

fn intersect_box(o: Vec3, inv_d: Vec3, lo: Vec3, hi: Vec3, tmax: f32) -> f32 {
    let t0 = (lo - o) * inv_d;
    let t1 = (hi - o) * inv_d;
    let a = t0.min(t1);
    let b = t0.max(t1);
    let enter = a.x.max(a.y).max(a.z.max(0.0));
    let leave = b.x.min(b.y).min(b.z.min(tmax));
    if enter <= leave {
        enter
    } else {
        FAR
    }
}

fn safe_inverse(d: Vec3) -> Vec3 {
    let f = |x: f32| {
        if x.abs() > 1e-20 {
            x
        } else if x >= 0.0 {
            1e-20
        } else {
            -1e-20
        }
    };
    Vec3::ONE / Vec3::new(f(d.x), f(d.y), f(d.z))
}

/// The nearest hit (t, triangle) before tmax, or any hit, and the steps taken.
fn walk(nodes: &[BvhNode], o: Vec3, d: Vec3, tmax: f32, any_hit: bool) -> (f32, u32, u32) {
    let inv_d = safe_inverse(d);
    let octant = (d.x < 0.0) as usize | ((d.y < 0.0) as usize) << 1 | ((d.z < 0.0) as usize) << 2;
    let (mut t_hit, mut hit) = (tmax, BVH_NO_CHILD);
    let mut node = 0u32;
    let mut stack = [0u32; 3];
    let mut depth = 0usize;
    let mut lost = false;
    let mut steps = 0;
    while node != BVH_NO_CHILD {
        steps += 1;
        let n = &nodes[node as usize];
        let mut visit = |c: u32, a: [f32; 3], b: [f32; 3], k: [f32; 3]| {
            let leaf = c & BVH_LEAF != 0;
            let (p, q, r) = (Vec3::from(a), Vec3::from(b), Vec3::from(k));
            let t = intersect_triangle(o, d, p, q, r, t_hit);
            if leaf && c != BVH_NO_CHILD && t > 0.0 {
                hit = c & !BVH_LEAF;
                t_hit = t;
            }
            let enter = intersect_box(o, inv_d, p, q, t_hit);
            if leaf {
                FAR
            } else {
                enter
            }
        };
        let t0 = visit(n.child0, n.a0, n.b0, n.c0);
        let t1 = visit(n.child1, n.a1, n.b1, n.c1);
        if any_hit && hit != BVH_NO_CHILD {
            break;
        }
        let swap = (octant >> n.axis) & 1 != 0;
        let (first, second) = if swap {
            (n.child1, n.child0)
        } else {
            (n.child0, n.child1)
        };
        let (hit_first, hit_second) = if swap {
            (t1 != FAR, t0 != FAR)
        } else {
            (t0 != FAR, t1 != FAR)
        };
        let popped = if depth > 0 {
            stack[0]
        } else if lost {
            n.escapes[octant]
        } else {
            BVH_NO_CHILD
        };
        if hit_first && hit_second {
            lost |= depth == 3;
            depth = (depth + 1).min(3);
            stack = [second, stack[0], stack[1]];
        } else if !hit_first && !hit_second && depth > 0 {
            depth -= 1;
            stack = [stack[1], stack[2], stack[2]];
        }
        node = if hit_first {
            first
        } else if hit_second {
            second
        } else {
            popped
        };
    }
    (t_hit, hit, steps)
}

/// A small deterministic generator (xorshift), for repeatable rays.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// Steps of each ray of one kind, in SIMD-group order.
#[derive(Default)]
struct Tally {
    steps: Vec<u32>,
    rays: Vec<WalkRay>,
    /// The replica's hit of each ray (triangle, or BVH_NO_CHILD).
    hits: Vec<u32>,
}

impl Tally {
    fn report(&self, what: &str) {
        let n = self.steps.len().max(1) as f64;
        let mean = self.steps.iter().map(|&s| s as f64).sum::<f64>() / n;
        let groups: Vec<u32> = self
            .steps
            .chunks(8)
            .map(|c| *c.iter().max().unwrap_or(&0))
            .collect();
        let longest = groups.iter().map(|&s| s as f64).sum::<f64>() / groups.len().max(1) as f64;
        println!(
            "{what:>8}: {:>7} rays, {mean:6.2} steps per ray, {longest:6.2} for the longest of 8",
            self.steps.len()
        );
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let Some(path) = args.get(1) else {
        eprintln!("usage: bvh_steps SCENE [WIDTH]");
        std::process::exit(2);
    };
    let width: u32 = args.get(2).and_then(|w| w.parse().ok()).unwrap_or(128);
    let scene = match Scene::load(path) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    };
    let eps = scene.ray_offset();
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let (mut camera, mut bounce, mut shadow) =
        (Tally::default(), Tally::default(), Tally::default());
    let (mut checked, mut mismatches) = (0, 0);
    for y in 0..width {
        for x in 0..width {
            let (o, d) =
                scene
                    .camera
                    .ray(x as f32 + rng.next(), y as f32 + rng.next(), width, width);
            let (t, tri, steps) = walk(&scene.nodes, o, d, FAR, false);
            camera.steps.push(steps);
            camera.rays.push((o, d, FAR, false));
            camera.hits.push(tri);
            // The replica must find what testing every triangle finds.
            if (x + y * width) % 97 == 0 {
                checked += 1;
                let brute = scene.intersect_brute(o, d);
                if brute.map(|b| b.1) != (tri != BVH_NO_CHILD).then_some(tri) {
                    mismatches += 1;
                }
            }
            if tri == BVH_NO_CHILD {
                continue;
            }
            let t_ = &scene.triangles[tri as usize];
            let n = Vec3::from(t_.e1).cross(Vec3::from(t_.e2)).normalize();
            let n = if n.dot(d) < 0.0 { n } else { -n };
            let p = o + t * d + n * eps;
            // A cosine-distributed bounce.
            let (u1, u2) = (rng.next(), rng.next());
            let (r, phi) = (u1.sqrt(), 2.0 * std::f32::consts::PI * u2);
            let (tx, ty) = n.any_orthonormal_pair();
            let w = tx * r * phi.cos() + ty * r * phi.sin() + n * (1.0 - u1).max(0.0).sqrt();
            let (_, hit, steps) = walk(&scene.nodes, p, w, FAR, false);
            bounce.steps.push(steps);
            bounce.rays.push((p, w, FAR, false));
            bounce.hits.push(hit);
            // A shadow ray to a point on a light.
            if let Some(light) = scene
                .lights
                .get((rng.next() * scene.lights.len() as f32) as usize)
            {
                let l = &scene.triangles[light.triangle as usize];
                let (mut a, mut b) = (rng.next(), rng.next());
                if a + b > 1.0 {
                    (a, b) = (1.0 - a, 1.0 - b);
                }
                let target = Vec3::from(l.v0) + a * Vec3::from(l.e1) + b * Vec3::from(l.e2);
                let to = target - p;
                let dist = to.length();
                if to.dot(n) > 0.0 {
                    let tmax = dist * (1.0 - 1e-4) - eps;
                    let (_, hit, steps) = walk(&scene.nodes, p, to / dist, tmax, true);
                    shadow.steps.push(steps);
                    shadow.rays.push((p, to / dist, tmax, true));
                    shadow.hits.push(hit);
                }
            }
        }
    }
    println!(
        "{} ({} triangles, {} nodes, depth {})",
        path,
        scene.triangles.len(),
        scene.nodes.len(),
        scene.bvh_depth
    );
    camera.report("camera");
    bounce.report("bounce");
    shadow.report("shadow");
    println!("{mismatches} of {checked} camera rays checked against every triangle differ");
    if args.iter().any(|a| a == "--gpu") {
        // Camera rays and bounces interleaved, so that a SIMD group's
        // neighbours are of the other kind, as in the trace kernel's walk for
        // the closest hit once its lanes' paths drift apart.
        let mut mixed = Tally::default();
        let kinds = [&camera, &bounce];
        let longest = kinds.iter().map(|k| k.rays.len()).max().unwrap_or(0);
        for i in 0..longest {
            for k in kinds {
                if let (Some(&r), Some(&h)) = (k.rays.get(i), k.hits.get(i)) {
                    mixed.rays.push(r);
                    mixed.hits.push(h);
                }
            }
        }
        gpu_walks(
            &scene,
            [
                ("camera", &camera),
                ("bounce", &bounce),
                ("shadow", &shadow),
                ("mixed", &mixed),
            ],
        );
    }
}

/// Times the walk-only kernel on each kind of ray, lanes waiting for their
/// group's longest walk and lanes starting their next ray at once, and
/// checks both find the replica's hits (shadow rays: whether they hit).
fn gpu_walks(scene: &Scene, kinds: [(&str, &Tally); 4]) {
    let ctx = match qtrace::gpu::GpuContext::new(&Default::default()) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    };
    let per_lane = 32;
    for (what, tally) in kinds {
        let mut line = format!("{what:>8} on {}:", ctx.info().name);
        for refill in [0, 1, 2] {
            let (hits, seconds) = walk_timed(&ctx, scene, &tally.rays, per_lane, refill, 5)
                .unwrap_or_else(|e| {
                    eprintln!("error: {e}");
                    std::process::exit(1);
                });
            let differ = hits
                .iter()
                .zip(&tally.hits)
                .zip(&tally.rays)
                .filter(|&((&(_, g), &c), ray)| {
                    (g == u32::MAX) != (c == BVH_NO_CHILD) || (!ray.3 && g != c)
                })
                .count();
            line += &format!(
                " {} {:.2} Mrays/s ({:.2} ms, {differ} differ)",
                ["rounds", "refill", "refill/2"][refill as usize],
                tally.rays.len() as f64 / seconds / 1e6,
                seconds * 1e3
            );
        }
        println!("{line}");
    }
}
