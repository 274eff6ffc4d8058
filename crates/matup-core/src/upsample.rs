//! The `RgbUpsampler` plugin trait and its registry.

use candle_core::{Device, Tensor};

use crate::device_maps::{upload, Separable};
use crate::map::Map;
use crate::plugin::{find_registration, sorted_registry, PluginOption, PluginSpec, Registration};
use crate::resample::{shrink, upsample, Border, Kernel, Shrink};
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

    /// Whether it makes the scales below its native one itself ([`through_native`]'s
    /// wrapper): then the registry does not wrap it again.
    fn serves_smaller_scales(&self) -> bool {
        false
    }

    /// Upsamples each image by `scale`. `border` says what lies beyond the edges:
    /// [`Border::Wrap`] for tileable materials, whose output must tile too.
    fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>>;

    /// [`RgbUpsampler::upsample`], telling `watch` how far the call has got after each of its
    /// pieces of work (a batch of a network's tiles) and stopping where `watch` says so. An
    /// upsampler that works in pieces implements it (and `upsample` as it, [`Unwatched`]);
    /// the default makes the call whole.
    fn upsample_watched(
        &self,
        images: &[Map],
        scale: usize,
        border: Border,
        _watch: &dyn Watch,
    ) -> Result<Vec<Map>> {
        self.upsample(images, scale, border)
    }

    /// The candle device it computes on, where it can leave its outputs there
    /// ([`RgbUpsampler::upsample_on_device`]): the stages after it then run on that device
    /// too, and only the finished maps come back to the host.
    fn device(&self) -> Option<Device> {
        None
    }

    /// Where it computes and why, in words, where a run should say so: a network on a GPU
    /// adapter, or on the CPU because `device=auto` found none. `None` for the host's kernels.
    fn placement(&self) -> Option<String> {
        None
    }

    /// [`RgbUpsampler::upsample`], the outputs left on [`RgbUpsampler::device`] as
    /// `[3, height, width]` tensors.
    fn upsample_on_device(
        &self,
        _images: &[Map],
        _scale: usize,
        _border: Border,
    ) -> Result<Vec<Tensor>> {
        Err(Error::Invalid(
            "this upsampler keeps no outputs on a device".into(),
        ))
    }

    /// [`RgbUpsampler::upsample_on_device`] as [`RgbUpsampler::upsample_watched`] watches.
    fn upsample_on_device_watched(
        &self,
        images: &[Map],
        scale: usize,
        border: Border,
        _watch: &dyn Watch,
    ) -> Result<Vec<Tensor>> {
        self.upsample_on_device(images, scale, border)
    }
}

/// Follows an upsampler's call piece by piece ([`RgbUpsampler::upsample_watched`]): a run's
/// progress per tile, and where it asks to stop, the stop.
pub trait Watch: Sync {
    /// `done` of the call's `total` pieces are finished; an error ends the call with it.
    fn pieces_done(&self, done: usize, total: usize) -> Result<()>;
}

/// Watches nothing: [`RgbUpsampler::upsample`] as [`RgbUpsampler::upsample_watched`].
pub struct Unwatched;

impl Watch for Unwatched {
    fn pieces_done(&self, _done: usize, _total: usize) -> Result<()> {
        Ok(())
    }
}

/// An upsampler shared (a process's cache of loaded networks hands out clones) is the
/// upsampler itself.
impl<T: RgbUpsampler + ?Sized> RgbUpsampler for std::sync::Arc<T> {
    fn native_scale(&self) -> Option<usize> {
        (**self).native_scale()
    }
    fn context(&self) -> usize {
        (**self).context()
    }
    fn tile(&self) -> Option<usize> {
        (**self).tile()
    }
    fn batches_images(&self) -> bool {
        (**self).batches_images()
    }
    fn serves_smaller_scales(&self) -> bool {
        (**self).serves_smaller_scales()
    }
    fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>> {
        (**self).upsample(images, scale, border)
    }
    fn upsample_watched(
        &self,
        images: &[Map],
        scale: usize,
        border: Border,
        watch: &dyn Watch,
    ) -> Result<Vec<Map>> {
        (**self).upsample_watched(images, scale, border, watch)
    }
    fn device(&self) -> Option<Device> {
        (**self).device()
    }
    fn placement(&self) -> Option<String> {
        (**self).placement()
    }
    fn upsample_on_device(
        &self,
        images: &[Map],
        scale: usize,
        border: Border,
    ) -> Result<Vec<Tensor>> {
        (**self).upsample_on_device(images, scale, border)
    }
    fn upsample_on_device_watched(
        &self,
        images: &[Map],
        scale: usize,
        border: Border,
        watch: &dyn Watch,
    ) -> Result<Vec<Tensor>> {
        (**self).upsample_on_device_watched(images, scale, border, watch)
    }
}

/// An upsampler that interpolates with a separable kernel (the registry's `bilinear`,
/// `bicubic` and `lanczos3`). [`KernelUpsampler::on`] a device, it leaves its outputs there,
/// for a run whose other maps a network upsamples on that device.
pub struct KernelUpsampler {
    pub kernel: Kernel,
    device: Option<Device>,
}

