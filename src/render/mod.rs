//! The renderer: uploads a scene, runs sample passes (trace → accumulate),
//! reads back the image and the statistics.

pub mod probe;
pub mod race;
pub mod settings;
pub mod state;
pub mod stats;

pub use race::RaceRecord;
pub use settings::{Budget, Method, Overrides, RenderSettings, Sampling, SettingsError};
pub use stats::{PassRecord, RenderStats};

use crate::gpu::{self, Buffer, ComputePipeline, DescriptorSet, GpuContext, Pass, Profiler};
use crate::guide::Guide;
use crate::image::Image;
use crate::scene::{PixelFilter, Scene};
use crate::shaders::{self, spirv, Accum, PassParams, PassStats, PathSample};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(transparent)]
    Gpu(#[from] gpu::Error),
    #[error(transparent)]
    Settings(#[from] SettingsError),
    #[error(transparent)]
    Write(#[from] crate::image::ImageError),
    #[error("{0}: {1}")]
    Textures(std::path::PathBuf, crate::scene::texture::TextureTooLarge),
    #[error("{path}: {message}")]
    Sky {
        path: std::path::PathBuf,
        message: String,
    },
}

/// The scene's buffers on the device.
pub struct GpuScene {
    pub nodes: Buffer,
    pub triangles: Buffer,
    pub materials: Buffer,
    pub lights: Buffer,
    /// Shading normals; one unused texel where the scene has none.
    pub normals: Buffer,
    /// Point, spot and directional lights; one unused where none.
    pub delta_lights: Buffer,
    /// Texture coordinates and textures; one unused texel each where no
    /// material is textured.
    pub uvs: Buffer,
    pub textures: Buffer,
    /// Mesh attributes at the triangles' corners; one unused texel where
    /// no texture reads one.
    pub attributes: Buffer,
    /// The environment; one unused texel where there is none.
    pub environment: Buffer,
    /// How its texels lie (SKY_*: the kernels' CONSTANT_ENVIRONMENT).
    pub sky: u32,
}

impl GpuScene {
    pub fn upload(ctx: &Arc<GpuContext>, scene: &Scene) -> Result<Self, RenderError> {
        let materials = crate::scene::gpu_materials(&scene.materials);
        let info = ctx.info();
        // The most one buffer may hold here, read as storage or as texels.
        let limit = info
            .max_storage_buffer_range
            .min(16 * info.max_texel_buffer_elements);
        // Buffers a scene may lack are bound all the same: one unused texel.
        let unused = |name: &str| Buffer::gpu_only_with(ctx, name, &[[0u32; 4]]);
        let (uvs, textures) = if scene.material_features() & crate::shaders::FEATURE_TEXTURES != 0 {
            let error = |e| RenderError::Textures(scene.path.clone(), e);
            let fitted = crate::scene::texture::fit(&scene.textures, limit).map_err(error)?;
            let textures =
                crate::scene::texture::pack(fitted.as_deref().unwrap_or(&scene.textures), limit)
                    .map_err(error)?;
            let uvs: Vec<[[f32; 2]; 4]> = scene
                .uvs
                .iter()
                .map(|[a, b, c]| [a.to_array(), b.to_array(), c.to_array(), [0.0; 2]])
                .collect();
            (
                Buffer::gpu_only_with(ctx, "texture coordinates", &uvs)?,
                Buffer::gpu_only_with(ctx, "textures", &textures)?,
            )
        } else {
            (unused("texture coordinates")?, unused("textures")?)
        };
        let attributes = if scene.attributes.is_empty() {
            unused("mesh attributes")?
        } else {
            // Per triangle, each attribute's three corners.
            let texels: Vec<[f32; 4]> = (0..scene.triangles.len())
                .flat_map(|i| scene.attributes.iter().flat_map(move |(_, v)| v[i]))
                .map(|c| c.extend(0.0).to_array())
                .collect();
            let bytes = 16 * texels.len() as u64;
            if bytes > limit {
                return Err(RenderError::Textures(
                    scene.path.clone(),
                    crate::scene::texture::TextureTooLarge {
                        name: "mesh attributes".into(),
                        bytes,
                        limit,
                    },
                ));
            }
            Buffer::gpu_only_with(ctx, "mesh attributes", &texels)?
        };
        let (environment, sky) = match &scene.environment {
            Some(e) => {
                // A sky too large for one buffer even packed tight is halved
                // until it fits, with a warning.
                let original = e;
                let mut fitted = std::borrow::Cow::Borrowed(e);
                while 16 * fitted.words(true) as u64 > limit && fitted.width > 1 {
                    fitted = std::borrow::Cow::Owned(fitted.halved());
                }
                let e = fitted.as_ref();
                if e.width != original.width {
                    log::warn!(
                        "the sky '{}' ({}x{}) halved to {}x{}: it fits the {} MiB one device buffer may hold here no other way",
                        e.name,
                        original.width,
                        original.height,
                        e.width,
                        e.height,
                        limit >> 20
                    );
                }
                // Texels a word each where they fit, else packed tighter.
                let dense = 16 * e.words(false) as u64 > limit;
                let bytes = 16 * e.words(dense) as u64;
                if bytes > limit {
                    return Err(RenderError::Sky {
                        path: scene.path.clone(),
                        message: format!(
                            "the sky '{}' ({}x{}) needs {} MiB of device memory, over the {} MiB one buffer may hold here (12 bytes a texel)",
                            e.name,
                            e.width,
                            e.height,
                            bytes.div_ceil(1 << 20),
                            limit >> 20
                        ),
                    });
                }
                (
                    Buffer::gpu_only_with(ctx, "environment", &e.pack(dense))?,
                    e.layout(dense),
                )
            }
            None => (unused("environment")?, shaders::SKY_NONE),
        };
        Ok(Self {
            environment,
            sky,
            uvs,
            textures,
            attributes,
            // The largest table: a CPU device reads the scene's own copy.
            nodes: match Buffer::import_host(ctx, "bvh nodes", &scene.nodes, scene.nodes.clone())? {
                Some(imported) => imported,
                None => Buffer::gpu_only_with(ctx, "bvh nodes", &scene.nodes)?,
            },
            triangles: Buffer::gpu_only_with(ctx, "triangles", &scene.triangles)?,
            materials: Buffer::gpu_only_with(ctx, "materials", &materials)?,
            lights: {
                // NEE's list, then the lights the guides may pick among
                // and their members (shaders::LightGroup).
                let (groups, members) = scene.light_groups();
                let texels: Vec<[u32; 4]> = scene
                    .nee_entries()
                    .map(|l| bytemuck::cast(*l))
                    .chain(groups.iter().map(|g| bytemuck::cast(*g)))
                    .chain(members.iter().map(|m| bytemuck::cast(*m)))
                    .collect();
                Buffer::gpu_only_with(ctx, "lights", &texels)?
            },
            delta_lights: if scene.delta_lights.is_empty() {
                Buffer::gpu_only_with(ctx, "delta lights", &[shaders::DeltaLight::default()])?
            } else {
                Buffer::gpu_only_with(ctx, "delta lights", &scene.delta_lights)?
            },
            normals: if scene.normals.is_empty() {
                unused("shading normals")?
            } else {
                Buffer::gpu_only_with(ctx, "shading normals", &scene.normals)?
            },
        })
    }

    /// Bindings every kernel that traces rays uses.
    pub fn bindings(&self) -> [(u32, &Buffer); 10] {
        [
            (shaders::B_ENVIRONMENT, &self.environment),
            (shaders::B_ATTRIBUTES, &self.attributes),
            (shaders::B_UVS, &self.uvs),
            (shaders::B_TEXTURES, &self.textures),
            (shaders::B_NODES, &self.nodes),
            (shaders::B_TRIANGLES, &self.triangles),
            (shaders::B_MATERIALS, &self.materials),
            (shaders::B_LIGHTS, &self.lights),
            (shaders::B_NORMALS, &self.normals),
            (shaders::B_DELTA_LIGHTS, &self.delta_lights),
        ]
    }
}

/// Push constants describing the camera and scene for every pass of a render.
pub fn pass_params(scene: &Scene, s: &RenderSettings) -> PassParams {
    let c = &scene.camera;
    let (tx, ty) = c.tan_half_fov(s.width, s.height);
    let filter_size = match scene.filter {
        PixelFilter::Box => 0.0,
        PixelFilter::Tent { radius } => radius,
        PixelFilter::Gaussian { stddev } => stddev,
        PixelFilter::Cubic { .. } => 2.0,
        PixelFilter::Lanczos { lobes } => lobes as f32,
    };
    let mut flags = 0;
    if s.nee {
        flags |= shaders::FLAG_NEE;
    }
    if s.sampling == Sampling::Uniform {
        flags |= shaders::FLAG_UNIFORM;
    }
    if scene.defaults.sample_border {
        flags |= shaders::FLAG_SAMPLE_BORDER;
    }
    PassParams {
        cam_pos: c.origin().extend(scene.ray_offset()).into(),
        cam_right: (c.right * tx).extend(c.aperture_radius).into(),
        cam_up: (c.up * ty).extend(c.focus_distance).into(),
        cam_forward: c.centre_ray(tx, ty).extend(filter_size).into(),
        environment: {
            let [b, c, bound] = match scene.filter {
                PixelFilter::Cubic { b, c } => [b, c, PixelFilter::cubic_bound(b, c)],
                _ => [0.0, 0.0, 1.0],
            };
            [scene.environment_pick(), b, c, bound]
        },
        width: s.width,
        height: s.height,
        pass_index: 0,
        seed: s.seed,
        max_depth: s.max_depth,
        flags,
        light_count: (scene.lights.len() + scene.delta_entries.len()) as u32,
        ..Default::default()
    }
}

/// Where a render stands, for progress bars.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    pub passes_done: u32,
    /// Known for a sample budget; `None` for a time budget.
    pub passes_total: Option<u32>,
    pub elapsed: f64,
    pub budget_seconds: Option<f64>,
    pub rays_per_second: f64,
}

/// The image part-way through a render.
pub struct Checkpoint {
    pub spp: u32,
    /// Render time so far, read-backs for checkpoints excluded.
    pub seconds: f64,
    pub image: Image,
    /// Over all passes so far.
    pub zero_contribution_fraction: f64,
    /// The statistics so far, as the finished render would report them.
    pub stats: RenderStats,
}

/// The finished render.
pub struct RenderOutput {
    /// Mean of the path estimates per pixel.
    pub image: Image,
    /// Per-pixel, per-channel sample variance of one path's estimate.
    pub variance: Image,
    pub stats: RenderStats,
}

/// A render in progress: pipelines, buffers and descriptor sets for one scene
/// and one set of settings.
pub struct Renderer {
    ctx: Arc<GpuContext>,
    settings: RenderSettings,
    params: PassParams,
    scene_name: String,
    _scene: GpuScene,
    trace: ComputePipeline,
    accumulate: ComputePipeline,
    trace_set: DescriptorSet,
    /// The guide's trace kernel for passes that learn nothing, if it has one.
    frozen: Option<(ComputePipeline, DescriptorSet)>,
    /// Plain path tracing's kernel, once a guide has stood back (see
    /// `Common::stand_back`).
    plain: Option<(ComputePipeline, DescriptorSet)>,
    /// The pass from which the guide stands back, if it does.
    stood_back: Option<u32>,
    /// The race in progress, if one is (see [`race`]).
    race: Option<race::Race>,
    /// The guide's ordinary passes since the last stand-back check.
    window: race::Window,
    /// The trace kernels' specialisation constants.
    constants: Vec<u32>,
    accumulate_set: DescriptorSet,
    /// The accumulate kernel of a race's passes, where the guide may race.
    race_accumulate: Option<(ComputePipeline, DescriptorSet)>,
    accum: Buffer,
    /// The accumulation when the race in progress began.
    race_ref: Buffer,
    /// Device-local pass stats (STATS_COPIES copies of MAX_BATCH slots):
    /// a GPU's atomics on host-visible memory cross the bus one by one.
    stats: Buffer,
    /// Where each submit copies `stats` for the host to sum.
    stats_readback: Buffer,
    /// Trace dispatches' work counters, zeroed at each submit.
    work: Buffer,
    _samples: Buffer,
    /// Most sample passes one trace dispatch may take (see `passes`).
    samples_per_dispatch: u32,
    trace_dispatches: u32,
    profiler: Profiler,
    guide: Option<Guide>,
    /// What the render holds and must match to resume (see [`state`]).
    identity: state::Identity,
    /// The tally a resumed render starts from.
    resumed: Option<Tally>,
}

/// SPIR-V of the trace kernel for the settings on this device.
fn trace_variant(ctx: &GpuContext, settings: &RenderSettings) -> gpu::Result<&'static [u8]> {
    match &settings.guide {
        Some(g) => Ok(spirv::for_reads(
            g.trace_spirv(ctx.info(), settings.nee)?,
            ctx.info().reads,
        )),
        None => Ok(plain_variant(ctx, settings)),
    }
}

