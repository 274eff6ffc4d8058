//! Routes from the ×4 network to ×2 or ×3, compared: matup's command line with three more
//! upsamplers. `through-lanczos3:SPEC` and `through-bicubic:SPEC` run `SPEC` (any upsampler,
//! e.g. `onnx:span_x4_materials`) at its native scale and shrink its output with that kernel
//! instead of area averaging (the defaults' route). `from-half:SPEC` makes ×2 as ×4 of the
//! input box-filtered to half its size: the network's work of a ×4 run of the same output
//! size, a quarter of the defaults' route.
//!
//! `cargo run --release --example route_filters -- sweep sweeps/x3_filters.toml`

use std::process::ExitCode;

use matup::resample::{box_downsample, Border, Kernel, Shrink};
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
