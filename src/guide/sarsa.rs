//! Expected Sarsa guiding (docs/guides.md): Q-values in radiance volumes, updated
//! by atomic accumulation during a sample pass and folded between passes.

use super::lookup::VolumeLookup;
use super::volumes::Volume;
use super::{volumes, Common, DeviceGuide, Guide, GuideConfig, GuideEntry, GuideSettings};
use crate::bench::learned;
use crate::gpu::{
    self, Buffer, ComputePipeline, DescriptorSet, DeviceInfo, GpuContext, Pass, Recorder,
};
use crate::render::RenderError;
use crate::scene::Scene;
use crate::shaders::{self, spirv, PassParams, SectorEntry};
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// How the GPU adds targets.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Atomics {
    /// Fixed point where the device has 64-bit atomics, else float atomics,
    /// else compare-and-swap.
    #[default]
    Auto,
    /// 64-bit fixed-point integer adds (`shaderBufferInt64Atomics`; an error
    /// where missing): associative, so one seed gives one image, bit for bit.
    Fixed,
    /// `VK_EXT_shader_atomic_float` (an error where missing); the order of
    /// adds, and so the last bits of Q, differ from run to run.
    Float,
    /// Compare-and-swap loops on float bits (works everywhere; as `float`).
    Cas,
}

/// The `[sarsa]` table.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SarsaSettings {
    #[serde(flatten)]
    pub common: Common,
    /// Radiance volumes to place (fewer if the memory budget says so); None:
    /// one per PIXELS_PER_VOLUME pixels of the image in a render, else
    /// DEFAULT_VOLUMES.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub volumes: Option<u32>,
    /// Volumes per unit² of (non-emitting) surface; replaces `volumes` when set.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub density: Option<f64>,
    /// Upper bound on the guide's device memory, MiB.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub memory_mib: Option<f64>,
    pub atomics: Atomics,
    /// Whether each volume learns its share of BSDF sampling in the
    /// mixture, starting from `epsilon` (None: yes).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub learn_epsilon: Option<bool>,
}

/// Pixels per radiance volume when neither a count nor a density is given:
/// each pass then brings every volume about the same number of paths at any
/// image size. Measured at 256 spp: at 128×128, 256 volumes beat 1024 on
/// four scenes (relMSE 0.014 vs 0.016 on the Cornell box, 0.039 vs 0.044 on
/// the door ajar); at 256×256, 1024 beat 256 and 512 on the indirectly lit room.
pub const PIXELS_PER_VOLUME: u64 = 64;
/// Fewest volumes that default gives.
pub const MIN_DEFAULT_VOLUMES: u32 = 64;
/// Volumes of a guide made outside a render.
pub const DEFAULT_VOLUMES: u32 = 1024;

/// Most volumes a guide may hold.
pub const MAX_VOLUMES: u32 = 1 << 22;

/// Device bytes per volume for an n-sector grid and `lights` lights it
/// picks among for NEE: Q, the alias table, target sums (8 bytes), new and
/// total visit counts, and the NEE share's sums (8 bytes) and mean per
/// sector; per light the tries' sums (8), counts, mean, total count and
/// alias entry; per volume its sums and BSDF share (16), the share's
/// gradient tallies (16) and state (16).
fn table_bytes_per_volume(sectors: u32, lights: u32) -> u64 {
    let entry = size_of::<SectorEntry>() as u64;
    (8 * 4 + entry) * sectors as u64 + (8 + 3 * 4 + entry) * lights as u64 + 48
}

/// What the memory budget counts per volume: its tables and about 16 lookup
/// cells (cells are half the volume spacing; small triangles add their own,
/// which `SarsaGuide::bytes` reports).
pub fn bytes_per_volume(sectors: u32, lights: u32) -> u64 {
    table_bytes_per_volume(sectors, lights) + 16 * 8
}

/// Each light's share of the scene's emitted power where a guide picks
/// NEE's light, else none: where there are several lights to pick among
/// (`Scene::lights_to_pick`; a light is an emitter's connected triangles,
/// a delta light or the sky, so that the two halves of one quad light,
/// not worth a choice, are one).
pub fn guided_light_power(scene: &Scene) -> Vec<f32> {
    scene.light_groups().0.iter().map(|g| g.power).collect()
}

impl SarsaSettings {
    pub fn sectors(&self) -> u32 {
        self.common.sectors()
    }

    /// The share of BSDF sampling, or where each volume's learned share starts.
    pub fn epsilon(&self) -> f32 {
        self.common.epsilon(self.learns_epsilon())
    }

    /// Whether volumes learn their share of BSDF sampling (the default).
    pub fn learns_epsilon(&self) -> bool {
        self.learn_epsilon.unwrap_or(true)
    }

