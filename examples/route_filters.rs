//! Routes from the ×4 network to ×2 or ×3, compared: matup's command line with three more
//! upsamplers. `through-lanczos3:SPEC` and `through-bicubic:SPEC` run `SPEC` (any upsampler,
//! e.g. `onnx:span_x4_materials`) at its native scale and shrink its output with that kernel
//! instead of area averaging (the defaults' route). `from-half:SPEC` makes ×2 as ×4 of the
//! input box-filtered to half its size: the network's work of a ×4 run of the same output
//! size, a quarter of the defaults' route. `projected:SPEC` back-projects each of `SPEC`'s
//! native outputs onto its input at the native scale before the area filter down, as the ×4
//! path back-projects its own output (the defaults back-project at the target scale only).
//! `finer:SPEC` makes ×3 as `SPEC`'s ×4 of the input made 1.5 times larger (Lanczos-3 ×3, then
//! ÷2 by area), then ÷2 by area: the network sees the input on a finer grid, at 2.25 times the
//! work.
//!
//! `cargo run --release --example route_filters -- sweep sweeps/x3_filters.toml`

use std::process::ExitCode;

use matup::resample::{box_downsample, shrink, upsample, Border, Kernel, Shrink};
use matup::residual::back_project_within;
use matup::upsample::{upsampler, upsampler_shrinking_by, RgbUpsampler, UpsamplerRegistration};
use matup::{Error, Map, PluginSpec, Result};

/// The upsampler `argument` names (`through-lanczos3:onnx:span_x4_materials`).
fn inner_spec(argument: Option<&str>) -> Result<PluginSpec> {
    argument
        .ok_or_else(|| {
            Error::Invalid("name the upsampler after it (from-half:onnx:span_x4_materials)".into())
        })?
        .parse()
}

fn through(argument: Option<&str>, kernel: Kernel) -> Result<Box<dyn RgbUpsampler>> {
    upsampler_shrinking_by(&inner_spec(argument)?, Shrink::Kernel(kernel))
}

/// ×2 as ×4 of the input box-filtered ÷2.
struct FromHalf(Box<dyn RgbUpsampler>);

impl RgbUpsampler for FromHalf {
    fn native_scale(&self) -> Option<usize> {
        Some(2)
    }
    fn context(&self) -> usize {
        2 * self.0.context()
    }
    fn tile(&self) -> Option<usize> {
        self.0.tile().map(|t| 2 * t)
    }
    fn batches_images(&self) -> bool {
        self.0.batches_images()
    }
    fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>> {
        if scale != 2 || images.iter().any(|m| m.width() % 2 + m.height() % 2 > 0) {
            return Err(Error::Invalid(
                "from-half makes ×2 of even-sided images only".into(),
            ));
        }
        let halves: Vec<Map> = images.iter().map(|m| box_downsample(m, 2)).collect();
        self.0.upsample(&halves, 4, border)
    }
}

/// SPEC at its native scale, each output back-projected onto its input there, then area-shrunk.
struct Projected {
    inner: Box<dyn RgbUpsampler>,
    native: usize,
}

impl RgbUpsampler for Projected {
    fn native_scale(&self) -> Option<usize> {
        Some(self.native)
    }
    fn serves_smaller_scales(&self) -> bool {
        true
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
    fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>> {
        if scale > self.native {
            return Err(Error::Invalid(format!(
                "projected serves ×{} and below",
                self.native
            )));
        }
        let large = self.inner.upsample(images, self.native, border)?;
        Ok((large.into_iter().zip(images))
            .map(|(mut up, image)| {
                back_project_within(&mut up, image, self.native, border, |_| (0.0, 1.0));
                let size = [image.width(), image.height()].map(|n| n * scale);
                if scale == self.native {
                    up
                } else {
                    shrink(&up, size[0], size[1], Shrink::Area, border)
                }
            })
            .collect())
    }
}

/// ×3 as SPEC's ×4 of the input made 1.5 times larger, then ÷2.
struct Finer(Box<dyn RgbUpsampler>);

impl RgbUpsampler for Finer {
    fn native_scale(&self) -> Option<usize> {
        Some(3)
    }
    fn serves_smaller_scales(&self) -> bool {
        true
    }
    fn context(&self) -> usize {
        self.0.context()
    }
    fn tile(&self) -> Option<usize> {
        self.0.tile()
    }
    fn batches_images(&self) -> bool {
        self.0.batches_images()
    }
    fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>> {
        if scale != 3 || images.iter().any(|m| m.width() % 2 + m.height() % 2 > 0) {
            return Err(Error::Invalid(
                "finer makes ×3 of even-sided images only".into(),
            ));
        }
        let larger: Vec<Map> = (images.iter())
            .map(|m| {
                let larger = box_downsample(&upsample(m, 3, Kernel::Lanczos3, border), 2);
                larger.map_values(|v| v.clamp(0.0, 1.0)) // the network's input range
            })
            .collect();
        let up = self.0.upsample(&larger, 4, border)?;
        Ok(up.iter().map(|m| box_downsample(m, 2)).collect())
    }
}

fn projected(argument: Option<&str>) -> Result<Box<dyn RgbUpsampler>> {
    let inner = upsampler(&inner_spec(argument)?)?;
    let native = inner
        .native_scale()
        .ok_or_else(|| Error::Invalid("projected runs an upsampler with a native scale".into()))?;
    Ok(Box::new(Projected { inner, native }))
}

inventory::submit! {
    UpsamplerRegistration {
        name: "projected",
        description: "SPEC at its native scale, back-projected there, then area-shrunk (studies)",
        options: &[],
        create: projected,
    }
}

inventory::submit! {
    UpsamplerRegistration {
        name: "finer",
        description: "×3 as SPEC's ×4 of the input made 1.5 times larger, then ÷2 (studies)",
        options: &[],
        create: |argument| Ok(Box::new(Finer(upsampler(&inner_spec(argument)?)?))),
    }
}

inventory::submit! {
    UpsamplerRegistration {
        name: "through-lanczos3",
        description: "SPEC at its native scale, then shrunk by Lanczos-3 (studies)",
        options: &[],
        create: |argument| through(argument, Kernel::Lanczos3),
    }
}

inventory::submit! {
    UpsamplerRegistration {
        name: "through-bicubic",
        description: "SPEC at its native scale, then shrunk by bicubic (studies)",
        options: &[],
        create: |argument| through(argument, Kernel::Bicubic { a: -0.5 }),
    }
}

inventory::submit! {
    UpsamplerRegistration {
        name: "from-half",
        description: "×2 as SPEC's ×4 of the input box-filtered ÷2 (studies)",
        options: &[],
        create: |argument| Ok(Box::new(FromHalf(upsampler(&inner_spec(argument)?)?))),
    }
}

fn main() -> ExitCode {
    matup_cli::main()
}
