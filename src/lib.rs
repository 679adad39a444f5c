//! qtrace: a Vulkan compute path tracer that learns where light comes from.
//!
//! Everything the `qtrace` binary does is callable from here, so tests drive
//! the same code. `unsafe` lives in [`gpu`] only.
#![deny(unsafe_code)]

pub mod bench;
pub mod bsdf;
pub mod cli;
pub mod fuzz;
#[allow(unsafe_code)]
pub mod gpu;
pub mod guide;
pub mod image;
pub mod render;
pub mod sampling;
pub mod scene;
pub mod shaders;

pub use render::{render, Method, Overrides, RenderOutput, RenderSettings, RenderStats};
pub use scene::Scene;
