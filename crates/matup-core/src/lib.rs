//! matup's core: what a plugin author needs, nothing more.
//!
//! It holds the material model (`Map`, `Material`) with its I/O and conventions, colour,
//! resampling and tileability measures, lights, the renderer, the plugin traits
//! (`RgbUpsampler`, `ShadingModel`) with their registries and tensor forms, errors and
//! progress callbacks.
//!
//! It holds no method, evaluation or application code: the pipeline, its configuration and
//! training are in `matup-method`, metrics and per-map baselines in `matup-eval`, the batch
//! runner, pages and experiments in `matup-apps`; each crate builds only on the ones below it.

pub mod color;
pub mod device;
pub mod device_maps;
mod error;
mod file_format;
pub mod io;
pub mod layout;
pub mod lights;
pub mod loss;
pub mod map;
mod map_kind;
pub mod material;
pub mod normal_convention;
pub mod output_band;
pub mod plugin;
pub mod progress;
pub mod render;
pub mod resample;
pub mod shading;
pub mod svbrdf;
pub mod tensor_shading;
pub mod tileable;
pub mod upsample;

pub use error::{Error, Result};
pub use io::{load_material, save_material, LoadOptions, MaterialPaths, SaveOptions};
pub use lights::{Light, LightSample, LightSetSpec};
pub use loss::LossNorm;
pub use map::{Dihedral, Map};
pub use material::{BlockQuality, DdsFormat, FileFormat, MapKind, Material, NormalConvention};
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
