//! `unsharp`: an unsharp mask followed by Lanczos-3 upsampling, a plugin crate of the kind a
//! researcher writes to try their own RGB upsampler in matup. Everything a plugin needs is the
//! `RgbUpsampler` trait and one `inventory::submit!`; matup finds it by name once the crate is
//! linked into a binary (see `main.rs`).

use matup_core::plugin::{option_value, parse_options, PluginOption};
use matup_core::resample::{upsample, Border, Kernel};
use matup_core::upsample::{RgbUpsampler, UpsamplerRegistration};
use matup_core::{Map, Result};

/// `image + amount · (image − blur(image))`, upsampled with Lanczos-3 and clamped to [0, 1];
/// the blur is a [1 2 1]/4 binomial filter in each direction. Sharpening before upsampling
/// scales the mask's radius with the scale factor.
pub struct Unsharp {
    pub amount: f32,
}

/// One pass of the [1 2 1]/4 filter along rows (`dx = 1`) or columns (`dy = 1`).
fn binomial(map: &Map, (dx, dy): (isize, isize), border: Border) -> Map {
    let (w, h) = (map.width(), map.height());
    Map::from_fn(w, h, map.channels(), |c, y, x| {
        let at = |k: isize| {
            let yy = border.index(y as isize + k * dy, h);
            let xx = border.index(x as isize + k * dx, w);
            map.get(c, yy, xx)
        };
        0.25 * at(-1) + 0.5 * at(0) + 0.25 * at(1)
    })
}

impl RgbUpsampler for Unsharp {
    fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>> {
        Ok(images
            .iter()
            .map(|image| {
                let blurred = binomial(&binomial(image, (1, 0), border), (0, 1), border);
                let mut sharp = image.clone();
                for (v, b) in sharp.data_mut().iter_mut().zip(blurred.data()) {
                    *v += self.amount * (*v - b);
                }
                upsample(&sharp, scale, Kernel::Lanczos3, border).map_values(|v| v.clamp(0.0, 1.0))
            })
            .collect())
    }
}

const OPTIONS: &[PluginOption] = &[PluginOption {
    key: "amount",
    default: "0.5",
    help: "strength of the unsharp mask (0 is plain lanczos3)",
}];

fn create(argument: Option<&str>) -> Result<Box<dyn RgbUpsampler>> {
    let values = parse_options("unsharp", argument, OPTIONS)?;
    Ok(Box::new(Unsharp {
        amount: option_value("unsharp", &values, "amount")?,
    }))
}

matup_core::inventory::submit! {
    UpsamplerRegistration {
        name: "unsharp",
        description: "an unsharp mask, then lanczos3 (example plugin crate)",
        options: OPTIONS,
        create,
    }
}
