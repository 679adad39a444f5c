//! The probes only tests and examples use (the `probes` feature).

use super::{launch, run, run_outputs};
use crate::gpu::{Buffer, ComputePipeline, DescriptorSet, GpuContext, Pass};
use crate::guide::{DeviceGuide, NeuralGuide, SarsaGuide};
use crate::render::{pass_params, GpuScene, RenderError, RenderSettings};
use crate::scene::Scene;
use crate::shaders::{self, spirv, PassParams};
use glam::{Vec2, Vec3, Vec4};
use std::sync::Arc;

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
    let out = run(
        ctx,
        scene,
        None,
        shaders::PROBE_HEMISPHERE,
        &input,
        points.len(),
    )?;
    Ok(out.iter().map(|v| (v.truncate(), v.w as u32)).collect())
}

/// A point shading one side of a triangle, where the renderer looks a volume up.
/// (wo, 1 on the front side or 0).
fn shading_texels(material: &crate::scene::Material, wo: Vec3, front: bool) -> [Vec4; 5] {
    material_texels(material.gpu(), wo, front)
}

fn material_texels(m: shaders::Material, wo: Vec3, front: bool) -> [Vec4; 5] {
    [
        Vec4::from(m.color),
        Vec4::from(m.emission),
        Vec4::from(m.eta),
        Vec4::from(m.k),
        wo.extend(if front { 1.0 } else { 0.0 }),
    ]
}

/// Directions the GPU guide sampler draws for volume `volume` from the given
/// uniform triples, at a vertex of `material` (front side) seen from `wo`,
/// with `back` the volume on the surface's far side (NO_VOLUME: none), and
/// for each the pdf it reports and the pdf NEE's MIS finds there.
pub fn guide_samples(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    guide: &SarsaGuide,
    (volume, back): (u32, u32),
    (material, wo): (&crate::scene::Material, Vec3),
    uniforms: &[Vec3],
) -> Result<Vec<(Vec3, f32, f32)>, RenderError> {
    let input: Vec<Vec4> = shading_texels(material, wo, true)
        .into_iter()
        .chain(std::iter::once(Vec4::new(
            f32::from_bits(back),
            0.0,
            0.0,
            0.0,
        )))
        .chain(
            uniforms
                .iter()
                .map(|u| Vec4::new(f32::from_bits(volume), u.x, u.y, u.z)),
        )
        .collect();
    let out = run_outputs(
        ctx,
        scene,
        Some(guide),
        shaders::PROBE_GUIDE_SAMPLE,
        &input,
        (uniforms.len(), 2),
    )?;
    Ok(out
        .chunks(2)
        .map(|v| (v[0].truncate(), v[0].w, v[1].x))
        .collect())
}

/// The lights NEE picks at volume `volume` (NO_VOLUME: where there is
/// none) for the given uniforms, each with its probability as drawn and as
/// looked up for MIS.
pub fn light_choices(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    guide: &SarsaGuide,
    volume: u32,
    uniforms: &[f32],
) -> Result<Vec<(u32, f32, f32)>, RenderError> {
    let input: Vec<Vec4> = uniforms
        .iter()
        .map(|&u| Vec4::new(f32::from_bits(volume), u, 0.0, 0.0))
        .collect();
    let out = run(
        ctx,
        scene,
        Some(guide),
        shaders::PROBE_LIGHT_CHOICE,
        &input,
        uniforms.len(),
    )?;
    Ok(out.iter().map(|v| (v.x.to_bits(), v.y, v.z)).collect())
}

/// Directions the GPU Neural-Q sampler draws at the state (point, normal)
/// from the given uniform triples, with the pdf it reports for each.
pub fn neural_samples(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    guide: &NeuralGuide,
    point: Vec3,
    normal: Vec3,
    uniforms: &[Vec3],
) -> Result<Vec<(Vec3, f32)>, RenderError> {
    let input: Vec<Vec4> = [point, normal]
        .iter()
        .chain(uniforms)
        .map(|v| v.extend(0.0))
        .collect();
    let pipeline = ComputePipeline::specialized(
        ctx,
        "neural probe",
        spirv::NEURAL_PROBE,
        size_of::<PassParams>() as u32,
        &guide.network.shape.constants(),
    )?;
    let settings = RenderSettings::resolve(scene, &Default::default())?;
    let mut params = pass_params(scene, &settings);
    guide.set_params(&mut params, false);
    let out = launch(
        ctx,
        &pipeline,
        &guide.bindings(),
        params,
        &input,
        (uniforms.len(), 1),
    )?;
    Ok(out.iter().map(|v| (v.truncate(), v.w)).collect())
}

