//! What a run is given beside its configuration ([`RunOptions`]), and what every level of it
//! shares ([`Context`]).

use std::path::PathBuf;
use std::sync::Arc;

use crate::config::Config;
use matup_core::lights::Light;
use matup_core::material::Material;
use matup_core::progress::Progress;
use matup_core::resample::Border;
use matup_core::shading::ShadingModel;
use matup_core::upsample::RgbUpsampler;

/// Where a run may keep checkpoints, and whether to continue from them.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    pub checkpoint_folder: Option<PathBuf>,
    pub resume: bool,
    /// The true material at the output size, for benchmarks: its exact renders replace the
    /// upsampled ones as targets, which measures the method's ceiling (what the RGB upsampler
    /// costs).
    pub oracle: Option<Material>,
    /// Bytes of heap the output's bands are planned within (none: whole levels). Levels that
    /// train hold their residual base whole whatever the limit.
    pub memory_limit: Option<u64>,
}

/// Everything a level needs that stays the same across levels.
pub(crate) struct Context<'a> {
    pub(crate) config: &'a Config,
    pub(crate) model: Arc<dyn ShadingModel>,
    pub(crate) upsampler: Box<dyn RgbUpsampler>,
    /// The upsampler's name, as the run reports it.
    pub(crate) upsampler_name: &'a str,
    pub(crate) lights: Vec<Light>,
    pub(crate) border: Border,
    pub(crate) options: &'a RunOptions,
    pub(crate) progress: &'a dyn Progress,
}
