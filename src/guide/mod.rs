//! Learned guides: where light comes from, learned while rendering, used to
//! importance-sample bounce directions.

pub mod lookup;
pub mod mlp;
pub mod network;
pub mod sarsa;
pub mod volumes;

pub use sarsa::{SarsaGuide, SarsaSettings};