/// One transition for [`sarsa_updates`]: the bounce left volume `volume` through
/// `sector` and landed on a surface of albedo `albedo` served by `next_volume`,
/// or on an emitter (`emitted` = its radiance towards the bounce).
#[derive(Clone, Copy, Debug)]
pub struct Transition {
    pub volume: u32,
    pub sector: u32,
    pub next_volume: u32,
    pub albedo: f32,
    pub emitted: Option<f32>,
    /// With NEE: the part of `emitted` that NEE carries.
    pub nee_share: f32,
}

/// Records `transitions` with the GPU update code, then folds them into Q.
/// Returns the target the GPU computed for each.
pub fn sarsa_updates(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    guide: &SarsaGuide,
    transitions: &[Transition],
) -> Result<Vec<f32>, RenderError> {
    let input: Vec<Vec4> = transitions
        .iter()
        .flat_map(|t| {
            [
                Vec4::new(
                    f32::from_bits(t.volume),
                    f32::from_bits(t.sector),
                    f32::from_bits(t.next_volume),
                    t.emitted.map_or(t.albedo, |e| -e),
                ),
                Vec4::new(t.nee_share, 0.0, 0.0, 0.0),
            ]
        })
        .collect();
    let out = run(
        ctx,
        scene,
        Some(guide),
        shaders::PROBE_SARSA_UPDATE,
        &input,
        transitions.len(),
    )?;
    guide.fold(ctx)?;
    Ok(out.iter().map(|v| v.x).collect())
}

/// Records NEE tries (volume, light, what it brought) as the trace kernel
/// does, then folds them into the guide's running means.
pub fn light_tries(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    guide: &SarsaGuide,
    tries: &[(u32, u32, f32)],
) -> Result<(), RenderError> {
    let input: Vec<Vec4> = tries
        .iter()
        .map(|&(v, l, brought)| Vec4::new(f32::from_bits(v), f32::from_bits(l), brought, 0.0))
        .collect();
    run(
        ctx,
        scene,
        Some(guide),
        shaders::PROBE_LIGHT_TRY,
        &input,
        tries.len(),
    )?;
    guide.fold(ctx)?;
    Ok(())
}

/// What the GPU BSDF does with one query: the direction it samples, its
/// pdf, f·cos there, and the reflected estimate of a unit irradiance; for a
/// delta lobe, pdf 0 and `eval` its weight f·cos/pdf.
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample {
    pub wi: Vec3,
    pub pdf: f32,
    pub eval: Vec3,
    pub reflected: f32,
    /// `bsdf_sample_delta`'s weight and `bsdf_delta_share` (a plastic's).
    pub delta_weight: Vec3,
    pub delta_share: f32,
}

/// One query of the GPU BSDF: a material seen from its front side or not,
/// wo, and three uniform numbers (two for sampling, one for delta lobes).
#[derive(Clone, Debug)]
pub struct BsdfQuery {
    pub material: crate::scene::Material,
    pub front: bool,
    pub wo: Vec3,
    pub u: Vec3,
    /// The angle of the surface's tangent in the local frame (from x toward
    /// y), which an anisotropic roughness follows.
    pub tangent: f32,
}

/// GPU `bsdf_sample` (or `bsdf_sample_delta`), `bsdf_pdf`, `bsdf_eval` and
/// `bsdf_reflect` for each query.
pub fn bsdf_samples(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    sampling: crate::render::Sampling,
    queries: &[BsdfQuery],
) -> Result<Vec<BsdfSample>, RenderError> {
    let gpu_scene = GpuScene::upload(ctx, scene)?;
    let settings = RenderSettings::resolve(
        scene,
        &crate::render::Overrides {
            sampling: Some(sampling),
            ..Default::default()
        },
    )?;
    let mut params = pass_params(scene, &settings);
    params.selector = shaders::PROBE_BSDF;
    let pipeline =
        ComputePipeline::new(ctx, "probe", spirv::PROBE, size_of::<PassParams>() as u32)?;
    // The queries' materials take the scene's place, with the tables
    // rough plastics read.
    let materials: Vec<_> = queries.iter().map(|q| q.material.clone()).collect();
    let materials = crate::scene::gpu_materials(&materials);
    let material_buffer = Buffer::gpu_only_with(ctx, "probe materials", &materials)?;
    let mut bindings = gpu_scene.bindings().to_vec();
    bindings.retain(|(b, _)| *b != shaders::B_MATERIALS);
    bindings.push((shaders::B_MATERIALS, &material_buffer));
    let input: Vec<Vec4> = queries
        .iter()
        .zip(&materials)
        .flat_map(|(q, m)| {
            let [color, emission, eta, k, side] = material_texels(*m, q.wo, q.front);
            [color, emission, eta, k, side, q.u.extend(q.tangent)]
        })
        .collect();
    let n = queries.len();
    let out = launch(ctx, &pipeline, &bindings, params, &input, (n, 3))?;
    Ok((0..n)
        .map(|i| BsdfSample {
            wi: out[i].truncate(),
            pdf: out[i].w,
            eval: out[n + i].truncate(),
            reflected: out[n + i].w,
            delta_weight: out[2 * n + i].truncate(),
            delta_share: out[2 * n + i].w,
        })
        .collect())
}