    /// Checks the ranges of Sarsa's own keys (`Common::validate` checks
    /// the rest); the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        if let Some(v) = self.volumes.filter(|&v| v == 0 || v > MAX_VOLUMES) {
            return Err(format!("volumes = {v} must lie in 1..={MAX_VOLUMES}"));
        }
        if let Some(d) = self.density {
            if !(d.is_finite() && d > 0.0) {
                return Err(format!("density = {d} must be positive"));
            }
        }
        if let Some(m) = self.memory_mib {
            if !(m.is_finite() && m > 0.0) {
                return Err(format!("memory_mib = {m} must be positive"));
            }
            if ((m * 1024.0 * 1024.0) as u64) < bytes_per_volume(self.sectors(), 0) {
                return Err(format!("memory_mib = {m} holds no volume"));
            }
        }
        Ok(())
    }

    /// Checks the tables fit `device`'s buffers, before placing volumes
    /// (which takes a while for huge counts).
    pub fn check_device(&self, scene: &Scene, device: &DeviceInfo) -> Result<(), String> {
        self.check_tables_fit(scene, device, "sarsa")
    }

    /// [`SarsaSettings::check_device`] for the tables of the guide whose
    /// table is `[guide]` (Neural-Q's inference at the volumes has them too).
    pub fn check_tables_fit(
        &self,
        scene: &Scene,
        device: &DeviceInfo,
        guide: &str,
    ) -> Result<(), String> {
        let lights = guided_light_power(scene).len() as u32;
        let count = self.volume_count(volumes::placement_area(scene), lights);
        self.common
            .wide_update(device, self.sectors().max(lights))
            .map_err(|e| format!("[{guide}] {e}"))?;
        // The largest per-sector buffer is the alias table.
        let bytes = count as u64 * self.sectors() as u64 * size_of::<SectorEntry>() as u64;
        let limit = device.max_storage_buffer_range;
        if bytes > limit {
            return Err(format!(
                "{} {guide} volumes of {} sectors need {} MiB per guide buffer; device '{}' allows {} MiB: use fewer volumes or sectors{} in [{guide}]",
                count,
                self.sectors(),
                bytes >> 20,
                device.name,
                limit >> 20,
                if guide == "sarsa" {
                    ", or a smaller memory_mib"
                } else {
                    ""
                }
            ));
        }
        Ok(())
    }

    /// The default volume count for a `width` × `height` image, where neither
    /// a count nor a density is given.
    pub fn for_image(&self, width: u32, height: u32) -> Self {
        let mut s = self.clone();
        if s.volumes.is_none() && s.density.is_none() {
            let count = (width as u64 * height as u64 / PIXELS_PER_VOLUME)
                .clamp(MIN_DEFAULT_VOLUMES as u64, MAX_VOLUMES as u64);
            s.volumes = Some(count as u32);
        }
        s
    }

    /// Volumes actually placed on `surface_area` units² of surface, each
    /// picking among `lights` lights for NEE: the requested count (or
    /// density × area) within the memory budget.
    pub fn volume_count(&self, surface_area: f64, lights: u32) -> u32 {
        let wanted = match self.density {
            Some(d) => (d * surface_area).ceil().clamp(1.0, MAX_VOLUMES as f64) as u32,
            None => self.volumes.unwrap_or(DEFAULT_VOLUMES),
        };
        let per = bytes_per_volume(self.sectors(), lights);
        match self.memory_mib {
            Some(m) => wanted.min(((m * 1024.0 * 1024.0) as u64 / per) as u32),
            None => wanted,
        }
    }

    /// How targets are added on `device` (`Auto` resolved); an error where
    /// `atomics` asks for what the device lacks.
    pub fn atomics_on(&self, device: &DeviceInfo) -> gpu::Result<Atomics> {
        let missing = |feature: &str| gpu::Error::MissingFeature {
            device: device.name.clone(),
            feature: format!(
                "{feature}, needed by [sarsa] atomics = \"{}\"",
                match self.atomics {
                    Atomics::Fixed => "fixed",
                    _ => "float",
                }
            ),
        };
        match self.atomics {
            Atomics::Fixed if !device.int64_atomics => Err(missing("64-bit buffer atomics")),
            Atomics::Float if !device.float_atomics => {
                Err(missing("float atomics (VK_EXT_shader_atomic_float)"))
            }
            Atomics::Auto if device.int64_atomics => Ok(Atomics::Fixed),
            Atomics::Auto if device.float_atomics => Ok(Atomics::Float),
            Atomics::Auto => Ok(Atomics::Cas),
            chosen => Ok(chosen),
        }
    }

    /// SPIR-V of a kernel that adds targets, by the atomics it uses on `device`:
    /// `[fixed, float, cas]`.
    pub fn pick(
        &self,
        device: &DeviceInfo,
        variants: [&'static [u8]; 3],
    ) -> gpu::Result<&'static [u8]> {
        Ok(match self.atomics_on(device)? {
            Atomics::Fixed => variants[0],
            Atomics::Float => variants[1],
            _ => variants[2],
        })
    }
}

