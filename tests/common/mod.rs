//! Shared test helpers: a validated GPU context and image statistics.
#![allow(dead_code)]

use glam::{Vec2, Vec3};
use qtrace::gpu::{ContextOptions, GpuContext};
use qtrace::guide::GuideSettings;
use qtrace::image::Image;
use qtrace::render::{self, Overrides, RenderOutput, RenderSettings};
use qtrace::sampling;
use qtrace::Scene;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use std::sync::Arc;

pub fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(path)
}

/// A command that succeeded, or its stderr as the failure.
pub fn assert_success(output: &std::process::Output) {
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
}

/// A JSON file the binary wrote (stats, a bench's results).
pub fn read_json(path: impl AsRef<Path>) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// The qtrace binary, with the validation layer (synchronisation
/// validation included) on: any error it reports fails the command.
pub fn qtrace() -> std::process::Command {
    let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_qtrace"));
    c.env("QTRACE_VALIDATION", "1");
    c
}

/// A fresh, empty directory `target/test-scratch/<name>` of this test's own:
/// a fresh clone has no `target/`, and tests run in any order.
pub fn scratch(name: &str) -> PathBuf {
    let dir = repo(&format!("target/test-scratch/{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    dir
}

/// A context on the default device (or QTRACE_DEVICE) with validation on.
/// Without a Vulkan device the test fails with the reason: it never passes silently.
pub fn gpu() -> Arc<GpuContext> {
    let ctx = GpuContext::new(&ContextOptions {
        device: std::env::var("QTRACE_DEVICE").ok(),
        validation: true,
        reads: std::env::var("QTRACE_READS").ok().map(|v| {
            clap::ValueEnum::from_str(&v, true).unwrap_or_else(|e| panic!("QTRACE_READS: {e}"))
        }),
    })
    .unwrap_or_else(|e| panic!("GPU test needs a Vulkan device (lavapipe will do): {e}"));
    if !ctx.validation_enabled() {
        eprintln!("note: VK_LAYER_KHRONOS_validation is not installed; running without validation");
    }
    ctx
}

/// Fails the test if the validation layer reported errors on `ctx`.
pub fn assert_no_validation_errors(ctx: &GpuContext) {
    assert_eq!(
        ctx.validation_errors(),
        0,
        "Vulkan validation errors (see log above)"
    );
}

pub fn scene(name: &str) -> Scene {
    Scene::load(repo(&format!("scenes/{name}.toml"))).expect("shipped scene loads")
}

pub fn render_with(ctx: &Arc<GpuContext>, scene: &Scene, o: Overrides) -> RenderOutput {
    let settings = RenderSettings::resolve(scene, &o).expect("valid settings");
    let out = render::render(ctx, scene, settings, &mut |_| {}).expect("render");
    assert_no_validation_errors(ctx);
    out
}

/// A renderer that has run the whole render `o` asks for, to read what its
/// guide learned.
pub fn run_renderer(ctx: &Arc<GpuContext>, scene: &Scene, o: Overrides) -> render::Renderer {
    let settings = RenderSettings::resolve(scene, &o).expect("valid settings");
    let mut renderer = render::Renderer::new(ctx, scene, settings).expect("renderer");
    renderer.run(&mut |_| {}).expect("render");
    assert_no_validation_errors(ctx);
    renderer
}

/// A small render of shipped scene `name` (64 spp at 32×32) guided by
/// `guide`, run to its end.
pub fn run_guided(name: &str, guide: GuideSettings) -> render::Renderer {
    let method = render::Method::named(guide.name()).unwrap();
    let o = Overrides {
        method: Some(method),
        spp: Some(64),
        width: Some(32),
        height: Some(32),
        guide: Some(guide),
        ..Default::default()
    };
    run_renderer(&gpu(), &scene(name), o)
}

/// Small deterministic generator so failures reproduce.
pub struct Lcg(pub u64);

impl Lcg {
    pub fn next(&mut self) -> f32 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 40) as f32) / (1u64 << 24) as f32
    }

    pub fn below(&mut self, n: u32) -> u32 {
        ((self.next() * n as f32) as u32).min(n - 1)
    }

    /// A uniformly distributed unit vector (by rejection).
    pub fn unit(&mut self) -> glam::Vec3 {
        loop {
            let v = glam::Vec3::new(self.next(), self.next(), self.next()) * 2.0 - glam::Vec3::ONE;
            if v.length_squared() > 1e-4 && v.length_squared() <= 1.0 {
                return v.normalize();
            }
        }
    }
}

