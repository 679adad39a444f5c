//! Neural-Q guiding (docs/guides.md): an MLP maps the encoded state (position,
//! normal) to the Q of every hemisphere sector. The trace kernel infers it at
//! each path vertex and samples from it, or (`inference = "volumes"`) samples
//! from tables the network's Q at the radiance volumes fills after each
//! pass that trains; either way it offers its transitions to a batch the
//! network trains on after the pass.

use super::mlp::{Adam, MlpShape};
use super::network::{Network, STEP_PASSES};
use super::sarsa::{self, SarsaGuide, SarsaSettings};
use super::{Common, DeviceFit, DeviceGuide, Guide, GuideConfig, GuideEntry, GuideSettings};
use crate::bench::learned;
use crate::gpu::{
    self, Buffer, ComputePipeline, DescriptorSet, DeviceInfo, GpuContext, Pass, PassTiming,
    Recorder,
};
use crate::render::RenderError;
use crate::scene::Scene;
use crate::shaders::{self, spirv, PassParams};
use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// The bootstrap term of a transition's target.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Target {
    /// (2π/n) Σ_j Q̂(y)_j f_s cos θ_j: the rendering equation's (Expected Sarsa) form.
    #[default]
    Expected,
    /// max_j Q̂(y)_j f_s cos θ_j: deep Q-learning (thesis Eq. 3.7).
    Max,
}

/// How a path vertex's state becomes the network's input.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Encoding {
    /// Position in the scene's box and sin/cos of it at a few octaves, and the normal.
    #[default]
    Frequency,
    /// Every scene vertex relative to the point, and the normal (the
    /// thesis's; for scenes of a few dozen vertices).
    Vertices,
}

/// Where the network is evaluated for sampling.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Inference {
    /// At every path vertex.
    Vertices,
    /// Once per training pass at each radiance volume's point and normal,
    /// into tables paths sample from as Sarsa's do (nearest volume): one
    /// table read per vertex instead of one inference. Measured on the
    /// indirectly lit room at 256×256 and 256 spp: the same error as at
    /// the vertices (relMSE 0.124 against 0.120) at an eighth of the cost.
    #[default]
    Volumes,
}

/// What the network trains on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Training {
    /// Each path offers one of its transitions, at its own point and normal.
    #[default]
    Transitions,
    /// Every transition's TD target is tallied at its nearest volume and
    /// sector (as Sarsa tallies its own), folded into running means, and
    /// each training step draws rows from those means: a volume's state,
    /// a sector, the mean target. Needs `inference = "volumes"`.
    Volumes,
}

/// The `[neural]` table. The network has one output per sector of the grid.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NeuralSettings {
    #[serde(flatten)]
    pub common: Common,
    /// Units per hidden layer.
    pub width: u32,
    /// Hidden layers.
    pub layers: u32,
    /// Adam's learning rate; None: the training mode's default (see
    /// [`NeuralSettings::learning_rate`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub learning_rate: Option<f32>,
    /// Training transitions per pass (the batch's capacity); None: one per
    /// PIXELS_PER_TRANSITION pixels of the image, within
    /// MIN_DEFAULT_BATCH..=DEFAULT_BATCH, so training keeps its share of a
    /// pass at any image size.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub batch: Option<u32>,
    /// Training steps in each pass that trains; None: the training mode's
    /// default, which training on the volumes' means sizes by what a step
    /// and a pass cost on the device (see [`fitted_steps`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub steps: Option<u32>,
    pub target: Target,
    pub encoding: Encoding,
    pub inference: Inference,
    /// None: on the volumes' means where inference is at the volumes, else
    /// on transitions (see [`NeuralSettings::training`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub training: Option<Training>,
    /// With inference at the volumes and training on their means: the
    /// tables hold (N mean + m Q̂) / (N + m), where a cell's running mean of
    /// N targets outweighs the network's Q̂ once N passes m (`inf`: the
    /// network alone). The network is the prior of cells paths seldom reach.
    pub prior_visits: f32,
    /// With training on the volumes' means: of the passes that learn (whose
    /// tallies feed the means), those that also train the network: every
    /// one up to this pass, then ever more rarely (as `thin_after`).
    /// Training takes `steps` dispatches a pass; the tallies cost far less.
    pub train_thin_after: u32,
    /// With training on the volumes' means: whether each volume learns its
    /// share of BSDF sampling from the tallies, as Sarsa's do (None: yes).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub learn_epsilon: Option<bool>,
    /// Radiance volumes for `inference = "volumes"`; None: as Sarsa's
    /// default, one per `sarsa::PIXELS_PER_VOLUME` pixels of the image.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub volumes: Option<u32>,
}

impl Default for NeuralSettings {
    fn default() -> Self {
        Self {
            common: Common::default(),
            // Measured at 256 spp with 128-row steps on the volumes' means:
            // 32 units cut relMSE by 11-19% on six of the eight shipped
            // scenes at 128x128 (the room at 256x256: 0.025 -> 0.0215) for
            // a few percent more time; 64 gave 0.0205 for 30% more.
            width: 32,
            layers: 2,
            learning_rate: None,
            batch: None,
            steps: None,
            target: Target::Expected,
            encoding: Encoding::Frequency,
            inference: Inference::Volumes,
            training: None,
            // Measured on the indirectly lit room at 128x128, 256 spp
            // (relMSE): the network alone 0.040, the means alone 0.026,
            // m = 1: 0.023, 4: 0.023, 16: 0.024, 64: 0.028.
            prior_visits: 4.0,
            train_thin_after: 4,
            learn_epsilon: None,
            volumes: None,
        }
    }
}

const _: () = assert!(
    shaders::ENCODED_INPUTS >= 6 + 6 * shaders::ENCODING_FREQUENCIES
        && shaders::ENCODED_INPUTS % 4 == 0
);