/// Expected Sarsa among the guides.
pub const GUIDE: GuideEntry = GuideEntry {
    name: "sarsa",
    about: "Expected Sarsa guiding: Q-values in radiance volumes",
    read: |table| table.try_into().map(|s: SarsaSettings| s.into()),
    every_key: |common| {
        GuideSettings::from(SarsaSettings {
            common,
            volumes: Some(0),
            density: Some(0.0),
            memory_mib: Some(0.0),
            learn_epsilon: Some(true),
            ..Default::default()
        })
    },
};

impl crate::render::Method {
    pub const SARSA: Self = Self::guided(GUIDE.name);
}

/// Sarsa's trace kernels, `[fixed, float, cas]` by the atomics that add
/// targets (see [`SarsaSettings::pick`]); Neural-Q trained on the volumes'
/// means runs them too.
pub fn trace_variants(nee: bool) -> [&'static [u8]; 3] {
    if nee {
        [
            spirv::TRACE_SARSA_NEE_FIXED,
            spirv::TRACE_SARSA_NEE,
            spirv::TRACE_SARSA_NEE_CAS,
        ]
    } else {
        [
            spirv::TRACE_SARSA_FIXED,
            spirv::TRACE_SARSA,
            spirv::TRACE_SARSA_CAS,
        ]
    }
}

/// Sarsa's trace kernel without the learning code.
pub fn frozen_trace(nee: bool) -> &'static [u8] {
    if nee {
        spirv::TRACE_SARSA_NEE_FROZEN
    } else {
        spirv::TRACE_SARSA_FROZEN
    }
}

impl GuideConfig for SarsaSettings {
    fn name(&self) -> &'static str {
        GUIDE.name
    }

    fn common(&self) -> &Common {
        &self.common
    }

    fn default_thin_after(&self) -> u32 {
        // Measured at 128×128, 256 spp (docs/notebook.md): learning only in
        // the first 16 passes kept the error at equal samples within 10% on
        // the indirectly lit and glossy rooms and cut it 1.4–1.6× at equal
        // time; thinning instead of stopping keeps longer renders learning.
        16
    }

    fn learns_shares(&self) -> bool {
        self.learns_epsilon()
    }

    fn validate(&self, _scene: &Scene) -> Result<(), String> {
        SarsaSettings::validate(self)
    }

    fn check_device(&self, scene: &Scene, device: &DeviceInfo) -> Result<(), String> {
        SarsaSettings::check_device(self, scene, device)
    }

    fn trace_spirv(&self, device: &DeviceInfo, nee: bool) -> gpu::Result<&'static [u8]> {
        self.pick(device, trace_variants(nee))
    }

    fn frozen_trace_spirv(&self, nee: bool) -> Option<&'static [u8]> {
        Some(frozen_trace(nee))
    }

    fn for_image(&self, width: u32, height: u32) -> GuideSettings {
        SarsaSettings::for_image(self, width, height).into()
    }

    fn build(
        &self,
        ctx: &Arc<GpuContext>,
        scene: &Scene,
        seed: u32,
        _pixels: u64,
    ) -> gpu::Result<Guide> {
        let guide = SarsaGuide::new(ctx, scene, self, seed, self.common.picks_lights())?;
        Ok(Box::new(guide))
    }
}

impl DeviceGuide for SarsaGuide {
    fn chooses_lights(&self) -> bool {
        SarsaGuide::chooses_lights(self)
    }

    fn constants(&self) -> Vec<u32> {
        Vec::new()
    }

    fn volume_table(&self) -> Option<&SarsaGuide> {
        Some(self)
    }

    fn bindings(&self) -> Vec<(u32, &Buffer)> {
        SarsaGuide::bindings(self).to_vec()
    }

    fn set_params(&self, p: &mut PassParams, learn: bool) {
        SarsaGuide::set_params(self, p, learn)
    }

    fn record_update(&mut self, rec: &mut Recorder<'_>, params: &PassParams) {
        SarsaGuide::record_update(self, rec, params)
    }

    fn bytes(&self) -> u64 {
        SarsaGuide::bytes(self)
    }

    fn save(&self) -> gpu::Result<Vec<(&'static str, Vec<u8>)>> {
        SarsaGuide::save(self)
    }

    fn restore(
        &mut self,
        ctx: &Arc<GpuContext>,
        blobs: &[(String, Vec<u8>)],
        _nee: bool,
    ) -> Result<(), String> {
        SarsaGuide::restore(self, ctx, blobs)
    }

    fn volume_count(&self) -> u64 {
        self.volumes.len() as u64
    }