/// Where failing image tests leave their pictures.
pub fn artifact_dir() -> PathBuf {
    let dir = repo("target/test-output");
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

pub fn save_failure_images(name: &str, images: &[(&str, &Image)]) {
    let dir = artifact_dir();
    for (tag, img) in images {
        let path = dir.join(format!("{name}-{tag}.exr"));
        img.write_exr(&path).unwrap();
        eprintln!("wrote {}", path.display());
    }
}

/// Two-sample z statistics of two independent renders, per pixel of the image
/// binned `bin` × `bin` (binning makes the rare, bright light hits of plain path
/// tracing add up to a near-normal mean). `bin` = full size gives the image mean.
pub fn z_scores(a: &RenderOutput, b: &RenderOutput, bin: usize) -> Vec<f64> {
    let (w, h) = (a.image.width, a.image.height);
    let (na, nb) = (a.stats.image_spp as f64, b.stats.image_spp as f64);
    let mut z = Vec::new();
    for by in (0..h).step_by(bin) {
        for bx in (0..w).step_by(bin) {
            for c in 0..3 {
                let (mut d, mut se2) = (0.0f64, 0.0f64);
                for y in by..(by + bin).min(h) {
                    for x in bx..(bx + bin).min(w) {
                        let i = y * w + x;
                        d += a.image.pixels[i][c] as f64 - b.image.pixels[i][c] as f64;
                        se2 += a.variance.pixels[i][c] as f64 / na
                            + b.variance.pixels[i][c] as f64 / nb;
                    }
                }
                if se2 > 0.0 {
                    z.push(d / se2.sqrt());
                } else {
                    assert!(
                        d.abs() < 1e-5,
                        "block ({bx}, {by}): noiseless but different"
                    );
                }
            }
        }
    }
    z
}

/// Two renders estimate the same image: per pixel binned 4 × 4, few z-scores
/// beyond 4 sigma and a spread close to N(0, 1); over the whole image, |z| < 4.
/// On failure, writes both images and their difference to target/test-output.
pub fn assert_same_expectation(name: &str, a: &RenderOutput, b: &RenderOutput) {
    assert_same_expectation_binned(name, a, b, 4);
}

/// [`assert_same_expectation`] with `bin` × `bin` pixel bins (1: every pixel on its own).
pub fn assert_same_expectation_binned(name: &str, a: &RenderOutput, b: &RenderOutput, bin: usize) {
    let z = z_scores(a, b, bin);
    let n = z.len() as f64;
    let outliers = z.iter().filter(|v| v.abs() > 4.0).count();
    let rms_z = (z.iter().map(|v| v * v).sum::<f64>() / n).sqrt();
    let whole = a.image.width.max(a.image.height);
    let image_z = z_scores(a, b, whole)
        .iter()
        .map(|v| v.abs())
        .fold(0.0, f64::max);
    let ok = outliers as f64 <= 0.02 * n && rms_z < 1.5 && image_z < 4.0;
    if !ok {
        let diff = Image {
            width: a.image.width,
            height: a.image.height,
            pixels: a
                .image
                .pixels
                .iter()
                .zip(&b.image.pixels)
                .map(|(p, q)| [p[0] - q[0], p[1] - q[1], p[2] - q[2]])
                .collect(),
        };
        save_failure_images(
            name,
            &[("a", &a.image), ("b", &b.image), ("difference", &diff)],
        );
    }
    assert!(
        ok,
        "{name}: {outliers} of {n} binned pixel channels beyond 4 sigma, rms z {rms_z:.3}, whole-image z {image_z:.3}"
    );
}

/// The white furnace has an analytic answer (every pixel is 1): the image
/// mean must lie within 5 standard errors of it.
pub fn assert_white_furnace(out: &RenderOutput) {
    let n = (3 * out.image.pixels.len()) as f64;
    let mean = out.image.mean();
    // Standard error of the image mean from the per-pixel variances.
    let se = (out
        .variance
        .pixels
        .iter()
        .flatten()
        .map(|&v| v as f64)
        .sum::<f64>()
        / out.stats.image_spp as f64)
        .sqrt()
        / n;
    let z = (mean - 1.0) / se;
    assert!(
        z.abs() < 5.0,
        "image mean {mean}, {z:.2} standard errors from 1"
    );
}

/// Regularised upper incomplete gamma Q(a, x) by series/continued fraction
/// (Numerical Recipes), for the chi-square p-value.
pub fn chi2_survival(chi2: f64, dof: f64) -> f64 {
    let (a, x) = (dof / 2.0, chi2 / 2.0);
    let ln_gamma = |z: f64| {
        // Lanczos approximation.
        let g = [
            76.18009172947146,
            -86.50532032941677,
            24.01409824083091,
            -1.231739572450155,
            0.1208650973866179e-2,
            -0.5395239384953e-5,
        ];
        let mut y = z;
        let tmp = z + 5.5 - (z + 0.5) * (z + 5.5).ln();
        let mut ser = 1.000000000190015;
        for c in g {
            y += 1.0;
            ser += c / y;
        }
        -tmp + (2.5066282746310005 * ser / z).ln()
    };
    if x < a + 1.0 {
        let (mut sum, mut del, mut ap) = (1.0 / a, 1.0 / a, a);
        for _ in 0..1000 {
            ap += 1.0;
            del *= x / ap;
            sum += del;
        }
        1.0 - sum * (-x + a * x.ln() - ln_gamma(a)).exp()
    } else {
        let (mut b, mut c, mut d) = (x + 1.0 - a, 1.0 / 1e-300, 1.0 / (x + 1.0 - a));
        let mut h = d;
        for i in 1..1000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            d = 1.0 / if d.abs() < 1e-300 { 1e-300 } else { d };
            c = b + an / c;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-12 {
                break;
            }
        }
        (-x + a * x.ln() - ln_gamma(a)).exp() * h
    }
}

