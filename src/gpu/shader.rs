//! SPIR-V modules and the little reflection the layer needs.

use super::{Error, GpuContext, Result};
use ash::vk;

const SPIRV_MAGIC: u32 = 0x0723_0203;
const OP_DECORATE: u32 = 71;
const DECORATION_BINDING: u32 = 33;
const OP_TYPE_IMAGE: u32 = 25;
const OP_TYPE_SAMPLED_IMAGE: u32 = 27;
const OP_TYPE_POINTER: u32 = 32;
const OP_VARIABLE: u32 = 59;
const DIM_BUFFER: u32 = 5;

/// SPIR-V words from the bytes `build.rs` wrote (alignment is not guaranteed).
pub(super) fn words(name: &str, bytes: &[u8]) -> Result<Vec<u32>> {
    if bytes.len() % 4 != 0 || bytes.len() < 20 {
        return Err(Error::Spirv(name.into()));
    }
    let words: Vec<u32> = bytes
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    if words[0] != SPIRV_MAGIC {
        return Err(Error::Spirv(name.into()));
    }
    Ok(words)
}

/// How a binding is declared in the shader.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum BindingKind {
    /// `buffer { ... }`: a storage buffer.
    StorageBuffer,
    /// `uniform utextureBuffer` or `usamplerBuffer` (any buffer image read by
    /// texel fetches): a uniform texel buffer, read through a view of 16-byte
    /// `uvec4` texels.
    UniformTexelBuffer,
}

impl BindingKind {
    pub fn descriptor_type(self) -> vk::DescriptorType {
        match self {
            BindingKind::StorageBuffer => vk::DescriptorType::STORAGE_BUFFER,
            BindingKind::UniformTexelBuffer => vk::DescriptorType::UNIFORM_TEXEL_BUFFER,
        }
    }
}

/// Descriptor bindings the shader declares (all in set 0), sorted by number.
/// A binding whose variable points to an image of dimension Buffer, or to a
/// sampled one, is a uniform texel buffer; every other one is a storage
/// buffer.
pub(super) fn reflect_bindings(words: &[u32]) -> Vec<(u32, BindingKind)> {
    use std::collections::HashMap;
    let mut binding_of = HashMap::new(); // variable id -> binding
    let mut variable_type = HashMap::new(); // variable id -> pointer type id
    let mut pointee = HashMap::new(); // pointer type id -> type id
    let mut sampled_image = HashMap::new(); // sampled image type id -> image type id
    let mut buffer_images = std::collections::HashSet::new(); // image type ids of Dim Buffer
    let mut i = 5; // skip the header
    while i < words.len() {
        let count = (words[i] >> 16) as usize;
        let opcode = words[i] & 0xffff;
        if count == 0 || i + count > words.len() {
            break;
        }
        let w = &words[i..i + count];
        match opcode {
            OP_DECORATE if count == 4 && w[2] == DECORATION_BINDING => {
                binding_of.insert(w[1], w[3]);
            }
            OP_TYPE_IMAGE if count >= 4 && w[3] == DIM_BUFFER => {
                buffer_images.insert(w[1]);
            }
            OP_TYPE_SAMPLED_IMAGE if count == 3 => {
                sampled_image.insert(w[1], w[2]);
            }
            OP_TYPE_POINTER if count == 4 => {
                pointee.insert(w[1], w[3]);
            }
            OP_VARIABLE if count >= 4 => {
                variable_type.insert(w[2], w[1]);
            }
            _ => {}
        }
        i += count;
    }
    let mut bindings: Vec<(u32, BindingKind)> = binding_of
        .iter()
        .map(|(var, &binding)| {
            let texel = variable_type
                .get(var)
                .and_then(|p| pointee.get(p))
                .map(|t| sampled_image.get(t).unwrap_or(t))
                .is_some_and(|image| buffer_images.contains(image));
            let kind = if texel {
                BindingKind::UniformTexelBuffer
            } else {
                BindingKind::StorageBuffer
            };
            (binding, kind)
        })
        .collect();
    bindings.sort_unstable_by_key(|&(b, _)| b);
    bindings.dedup_by_key(|&mut (b, _)| b);
    bindings
}

pub(super) struct ShaderModule<'a> {
    ctx: &'a GpuContext,
    pub raw: vk::ShaderModule,
}

impl<'a> ShaderModule<'a> {
    pub fn new(ctx: &'a GpuContext, words: &[u32]) -> Result<Self> {
        let info = vk::ShaderModuleCreateInfo::default().code(words);
        let raw = unsafe { ctx.device.create_shader_module(&info, None)? };
        Ok(Self { ctx, raw })
    }
}

impl Drop for ShaderModule<'_> {
    fn drop(&mut self) {
        unsafe { self.ctx.device.destroy_shader_module(self.raw, None) };
    }
}