    fn grid(&self) -> [u32; 2] {
        self.settings.common.grid
    }

    fn sample_rows(
        &self,
        _ctx: &Arc<GpuContext>,
        scene: &Scene,
        count: usize,
    ) -> Result<(Vec<Vec<f32>>, String), RenderError> {
        let volumes = learned::volumes_near_light(scene, self, count);
        let q = self.download_q()?;
        let rows = learned::volume_rows(self, &q, &volumes);
        let list: Vec<String> = volumes.iter().map(|v| v.to_string()).collect();
        let at = format!(
            "the {} volumes nearest the brightest light (volumes {})",
            volumes.len(),
            list.join(", ")
        );
        Ok((rows, at))
    }
}

/// The guide's device state and its between-pass passes.
pub struct SarsaGuide {
    pub volumes: Vec<Volume>,
    pub settings: SarsaSettings,
    q: Buffer,
    sectors: Buffer,
    sum: Buffer,
    visits: Buffer,
    visits_total: Buffer,
    direct_sum: Buffer,
    q_direct: Buffer,
    /// NEE's choice of light (empty tables where the guide makes none).
    lights: u32,
    light_power: Buffer,
    light_sum: Buffer,
    light_tries: Buffer,
    light_mean: Buffer,
    light_seen: Buffer,
    volume_sums: Buffer,
    mix_grad: Buffer,
    mix_state: Buffer,
    lookup: VolumeLookup,
    lookup_triangles: Buffer,
    lookup_cells: Buffer,
    lookup_items: Buffer,
    build: ComputePipeline,
    build_set: DescriptorSet,
    /// Whether the update runs a workgroup a volume, and the most
    /// workgroups the device takes along x.
    wide: bool,
    max_groups_x: u32,
}

impl SarsaGuide {
    /// Places volumes over `scene` and uploads the initial guide, which
    /// learns to pick NEE's light where `pick_lights` and the scene has
    /// lights to pick among.
    pub fn new(
        ctx: &Arc<GpuContext>,
        scene: &Scene,
        settings: &SarsaSettings,
        seed: u32,
        pick_lights: bool,
    ) -> gpu::Result<Self> {
        let light_power = if pick_lights {
            guided_light_power(scene)
        } else {
            Vec::new()
        };
        let count = settings.volume_count(volumes::placement_area(scene), light_power.len() as u32);
        let mut vols = volumes::place(scene, count as usize, seed as u64);
        volumes::build_kd_tree(&mut vols);
        let start = std::time::Instant::now();
        let lookup = VolumeLookup::build(scene, &vols);
        log::info!(
            "volume lookup: {} of {} triangles direct, {} cells, {:.2} volumes per cell, {:.1} MiB, built in {:.2} s",
            lookup.direct_triangles(),
            lookup.triangles.len(),
            lookup.cells.len(),
            lookup.mean_candidates(),
            lookup.bytes() as f64 / (1024.0 * 1024.0),
            start.elapsed().as_secs_f64()
        );
        Self::from_volumes(ctx, vols, lookup, settings, &light_power, true)
    }

    /// A fresh table of running means over the same volumes and lookup (no
    /// placement or lookup build again), with its own Q and tallies: its
    /// update folds targets and learns the share, and builds no sampling
    /// distribution, as nothing samples from it.
    pub fn means_twin(&self, ctx: &Arc<GpuContext>) -> gpu::Result<Self> {
        let light_power: Vec<f32> = if self.lights > 0 {
            self.light_power.download()?
        } else {
            Vec::new()
        };
        Self::from_volumes(
            ctx,
            self.volumes.clone(),
            self.lookup.clone(),
            &self.settings,
            &light_power,
            false,
        )
    }

