//! matup's core: what a plugin author needs, nothing more. Each crate above builds only on
//! the ones below it; the method, evaluation and applications are not here.
//!
//! Rooms:
//! - `map`, `material`, `map_kind`, `svbrdf`: planar f32 maps, a material's maps and where
//!   it came from, the kinds of map, the ten shading parameters of a texel.
//! - `io` (`discover`, `read`, `write`, `stream`, `image_file`, `dds_file`), `layout`,
//!   `file_format`, `normal_convention`: **formats and exporters' layouts** live here:
//!   recognising a folder's files by exporters' names and packings (Unity's mask map, ORM…),
//!   each file's channels (`layout`), reading and writing every format in bands.
//! - `degrade`: what stored maps go through in the wild (block compression, JPEG, dithering,
//!   noise, blur, halos), applied as files store them, for training and measurement.
//! - `shading`, `render`, `lights`, `loss`, `tensor_shading`: **the `ShadingModel` trait**
//!   and registry, the renderer and light sets, the loss norms, shading as candle tensors.
//! - `upsample`, `resample`, `tileable`: **the `RgbUpsampler` trait** and registry, the
//!   separable resampling kernels with border modes, whether a material tiles.
//! - `device`, `device_maps`, `output_band`: the candle device a spec names, maps as tensors
//!   there, and output bands whose maps stay there.
//! - `color`, `plugin`, `progress`, `error`: sRGB, plugin specs and options, the progress
//!   callback, the typed error.
//!
//! The built-in plugins are in `matup-shading` and `matup-upsamplers`.

pub mod color;
pub mod degrade;
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
pub mod texel_trace;
pub mod tileable;
pub mod upsample;

pub use error::{Error, Result};
pub use io::{
    load_material, load_material_from_images, save_material, LoadOptions, MaterialPaths,
    SaveOptions,
};
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
pub use upsample::{upsampler, upsamplers, RgbUpsampler, Unwatched, UpsamplerRegistration, Watch};

// Re-exported so plugin crates register without naming the same `inventory` version, and
// write tensor forms against the same `candle_core`.
pub use candle_core;
pub use inventory;
