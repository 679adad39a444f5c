//! Learned guides: where light comes from, learned while rendering, used to
//! importance-sample bounce directions.
//!
//! One seam: [`GuideSettings`] says which guide and how (a `[sarsa]` or
//! `[neural]` table), [`Guide`] is its state on the device with everything a
//! render asks of it. In the trace kernel the same seam is `glsl/guide.glsl`.

pub mod lookup;
pub mod mlp;
pub mod network;
pub mod neural;
pub mod sarsa;
pub mod volumes;

pub use neural::{NeuralGuide, NeuralSettings};
pub use sarsa::{SarsaGuide, SarsaSettings};

use crate::gpu::{self, Buffer, DeviceInfo, GpuContext, PassTiming, Recorder};
use crate::scene::Scene;
use crate::shaders::{self, PassParams};
use serde::{Deserialize, Serialize};
use std::any::Any;
use std::path::PathBuf;
use std::sync::Arc;

/// What a guide's sampler draws sectors in proportion to.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Distribution {
    /// P(k) ∝ Q(k).
    Q,
    /// P(k) ∝ Q(k) cos θ_k.
    #[default]
    Qcos,
}

/// How the guide update between passes spreads its work over the device.
/// The tables come out the same, bit for bit; only the speed differs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Update {
    /// `workgroup` on a GPU, `invocation` on a CPU device (and where a
    /// table does not fit a workgroup's memory).
    #[default]
    Auto,
    /// One invocation a volume walks its sectors: lavapipe's SIMD lanes
    /// hold eight volumes, where a workgroup's lane 0 would run alone.
    Invocation,
    /// One workgroup a volume, its lanes reading and writing the sectors
    /// side by side: one invocation a volume leaves most of a GPU idle.
    Workgroup,
}

/// Workgroup memory of the update's workgroup a volume, for tables of up
/// to `entries` entries (guide_build.comp, WIDE_UPDATE): five words an
/// entry and the volume's means.
pub fn workgroup_update_bytes(entries: u32) -> u32 {
    20 * entries + 16
}

/// Whether `update` runs a workgroup a volume on a device (`cpu` or not,
/// with `shared` bytes of workgroup memory) for tables of up to `entries`
/// entries; `Err` with the bytes needed where `Workgroup` does not fit.
fn wide_update(update: Update, cpu: bool, shared: u32, entries: u32) -> Result<bool, u32> {
    let bytes = workgroup_update_bytes(entries);
    let fits = bytes <= shared;
    match update {
        Update::Invocation => Ok(false),
        Update::Workgroup if !fits => Err(bytes),
        Update::Workgroup => Ok(true),
        Update::Auto => Ok(fits && !cpu),
    }
}

/// Default share of BSDF sampling where it stays fixed. Measured: 0.5 halved
/// the error of 0.3 on the door-ajar scene (fewer fireflies: the weight per
/// bounce is at most albedo / epsilon) and beat it on the Cornell box and the
/// indirectly lit room.
pub const EPSILON_FIXED: f32 = 0.5;
/// Default start of a share each volume learns: mostly BSDF sampling, since
/// the guide knows nothing yet. Starting at 0.5, a guide that had learned
/// little (the white furnace, where it cannot help) had 11× the error of
/// `pt` at 256 spp; from 0.8–0.95 it has about `pt`'s, and the other shipped
/// scenes are within ±5% of what they had from 0.5.
pub const EPSILON_LEARNED_START: f32 = 0.9;

/// Settings every guide has, beside its own, in its `[sarsa]` or `[neural]` table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Common {
    /// Sector grid a × b over the unit square; n = a·b sectors.
    pub grid: [u32; 2],
    /// Weight of BSDF sampling in the one-sample mixture (keeps every pdf > 0);
    /// where a guide learns it per volume, where it starts. None: the
    /// default of `Common::epsilon`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub epsilon: Option<f32>,
    pub distribution: Distribution,
    /// Stop learning after this many passes (None: learn throughout).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub freeze_after: Option<u32>,
    /// Learn in every pass up to this one, then in every 2nd pass up to
    /// twice it, every 4th up to four times it, and so on (0: every pass).
    /// Sarsa's Q is a running mean, so late passes add little to it, while
    /// a pass that learns costs about 1.5× one that does not: its default is
    /// 16. So is the network's with inference at the volumes (its training
    /// has a schedule of its own, `train_thin_after`); with inference at
    /// every vertex it learns in every pass.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub thin_after: Option<u32>,
    /// Reset the image after this many passes: the earlier passes only train
    /// the guide. Each pass is unbiased, so the image stays unbiased.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reset_after: Option<u32>,
    /// Q of every sector before any update.
    pub initial_q: f32,
    /// The passes left run plain path tracing once the guide is found not to
    /// pay: where each volume learns its share of BSDF sampling, when nearly
    /// every volume has learned to sample the BSDF all it may (see
    /// [`stands_back`]); from pass 16 on, when plain path tracing wins two
    /// races in a row (see `crate::render::race`). None: true.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stand_back: Option<bool>,
    /// Each volume learns which light NEE picks, where the scene has several
    /// (see `sarsa::guided_light_power`). None: true.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pick_lights: Option<bool>,
    /// How the update between passes runs on the device (see [`Update`]).
    pub update: Update,
}

