//! The residual base: the output-size features the filter's answer is added to, and that the
//! prior pulls toward. Either the LR features upsampled by a classical kernel (the paper's
//! bilinear), or each LR map upsampled on its own by the run's RGB upsampler, the way an
//! artist would run each file through it (per-map super-resolution as a starting point).

use std::borrow::Cow;
use std::convert::Infallible;

use rayon::prelude::*;

use crate::chroma::{
    chroma_bounds_on_device, clamp_chroma_on_device, clamp_chroma_to_input, luma, with_chroma_of,
};
use crate::config::{Chroma, FilterConfig, ResidualBase};
use crate::features::{feature_range, features, pack_features, FEATURE_MAPS};
use crate::features::{ALPHA, FEATURES};
use crate::per_map::{upscale_each_map, upscale_one_map_on_device, MapUpsamplers};
use matup_core::candle_core::{self, DType, Device, Tensor};
use matup_core::color::{linear_to_srgb, srgb_to_linear};
use matup_core::device_maps::{self, Separable};
use matup_core::map::Map;
use matup_core::material::{MapKind, Material};
use matup_core::resample::{
    box_downsample_channels, for_each_upsampled_row, gaussian_radius, guided_blur, lr_texel,
    neighbourhood_ranges, rows_per_task, upsample, Border, Kernel,
};
use matup_core::upsample::RgbUpsampler;
use matup_core::Result;

/// The grey features, metallic and alpha (as the roughness r), kept near their input after
/// back-projection ([`back_project`]).
const GREY_FEATURES: [std::ops::Range<usize>; 2] = [3..4, ALPHA..ALPHA + 1];

/// Rounds of back-projection: each removes most of the mismatch that remains (a bilinear
/// spread does not invert the box filter in one round), so three leave little.
pub const BACK_PROJECTIONS: usize = 3;

/// The chroma clamps that follow the first, each after the colours are brought back to their
/// input ([`project_onto_input`]).
const LATER_CLAMPS: usize = 2;

/// The residual base of `lr` upsampled by `scale`, as the 7 filter features, back-projected
/// onto the LR features when the configuration says so.
pub fn residual_base(
    lr: &Material,
    config: &FilterConfig,
    upsamplers: &MapUpsamplers,
    scale: usize,
    border: Border,
) -> Result<Map> {
    if let Some(device) = device_for(config, upsamplers) {
        let base = residual_base_on_device(lr, config, upsamplers, &device, scale, border)?;
        return Ok(device_maps::download(&base)?);
    }
    let mut base = upsampled_base(lr, config, upsamplers, scale, border)?;
    project_onto_input(&mut base, lr, config, scale, border);
    Ok(base)
}

/// What [`residual_base`] does after the upsampling: the back-projection onto `lr` and the
/// chroma clamp, where `config` asks for them.
pub fn project_onto_input(
    base: &mut Map,
    lr: &Material,
    config: &FilterConfig,
    scale: usize,
    border: Border,
) {
    if !(config.back_project || config.clamp_chroma) {
        return;
    }
    let lr_features = features(lr);
    let margin = config.neighbourhood_margin;
    let projected = projected_features(config);
    let colour_projected = config.projects(MapKind::BaseColor);
    let seen_colour = || Ok::<_, Infallible>(box_downsample_channels(base, scale, 0..3));
    let Ok(target) = projection_goal(config, &lr_features, border, seen_colour);
    back_project(base, &target, scale, border, margin, &projected);
    if config.clamp_chroma {
        // The base colour is the features' first three channels, linear.
        let near = NearInput::new(&lr_features, 0..3, border, margin, Encoding::Srgb);
        let clamp = |base: &mut Map| {
            clamp_chroma_to_input(base, &lr_features, scale, border);
            near.keep(base, scale, lr_features.width());
        };
        clamp(base);
        if colour_projected {
            // The clamp moves colours off their input, and bringing them back moves a few hues
            // out of their range: each twice more, the later moves far smaller, ending settled.
            // So no hue and no mean is left off on the sample and the exporters' test
            // materials (tests/colour.rs, tests/exporters.rs), where one round of each left
            // a few of one or the other (docs/experiments/2026-11-26-files-back-exactly.md).
            // With `clamp_back_project` the colours are brought back by back-projection, a
            // smooth spread, where settling each block alone moves whole blocks apart and
            // draws the input's texel grid, most at ×16
            // (docs/experiments/2026-11-26-seamless-by-default.md). The last bringing back
            // settles the blocks either way, within the range kept near the input: both hold.
            for _ in 0..LATER_CLAMPS {
                if config.clamp_back_project {
                    back_project_channels(base, &target, scale, border, 0..3, stored_range);
                } else {
                    near.settle(base, &target, scale);
                }
                clamp(base);
            }
            near.settle(base, &target, scale);
        }
    }
}

