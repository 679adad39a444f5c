//! Command recording and submission. Every dispatch goes through
//! [`Recorder::dispatch`], which adds the barrier, debug label and timestamps.

use super::{Buffer, ComputePipeline, DescriptorSet, GpuContext, Profiler, Result};
use ash::vk;
use std::ffi::CString;
use std::sync::atomic::Ordering;

/// The context's one command buffer and fence; each submit waits, so one suffices.
pub(super) struct Submitter {
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
}

impl Submitter {
    pub fn new(device: &ash::Device, queue_family: u32) -> Result<Self> {
        unsafe {
            let pool = device.create_command_pool(
                &vk::CommandPoolCreateInfo::default()
                    .queue_family_index(queue_family)
                    .flags(vk::CommandPoolCreateFlags::TRANSIENT),
                None,
            )?;
            let cmd = match device.allocate_command_buffers(
                &vk::CommandBufferAllocateInfo::default()
                    .command_pool(pool)
                    .level(vk::CommandBufferLevel::PRIMARY)
                    .command_buffer_count(1),
            ) {
                Ok(c) => c[0],
                Err(e) => {
                    device.destroy_command_pool(pool, None);
                    return Err(e.into());
                }
            };
            let fence = match device.create_fence(&vk::FenceCreateInfo::default(), None) {
                Ok(f) => f,
                Err(e) => {
                    device.destroy_command_pool(pool, None);
                    return Err(e.into());
                }
            };
            Ok(Self { pool, cmd, fence })
        }
    }

    pub unsafe fn destroy(&mut self, device: &ash::Device) {
        device.destroy_fence(self.fence, None);
        device.destroy_command_pool(self.pool, None);
    }
}

/// One compute dispatch.
pub struct Pass<'a> {
    /// Shown in debug tools and in the `--profile` table.
    pub name: &'a str,
    pub pipeline: &'a ComputePipeline,
    pub set: &'a DescriptorSet,
    /// Push constants (the shared `PassParams` block).
    pub push: &'a [u8],
    pub groups: [u32; 3],
}

/// Records commands into the context's command buffer during [`GpuContext::submit`].
pub struct Recorder<'a> {
    ctx: &'a GpuContext,
    cmd: vk::CommandBuffer,
    profiler: Option<&'a mut Profiler>,
}