impl Default for Common {
    fn default() -> Self {
        Self {
            grid: [12, 12],
            epsilon: None,
            // Q·cos is the integrand of a diffuse bounce; it beat ∝ Q in MSE.
            distribution: Distribution::Qcos,
            freeze_after: None,
            thin_after: None,
            reset_after: None,
            initial_q: 1e-2,
            stand_back: None,
            pick_lights: None,
            update: Update::Auto,
        }
    }
}

impl Common {
    pub fn sectors(&self) -> u32 {
        self.grid[0] * self.grid[1]
    }

    /// Checks ranges; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        let [a, b] = self.grid;
        if !(1..=64).contains(&a) || !(1..=64).contains(&b) {
            return Err(format!("grid = [{a}, {b}]: each side must lie in 1..=64"));
        }
        if let Some(e) = self.epsilon.filter(|e| !(*e > 0.0 && *e <= 1.0)) {
            return Err(format!(
                "epsilon = {e} must lie in (0, 1]: BSDF sampling keeps every direction possible, so the estimator unbiased"
            ));
        }
        if !(self.initial_q.is_finite() && self.initial_q > 0.0) {
            return Err(format!("initial_q = {} must be positive", self.initial_q));
        }
        experiment(self.reset_after.is_some(), "reset_after")?;
        experiment(self.distribution == Distribution::Q, "distribution = \"q\"")
    }

    /// Whether the update runs a workgroup a volume on `device`, for tables
    /// of up to `entries` entries; an error where `update = "workgroup"`
    /// asks for more workgroup memory than the device has.
    pub fn wide_update(&self, device: &DeviceInfo, entries: u32) -> Result<bool, String> {
        let cpu = device.kind == "CPU";
        wide_update(self.update, cpu, device.max_shared_memory, entries).map_err(|bytes| {
            format!(
                "update = \"workgroup\": a table of {entries} entries needs {} KiB of workgroup memory; device '{}' has {} KiB: use a smaller grid or update = \"invocation\"",
                bytes.div_ceil(1024),
                device.name,
                device.max_shared_memory / 1024
            )
        })
    }

    /// Whether volumes learn which light NEE picks, where there are several.
    pub fn picks_lights(&self) -> bool {
        self.pick_lights.unwrap_or(true)
    }

    /// The share of BSDF sampling: as set, or the default for a share that
    /// stays fixed or (`learned`) one that each volume learns from there.
    pub fn epsilon(&self, learned: bool) -> f32 {
        self.epsilon.unwrap_or(if learned {
            EPSILON_LEARNED_START
        } else {
            EPSILON_FIXED
        })
    }

    /// Whether pass `index` learns, where the guide's `thin_after` default
    /// is `default_thin`.
    pub fn learns_in_pass(&self, index: u32, default_thin: u32) -> bool {
        if self.freeze_after.is_some_and(|k| index >= k) {
            return false;
        }
        thinned(index, self.thin_after.unwrap_or(default_thin))
    }

    /// The push constants every guided kernel reads: the grid, epsilon, and
    /// the learn and distribution flags.
    pub fn set_params(&self, p: &mut PassParams, learn: bool) {
        let [a, b] = self.grid;
        p.sector_grid = a | (b << 16);
        p.guide_epsilon = self.epsilon(false);
        p.flags &= !(shaders::FLAG_LEARN | shaders::FLAG_Q_DISTRIBUTION);
        if learn {
            p.flags |= shaders::FLAG_LEARN;
        }
        if self.distribution == Distribution::Q {
            p.flags |= shaders::FLAG_Q_DISTRIBUTION;
        }
    }
}