    /// A guide over given volumes (already in k-d tree order) and their
    /// lookup, picking NEE's light where given the lights' shares of power;
    /// its update builds the sampling distributions where `table`.
    fn from_volumes(
        ctx: &Arc<GpuContext>,
        vols: Vec<Volume>,
        lookup: VolumeLookup,
        settings: &SarsaSettings,
        light_power: &[f32],
        table: bool,
    ) -> gpu::Result<Self> {
        let n = settings.sectors() as u64;
        let cells = vols.len() as u64 * n;
        let lights = light_power.len() as u32;
        // Per (volume, light); the alias tables have a row more, by power
        // alone, for vertices without a volume.
        let light_cells = (vols.len() as u64 * lights as u64).max(1);
        let light_entries = (vols.len() as u64 + 1) * lights as u64;
        let initial = vec![settings.common.initial_q; cells as usize];
        let push = size_of::<PassParams>() as u32;
        let q = Buffer::gpu_only_with(ctx, "sarsa Q", &initial)?;
        let sectors = Buffer::gpu_only(
            ctx,
            "sarsa sector tables",
            (cells + light_entries) * size_of::<SectorEntry>() as u64,
        )?;
        // Sums are 64-bit fixed point or (in the low half) float.
        let sum = Buffer::gpu_only(ctx, "sarsa target sums", cells * 8)?;
        let visits = Buffer::gpu_only(ctx, "sarsa visits (pass)", cells * 4)?;
        let visits_total = Buffer::gpu_only(ctx, "sarsa visits (total)", cells * 4)?;
        let direct_sum = Buffer::gpu_only(ctx, "sarsa direct sums", cells * 8)?;
        let q_direct = Buffer::gpu_only(ctx, "sarsa Q carried by NEE", cells * 4)?;
        let power: &[f32] = if light_power.is_empty() {
            &[0.0]
        } else {
            light_power
        };
        let light_power = Buffer::gpu_only_with(ctx, "sarsa light power", power)?;
        let light_sum = Buffer::gpu_only(ctx, "sarsa light sums", light_cells * 8)?;
        let light_tries = Buffer::gpu_only(ctx, "sarsa light tries (pass)", light_cells * 4)?;
        let light_mean = Buffer::gpu_only(ctx, "sarsa light means", light_cells * 4)?;
        let light_seen = Buffer::gpu_only(ctx, "sarsa light tries (total)", light_cells * 4)?;
        let volume_sums = Buffer::gpu_only(ctx, "sarsa volume sums", vols.len() as u64 * 16)?;
        let mix_grad = Buffer::gpu_only(ctx, "sarsa BSDF share gradients", vols.len() as u64 * 16)?;
        let mix_state = Buffer::gpu_only(ctx, "sarsa BSDF shares", vols.len() as u64 * 16)?;
        // List items carry their volume's position, so the scan reads one
        // contiguous vec4 per candidate: (position, index bits).
        let items: Vec<[f32; 4]> = lookup
            .items
            .iter()
            .map(|&j| {
                let p = vols[j as usize].position;
                [p[0], p[1], p[2], f32::from_bits(j)]
            })
            .collect();
        let lookup_triangles =
            Buffer::gpu_only_with(ctx, "volume lookup triangles", &lookup.triangles)?;
        let lookup_cells = Buffer::gpu_only_with(ctx, "volume lookup cells", &lookup.cells)?;
        let lookup_items = Buffer::gpu_only_with(ctx, "volume lookup lists", &items)?;
        // The tallies' type and the update's width decide the variant.
        let entries = settings.sectors().max(lights);
        let wide = settings
            .common
            .wide_update(ctx.info(), entries)
            .map_err(|_| gpu::Error::MissingFeature {
                device: ctx.info().name.clone(),
                feature: format!(
                    "the workgroup memory a table of {entries} entries needs with update = \"workgroup\""
                ),
            })?;
        let build_spirv = settings.pick(
            ctx.info(),
            if wide {
                [
                    spirv::GUIDE_BUILD_WIDE_FIXED,
                    spirv::GUIDE_BUILD_WIDE,
                    spirv::GUIDE_BUILD_WIDE,
                ]
            } else {
                [
                    spirv::GUIDE_BUILD_FIXED,
                    spirv::GUIDE_BUILD,
                    spirv::GUIDE_BUILD,
                ]
            },
        )?;
        let build = ComputePipeline::specialized(
            ctx,
            "guide update",
            build_spirv,
            push,
            &[table as u32, entries],
        )?;
        let bindings = [
            (shaders::B_Q, &q),
            (shaders::B_SECTORS, &sectors),
            (shaders::B_SUM, &sum),
            (shaders::B_VISITS, &visits),
            (shaders::B_VISITS_TOTAL, &visits_total),
            (shaders::B_VOLUME_SUMS, &volume_sums),
            (shaders::B_DIRECT_SUM, &direct_sum),
            (shaders::B_Q_DIRECT, &q_direct),
            (shaders::B_MIX_GRAD, &mix_grad),
            (shaders::B_MIX_STATE, &mix_state),
            (shaders::B_LIGHT_SUM, &light_sum),
            (shaders::B_LIGHT_TRIES, &light_tries),
            (shaders::B_LIGHT_MEAN, &light_mean),
            (shaders::B_LIGHT_SEEN, &light_seen),
            (shaders::B_LIGHT_POWER, &light_power),
        ];
        let build_set = DescriptorSet::new(ctx, &build, &bindings)?;
        let guide = Self {
            volumes: vols,
            settings: settings.clone(),
            q,
            sectors,
            sum,
            visits,
            visits_total,
            direct_sum,
            q_direct,
            lights,
            light_power,
            light_sum,
            light_tries,
            light_mean,
            light_seen,
            volume_sums,
            mix_grad,
            mix_state,
            lookup,
            lookup_triangles,
            lookup_cells,
            lookup_items,
            build,
            build_set,
            wide,
            max_groups_x: ctx.info().max_workgroup_count[0],
        };
        let mut params = PassParams::default();
        guide.set_params(&mut params, false);
        ctx.submit(None, |rec| {
            for b in [
                &guide.sum,
                &guide.visits,
                &guide.visits_total,
                &guide.direct_sum,
                &guide.q_direct,
                &guide.mix_grad,
                &guide.mix_state,
                &guide.light_sum,
                &guide.light_tries,
                &guide.light_mean,
                &guide.light_seen,
            ] {
                rec.fill(b, 0);
            }
            guide.record_build(rec, bytemuck::bytes_of(&params));
        })?;
        Ok(guide)
    }