/// SPIR-V of plain path tracing's kernel on this device.
fn plain_variant(ctx: &GpuContext, settings: &RenderSettings) -> &'static [u8] {
    let kernel = if settings.nee {
        spirv::TRACE_PT_NEE
    } else {
        spirv::TRACE_PT
    };
    spirv::for_reads(kernel, ctx.info().reads)
}

// A submit's trace dispatches (at most one per pass) each have a work counter,
// whose number shares the selector with a samples slot (glsl/shared.h).
const _: () = assert!(shaders::MAX_BATCH < 1 << shaders::WORK_SLOT_SHIFT);
const _: () = assert!(shaders::MAX_CLAIMS >= shaders::MAX_BATCH);

/// Most sample passes one trace dispatch takes: as many as a submit holds
/// (MAX_BATCH), as the samples buffer can hold (one path sample per pixel
/// each), and as keep a path's bounce steps under the kernel's step cap.
fn samples_per_dispatch(settings: &RenderSettings, pixels: u64, device: &gpu::DeviceInfo) -> u32 {
    let per_sample = pixels * size_of::<PathSample>() as u64;
    let by_memory = (device.max_storage_buffer_range / per_sample.max(1)).max(1);
    let by_steps = (shaders::MAX_TRACE_STEPS / (settings.max_depth + 2)).max(1);
    (shaders::MAX_BATCH as u64)
        .min(by_memory)
        .min(by_steps as u64) as u32
}

