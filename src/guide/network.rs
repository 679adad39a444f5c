//! The Neural-Q network on the GPU: its parameters and Adam moments, a batch
//! of training transitions, and the passes that train on that batch
//! (`mlp_train`, `mlp_bucket` to group the rows by sector, `mlp_adam` for
//! all layers in one dispatch, then `mlp_batch` to empty it). The maths is `guide::mlp`'s.
//! A dense network's rows have a target for every sector (a volume's row of
//! target means) instead of one: its training and output passes are the
//! `MLP_DENSE` variants, and it needs no grouping by sector.

use super::mlp::{Adam, MlpShape};
use crate::gpu::{self, Buffer, ComputePipeline, DescriptorSet, GpuContext, Pass, Recorder};
use crate::shaders::{self, spirv, MlpBatch, MlpPush, MlpTarget};
use std::mem::size_of;
use std::sync::Arc;

pub struct Network {
    pub shape: MlpShape,
    pub adam: Adam,
    /// Rows of the training batch.
    pub capacity: u32,
    /// Adam steps taken.
    steps: u32,
    params: Buffer,
    moments: Buffer,
    grad: Buffer,
    inputs: Buffer,
    targets: Buffer,
    /// The batch's state (`MlpBatch`).
    batch_state: Buffer,
    acts: Buffer,
    deltas: Buffer,
    /// The batch's rows grouped by sector (see glsl/mlp_bucket.comp).
    buckets: Buffer,
    /// Dense rows: per row and sector the target; then, after `capacity`
    /// rows, per row and sector the last step's dLoss/dz.
    dense: Option<Buffer>,
    train: ComputePipeline,
    bucket: ComputePipeline,
    bucket_set: DescriptorSet,
    adam_pass: ComputePipeline,
    batch_pass: ComputePipeline,
    train_set: DescriptorSet,
    adam_set: DescriptorSet,
    batch_set: DescriptorSet,
}

fn groups(items: u32) -> [u32; 3] {
    [items.div_ceil(shaders::LINEAR_GROUP).max(1), 1, 1]
}

/// The passes of one training step, as the profiler names them.
const TRAINING: &str = "mlp training";
const ROWS_BY_SECTOR: &str = "mlp rows by sector";
const ADAM: &str = "mlp Adam step";
pub const STEP_PASSES: [&str; 3] = [TRAINING, ROWS_BY_SECTOR, ADAM];

