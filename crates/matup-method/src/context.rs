//! What a run is given beside its configuration ([`RunOptions`]), and what every level of it
//! shares ([`Context`]).

use std::path::PathBuf;
use std::sync::Arc;

use crate::config::Config;
use crate::per_map::MapUpsamplers;
use matup_core::candle_core::{Device, Tensor};
use matup_core::lights::Light;
use matup_core::map::Map;
use matup_core::material::{MapKind, Material};
use matup_core::progress::Progress;
use matup_core::resample::Border;
use matup_core::shading::ShadingModel;
use matup_core::upsample::{RgbUpsampler, Watch};
use matup_core::{Error, Result};

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

/// Everything a level needs: the run's, with the settings as that level runs them
/// (`crate::plan::Level`).
#[derive(Clone)]
pub(crate) struct Context<'a> {
    pub(crate) config: &'a Config,
    pub(crate) model: Arc<dyn ShadingModel>,
    pub(crate) upsampler: &'a (dyn RgbUpsampler + 'a),
    /// The maps routed apart whose upsampler is another (`crate::plan::Setup::apart`).
    pub(crate) apart: Vec<(MapKind, &'a (dyn RgbUpsampler + 'a))>,
    /// The clean route's upsampler for a noisy material's normals
    /// (`crate::plan::Setup::clean_normals`).
    pub(crate) clean_normals: Option<&'a (dyn RgbUpsampler + 'a)>,
    /// The upsamplers' names, as the run reports them.
    pub(crate) upsampler_name: &'a str,
    pub(crate) lights: Vec<Light>,
    pub(crate) border: Border,
    pub(crate) options: &'a RunOptions,
    pub(crate) progress: &'a dyn Progress,
}

impl<'a> Context<'a> {
    /// The upsampler of each map.
    pub(crate) fn map_upsamplers(&self) -> MapUpsamplers<'a> {
        MapUpsamplers {
            run: self.upsampler,
            apart: self.apart.clone(),
            clean_normals: self.clean_normals,
        }
    }
}

/// The run's upsampler, stopping the run where the caller asks ([`Progress::cancelled`]):
/// each call checks first, and a network's calls at every batch of tiles, which they report
/// ([`Progress::tiles`]), so Ctrl-C stops a run within a tile's time.
pub(crate) struct StopsOnRequest<'a> {
    pub(crate) inner: &'a dyn RgbUpsampler,
    pub(crate) progress: &'a dyn Progress,
}

impl StopsOnRequest<'_> {
    fn go_on(&self) -> Result<()> {
        match self.progress.cancelled() {
            true => Err(Error::Interrupted),
            false => Ok(()),
        }
    }
}

impl RgbUpsampler for StopsOnRequest<'_> {
    fn native_scale(&self) -> Option<usize> {
        self.inner.native_scale()
    }
    fn context(&self) -> usize {
        self.inner.context()
    }
    fn tile(&self) -> Option<usize> {
        self.inner.tile()
    }
    fn batches_images(&self) -> bool {
        self.inner.batches_images()
    }
    fn serves_smaller_scales(&self) -> bool {
        self.inner.serves_smaller_scales()
    }
    fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>> {
        self.go_on()?;
        self.inner.upsample_watched(images, scale, border, self)
    }
    fn device(&self) -> Option<Device> {
        self.inner.device()
    }
    fn placement(&self) -> Option<String> {
        self.inner.placement()
    }
    fn upsample_on_device(
        &self,
        images: &[Map],
        scale: usize,
        border: Border,
    ) -> Result<Vec<Tensor>> {
        self.go_on()?;
        self.inner
            .upsample_on_device_watched(images, scale, border, self)
    }
}

impl Watch for StopsOnRequest<'_> {
    fn pieces_done(&self, done: usize, total: usize) -> Result<()> {
        self.progress.tiles(done as u64, total as u64);
        self.go_on()
    }
}