/// A material's BSDF at texture coordinates `uv` on the front side or the
/// back: the GPU's `bsdf_textured`.
#[derive(Clone, Debug)]
pub struct TextureQuery {
    pub material: crate::scene::Material,
    pub front: bool,
    pub uv: glam::Vec2,
}

/// What the GPU makes of each query's BSDF, textured with `textures`.
#[derive(Clone, Copy, Debug)]
pub struct TextureLookup {
    pub color: Vec3,
    /// Its second colour (`Bsdf.ior_eta`; a principled lobe's metallic,
    /// specular tint and sheen).
    pub second: Vec3,
    pub alpha: f32,
    /// Its alpha across its tangent.
    pub alpha_v: f32,
    /// `Bsdf.ior_k` (a principled lobe's sheen tint, flatness, clearcoat).
    pub k: Vec3,
    /// A principled lobe's clearcoat gloss, spec_trans and anisotropic.
    pub extra: Vec3,
}

/// [`TextureLookup`] of each query's BSDF, textured on the GPU with `textures`.
pub fn texture_lookups(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    textures: &[crate::scene::texture::Texture],
    queries: &[TextureQuery],
) -> Result<Vec<TextureLookup>, RenderError> {
    let gpu_scene = GpuScene::upload(ctx, scene)?;
    let settings = RenderSettings::resolve(scene, &Default::default())?;
    let mut params = pass_params(scene, &settings);
    params.selector = shaders::PROBE_TEXTURE;
    let pipeline =
        ComputePipeline::new(ctx, "probe", spirv::PROBE, size_of::<PassParams>() as u32)?;
    let materials: Vec<_> = queries.iter().map(|q| q.material.clone()).collect();
    let materials = crate::scene::gpu_materials(&materials);
    let material_buffer = Buffer::gpu_only_with(ctx, "probe materials", &materials)?;
    let packed = crate::scene::texture::pack(textures, u64::MAX)
        .map_err(|e| RenderError::Textures(scene.path.clone(), e))?;
    let texture_buffer = Buffer::gpu_only_with(ctx, "probe textures", &packed)?;
    let mut bindings = gpu_scene.bindings().to_vec();
    bindings.retain(|(b, _)| *b != shaders::B_MATERIALS && *b != shaders::B_TEXTURES);
    bindings.push((shaders::B_MATERIALS, &material_buffer));
    bindings.push((shaders::B_TEXTURES, &texture_buffer));
    let input: Vec<Vec4> = queries
        .iter()
        .zip(&materials)
        .flat_map(|(q, m)| {
            let [color, emission, eta, k, _] = material_texels(*m, Vec3::Z, q.front);
            let at = Vec4::new(q.uv.x, q.uv.y, if q.front { 1.0 } else { 0.0 }, 0.0);
            [color, emission, eta, k, at]
        })
        .collect();
    let n = queries.len();
    let out = launch(ctx, &pipeline, &bindings, params, &input, (n, 4))?;
    Ok((0..n)
        .map(|i| TextureLookup {
            color: out[i].truncate(),
            second: out[n + i].truncate(),
            alpha: out[i].w,
            alpha_v: out[n + i].w,
            k: out[2 * n + i].truncate(),
            extra: Vec3::new(out[3 * n + i].x, out[3 * n + i].y, out[n + i].w),
        })
        .collect())
}

/// What the GPU's environment gives for each (direction, four uniform
/// numbers): the radiance and density in the direction; the direction the
/// numbers draw and its density; the radiance and density looked up there.
pub type EnvironmentProbe = ((Vec3, f32), (Vec3, f32), (Vec3, f32));

