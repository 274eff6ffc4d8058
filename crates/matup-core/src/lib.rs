//! matup's core: the material model and its I/O, the plugin traits (`RgbUpsampler`,
//! `ShadingModel`) with their registries, lights, resampling and rendering.

pub mod baseline;
pub mod batch;
pub mod color;
pub mod config;
mod error;
pub mod experiment;
pub mod features;
pub mod filter;
pub mod folder;
pub mod gemm;
pub mod height;
pub mod html;
pub mod io;
pub mod lights;
pub mod loss;
pub mod map;
pub mod material;
pub mod metrics;
pub mod op;
pub mod pipeline;
pub mod plugin;
pub mod progress;
pub mod render;
pub mod resample;
pub mod residual;
pub mod select;
pub mod shading;
pub mod simd;
pub mod svbrdf;
pub mod targets;
pub mod tensor;
pub mod text;
pub mod tileable;
pub mod train;
pub mod upsample;
pub mod view;

pub use config::Config;
pub use error::{Error, Result};
pub use io::{load_material, save_material, LoadOptions, MaterialPaths, SaveOptions};
pub use lights::{Light, LightSample, LightSetSpec};
pub use loss::LossNorm;
pub use map::{Dihedral, Map};
pub use material::{FileFormat, MapKind, Material, NormalConvention};
pub use pipeline::{upscale, RunOptions, RunReport};
pub use plugin::{PluginOption, PluginSpec};
pub use render::{render, RenderOptions};
pub use resample::{Border, Kernel};
pub use shading::{
    shading_model, shading_models, ShadingModel, ShadingModelRegistration, Svbrdf, Texel,
};
pub use upsample::{upsampler, upsamplers, RgbUpsampler, UpsamplerRegistration};

// Re-exported so plugin crates register without naming the same `inventory` version, and
// write tensor forms against the same `candle_core`.
pub use candle_core;
pub use inventory;
