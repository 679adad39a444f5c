//! Compute pipelines whose descriptor layout is reflected from their SPIR-V.

use super::shader::{self, BindingKind, ShaderModule};
use super::{GpuContext, Result};
use ash::vk;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

/// A compute pipeline: every binding is a buffer in set 0 (a storage buffer or
/// a uniform texel buffer), and all pipelines share one push-constant block of
/// `push_size` bytes.
pub struct ComputePipeline {
    ctx: Arc<GpuContext>,
    pub(super) raw: vk::Pipeline,
    pub(super) layout: vk::PipelineLayout,
    pub(super) set_layout: vk::DescriptorSetLayout,
    pub(super) bindings: Vec<(u32, BindingKind)>,
    pub(super) push_size: u32,
    /// Dispatched at least once (see `Recorder::dispatch_covering`).
    pub(super) warm: AtomicBool,
    name: String,
}

impl ComputePipeline {
    pub fn new(ctx: &Arc<GpuContext>, name: &str, spirv: &[u8], push_size: u32) -> Result<Self> {
        Self::specialized(ctx, name, spirv, push_size, &[])
    }

    /// A pipeline whose shader's specialization constants 0, 1, … take the
    /// values `constants` (sizes fixed per pipeline, such as a network's shape).
    pub fn specialized(
        ctx: &Arc<GpuContext>,
        name: &str,
        spirv: &[u8],
        push_size: u32,
        constants: &[u32],
    ) -> Result<Self> {
        let words = shader::words(name, spirv)?;
        let bindings = shader::reflect_bindings(&words);
        let module = ShaderModule::new(ctx, &words)?;
        let device = &ctx.device;

        let layout_bindings: Vec<_> = bindings
            .iter()
            .map(|&(b, kind)| {
                vk::DescriptorSetLayoutBinding::default()
                    .binding(b)
                    .descriptor_type(kind.descriptor_type())
                    .descriptor_count(1)
                    .stage_flags(vk::ShaderStageFlags::COMPUTE)
            })
            .collect();
        let set_layout = unsafe {
            device.create_descriptor_set_layout(
                &vk::DescriptorSetLayoutCreateInfo::default().bindings(&layout_bindings),
                None,
            )?
        };
        let ranges = [vk::PushConstantRange::default()
            .stage_flags(vk::ShaderStageFlags::COMPUTE)
            .offset(0)
            .size(push_size)];
        let set_layouts = [set_layout];
        let mut layout_info = vk::PipelineLayoutCreateInfo::default().set_layouts(&set_layouts);
        if push_size > 0 {
            layout_info = layout_info.push_constant_ranges(&ranges);
        }
        let layout = match unsafe { device.create_pipeline_layout(&layout_info, None) } {
            Ok(l) => l,
            Err(e) => {
                unsafe { device.destroy_descriptor_set_layout(set_layout, None) };
                return Err(e.into());
            }
        };
        let entries: Vec<_> = (0..constants.len() as u32)
            .map(|id| vk::SpecializationMapEntry {
                constant_id: id,
                offset: id * 4,
                size: 4,
            })
            .collect();
        let specialization = vk::SpecializationInfo::default()
            .map_entries(&entries)
            .data(bytemuck::cast_slice(constants));
        let mut stage = vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::COMPUTE)
            .module(module.raw)
            .name(c"main");
        if !constants.is_empty() {
            stage = stage.specialization_info(&specialization);
        }
        let info = [vk::ComputePipelineCreateInfo::default()
            .stage(stage)
            .layout(layout)];
        let raw = match unsafe {
            device.create_compute_pipelines(vk::PipelineCache::null(), &info, None)
        } {
            Ok(p) => p[0],
            Err((_, e)) => {
                unsafe {
                    device.destroy_pipeline_layout(layout, None);
                    device.destroy_descriptor_set_layout(set_layout, None);
                }
                return Err(e.into());
            }
        };
        ctx.set_name(raw, name);
        Ok(Self {
            ctx: ctx.clone(),
            raw,
            layout,
            set_layout,
            bindings,
            push_size,
            warm: AtomicBool::new(false),
            name: name.into(),
        })
    }

    pub fn name(&self) -> &str {
        &self.name
    }
}

impl Drop for ComputePipeline {
    fn drop(&mut self) {
        let device = &self.ctx.device;
        unsafe {
            device.destroy_pipeline(self.raw, None);
            device.destroy_pipeline_layout(self.layout, None);
            device.destroy_descriptor_set_layout(self.set_layout, None);
        }
    }
}