/// `environment_eval`, `environment_pdf` and `environment_sample` of the
/// scene's environment on the GPU, its texels a word each or, `dense`,
/// packed as a sky too large for one buffer otherwise is.
pub fn environment_lookups(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    queries: &[(Vec3, Vec4)],
    dense: bool,
) -> Result<Vec<EnvironmentProbe>, RenderError> {
    let input: Vec<Vec4> = queries
        .iter()
        .flat_map(|(d, u)| [d.extend(0.0), *u])
        .collect();
    let n = queries.len();
    let env = scene.environment.as_ref().expect("a scene with a sky");
    let gpu_scene = GpuScene::upload(ctx, scene)?;
    let sky = Buffer::gpu_only_with(ctx, "probe sky", &env.pack(dense))?;
    let mut bindings = gpu_scene.bindings().to_vec();
    bindings.retain(|(b, _)| *b != shaders::B_ENVIRONMENT);
    bindings.push((shaders::B_ENVIRONMENT, &sky));
    let settings = RenderSettings::resolve(scene, &Default::default())?;
    let mut params = pass_params(scene, &settings);
    params.selector = shaders::PROBE_ENVIRONMENT;
    let mut constants = vec![0; shaders::CONSTANT_ENVIRONMENT as usize + 1];
    constants[shaders::CONSTANT_ENVIRONMENT as usize] = env.layout(dense);
    let push = size_of::<PassParams>() as u32;
    let pipeline = ComputePipeline::specialized(ctx, "probe", spirv::PROBE, push, &constants)?;
    let out = launch(ctx, &pipeline, &bindings, params, &input, (n, 3))?;
    let split = |v: Vec4| (v.truncate(), v.w);
    Ok((0..n)
        .map(|i| (split(out[i]), split(out[n + i]), split(out[2 * n + i])))
        .collect())
}

/// One ray for [`walk_timed`]: origin, direction, tmax, any hit.
pub type WalkRay = (Vec3, Vec3, f32, bool);

/// Walks `rays` through the BVH with the walk-only kernel
/// (glsl/walk_bench.comp), `per_lane` rays per invocation, a lane starting
/// its next ray after its SIMD group's longest walk of the round (`refill`
/// 0), as soon as its own walk ends (1), or once half its group waits (2).
/// Returns the hits (t, triangle; `u32::MAX` none) and the fastest of
/// `repeats` runs' seconds, after one run that compiles the kernel. A
/// benchmark.
pub fn walk_timed(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    rays: &[WalkRay],
    per_lane: u32,
    refill: u32,
    repeats: u32,
) -> Result<(Vec<(f32, u32)>, f64), RenderError> {
    let gpu_scene = GpuScene::upload(ctx, scene)?;
    let settings = RenderSettings::resolve(scene, &Default::default())?;
    let mut params = pass_params(scene, &settings);
    params.item_count = rays.len() as u32;
    params.selector = per_lane;
    let spirv = [
        spirv::WALK_BENCH,
        spirv::WALK_BENCH_REFILL,
        spirv::WALK_BENCH_REFILL_HALF,
    ][refill as usize];
    let pipeline = ComputePipeline::new(ctx, "walk", spirv, size_of::<PassParams>() as u32)?;
    let input: Vec<Vec4> = rays
        .iter()
        .flat_map(|&(o, d, tmax, any)| [o.extend(tmax), d.extend(if any { 1.0 } else { 0.0 })])
        .collect();
    let input_buf = Buffer::gpu_only_with(ctx, "walk rays", &input)?;
    let output = Buffer::gpu_only(ctx, "walk hits", (rays.len() * size_of::<Vec4>()) as u64)?;
    let mut bindings = gpu_scene.bindings().to_vec();
    bindings.extend([
        (shaders::B_PROBE_IN, &input_buf),
        (shaders::B_PROBE_OUT, &output),
    ]);
    let set = DescriptorSet::new(ctx, &pipeline, &bindings)?;
    let lanes = (rays.len() as u32).div_ceil(per_lane.max(1));
    let mut best = f64::INFINITY;
    for run in 0..=repeats {
        let start = std::time::Instant::now();
        ctx.submit(None, |rec| {
            rec.dispatch(Pass {
                name: "walk",
                pipeline: &pipeline,
                set: &set,
                push: bytemuck::bytes_of(&params),
                groups: [lanes.div_ceil(shaders::LINEAR_GROUP), 1, 1],
            })
        })?;
        if run > 0 {
            best = best.min(start.elapsed().as_secs_f64());
        }
    }
    let out: Vec<Vec4> = output.download()?;
    Ok((
        out.iter()
            .take(rays.len())
            .map(|v| (v.x, v.y.to_bits()))
            .collect(),
        best,
    ))
}
