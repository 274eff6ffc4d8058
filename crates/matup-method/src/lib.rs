//! matup's method: the settings, the run's plan made of them, and the pipeline's stages, run
//! as one straight line by `pipeline::upscale_streamed`. Built on `matup-core` and
//! `matup-eval`.
//!
//! Rooms:
//! - `config`: the settings (one module per TOML table) and their parsing and checks;
//!   `plan`: the settings and a material made, once, into what a run carries out.
//! - `pipeline`, `context`, `bands`, `report`: the stages' order, what every level shares,
//!   output in bands within a memory limit, the run's report.
//! - `per_map`, `residual`, `normal_blend`, `chroma`, `carried`, `height`: the defaults'
//!   per-map path with its self-ensemble, back-projection, a noisy material's normals from
//!   two routes, the base colour's chroma, maps carried unrendered.
//! - `fit`, `targets`, `features`, `filter`, `train`, `texel_loss_op`: the paper's
//!   per-material filter, its targets and training (two backends, one Adam).
//! - `select`, `preview`: self-validation among candidate settings; `preview.png`.

pub mod bands;
pub mod carried;
pub mod chroma;
pub mod config;
pub mod context;
pub mod features;
pub mod filter;
mod fit;
pub mod height;
pub mod normal_blend;
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
