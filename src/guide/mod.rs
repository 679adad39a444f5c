//! Learned guides: where light comes from, learned while rendering, used to
//! importance-sample bounce directions.

pub mod lookup;
pub mod mlp;
pub mod network;
pub mod neural;
pub mod sarsa;
pub mod volumes;

pub use neural::{NeuralGuide, NeuralSettings};
pub use sarsa::{SarsaGuide, SarsaSettings};