/// Workgroups of a trace dispatch of `samples` sample passes over an image
/// of `tiles` workgroups. Lanes claim their paths from the dispatch's work
/// counter (glsl/trace.comp), so a dispatch needs only enough lanes to take
/// every item. On a GPU it covers the image, to fill the device. On a CPU
/// device (lavapipe) every workgroup past those that find work is a launch
/// that claims nothing, and a dispatch of one sample per pixel (a pass that
/// learns, a race's lap) ran such launches for most of its workgroups, so
/// there it holds four times the lanes its items need, each lane sure to
/// take as many paths as the step cap leaves room for (see `room` in the
/// kernel: a path takes at most `max_depth + 1` steps), up to MAX_CLAIMS.
fn trace_groups(tiles: [u32; 3], samples: u32, pixels: u64, max_depth: u32, cpu: bool) -> [u32; 3] {
    if !cpu {
        return tiles;
    }
    let all = tiles[0] as u64 * tiles[1] as u64;
    let sure = (shaders::MAX_CLAIMS as u64)
        .min((shaders::MAX_TRACE_STEPS as u64 - 1) / (max_depth as u64 + 2))
        .max(1);
    let lanes = (shaders::TILE_X * shaders::TILE_Y) as u64;
    let needed = (4 * samples as u64 * pixels).div_ceil(lanes * sure);
    if needed >= all {
        tiles
    } else {
        // Whole rows of the image's tiles, within its workgroup counts.
        [tiles[0], needed.div_ceil(tiles[0] as u64).max(1) as u32, 1]
    }
}

/// What every trace kernel binds besides a guide's buffers: the scene, the
/// path samples, the accumulation, the pass stats and the work counters.
fn own_bindings<'a>(
    scene: &'a GpuScene,
    samples: &'a Buffer,
    accum: &'a Buffer,
    stats: &'a Buffer,
    work: &'a Buffer,
) -> Vec<(u32, &'a Buffer)> {
    let mut bindings = scene.bindings().to_vec();
    bindings.extend([
        (shaders::B_SAMPLES, samples),
        (shaders::B_ACCUM, accum),
        (shaders::B_STATS, stats),
        (shaders::B_WORK, work),
    ]);
    bindings
}

/// A pipeline of `spirv` under specialisation `constants` and its
/// descriptor set, from `bindings`.
fn pipeline_with_set(
    ctx: &Arc<GpuContext>,
    name: &str,
    spirv: &[u8],
    constants: &[u32],
    bindings: &[(u32, &Buffer)],
) -> gpu::Result<(ComputePipeline, DescriptorSet)> {
    let push = size_of::<PassParams>() as u32;
    let pipeline = ComputePipeline::specialized(ctx, name, spirv, push, constants)?;
    let set = DescriptorSet::new(ctx, &pipeline, bindings)?;
    Ok((pipeline, set))
}

fn groups(width: u32, height: u32) -> [u32; 3] {
    [
        width.div_ceil(shaders::TILE_X),
        height.div_ceil(shaders::TILE_Y),
        1,
    ]
}