/// Refuses a mode measured not to pay (docs/guides.md, "Experiments")
/// unless qtrace was built with the cargo feature `experiments`.
pub(crate) fn experiment(used: bool, what: &str) -> Result<(), String> {
    if used && !cfg!(feature = "experiments") {
        return Err(format!(
            "{what} is an experiment that was measured not to pay (docs/guides.md, \"Experiments\"); it needs qtrace built with `--features experiments`"
        ));
    }
    Ok(())
}

/// A share of BSDF sampling at its cap: the learned share is the sigmoid of
/// a logit bounded by MIX_LOGIT_BOUND (3), so at most 0.9526.
pub const CAPPED_SHARE: f32 = 0.95;

/// The passes after which a guide that may stand back checks whether it
/// should: 4, 8, then every power of two (results stay one per seed
/// whatever the batches).
pub fn stand_back_check(done: u32) -> bool {
    done >= FIRST_CHECK && done.is_power_of_two()
}

/// The first check: four passes, where a white furnace's guide has learned
/// enough to tell (see [`stands_back`]).
pub const FIRST_CHECK: u32 = 4;

/// Whether the learned shares of BSDF sampling (`start`: where they began)
/// say, after `done` passes, that the guide cannot help: at least half of
/// the volumes have learned (moved from the start), and 90% of those sit
/// at the cap. In a white furnace 86-98% of the volumes get there within 8
/// passes (both guides, 32x32 to 256x256; `neural` 93% at 128x128, under
/// the 95% this once asked); on every other shipped scene at most 39% do.
/// At the first check a looser reading (below) already tells a furnace. A
/// guided pass costs about twice a plain one, so the passes left run plain
/// path tracing: each pass stays unbiased, and so does the image.
pub fn stands_back(shares: &[f32], start: f32, done: u32) -> bool {
    let learned: Vec<f32> = shares
        .iter()
        .copied()
        .filter(|&s| (s - start).abs() > 1e-4)
        .collect();
    if 2 * learned.len() < shares.len() || learned.is_empty() {
        return false;
    }
    let capped = learned.iter().filter(|&&s| s >= CAPPED_SHARE).count() as f64;
    let n = learned.len() as f64;
    if done <= FIRST_CHECK {
        // After four passes a furnace's volumes are on their way: 55-72% at
        // the cap, their mean share 0.938-0.945 (both guides, 32x32 and
        // 256x256, from 0.9); on every other shipped scene at most 41% and
        // 0.913. Both must say so.
        let mean = learned.iter().map(|&s| f64::from(s)).sum::<f64>() / n;
        capped >= 0.5 * n && mean >= f64::from(CAPPED_SHARE) - 0.02
    } else {
        capped >= 0.9 * n
    }
}

/// Whether pass `index` falls in a schedule that takes every pass up to
/// `k`, then every 2nd pass up to 2k, every 4th up to 4k, … (k = 0: all).
pub fn thinned(index: u32, k: u32) -> bool {
    if k == 0 || index < k {
        return true;
    }
    // In [k 2^j, k 2^(j+1)), every 2^(j+1)-th pass from its start.
    let j = (index / k).ilog2();
    let start = u64::from(k) << j;
    (u64::from(index) - start) % (2u64 << j) == 0
}

/// What every guide's settings have by being a serde struct: written for
/// all of them at once.
pub trait SettingsBase {
    /// The settings as JSON (stats, render states), floats as written (an
    /// f32 0.3 as 0.3, as `serde_json::to_string` writes it).
    fn to_json(&self) -> serde_json::Value;
    /// The settings as `serde_json::to_value` gives them, each f32 widened
    /// to the f64 nearest it (0.3 as 0.30000001192092896): how render
    /// states have always recorded them, so that a state still resumes.
    fn to_value(&self) -> serde_json::Value;
    /// The settings as their table, every key written out.
    fn to_table(&self) -> toml::Table;
    fn clone_boxed(&self) -> Box<dyn GuideConfig>;
    fn as_any(&self) -> &dyn Any;
}

impl<T: GuideConfig + Serialize + Clone> SettingsBase for T {
    fn to_json(&self) -> serde_json::Value {
        serde_json::to_string(self)
            .and_then(|text| serde_json::from_str(&text))
            .unwrap_or_default()
    }

    fn to_value(&self) -> serde_json::Value {
        serde_json::to_value(self).unwrap_or_default()
    }

    fn to_table(&self) -> toml::Table {
        match toml::Value::try_from(self) {
            Ok(toml::Value::Table(t)) => t,
            _ => unreachable!("guide settings serialize to a table"),
        }
    }

    fn clone_boxed(&self) -> Box<dyn GuideConfig> {
        Box::new(self.clone())
    }