/// How a feature's values are compared with its input's: as they are, or (colour) as sRGB,
/// the values a file stores and an eye judges.
#[derive(Clone, Copy)]
enum Encoding {
    Linear,
    Srgb,
}

impl Encoding {
    fn encode(self, v: f32) -> f32 {
        match self {
            Encoding::Linear => v,
            Encoding::Srgb => linear_to_srgb(v),
        }
    }

    fn decode(self, v: f32) -> f32 {
        match self {
            Encoding::Linear => v,
            Encoding::Srgb => srgb_to_linear(v),
        }
    }
}

/// The range each output texel of `channels` is kept within: the range its input texel's 3×3
/// neighbourhood spans (rows and columns past the edge as the border says), widened by
/// `margin`, per input texel. An SR network trained on clean materials reads a game
/// texture's speckle and JPEG blocks as detail and draws a grey speck as a dark stroke;
/// back-projection then keeps the block's mean by brightening the texels around it and pins
/// the stroke at 0: black blobs and worms no input texel around them has
/// (docs/experiments/2026-11-28-no-new-structure.md). Edges the input has, sharpened, stay.
/// `None` ranges where the margin keeps everything (1 or more).
struct NearInput {
    channels: std::ops::Range<usize>,
    /// Per channel, per input texel: the least and greatest value (in the map's own values).
    ranges: Option<Vec<Vec<(f32, f32)>>>,
}

impl NearInput {
    fn new(
        lr: &Map,
        channels: std::ops::Range<usize>,
        border: Border,
        margin: f32,
        encoding: Encoding,
    ) -> Self {
        let ranges = (margin < 1.0).then(|| {
            let (encode, decode) = (|v| encoding.encode(v), |v| encoding.decode(v));
            (channels.clone())
                .map(|c| {
                    let (lo, hi) = stored_range(c);
                    let values: Vec<[f32; 1]> = lr.plane(c).iter().map(|&v| [encode(v)]).collect();
                    (neighbourhood_ranges(&values, lr.width(), border).into_iter())
                        .map(|[[a, b]]| {
                            let widened = |v: f32| decode(v.clamp(encode(lo), encode(hi)));
                            (widened(a - margin), widened(b + margin))
                        })
                        .collect()
                })
                .collect()
        });
        NearInput { channels, ranges }
    }

    /// Each texel of `hr` (`scale` times the size of an input `lr_width` wide) kept within
    /// its range.
    fn keep(&self, hr: &mut Map, scale: usize, lr_width: usize) {
        let Some(ranges) = &self.ranges else {
            return;
        };
        let w = hr.width();
        for (c, ranges) in self.channels.clone().zip(ranges) {
            (hr.plane_mut(c).par_chunks_mut(w))
                .enumerate()
                .for_each(|(y, row)| {
                    for (x, v) in row.iter_mut().enumerate() {
                        let (lo, hi) = ranges[lr_texel(y * w + x, w, scale, lr_width)];
                        *v = v.clamp(lo, hi);
                    }
                });
        }
    }

    /// [`settle_blocks`] of the channels, within their ranges (the stored ranges where the
    /// margin keeps everything): each block's mean its input texel's, and no texel moved out
    /// of its range. The input texel lies within its own range, so every block can settle.
    fn settle(&self, hr: &mut Map, lr: &Map, scale: usize) {
        match &self.ranges {
            None => settle_blocks(hr, lr, scale, self.channels.clone(), stored_range),
            Some(ranges) => {
                let start = self.channels.start;
                settle_blocks_by(hr, lr, scale, self.channels.clone(), |c, j| {
                    ranges[c - start][j]
                })
            }
        }
    }