impl Renderer {
    pub fn new(
        ctx: &Arc<GpuContext>,
        scene: &Scene,
        settings: RenderSettings,
    ) -> Result<Self, RenderError> {
        // The accumulate pass totals its stats per subgroup, in workgroup
        // memory sized for subgroups of at least 4 invocations; the trace
        // kernel's lanes claim paths by subgroup ballots.
        let info = ctx.info();
        if !info.subgroup_arithmetic || !info.subgroup_ballot || info.subgroup_size < 4 {
            return Err(RenderError::Gpu(gpu::Error::MissingFeature {
                device: info.name.clone(),
                feature: "subgroup arithmetic, ballot and vote in compute shaders, with subgroups of 4 or more"
                    .into(),
            }));
        }
        let max_groups = ctx.info().max_workgroup_count;
        let [gx, gy, _] = groups(settings.width, settings.height);
        if gx > max_groups[0] || gy > max_groups[1] {
            return Err(SettingsError(format!(
                "image size {}x{} exceeds what device '{}' can dispatch",
                settings.width,
                settings.height,
                ctx.info().name
            ))
            .into());
        }
        let pixels = settings.width as u64 * settings.height as u64;
        let guide = match &settings.guide {
            Some(g) => {
                g.check_device(scene, ctx.info()).map_err(SettingsError)?;
                Some(g.build(ctx, scene, settings.seed, pixels)?)
            }
            None => None,
        };
        let gpu_scene = GpuScene::upload(ctx, scene)?;
        let samples_per_dispatch = samples_per_dispatch(&settings, pixels, ctx.info());
        let samples = Buffer::gpu_only(
            ctx,
            "path samples",
            samples_per_dispatch as u64 * pixels * size_of::<PathSample>() as u64,
        )?;
        let accum = Buffer::gpu_only(ctx, "accumulation", pixels * size_of::<Accum>() as u64)?;
        let stats_bytes =
            (shaders::STATS_COPIES * shaders::MAX_BATCH) as u64 * size_of::<PassStats>() as u64;
        let stats = Buffer::gpu_only(ctx, "pass stats", stats_bytes)?;
        let stats_readback = Buffer::readback(ctx, "pass stats (readback)", stats_bytes)?;
        // One counter per trace dispatch of a submit (at most one per pass).
        let work = Buffer::gpu_only(ctx, "work counters", shaders::MAX_BATCH as u64 * 4)?;
        let push = size_of::<PassParams>() as u32;
        // A guide's kernel may be built for its shape (the network's); every
        // trace kernel, for whether the scene has materials beyond diffuse.
        let mut constants = guide.as_ref().map_or(Vec::new(), |g| g.constants());
        debug_assert!(constants.len() <= shaders::CONSTANT_NON_DIFFUSE as usize);
        constants.resize(shaders::CONSTANT_NON_DIFFUSE as usize, 0);
        constants.push(scene.has_non_diffuse() as u32);
        constants.push(guide.as_ref().is_some_and(|g| g.chooses_lights()) as u32);
        constants.push(!scene.normals.is_empty() as u32);
        constants.push(match scene.filter {
            PixelFilter::Box => shaders::FILTER_BOX,
            PixelFilter::Tent { .. } => shaders::FILTER_TENT,
            PixelFilter::Gaussian { .. } => shaders::FILTER_GAUSSIAN,
            PixelFilter::Cubic { .. } => shaders::FILTER_CUBIC,
            PixelFilter::Lanczos { .. } => shaders::FILTER_LANCZOS,
        });
        constants.push(scene.material_features());
        constants.push(!scene.delta_lights.is_empty() as u32);
        constants.push(gpu_scene.sky);
        constants.push(scene.defaults.hide_emitters as u32);
        constants.push((scene.camera.aperture_radius > 0.0) as u32);
        constants.push((scene.material_features() & shaders::FEATURE_NORMAL_MAPS != 0) as u32);
        constants.push(scene.camera.orthographic.is_some() as u32);
        let trace = ComputePipeline::specialized(
            ctx,
            "trace",
            trace_variant(ctx, &settings)?,
            push,
            &constants,
        )?;
        let accumulate = ComputePipeline::new(ctx, "accumulate", spirv::ACCUMULATE, push)?;
        let mut bindings = own_bindings(&gpu_scene, &samples, &accum, &stats, &work);
        if let Some(g) = &guide {
            bindings.extend(g.bindings());
        }
        let trace_set = DescriptorSet::new(ctx, &trace, &bindings)?;
        let frozen = settings
            .guide
            .as_ref()
            .and_then(|g| g.frozen_trace_spirv(settings.nee))
            .map(|kernel| spirv::for_reads(kernel, ctx.info().reads))
            .map(|spirv| pipeline_with_set(ctx, "trace", spirv, &constants, &bindings))
            .transpose()?;
        // A race's reference sums: a copy of the accumulation when it began.
        let may_race = settings.guide.as_ref().is_some_and(|g| g.may_stand_back());
        let race_ref = Buffer::gpu_only(
            ctx,
            "race reference",
            if may_race { accum.size() } else { 16 },
        )?;
        bindings.push((shaders::B_RACE_REF, &race_ref));
        let accumulate_set = DescriptorSet::new(ctx, &accumulate, &bindings)?;
        let race_accumulate = may_race
            .then(|| pipeline_with_set(ctx, "accumulate", spirv::ACCUMULATE, &[1], &bindings))
            .transpose()?;
        ctx.submit(None, |rec| rec.fill(&accum, 0))?;
        let identity = state::Identity::of(scene, &settings);
        let mut renderer = Self {
            ctx: ctx.clone(),
            params: pass_params(scene, &settings),
            settings,
            scene_name: scene.path.display().to_string(),
            _scene: gpu_scene,
            trace,
            accumulate,
            trace_set,
            frozen,
            plain: None,
            stood_back: None,
            race: None,
            window: race::Window::default(),
            constants,
            accumulate_set,
            race_accumulate,
            accum,
            race_ref,
            stats,
            stats_readback,
            work,
            _samples: samples,
            samples_per_dispatch,
            trace_dispatches: 0,
            profiler: Profiler::new(ctx)?,
            identity,
            guide,
            resumed: None,
        };
        // Plain path tracing's kernel, for races and standing back, made
        // now: a driver that compiles a kernel when it is made (NVIDIA's)
        // would otherwise compile it inside the render's clock.
        if may_race {
            renderer.plain = Some(renderer.plain_pipeline()?);
        }
        Ok(renderer)
    }