    fn as_any(&self) -> &dyn Any {
        self
    }
}

/// A guide's settings, behind [`GuideSettings`]: its table, its checks, and
/// the trace kernels and device state it builds. Each guide's module
/// implements it for its settings (a serde struct) and lists the guide in
/// [`GUIDES`].
pub trait GuideConfig: SettingsBase + std::fmt::Debug + Send + Sync + 'static {
    /// The method (and table) name.
    fn name(&self) -> &'static str;
    /// The keys every guide has.
    fn common(&self) -> &Common;
    /// Its `thin_after` default (see `Common::thin_after`).
    fn default_thin_after(&self) -> u32;
    /// Whether each volume learns its share of BSDF sampling, which
    /// [`stands_back`] reads.
    fn learns_shares(&self) -> bool;
    /// Checks its own keys' ranges, and that it fits `scene`.
    fn validate(&self, scene: &Scene) -> Result<(), String>;
    /// Checks the guide fits `device`'s memory limits, before building it.
    fn check_device(&self, scene: &Scene, device: &DeviceInfo) -> Result<(), String>;
    /// SPIR-V of its trace kernel on `device`.
    fn trace_spirv(&self, device: &DeviceInfo, nee: bool) -> gpu::Result<&'static [u8]>;
    /// SPIR-V of a trace kernel without the learning code, for the passes
    /// that learn nothing, where the guide has one.
    fn frozen_trace_spirv(&self, nee: bool) -> Option<&'static [u8]>;
    /// These settings for a `width` x `height` image (defaults that follow
    /// the image).
    fn for_image(&self, width: u32, height: u32) -> GuideSettings;
    /// Builds the guide for `scene`, for a render of `pixels` pixels.
    fn build(
        &self,
        ctx: &Arc<GpuContext>,
        scene: &Scene,
        seed: u32,
        pixels: u64,
    ) -> gpu::Result<Guide>;
}

/// A guide: its name, what `--method` says of it, and how its table reads.
pub struct GuideEntry {
    pub name: &'static str,
    pub about: &'static str,
    /// Its settings from its table (missing keys: defaults).
    pub read: fn(toml::Value) -> Result<GuideSettings, toml::de::Error>,
    /// Its settings with every optional key set, `common` among them: the
    /// keys a message on a typo lists.
    pub every_key: fn(Common) -> GuideSettings,
}

/// Every guide. A new guide is its GLSL behind `glsl/guide.glsl`, its module
/// here, and its line in this list (docs/architecture.md, "Adding a guide").
pub const GUIDES: &[GuideEntry] = &[sarsa::GUIDE, neural::GUIDE];

/// The guide named `name`.
pub fn guide_named(name: &str) -> Option<&'static GuideEntry> {
    GUIDES.iter().find(|g| g.name == name)
}

/// The guides' names, for messages ("sarsa, neural").
pub fn guide_names() -> String {
    GUIDES.iter().map(|g| g.name).collect::<Vec<_>>().join(", ")
}

/// Which guide a render uses, and its settings.
pub struct GuideSettings(Box<dyn GuideConfig>);

impl Clone for GuideSettings {
    fn clone(&self) -> Self {
        Self(self.0.clone_boxed())
    }
}

impl std::fmt::Debug for GuideSettings {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.0.fmt(f)
    }
}

impl PartialEq for GuideSettings {
    fn eq(&self, other: &Self) -> bool {
        self.name() == other.name() && self.0.to_json() == other.0.to_json()
    }
}

/// As `{"name": {settings}}`.
impl Serialize for GuideSettings {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut map = s.serialize_map(Some(1))?;
        map.serialize_entry(self.name(), &self.0.to_json())?;
        map.end()
    }
}

impl std::ops::Deref for GuideSettings {
    type Target = dyn GuideConfig;
    fn deref(&self) -> &Self::Target {
        self.0.as_ref()
    }
}

impl<T: GuideConfig> From<T> for GuideSettings {
    fn from(settings: T) -> Self {
        Self(Box::new(settings))
    }
}

impl GuideSettings {
    /// As render states record them: `{"name": {settings}}`, by
    /// `SettingsBase::to_value`.
    pub fn state_value(&self) -> serde_json::Value {
        serde_json::json!({ self.name(): self.0.to_value() })
    }

    /// The settings of guide `T`'s type, if these are its.
    pub fn downcast<T: GuideConfig>(&self) -> Option<&T> {
        self.0.as_any().downcast_ref()
    }

