//! Shared test helpers: a validated GPU context and image statistics.
#![allow(dead_code)]

use qtrace::gpu::{ContextOptions, GpuContext};
use qtrace::image::Image;
use qtrace::render::{self, Overrides, RenderOutput, RenderSettings};
use qtrace::Scene;
use std::path::{Path, PathBuf};
use std::sync::Arc;

pub fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(path)
}

/// A context on the default device (or QTRACE_DEVICE) with validation on.
/// Without a Vulkan device the test fails with the reason: it never passes silently.
pub fn gpu() -> Arc<GpuContext> {
    let ctx = GpuContext::new(&ContextOptions {
        device: std::env::var("QTRACE_DEVICE").ok(),
        validation: true,
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
