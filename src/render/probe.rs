//! Runs GLSL building blocks on given inputs, so tests can hold them against
//! CPU references (BVH traversal, hemisphere map).

use super::{pass_params, GpuScene, RenderError, RenderSettings};
use crate::gpu::{Buffer, ComputePipeline, DescriptorSet, GpuContext, Pass};
use crate::scene::Scene;
use crate::shaders::{self, spirv, PassParams};
use glam::{Vec2, Vec3, Vec4};
use std::sync::Arc;

fn run(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    mode: u32,
    input: &[Vec4],
    count: usize,
) -> Result<Vec<Vec4>, RenderError> {
    let gpu_scene = GpuScene::upload(ctx, scene)?;
    let input_buf = Buffer::gpu_only_with(ctx, "probe input", input)?;
    let output = Buffer::gpu_only(ctx, "probe output", (count * size_of::<Vec4>()) as u64)?;
    let pipeline =
        ComputePipeline::new(ctx, "probe", spirv::PROBE, size_of::<PassParams>() as u32)?;
    let mut bindings = gpu_scene.bindings().to_vec();
    bindings.extend([
        (shaders::B_PROBE_IN, &input_buf),
        (shaders::B_PROBE_OUT, &output),
    ]);
    let set = DescriptorSet::new(ctx, &pipeline, &bindings)?;
    let settings = RenderSettings::resolve(scene, &Default::default())?;
    let mut params = pass_params(scene, &settings);
    params.probe_mode = mode;
    params.item_count = count as u32;
    ctx.submit(None, |rec| {
        rec.dispatch(Pass {
            name: "probe",
            pipeline: &pipeline,
            set: &set,
            push: bytemuck::bytes_of(&params),
            groups: [(count as u32).div_ceil(shaders::LINEAR_GROUP), 1, 1],
        })
    })?;
    let mut out: Vec<Vec4> = output.download()?;
    out.truncate(count);
    Ok(out)
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
    let out = run(ctx, scene, shaders::PROBE_TRACE, &input, rays.len())?;
    Ok(out
        .iter()
        .map(|v| {
            let tri = v.y.to_bits();
            let closest = (tri != u32::MAX).then_some((v.x, tri));
            (closest, v.z != 0.0)
        })
        .collect())
}

/// GPU `square_to_hemisphere` and `hemisphere_sector` (a × b grid) for each point.
pub fn hemisphere(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    points: &[Vec2],
    a: u32,
    b: u32,
) -> Result<Vec<(Vec3, u32)>, RenderError> {
    let input: Vec<Vec4> = points
        .iter()
        .map(|p| Vec4::new(p.x, p.y, a as f32, b as f32))
        .collect();
    let out = run(ctx, scene, shaders::PROBE_HEMISPHERE, &input, points.len())?;
    Ok(out.iter().map(|v| (v.truncate(), v.w as u32)).collect())
}
