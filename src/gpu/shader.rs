//! SPIR-V modules and the little reflection the layer needs.

use super::{Error, GpuContext, Result};
use ash::vk;

const SPIRV_MAGIC: u32 = 0x0723_0203;
const OP_DECORATE: u32 = 71;
const DECORATION_BINDING: u32 = 33;

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

/// Descriptor bindings the shader declares, sorted. Every binding is a storage
/// buffer in set 0, so the binding numbers are all the layout needs.
pub(super) fn reflect_bindings(words: &[u32]) -> Vec<u32> {
    let mut bindings = Vec::new();
    let mut i = 5; // skip the header
    while i < words.len() {
        let count = (words[i] >> 16) as usize;
        let opcode = words[i] & 0xffff;
        if count == 0 {
            break;
        }
        if opcode == OP_DECORATE && count == 4 && words[i + 2] == DECORATION_BINDING {
            bindings.push(words[i + 3]);
        }
        i += count;
    }
    bindings.sort_unstable();
    bindings.dedup();
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
