//! The `RgbUpsampler` plugin trait and its registry.

use crate::map::Map;
use crate::plugin::{find_registration, sorted_registry, PluginOption, PluginSpec, Registration};
use crate::resample::Border;
use crate::{Error, Result};

/// Turns a batch of RGB images (3-channel [`Map`]s in display space, values in [0, 1]) into
/// larger ones. Plugins know nothing of materials or the pipeline.
pub trait RgbUpsampler: Send + Sync {
    /// The one scale this upsampler produces per call (a ×4 network), or `None` when it
    /// handles any integer scale.
    fn native_scale(&self) -> Option<usize> {
        None
    }

    /// How many input texels beyond a region still change its output (the network's
    /// receptive field as far as it matters, a kernel's radius). Streamed runs read this much
    /// context around each band of rows; the default is generous for a plugin that does not
    /// say.
    fn context(&self) -> usize {
        16
    }

    /// The side of the pieces it works in, if any (a network's tiles): streamed runs make
    /// their bands a multiple of it tall, so no band ends in a mostly empty row of tiles.
    fn tile(&self) -> Option<usize> {
        None
    }

    /// Whether images run faster together than one a call (a GPU fills its batch with all
    /// their tiles). Callers with several images to upsample at once (the self-ensemble's
    /// passes) then hand them over in one call, holding all their outputs at once.
    fn batches_images(&self) -> bool {
        false
    }

    /// Upsamples each image by `scale`. `border` says what lies beyond the edges:
    /// [`Border::Wrap`] for tileable materials, whose output must tile too.
    fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>>;
}

/// Checks a requested scale against what an upsampler supports.
pub fn check_scale(name: &str, upsampler: &dyn RgbUpsampler, scale: usize) -> Result<()> {
    match upsampler.native_scale() {
        Some(native) if native != scale => Err(Error::Unsupported {
            plugin: name.to_string(),
            what: format!("scale ×{scale} (it upsamples by ×{native})"),
        }),
        _ if scale == 0 => Err(Error::Invalid("scale must be at least 1".into())),
        _ => Ok(()),
    }
}

/// An upsampler's entry in the registry; submit one with `inventory::submit!`.
pub struct UpsamplerRegistration {
    pub name: &'static str,
    pub description: &'static str,
    pub options: &'static [PluginOption],
    /// Builds the upsampler from the spec's argument.
    pub create: fn(argument: Option<&str>) -> Result<Box<dyn RgbUpsampler>>,
}

inventory::collect!(UpsamplerRegistration);

impl Registration for UpsamplerRegistration {
    fn name(&self) -> &'static str {
        self.name
    }
}

/// Every registered upsampler, sorted by name.
pub fn upsamplers() -> Result<Vec<&'static UpsamplerRegistration>> {
    sorted_registry(
        "upsampler",
        inventory::iter::<UpsamplerRegistration>.into_iter(),
    )
}

/// Builds the upsampler a spec names (`lanczos3`, `bicubic:a=-0.75`, …).
pub fn upsampler(spec: &PluginSpec) -> Result<Box<dyn RgbUpsampler>> {
    let registration = find_registration("upsampler", upsamplers()?, &spec.name)?;
    (registration.create)(spec.argument.as_deref())
}