/// The batch of a render with no `batch` given: one transition per this many
/// pixels (4096 at 256×256). Measured on the indirectly lit room at
/// 128×128 and 256 spp: 1024 instead of 4096 took 3.4 s instead of 4.6 s
/// for relMSE 0.149 instead of 0.133.
pub const PIXELS_PER_TRANSITION: u64 = 16;
/// Training on the volumes' means, the default rows per step, and one step
/// per this many pixels of the image (16 at 256×256), at least
/// MIN_DEFAULT_STEPS. Small steps, many of them: on the indirectly lit room
/// at 256×256, 256 spp (relMSE at equal samples / at `pt`'s time, `pt`
/// 0.199), 1024 rows × 8 steps gave 0.035 / 0.089–0.105, 128 × 32 gave
/// 0.025 / 0.057, 128 × 64 0.023 / 0.058, 64 × 64 0.025 / 0.066. At
/// 128×128, where a pass costs a quarter, 32 steps cost more than they gain
/// (room 0.227 at `pt`'s time against 0.095 with 8). Since the tables blend
/// the means with the network, half as many steps do as well: room at
/// 256×256 0.0140 with 16 against 0.0142 with 32; at 128×128 with 4
/// instead of 8, 0.96–1.03× on four scenes.
pub const VOLUME_ROWS: u32 = 128;
pub const PIXELS_PER_STEP: u64 = 4096;
pub const MIN_DEFAULT_STEPS: u64 = 4;
/// Most training steps a pass may take.
pub const MAX_STEPS: u32 = 64;
/// With `steps` unset, training on the volumes' means: the GPU time a pass
/// that trains spends on its steps, as a share of a trace pass's, measured
/// on the device in the render's first pass (see [`fitted_steps`]). Half:
/// on an NVIDIA H200 at 1024×1024 a step costs about a whole pass (0.45 ms
/// against 0.5-0.8), so it trains 4 steps instead of the image's 64, where
/// 4 measured better (docs/notebook.md, "On a GPU"); on lavapipe at
/// 256×256 half a pass holds 0.8 to 4.0 times the image's 16 steps on every
/// shipped scene, with NEE or without, so they keep 16.
pub const TRAINING_SHARE: f64 = 0.5;
/// Training steps per pass that trains on a device where a trace pass takes
/// `pass_ms` of GPU time and a training step `step_ms`, for a render whose
/// first pass trained `first` (`NeuralSettings::first_steps`): `first`
/// where TRAINING_SHARE of the pass holds between an eighth of that and
/// eight times it, else that share to the nearest power of two within
/// MIN_DEFAULT_STEPS..=MAX_STEPS; None where the times say nothing (no
/// timestamps, or too coarse ones). The margin keeps a render reproducible
/// (one image per seed) where the image's count is near enough: one
/// measurement swings by a third.
pub fn fitted_steps(pass_ms: f64, step_ms: f64, first: u32) -> Option<u32> {
    let fits = |ms: f64| ms.is_finite() && ms > 0.0;
    if !fits(pass_ms) || !fits(step_ms) {
        return None;
    }
    let steps = TRAINING_SHARE * pass_ms / step_ms;
    if (0.125..=8.0).contains(&(steps / first as f64)) {
        return Some(first);
    }
    let power = steps.max(1.0).log2().round().min(MAX_STEPS.ilog2() as f64);
    Some((1u32 << power as u32).clamp(MIN_DEFAULT_STEPS as u32, MAX_STEPS))
}

/// The default batch's bounds, and the batch of a guide made outside a render.
pub const MIN_DEFAULT_BATCH: u32 = 256;
pub const DEFAULT_BATCH: u32 = 4096;

/// Largest training batch: its activations must fit one storage buffer.
pub const MAX_BATCH: u32 = 1 << 18;

impl NeuralSettings {
    pub fn sectors(&self) -> u32 {
        self.common.sectors()
    }

    /// The settings of the volumes and tables `inference = "volumes"` samples from.
    pub fn table(&self) -> SarsaSettings {
        SarsaSettings {
            common: self.common.clone(),
            volumes: self.volumes,
            learn_epsilon: Some(self.learns_epsilon()),
            ..Default::default()
        }
    }

    /// Whether the volumes learn their share of BSDF sampling: from the
    /// tallies of the target means, so only when training on them.
    pub fn learns_epsilon(&self) -> bool {
        self.training() == Training::Volumes && self.learn_epsilon.unwrap_or(true)
    }

    /// Whether a pass that learns (`index`) also trains the network, where
    /// it trains on the volumes' means (see `train_thin_after`).
    pub fn trains_in_pass(&self, index: u32) -> bool {
        super::thinned(index, self.train_thin_after)
    }

    /// How the network trains: as given, or on the volumes' means where
    /// inference is at the volumes (which it needs), else on transitions.
    pub fn training(&self) -> Training {
        self.training.unwrap_or(match self.inference {
            Inference::Volumes => Training::Volumes,
            Inference::Vertices => Training::Transitions,
        })
    }

    /// Training steps per pass that trains: as given, or the mode's default
    /// outside a render (on the volumes' means 8, which a render sizes: see
    /// [`NeuralSettings::first_steps`]). On transitions, one step (training
    /// is most of such a pass).
    pub fn steps(&self) -> u32 {
        self.steps.unwrap_or(match self.training() {
            Training::Volumes => 8,
            Training::Transitions => 1,
        })
    }