    /// Runs sample passes `first .. first + count` (count <= MAX_BATCH) in one
    /// submit and returns each pass's totals. Passes in which no guide learns
    /// share trace dispatches (see [`samples_per_dispatch`]); a learning pass
    /// has its own, since the next one samples from what it learned. A race's
    /// lap (`lap`) runs its entrant's kernel and learns nothing.
    fn passes(
        &mut self,
        first: u32,
        count: u32,
        lap: Option<race::Lap>,
    ) -> Result<Vec<PassStats>, RenderError> {
        debug_assert!((1..=shaders::MAX_BATCH).contains(&count));
        let g = groups(self.settings.width, self.settings.height);
        let plain = lap.is_some_and(|l| l.entrant == race::Entrant::Plain)
            || self.stood_back.is_some_and(|from| first >= from);
        if plain && self.plain.is_none() {
            // Made in `new` wherever the guide may race or stand back.
            self.plain = Some(self.plain_pipeline()?);
        }
        let plain = self.plain.as_ref().filter(|_| plain).map(|(p, s)| (p, s));
        let learning = (&self.trace, &self.trace_set);
        let frozen = self.frozen.as_ref().map(|(p, s)| (p, s));
        let (accumulate, accumulate_set) = (&self.accumulate, &self.accumulate_set);
        let race_accumulate = self.race_accumulate.as_ref();
        let mut guide = self.guide.as_mut();
        let (base, settings, accum) = (self.params, &self.settings, &self.accum);
        let most = self.samples_per_dispatch;
        let pixels = settings.width as u64 * settings.height as u64;
        let cpu = self.ctx.info().kind == "CPU";
        let dispatches = &mut self.trace_dispatches;
        let (work, stats, stats_readback) = (&self.work, &self.stats, &self.stats_readback);
        self.ctx.submit(Some(&mut self.profiler), |rec| {
            // Each trace dispatch hands out its paths from a counter of its own.
            rec.fill(work, 0);
            rec.fill(stats, 0);
            let mut work_slot = 0u32;
            // Samples traced but not yet accumulated: passes pending_first..
            // in samples-buffer slots 0.. . One accumulate dispatch takes
            // them all, so passes that learn (one trace dispatch each) still
            // share it.
            let (mut pending_first, mut pending) = (first, 0u32);
            let flush = |rec: &mut gpu::Recorder<'_>, pending_first: u32, pending: u32| {
                if pending == 0 {
                    return;
                }
                let mut params = base;
                params.pass_index = pending_first;
                params.item_count = pending;
                let (pipeline, set) = match (lap, race_accumulate) {
                    (Some(_), Some((p, s))) => (p, s),
                    _ => (accumulate, accumulate_set),
                };
                rec.dispatch_covering(
                    Pass {
                        name: "accumulate",
                        pipeline,
                        set,
                        push: bytemuck::bytes_of(&params),
                        groups: g,
                    },
                    pending,
                );
            };
            let end = first + count;
            let mut index = first;
            let learns = |i: u32| lap.is_none() && plain.is_none() && settings.learns_in_pass(i);
            while index < end {
                let learn = learns(index);
                // A dispatch never spans a reset or a pass that learns.
                let mut samples = 1;
                while !learn
                    && samples < most
                    && index + samples < end
                    && !learns(index + samples)
                    && settings.reset_after() != Some(index + samples)
                {
                    samples += 1;
                }
                if settings.reset_after() == Some(index) || pending + samples > most {
                    flush(rec, pending_first, pending);
                    (pending_first, pending) = (index, 0);
                }
                if settings.reset_after() == Some(index) {
                    rec.fill(accum, 0);
                }
                let mut params = base;
                // The trace kernel draws its random numbers by pass_index.
                params.pass_index = index - u32::from(lap.is_some_and(|l| l.repeat));
                params.item_count = samples;
                debug_assert!(work_slot < shaders::MAX_BATCH);
                params.selector = pending | (work_slot << shaders::WORK_SLOT_SHIFT);
                work_slot += 1;
                if let Some(g) = guide.as_deref() {
                    g.set_params(&mut params, learn);
                }
                let (pipeline, set) = if learn {
                    learning
                } else {
                    plain.or(frozen).unwrap_or(learning)
                };
                rec.dispatch_covering(
                    Pass {
                        name: "trace",
                        pipeline,
                        set,
                        push: bytemuck::bytes_of(&params),
                        groups: trace_groups(g, samples, pixels, settings.max_depth, cpu),
                    },
                    samples,
                );
                pending += samples;
                // The next pass samples from what this one learned.
                if let (Some(g), true) = (guide.as_deref_mut(), learn) {
                    g.record_update(rec, &params);
                }
                index += samples;
                *dispatches += 1;
            }
            flush(rec, pending_first, pending);
            rec.copy(stats, stats_readback);
        })?;
        let copies = self.stats_readback.read::<PassStats>();
        Ok((first..first + count)
            .map(|i| {
                PassStats::sum(
                    copies
                        .iter()
                        .skip((i % shaders::MAX_BATCH) as usize)
                        .step_by(shaders::MAX_BATCH as usize),
                )
            })
            .collect())
    }

    /// Plain path tracing's kernel and its descriptor set, for passes after
    /// the guide stood back.
    fn plain_pipeline(&self) -> gpu::Result<(ComputePipeline, DescriptorSet)> {
        let bindings = own_bindings(
            &self._scene,
            &self._samples,
            &self.accum,
            &self.stats,
            &self.work,
        );
        pipeline_with_set(
            &self.ctx,
            "trace",
            plain_variant(&self.ctx, &self.settings),
            &self.constants,
            &bindings,
        )
    }

    /// How many of `passes` the guide learns in.
    fn learning_passes(&self, passes: std::ops::Range<u32>) -> u32 {
        passes.filter(|&i| self.settings.learns_in_pass(i)).count() as u32
    }

    /// Whether the guide has yet to stand back and may (see
    /// `GuideSettings::may_stand_back`).
    fn may_stand_back(&self) -> bool {
        self.stood_back.is_none()
            && self
                .settings
                .guide
                .as_ref()
                .is_some_and(|g| g.may_stand_back())
    }

    /// After an ordinary batch ending at pass `tally.done`: at a check (see
    /// `crate::guide::stand_back_check`) the guide stands back if its
    /// learned shares say it cannot help, and otherwise starts a race (see
    /// [`race`]) where passes are left to run after it.
    fn check_stand_back(&mut self, tally: &Tally) -> Result<(), RenderError> {
        let done = tally.done;
        let Some(g) = self
            .settings
            .guide
            .as_ref()
            .filter(|_| self.may_stand_back())
        else {
            return Ok(());
        };
        if !crate::guide::stand_back_check(done) {
            return Ok(());
        }
        let window = std::mem::take(&mut self.window);
        if g.learns_shares() {
            let start = g.common().epsilon(true);
            let shares = self
                .guide
                .as_ref()
                .map(|g| g.bsdf_shares())
                .transpose()?
                .flatten();
            if shares.is_some_and(|s| crate::guide::stands_back(&s, start, done)) {
                log::info!("the guide stands back after {done} passes: every volume learned to sample the BSDF");
                self.stood_back = Some(done);
                return Ok(());
            }
        }
        let laps = race::LAPS.len() as u32;
        let pixels = u64::from(self.settings.width) * u64::from(self.settings.height);
        let room = done >= race::FIRST
            && pixels >= race::MIN_PIXELS
            && match self.settings.budget {
                Budget::Samples(n) => n.saturating_sub(done) >= 2 * laps,
                Budget::Seconds(_) => true,
            };
        if room {
            let (accum, race_ref) = (&self.accum, &self.race_ref);
            self.ctx.submit(None, |rec| rec.copy(accum, race_ref))?;
            self.race = Some(race::Race::new(done, window));
        }
        Ok(())
    }

    /// Records a race's lap (one pass, `seconds` long); after its last, the
    /// verdict over the passes up to `end` (the render's last, as far as
    /// known): the guide stands back once plain path tracing has won two
    /// races in a row.
    fn lap_done(&mut self, tally: &mut Tally, seconds: f64, stats: &PassStats, end: u32) {
        let Some(r) = self.race.as_mut() else {
            return;
        };
        let lap = race::LapNoise::new(seconds, stats.deviation(), stats.paths as f64, stats.lap());
        log::debug!("race lap: {lap:?}");
        r.record(lap);
        if r.next().is_some() {
            return;
        }
        let r = self.race.take().expect("a race in progress");
        // The guide's cost to come: what it has learned is paid for.
        let done = tally.done;
        let until = end.max(done + 1);
        let learning = self.learning_passes(done..until);
        let won_before = tally.races.last().is_some_and(|r| r.plain_wins);
        let verdict = r.verdict(learning as f64 / (until - done) as f64, won_before);
        log::info!("race after {} passes: {verdict:?}", verdict.after);
        if verdict.stands_back {
            self.stood_back = Some(done);
        }
        tally.races.push(verdict);
    }

    /// Renders until the budget is spent, reporting progress after each pass.
    pub fn run(
        &mut self,
        progress: &mut dyn FnMut(&Progress),
    ) -> Result<RenderOutput, RenderError> {
        self.run_with_checkpoints(progress, &[], &mut |_| {})
    }

    /// The learned guide, if the method has one.
    pub fn guide(&self) -> Option<&Guide> {
        self.guide.as_ref()
    }

    /// Mean and per-path variance of what has been accumulated so far.
    fn images(&self) -> Result<(Image, Image), RenderError> {
        let accum: Vec<Accum> = self.accum.download()?;
        let (w, h) = (self.settings.width as usize, self.settings.height as usize);
        let mut image = Image::new(w, h);
        let mut variance = Image::new(w, h);
        for (i, a) in accum.iter().take(w * h).enumerate() {
            let n = a.sum[3].max(1.0);
            for c in 0..3 {
                let mean = a.sum[c] / n;
                image.pixels[i][c] = mean;
                variance.pixels[i][c] = if n > 1.0 {
                    ((a.sum_sq[c] - n * mean * mean) / (n - 1.0)).max(0.0)
                } else {
                    0.0
                };
            }
        }
        Ok((image, variance))
    }

    /// [`Renderer::run`], also handing `on_checkpoint` the image after each
    /// pass count in `checkpoints`. Reading it back does not count as render time.
    pub fn run_with_checkpoints(
        &mut self,
        progress: &mut dyn FnMut(&Progress),
        checkpoints: &[u32],
        on_checkpoint: &mut dyn FnMut(&Checkpoint),
    ) -> Result<RenderOutput, RenderError> {
        let control = Control {
            at_passes: checkpoints,
            ..Default::default()
        };
        self.run_controlled(progress, &control, on_checkpoint)
    }

    /// [`Renderer::run`] under `control`: checkpoints by pass count or by
    /// time, and a stop flag that ends the render after the batch in
    /// flight (the output then says it was interrupted).
    pub fn run_controlled(
        &mut self,
        progress: &mut dyn FnMut(&Progress),
        control: &Control<'_>,
        on_checkpoint: &mut dyn FnMut(&Checkpoint),
    ) -> Result<RenderOutput, RenderError> {
        let mut run = self.start();
        while !run.finished() {
            self.step(&mut run, progress, control, on_checkpoint)?;
            if control.stopped() {
                break;
            }
        }
        self.finish(run, control)
    }

    /// A render under way, to run a batch at a time with [`Renderer::step`].
    pub fn start(&mut self) -> Run {
        let tally = self.resumed.take().unwrap_or_default();
        self.stood_back = tally.stood_back;
        if let (Some(g), Some(fit)) = (self.guide.as_mut(), &tally.fit) {
            g.refit(fit);
        }
        Run {
            tally,
            seconds: 0.0,
            last_checkpoint: 0.0,
            pass_seconds: 0.0,
            finished: false,
        }
    }

    /// Runs `run`'s next batch of passes, and its checkpoint if one is due.
    pub fn step(
        &mut self,
        run: &mut Run,
        progress: &mut dyn FnMut(&Progress),
        control: &Control<'_>,
        on_checkpoint: &mut dyn FnMut(&Checkpoint),
    ) -> Result<(), RenderError> {
        // The render's clock runs only inside its own batches.
        let since = Instant::now();
        let base = run.seconds;
        let (passes_total, budget_seconds) = match self.settings.budget {
            Budget::Samples(n) => (Some(n), None),
            Budget::Seconds(t) => (None, Some(t)),
        };
        let tally = &mut run.tally;
        // A batch never runs past the budget or the next checkpoint, and
        // stays short enough (~0.25 s) for progress, time budgets and
        // stopping; longer batches let passes that learn nothing share
        // trace dispatches.
        let done = tally.done;
        let mut count = shaders::MAX_BATCH;
        if let Budget::Samples(n) = self.settings.budget {
            count = count.min(n - done);
        }
        if let Some(&next) = control.at_passes.iter().filter(|&&c| c > done).min() {
            count = count.min(next - done);
        }
        // The guide checks whether to stand back after fixed passes.
        if self.may_stand_back() {
            if let Some(next) =
                (done + 1..done + count).find(|&i| crate::guide::stand_back_check(i))
            {
                count = next - done;
            }
        }
        if run.pass_seconds > 0.0 {
            let mut seconds = 0.25f64;
            if let Budget::Seconds(t) = self.settings.budget {
                seconds = seconds.min(t - run.seconds);
            }
            count = count.min((seconds / run.pass_seconds).ceil().max(1.0) as u32);
        } else {
            count = 1; // the first pass measures the cost of one
        }
        // A race runs its laps a pass at a time.
        let lap = self.race.as_ref().and_then(|r| r.next());
        if lap.is_some() {
            count = 1;
        }
        let batch_start = Instant::now();
        let compiled = self.profiler.compile_ms();
        let batch = self.passes(done, count, lap)?;
        // The driver's first compile of a kernel is start-up, not render
        // time: the clock leaves it out.
        let compile = (self.profiler.compile_ms() - compiled) * 1e-3;
        let wall = (batch_start.elapsed().as_secs_f64() - compile).max(0.0);
        // The run's seconds so far: its earlier batches and this step's.
        let clock = || base + since.elapsed().as_secs_f64() - compile;
        run.pass_seconds = wall / count as f64;
        // Races compare GPU time where the device has timestamps: a
        // submit's wall time also holds the host's waits, which
        // swamp small images' passes.
        let seconds = self.profiler.last_submit_ms().map_or(wall, |ms| ms * 1e-3);
        for s in &batch {
            tally.add(s, self.guide.is_some());
        }
        if done == 0 {
            // The first pass runs alone: its times are the device's costs.
            if let Some(g) = self.guide.as_mut() {
                tally.fit = g.fit_to_device(&self.profiler.timings());
            }
        }
        if lap.is_some() {
            // The passes left: the budget's, or as many as its time holds.
            let end = match self.settings.budget {
                Budget::Samples(n) => n,
                Budget::Seconds(t) => {
                    let left = t - clock();
                    done + (left / run.pass_seconds).clamp(0.0, settings::MAX_SPP as f64) as u32
                }
            };
            self.lap_done(tally, seconds, &batch[0], end);
        } else {
            // The first pass may hold the driver's start-up costs.
            if done > 0 {
                let learning = self.learning_passes(done..done + count);
                self.window.add(seconds, count, learning);
            }
            self.check_stand_back(tally)?;
        }
        tally.stood_back = self.stood_back;
        let elapsed = clock();
        let timed = control
            .every_seconds
            .is_some_and(|t| elapsed - run.last_checkpoint >= t);
        if control.at_passes.contains(&tally.done) || timed {
            if let Some(path) = control.state {
                self.save_state(path, tally, elapsed)?;
            }
            let (image, _) = self.images()?;
            on_checkpoint(&Checkpoint {
                spp: tally.done,
                seconds: elapsed,
                zero_contribution_fraction: tally.zero as f64 / tally.paths.max(1) as f64,
                stats: self.stats(tally, elapsed, false),
                image,
            });
            // Reading the checkpoint back is not render time: the clock
            // stopped before it.
            run.last_checkpoint = elapsed;
        }
        run.seconds = elapsed;
        progress(&Progress {
            passes_done: tally.done,
            passes_total,
            elapsed,
            budget_seconds,
            rays_per_second: tally.rays as f64 / elapsed.max(1e-9),
        });
        run.finished = match self.settings.budget {
            Budget::Samples(n) => tally.done >= n,
            Budget::Seconds(t) => elapsed >= t || tally.done >= settings::MAX_SPP,
        };
        Ok(())
    }

    /// The image and statistics of `run`, which ended or was stopped.
    pub fn finish(&mut self, run: Run, control: &Control<'_>) -> Result<RenderOutput, RenderError> {
        let (image, variance) = self.images()?;
        if let Some(path) = control.state {
            self.save_state(path, &run.tally, run.seconds)?;
        }
        Ok(RenderOutput {
            image,
            variance,
            stats: self.stats(&run.tally, run.seconds, !run.finished),
        })
    }

    /// The statistics of what `tally` counted, `wall` seconds into this run.
    fn stats(&self, tally: &Tally, wall: f64, interrupted: bool) -> RenderStats {
        let wall = wall + tally.seconds_before;
        let timings = self.profiler.timings();
        let nz = tally.paths.max(1) as f64;
        let done = tally.done;
        RenderStats {
            method: self.settings.method.name().into(),
            nee: self.settings.nee,
            device: self.ctx.info().name.clone(),
            reads: self.ctx.info().reads,
            scene: self.scene_name.clone(),
            width: self.settings.width,
            height: self.settings.height,
            seed: self.settings.seed,
            spp: done,
            image_spp: done - self.settings.reset_after().unwrap_or(0).min(done),
            interrupted,
            wall_seconds: wall,
            compile_seconds: self.profiler.compile_ms() * 1e-3,
            samples_per_second: tally.paths as f64 / wall.max(1e-9),
            rays_per_second: tally.rays as f64 / wall.max(1e-9),
            paths: tally.paths,
            rays: tally.rays,
            zero_contribution_fraction: tally.zero as f64 / nz,
            mean_path_length: tally.length as f64 / nz,
            invalid_paths: tally.invalid,
            gpu_ms: timings
                .iter()
                .map(|t| (t.name.clone(), t.total_ms))
                .collect(),
            gpu_passes: timings,
            guide: self.settings.guide.clone(),
            guide_bytes: self.guide.as_ref().map_or(0, |g| g.bytes()),
            guide_volumes: self.guide.as_ref().map_or(0, |g| g.volume_count()),
            passes: tally.records.clone(),
            trace_dispatches: self.trace_dispatches,
            guide_stood_back_after: tally.stood_back,
            guide_races: tally.races.clone(),
            guide_fit: tally.fit.clone(),
            guide_update: self
                .guide
                .as_ref()
                .and_then(|g| g.volume_table())
                .map(|t| t.update_layout()),
        }
    }
}

