//! Rendering tests on lavapipe: analytic furnace, determinism, and the
//! statistical agreement of `pt` with and without next-event estimation.

mod common;

use qtrace::image::Image;
use qtrace::render::{Overrides, RenderOutput, Sampling};

/// White furnace: every surface reflects all light (albedo 1) under a uniform
/// environment of radiance 1, so every pixel's expected value is exactly 1.
#[test]
fn white_furnace_matches_analytic_value() {
    let ctx = common::gpu();
    let scene = common::scene("furnace");
    for (nee, sampling) in [
        (false, Sampling::Cosine),
        (true, Sampling::Cosine),
        (false, Sampling::Uniform),
    ] {
        let out = common::render_with(
            &ctx,
            &scene,
            Overrides {
                spp: Some(64),
                nee,
                sampling: Some(sampling),
                ..Default::default()
            },
        );
        let mean = out.image.mean();
        assert!(
            (mean - 1.0).abs() < 0.01,
            "nee={nee} {sampling:?}: image mean {mean}"
        );
        // Per pixel: the distance from 1 is within the pixel's own statistical error.
        let n = out.stats.spp as f32;
        let far = (0..out.image.pixels.len())
            .flat_map(|i| (0..3).map(move |c| (i, c)))
            .filter(|&(i, c)| {
                let err = (out.image.pixels[i][c] - 1.0).abs();
                let se = (out.variance.pixels[i][c] / n).sqrt();
                err > 5.0 * se + 1e-4
            })
            .count();
        assert!(
            far * 100 <= out.image.pixels.len() * 3,
            "nee={nee} {sampling:?}: {far} pixel channels far from 1"
        );
        assert!(
            out.stats.mean_path_length > 1.0,
            "paths must bounce in the box"
        );
    }
}

#[test]
fn same_seed_gives_the_same_image_and_other_seeds_do_not() {
    let ctx = common::gpu();
    let scene = common::scene("cornell-box");
    let run = |seed| {
        common::render_with(
            &ctx,
            &scene,
            Overrides {
                spp: Some(4),
                width: Some(48),
                height: Some(40),
                nee: true,
                seed: Some(seed),
                ..Default::default()
            },
        )
        .image
    };
    let a = run(11);
    assert_eq!(a, run(11), "same seed, different image");
    assert_ne!(a, run(12), "different seeds gave identical images");
}

#[test]
fn stats_are_consistent() {
    let ctx = common::gpu();
    let scene = common::scene("cornell-box");
    let out = common::render_with(
        &ctx,
        &scene,
        Overrides {
            spp: Some(3),
            width: Some(32),
            height: Some(24),
            ..Default::default()
        },
    );
    let s = &out.stats;
    assert_eq!(s.spp, 3);
    assert_eq!(s.paths, 3 * 32 * 24);
    assert_eq!(s.passes.len(), 3);
    assert!(s.rays >= s.paths);
    assert!((0.0..=1.0).contains(&s.zero_contribution_fraction));
    // Without NEE a path counts only if it reaches the small light: most do not.
    assert!(s.zero_contribution_fraction > 0.5);
    assert!(s.mean_path_length >= 1.0);
    assert!(s.gpu_ms.contains_key("trace") && s.gpu_ms.contains_key("accumulate"));
    assert_eq!(s.invalid_paths, 0);
    let json = serde_json::to_value(s).unwrap();
    for key in [
        "method",
        "spp",
        "wall_seconds",
        "samples_per_second",
        "rays_per_second",
        "zero_contribution_fraction",
        "mean_path_length",
        "gpu_ms",
        "guide_bytes",
        "passes",
    ] {
        assert!(json.get(key).is_some(), "stats JSON lacks '{key}'");
    }
}

/// Two-sample z statistics of two independent renders, per pixel of the image
/// binned `bin` × `bin` (binning makes the rare, bright light hits of plain path
/// tracing add up to a near-normal mean). `bin` = full size gives the image mean.
fn z_scores(a: &RenderOutput, b: &RenderOutput, bin: usize) -> Vec<f64> {
    let (w, h) = (a.image.width, a.image.height);
    let (na, nb) = (a.stats.spp as f64, b.stats.spp as f64);
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

/// `pt` with and without NEE estimate the same integral: their Cornell box
/// images agree pixel by pixel within statistical error at a fixed seed and budget.
#[test]
fn cornell_box_pt_and_nee_converge_to_the_same_image() {
    let ctx = common::gpu();
    let scene = common::scene("cornell-box");
    let opts = |nee, seed| Overrides {
        spp: Some(if nee { 512 } else { 4096 }),
        width: Some(32),
        height: Some(32),
        nee,
        seed: Some(seed),
        ..Default::default()
    };
    let plain = common::render_with(&ctx, &scene, opts(false, 1));
    let nee = common::render_with(&ctx, &scene, opts(true, 2));
    // Per binned pixel (4 x 4): few beyond 4 sigma, and a spread close to N(0, 1).
    let z = z_scores(&plain, &nee, 4);
    let n = z.len() as f64;
    let outliers = z.iter().filter(|v| v.abs() > 4.0).count();
    let rms_z = (z.iter().map(|v| v * v).sum::<f64>() / n).sqrt();
    // Whole image: a bias of a fraction of a percent shows here.
    let image_z = z_scores(&plain, &nee, 32);
    let mean_z = image_z.iter().map(|v| v.abs()).fold(0.0, f64::max);
    let ok = outliers as f64 <= 0.02 * n && rms_z < 1.5 && mean_z < 4.0;
    if !ok {
        let diff = Image {
            width: plain.image.width,
            height: plain.image.height,
            pixels: plain
                .image
                .pixels
                .iter()
                .zip(&nee.image.pixels)
                .map(|(p, q)| [p[0] - q[0], p[1] - q[1], p[2] - q[2]])
                .collect(),
        };
        common::save_failure_images(
            "cornell-pt-vs-nee",
            &[
                ("pt", &plain.image),
                ("nee", &nee.image),
                ("difference", &diff),
            ],
        );
    }
    assert!(
        ok,
        "pt vs pt+nee: {outliers} of {n} binned pixel channels beyond 4 sigma, rms z {rms_z:.3}, image-mean z {mean_z:.3}"
    );
    // And NEE must actually help: fewer zero-contribution paths.
    assert!(nee.stats.zero_contribution_fraction < plain.stats.zero_contribution_fraction);
}
