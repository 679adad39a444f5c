//! Rendering tests on lavapipe: analytic furnace, determinism, and the
//! statistical agreement of `pt` with and without next-event estimation.

mod common;

use qtrace::render::{Method, Overrides, RenderSettings, Renderer, Sampling};

/// White furnace: every surface reflects all light (albedo 1) under a uniform
/// environment of radiance 1, so every pixel's expected value is exactly 1.
#[test]
fn white_furnace_matches_analytic_value() {
    let ctx = common::gpu();
    let scene = common::scene("furnace");
    // NEE draws the sky; the guides learn it and sample toward it.
    for (method, nee, sampling) in [
        (Method::PT, false, Sampling::Cosine),
        (Method::PT, true, Sampling::Cosine),
        (Method::PT, false, Sampling::Uniform),
        (Method::SARSA, true, Sampling::Cosine),
        (Method::NEURAL, true, Sampling::Cosine),
    ] {
        let out = common::render_with(
            &ctx,
            &scene,
            Overrides {
                method: Some(method),
                spp: Some(64),
                nee,
                sampling: Some(sampling),
                ..Default::default()
            },
        );
        let mean = out.image.mean();
        assert!(
            (mean - 1.0).abs() < 0.01,
            "{method:?} nee={nee} {sampling:?}: image mean {mean}"
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
            "{method:?} nee={nee} {sampling:?}: {far} pixel channels far from 1"
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

/// With fixed-point tallies (the default where the device has 64-bit
/// atomics) Sarsa's image is the same bit for bit under one seed, with and
/// without NEE; float atomics add in another order each run. (Races, which
/// read the clock, begin after 16 passes: see `qtrace::render::race`.)
#[test]
fn sarsa_is_reproducible_bit_for_bit_with_fixed_point_tallies() {
    use qtrace::guide::{sarsa::Atomics, GuideSettings, SarsaSettings};
    let ctx = common::gpu();
    if !ctx.info().int64_atomics {
        eprintln!(
            "SKIPPED: device '{}' lacks 64-bit buffer atomics",
            ctx.info().name
        );
        return;
    }
    let scene = common::scene("cornell-box");
    for nee in [false, true] {
        let run = || {
            common::render_with(
                &ctx,
                &scene,
                Overrides {
                    method: Some(qtrace::Method::SARSA),
                    spp: Some(16),
                    width: Some(64),
                    height: Some(64),
                    nee,
                    seed: Some(5),
                    guide: Some(GuideSettings::from(SarsaSettings {
                        atomics: Atomics::Fixed,
                        ..Default::default()
                    })),
                    ..Default::default()
                },
            )
            .image
        };
        let a = run();
        for _ in 0..2 {
            assert_eq!(a, run(), "nee {nee}: same seed, different image");
        }
    }
}

/// A dispatch that traces several samples per pixel gives exactly the image
/// and per-pass stats of one dispatch per sample (checkpoints at every
/// sample force the latter), though the lanes claim different paths from
/// their dispatch's work in each (in a dispatch of one sample per pixel a
/// lane may take up to MAX_CLAIMS): every path is traced once.
#[test]
fn several_samples_per_dispatch_change_nothing() {
    // The door ajar's deep walks would spend llvmpipe's shared loop budget
    // if lanes took paths without bound (they once did: its image broke).
    for (name, width, height) in [("cornell-box", 24, 20), ("door-ajar", 64, 48)] {
        samples_per_dispatch_change_nothing(name, width, height);
    }
}

fn samples_per_dispatch_change_nothing(name: &str, width: u32, height: u32) {
    let ctx = common::gpu();
    let scene = common::scene(name);
    let settings = RenderSettings::resolve(
        &scene,
        &Overrides {
            spp: Some(12),
            width: Some(width),
            height: Some(height),
            nee: true,
            seed: Some(3),
            ..Default::default()
        },
    )
    .unwrap();
    let mut shared = Renderer::new(&ctx, &scene, settings.clone()).unwrap();
    let a = shared.run(&mut |_| {}).unwrap();
    let every: Vec<u32> = (1..=12).collect();
    let mut single = Renderer::new(&ctx, &scene, settings).unwrap();
    let b = single
        .run_with_checkpoints(&mut |_| {}, &every, &mut |_| {})
        .unwrap();
    common::assert_no_validation_errors(&ctx);
    assert_eq!(a.image, b.image, "{name}");
    let pass = |s: &qtrace::render::RenderStats| {
        s.passes
            .iter()
            .map(|p| (p.rays, p.zero_contribution_fraction, p.mean_path_length))
            .collect::<Vec<_>>()
    };
    assert_eq!(pass(&a.stats), pass(&b.stats), "{name}");
    assert_eq!(b.stats.trace_dispatches, 12);
    assert!(
        a.stats.trace_dispatches < 12,
        "{name}: no dispatch was shared: {}",
        a.stats.trace_dispatches
    );
}

/// The bench steps its methods' renders in turn: each gives the image it
/// gives alone, and its clock counts only its own batches.
#[test]
fn renders_stepped_in_turn_keep_their_images_and_their_own_clocks() {
    use qtrace::render::{Control, Method};
    let ctx = common::gpu();
    let scene = common::scene("cornell-box");
    let settings = |method| {
        RenderSettings::resolve(
            &scene,
            &Overrides {
                method: Some(method),
                spp: Some(6),
                width: Some(24),
                height: Some(20),
                nee: true,
                seed: Some(5),
                ..Default::default()
            },
        )
        .unwrap()
    };
    let alone: Vec<_> = [Method::PT, Method::SARSA]
        .map(|m| {
            Renderer::new(&ctx, &scene, settings(m))
                .unwrap()
                .run(&mut |_| {})
                .unwrap()
        })
        .into();
    let mut renders: Vec<_> = [Method::PT, Method::SARSA]
        .map(|m| {
            let mut r = Renderer::new(&ctx, &scene, settings(m)).unwrap();
            let run = r.start();
            (r, run)
        })
        .into();
    // A checkpoint after every pass: one pass a step.
    let every: Vec<u32> = (1..=6).collect();
    let control = Control {
        at_passes: &every,
        ..Default::default()
    };
    let outside = std::time::Duration::from_millis(60);
    let start = std::time::Instant::now();
    let mut steps = 0;
    while renders.iter().any(|(_, run)| !run.finished()) {
        for (r, run) in renders.iter_mut().filter(|(_, run)| !run.finished()) {
            r.step(run, &mut |_| {}, &control, &mut |_| {}).unwrap();
            steps += 1;
            // Time that is not this render's: another's batch, or a pause.
            std::thread::sleep(outside);
        }
    }
    let wall = start.elapsed().as_secs_f64();
    for ((mut r, run), a) in renders.into_iter().zip(&alone) {
        let b = r.finish(run, &control).unwrap();
        assert_eq!(a.image, b.image, "{}", a.stats.method);
        assert_eq!(b.stats.spp, 6);
        assert!(!b.stats.interrupted);
        assert_eq!(steps, 12);
        assert!(
            b.stats.wall_seconds < wall - outside.as_secs_f64() * steps as f64 / 2.0,
            "{}: its clock ({} s) counted time outside its steps ({steps} steps, {wall} s in all)",
            a.stats.method,
            b.stats.wall_seconds
        );
    }
    common::assert_no_validation_errors(&ctx);
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
    common::assert_same_expectation("cornell-pt-vs-nee", &plain, &nee);
    // And NEE must actually help: fewer zero-contribution paths.
    assert!(nee.stats.zero_contribution_fraction < plain.stats.zero_contribution_fraction);

    // Every pixel on its own, at a size where each gets enough light hits
    // for its mean to be close to normal.
    let tiny = |nee, seed| Overrides {
        spp: Some(if nee { 1024 } else { 8192 }),
        width: Some(12),
        height: Some(12),
        nee,
        seed: Some(seed),
        ..Default::default()
    };
    let plain = common::render_with(&ctx, &scene, tiny(false, 3));
    let nee = common::render_with(&ctx, &scene, tiny(true, 4));
    common::assert_same_expectation_binned("cornell-pt-vs-nee-per-pixel", &plain, &nee, 1);
}

/// `hide_emitters` (here on a TOML scene): the camera sees the ceiling
/// through the Cornell box's light, and every pixel whose rays meet no
/// emitter stays as it was, bit for bit (the same random numbers).
#[test]
fn hidden_emitters_show_what_lies_behind_them() {
    let ctx = common::gpu();
    let mut scene = common::scene("cornell-box");
    let o = Overrides {
        spp: Some(16),
        width: Some(32),
        height: Some(32),
        nee: true,
        seed: Some(1),
        ..Default::default()
    };
    let shown = common::render_with(&ctx, &scene, o.clone());
    scene.defaults.hide_emitters = true;
    let hidden = common::render_with(&ctx, &scene, o);
    let (mut same, mut dimmed) = (0, 0);
    for (a, b) in shown.image.pixels.iter().zip(&hidden.image.pixels) {
        if a == b {
            same += 1;
        } else {
            assert!(b[0] < a[0], "a pixel grew brighter: {a:?} to {b:?}");
            if a[0] > 2.0 && b[0] < 1.0 {
                dimmed += 1;
            }
        }
    }
    assert!(dimmed >= 4, "{dimmed} pixels of the light went dark");
    assert!(same > 900, "only {same} of 1024 pixels kept their value");
}

/// The trace kernels read the scene and the guides' tables through uniform
/// texel buffers or through storage buffers (`--reads`; the driver decides
/// by default): one image either way, bit for bit, for plain, learning,
/// frozen and neural kernels, diffuse and not.
#[test]
fn texel_and_storage_reads_give_the_same_image() {
    use qtrace::gpu::{ContextOptions, GpuContext, Reads};
    use qtrace::guide::{sarsa::Atomics, GuideSettings, SarsaSettings};
    use qtrace::render::Method;
    let open = |reads| {
        let ctx = GpuContext::new(&ContextOptions {
            device: std::env::var("QTRACE_DEVICE").ok(),
            validation: true,
            reads: Some(reads),
        })
        .unwrap_or_else(|e| panic!("GPU test needs a Vulkan device (lavapipe will do): {e}"));
        assert_eq!(ctx.info().reads, reads);
        ctx
    };
    let (texel, storage) = (open(Reads::Texel), open(Reads::Storage));
    if !texel.info().int64_atomics {
        eprintln!(
            "SKIPPED: device '{}' lacks 64-bit buffer atomics",
            texel.info().name
        );
        return;
    }
    // Fixed-point tallies, so that a guided image is one per seed; 20
    // passes, so that Sarsa's passes 17 and 19 run the kernel that learns
    // nothing, and fewer than 24, so that no race reads the clock.
    let sarsa = || {
        Some(GuideSettings::from(SarsaSettings {
            atomics: Atomics::Fixed,
            ..Default::default()
        }))
    };
    let cases = [
        ("cornell-box", Method::PT, false, None),
        ("glass-cornell", Method::PT, true, None),
        ("cornell-box", Method::SARSA, true, sarsa()),
        ("glossy-cornell", Method::SARSA, false, sarsa()),
        ("cornell-box", Method::NEURAL, true, None),
    ];
    for (name, method, nee, guide) in cases {
        let scene = common::scene(name);
        let o = Overrides {
            method: Some(method),
            spp: Some(20),
            width: Some(32),
            height: Some(32),
            nee,
            seed: Some(7),
            guide,
            ..Default::default()
        };
        let a = common::render_with(&texel, &scene, o.clone()).image;
        let b = common::render_with(&storage, &scene, o).image;
        assert!(
            a == b,
            "{name} {method:?} nee {nee}: the reads changed the image"
        );
    }
}