/// What the passes of a render so far add up to.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub(crate) struct Tally {
    done: u32,
    /// Render time before this run (a resumed render's earlier runs).
    seconds_before: f64,
    paths: u64,
    rays: u64,
    zero: u64,
    length: u64,
    invalid: u64,
    records: Vec<PassRecord>,
    /// The pass from which the guide stood back, if it did.
    #[serde(default)]
    stood_back: Option<u32>,
    /// The races run so far (see [`race`]).
    #[serde(default)]
    races: Vec<RaceRecord>,
    /// How the guide sized its work to the device after the first pass.
    #[serde(default)]
    fit: Option<crate::guide::DeviceFit>,
}

impl Tally {
    fn add(&mut self, s: &PassStats, guided: bool) {
        self.done += 1;
        self.paths += s.paths as u64;
        self.rays += s.rays as u64;
        self.zero += s.zero_paths as u64;
        self.length += s.length_sum as u64;
        self.invalid += s.nan_paths as u64;
        let n = s.paths.max(1) as f64;
        self.records.push(PassRecord {
            pass: self.done - 1,
            zero_contribution_fraction: s.zero_paths as f64 / n,
            mean_path_length: s.length_sum as f64 / n,
            rays: s.rays as u64,
            deviation: s.deviation(),
            loss: guided.then(|| f32::from_bits(s.td_sq_bits) as f64 / s.td_count.max(1) as f64),
        });
    }
}

