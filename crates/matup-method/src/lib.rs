//! matup's method: the configuration and the pipeline's stages, run as one straight line by
//! `pipeline::upscale`: the per-map path (`per_map`, the defaults' upsampling), the residual
//! base, the per-material fit (`fit`: targets, filter, training backends), height
//! reconstruction, self-validation among candidates (`select`), the preview and the run's
//! report. Built on `matup-core` and `matup-eval`.

pub mod bands;
pub mod carried;
pub mod chroma;
pub mod config;
pub mod context;
pub mod features;
pub mod filter;
mod fit;
pub mod height;
pub mod per_map;
pub mod pipeline;
pub mod plan;
pub mod preview;
pub mod report;
pub mod residual;
pub mod select;
pub mod targets;
pub mod texel_loss_op;
pub mod train;

pub use config::Config;
pub use context::RunOptions;
pub use pipeline::{upscale, upscale_streamed};
pub use plan::Plan;
pub use report::{LevelReport, OtherSizeRun, RunReport};