    /// Training steps of a render of `pixels` pixels until the device's
    /// costs are measured: as given, or on the volumes' means one per
    /// PIXELS_PER_STEP pixels (a trace pass on lavapipe costs in proportion
    /// to its pixels, a step does not).
    pub fn first_steps(&self, pixels: u64) -> u32 {
        match (self.steps, self.training()) {
            (None, Training::Volumes) => {
                (pixels / PIXELS_PER_STEP).clamp(MIN_DEFAULT_STEPS, MAX_STEPS as u64) as u32
            }
            _ => self.steps(),
        }
    }

    /// Whether a render sizes the training steps by their measured cost:
    /// `steps` unset, training on the volumes' means.
    pub fn fits_steps(&self) -> bool {
        self.steps.is_none() && self.training() == Training::Volumes
    }

    /// Adam's learning rate: as given, or the training mode's default (the
    /// volumes' means are far less noisy targets than single transitions).
    pub fn learning_rate(&self) -> f32 {
        self.learning_rate.unwrap_or(match self.training() {
            Training::Volumes => 0.04,
            Training::Transitions => 5e-3,
        })
    }

    /// The batch's capacity: rows per training step.
    pub fn batch(&self) -> u32 {
        self.batch.unwrap_or(match self.training() {
            Training::Volumes => VOLUME_ROWS,
            Training::Transitions => DEFAULT_BATCH,
        })
    }

    /// These settings for a `width` × `height` image: the default batch,
    /// and with inference at the volumes their default count, follow the
    /// image (the steps follow the device: see [`fitted_steps`]).
    pub fn for_image(&self, width: u32, height: u32) -> Self {
        let mut s = self.clone();
        let pixels = width as u64 * height as u64;
        let volumes = s.training() == Training::Volumes;
        if s.batch.is_none() {
            let batch = if volumes {
                VOLUME_ROWS as u64
            } else {
                (pixels / PIXELS_PER_TRANSITION)
                    .clamp(MIN_DEFAULT_BATCH as u64, DEFAULT_BATCH as u64)
            };
            s.batch = Some(batch as u32);
        }
        if s.inference == Inference::Volumes {
            s.volumes = s.table().for_image(width, height).volumes;
        }
        s
    }

    /// The network for the frequency encoding.
    pub fn shape(&self) -> MlpShape {
        self.shape_with_inputs(shaders::ENCODED_INPUTS)
    }

    /// The network for this encoding in `scene`.
    pub fn shape_for(&self, scene: &Scene) -> MlpShape {
        match self.encoding {
            Encoding::Frequency => self.shape(),
            Encoding::Vertices => self.shape_with_inputs(
                (3 * scene_vertices(scene).len() as u32 + 3).next_multiple_of(4),
            ),
        }
    }

    /// Checks the network this encoding needs in `scene` fits the shaders.
    pub fn validate_for(&self, scene: &Scene) -> Result<(), String> {
        let shape = self.shape_for(scene);
        shape.validate().map_err(|e| match self.encoding {
            Encoding::Frequency => e,
            Encoding::Vertices => {
                let widest = (4..=self.width)
                    .rev()
                    .step_by(4)
                    .find(|&width| MlpShape { width, ..shape }.validate().is_ok());
                let hint = match widest {
                    Some(w) => format!("; width = {w} would fit"),
                    None => String::new(),
                };
                format!(
                    "encoding = \"vertices\": the scene's {} vertices give {} inputs, too many: {e}{hint}",
                    scene_vertices(scene).len(),
                    shape.inputs
                )
            }
        })
    }

    fn shape_with_inputs(&self, inputs: u32) -> MlpShape {
        MlpShape {
            inputs,
            width: self.width,
            hidden: self.layers,
            outputs: self.sectors(),
        }
    }

    /// Checks the ranges of the network's own keys (`Common::validate`
    /// checks the rest); the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        if !(4..=64).contains(&self.width) || self.width % 4 != 0 {
            return Err(format!(
                "width = {} must be a multiple of 4 in 4..=64",
                self.width
            ));
        }
        if !(1..=8).contains(&self.layers) {
            return Err(format!("layers = {} must lie in 1..=8", self.layers));
        }
        let learning_rate = self.learning_rate();
        if !(learning_rate.is_finite() && learning_rate > 0.0 && learning_rate <= 1.0) {
            return Err(format!(
                "learning_rate = {learning_rate} must lie in (0, 1]"
            ));
        }
        if let Some(b) = self.batch.filter(|b| !(1..=MAX_BATCH).contains(b)) {
            return Err(format!("batch = {b} must lie in 1..={MAX_BATCH}"));
        }
        if !(1..=MAX_STEPS).contains(&self.steps()) {
            return Err(format!(
                "steps = {} must lie in 1..={MAX_STEPS}",
                self.steps()
            ));
        }
        self.table().validate()?;
        if self.prior_visits.is_nan() || self.prior_visits < 0.0 {
            return Err(format!(
                "prior_visits = {} must be at least 0 (inf: the network alone)",
                self.prior_visits
            ));
        }
        if self.training() == Training::Volumes && self.inference != Inference::Volumes {
            return Err("training = \"volumes\" needs inference = \"volumes\"".into());
        }
        super::experiment(self.target == Target::Max, "target = \"max\"")?;
        super::experiment(
            self.encoding == Encoding::Vertices,
            "encoding = \"vertices\"",
        )?;
        self.shape().validate()
    }

    /// Checks the network for `scene` fits `device`: its workgroup memory,
    /// and the batch's largest buffer (the activations; deltas match them).
    pub fn check_device(&self, scene: &Scene, device: &DeviceInfo) -> Result<(), String> {
        let shape = self.shape_for(scene);
        if shape.workgroup_bytes() > device.max_shared_memory {
            return Err(format!(
                "the network needs {} KiB of workgroup memory; device '{}' has {} KiB: use a smaller width in [neural]",
                shape.workgroup_bytes() / 1024,
                device.name,
                device.max_shared_memory / 1024
            ));
        }
        let bytes = self.batch() as u64 * self.layers as u64 * self.width as u64 * 4;
        if bytes > device.max_storage_buffer_range {
            return Err(format!(
                "a batch of {} transitions through {} layers of {} units needs {} MiB per buffer; device '{}' allows {} MiB: use a smaller batch in [neural]",
                self.batch(),
                self.layers,
                self.width,
                bytes >> 20,
                device.name,
                device.max_storage_buffer_range >> 20
            ));
        }
        match self.inference {
            Inference::Volumes => self.table().check_tables_fit(scene, device, "neural"),
            Inference::Vertices => Ok(()),
        }
    }
}