    /// The ranges on `device` at `scale` times the input's size, `[2, N, H, W]`: the least
    /// values, then the greatest; `None` where the margin keeps everything.
    fn on_device(
        &self,
        lr: &Map,
        scale: usize,
        device: &Device,
    ) -> candle_core::Result<Option<[Tensor; 2]>> {
        let Some(ranges) = &self.ranges else {
            return Ok(None);
        };
        let end = |pick: fn((f32, f32)) -> f32| -> candle_core::Result<Tensor> {
            let values: Vec<f32> = ranges
                .iter()
                .flat_map(|r| r.iter().map(|&e| pick(e)))
                .collect();
            let t = Tensor::from_vec(values, (ranges.len(), lr.height(), lr.width()), device)?;
            device_maps::repeated(&t, scale)
        };
        Ok(Some([end(|r| r.0)?, end(|r| r.1)?]))
    }
}

/// The device to make the residual base on: the upsampler's, where it leaves its outputs on
/// one (a GPU's network) and the base is the per-map one, its colour's chroma its own.
/// `None`: the host's path, which a noisy material's blend of normals takes too
/// (`crate::normal_blend`: the networks still run on their device).
pub fn device_for(config: &FilterConfig, upsamplers: &MapUpsamplers) -> Option<Device> {
    let per_map = config.residual_base == ResidualBase::Upsampler
        && config.base_color_chroma == Chroma::Upsampler
        && config.normal_blend_noise == 0.0;
    let device = per_map.then(|| upsamplers.run.device()).flatten()?;
    // Every map's upsampler there, or the host's path for all.
    let same = |u: &dyn RgbUpsampler| u.device().is_some_and(|d| d.same_device(&device));
    upsamplers.all().all(same).then_some(device)
}

/// [`residual_base`] on `device`, where [`device_for`] names one: each map upsampled, decoded
/// and averaged over the self-ensemble there ([`upscale_one_map_on_device`]), packed into the
/// features, back-projected and chroma-clamped there, where the features stay (`[7, h, w]`).
pub fn residual_base_on_device(
    lr: &Material,
    config: &FilterConfig,
    upsamplers: &MapUpsamplers,
    device: &Device,
    scale: usize,
    border: Border,
) -> Result<Tensor> {
    let up = |kind: MapKind| {
        let map = lr.map(kind).expect("every feature map is present");
        upscale_one_map_on_device(
            kind,
            map,
            upsamplers.of(kind),
            device,
            scale,
            border,
            config.map_passes(),
        )
    };
    // In feature order (`pack_features`): colour, metallic, normal x and y, alpha = r².
    let (colour, metallic, normal) = (
        up(MapKind::BaseColor)?,
        up(MapKind::Metallic)?,
        up(MapKind::Normal)?,
    );
    let alpha = up(MapKind::Roughness)?.sqr()?;
    let base = Tensor::cat(&[&colour, &metallic, &normal.narrow(0, 0, 2)?, &alpha], 0)?;
    Ok(project_on_device(base, lr, config, scale, border)?)
}