    /// The tallies a trace kernel adds targets to (with the bindings of
    /// another guide's tables, for a learner whose targets land apart from
    /// the tables it samples from).
    pub fn tally_bindings(&self) -> [(u32, &Buffer); 6] {
        [
            (shaders::B_SUM, &self.sum),
            (shaders::B_VISITS, &self.visits),
            (shaders::B_DIRECT_SUM, &self.direct_sum),
            (shaders::B_MIX_GRAD, &self.mix_grad),
            (shaders::B_LIGHT_SUM, &self.light_sum),
            (shaders::B_LIGHT_TRIES, &self.light_tries),
        ]
    }

    /// Records a copy of what `from` learned besides Q into this guide: the
    /// share of Q that NEE carries, which its distributions leave out, each
    /// volume's share of BSDF sampling, and what each light brought there.
    pub fn record_copy_learned(&self, rec: &mut Recorder<'_>, from: &SarsaGuide) {
        rec.copy(&from.q_direct, &self.q_direct);
        rec.copy(&from.mix_state, &self.mix_state);
        rec.copy(&from.light_mean, &self.light_mean);
        rec.copy(&from.light_seen, &self.light_seen);
    }

    /// The running means and their counts, as a table built from them binds them.
    pub fn mean_bindings(&self) -> [(u32, &Buffer); 2] {
        [
            (shaders::B_MEAN_Q, &self.q),
            (shaders::B_MEAN_VISITS, &self.visits_total),
        ]
    }

    /// Buffers every kernel that reads or updates the guide binds.
    pub fn bindings(&self) -> [(u32, &Buffer); 16] {
        [
            (shaders::B_Q, &self.q),
            (shaders::B_SECTORS, &self.sectors),
            (shaders::B_SUM, &self.sum),
            (shaders::B_VISITS, &self.visits),
            (shaders::B_VISITS_TOTAL, &self.visits_total),
            (shaders::B_VOLUME_SUMS, &self.volume_sums),
            (shaders::B_DIRECT_SUM, &self.direct_sum),
            (shaders::B_Q_DIRECT, &self.q_direct),
            (shaders::B_MIX_GRAD, &self.mix_grad),
            (shaders::B_MIX_STATE, &self.mix_state),
            (shaders::B_LOOKUP_TRIANGLES, &self.lookup_triangles),
            (shaders::B_LOOKUP_CELLS, &self.lookup_cells),
            (shaders::B_LOOKUP_ITEMS, &self.lookup_items),
            (shaders::B_LIGHT_SUM, &self.light_sum),
            (shaders::B_LIGHT_TRIES, &self.light_tries),
            (shaders::B_LIGHT_POWER, &self.light_power),
        ]
    }

    /// Fills the guide's part of the push constants; `learn` turns updates on.
    pub fn set_params(&self, p: &mut PassParams, learn: bool) {
        self.settings.common.set_params(p, learn);
        p.guide_epsilon = self.settings.epsilon();
        p.volume_count = self.volumes.len() as u32;
        p.flags &= !(shaders::FLAG_LEARN_MIX | shaders::FLAG_GUIDE_LIGHTS)
            & ((1 << shaders::LIGHT_GROUPS_SHIFT) - 1);
        if self.settings.learns_epsilon() {
            p.flags |= shaders::FLAG_LEARN_MIX;
        }
        if self.lights > 0 {
            p.flags |= shaders::FLAG_GUIDE_LIGHTS | self.lights << shaders::LIGHT_GROUPS_SHIFT;
        }
    }

    /// How its update runs: `Invocation` or `Workgroup` (a volume each).
    pub fn update_layout(&self) -> super::Update {
        if self.wide {
            super::Update::Workgroup
        } else {
            super::Update::Invocation
        }
    }

    /// Whether the guide picks NEE's light.
    pub fn chooses_lights(&self) -> bool {
        self.lights > 0
    }

