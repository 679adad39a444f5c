//! The Vulkan layer: the only module allowed to use `unsafe`.
//!
//! One module per Vulkan concept. Resources hold an `Arc<GpuContext>` and free
//! themselves in `Drop`, so nothing outside this module destroys Vulkan objects.

mod buffer;
mod commands;
mod context;
mod descriptors;
mod pipeline;
mod shader;
mod timestamps;

pub use buffer::{Buffer, STAGING_BYTES};
pub use commands::{Pass, Recorder};
pub use context::{list_devices, ContextOptions, DeviceInfo, GpuContext, Reads};
pub use descriptors::DescriptorSet;
pub use pipeline::ComputePipeline;
pub use timestamps::{PassTiming, Profiler};

use ash::vk;

/// Errors from the GPU layer.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("cannot load the Vulkan loader ({0}); install libvulkan1 and a Vulkan driver (mesa-vulkan-drivers provides the lavapipe CPU device)")]
    Loader(String),
    #[error("no Vulkan device with a compute queue found; install a Vulkan driver (mesa-vulkan-drivers provides the lavapipe CPU device)")]
    NoDevice,
    #[error("no Vulkan device matches '{0}' (run `qtrace devices` to list them)")]
    NoMatchingDevice(String),
    #[error("Vulkan device '{device}' lacks {feature}")]
    MissingFeature { device: String, feature: String },
    #[error("buffer '{name}' needs {size} bytes but device '{device}' allows at most {limit} bytes per storage buffer (`--reads texel` reads the scene through texel buffers, which may hold more)")]
    BufferTooLarge {
        name: String,
        size: u64,
        limit: u64,
        device: String,
    },
    #[error("buffer '{name}' needs {size} bytes but device '{device}' allows at most {limit} bytes per texel buffer view")]
    TexelViewTooLarge {
        name: String,
        size: u64,
        limit: u64,
        device: String,
    },
    #[error("shader '{0}' is not valid SPIR-V")]
    Spirv(String),
    #[error("descriptor set for '{pipeline}' lacks a buffer for binding {binding}")]
    MissingBinding { pipeline: String, binding: u32 },
    #[error("Vulkan call failed: {0}")]
    Vk(#[from] vk::Result),
    #[error("GPU memory allocation failed: {0}")]
    Alloc(#[from] gpu_allocator::AllocationError),
    #[error("GPU memory allocation for buffer '{name}' ({size} bytes) failed: {message}")]
    BufferAlloc {
        name: String,
        size: u64,
        message: String,
    },
}

pub type Result<T> = std::result::Result<T, Error>;
