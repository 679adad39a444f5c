//! Runs GLSL building blocks on given inputs, so tests can hold them against
//! CPU references (BVH traversal, hemisphere map).

use super::{pass_params, GpuScene, RenderError, RenderSettings};
use crate::gpu::{Buffer, ComputePipeline, DescriptorSet, GpuContext, Pass};
use crate::guide::SarsaGuide;
use crate::scene::Scene;
use crate::shaders::{self, spirv, PassParams};
use glam::{Vec3, Vec4};
use std::sync::Arc;

/// Dispatches `pipeline` once per item of `count` over `input` (bound at
/// B_PROBE_IN, with `bindings`) and returns its B_PROBE_OUT vec4s,
/// `outputs` per item.
fn launch(
    ctx: &Arc<GpuContext>,
    pipeline: &ComputePipeline,
    bindings: &[(u32, &Buffer)],
    mut params: PassParams,
    input: &[Vec4],
    (count, outputs): (usize, usize),
) -> Result<Vec<Vec4>, RenderError> {
    let input_buf = Buffer::gpu_only_with(ctx, "probe input", input)?;
    let output = Buffer::gpu_only(
        ctx,
        "probe output",
        (count * outputs * size_of::<Vec4>()) as u64,
    )?;
    let mut bindings = bindings.to_vec();
    bindings.extend([
        (shaders::B_PROBE_IN, &input_buf),
        (shaders::B_PROBE_OUT, &output),
    ]);
    let set = DescriptorSet::new(ctx, pipeline, &bindings)?;
    params.item_count = count as u32;
    ctx.submit(None, |rec| {
        rec.dispatch(Pass {
            name: pipeline.name(),
            pipeline,
            set: &set,
            push: bytemuck::bytes_of(&params),
            groups: [(count as u32).div_ceil(shaders::LINEAR_GROUP), 1, 1],
        })
    })?;
    let mut out: Vec<Vec4> = output.download()?;
    out.truncate(count * outputs);
    Ok(out)
}

/// Runs probe `mode` over `input`: the scene probe, or with a guide the
/// Sarsa probe, which also binds the guide.
fn run(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    guide: Option<&SarsaGuide>,
    mode: u32,
    input: &[Vec4],
    count: usize,
) -> Result<Vec<Vec4>, RenderError> {
    run_outputs(ctx, scene, guide, mode, input, (count, 1))
}

/// [`run`] with `outputs` vectors per item.
fn run_outputs(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    guide: Option<&SarsaGuide>,
    mode: u32,
    input: &[Vec4],
    (count, outputs): (usize, usize),
) -> Result<Vec<Vec4>, RenderError> {
    let gpu_scene = GpuScene::upload(ctx, scene)?;
    let mut bindings = gpu_scene.bindings().to_vec();
    let settings = RenderSettings::resolve(scene, &Default::default())?;
    let mut params = pass_params(scene, &settings);
    params.selector = mode;
    let push = size_of::<PassParams>() as u32;
    let pipeline = match guide {
        Some(g) => {
            bindings.extend(g.bindings());
            g.set_params(&mut params, true);
            let spirv = g.settings.pick(
                ctx.info(),
                [
                    spirv::SARSA_PROBE_FIXED,
                    spirv::SARSA_PROBE,
                    spirv::SARSA_PROBE_CAS,
                ],
            )?;
            ComputePipeline::new(ctx, "sarsa probe", spirv, push)?
        }
        None => ComputePipeline::new(ctx, "probe", spirv::PROBE, push)?,
    };
    launch(ctx, &pipeline, &bindings, params, input, (count, outputs))
}

/// What the GPU found along one ray: the closest hit (t, triangle), if any,
/// and whether the any-hit query saw something.
pub type RayResult = (Option<(f32, u32)>, bool);

/// GPU closest hit and any-hit flag for each (origin, direction).
pub fn trace_rays(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    rays: &[(Vec3, Vec3)],
) -> Result<Vec<RayResult>, RenderError> {
    let input: Vec<Vec4> = rays
        .iter()
        .flat_map(|(o, d)| [o.extend(0.0), d.extend(0.0)])
        .collect();
    let out = run(ctx, scene, None, shaders::PROBE_TRACE, &input, rays.len())?;
    Ok(out
        .iter()
        .map(|v| {
            let tri = v.y.to_bits();
            let closest = (tri != u32::MAX).then_some((v.x, tri));
            (closest, v.z != 0.0)
        })
        .collect())
}

#[derive(Clone, Copy, Debug)]
pub struct SurfacePoint {
    pub position: Vec3,
    pub triangle: u32,
    pub front: bool,
}

/// GPU nearest volume (facing the shaded side) for each surface point.
pub fn nearest_volumes(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    guide: &SarsaGuide,
    queries: &[SurfacePoint],
) -> Result<Vec<Option<u32>>, RenderError> {
    let input: Vec<Vec4> = queries
        .iter()
        .flat_map(|q| {
            let side = if q.front { 1.0 } else { 0.0 };
            [
                q.position.extend(0.0),
                Vec4::new(f32::from_bits(q.triangle), side, 0.0, 0.0),
            ]
        })
        .collect();
    let out = run(
        ctx,
        scene,
        Some(guide),
        shaders::PROBE_NEAREST_VOLUME,
        &input,
        queries.len(),
    )?;
    Ok(out
        .iter()
        .map(|v| Some(v.x.to_bits()).filter(|&i| i != shaders::NO_VOLUME))
        .collect())
}

/// A shading point as the probes read it: the material's four texels, then
/// The probes only tests and examples use: the hemisphere map, the guides'
/// samplers and updates, the BSDFs, textures and the sky against their CPU
/// twins, timed BVH walks. Built with the `probes` feature, which the
/// crate's own tests and examples turn on.
#[cfg(feature = "probes")]
mod checks;
#[cfg(feature = "probes")]
pub use checks::*;
