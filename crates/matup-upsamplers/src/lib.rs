//! matup's built-in RGB upsamplers, each registered with `inventory`: `bilinear`, `bicubic`
//! and `lanczos3`, at any integer scale, on matup-core's resampling kernels; and, with the
//! `onnx` feature (on by default), `onnx`: pre-trained super-resolution networks; and
//! `callable`: a function the caller registers at run time.
//!
//! Rooms:
//! - `onnx`: a network from an ONNX file and its sidecar, run by matup's executor, tract, or
//!   candle on a device; its options and the process's cache of loaded networks.
//! - `gpu`: the GPU adapters wgpu offers (Vulkan, Metal, DirectX 12), found and opened once.
//! - `tiled`: tiles with context and their feathered blend, on the host or on a device.
//! - `function`: the `callable` upsampler, a caller's function run on tiles.

pub mod function;
#[cfg(feature = "onnx")]
pub mod gpu;
#[cfg(feature = "onnx")]
pub mod onnx;
pub mod tiled;

use matup_core::plugin::{option_value, parse_options, PluginOption};
use matup_core::resample::Kernel;
pub use matup_core::upsample::KernelUpsampler;
use matup_core::upsample::{RgbUpsampler, UpsamplerRegistration};
use matup_core::Result;

fn bilinear(argument: Option<&str>) -> Result<Box<dyn RgbUpsampler>> {
    parse_options("bilinear", argument, &[])?;
    Ok(Box::new(KernelUpsampler::new(Kernel::Bilinear)))
}

const BICUBIC_OPTIONS: &[PluginOption] = &[PluginOption {
    key: "a",
    default: "-0.5",
    help: "Keys' parameter (−0.5 reproduces quadratics; −0.75 is sharper)",
}];

fn bicubic(argument: Option<&str>) -> Result<Box<dyn RgbUpsampler>> {
    let options = parse_options("bicubic", argument, BICUBIC_OPTIONS)?;
    let a: f32 = option_value("bicubic", &options, "a")?;
    Ok(Box::new(KernelUpsampler::new(Kernel::Bicubic { a })))
}

fn lanczos3(argument: Option<&str>) -> Result<Box<dyn RgbUpsampler>> {
    parse_options("lanczos3", argument, &[])?;
    Ok(Box::new(KernelUpsampler::new(Kernel::Lanczos3)))
}

inventory::submit! {
    UpsamplerRegistration {
        name: "bilinear",
        description: "bilinear interpolation, any integer scale",
        options: &[],
        create: bilinear,
    }
}

inventory::submit! {
    UpsamplerRegistration {
        name: "bicubic",
        description: "Keys bicubic convolution, any integer scale",
        options: BICUBIC_OPTIONS,
        create: bicubic,
    }
}

inventory::submit! {
    UpsamplerRegistration {
        name: "lanczos3",
        description: "Lanczos windowed sinc with 3 lobes, any integer scale",
        options: &[],
        create: lanczos3,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use matup_core::resample::Border;
    use matup_core::{upsampler, Map, PluginSpec};

    fn build(name: &str) -> Box<dyn RgbUpsampler> {
        upsampler(&name.parse::<PluginSpec>().unwrap()).unwrap()
    }

    #[test]
    fn constants_stay_constant() {
        let image = Map::from_fn(9, 6, 3, |c, _, _| [0.2, 0.5, 0.9][c]);
        for name in ["bilinear", "bicubic", "lanczos3"] {
            for border in [Border::Wrap, Border::Clamp, Border::Mirror] {
                let out = build(name)
                    .upsample(std::slice::from_ref(&image), 4, border)
                    .unwrap();
                for c in 0..3 {
                    let want = [0.2, 0.5, 0.9][c];
                    let worst = out[0]
                        .plane(c)
                        .iter()
                        .map(|v| (v - want).abs())
                        .fold(0.0, f32::max);
                    assert!(worst < 1e-6, "{name} {border}: off by {worst}");
                }
            }
        }
    }

    #[test]
    fn bilinear_and_bicubic_reproduce_linear_ramps_inside() {
        // value = 0.03·x + 0.02·y in input texel coordinates
        let image = Map::from_fn(16, 16, 3, |_, y, x| 0.03 * x as f32 + 0.02 * y as f32);
        for name in ["bilinear", "bicubic"] {
            for scale in [2, 3, 4] {
                let out = &build(name)
                    .upsample(std::slice::from_ref(&image), scale, Border::Clamp)
                    .unwrap()[0];
                let margin = 2 * scale;
                let mut worst = 0f32;
                for y in margin..out.height() - margin {
                    for x in margin..out.width() - margin {
                        let u = (x as f32 + 0.5) / scale as f32 - 0.5;
                        let v = (y as f32 + 0.5) / scale as f32 - 0.5;
                        worst = worst.max((out.get(0, y, x) - (0.03 * u + 0.02 * v)).abs());
                    }
                }
                assert!(worst < 1e-5, "{name} ×{scale}: ramp off by {worst}");
            }
        }
    }

    /// The image shifted by (dy, dx) with wrap-around.
    fn roll(image: &Map, dy: usize, dx: usize) -> Map {
        let (w, h) = (image.width(), image.height());
        Map::from_fn(w, h, image.channels(), |c, y, x| {
            image.get(c, (y + h - dy) % h, (x + w - dx) % w)
        })
    }

    #[test]
    fn wrap_mode_keeps_tileable_inputs_tileable() {
        // Tileable means no place is special: upsampling a shifted tile gives the shifted
        // upsample, so the wrap-around edge is as seamless as any interior line.
        let image = Map::from_fn(20, 20, 3, |c, y, x| {
            let v = (x * 7 + y * 13 + c * 5) as f32;
            0.5 + 0.4 * (v * 0.37).sin()
        });
        let scale = 4;
        for name in ["bilinear", "bicubic", "lanczos3"] {
            let up = |m: &Map, border| {
                build(name)
                    .upsample(std::slice::from_ref(m), scale, border)
                    .unwrap()
                    .remove(0)
            };
            let shifted_then_up = up(&roll(&image, 7, 3), Border::Wrap);
            let up_then_shifted = roll(&up(&image, Border::Wrap), 7 * scale, 3 * scale);
            let worst = shifted_then_up
                .data()
                .iter()
                .zip(up_then_shifted.data())
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f32::max);
            assert!(
                worst < 1e-5,
                "{name}: wrap-mode output is not tileable ({worst})"
            );
            // A mirrored border makes the edge special, and the same check sees it.
            let mirrored = roll(&up(&image, Border::Mirror), 7 * scale, 3 * scale);
            let shifted_mirrored = up(&roll(&image, 7, 3), Border::Mirror);
            let diff = mirrored
                .data()
                .iter()
                .zip(shifted_mirrored.data())
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f32::max);
            assert!(diff > 1e-2, "{name}: mirror border should not tile");
        }
    }

    #[test]
    fn bicubic_takes_its_option_and_rejects_others() {
        assert!(upsampler(&"bicubic:a=-0.75".parse().unwrap()).is_ok());
        let e = upsampler(&"bicubic:b=1".parse().unwrap()).err().unwrap();
        assert!(e.to_string().contains("valid options: a"), "{e}");
        let e = upsampler(&"lanczos9".parse().unwrap()).err().unwrap();
        assert!(
            e.to_string()
                .contains("known: bicubic, bilinear, callable, lanczos3"),
            "{e}"
        );
    }
}