/// The scene's distinct triangle corners, in order of first use.
pub fn scene_vertices(scene: &Scene) -> Vec<Vec3> {
    let mut seen = std::collections::HashSet::new();
    let mut out = Vec::new();
    for t in &scene.triangles {
        let v0 = Vec3::from(t.v0);
        for v in [v0, v0 + Vec3::from(t.e1), v0 + Vec3::from(t.e2)] {
            if seen.insert(v.to_array().map(f32::to_bits)) {
                out.push(v);
            }
        }
    }
    out
}

/// The vertex encoding of a point p with normal n (the CPU twin of
/// `neural_encode` with FLAG_VERTEX_ENCODING): every vertex relative to p
/// over the extent of the scene's box `bounds`, n, zeros up to `inputs`.
pub fn encode_vertices(
    vertices: &[Vec3],
    bounds: (Vec3, Vec3),
    inputs: usize,
    p: Vec3,
    n: Vec3,
) -> Vec<f32> {
    let scale = Vec3::ONE / (bounds.1 - bounds.0).max(Vec3::splat(1e-6));
    let mut e: Vec<f32> = vertices
        .iter()
        .flat_map(|&v| ((v - p) * scale).to_array())
        .chain(n.to_array())
        .collect();
    e.resize(inputs, 0.0);
    e
}

/// The network's input for a point p with normal n in a scene whose box is
/// `bounds` (the CPU twin of `neural_encode` in glsl/neural.glsl): p mapped
/// to [-1, 1]³, n, sin and cos of p at ENCODING_FREQUENCIES octaves, zeros.
pub fn encode(bounds: (Vec3, Vec3), p: Vec3, n: Vec3) -> Vec<f32> {
    let (lo, hi) = bounds;
    let u = (p - lo) / (hi - lo).max(Vec3::splat(1e-6));
    let mut e = vec![0.0; shaders::ENCODED_INPUTS as usize];
    for i in 0..3 {
        e[i] = 2.0 * u[i] - 1.0;
        e[3 + i] = n[i];
    }
    for o in 0..shaders::ENCODING_FREQUENCIES as usize {
        let f = std::f32::consts::PI * (1 << o) as f32;
        for i in 0..3 {
            e[6 + 6 * o + i] = (u[i] * f).sin();
            e[9 + 6 * o + i] = (u[i] * f).cos();
        }
    }
    e
}

/// What the trace and gather kernels bind: the network and its batch, the
/// scene's vertices and the offered transitions.
fn kernel_bindings<'a>(
    network: &'a Network,
    vertices: &'a Buffer,
    pending: &'a Buffer,
) -> Vec<(u32, &'a Buffer)> {
    let mut b = network.bindings();
    b.push((shaders::B_NEURAL_VERTICES, vertices));
    b.push((shaders::B_NEURAL_PENDING, pending));
    b
}

/// The pass that draws a training step's rows from the volumes' means.
const GATHER_FROM_VOLUMES: &str = "mlp gather from volumes";

/// With inference at the volumes: the volumes and their tables, and the
/// pass that fills Q there from the network.
struct VolumeTable {
    guide: SarsaGuide,
    /// Per volume: (position, 0), (normal, 0).
    states: Buffer,
    infer: ComputePipeline,
    infer_set: DescriptorSet,
    prior_visits: f32,
}

/// Neural-Q among the guides.
pub const GUIDE: GuideEntry = GuideEntry {
    name: "neural",
    about: "Neural-Q guiding: an MLP gives every sector's Q at a point",
    read: |table| table.try_into().map(|s: NeuralSettings| s.into()),
    every_key: |common| {
        GuideSettings::from(NeuralSettings {
            common,
            volumes: Some(0),
            batch: Some(0),
            learning_rate: Some(0.0),
            steps: Some(0),
            training: Some(Training::Volumes),
            ..Default::default()
        })
    },
};

impl crate::render::Method {
    pub const NEURAL: Self = Self::guided(GUIDE.name);
}

