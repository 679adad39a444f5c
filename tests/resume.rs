//! Renders stopped and resumed from their state go on as if they had never
//! stopped, for every method; states of other renders are refused.

mod common;

use qtrace::guide::{GuideSettings, NeuralSettings, SarsaSettings};
use qtrace::render::{Control, Method, Overrides, RenderSettings, Renderer};
use qtrace::RenderOutput;
use std::path::Path;

fn overrides(method: Method, spp: u32, seed: u32) -> Overrides {
    let guide = match method {
        Method::SARSA => Some(GuideSettings::from(SarsaSettings {
            volumes: Some(256),
            ..Default::default()
        })),
        Method::NEURAL => Some(GuideSettings::from(NeuralSettings {
            batch: Some(1024),
            ..Default::default()
        })),
        _ => None,
    };
    Overrides {
        method: Some(method),
        spp: Some(spp),
        seed: Some(seed),
        nee: true,
        width: Some(32),
        height: Some(32),
        guide,
        ..Default::default()
    }
}

/// Renders `spp` samples in two runs: half, its state saved, then a new
/// renderer resumed from that state.
fn stopped_and_resumed(
    scene: &str,
    method: Method,
    spp: u32,
    seed: u32,
    state: &Path,
) -> RenderOutput {
    let ctx = common::gpu();
    let scene = common::scene(scene);
    let control = Control {
        state: Some(state),
        ..Default::default()
    };
    let half = RenderSettings::resolve(&scene, &overrides(method, spp / 2, seed)).unwrap();
    let first = Renderer::new(&ctx, &scene, half)
        .unwrap()
        .run_controlled(&mut |_| {}, &control, &mut |_| {})
        .unwrap();
    assert_eq!(first.stats.spp, spp / 2);
    let all = RenderSettings::resolve(&scene, &overrides(method, spp, seed)).unwrap();
    let mut renderer = Renderer::new(&ctx, &scene, all).unwrap();
    assert_eq!(renderer.resume(state).unwrap(), spp / 2);
    let out = renderer
        .run_controlled(&mut |_| {}, &control, &mut |_| {})
        .unwrap();
    common::assert_no_validation_errors(&ctx);
    out
}

#[test]
fn resumed_renders_equal_renders_that_ran_through() {
    let ctx = common::gpu();
    // With several lights the state holds each volume's choice of light too.
    for (scene_name, method, spp) in [
        ("cornell-box", Method::PT, 256),
        ("cornell-box", Method::SARSA, 256),
        ("several-lights", Method::SARSA, 256),
        ("cornell-box", Method::NEURAL, 64),
    ] {
        let scene = common::scene(scene_name);
        let name = format!("resume-{scene_name}-{}", method.name());
        let dir = common::scratch(&name);
        let resumed = stopped_and_resumed(scene_name, method, spp, 1, &dir.join("state"));
        assert_eq!(resumed.stats.spp, spp);
        assert_eq!(resumed.stats.passes.len(), spp as usize);
        assert!(!resumed.stats.interrupted);
        // Against an independent render (another seed) of all the samples.
        let other = common::render_with(&ctx, &scene, overrides(method, spp, 2));
        common::assert_same_expectation(&name, &resumed, &other);
        if method == Method::NEURAL && ctx.info().timestamps {
            // The training steps the first run's first pass fitted to the
            // device hold on: passes 32 and 48 train.
            let fit = resumed
                .stats
                .guide_fit
                .clone()
                .expect("the first run's fit");
            let steps = resumed
                .stats
                .gpu_passes
                .iter()
                .find(|t| t.name == "mlp training")
                .map_or(0, |t| t.count);
            assert_eq!(steps, 2 * u64::from(fit.training_steps));
        }
        if method == Method::PT {
            // The same seed gives the same samples: the very same image.
            let through = common::render_with(&ctx, &scene, overrides(method, spp, 1));
            assert_eq!(resumed.image, through.image);
        }
    }
}

#[test]
fn a_state_of_another_render_is_refused() {
    let ctx = common::gpu();
    let scene = common::scene("cornell-box");
    let dir = common::scratch("resume-refused");
    let state = dir.join("state");
    stopped_and_resumed("cornell-box", Method::PT, 4, 1, &state);
    for (o, want) in [
        (overrides(Method::SARSA, 8, 1), "method"),
        (overrides(Method::PT, 8, 3), "seed"),
        (
            Overrides {
                width: Some(16),
                ..overrides(Method::PT, 8, 1)
            },
            "width",
        ),
    ] {
        let settings = RenderSettings::resolve(&scene, &o).unwrap();
        let mut renderer = Renderer::new(&ctx, &scene, settings).unwrap();
        let e = renderer.resume(&state).expect_err("refused").to_string();
        assert!(e.contains("another render") && e.contains(want), "{e}");
    }
    std::fs::write(&state, b"not a state").unwrap();
    let settings = RenderSettings::resolve(&scene, &overrides(Method::PT, 8, 1)).unwrap();
    let e = Renderer::new(&ctx, &scene, settings)
        .unwrap()
        .resume(&state)
        .expect_err("refused")
        .to_string();
    assert!(e.contains("not a qtrace render state"), "{e}");
}
