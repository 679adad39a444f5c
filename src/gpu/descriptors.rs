//! Descriptor sets binding storage buffers to a pipeline's reflected bindings.

use super::{Buffer, ComputePipeline, Error, GpuContext, Result};
use ash::vk;
use std::sync::Arc;

/// One descriptor set (with its own small pool) for one pipeline.
pub struct DescriptorSet {
    ctx: Arc<GpuContext>,
    pool: vk::DescriptorPool,
    pub(super) raw: vk::DescriptorSet,
}

impl DescriptorSet {
    /// Binds `buffers` (binding number, buffer); every binding the shader
    /// declares must be given, extra ones are ignored.
    pub fn new(
        ctx: &Arc<GpuContext>,
        pipeline: &ComputePipeline,
        buffers: &[(u32, &Buffer)],
    ) -> Result<Self> {
        let chosen: Vec<(u32, &Buffer)> = pipeline
            .bindings
            .iter()
            .map(|&b| {
                buffers
                    .iter()
                    .find(|(n, _)| *n == b)
                    .map(|&(n, buf)| (n, buf))
                    .ok_or_else(|| Error::MissingBinding {
                        pipeline: pipeline.name().into(),
                        binding: b,
                    })
            })
            .collect::<Result<_>>()?;
        let device = &ctx.device;
        let sizes = [vk::DescriptorPoolSize::default()
            .ty(vk::DescriptorType::STORAGE_BUFFER)
            .descriptor_count(chosen.len().max(1) as u32)];
        let pool = unsafe {
            device.create_descriptor_pool(
                &vk::DescriptorPoolCreateInfo::default()
                    .max_sets(1)
                    .pool_sizes(&sizes),
                None,
            )?
        };
        let layouts = [pipeline.set_layout];
        let raw = match unsafe {
            device.allocate_descriptor_sets(
                &vk::DescriptorSetAllocateInfo::default()
                    .descriptor_pool(pool)
                    .set_layouts(&layouts),
            )
        } {
            Ok(sets) => sets[0],
            Err(e) => {
                unsafe { device.destroy_descriptor_pool(pool, None) };
                return Err(e.into());
            }
        };
        let infos: Vec<[vk::DescriptorBufferInfo; 1]> = chosen
            .iter()
            .map(|(_, buf)| {
                [vk::DescriptorBufferInfo::default()
                    .buffer(buf.raw)
                    .offset(0)
                    .range(vk::WHOLE_SIZE)]
            })
            .collect();
        let writes: Vec<_> = chosen
            .iter()
            .zip(&infos)
            .map(|((binding, _), info)| {
                vk::WriteDescriptorSet::default()
                    .dst_set(raw)
                    .dst_binding(*binding)
                    .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                    .buffer_info(info)
            })
            .collect();
        unsafe { device.update_descriptor_sets(&writes, &[]) };
        Ok(Self {
            ctx: ctx.clone(),
            pool,
            raw,
        })
    }
}

impl Drop for DescriptorSet {
    fn drop(&mut self) {
        unsafe { self.ctx.device.destroy_descriptor_pool(self.pool, None) };
    }
}