impl GuideConfig for NeuralSettings {
    fn name(&self) -> &'static str {
        GUIDE.name
    }

    fn common(&self) -> &Common {
        &self.common
    }

    fn default_thin_after(&self) -> u32 {
        // Inferring at the volumes, training is most of a pass, and thinning
        // it as Sarsa's kept the room's error at 256 spp (relMSE 0.129
        // against 0.124 at 256x256) and cut it at equal time (0.37 against
        // 0.55). Trained on the volumes' means, the passes that learn tally
        // targets as Sarsa's do, and only some of them also train the
        // network (`train_thin_after`): at 128x128, tallying as Sarsa does
        // instead of up to the 4th pass cut the error at equal samples by
        // 5-40% for 1.12-1.17x the GPU time per pass. Inferring at every
        // vertex, it learns in every pass.
        match self.inference {
            Inference::Volumes => 16,
            Inference::Vertices => 0,
        }
    }

    fn learns_shares(&self) -> bool {
        self.learns_epsilon()
    }

    fn validate(&self, scene: &Scene) -> Result<(), String> {
        NeuralSettings::validate(self).and_then(|()| self.validate_for(scene))
    }

    fn check_device(&self, scene: &Scene, device: &DeviceInfo) -> Result<(), String> {
        NeuralSettings::check_device(self, scene, device)
    }

    fn trace_spirv(&self, device: &DeviceInfo, nee: bool) -> gpu::Result<&'static [u8]> {
        Ok(match (self.training(), self.inference, nee) {
            // Training on the volumes adds targets as Sarsa's kernel does.
            (Training::Volumes, _, _) => self.table().pick(device, sarsa::trace_variants(nee))?,
            (_, Inference::Vertices, false) => spirv::TRACE_NEURAL,
            (_, Inference::Vertices, true) => spirv::TRACE_NEURAL_NEE,
            (_, Inference::Volumes, false) => spirv::TRACE_NEURAL_TABLE,
            (_, Inference::Volumes, true) => spirv::TRACE_NEURAL_TABLE_NEE,
        })
    }

    fn frozen_trace_spirv(&self, nee: bool) -> Option<&'static [u8]> {
        (self.training() == Training::Volumes).then(|| sarsa::frozen_trace(nee))
    }

    fn for_image(&self, width: u32, height: u32) -> GuideSettings {
        NeuralSettings::for_image(self, width, height).into()
    }

    fn build(
        &self,
        ctx: &Arc<GpuContext>,
        scene: &Scene,
        seed: u32,
        pixels: u64,
    ) -> gpu::Result<Guide> {
        Ok(Box::new(NeuralGuide::new(ctx, scene, self, seed, pixels)?))
    }
}

impl DeviceGuide for NeuralGuide {
    fn chooses_lights(&self) -> bool {
        self.table
            .as_ref()
            .is_some_and(|t| t.guide.chooses_lights())
    }

    fn constants(&self) -> Vec<u32> {
        self.network.shape.constants().to_vec()
    }

    fn volume_table(&self) -> Option<&SarsaGuide> {
        self.table()
    }

    fn bindings(&self) -> Vec<(u32, &Buffer)> {
        // With training on the volumes, targets go to the means' tallies
        // (bound first, so they win over the sampling tables' own).
        let mut b: Vec<(u32, &Buffer)> = self
            .targets
            .as_ref()
            .map_or(Vec::new(), |t| t.means.tally_bindings().to_vec());
        b.extend(kernel_bindings(
            &self.network,
            &self.vertex_buffer,
            &self.pending,
        ));
        if let Some(t) = &self.table {
            b.extend(t.guide.bindings());
        }
        b
    }

    fn set_params(&self, p: &mut PassParams, learn: bool) {
        let s = &self.settings;
        s.common.set_params(p, learn);
        if s.learns_epsilon() {
            // As Sarsa's: the means learn the share, the tables copy it.
            p.guide_epsilon = s.common.epsilon(true);
            p.flags |= shaders::FLAG_LEARN_MIX;
        }
        if s.target == Target::Max {
            p.flags |= shaders::FLAG_MAX_TARGET;
        }
        if s.encoding == Encoding::Vertices {
            p.flags |= shaders::FLAG_VERTEX_ENCODING;
        }
        p.volume_count = self.volume_count() as u32;
        if let Some(t) = &self.table {
            // The flag and count its tables' updates need.
            let mut q = *p;
            t.guide.set_params(&mut q, learn);
            p.flags |=
                q.flags & (shaders::FLAG_GUIDE_LIGHTS | u32::MAX << shaders::LIGHT_GROUPS_SHIFT);
        }
    }

    fn record_update(&mut self, rec: &mut Recorder<'_>, params: &PassParams) {
        if let (Some(t), Some(table)) = (&self.targets, &self.table) {
            // Fold the pass's targets into the means, train on rows drawn
            // from them, then refill the sampling tables from the network,
            // leaving out the share NEE carries as Sarsa's do.
            t.means.record_update(rec, params);
            let mut p = *params;
            p.volume_count = t.means.volumes.len() as u32;
            let steps = if self.settings.trains_in_pass(params.pass_index) {
                self.steps
            } else {
                0
            };
            for step in 0..steps {
                p.selector = step;
                rec.dispatch(Pass {
                    name: GATHER_FROM_VOLUMES,
                    pipeline: &t.gather,
                    set: &t.gather_set,
                    push: bytemuck::bytes_of(&p),
                    groups: [self.network.capacity.div_ceil(shaders::MLP_LANES), 1, 1],
                });
                self.network.record_step(rec);
            }
            self.network.record_reset(rec);
            table.guide.record_copy_learned(rec, &t.means);
            table.record_refresh(rec, params);
            return;
        }
        rec.dispatch(Pass {
            name: "mlp gather",
            pipeline: &self.gather,
            set: &self.gather_set,
            push: bytemuck::bytes_of(params),
            groups: [1, 1, 1],
        });
        self.network.record_training(rec, self.steps);
        if let Some(t) = &self.table {
            t.record_refresh(rec, params);
        }
    }

    fn fit_to_device(&mut self, timings: &[PassTiming]) -> Option<DeviceFit> {
        if !self.settings.fits_steps() {
            return None;
        }
        let total = |names: &[&str]| -> f64 {
            timings
                .iter()
                .filter(|t| names.contains(&t.name.as_str()))
                .map(|t| t.total_ms)
                .sum()
        };
        let trace = timings.iter().find(|t| t.name == "trace")?;
        let pass_ms = trace.total_ms / trace.count.max(1) as f64;
        let mut step_passes = STEP_PASSES.to_vec();
        step_passes.push(GATHER_FROM_VOLUMES);
        let step_ms = total(&step_passes) / self.steps as f64;
        let fit = DeviceFit {
            training_steps: fitted_steps(pass_ms, step_ms, self.steps)?,
            step_ms,
            pass_ms,
        };
        self.refit(&fit);
        Some(fit)
    }