impl Network {
    /// A network with parameters `params` (see `MlpShape::init`) and a
    /// training batch of `capacity` rows, each with one target or, `dense`,
    /// one per sector.
    pub fn new(
        ctx: &Arc<GpuContext>,
        shape: MlpShape,
        adam: Adam,
        capacity: u32,
        params: &[f32],
        dense: bool,
    ) -> gpu::Result<Self> {
        assert_eq!(params.len(), shape.param_count(), "parameters of {shape:?}");
        let p = params.len() as u64;
        let rows = capacity as u64;
        let units = rows * shape.hidden as u64 * shape.width as u64;
        let params = Buffer::gpu_only_with(ctx, "mlp parameters", params)?;
        let moments = Buffer::gpu_only(ctx, "mlp Adam moments", p * 8)?;
        let grad = Buffer::gpu_only(ctx, "mlp gradient", p * 4)?;
        let inputs = Buffer::gpu_only(ctx, "mlp batch inputs", rows * shape.inputs as u64 * 4)?;
        let targets = Buffer::gpu_only(
            ctx,
            "mlp batch targets",
            rows * size_of::<MlpTarget>() as u64,
        )?;
        let state = MlpBatch {
            capacity,
            probability: 1.0,
            bounds_scale: [1.0; 4],
            ..Default::default()
        };
        let batch_state = Buffer::gpu_only_with(ctx, "mlp batch state", &[state])?;
        let acts = Buffer::gpu_only(ctx, "mlp batch activations", units * 4)?;
        let deltas = Buffer::gpu_only(ctx, "mlp batch deltas", units * 4)?;
        let buckets = Buffer::gpu_only(
            ctx,
            "mlp batch rows by sector",
            (shape.outputs as u64 + 2 + rows) * 4,
        )?;
        let dense = if dense {
            let bytes = 2 * rows * shape.outputs as u64 * 4;
            Some(Buffer::gpu_only(ctx, "mlp batch dense targets", bytes)?)
        } else {
            None
        };
        let (train_spirv, adam_spirv) = match dense {
            Some(_) => (spirv::MLP_TRAIN_DENSE, spirv::MLP_ADAM_DENSE),
            None => (spirv::MLP_TRAIN, spirv::MLP_ADAM),
        };
        let push = size_of::<MlpPush>() as u32;
        let constants = shape.constants();
        let train =
            ComputePipeline::specialized(ctx, "mlp training", train_spirv, push, &constants)?;
        let adam_pass = ComputePipeline::specialized(ctx, ADAM, adam_spirv, push, &constants)?;
        let bucket = ComputePipeline::specialized(
            ctx,
            "mlp rows by sector",
            spirv::MLP_BUCKET,
            push,
            &constants,
        )?;
        let batch_pass = ComputePipeline::new(ctx, "mlp batch reset", spirv::MLP_BATCH, 0)?;
        let mut bindings = vec![
            (shaders::B_MLP_PARAMS, &params),
            (shaders::B_MLP_MOMENTS, &moments),
            (shaders::B_MLP_GRAD, &grad),
            (shaders::B_MLP_INPUTS, &inputs),
            (shaders::B_MLP_TARGETS, &targets),
            (shaders::B_MLP_COUNT, &batch_state),
            (shaders::B_MLP_ACTS, &acts),
            (shaders::B_MLP_DELTAS, &deltas),
            (shaders::B_MLP_BUCKETS, &buckets),
        ];
        bindings.extend(dense.iter().map(|d| (shaders::B_MLP_DENSE, d)));
        let train_set = DescriptorSet::new(ctx, &train, &bindings)?;
        let adam_set = DescriptorSet::new(ctx, &adam_pass, &bindings)?;
        let batch_set = DescriptorSet::new(ctx, &batch_pass, &bindings)?;
        let bucket_set = DescriptorSet::new(ctx, &bucket, &bindings)?;
        ctx.submit(None, |rec| {
            for b in [&moments, &grad, &inputs].into_iter().chain(&dense) {
                rec.fill(b, 0);
            }
        })?;
        Ok(Self {
            shape,
            adam,
            capacity,
            steps: 0,
            params,
            moments,
            grad,
            inputs,
            targets,
            batch_state,
            acts,
            deltas,
            buckets,
            dense,
            train,
            bucket,
            bucket_set,
            adam_pass,
            batch_pass,
            train_set,
            adam_set,
            batch_set,
        })
    }

    /// Buffers a kernel that fills the batch or reads the network binds.
    pub fn bindings(&self) -> Vec<(u32, &Buffer)> {
        let mut b = vec![
            (shaders::B_MLP_PARAMS, &self.params),
            (shaders::B_MLP_INPUTS, &self.inputs),
            (shaders::B_MLP_TARGETS, &self.targets),
            (shaders::B_MLP_COUNT, &self.batch_state),
        ];
        b.extend(self.dense.iter().map(|d| (shaders::B_MLP_DENSE, d)));
        b
    }

    fn push(&self) -> MlpPush {
        MlpPush {
            capacity: self.capacity,
            step: self.steps,
            learning_rate: self.adam.learning_rate,
            beta1: self.adam.beta1,
            beta2: self.adam.beta2,
            epsilon: self.adam.epsilon,
            pad: [0; 2],
        }
    }

    /// Records `steps` training steps on the batch, then empties it and
    /// sets how likely the next pass offers each transition.
    pub fn record_training(&mut self, rec: &mut Recorder<'_>, steps: u32) {
        for _ in 0..steps {
            self.record_step(rec);
        }
        self.record_reset(rec);
    }