    /// Records the guide update: with FLAG_LEARN in `push`, the pass's
    /// targets folded into Q; then every volume's distribution rebuilt.
    fn record_build(&self, rec: &mut Recorder<'_>, push: &[u8]) {
        // One more for the lights' row by power alone.
        let rows = self.volumes.len() as u32 + 1;
        let groups = if self.wide {
            // A workgroup a row, going on in y past the largest x count.
            let x = rows.min(self.max_groups_x);
            [x, rows.div_ceil(x), 1]
        } else {
            [rows.div_ceil(shaders::LINEAR_GROUP), 1, 1]
        };
        rec.dispatch(Pass {
            name: "guide update",
            pipeline: &self.build,
            set: &self.build_set,
            push,
            groups,
        });
    }

    /// Folds this pass's targets into Q (where `params` asks to learn) and
    /// rebuilds every distribution, in one pass over the volumes.
    pub fn record_update(&self, rec: &mut Recorder<'_>, params: &PassParams) {
        self.record_build(rec, bytemuck::bytes_of(params));
        // The update read the pass's tallies; the next pass that learns
        // starts them from zero (a fill, where the update would zero them
        // word by word and lane by lane on lavapipe).
        if params.flags & shaders::FLAG_LEARN != 0 {
            for (_, tally) in self.tally_bindings() {
                rec.fill(tally, 0);
            }
        }
    }

    /// Folds pending targets and rebuilds the distributions now.
    pub fn fold(&self, ctx: &Arc<GpuContext>) -> gpu::Result<()> {
        let mut params = PassParams::default();
        self.set_params(&mut params, true);
        ctx.submit(None, |rec| self.record_update(rec, &params))
    }

    /// Device memory the guide holds.
    pub fn bytes(&self) -> u64 {
        self.volumes.len() as u64 * table_bytes_per_volume(self.settings.sectors(), self.lights)
            + self.lookup.bytes()
    }

    /// Current Q-values, volume-major.
    pub fn download_q(&self) -> gpu::Result<Vec<f32>> {
        let mut q: Vec<f32> = self.q.download()?;
        q.truncate(self.volumes.len() * self.settings.sectors() as usize);
        Ok(q)
    }

    /// Current sector probabilities P(k), volume-major.
    pub fn download_probabilities(&self) -> gpu::Result<Vec<f32>> {
        let n = self.settings.sectors();
        Ok(self.download_sectors()?.iter().map(|e| e.p(n)).collect())
    }

    /// Each volume's share of BSDF sampling in the mixture.
    pub fn download_bsdf_shares(&self) -> gpu::Result<Vec<f32>> {
        let sums: Vec<[f32; 4]> = self.volume_sums.download()?;
        Ok(sums.iter().take(self.volumes.len()).map(|s| s[2]).collect())
    }

    /// Running means of the share of targets NEE carries, volume-major.
    pub fn download_q_direct(&self) -> gpu::Result<Vec<f32>> {
        let mut q: Vec<f32> = self.q_direct.download()?;
        q.truncate(self.volumes.len() * self.settings.sectors() as usize);
        Ok(q)
    }

    /// Current alias tables, volume-major.
    pub fn download_sectors(&self) -> gpu::Result<Vec<SectorEntry>> {
        let mut entries: Vec<SectorEntry> = self.sectors.download()?;
        entries.truncate(self.volumes.len() * self.settings.sectors() as usize);
        Ok(entries)
    }

    /// NEE's probability of picking each light at each volume, then in the
    /// row by power alone (volume-major); empty where the guide picks none.
    pub fn download_light_choice(&self) -> gpu::Result<Vec<f32>> {
        let entries: Vec<SectorEntry> = self.sectors.download()?;
        let start = self.volumes.len() * self.settings.sectors() as usize;
        let end = start + (self.volumes.len() + 1) * self.lights as usize;
        Ok(entries[start..end]
            .iter()
            .map(|e| e.p(self.lights))
            .collect())
    }

    /// Per (volume, light), volume-major: the running mean of what NEE's
    /// tries of the light brought there, and how many tries.
    pub fn download_light_means(&self) -> gpu::Result<(Vec<f32>, Vec<u32>)> {
        let cells = self.volumes.len() * self.lights as usize;
        let mut means: Vec<f32> = self.light_mean.download()?;
        let mut seen: Vec<u32> = self.light_seen.download()?;
        means.truncate(cells);
        seen.truncate(cells);
        Ok((means, seen))
    }

    /// What the guide has learned, to resume from: Q, the visit counts,
    /// the share NEE carries and the volumes' BSDF shares (the tables are
    /// rebuilt from them).
    pub fn save(&self) -> gpu::Result<Vec<(&'static str, Vec<u8>)>> {
        Ok(vec![
            ("sarsa Q", self.q.download()?),
            ("sarsa visits", self.visits_total.download()?),
            ("sarsa Q carried by NEE", self.q_direct.download()?),
            ("sarsa BSDF shares", self.mix_state.download()?),
            ("sarsa light means", self.light_mean.download()?),
            ("sarsa light tries", self.light_seen.download()?),
        ])
    }