/// [`project_onto_input`] of the features `base` on their device.
fn project_on_device(
    base: Tensor,
    lr: &Material,
    config: &FilterConfig,
    scale: usize,
    border: Border,
) -> candle_core::Result<Tensor> {
    if !(config.back_project || config.clamp_chroma) {
        return Ok(base);
    }
    let lr_features = features(lr);
    let device = base.device().clone();
    let projected = projected_features(config);
    let colour_projected = config.projects(MapKind::BaseColor);
    let seen_colour = || {
        let sums = device_maps::block_sums(&base.narrow(0, 0, 3)?, scale)?;
        device_maps::download(&(sums / (scale * scale) as f64)?)
    };
    let target = projection_goal(config, &lr_features, border, seen_colour)?;
    let lr_on_device = device_maps::upload(&target, &device)?;
    let ranges = |channels: std::ops::Range<usize>| -> candle_core::Result<[Tensor; 2]> {
        let ends = |end: fn((f32, f32)) -> f32| {
            let values: Vec<f32> = channels.clone().map(|c| end(stored_range(c))).collect();
            Tensor::from_vec(values, (channels.len(), 1, 1), &device)
        };
        Ok([ends(|r| r.0)?, ends(|r| r.1)?])
    };
    let mut base = base;
    if !projected.is_empty() {
        // As stored: alpha as the roughness r (see `back_project`); each map's features
        // projected or left as they are.
        let as_stored = |t: &Tensor| -> candle_core::Result<Tensor> {
            Tensor::cat(&[t.narrow(0, 0, ALPHA)?, t.narrow(0, ALPHA, 1)?.sqrt()?], 0)
        };
        let lr = as_stored(&lr_on_device)?;
        let hr = as_stored(&base)?;
        let mut lr_stored = target.clone().into_owned();
        alpha_as_stored(&mut lr_stored);
        let margin = config.neighbourhood_margin;
        let mut parts = Vec::new();
        for kind in FEATURE_MAPS {
            let features = feature_range(kind).expect("a feature map");
            let part = hr.narrow(0, features.start, features.len())?;
            if !projected.contains(&features) {
                parts.push(part);
                continue;
            }
            let lr_part = lr.narrow(0, features.start, features.len())?;
            let mut part =
                back_project_on_device(&part, &lr_part, scale, border, &ranges(features.clone())?)?;
            if GREY_FEATURES.contains(&features) && margin < 1.0 {
                // As `back_project` keeps the grey features near their input.
                let near = NearInput::new(
                    &lr_stored,
                    features.clone(),
                    border,
                    margin,
                    Encoding::Linear,
                );
                if let Some(ends) = near.on_device(&lr_stored, scale, &device)? {
                    let kept = part.maximum(&ends[0])?.minimum(&ends[1])?;
                    part = settle_blocks_on_device(&kept, &lr_part, scale, &ends)?;
                }
            }
            parts.push(part);
        }
        // In feature order: colour, metallic, normal, alpha (`FEATURE_MAPS`).
        let hr = Tensor::cat(&parts, 0)?;
        base = Tensor::cat(
            &[hr.narrow(0, 0, ALPHA)?, hr.narrow(0, ALPHA, 1)?.sqr()?],
            0,
        )?;
    }
    if config.clamp_chroma {
        let rest = base.narrow(0, 3, FEATURES - 3)?;
        let bounds = chroma_bounds_on_device(&lr_features, scale, border, &device)?;
        let margin = config.neighbourhood_margin;
        let near = NearInput::new(&lr_features, 0..3, border, margin, Encoding::Srgb);
        let near = near.on_device(&lr_features, scale, &device)?;
        let keep = |colour: Tensor| match &near {
            Some([lo, hi]) => colour.maximum(lo)?.minimum(hi),
            None => Ok(colour),
        };
        let mut colour = keep(clamp_chroma_on_device(&base.narrow(0, 0, 3)?, &bounds)?)?;
        if colour_projected {
            // As `project_onto_input` brings them back and clamps them, and why.
            let lr_colour = lr_on_device.narrow(0, 0, 3)?;
            let range = ranges(0..3)?;
            // Settled within the range kept near the input, where there is one.
            let settle_range = near.clone().unwrap_or(range.clone());
            for _ in 0..LATER_CLAMPS {
                colour = if config.clamp_back_project {
                    back_project_on_device(&colour, &lr_colour, scale, border, &range)?
                } else {
                    settle_blocks_on_device(&colour, &lr_colour, scale, &settle_range)?
                };
                colour = keep(clamp_chroma_on_device(&colour, &bounds)?)?;
            }
            colour = settle_blocks_on_device(&colour, &lr_colour, scale, &settle_range)?;
        }
        base = Tensor::cat(&[&colour, &rest], 0)?;
    }
    Ok(base)
}

/// [`back_project_within`] on a device: `hr` `[c, h·scale, w·scale]` corrected toward `lr`
/// `[c, h, w]`, channel `c`'s values kept in `[lo[c], hi[c]]` (`[c, 1, 1]` each, finite).
pub fn back_project_on_device(
    hr: &Tensor,
    lr: &Tensor,
    scale: usize,
    border: Border,
    [lo, hi]: &[Tensor; 2],
) -> candle_core::Result<Tensor> {
    let (_, h, w) = lr.dims3()?;
    let spread = Separable::upsample([w, h], scale, Kernel::Bilinear, border, lr.device())?;
    let norm = 1.0 / (scale * scale) as f64;
    let mut hr = hr.clone();
    let mut seen = (device_maps::block_sums(&hr, scale)? * norm)?;
    for round in 0..BACK_PROJECTIONS {
        let mismatch = (lr - &seen)?;
        hr = (hr + spread.apply(&mismatch)?)?
            .broadcast_maximum(lo)?
            .broadcast_minimum(hi)?;
        if round + 1 < BACK_PROJECTIONS {
            seen = (device_maps::block_sums(&hr, scale)? * norm)?;
        }
    }
    settle_blocks_on_device(&hr, lr, scale, &[lo.clone(), hi.clone()])
}

