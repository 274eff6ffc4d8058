//! `matup learn`: super-resolution networks for material maps, trained and judged in render
//! space. A network that matup's ONNX executor runs is rebuilt from candle operations
//! ([`net`]), fed pairs made as matup makes its inputs ([`data`]), and its maps go through what
//! `matup upscale` does with them (decoding, back-projection, rendering: [`post_process`]) before
//! the loss compares their renders with the truth's under random lights ([`train`]). The
//! result is written back into the ONNX file ([`export`]) and validated by `matup upscale`.

pub mod config;
pub mod data;
pub mod export;
pub mod floor_tiles;
pub mod grid_term;
pub mod net;
pub mod post_process;
pub mod train;

pub use config::LearnConfig;
pub use train::{train, Summary};