    /// Restores what [`SarsaGuide::save`] gave, then rebuilds the tables.
    pub fn restore(
        &self,
        ctx: &Arc<GpuContext>,
        blobs: &[(String, Vec<u8>)],
    ) -> Result<(), String> {
        for (name, buffer) in [
            ("sarsa Q", &self.q),
            ("sarsa visits", &self.visits_total),
            ("sarsa Q carried by NEE", &self.q_direct),
            ("sarsa BSDF shares", &self.mix_state),
            ("sarsa light means", &self.light_mean),
            ("sarsa light tries", &self.light_seen),
        ] {
            super::restore_blob(buffer, name, blobs)?;
        }
        let mut params = PassParams::default();
        self.set_params(&mut params, false);
        ctx.submit(None, |rec| {
            self.record_build(rec, bytemuck::bytes_of(&params))
        })
        .map_err(|e| e.to_string())
    }

    /// Overwrites the share of Q that NEE carries (tests and tools).
    pub fn upload_q_direct(&self, ctx: &Arc<GpuContext>, q_direct: &[f32]) -> gpu::Result<()> {
        let bytes = std::mem::size_of_val(q_direct) as u64;
        let staging = Buffer::upload(ctx, "sarsa Q direct (staging)", bytes)?;
        staging.write(q_direct);
        ctx.submit(None, |rec| rec.copy(&staging, &self.q_direct))
    }

    /// Overwrites the visits each cell's running mean has counted (tests and tools).
    pub fn upload_visits(&self, ctx: &Arc<GpuContext>, visits: &[u32]) -> gpu::Result<()> {
        let bytes = std::mem::size_of_val(visits) as u64;
        let staging = Buffer::upload(ctx, "sarsa visits (staging)", bytes)?;
        staging.write(visits);
        ctx.submit(None, |rec| rec.copy(&staging, &self.visits_total))
    }

    /// Overwrites Q (tests and tools), then rebuilds the distributions.
    pub fn upload_q(&self, ctx: &Arc<GpuContext>, q: &[f32]) -> gpu::Result<()> {
        let staging = Buffer::upload(ctx, "sarsa Q (staging)", std::mem::size_of_val(q) as u64)?;
        staging.write(q);
        let mut params = PassParams::default();
        self.set_params(&mut params, false);
        ctx.submit(None, |rec| {
            rec.copy(&staging, &self.q);
            self.record_build(rec, bytemuck::bytes_of(&params));
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shaders_find_the_same_column_units_by_float_division() {
        // The shaders take ⌊65535 / n⌋ as uint(65535.0 / float(n)): exact,
        // because a fraction of at least 1 / n stands far above the rounding.
        for n in 1..=64 * 64u32 {
            assert_eq!(
                (65535.0f32 / n as f32) as u32,
                SectorEntry::column_units(n),
                "n = {n}"
            );
        }
    }

    #[test]
    fn default_volume_count_follows_the_image() {
        let s = SarsaSettings::default();
        assert_eq!(s.for_image(256, 256).volumes, Some(1024));
        assert_eq!(s.for_image(128, 128).volumes, Some(256));
        assert_eq!(s.for_image(8, 8).volumes, Some(MIN_DEFAULT_VOLUMES));
        // A count or a density the user gives stays.
        let counted = SarsaSettings {
            volumes: Some(7),
            ..Default::default()
        };
        assert_eq!(counted.for_image(256, 256).volumes, Some(7));
        let dense = SarsaSettings {
            density: Some(0.5),
            ..Default::default()
        };
        assert_eq!(dense.for_image(256, 256).volumes, None);
    }

    #[test]
    fn volume_count_follows_count_density_and_budget() {
        let s = SarsaSettings::default();
        assert_eq!(s.volume_count(1e6, 0), 1024);
        let dense = SarsaSettings {
            density: Some(0.002),
            ..Default::default()
        };
        assert_eq!(dense.volume_count(1e6, 0), 2000);
        let budget = SarsaSettings {
            memory_mib: Some(1.0),
            ..dense.clone()
        };
        let per = bytes_per_volume(144, 0);
        assert_eq!(budget.volume_count(1e6, 0) as u64, (1 << 20) / per);
        let per = bytes_per_volume(144, 6);
        assert_eq!(budget.volume_count(1e6, 6) as u64, (1 << 20) / per);
        assert!(SarsaSettings {
            density: Some(0.0),
            ..Default::default()
        }
        .validate()
        .is_err());
        assert!(SarsaSettings {
            memory_mib: Some(1e-4),
            ..Default::default()
        }
        .validate()
        .is_err());
        assert!(s.validate().is_ok());
    }
}