/// χ² test of a guide's sampler: `samples` (local direction, reported pdf)
/// drawn from the one-sample mixture eps · cosine + (1 − eps) · (sector k
/// with probability p[k], uniform inside it) over an a×b `grid`. Each
/// reported pdf must be the mixture's, and the directions must follow it.
pub fn assert_mixture_sampler(samples: &[(Vec3, f32)], p: &[f64], eps: f64, grid: [u32; 2]) {
    assert_mixture_sampler_with(samples, p, eps, grid, &|w: Vec3| w.z as f64 / PI);
}

/// [`assert_mixture_sampler`] for any BSDF: `bsdf_pdf` is its sampler's
/// solid-angle density (which may lose mass below the horizon: such draws
/// must come with pdf 0) and `eps` its share of the mixture.
pub fn assert_mixture_sampler_with(
    samples: &[(Vec3, f32)],
    p: &[f64],
    eps: f64,
    grid: [u32; 2],
    bsdf_pdf: &dyn Fn(Vec3) -> f64,
) {
    let (a, b) = (grid[0] as usize, grid[1] as usize);
    let n = a * b;
    let draws = samples.len();
    // Bins: each sector split 2 x 2 on the square.
    let sub = 2usize;
    let (ba, bb) = (a * sub, b * sub);
    let mut observed = vec![0f64; ba * bb];
    for (w, pdf) in samples {
        assert!((w.length() - 1.0).abs() < 1e-4, "bad direction {w}");
        if w.z <= 0.0 {
            assert_eq!(*pdf, 0.0, "a direction below the horizon at {w}");
            continue;
        }
        let u = sampling::hemisphere_to_square(*w);
        let (i, j) = (
            ((u.x * ba as f32) as usize).min(ba - 1),
            ((u.y * bb as f32) as usize).min(bb - 1),
        );
        observed[i + ba * j] += 1.0;
        // The reported pdf is the mixture's. Within rounding of a sector edge
        // the CPU may place the direction in the neighbouring sector: accept either.
        let pdf_in = |k: usize| eps * bsdf_pdf(*w) + (1.0 - eps) * p[k] * n as f64 / (2.0 * PI);
        let near: Vec<usize> = [
            (0.0, 0.0),
            (1e-5, 0.0),
            (-1e-5, 0.0),
            (0.0, 1e-5),
            (0.0, -1e-5),
        ]
        .iter()
        .map(|(dx, dy)| {
            let c = (u + Vec2::new(*dx, *dy)).clamp(Vec2::ZERO, Vec2::splat(0.999_999));
            (c.x * a as f32) as usize + a * (c.y * b as f32) as usize
        })
        .collect();
        assert!(
            near.iter()
                .any(|&k| (*pdf as f64 - pdf_in(k)).abs() <= 1e-3 * pdf_in(k) + 1e-6),
            "pdf {pdf} vs {} at {w}",
            pdf_in(near[0])
        );
    }
    // Expected bin probabilities: the BSDF part integrated over the bin
    // (dω = 2π du dv under the equal-area map), the guided part uniform in its sector.
    let m = 12;
    let mut chi2 = 0.0;
    let mut bins = 0;
    for j in 0..bb {
        for i in 0..ba {
            let mut cos_integral = 0.0;
            for y in 0..m {
                for x in 0..m {
                    let u = Vec2::new(
                        (i as f32 + (x as f32 + 0.5) / m as f32) / ba as f32,
                        (j as f32 + (y as f32 + 0.5) / m as f32) / bb as f32,
                    );
                    cos_integral += bsdf_pdf(sampling::square_to_hemisphere(u));
                }
            }
            let cos_prob = 2.0 * PI * cos_integral / (m * m) as f64 / (ba * bb) as f64;
            let k = (i / sub) + a * (j / sub);
            let prob = eps * cos_prob + (1.0 - eps) * p[k] / (sub * sub) as f64;
            let e = prob * draws as f64;
            let o = observed[i + ba * j];
            if e < 5.0 {
                assert!(
                    o <= 5.0 * e.max(1.0) + 10.0,
                    "bin ({i}, {j}): {o} draws where {e} expected"
                );
                continue;
            }
            chi2 += (o - e) * (o - e) / e;
            bins += 1;
        }
    }
    let p_value = chi2_survival(chi2, (bins - 1) as f64);
    assert!(
        p_value > 1e-3,
        "chi-square {chi2:.1} over {bins} bins: p = {p_value:.2e}"
    );
}