/// [`settle_blocks`] on a device, every channel of `hr`, the range's ends finite: `[c, 1, 1]`
/// each, or each texel's own (`[c, H, W]`, [`NearInput::on_device`]).
fn settle_blocks_on_device(
    hr: &Tensor,
    lr: &Tensor,
    scale: usize,
    [lo, hi]: &[Tensor; 2],
) -> candle_core::Result<Tensor> {
    let n = (scale * scale) as f64;
    let miss = settled_part_on_device(&(lr - (device_maps::block_sums(hr, scale)? / n)?)?)?;
    let up = |t: &Tensor| device_maps::repeated(t, scale);
    let toward_hi = up(&miss.gt(0f32)?.to_dtype(DType::F32)?)?.gt(0.5f32)?;
    let end = toward_hi.where_cond(&hi.broadcast_as(hr.shape())?, &lo.broadcast_as(hr.shape())?)?;
    let room = (end - hr)?.abs()?;
    let total = device_maps::block_sums(&room, scale)?;
    let settles = miss.ne(0f32)?.mul(&total.gt(0f32)?)?;
    let share = settles.where_cond(&((&miss * n)? / &total)?, &miss.zeros_like()?)?;
    (hr + up(&share)?.mul(&room)?)?
        .broadcast_maximum(lo)?
        .broadcast_minimum(hi)
}

/// LR texels of context around a region that change its residual base: the upsampler's (or
/// the kernel's) own, the low-pass projection's blur (its target's colour reads that far),
/// and two per round of back-projection (a box cell, then a bilinear spread over the
/// neighbouring cells). A noisy material's blend of normals reads further
/// (`crate::normal_blend::context`).
pub fn context(config: &FilterConfig, upsamplers: &MapUpsamplers) -> usize {
    let upsampled = match config.residual_base {
        ResidualBase::Kernel(kernel) => kernel.radius().ceil() as usize,
        ResidualBase::Upsampler => (upsamplers.all().map(|u| u.context()).max()).unwrap_or(0),
    };
    let low_pass = match config.projects_low_pass() {
        true => gaussian_radius(config.projection_blur),
        false => 0,
    };
    let projections = match config.back_project {
        false => 0,
        true if config.clamp_chroma && config.clamp_back_project => 1 + LATER_CLAMPS,
        true => 1,
    };
    upsampled + low_pass + 2 * BACK_PROJECTIONS * projections
}

/// Iterative back-projection (Irani & Peleg 1991): corrects output-size features `hr` so that
/// their box-downsample, what a capture at the LR size would see, comes back to `lr`: the
/// mismatch is spread back over the output texels bilinearly, a few times. Values are kept in
/// their ranges.
///
/// Each feature is corrected as its file stores it, so that the output's files box-filter back
/// to the input's: alpha (r²) as the roughness r (a mean of r² is not the square of a mean of
/// r, and the two drift apart by up to 10 levels where roughness varies near 0).
///
/// The grey features (metallic, roughness) are then kept within `margin` of their input's
/// neighbourhoods ([`NearInput`]) and their blocks settled within them; the colour is kept so
/// with its chroma ([`project_onto_input`]). Only the `projected` features are touched, each
/// feature alone, as back-projection treats every channel.
pub fn back_project(
    hr: &mut Map,
    lr: &Map,
    scale: usize,
    border: Border,
    margin: f32,
    projected: &[std::ops::Range<usize>],
) {
    if projected.is_empty() {
        return;
    }
    let mut lr = lr.clone();
    alpha_as_stored(&mut lr);
    alpha_as_stored(hr);
    for features in projected {
        back_project_channels(hr, &lr, scale, border, features.clone(), stored_range);
    }
    if margin < 1.0 {
        for grey in GREY_FEATURES.into_iter().filter(|g| projected.contains(g)) {
            let near = NearInput::new(&lr, grey, border, margin, Encoding::Linear);
            near.keep(hr, scale, lr.width());
            near.settle(hr, &lr, scale);
        }
    }
    // Alpha was made by squaring r (`pack_features`), and √(r²) rounds back to r exactly, so a
    // texel no correction moved gets its alpha back bit for bit.
    hr.plane_mut(ALPHA).iter_mut().for_each(|r| *r *= *r);
}