    /// Whether the guide learns in pass `index` (see `Common::thin_after`).
    pub fn learns_in_pass(&self, index: u32) -> bool {
        self.common()
            .learns_in_pass(index, self.default_thin_after())
    }

    /// Whether the guide may stand back (see `Common::stand_back`).
    pub fn may_stand_back(&self) -> bool {
        self.common().stand_back.unwrap_or(true)
    }

    /// The guide `name`'s settings from its table (keys missing: defaults).
    pub fn from_table(name: &str, table: &toml::Table) -> Result<Self, String> {
        let Some(guide) = guide_named(name) else {
            return Err(format!(
                "no guide named '{name}' (guides: {})",
                guide_names()
            ));
        };
        (guide.read)(toml::Value::Table(table.clone())).map_err(|e| {
            // Every key, optional ones included, for the message on a typo.
            let common = Common {
                freeze_after: Some(0),
                thin_after: Some(0),
                reset_after: Some(0),
                stand_back: Some(true),
                pick_lights: Some(true),
                ..Default::default()
            };
            let all = (guide.every_key)(common).to_table();
            let keys: Vec<String> = all.keys().cloned().collect();
            format!("[{name}] {} (keys: {})", e.message(), keys.join(", "))
        })
    }

    /// Checks ranges, and that the guide fits `scene`; the message names the table and key.
    pub fn validate(&self, scene: &Scene) -> Result<(), String> {
        let checked = self
            .common()
            .validate()
            .and_then(|()| self.0.validate(scene));
        checked.map_err(|e| format!("[{}] {e}", self.name()))
    }
}

/// Where guide settings come from besides the scene's own tables: a file
/// of `[sarsa]` / `[neural]` tables, then `guide.key=value` assignments.
#[derive(Clone, Debug, Default)]
pub struct GuideSources {
    pub config: Option<PathBuf>,
    pub sets: Vec<String>,
}

impl GuideSources {
    /// Refuses a `--set` for a guide none of `methods` uses: it would
    /// change nothing, which is surely not what was meant.
    pub fn check_used(&self, methods: &[&str]) -> Result<(), String> {
        for set in &self.sets {
            let guide = set.split_once('.').map_or("", |(g, _)| g.trim());
            if guide_named(guide).is_some() && !methods.contains(&guide) {
                let methods = methods.join(", ");
                return Err(format!(
                    "--set '{set}' sets the {guide} guide, but the method is {methods}"
                ));
            }
        }
        Ok(())
    }

    /// The settings of the guide of method `method` (None for a method
    /// without one): the scene's table, then the config file's, then the
    /// assignments, key by key.
    pub fn resolve(&self, scene: &Scene, method: &str) -> Result<Option<GuideSettings>, String> {
        let mut tables: Vec<(String, toml::Table)> = GUIDES
            .iter()
            .map(|g| (g.name.to_string(), scene.guide_table(g.name).clone()))
            .collect();
        if let Some(path) = &self.config {
            let text = std::fs::read_to_string(path)
                .map_err(|e| format!("{}: cannot read the guide config: {e}", path.display()))?;
            let file: toml::Table = toml::from_str(&text)
                .map_err(|e| format!("{}: {}", path.display(), e.message()))?;
            for (name, value) in file {
                let (Some((_, table)), toml::Value::Table(given)) =
                    (tables.iter_mut().find(|(n, _)| *n == name), value)
                else {
                    return Err(format!(
                        "{}: '{name}' is not a guide table (guides: {})",
                        path.display(),
                        guide_names()
                    ));
                };
                table.extend(given);
            }
        }
        for set in &self.sets {
            let malformed = || format!("--set '{set}' is not guide.key=value");
            let (key, value) = set.split_once('=').ok_or_else(malformed)?;
            let (guide, key) = key.trim().split_once('.').ok_or_else(malformed)?;
            let Some((_, table)) = tables.iter_mut().find(|(n, _)| n == guide) else {
                return Err(format!(
                    "--set '{set}': no guide named '{guide}' (guides: {})",
                    guide_names()
                ));
            };
            // Another method's guide: check_used says whether any method uses it.
            if guide == method {
                table.insert(key.to_string(), parse_value(value.trim()));
            }
        }
        match tables.iter().find(|(n, _)| n == method) {
            Some((_, table)) => GuideSettings::from_table(method, table).map(Some),
            None => Ok(None),
        }
    }
}

/// A TOML value as written (`0.3`, `[8, 8]`, `true`), else the text as a
/// string (`cas`, `qcos`).
fn parse_value(text: &str) -> toml::Value {
    toml::from_str::<toml::Table>(&format!("v = {text}"))
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(text.to_string()))
}