impl KernelUpsampler {
    /// `kernel` on the host.
    pub fn new(kernel: Kernel) -> KernelUpsampler {
        KernelUpsampler {
            kernel,
            device: None,
        }
    }

    /// `kernel`, its outputs left on `device`.
    pub fn on(kernel: Kernel, device: Device) -> KernelUpsampler {
        KernelUpsampler {
            kernel,
            device: Some(device),
        }
    }
}

impl RgbUpsampler for KernelUpsampler {
    fn context(&self) -> usize {
        self.kernel.radius().ceil() as usize
    }

    fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>> {
        Ok(images
            .iter()
            .map(|image| upsample(image, scale, self.kernel, border))
            .collect())
    }

    fn device(&self) -> Option<Device> {
        self.device.clone()
    }

    fn upsample_on_device(
        &self,
        images: &[Map],
        scale: usize,
        border: Border,
    ) -> Result<Vec<Tensor>> {
        let Some(device) = &self.device else {
            return Err(Error::Invalid(
                "this kernel upsampler is on the host".into(),
            ));
        };
        let mut out = Vec::with_capacity(images.len());
        let mut resamplings = Vec::new();
        for image in images {
            let size = [image.width(), image.height()];
            let resampling = once_a_size(&mut resamplings, size, || {
                Separable::upsample(size, scale, self.kernel, border, device)
            })?;
            out.push(resampling.apply(&upload(image, device)?)?);
        }
        Ok(out)
    }
}

/// The resampling of images of `size` from `made`, made there first if it is not: one a size,
/// which the self-ensemble's passes share.
fn once_a_size(
    made: &mut Vec<([usize; 2], Separable)>,
    size: [usize; 2],
    make: impl FnOnce() -> candle_core::Result<Separable>,
) -> candle_core::Result<&Separable> {
    let i = match made.iter().position(|(s, _)| *s == size) {
        Some(i) => i,
        None => {
            made.push((size, make()?));
            made.len() - 1
        }
    };
    Ok(&made[i].1)
}

