//! matup's method: the configuration and the pipeline's stages, run as one straight line by
//! `pipeline::upscale`: the residual base, the upsampled render targets, the per-material
//! filter and its training backends, height reconstruction, and self-validation among
//! candidates (`select`). Built on `matup-core` and `matup-eval`.

pub mod bands;
pub mod config;
pub mod features;
pub mod filter;
pub mod height;
pub mod op;
pub mod pipeline;
pub mod residual;
pub mod select;
pub mod targets;
pub mod train;

pub use config::Config;
pub use pipeline::{upscale, upscale_streamed, RunOptions, RunReport};
