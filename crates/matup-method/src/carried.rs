//! The maps a material carries beside those it is rendered with (alpha channels, occlusion,
//! opacity, emission, unknown maps): each upsampled on its own by the run's RGB upsampler, as
//! the per-map path upsamples base colour (RGB) or roughness (grey), then back-projected onto
//! its input. Alpha is kept free of halos, and a cutout's alpha stays binary.

use matup_core::map::Map;
use matup_core::material::{Carried, Extra, MapKind, Material};
use matup_core::resample::{neighbourhood_ranges, upsample, Border, Kernel};
use matup_core::upsample::RgbUpsampler;
use matup_core::Result;

use crate::per_map::{upscale_one_map, SelfEnsemble};
use crate::residual::back_project_within;

/// How the carried maps are upsampled: the run's upsampler and self-ensemble, and whether the
/// result is back-projected onto the input (the defaults do; the per-map baseline does not).
#[derive(Clone, Copy)]
pub struct CarriedUpsampling<'a> {
    pub upsampler: &'a dyn RgbUpsampler,
    pub ensemble: SelfEnsemble,
    pub back_project: bool,
    pub scale: usize,
    pub border: Border,
}

/// Every map `lr` carries, upsampled.
pub fn upscale_carried(lr: &Carried, how: CarriedUpsampling) -> Result<Carried> {
    let alpha = (lr.alpha.iter())
        .map(|(kind, a)| Ok((*kind, upscale_alpha(a, how)?)))
        .collect::<Result<_>>()?;
    let extras = (lr.extras.iter())
        .map(|e| {
            Ok(Extra {
                map: upscale_extra(&e.map, how)?,
                alpha: e
                    .alpha
                    .as_ref()
                    .map(|a| upscale_alpha(a, how))
                    .transpose()?,
                ..e.clone()
            })
        })
        .collect::<Result<_>>()?;
    Ok(Carried { alpha, extras })
}

/// What [`upscale_carried`] does to each of `material`'s carried maps, for the run's report:
/// `"AmbientOcclusion.jpg: grey, by span_x4 (2 passes), back-projected"`.
pub fn describe_carried(
    material: &Material,
    upsampler: &str,
    how: CarriedUpsampling,
) -> Vec<String> {
    let passes = match how.ensemble.symmetries {
        1 => String::new(),
        n => format!(" ({n} passes)"),
    };
    let projected = if how.back_project {
        ", back-projected"
    } else {
        ""
    };
    let file = |p: &std::path::Path| {
        p.file_name()
            .unwrap_or_default()
            .to_string_lossy()
            .into_owned()
    };
    let mut out = Vec::new();
    for kind in material.carried.alpha.keys() {
        let source = (material.origin.as_ref())
            .and_then(|o| o.files.get(kind))
            .map_or_else(|| kind.to_string(), |(p, _)| file(p));
        out.push(format!(
            "{source}: alpha, {}",
            alpha_method(&material.carried.alpha[kind], upsampler)
        ));
    }
    for e in &material.carried.extras {
        let what = if e.map.channels() == 3 { "RGB" } else { "grey" };
        let by = if in_unit_range(&e.map) {
            format!("by {upsampler}{passes}{projected}")
        } else {
            format!("by lanczos3 (values outside [0, 1]){projected}")
        };
        let mut line = format!("{} as {}: {what}, {by}", file(&e.source), e.name);
        if let Some(a) = &e.alpha {
            line += &format!("; alpha, {}", alpha_method(a, upsampler));
        }
        out.push(line);
    }
    out
}

/// How [`upscale_alpha`] upsamples `alpha`.
fn alpha_method(alpha: &Map, upsampler: &str) -> String {
    if is_binary(alpha) {
        "a cutout: bicubic, thresholded at 0.5 (stays 0 or 1)".to_string()
    } else {
        format!("by {upsampler}, back-projected, kept within its 3×3 neighbourhood (no halo)")
    }
}

/// Whether every value lies in [0, 1] (an image's; HDR emission may not).
fn in_unit_range(map: &Map) -> bool {
    map.data().iter().all(|v| (0.0..=1.0).contains(v))
}

/// Whether every value is 0 or 1: a cutout's alpha.
fn is_binary(map: &Map) -> bool {
    map.data().iter().all(|&v| v == 0.0 || v == 1.0)
}