impl Recorder<'_> {
    fn barrier(
        &self,
        src: vk::PipelineStageFlags,
        src_access: vk::AccessFlags,
        dst: vk::PipelineStageFlags,
        dst_access: vk::AccessFlags,
    ) {
        let barrier = [vk::MemoryBarrier::default()
            .src_access_mask(src_access)
            .dst_access_mask(dst_access)];
        unsafe {
            self.ctx.device.cmd_pipeline_barrier(
                self.cmd,
                src,
                dst,
                vk::DependencyFlags::empty(),
                &barrier,
                &[],
                &[],
            )
        };
    }

    /// Records one compute pass: barrier, label, timestamps, dispatch.
    pub fn dispatch(&mut self, pass: Pass<'_>) {
        self.dispatch_covering(pass, 1);
    }

    /// [`Recorder::dispatch`] for a pass that does the work of `passes` sample
    /// passes at once: the profiler counts each a `1/passes` share of its time.
    pub fn dispatch_covering(&mut self, pass: Pass<'_>, passes: u32) {
        let device = &self.ctx.device;
        // A pass may read or overwrite anything an earlier pass or copy wrote.
        let barrier = |r: &Self| {
            r.barrier(
                vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER,
                vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE,
                vk::PipelineStageFlags::COMPUTE_SHADER,
                vk::AccessFlags::SHADER_READ | vk::AccessFlags::SHADER_WRITE,
            )
        };
        barrier(self);
        let label = CString::new(pass.name).unwrap_or_default();
        if let Some(du) = &self.ctx.debug_utils {
            let info = vk::DebugUtilsLabelEXT::default().label_name(&label);
            unsafe { du.cmd_begin_debug_utils_label(self.cmd, &info) };
        }
        unsafe {
            device.cmd_bind_pipeline(self.cmd, vk::PipelineBindPoint::COMPUTE, pass.pipeline.raw);
            device.cmd_bind_descriptor_sets(
                self.cmd,
                vk::PipelineBindPoint::COMPUTE,
                pass.pipeline.layout,
                0,
                &[pass.set.raw],
                &[],
            );
            if pass.pipeline.push_size > 0 {
                debug_assert_eq!(pass.push.len() as u32, pass.pipeline.push_size);
                device.cmd_push_constants(
                    self.cmd,
                    pass.pipeline.layout,
                    vk::ShaderStageFlags::COMPUTE,
                    0,
                    pass.push,
                );
            }
        }
        // llvmpipe compiles a kernel at its first dispatch (hundreds of
        // milliseconds where Mesa's disk cache does not have it yet): an
        // empty dispatch does that first, timed apart, so that the pass's
        // time and a render's clock hold the kernel's work alone.
        if !pass.pipeline.warm.swap(true, Ordering::Relaxed) {
            let compile = self
                .profiler
                .as_deref_mut()
                .and_then(|p| p.begin(self.cmd, pass.name, 0));
            unsafe { device.cmd_dispatch(self.cmd, 0, 0, 0) };
            if let (Some(p), Some(q)) = (self.profiler.as_deref_mut(), compile) {
                p.end(self.cmd, q);
            }
            // Validation counts the empty dispatch as touching every binding.
            barrier(self);
        }
        let query = self
            .profiler
            .as_deref_mut()
            .and_then(|p| p.begin(self.cmd, pass.name, passes.max(1)));
        unsafe {
            device.cmd_dispatch(self.cmd, pass.groups[0], pass.groups[1], pass.groups[2]);
        }
        if let (Some(p), Some(q)) = (self.profiler.as_deref_mut(), query) {
            p.end(self.cmd, q);
        }
        if let Some(du) = &self.ctx.debug_utils {
            unsafe { du.cmd_end_debug_utils_label(self.cmd) };
        }
    }

    /// Copies the whole of `src` into `dst`.
    pub fn copy(&mut self, src: &Buffer, dst: &Buffer) {
        self.copy_region(src, dst, 0, src.size().min(dst.size()));
    }

    /// Copies `size` bytes from the start of `src` to `dst` at `offset`.
    pub fn copy_region(&mut self, src: &Buffer, dst: &Buffer, offset: u64, size: u64) {
        // The copy reads what shaders or earlier copies wrote.
        self.barrier(
            vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER,
            vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE,
            vk::PipelineStageFlags::TRANSFER,
            vk::AccessFlags::TRANSFER_READ | vk::AccessFlags::TRANSFER_WRITE,
        );
        let region = [vk::BufferCopy::default().dst_offset(offset).size(size)];
        unsafe {
            self.ctx
                .device
                .cmd_copy_buffer(self.cmd, src.raw, dst.raw, &region)
        };
    }

    /// Fills `buffer` with the 32-bit word `value`.
    pub fn fill(&mut self, buffer: &Buffer, value: u32) {
        // Earlier passes must be done with the buffer before it is overwritten.
        self.barrier(
            vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER,
            vk::AccessFlags::SHADER_READ
                | vk::AccessFlags::SHADER_WRITE
                | vk::AccessFlags::TRANSFER_WRITE,
            vk::PipelineStageFlags::TRANSFER,
            vk::AccessFlags::TRANSFER_WRITE,
        );
        unsafe {
            self.ctx
                .device
                .cmd_fill_buffer(self.cmd, buffer.raw, 0, vk::WHOLE_SIZE, value)
        };
    }
}

impl GpuContext {
    /// Records commands with `record`, submits them and waits for completion.
    /// With a profiler, each pass gets a timestamp pair collected after the wait.
    pub fn submit<R>(
        &self,
        mut profiler: Option<&mut Profiler>,
        record: impl FnOnce(&mut Recorder<'_>) -> R,
    ) -> Result<R> {
        let submitter = self.submitter.lock().unwrap_or_else(|e| e.into_inner());
        let device = &self.device;
        let cmd = submitter.cmd;
        unsafe {
            device.reset_command_pool(submitter.pool, vk::CommandPoolResetFlags::empty())?;
            device.begin_command_buffer(
                cmd,
                &vk::CommandBufferBeginInfo::default()
                    .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT),
            )?;
        }
        if let Some(p) = profiler.as_deref_mut() {
            p.reset();
        }
        let mut recorder = Recorder {
            ctx: self,
            cmd,
            profiler: profiler.as_deref_mut(),
        };
        let result = record(&mut recorder);
        // The host reads mapped buffers once the fence signals.
        recorder.barrier(
            vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER,
            vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE,
            vk::PipelineStageFlags::HOST,
            vk::AccessFlags::HOST_READ,
        );
        unsafe {
            device.end_command_buffer(cmd)?;
            let cmds = [cmd];
            let submit = [vk::SubmitInfo::default().command_buffers(&cmds)];
            device.queue_submit(self.queue, &submit, submitter.fence)?;
            device.wait_for_fences(&[submitter.fence], true, u64::MAX)?;
            device.reset_fences(&[submitter.fence])?;
        }
        if let Some(p) = profiler {
            p.collect()?;
        }
        Ok(result)
    }
}