/// A render under way (see [`Renderer::start`]). Its clock counts only its
/// own batches, so that renders stepped in turn (the bench's) each time
/// their own work, and a change in the machine's speed falls on all alike.
pub struct Run {
    tally: Tally,
    /// Render seconds so far: its batches' wall time, checkpoints' reads and
    /// kernel compiles left out.
    seconds: f64,
    last_checkpoint: f64,
    /// Seconds per pass in the last batch, to size the next.
    pass_seconds: f64,
    finished: bool,
}

impl Run {
    /// Whether the render has spent its budget.
    pub fn finished(&self) -> bool {
        self.finished
    }

    /// Sample passes run so far.
    pub fn passes_done(&self) -> u32 {
        self.tally.done
    }

    /// Render seconds so far (see [`Run`]).
    pub fn seconds(&self) -> f64 {
        self.seconds
    }
}

/// When a render hands out what it has so far, and when it stops early.
#[derive(Default)]
pub struct Control<'a> {
    /// Pass counts after which the image is handed out.
    pub at_passes: &'a [u32],
    /// Also every this many seconds of render time.
    pub every_seconds: Option<f64>,
    /// Set elsewhere (a signal handler) to end the render after the batch
    /// in flight.
    pub stop: Option<&'a AtomicBool>,
    /// Where to keep the render's state (see [`state`]), written at every
    /// checkpoint and when the render ends.
    pub state: Option<&'a std::path::Path>,
}