/// Renders `scene` at 32×32 with `guided` (method, spp, NEE and its
/// options) and checks it estimates the same image as a 1024-spp pt+NEE
/// reference. Returns the guided render.
pub fn assert_converges_to_pt(name: &str, scene: &Scene, guided: Overrides) -> RenderOutput {
    let ctx = gpu();
    let size = |o: Overrides| Overrides {
        width: Some(32),
        height: Some(32),
        ..o
    };
    let reference = render_with(
        &ctx,
        scene,
        size(Overrides {
            spp: Some(1024),
            nee: true,
            seed: Some(100),
            ..Default::default()
        }),
    );
    let out = render_with(&ctx, scene, size(guided));
    assert_same_expectation(name, &out, &reference);
    out
}

/// Learning shows: the last 8 passes the guide guided in its usual way
/// (neither a race's pass nor one after it stood back) leave fewer
/// zero-contribution paths than the first, and every pass reports a finite
/// loss.
pub fn assert_learning_shows(name: &str, out: &RenderOutput) {
    let s = &out.stats;
    let p = &s.passes;
    // Passes that learn report a finite loss (learning thins out over a render).
    assert!(p[0].loss.is_some());
    assert!(p.iter().all(|r| r.loss.is_none_or(f64::is_finite)));
    let guided: Vec<&qtrace::render::PassRecord> = p
        .iter()
        .filter(|r| s.guide_stood_back_after.is_none_or(|a| r.pass < a))
        .filter(|r| {
            !s.guide_races
                .iter()
                .any(|race| (race.after..race.after + 4).contains(&r.pass))
        })
        .collect();
    let first = p[0].zero_contribution_fraction;
    let last = guided[guided.len() - 8..]
        .iter()
        .map(|r| r.zero_contribution_fraction)
        .sum::<f64>()
        / 8.0;
    assert!(
        last < first,
        "{name}: zero-contribution {first} at first, {last} at the end"
    );
}