/// How different two input features may be (linear [0, 1] units) for the low-pass
/// projection's blur to mix their mismatches: a JPEG's noise is a few levels, an edge far
/// more. Without it, a correction on one side of a strong edge darkens or brightens the other
/// (a rim on DamagedHelmet's white paint against black).
const PROJECTION_EDGE: f32 = 0.1;

/// The LR features a low-pass projection brings the base colour back to, where the base's
/// colour box-filters to `seen` (its first three channels): the input's colour plus the
/// base's detail past it, the high frequencies of their mismatch (what a Gaussian of `sigma`
/// LR texels, kept to the input's edges, leaves), in luma alone. So an input's noise and
/// blocks, high frequencies, are not put back, its regions' colours are, and its chroma is
/// kept whole: detail taken per channel drew colour into grey materials (a grey JPEG of
/// Tiles036, ×4: G′ − R′ up to 55 levels). Mismatch and luma are sRGB-encoded, as the chroma clamp (`crate::chroma`)
/// reads them, so that adding the detail leaves the input's chroma as it is. The other
/// features are `lr`'s, and not projected (projecting them too lost 0.10 dB on JPEG 75
/// inputs: docs/experiments/2026-11-29-degraded-inputs.md).
fn projection_target(seen: &Map, lr: &Map, border: Border, sigma: f32) -> Map {
    let (w, h) = (lr.width(), lr.height());
    let encoded =
        |m: &Map, c: usize| -> Vec<f32> { m.plane(c).iter().map(|&v| linear_to_srgb(v)).collect() };
    let input = [0, 1, 2].map(|c| encoded(lr, c));
    let detail = [0, 1, 2].map(|c| {
        let mismatch: Vec<f32> = (encoded(seen, c).iter().zip(&input[c]))
            .map(|(s, l)| s - l)
            .collect();
        let low = guided_blur(&mismatch, lr.plane(c), w, h, sigma, PROJECTION_EDGE, border);
        (mismatch.iter().zip(low))
            .map(|(m, l)| m - l)
            .collect::<Vec<f32>>()
    });
    let luma_detail: Vec<f32> = (0..w * h)
        .map(|i| luma(detail.each_ref().map(|d| d[i])))
        .collect();
    let mut target = lr.clone();
    // The base colour is the features' first three channels.
    for (c, input) in input.iter().enumerate() {
        let (lo, hi) = stored_range(c);
        let planes = target.plane_mut(c).iter_mut().zip(input).zip(&luma_detail);
        for ((t, v), d) in planes {
            *t = srgb_to_linear((v + d).clamp(0.0, 1.0)).clamp(lo, hi);
        }
    }
    target
}

/// The features of the maps `config` projects ([`FilterConfig::projects`]), map by map in
/// feature order.
pub fn projected_features(config: &FilterConfig) -> Vec<std::ops::Range<usize>> {
    (FEATURE_MAPS.into_iter())
        .filter(|&kind| config.projects(kind))
        .filter_map(feature_range)
        .collect()
}

/// What the projections bring a base back to: `lr_features`, or where `config` brings the
/// base colour back to its low frequencies ([`FilterConfig::projects_low_pass`]), the
/// [`projection_target`] of the base's colour box-filtered to the input's size, which
/// `seen_colour` computes (on the host or on a device) only then.
fn projection_goal<'a, E>(
    config: &FilterConfig,
    lr_features: &'a Map,
    border: Border,
    seen_colour: impl FnOnce() -> std::result::Result<Map, E>,
) -> std::result::Result<Cow<'a, Map>, E> {
    if !config.projects_low_pass() {
        return Ok(Cow::Borrowed(lr_features));
    }
    let sigma = config.projection_blur;
    Ok(Cow::Owned(projection_target(
        &seen_colour()?,
        lr_features,
        border,
        sigma,
    )))
}

/// Features with alpha (r²) as its file stores it, the roughness r.
fn alpha_as_stored(features: &mut Map) {
    (features.plane_mut(ALPHA).iter_mut()).for_each(|a| *a = a.sqrt());
}

/// [`back_project`] for any map, channel `c`'s values kept in `range(c)`.
pub fn back_project_within(
    hr: &mut Map,
    lr: &Map,
    scale: usize,
    border: Border,
    range: impl Fn(usize) -> (f32, f32) + Sync,
) {
    back_project_channels(hr, lr, scale, border, 0..hr.channels(), range);
}