impl Control<'_> {
    /// Whether the stop flag is set.
    pub fn stopped(&self) -> bool {
        self.stop.is_some_and(|s| s.load(Ordering::Relaxed))
    }
}

/// Loads nothing, checks everything, renders: the library entry point the CLI uses.
pub fn render(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    settings: RenderSettings,
    progress: &mut dyn FnMut(&Progress),
) -> Result<RenderOutput, RenderError> {
    Renderer::new(ctx, scene, settings)?.run(progress)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cpu_trace_dispatch_holds_lanes_enough_for_its_paths() {
        let tiles = groups(128, 128);
        // One sample per pixel at max depth 64: each lane is sure of 32
        // paths, so 8 workgroups would do; it gets four times that.
        assert_eq!(trace_groups(tiles, 1, 128 * 128, 64, true), [16, 2, 1]);
        // A GPU, and a dispatch that needs the whole image, get the image.
        assert_eq!(trace_groups(tiles, 1, 128 * 128, 64, false), tiles);
        assert_eq!(trace_groups(tiles, 16, 128 * 128, 64, true), tiles);
        // Every item finds a lane sure to take it, at any depth and size.
        for (w, h) in [(1, 1), (7, 300), (200, 72), (4096, 4096)] {
            for samples in 1..=shaders::MAX_BATCH {
                for depth in [0, 5, 64, 1000, 20000] {
                    let t = groups(w, h);
                    let g = trace_groups(t, samples, w as u64 * h as u64, depth, true);
                    assert!(g[0] <= t[0] && g[1] <= t[1] && g[2] == 1);
                    let lanes = (g[0] * g[1] * shaders::TILE_X * shaders::TILE_Y) as u64;
                    let sure = (shaders::MAX_TRACE_STEPS as u64 - 1) / (depth as u64 + 2);
                    let sure = sure.min(shaders::MAX_CLAIMS as u64).max(samples as u64);
                    assert!(
                        g == t || lanes * sure >= samples as u64 * w as u64 * h as u64,
                        "{w}x{h}, {samples} samples, depth {depth}: {g:?}"
                    );
                }
            }
        }
    }
}