/// An extra map: RGB as the base colour is upsampled (linear colour shown sRGB-encoded), grey
/// as roughness is, values outside [0, 1] by Lanczos instead (no network sees those).
fn upscale_extra(map: &Map, how: CarriedUpsampling) -> Result<Map> {
    let bounded = in_unit_range(map);
    let mut up = if bounded {
        let kind = if map.channels() == 3 {
            MapKind::BaseColor
        } else {
            // Height: a grey map whose values the per-map path leaves as they come.
            MapKind::Height
        };
        upscale_one_map(
            kind,
            map,
            how.upsampler,
            how.scale,
            how.border,
            how.ensemble,
        )?
    } else {
        upsample(map, how.scale, Kernel::Lanczos3, how.border)
    };
    if bounded {
        up.data_mut()
            .iter_mut()
            .for_each(|v| *v = v.clamp(0.0, 1.0));
    }
    if how.back_project {
        let range = if bounded {
            (0.0, 1.0)
        } else {
            (f32::MIN, f32::MAX)
        };
        back_project_within(&mut up, map, how.scale, how.border, |_| range);
    }
    Ok(up)
}

/// An alpha channel: a cutout's (only 0 and 1) upsampled bicubically and thresholded at one
/// half, so it stays binary with edges where the input's lie; any other kept within the values of its LR
/// texel's 3×3 neighbourhood after back-projection, so no ring (halo) forms around an edge.
fn upscale_alpha(alpha: &Map, how: CarriedUpsampling) -> Result<Map> {
    if is_binary(alpha) {
        // A smooth interpolant's half-level line is a smooth contour through the input's
        // edges; a network's output speckles there (it hallucinates texture at a hard step).
        let mut up = upsample(alpha, how.scale, Kernel::Bicubic { a: -0.5 }, how.border);
        up.data_mut()
            .iter_mut()
            .for_each(|v| *v = if *v >= 0.5 { 1.0 } else { 0.0 });
        return Ok(up);
    }
    let mut up = upscale_one_map(
        MapKind::Height,
        alpha,
        how.upsampler,
        how.scale,
        how.border,
        how.ensemble,
    )?;
    if how.back_project {
        back_project_within(&mut up, alpha, how.scale, how.border, |_| (0.0, 1.0));
    }
    let values: Vec<[f32; 1]> = alpha.data().iter().map(|&v| [v]).collect();
    let ranges = neighbourhood_ranges(&values, alpha.width(), how.border);
    let (w, s) = (up.width(), how.scale);
    for (i, v) in up.data_mut().iter_mut().enumerate() {
        let [[low, high]] = ranges[(i / w / s) * alpha.width() + (i % w) / s];
        *v = v.clamp(low, high);
    }
    Ok(up)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Lanczos: an upsampler that rings at a step, as networks can.
    struct Lanczos;
    impl RgbUpsampler for Lanczos {
        fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>> {
            Ok(images
                .iter()
                .map(|m| upsample(m, scale, Kernel::Lanczos3, border))
                .collect())
        }
    }

    fn how(upsampler: &dyn RgbUpsampler) -> CarriedUpsampling<'_> {
        CarriedUpsampling {
            upsampler,
            ensemble: SelfEnsemble::NONE,
            back_project: true,
            scale: 4,
            border: Border::Mirror,
        }
    }

    #[test]
    fn soft_alpha_gets_no_halo_where_the_upsampler_rings() {
        // Opaque on the left, 30% on the right: a soft (non-binary) alpha with a hard step.
        let alpha = Map::from_fn(16, 16, 1, |_, _, x| if x < 8 { 1.0 } else { 0.3 });
        let rings = upsample(&alpha, 4, Kernel::Lanczos3, Border::Mirror);
        let below = rings.data().iter().copied().fold(f32::INFINITY, f32::min);
        assert!(below < 0.29, "the upsampler undershoots the step: {below}");
        let up = upscale_alpha(&alpha, how(&Lanczos)).unwrap();
        let (lo, hi) = (up.data().iter()).fold((f32::INFINITY, 0.0f32), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
        assert!(lo >= 0.3 && hi <= 1.0, "{lo}..{hi}");
        // Away from the step the values are the input's.
        assert_eq!(up.get(0, 20, 4), 1.0);
        assert!((up.get(0, 20, 60) - 0.3).abs() < 1e-6);
    }

    #[test]
    fn a_cutout_stays_binary_with_its_edge_in_place() {
        let alpha = Map::from_fn(16, 16, 1, |_, y, x| ((x + y) < 16) as u8 as f32);
        let up = upscale_alpha(&alpha, how(&Lanczos)).unwrap();
        assert!(up.data().iter().all(|&v| v == 0.0 || v == 1.0));
        let seen = matup_core::resample::box_downsample(&up, 4);
        let off: f32 = (seen.data().iter().zip(alpha.data()))
            .map(|(a, b)| (a - b).abs())
            .sum::<f32>()
            / alpha.texels() as f32;
        assert!(off < 0.05, "{off}");
    }
}