/// [`back_project_within`] of `channels` alone (of `hr` and `lr` alike); the others are left
/// as they are.
///
/// One pass over `hr` a round: the correction is spread a few rows at a time (never held at
/// the output size), and each corrected block of rows is box-summed there for the next round's
/// mismatch. The values are those of `box_downsample` and `upsample` done apart.
pub fn back_project_channels(
    hr: &mut Map,
    lr: &Map,
    scale: usize,
    border: Border,
    channels: std::ops::Range<usize>,
    range: impl Fn(usize) -> (f32, f32) + Sync,
) {
    let (w, h) = (lr.width(), lr.height());
    let ow = w * scale;
    let taps = Kernel::Bilinear.phase_taps(scale);
    let norm = 1.0 / (scale * scale) as f32;
    let rows = rows_per_task(ow * scale);
    // What a capture at the LR size sees of `hr`, kept up to date round by round.
    let mut seen = box_downsample_channels(hr, scale, channels.clone());
    for round in 0..BACK_PROJECTIONS {
        let last = round + 1 == BACK_PROJECTIONS;
        for c in channels.clone() {
            let mismatch: Vec<f32> = (lr.plane(c).iter().zip(seen.plane(c)))
                .map(|(l, s)| l - s)
                .collect();
            let (lo, hi) = range(c);
            hr.plane_mut(c)
                .par_chunks_mut(rows * scale * ow)
                .zip(seen.plane_mut(c).par_chunks_mut(rows * w))
                .enumerate()
                .for_each(|(task, (hr_rows, seen_rows))| {
                    let first = task * rows;
                    seen_rows.fill(0.0);
                    let lr_rows = first..(first + rows).min(h);
                    for_each_upsampled_row(
                        &mismatch,
                        [w, h],
                        scale,
                        &taps,
                        border,
                        lr_rows,
                        |y, correction| {
                            let local = y - first * scale;
                            let row = &mut hr_rows[local * ow..][..ow];
                            row.iter_mut()
                                .zip(correction)
                                .for_each(|(v, f)| *v = (*v + f).clamp(lo, hi));
                            if !last {
                                let sums = &mut seen_rows[local / scale * w..][..w];
                                for (sum, block) in sums.iter_mut().zip(row.chunks_exact(scale)) {
                                    block.iter().for_each(|v| *sum += v);
                                }
                            }
                        },
                    );
                    seen_rows.iter_mut().for_each(|s| *s *= norm);
                });
        }
    }
    settle_blocks(hr, lr, scale, channels, range);
}

/// A block whose mean misses its LR texel by more than this after back-projection's rounds is
/// settled: a third of an 8-bit level even where an sRGB file is steepest (near black, 12.92×
/// linear), a fortieth elsewhere.
pub const SETTLE_ABOVE: f32 = 1e-4;

/// The part of a block's `miss` that [`settle_blocks`] removes: none up to [`SETTLE_ABOVE`],
/// all from twice that, a ramp between. Never more than `SETTLE_ABOVE` is left, and a mean
/// computed in another order (a GPU's) moves the outcome as little as it moves the mean: a
/// step at the threshold would turn a 10⁻⁷ difference into 10⁻⁴.
pub fn settled_part(miss: f32) -> f32 {
    miss * ((miss.abs() - SETTLE_ABOVE) / SETTLE_ABOVE).clamp(0.0, 1.0)
}

/// [`settled_part`] of every miss in `miss`, on its device.
pub fn settled_part_on_device(miss: &Tensor) -> candle_core::Result<Tensor> {
    let t = SETTLE_ABOVE as f64;
    miss.mul(&((miss.abs()? - t)? / t)?.clamp(0f32, 1f32)?)
}

/// Settles each `scale × scale` block of `hr`'s `channels` whose mean misses `lr`'s texel by
/// more than [`SETTLE_ABOVE`]: the miss ([`settled_part`] of it) is shared among the block's
/// texels in proportion to the room each has toward the end of `range(c)` it moves to, so the
/// block's mean comes out equal to its LR texel (within `SETTLE_ABOVE`) and no value leaves
/// the range (an unbounded end gives every texel the same share). Bilinear rounds cannot bring
/// back a block whose texels are pinned at the range's ends (a white speck, a metal edge);
/// this does, and touches no other block, so a file box-filters back to its input within its
/// precision and bands need no more context.
pub fn settle_blocks(
    hr: &mut Map,
    lr: &Map,
    scale: usize,
    channels: std::ops::Range<usize>,
    range: impl Fn(usize) -> (f32, f32) + Sync,
) {
    settle_blocks_by(hr, lr, scale, channels, |c, _| range(c));
}