    /// Records one training step on the batch as it stands.
    pub fn record_step(&mut self, rec: &mut Recorder<'_>) {
        {
            self.steps += 1;
            let push = self.push();
            let push = bytemuck::bytes_of(&push);
            rec.dispatch(Pass {
                name: TRAINING,
                pipeline: &self.train,
                set: &self.train_set,
                push,
                groups: groups(self.capacity),
            });
            if self.dense.is_none() {
                rec.dispatch(Pass {
                    name: ROWS_BY_SECTOR,
                    pipeline: &self.bucket,
                    set: &self.bucket_set,
                    push,
                    groups: [1, 1, 1],
                });
            }
            // One dispatch for all layers (glsl/mlp_adam.comp): first the
            // hidden layers' workgroups, an invocation per four weights of
            // a unit and per bias, then the output layer's.
            let slots = |fan_in: usize, fan_out: usize| (fan_out * (fan_in / 4 + 1)) as u32;
            let layers = self.shape.layers();
            let (output, hidden) = layers.split_last().unwrap();
            let hidden_groups = groups(hidden.iter().map(|l| slots(l.fan_in, l.fan_out)).sum())[0];
            // One workgroup per output, or with dense rows as the hidden ones.
            let output_groups = match self.dense {
                Some(_) => groups(slots(output.fan_in, output.fan_out))[0],
                None => self.shape.outputs,
            };
            rec.dispatch(Pass {
                name: ADAM,
                pipeline: &self.adam_pass,
                set: &self.adam_set,
                push,
                groups: [hidden_groups + output_groups, 1, 1],
            });
        }
    }

    /// Records the batch's reset: empty, and the next pass's offer chance.
    pub fn record_reset(&mut self, rec: &mut Recorder<'_>) {
        rec.dispatch(Pass {
            name: "mlp batch reset",
            pipeline: &self.batch_pass,
            set: &self.batch_set,
            push: &[],
            groups: [1, 1, 1],
        });
    }

    /// Sets the batch's state: the encoding's box and vertex count, and the
    /// chance the first pass offers each transition.
    pub fn set_batch(
        &self,
        probability: f32,
        bounds_min: [f32; 3],
        bounds_max: [f32; 3],
        vertex_count: u32,
    ) -> gpu::Result<()> {
        let scale = |i: usize| 1.0 / (bounds_max[i] - bounds_min[i]).max(1e-6);
        let state = MlpBatch {
            count: 0,
            capacity: self.capacity,
            probability,
            vertex_count,
            bounds_min: [bounds_min[0], bounds_min[1], bounds_min[2], 0.0],
            bounds_scale: [scale(0), scale(1), scale(2), 0.0],
        };
        self.batch_state.overwrite(&[state])
    }

    /// Replaces the batch (tests and tools): inputs row-major, one target each.
    pub fn upload_batch(&self, inputs: &[f32], targets: &[MlpTarget]) -> gpu::Result<()> {
        assert!(targets.len() <= self.capacity as usize);
        assert_eq!(inputs.len(), targets.len() * self.shape.inputs as usize);
        self.inputs.overwrite(inputs)?;
        self.targets.overwrite(targets)?;
        self.batch_state.overwrite(&[targets.len() as u32])
    }

    /// The batch's input rows as the trace kernel or `upload_batch` left them.
    pub fn download_inputs(&self) -> gpu::Result<Vec<f32>> {
        self.inputs.download()
    }

    /// What training has reached, to resume from: parameters, Adam's
    /// moments and step count, and the batch's state.
    pub fn save(&self) -> gpu::Result<Vec<(&'static str, Vec<u8>)>> {
        Ok(vec![
            ("mlp parameters", self.params.download()?),
            ("mlp Adam moments", self.moments.download()?),
            ("mlp batch state", self.batch_state.download()?),
            ("mlp Adam steps", self.steps.to_le_bytes().to_vec()),
        ])
    }

    /// Restores what [`Network::save`] gave.
    pub fn restore(&mut self, blobs: &[(String, Vec<u8>)]) -> Result<(), String> {
        for (name, buffer) in [
            ("mlp parameters", &self.params),
            ("mlp Adam moments", &self.moments),
            ("mlp batch state", &self.batch_state),
        ] {
            super::restore_blob(buffer, name, blobs)?;
        }
        let steps = blobs
            .iter()
            .find(|(n, _)| n == "mlp Adam steps")
            .and_then(|(_, b)| <[u8; 4]>::try_from(b.as_slice()).ok())
            .ok_or("the state lacks the Adam step count")?;
        self.steps = u32::from_le_bytes(steps);
        Ok(())
    }