    fn refit(&mut self, fit: &DeviceFit) {
        if self.settings.fits_steps() {
            self.steps = fit.training_steps;
        }
    }

    fn bytes(&self) -> u64 {
        self.network.bytes()
            + self.table.as_ref().map_or(0, |t| t.guide.bytes())
            + self.targets.as_ref().map_or(0, |t| t.means.bytes())
    }

    fn save(&self) -> gpu::Result<Vec<(&'static str, Vec<u8>)>> {
        let mut blobs = self.network.save()?;
        if let Some(t) = &self.targets {
            blobs.extend(t.means.save()?);
        }
        Ok(blobs)
    }

    fn restore(
        &mut self,
        ctx: &Arc<GpuContext>,
        blobs: &[(String, Vec<u8>)],
        nee: bool,
    ) -> Result<(), String> {
        self.network.restore(blobs)?;
        if let (Some(t), Some(table)) = (&self.targets, &self.table) {
            t.means.restore(ctx, blobs)?;
            ctx.submit(None, |rec| table.guide.record_copy_learned(rec, &t.means))
                .map_err(|e| e.to_string())?;
        }
        self.refresh_for(ctx, nee).map_err(|e| e.to_string())
    }

    fn volume_count(&self) -> u64 {
        self.table
            .as_ref()
            .map_or(0, |t| t.guide.volumes.len() as u64)
    }

    fn grid(&self) -> [u32; 2] {
        self.settings.common.grid
    }

    fn sample_rows(
        &self,
        ctx: &Arc<GpuContext>,
        scene: &Scene,
        count: usize,
    ) -> Result<(Vec<Vec<f32>>, String), RenderError> {
        let rows = learned::neural_rows(ctx, scene, self, count)?;
        let at = format!(
            "the {} points the camera sees nearest the brightest light, as the network infers them",
            rows.len()
        );
        Ok((rows, at))
    }
}

impl VolumeTable {
    /// Records the refill: the network's Q at every volume, then the tables
    /// rebuilt from it (no Sarsa tallies to fold).
    fn record_refresh(&self, rec: &mut Recorder<'_>, params: &PassParams) {
        let mut params = *params;
        params.volume_count = self.guide.volumes.len() as u32;
        params.selector = self.prior_visits.to_bits();
        rec.dispatch(Pass {
            name: "neural at volumes",
            pipeline: &self.infer,
            set: &self.infer_set,
            push: bytemuck::bytes_of(&params),
            groups: [params.volume_count.div_ceil(shaders::MLP_LANES), 1, 1],
        });
        params.flags &= !shaders::FLAG_LEARN;
        self.guide.record_update(rec, &params);
    }
}

pub struct NeuralGuide {
    pub settings: NeuralSettings,
    pub network: Network,
    /// Training steps per pass that trains: `settings.first_steps`, then
    /// as fitted to the device (see [`fitted_steps`]).
    steps: u32,
    bounds: (Vec3, Vec3),
    /// The scene's vertices, for the vertex encoding (empty otherwise).
    vertices: Vec<Vec3>,
    vertex_buffer: Buffer,
    /// Per pixel, the transition its path offers (see glsl/neural.glsl).
    pending: Buffer,
    gather: ComputePipeline,
    gather_set: DescriptorSet,
    table: Option<VolumeTable>,
    targets: Option<TargetTable>,
}

/// With `training = "volumes"`: the tallies and running means of the TD
/// targets per volume and sector (a Sarsa table the trace kernel adds to,
/// over the same volumes), and the pass that draws training rows from them.
struct TargetTable {
    means: SarsaGuide,
    gather: ComputePipeline,
    gather_set: DescriptorSet,
}

impl NeuralGuide {
    /// A freshly initialised network for `scene`; the first pass offers
    /// transitions with a chance that fills about half the batch at
    /// `pixels` paths of a few bounces.
    pub fn new(
        ctx: &Arc<GpuContext>,
        scene: &Scene,
        settings: &NeuralSettings,
        seed: u32,
        pixels: u64,
    ) -> gpu::Result<Self> {
        let shape = settings.shape_for(scene);
        let params = shape.init(seed as u64, settings.common.initial_q);
        let adam = Adam {
            learning_rate: settings.learning_rate(),
            ..Adam::default()
        };
        // Rows of target means carry every sector's target.
        let dense = settings.training() == Training::Volumes;
        let network = Network::new(ctx, shape, adam, settings.batch(), &params, dense)?;
        let (lo, hi) = scene.bounds();
        let vertices = match settings.encoding {
            Encoding::Frequency => Vec::new(),
            Encoding::Vertices => scene_vertices(scene),
        };
        let mut padded: Vec<[f32; 4]> = vertices.iter().map(|v| v.extend(0.0).into()).collect();
        padded.resize(padded.len().max(1), [0.0; 4]);
        let vertex_buffer = Buffer::gpu_only_with(ctx, "neural scene vertices", &padded)?;
        let probability = (settings.batch() as f64 / (4.0 * pixels.max(1) as f64)).min(1.0);
        network.set_batch(
            probability as f32,
            lo.into(),
            hi.into(),
            vertices.len() as u32,
        )?;
        let pending = Buffer::gpu_only(ctx, "neural offered transitions", pixels.max(1) * 32)?;
        let gather = ComputePipeline::specialized(
            ctx,
            "mlp gather",
            spirv::MLP_GATHER,
            size_of::<PassParams>() as u32,
            &network.shape.constants(),
        )?;
        let gather_set = DescriptorSet::new(
            ctx,
            &gather,
            &kernel_bindings(&network, &vertex_buffer, &pending),
        )?;
        let mut table = match settings.inference {
            Inference::Vertices => None,
            Inference::Volumes => Some(Self::build_table(
                ctx,
                scene,
                settings,
                seed,
                &network,
                &vertex_buffer,
                &pending,
            )?),
        };
        let targets = match (&table, settings.training()) {
            (Some(t), Training::Volumes) => {
                // The sampling tables' volumes: the trace kernel tallies at
                // their volume indices.
                let means = t.guide.means_twin(ctx)?;
                let gather = ComputePipeline::specialized(
                    ctx,
                    GATHER_FROM_VOLUMES,
                    spirv::MLP_GATHER_TABLE,
                    size_of::<PassParams>() as u32,
                    &network.shape.constants(),
                )?;
                // The means' Q first: the gather reads it at B_Q.
                let mut bindings = means.bindings().to_vec();
                bindings.extend(kernel_bindings(&network, &vertex_buffer, &pending));
                bindings.push((shaders::B_NEURAL_STATES, &t.states));
                let gather_set = DescriptorSet::new(ctx, &gather, &bindings)?;
                Some(TargetTable {
                    means,
                    gather,
                    gather_set,
                })
            }
            _ => None,
        };
        if let (Some(t), Some(m)) = (&mut table, &targets) {
            let mut bindings = kernel_bindings(&network, &vertex_buffer, &pending);
            bindings.extend(t.guide.bindings());
            bindings.extend(m.means.mean_bindings());
            bindings.push((shaders::B_NEURAL_STATES, &t.states));
            t.infer_set = DescriptorSet::new(ctx, &t.infer, &bindings)?;
        }
        let guide = Self {
            settings: settings.clone(),
            network,
            steps: settings.first_steps(pixels),
            bounds: (lo, hi),
            vertices,
            vertex_buffer,
            pending,
            gather,
            gather_set,
            table,
            targets,
        };
        guide.refresh(ctx)?;
        Ok(guide)
    }