/// [`settle_blocks`] with a range of its own for each block: `range(c, j)` for channel `c`
/// of the block of LR texel `j`.
pub fn settle_blocks_by(
    hr: &mut Map,
    lr: &Map,
    scale: usize,
    channels: std::ops::Range<usize>,
    range: impl Fn(usize, usize) -> (f32, f32) + Sync,
) {
    let (w, ow) = (lr.width(), lr.width() * scale);
    let n = (scale * scale) as f32;
    for c in channels {
        let lr_plane = lr.plane(c);
        (hr.plane_mut(c).par_chunks_mut(scale * ow))
            .zip(lr_plane.par_chunks(w))
            .enumerate()
            .for_each(|(y, (rows, lr_row))| {
                for (x, &want) in lr_row.iter().enumerate() {
                    let (lo, hi) = range(c, y * w + x);
                    let block = |rows: &mut [f32], f: &mut dyn FnMut(&mut f32)| {
                        for row in rows.chunks_exact_mut(ow) {
                            row[x * scale..(x + 1) * scale].iter_mut().for_each(&mut *f);
                        }
                    };
                    let mut sum = 0.0;
                    block(rows, &mut |v| sum += *v);
                    let miss = settled_part(want - sum / n);
                    if miss == 0.0 {
                        continue;
                    }
                    let end = if miss > 0.0 { hi } else { lo };
                    let room = |v: f32| {
                        if end.is_finite() {
                            (end - v).abs()
                        } else {
                            1.0
                        }
                    };
                    let mut total = 0.0;
                    block(rows, &mut |v| total += room(*v));
                    if total <= 0.0 {
                        continue;
                    }
                    let share = miss * n / total;
                    block(rows, &mut |v| *v = (*v + share * room(*v)).clamp(lo, hi));
                }
            });
    }
}

/// The range a feature's values may take as stored (normal x and y: the unit disc's bounding
/// box; colour, metallic and roughness: [0, 1]).
fn stored_range(feature: usize) -> (f32, f32) {
    debug_assert!(feature < FEATURES);
    match feature {
        4 | 5 => (-1.0, 1.0),
        _ => (0.0, 1.0),
    }
}

/// The residual base before any back-projection.
pub fn upsampled_base(
    lr: &Material,
    config: &FilterConfig,
    upsamplers: &MapUpsamplers,
    scale: usize,
    border: Border,
) -> Result<Map> {
    Ok(match config.residual_base {
        ResidualBase::Kernel(kernel) => upsample(&features(lr), scale, kernel, border),
        ResidualBase::Upsampler => {
            // Each map packed as soon as it is upsampled: the maps and their features at the
            // output size at once were this stage's peak.
            let (w, h) = (lr.width() * scale, lr.height_px() * scale);
            let mut base = Map::filled(w, h, FEATURES, 0.0);
            upscale_each_map(
                &feature_maps(lr),
                upsamplers,
                scale,
                border,
                config.map_passes(),
                |kind, map| {
                    let map = match (kind, config.base_color_chroma) {
                        (MapKind::BaseColor, Chroma::Kernel(kernel)) => {
                            with_chroma_of(&map, &upsample(&lr.base_color, scale, kernel, border))
                        }
                        _ => map,
                    };
                    pack_features(&mut base, kind, &map);
                    Ok(())
                },
            )?;
            base
        }
    })
}

/// The maps of `lr` the features come from: height and anisotropy are no filter features,
/// so the upsampler is spared them.
fn feature_maps(lr: &Material) -> Material {
    // Built map by map: cloning the whole material would copy the maps left out too.
    Material {
        base_color: lr.base_color.clone(),
        normal: lr.normal.clone(),
        roughness: lr.roughness.clone(),
        metallic: lr.metallic.clone(),
        height: None,
        anisotropy: None,
        anisotropy_angle: None,
        carried: Default::default(),
        origin: lr.origin.clone(),
        lossy: lr.lossy.clone(),
    }
}

#[cfg(test)]
mod tests;
