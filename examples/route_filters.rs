//! The filter down from the ×4 network's output to ×2 or ×3, compared: matup's command line with
//! two more upsamplers, `through-lanczos3:SPEC` and `through-bicubic:SPEC`, which run `SPEC`
//! (any upsampler, e.g. `onnx:span_x4_materials`) at its native scale and shrink its output
//! with that kernel instead of area averaging (the defaults' route).
//!
//! `cargo run --release --example route_filters -- sweep sweeps/x3_filters.toml`

use std::process::ExitCode;

use matup::resample::{Kernel, Shrink};
use matup::upsample::{upsampler_shrinking_by, RgbUpsampler, UpsamplerRegistration};
use matup::{Error, PluginSpec, Result};

fn through(argument: Option<&str>, kernel: Kernel) -> Result<Box<dyn RgbUpsampler>> {
    let spec: PluginSpec = argument
        .ok_or_else(|| {
            Error::Invalid(
                "through-…: name the upsampler (through-lanczos3:onnx:span_x4_materials)".into(),
            )
        })?
        .parse()?;
    upsampler_shrinking_by(&spec, Shrink::Kernel(kernel))
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

fn main() -> ExitCode {
    matup_cli::main()
}