/// Overwrites `buffer` with the blob `name` of a saved state, which must
/// have its size.
fn restore_blob(buffer: &Buffer, name: &str, blobs: &[(String, Vec<u8>)]) -> Result<(), String> {
    let (_, bytes) = blobs
        .iter()
        .find(|(n, _)| n == name)
        .ok_or_else(|| format!("the state lacks {name}"))?;
    if bytes.len() as u64 != buffer.size() {
        return Err(format!(
            "the state's {name} holds {} bytes, this guide's {}",
            bytes.len(),
            buffer.size()
        ));
    }
    buffer.overwrite(bytes).map_err(|e| e.to_string())
}

/// Any guide as `Any`, for a downcast to its own type.
pub trait AsAny {
    fn as_any(&self) -> &dyn Any;
}

impl<T: DeviceGuide> AsAny for T {
    fn as_any(&self) -> &dyn Any {
        self
    }
}

/// A guide's state on the device and the passes it adds to a render:
/// everything the renderer asks of a guide.
pub trait DeviceGuide: AsAny + Any {
    /// Whether its trace kernels pick NEE's light (the CONSTANT_GUIDE_LIGHTS
    /// specialization constant).
    fn chooses_lights(&self) -> bool;
    /// Specialization constants of its trace kernel.
    fn constants(&self) -> Vec<u32>;
    /// The radiance volumes' tables it samples from, if it samples from them.
    fn volume_table(&self) -> Option<&SarsaGuide>;
    /// Buffers its trace kernel binds.
    fn bindings(&self) -> Vec<(u32, &Buffer)>;
    /// Fills its part of a pass's push constants; `learn` turns updates on.
    fn set_params(&self, p: &mut PassParams, learn: bool);
    /// Records what turns a learning pass's transitions into the guide the
    /// next pass samples from.
    fn record_update(&mut self, rec: &mut Recorder<'_>, params: &PassParams);
    /// After a render's first pass, given the GPU time of each pass name
    /// in it: a guide that sizes its work by what the device measured
    /// sizes it, and says how.
    fn fit_to_device(&mut self, _timings: &[PassTiming]) -> Option<DeviceFit> {
        None
    }
    /// A resumed render's fit, as `fit_to_device` made it.
    fn refit(&mut self, _fit: &DeviceFit) {}
    /// Device memory it holds.
    fn bytes(&self) -> u64;
    /// What the guide has learned, as named blobs, to resume from.
    fn save(&self) -> gpu::Result<Vec<(&'static str, Vec<u8>)>>;
    /// Restores what `save` gave, for a render with or without NEE.
    fn restore(
        &mut self,
        ctx: &Arc<GpuContext>,
        blobs: &[(String, Vec<u8>)],
        nee: bool,
    ) -> Result<(), String>;
    /// Radiance volumes, else 0.
    fn volume_count(&self) -> u64;
    /// Its sector grid.
    fn grid(&self) -> [u32; 2];
    /// Q of every sector at up to `count` places near the scene's brightest
    /// light, for the bench's pictures, and words on where they are.
    fn sample_rows(
        &self,
        ctx: &Arc<GpuContext>,
        scene: &Scene,
        count: usize,
    ) -> Result<(Vec<Vec<f32>>, String), crate::render::RenderError>;
}

/// A guide on the device.
pub type Guide = Box<dyn DeviceGuide>;

/// How a guide sized its work to the device in a render's first pass:
/// Neural-Q's training steps per pass that trains, from what a step and a
/// trace pass cost there (`neural::fitted_steps`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DeviceFit {
    pub training_steps: u32,
    /// GPU milliseconds of one training step, and of the first trace pass.
    pub step_ms: f64,
    pub pass_ms: f64,
}

impl dyn DeviceGuide {
    /// The guide as its own type, if it is `T`.
    pub fn downcast<T: DeviceGuide>(&self) -> Option<&T> {
        self.as_any().downcast_ref()
    }

