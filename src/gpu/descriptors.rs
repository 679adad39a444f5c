//! Descriptor sets binding buffers to a pipeline's reflected bindings: storage
//! buffers as they are, uniform texel buffers through a `uvec4` view.

use super::shader::BindingKind;
use super::{Buffer, ComputePipeline, Error, GpuContext, Result};
use ash::vk;
use std::sync::Arc;

/// Format of every texel view: shaders read raw 32-bit words and reinterpret
/// them, so no conversion can touch float bit patterns.
const TEXEL_FORMAT: vk::Format = vk::Format::R32G32B32A32_UINT;
const TEXEL_BYTES: u64 = 16;

/// One descriptor set (with its own small pool) for one pipeline.
pub struct DescriptorSet {
    ctx: Arc<GpuContext>,
    pool: vk::DescriptorPool,
    views: Vec<vk::BufferView>,
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
        let chosen: Vec<(u32, BindingKind, &Buffer)> = pipeline
            .bindings
            .iter()
            .map(|&(b, kind)| {
                buffers
                    .iter()
                    .find(|(n, _)| *n == b)
                    .map(|&(n, buf)| (n, kind, buf))
                    .ok_or_else(|| Error::MissingBinding {
                        pipeline: pipeline.name().into(),
                        binding: b,
                    })
            })
            .collect::<Result<_>>()?;
        // A storage binding sees the whole buffer, which the device bounds
        // (a texel view checks its own limit below).
        let info = ctx.info();
        for &(_, kind, buf) in &chosen {
            if kind == BindingKind::StorageBuffer && buf.capacity() > info.max_storage_buffer_range
            {
                return Err(Error::BufferTooLarge {
                    name: buf.name().into(),
                    size: buf.capacity(),
                    limit: info.max_storage_buffer_range,
                    device: info.name.clone(),
                });
            }
        }
        let device = &ctx.device;
        let count = |kind: BindingKind| chosen.iter().filter(|c| c.1 == kind).count() as u32;
        let sizes: Vec<_> = [BindingKind::StorageBuffer, BindingKind::UniformTexelBuffer]
            .into_iter()
            .filter(|&k| count(k) > 0)
            .map(|k| {
                vk::DescriptorPoolSize::default()
                    .ty(k.descriptor_type())
                    .descriptor_count(count(k))
            })
            .collect();
        let pool = unsafe {
            device.create_descriptor_pool(
                &vk::DescriptorPoolCreateInfo::default()
                    .max_sets(1)
                    .pool_sizes(&sizes),
                None,
            )?
        };
        let mut set = Self {
            ctx: ctx.clone(),
            pool,
            views: Vec::new(),
            raw: vk::DescriptorSet::null(),
        };
        let layouts = [pipeline.set_layout];
        set.raw = unsafe {
            device.allocate_descriptor_sets(
                &vk::DescriptorSetAllocateInfo::default()
                    .descriptor_pool(pool)
                    .set_layouts(&layouts),
            )?[0]
        };
        let mut buffer_infos = Vec::new();
        let mut texel_views = Vec::new();
        for &(binding, kind, buf) in &chosen {
            match kind {
                BindingKind::StorageBuffer => buffer_infos.push((
                    binding,
                    [vk::DescriptorBufferInfo::default()
                        .buffer(buf.raw)
                        .offset(0)
                        .range(vk::WHOLE_SIZE)],
                )),
                BindingKind::UniformTexelBuffer => {
                    let view = set.texel_view(buf)?;
                    texel_views.push((binding, [view]));
                }
            }
        }
        let mut writes: Vec<_> = buffer_infos
            .iter()
            .map(|(binding, info)| {
                vk::WriteDescriptorSet::default()
                    .dst_set(set.raw)
                    .dst_binding(*binding)
                    .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                    .buffer_info(info)
            })
            .collect();
        writes.extend(texel_views.iter().map(|(binding, view)| {
            vk::WriteDescriptorSet::default()
                .dst_set(set.raw)
                .dst_binding(*binding)
                .descriptor_type(vk::DescriptorType::UNIFORM_TEXEL_BUFFER)
                .texel_buffer_view(view)
        }));
        unsafe { device.update_descriptor_sets(&writes, &[]) };
        Ok(set)
    }

    /// A `uvec4` view of the whole of `buf`, owned (and destroyed) by this set.
    fn texel_view(&mut self, buf: &Buffer) -> Result<vk::BufferView> {
        let info = self.ctx.info();
        let texels = buf.capacity() / TEXEL_BYTES;
        if texels > info.max_texel_buffer_elements {
            return Err(Error::TexelViewTooLarge {
                name: buf.name().into(),
                size: buf.capacity(),
                limit: info.max_texel_buffer_elements * TEXEL_BYTES,
                device: info.name.clone(),
            });
        }
        let view = unsafe {
            self.ctx.device.create_buffer_view(
                &vk::BufferViewCreateInfo::default()
                    .buffer(buf.raw)
                    .format(TEXEL_FORMAT)
                    .offset(0)
                    .range(texels * TEXEL_BYTES),
                None,
            )?
        };
        self.views.push(view);
        Ok(view)
    }
}

impl Drop for DescriptorSet {
    fn drop(&mut self) {
        unsafe {
            for &view in &self.views {
                self.ctx.device.destroy_buffer_view(view, None);
            }
            self.ctx.device.destroy_descriptor_pool(self.pool, None);
        }
    }
}