    /// Places the volumes of `inference = "volumes"` and builds their tables.
    fn build_table(
        ctx: &Arc<GpuContext>,
        scene: &Scene,
        settings: &NeuralSettings,
        seed: u32,
        network: &Network,
        vertices: &Buffer,
        pending: &Buffer,
    ) -> gpu::Result<VolumeTable> {
        // Lights are picked where the trace kernel is Sarsa's, which tallies
        // their tries into the means (training on the volumes).
        let pick_lights =
            settings.training() == Training::Volumes && settings.common.picks_lights();
        let guide = SarsaGuide::new(ctx, scene, &settings.table(), seed, pick_lights)?;
        let states: Vec<[f32; 4]> = guide
            .volumes
            .iter()
            .flat_map(|v| {
                let [x, y, z] = v.position;
                let [nx, ny, nz] = v.normal;
                [[x, y, z, 0.0], [nx, ny, nz, 0.0]]
            })
            .collect();
        let states = Buffer::gpu_only_with(ctx, "neural volume states", &states)?;
        let infer = ComputePipeline::specialized(
            ctx,
            "neural at volumes",
            spirv::NEURAL_VOLUMES,
            size_of::<PassParams>() as u32,
            &network.shape.constants(),
        )?;
        let mut bindings = kernel_bindings(network, vertices, pending);
        bindings.extend(guide.bindings());
        bindings.extend(guide.mean_bindings());
        bindings.push((shaders::B_NEURAL_STATES, &states));
        let infer_set = DescriptorSet::new(ctx, &infer, &bindings)?;
        Ok(VolumeTable {
            guide,
            states,
            infer,
            infer_set,
            prior_visits: settings.prior_visits,
        })
    }

    /// With inference at the volumes, refills their tables from the network now.
    pub fn refresh(&self, ctx: &Arc<GpuContext>) -> gpu::Result<()> {
        self.refresh_for(ctx, false)
    }

    /// [`NeuralGuide::refresh`] as a pass with (`nee`) or without NEE
    /// refreshes the tables: with NEE their Q adds the share NEE carries.
    pub fn refresh_for(&self, ctx: &Arc<GpuContext>, nee: bool) -> gpu::Result<()> {
        let Some(table) = &self.table else {
            return Ok(());
        };
        let mut params = PassParams::default();
        self.set_params(&mut params, false);
        if nee {
            params.flags |= shaders::FLAG_NEE;
        }
        ctx.submit(None, |rec| table.record_refresh(rec, &params))
    }

    /// The volumes and their tables, with inference at the volumes.
    pub fn table(&self) -> Option<&SarsaGuide> {
        self.table.as_ref().map(|t| &t.guide)
    }

    /// With `training = "volumes"`: the running means of the TD targets per
    /// volume and sector that training draws its rows from.
    pub fn target_means(&self) -> Option<&SarsaGuide> {
        self.targets.as_ref().map(|t| &t.means)
    }