    /// Each volume's learned share of BSDF sampling, where it learns one.
    pub fn bsdf_shares(&self) -> gpu::Result<Option<Vec<f32>>> {
        self.volume_table()
            .map(|t| t.download_bsdf_shares())
            .transpose()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn guides_stand_back_when_nearly_every_learned_share_is_capped() {
        // The cap: the sigmoid of the logit's bound, 3.
        assert!(1.0 / (1.0 + (-3.0f32).exp()) > CAPPED_SHARE);
        let (start, done) = (0.9, 8);
        let mut shares = vec![0.9526; 200];
        assert!(stands_back(&shares, start, done));
        // Volumes that never learned (still at the start) do not count ...
        shares.extend([start; 100]);
        assert!(stands_back(&shares, start, done));
        // ... unless they are most of them.
        shares.extend([start; 200]);
        assert!(!stands_back(&shares, start, done));
        // One learned volume in ten that trusts the guide keeps it.
        let mut some = vec![0.9526; 179];
        some.extend([0.4; 21]);
        assert!(!stands_back(&some, start, done));
        some.truncate(195);
        assert!(stands_back(&some, start, done));
        assert!(!stands_back(&[], start, done));
        assert!(!stands_back(&[start; 10], start, done));
    }

    /// At the first check, half the learned volumes at the cap will do, if
    /// the learned shares' mean is within 0.02 of it too.
    #[test]
    fn the_first_check_reads_the_shares_on_their_way() {
        let (start, first) = (0.9, FIRST_CHECK);
        // A furnace after four passes: 60% capped, the rest close behind.
        let mut furnace = vec![0.9526; 60];
        furnace.extend([0.925; 40]);
        assert!(stands_back(&furnace, start, first));
        assert!(!stands_back(&furnace, start, 2 * first));
        // As many capped, but the rest trusting the guide: the mean says no.
        let mut split = vec![0.9526; 60];
        split.extend([0.8; 40]);
        assert!(!stands_back(&split, start, first));
        // A high mean with too few at the cap says no too.
        let mut near = vec![0.9526; 40];
        near.extend([0.945; 60]);
        assert!(!stands_back(&near, start, first));
    }

    #[test]
    fn stand_back_checks_fall_on_fixed_passes() {
        let checks: Vec<u32> = (0..300).filter(|&d| stand_back_check(d)).collect();
        assert_eq!(checks, [4, 8, 16, 32, 64, 128, 256]);
    }

    #[test]
    fn learning_thins_out_after_thin_after_passes() {
        let common = |thin_after, freeze_after| Common {
            thin_after: Some(thin_after),
            freeze_after,
            ..Default::default()
        };
        let learning = |c: &Common, n: u32| {
            (0..n)
                .filter(|&i| c.learns_in_pass(i, 99))
                .collect::<Vec<_>>()
        };
        assert_eq!(
            learning(&common(4, None), 40),
            [0, 1, 2, 3, 4, 6, 8, 12, 16, 24, 32]
        );
        assert_eq!(learning(&common(0, None), 5), [0, 1, 2, 3, 4]);
        assert_eq!(learning(&common(4, Some(7)), 40), [0, 1, 2, 3, 4, 6]);
        assert_eq!(learning(&common(1, None), 9), [0, 1, 2, 4, 8]);
        // No overflow at the end of the pass counter.
        assert!(common(1, None).learns_in_pass(1 << 31, 99));
        assert!(!common(1, None).learns_in_pass(u32::MAX, 99));
        // Unset, the guide's default holds.
        let unset = Common::default();
        assert!(unset.learns_in_pass(20, 0) && !unset.learns_in_pass(17, 16));
    }

    #[test]
    fn the_update_runs_a_workgroup_a_volume_on_gpus_where_it_fits() {
        // 144 sectors take 2,896 bytes; 4096 take 81,936.
        assert_eq!(wide_update(Update::Auto, false, 49152, 144), Ok(true));
        assert_eq!(wide_update(Update::Auto, true, 32768, 144), Ok(false));
        assert_eq!(wide_update(Update::Auto, false, 49152, 4096), Ok(false));
        assert_eq!(wide_update(Update::Workgroup, true, 32768, 144), Ok(true));
        assert_eq!(
            wide_update(Update::Workgroup, false, 49152, 4096),
            Err(81936)
        );
        assert_eq!(wide_update(Update::Invocation, false, 49152, 16), Ok(false));
    }

    #[test]
    fn settings_round_trip_through_their_tables() {
        let sarsa = GuideSettings::from(SarsaSettings {
            common: Common {
                grid: [6, 8],
                epsilon: Some(0.25),
                distribution: Distribution::Q,
                freeze_after: Some(3),
                thin_after: Some(5),
                reset_after: Some(2),
                initial_q: 0.5,
                stand_back: Some(false),
                pick_lights: Some(false),
                update: Update::Workgroup,
            },
            volumes: Some(77),
            density: None,
            memory_mib: Some(3.5),
            atomics: sarsa::Atomics::Cas,
            learn_epsilon: Some(false),
        });
        let neural = GuideSettings::from(NeuralSettings {
            width: 8,
            layers: 3,
            learning_rate: Some(1e-3),
            batch: Some(100),
            steps: Some(2),
            target: neural::Target::Max,
            encoding: neural::Encoding::Vertices,
            inference: neural::Inference::Volumes,
            training: Some(neural::Training::Volumes),
            volumes: Some(99),
            ..Default::default()
        });
        for g in [sarsa, neural] {
            let text = toml::to_string(&g.to_table()).unwrap();
            let back = GuideSettings::from_table(g.name(), &toml::from_str(&text).unwrap());
            assert_eq!(back.as_ref(), Ok(&g), "{text}");
        }
    }

    /// Render states record settings as earlier builds did (each f32
    /// widened), so that their states still resume; stats write them as
    /// given.
    #[test]
    fn states_record_settings_as_before() {
        let g = GuideSettings::from(SarsaSettings::default());
        let state = g.state_value();
        assert_eq!(state["sarsa"]["initial_q"], f64::from(1e-2f32));
        let stats = serde_json::to_string(&g).unwrap();
        assert!(stats.contains("\"initial_q\":0.01"), "{stats}");
    }

    /// The modes measured not to pay need the `experiments` feature.
    #[test]
    fn experiments_need_their_feature() {
        let q = Common {
            distribution: Distribution::Q,
            ..Default::default()
        };
        let reset = Common {
            reset_after: Some(4),
            ..Default::default()
        };
        let max = NeuralSettings {
            target: neural::Target::Max,
            ..Default::default()
        };
        let built = cfg!(feature = "experiments");
        for result in [q.validate(), reset.validate(), max.validate()] {
            match result {
                Err(e) => assert!(!built && e.contains("--features experiments"), "{e}"),
                Ok(()) => assert!(built, "an experiment passed without its feature"),
            }
        }
        assert!(Common::default().validate().is_ok());
    }

    #[test]
    fn epsilon_defaults_to_a_fixed_share_or_a_learned_start() {
        let unset = Common::default();
        assert_eq!(unset.epsilon(false), EPSILON_FIXED);
        assert_eq!(unset.epsilon(true), EPSILON_LEARNED_START);
        let set = Common {
            epsilon: Some(0.3),
            ..Default::default()
        };
        assert_eq!((set.epsilon(false), set.epsilon(true)), (0.3, 0.3));
        // Sarsa learns its share unless told not to, and so do the
        // network's tables where it trains on their means.
        let sarsa = SarsaSettings::default();
        assert_eq!(sarsa.epsilon(), EPSILON_LEARNED_START);
        let fixed = SarsaSettings {
            learn_epsilon: Some(false),
            ..Default::default()
        };
        assert_eq!(fixed.epsilon(), EPSILON_FIXED);
        assert_eq!(
            NeuralSettings::default().table().epsilon(),
            EPSILON_LEARNED_START
        );
        let on_transitions = NeuralSettings {
            training: Some(neural::Training::Transitions),
            ..Default::default()
        };
        assert!(!on_transitions.learns_epsilon());
        assert_eq!(on_transitions.table().epsilon(), EPSILON_FIXED);
        // Unset, it stays out of a saved table, so the default follows the mode.
        let table = GuideSettings::from(sarsa).to_table();
        assert!(!table.contains_key("epsilon"), "{table:?}");
    }

    #[test]
    fn tables_name_their_mistakes() {
        let table = |text: &str| toml::from_str::<toml::Table>(text).unwrap();
        let e = GuideSettings::from_table("sarsa", &table("epsilom = 0.2")).unwrap_err();
        assert!(
            e.contains("[sarsa]") && e.contains("epsilom") && e.contains("keys: "),
            "{e}"
        );
        // The message lists every key, optional ones included.
        for key in [
            "thin_after",
            "freeze_after",
            "reset_after",
            "learn_epsilon",
            "memory_mib",
        ] {
            assert!(e.contains(key), "{key} missing from: {e}");
        }
        let e = GuideSettings::from_table("neural", &table("width = \"wide\"")).unwrap_err();
        assert!(e.contains("[neural]"), "{e}");
        for key in [
            "thin_after",
            "learning_rate",
            "steps",
            "training",
            "batch",
            "volumes",
        ] {
            assert!(e.contains(key), "{key} missing from: {e}");
        }
        // Missing keys take the defaults, shared ones included.
        let g = GuideSettings::from_table("neural", &table("epsilon = 0.75")).unwrap();
        assert_eq!(g.common().epsilon(true), 0.75);
        assert_eq!(g.common().grid, Common::default().grid);
    }
}