/// Checks a requested scale against what an upsampler supports: any scale, or one up to its
/// native scale (smaller ones go through it, [`route`]).
pub fn check_scale(name: &str, upsampler: &dyn RgbUpsampler, scale: usize) -> Result<()> {
    match upsampler.native_scale() {
        Some(native) if native < scale => Err(Error::Unsupported {
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

/// Builds the upsampler a spec names (`lanczos3`, `bicubic:a=-0.75`, …). One with a native
/// scale serves the smaller scales too, through its own ([`route`]).
pub fn upsampler(spec: &PluginSpec) -> Result<Box<dyn RgbUpsampler>> {
    upsampler_shrinking_by(spec, Shrink::Area)
}

/// [`upsampler`] with another filter down from its native scale to the smaller ones (studies
/// compare them: docs/experiments/2026-11-26-every-scale.md).
pub fn upsampler_shrinking_by(spec: &PluginSpec, down: Shrink) -> Result<Box<dyn RgbUpsampler>> {
    let registration = find_registration("upsampler", upsamplers()?, &spec.name)?;
    Ok(through_native(
        (registration.create)(spec.argument.as_deref())?,
        down,
    ))
}

/// `upsampler`, made to serve the scales below its native one through it ([`route`]); as it
/// is where it has none.
pub fn serving_smaller_scales(upsampler: Box<dyn RgbUpsampler>) -> Box<dyn RgbUpsampler> {
    through_native(upsampler, Shrink::Area)
}

/// [`serving_smaller_scales`] with `down` as the filter down from the native scale.
pub fn through_native(upsampler: Box<dyn RgbUpsampler>, down: Shrink) -> Box<dyn RgbUpsampler> {
    match upsampler.native_scale() {
        Some(_) if upsampler.serves_smaller_scales() => upsampler,
        Some(native) => Box::new(ThroughNative {
            inner: upsampler,
            native,
            down,
        }),
        None => upsampler,
    }
}

/// How an upsampler of `native` scale (`None`: any) makes ×`scale`: `None` where it upsamples
/// by `scale` itself, else the words for its route, ×native and then an area filter down to
/// ×scale. A ×4 network at ×2 keeps what it sees at ×4: the output box-filtered to ×2 is
/// sharper than a ×2 network's (docs/experiments/2026-11-26-every-scale.md).
pub fn route(native: Option<usize>, scale: usize) -> Option<String> {
    let native = native.filter(|&n| n > scale)?;
    Some(if native % scale == 0 {
        format!("×{native}, then ÷{} by area", native / scale)
    } else {
        format!("×{native}, then area-shrunk to ×{scale}")
    })
}

/// An upsampler of one native scale serving smaller ones: each image ×native, then shrunk
/// (by area averaging in the defaults) to ×scale.
struct ThroughNative {
    inner: Box<dyn RgbUpsampler>,
    native: usize,
    down: Shrink,
}

impl RgbUpsampler for ThroughNative {
    fn native_scale(&self) -> Option<usize> {
        Some(self.native)
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
        true
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
        self.upsample_on_device_watched(images, scale, border, &Unwatched)
    }

    fn upsample_on_device_watched(
        &self,
        images: &[Map],
        scale: usize,
        border: Border,
        watch: &dyn Watch,
    ) -> Result<Vec<Tensor>> {
        if scale >= self.native {
            return (self.inner).upsample_on_device_watched(images, scale, border, watch);
        }
        let large = (self.inner).upsample_on_device_watched(images, self.native, border, watch)?;
        let mut out = Vec::with_capacity(large.len());
        let mut shrinks = Vec::new();
        for (up, image) in large.into_iter().zip(images) {
            let size = [image.width(), image.height()];
            let (_, h, w) = up.dims3()?;
            if [w, h] != size.map(|n| n * self.native) {
                out.push(up); // the wrong size, as the caller's check will say
                continue;
            }
            let down = once_a_size(&mut shrinks, size, || {
                let to = size.map(|n| n * scale);
                Separable::shrink([w, h], to, self.down, border, up.device())
            })?;
            out.push(down.apply(&up)?);
        }
        Ok(out)
    }

    fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>> {
        self.upsample_watched(images, scale, border, &Unwatched)
    }

    fn upsample_watched(
        &self,
        images: &[Map],
        scale: usize,
        border: Border,
        watch: &dyn Watch,
    ) -> Result<Vec<Map>> {
        if scale >= self.native {
            // Its own scale, or one it refuses.
            return self.inner.upsample_watched(images, scale, border, watch);
        }
        let large = self
            .inner
            .upsample_watched(images, self.native, border, watch)?;
        Ok((large.into_iter().zip(images))
            .map(|(up, image)| {
                let native = [image.width(), image.height()].map(|n| n * self.native);
                if [up.width(), up.height()] == native {
                    let size = [image.width(), image.height()].map(|n| n * scale);
                    shrink(&up, size[0], size[1], self.down, border)
                } else {
                    up // the wrong size, as the caller's check will say
                }
            })
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::resample::{box_downsample, Kernel};

    /// A ×4-only upsampler: every texel repeated 4 × 4.
    struct Nearest4;
    impl RgbUpsampler for Nearest4 {
        fn native_scale(&self) -> Option<usize> {
            Some(4)
        }
        fn upsample(&self, images: &[Map], scale: usize, _: Border) -> Result<Vec<Map>> {
            assert_eq!(scale, 4, "called at its own scale only");
            Ok(images
                .iter()
                .map(|m| {
                    Map::from_fn(m.width() * 4, m.height() * 4, m.channels(), |c, y, x| {
                        m.get(c, y / 4, x / 4)
                    })
                })
                .collect())
        }
    }

    #[test]
    fn a_route_with_its_own_filter_down_is_not_wrapped_again() {
        let image = Map::from_fn(6, 6, 1, |_, y, x| ((x * 3 + y * 7) % 5) as f32 / 4.0);
        let run = |up: Box<dyn RgbUpsampler>| {
            (up.upsample(std::slice::from_ref(&image), 3, Border::Wrap)
                .unwrap())
            .remove(0)
        };
        let area = run(serving_smaller_scales(Box::new(Nearest4)));
        let lanczos = through_native(Box::new(Nearest4), Shrink::Kernel(Kernel::Lanczos3));
        let lanczos = run(serving_smaller_scales(lanczos));
        let differ = (area.data().iter().zip(lanczos.data())).any(|(a, b)| (a - b).abs() > 1e-3);
        assert!(differ, "the Lanczos route shrank by area");
    }

    #[test]
    fn a_native_scale_serves_the_smaller_ones_through_it() {
        let image = Map::from_fn(6, 5, 3, |c, y, x| ((x * 3 + y * 7 + c) % 5) as f32 / 4.0);
        let up = serving_smaller_scales(Box::new(Nearest4));
        for scale in [2, 3, 4] {
            check_scale("nearest4", up.as_ref(), scale).unwrap();
            let out = up
                .upsample(std::slice::from_ref(&image), scale, Border::Mirror)
                .unwrap();
            let out = &out[0];
            assert_eq!((out.width(), out.height()), (6 * scale, 5 * scale));
            // Whatever the route, the output box-filters back to the input (nearest keeps
            // every block's mean; area filters keep means).
            let back = box_downsample(out, scale);
            let worst =
                (back.data().iter().zip(image.data())).fold(0f32, |m, (a, b)| m.max((a - b).abs()));
            assert!(worst < 1e-5, "×{scale}: {worst}");
        }
        assert!(check_scale("nearest4", up.as_ref(), 8).is_err());
        assert_eq!(route(Some(4), 2).as_deref(), Some("×4, then ÷2 by area"));
        assert_eq!(
            route(Some(4), 3).as_deref(),
            Some("×4, then area-shrunk to ×3")
        );
        assert_eq!(route(Some(4), 4), None);
        assert_eq!(route(None, 3), None);
    }
}