    /// The network's input for a point p with normal n (as the GPU encodes it).
    pub fn encode(&self, p: Vec3, n: Vec3) -> Vec<f32> {
        match self.settings.encoding {
            Encoding::Frequency => encode(self.bounds, p, n),
            Encoding::Vertices => encode_vertices(
                &self.vertices,
                self.bounds,
                self.network.shape.inputs as usize,
                p,
                n,
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn cornell() -> Scene {
        Scene::load(Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell-box.toml")).unwrap()
    }

    #[test]
    fn training_thins_out_apart_from_the_tallies() {
        let settings = |train_thin_after| NeuralSettings {
            train_thin_after,
            ..Default::default()
        };
        let training =
            |n: &NeuralSettings| (0..20).filter(|&i| n.trains_in_pass(i)).collect::<Vec<_>>();
        assert_eq!(training(&settings(4)), [0, 1, 2, 3, 4, 6, 8, 12, 16]);
        assert_eq!(training(&settings(0)), (0..20).collect::<Vec<_>>());
        // The tallies keep their own schedule: 16 passes by default.
        let guide = super::super::GuideSettings::from(settings(4));
        assert!(guide.learns_in_pass(15) && !settings(4).trains_in_pass(15));
    }

    #[test]
    fn scene_vertices_are_the_distinct_corners() {
        let scene = cornell();
        let v = scene_vertices(&scene);
        assert_eq!(v.len(), 32);
        let distinct: std::collections::HashSet<_> =
            v.iter().map(|p| p.to_array().map(f32::to_bits)).collect();
        assert_eq!(distinct.len(), v.len());
    }

    #[test]
    fn encodings_fill_their_inputs_and_pad_with_zeros() {
        let scene = cornell();
        let bounds = scene.bounds();
        let (p, n) = ((bounds.0 + bounds.1) * 0.5, Vec3::Y);
        let e = encode(bounds, p, n);
        assert_eq!(e.len(), shaders::ENCODED_INPUTS as usize);
        assert!(
            e[..3].iter().all(|x| x.abs() < 1e-6),
            "centre maps to 0: {e:?}"
        );
        assert_eq!(&e[3..6], &[0.0, 1.0, 0.0]);
        assert!(e[6 + 6 * shaders::ENCODING_FREQUENCIES as usize..]
            .iter()
            .all(|&x| x == 0.0));
        let vertices = scene_vertices(&scene);
        let e = encode_vertices(&vertices, bounds, 100, p, n);
        assert_eq!(e.len(), 100);
        assert_eq!(&e[96..99], &[0.0, 1.0, 0.0]);
        assert_eq!(e[99], 0.0);
    }

    #[test]
    fn default_batch_and_volumes_follow_the_image() {
        // Training on transitions: a batch per image size.
        let s = NeuralSettings {
            training: Some(Training::Transitions),
            ..Default::default()
        };
        let at = |w, h| {
            let t = s.for_image(w, h);
            (t.batch, t.volumes, t.steps)
        };
        assert_eq!(at(256, 256), (Some(4096), Some(1024), None));
        assert_eq!(at(128, 128), (Some(1024), Some(256), None));
        assert_eq!(at(1024, 1024), (Some(DEFAULT_BATCH), Some(16384), None));
        assert_eq!(at(8, 8).0, Some(MIN_DEFAULT_BATCH));
        // Training on the volumes' means (the default): fixed rows; steps
        // left to the device, the first pass's per image size.
        let means = NeuralSettings::default().for_image(256, 256);
        assert_eq!((means.batch, means.steps), (Some(VOLUME_ROWS), None));
        assert!(means.fits_steps());
        let first = |w: u64, h: u64| NeuralSettings::default().first_steps(w * h);
        assert_eq!(first(256, 256), 16);
        assert_eq!(first(512, 512), 64);
        assert_eq!(first(128, 128), 4);
        assert_eq!(first(8, 8), 4);
        assert_eq!(first(4096, 4096), 64);
        let pinned = NeuralSettings {
            steps: Some(3),
            ..Default::default()
        };
        assert_eq!(
            (pinned.first_steps(1 << 20), pinned.fits_steps()),
            (3, false)
        );
        assert!(!s.fits_steps());
        // Given values stay; inference at every vertex places no volumes.
        let given = NeuralSettings {
            batch: Some(7),
            inference: Inference::Vertices,
            ..Default::default()
        };
        assert_eq!(given.for_image(256, 256).batch, Some(7));
        assert_eq!(given.for_image(256, 256).volumes, None);
    }

    #[test]
    fn training_steps_follow_what_a_step_and_a_pass_cost() {
        // A step that costs 1/n of TRAINING_SHARE of a pass.
        let fit = |n: f64, first| fitted_steps(100.0, 100.0 * TRAINING_SHARE / n, first);
        // Within a factor 8 of the first pass's steps, those.
        for n in [2.1, 8.0, 16.0, 30.0, 70.0, 127.0] {
            assert_eq!(fit(n, 16), Some(16), "{n}");
        }
        // Beyond, the share to the nearest power of two.
        assert_eq!(fit(1.9, 16), Some(4));
        assert_eq!(fit(130.0, 16), Some(64));
        assert_eq!(fit(33.0, 4), Some(32));
        assert_eq!(fit(46.0, 4), Some(64));
        // Within MIN_DEFAULT_STEPS..=MAX_STEPS: an NVIDIA H200 at
        // 1024x1024, where a step costs about a pass, and a pass a
        // thousand steps.
        assert_eq!(fitted_steps(0.6, 0.45, 64), Some(MIN_DEFAULT_STEPS as u32));
        assert_eq!(fitted_steps(1e6, 1.0, 4), Some(MAX_STEPS));
        // Times that say nothing leave the steps as they were.
        assert_eq!(fitted_steps(0.0, 1.0, 16), None);
        assert_eq!(fitted_steps(1.0, 0.0, 16), None);
        assert_eq!(fitted_steps(f64::NAN, 1.0, 16), None);
    }

    #[test]
    fn vertex_encoding_fits_narrow_networks_only() {
        let scene = cornell();
        let wide = NeuralSettings {
            encoding: Encoding::Vertices,
            width: 32,
            ..Default::default()
        };
        let e = wide.validate_for(&scene).unwrap_err();
        assert!(e.contains("width = 28 would fit"), "{e}");
        let narrow = NeuralSettings { width: 28, ..wide };
        narrow.validate_for(&scene).unwrap();
        assert_eq!(narrow.shape_for(&scene).inputs, 100);
        assert!(NeuralSettings::default().validate_for(&scene).is_ok());
    }
}