    /// Overwrites the parameters (tests and tools).
    pub fn upload_params(&self, params: &[f32]) -> gpu::Result<()> {
        assert_eq!(params.len(), self.shape.param_count());
        self.params.overwrite(params)
    }

    pub fn download_params(&self) -> gpu::Result<Vec<f32>> {
        self.params.download()
    }

    /// The gradient of the last step (mean over its batch).
    pub fn download_grad(&self) -> gpu::Result<Vec<f32>> {
        self.grad.download()
    }

    /// The batch's targets, with the loss and output delta the last step wrote.
    pub fn download_targets(&self) -> gpu::Result<Vec<MlpTarget>> {
        self.targets.download()
    }

    /// A dense network's rows: per row and sector, the targets the batch
    /// holds, and the last step's dLoss/dz.
    pub fn download_dense(&self) -> gpu::Result<(Vec<f32>, Vec<f32>)> {
        let mut all: Vec<f32> = self.dense.as_ref().expect("a dense network").download()?;
        let deltas = all.split_off(self.capacity as usize * self.shape.outputs as usize);
        Ok((all, deltas))
    }

    /// Replaces a dense network's batch (tests): inputs row-major, a target
    /// per row and sector.
    pub fn upload_dense_batch(&self, inputs: &[f32], targets: &[f32]) -> gpu::Result<()> {
        let rows = inputs.len() / self.shape.inputs as usize;
        assert_eq!(targets.len(), rows * self.shape.outputs as usize);
        let blank = vec![MlpTarget::default(); rows];
        self.upload_batch(inputs, &blank)?;
        self.dense
            .as_ref()
            .expect("a dense network")
            .overwrite(targets)
    }

    /// Q of every sector for each row of `inputs`, by the batched forward pass.
    pub fn infer(&self, ctx: &Arc<GpuContext>, inputs: &[f32]) -> gpu::Result<Vec<f32>> {
        let rows = (inputs.len() / self.shape.inputs as usize) as u32;
        let staged = Buffer::gpu_only_with(ctx, "mlp inference inputs", inputs)?;
        let state = MlpBatch {
            count: rows,
            ..Default::default()
        };
        let count = Buffer::gpu_only_with(ctx, "mlp inference rows", &[state])?;
        let outputs = Buffer::gpu_only(
            ctx,
            "mlp inference outputs",
            (rows as u64 * self.shape.outputs as u64 * 4).max(4),
        )?;
        let push = MlpPush {
            capacity: rows,
            ..self.push()
        };
        let forward = ComputePipeline::specialized(
            ctx,
            "mlp inference",
            spirv::MLP_FORWARD,
            size_of::<MlpPush>() as u32,
            &self.shape.constants(),
        )?;
        let set = DescriptorSet::new(
            ctx,
            &forward,
            &[
                (shaders::B_MLP_PARAMS, &self.params),
                (shaders::B_MLP_INPUTS, &staged),
                (shaders::B_MLP_COUNT, &count),
                (shaders::B_MLP_OUTPUTS, &outputs),
            ],
        )?;
        ctx.submit(None, |rec| {
            rec.dispatch(Pass {
                name: "mlp inference",
                pipeline: &forward,
                set: &set,
                push: bytemuck::bytes_of(&push),
                groups: groups(rows),
            })
        })?;
        let mut q: Vec<f32> = outputs.download()?;
        q.truncate(rows as usize * self.shape.outputs as usize);
        Ok(q)
    }

    /// Device memory the network and its batch hold.
    pub fn bytes(&self) -> u64 {
        [
            &self.params,
            &self.moments,
            &self.grad,
            &self.inputs,
            &self.targets,
            &self.batch_state,
            &self.acts,
            &self.deltas,
            &self.buckets,
        ]
        .iter()
        .map(|b| b.size())
        .sum::<u64>()
            + self.dense.as_ref().map_or(0, |d| d.size())
    }
}
