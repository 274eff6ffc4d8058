//! `matup learn`: super-resolution networks for material maps, trained and judged in render
//! space. The result is written back into the ONNX file and validated by `matup upscale`.
//!
//! Rooms:
//! - `config`, `data`, `floor_tiles`, `degradations`: the settings; training pairs made as
//!   matup makes its inputs; floor tiles cut into training crops, which the corpus lacks; the
//!   compression, noise and sharpening the network's inputs go through.
//! - `net`, `export`: the ONNX network rebuilt from candle operations, and written back.
//! - `post_process`, `grid_term`: what `matup upscale` does with the network's maps, as
//!   differentiable operations; a loss term on the output's texel grid.
//! - `train`: the loop, each step's loss, checkpoints that resume exactly, validation.

pub mod config;
pub mod data;
pub mod degradations;
pub mod export;
pub mod floor_tiles;
pub mod grid_term;
pub mod net;
pub mod post_process;
pub mod train;

pub use config::LearnConfig;
pub use train::{train, Summary};
