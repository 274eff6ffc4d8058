//! How close a material is to a reference: its renders under a held-out light set (PSNR, SSIM,
//! FLIP), its maps (base colour, normal, roughness and metallic errors) and its seam.

use std::collections::BTreeMap;

use rayon::prelude::*;
use serde::Serialize;

use matup_core::color::{linear_to_srgb, to_u8};
use matup_core::lights::{Light, LightSetSpec};
use matup_core::map::Map;
use matup_core::material::{MapKind, Material};
use matup_core::render::{render, RenderOptions};
use matup_core::resample::{
    box_downsample, gaussian_blur, lr_texel, neighbourhood_ranges, seam_steps, Border, SeamSteps,
};
use matup_core::shading::ShadingModel;
use matup_core::tileable::{detect_tileable, wrap_seam_ratio};
use matup_core::{Error, Result};

use crate::invented::{invented_structure, Invented};

/// PSNR of identical images: the mean squared error is floored at 1e-10, so PSNR tops out at
/// 100 dB instead of infinity (JSON has no infinity).
pub const MAX_PSNR: f64 = 100.0;

/// Lights rendered and compared together by [`evaluate`].
const LIGHTS_AT_ONCE: usize = 4;

/// The numbers `matup eval` reports. Render metrics are over display-space renders (METHOD.md's
/// tone mapping and sRGB curve), averaged over the lights.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Evaluation {
    pub lights: usize,
    /// dB over every texel of every render (peak 1).
    pub render_psnr: f64,
    /// Mean SSIM (Gaussian window σ = 1.5, per channel).
    pub render_ssim: f64,
    /// Mean FLIP error (NVIDIA's LDR FLIP at its default 67 pixels per degree); 0 is identical.
    pub render_flip: f64,
    /// RMSE of the linear base colour.
    pub base_color_rmse: f64,
    /// Mean angle between the normals, in degrees.
    pub normal_error_degrees: f64,
    pub roughness_rmse: f64,
    pub metallic_rmse: f64,
    /// The scale the candidate was upscaled by: seams and block edges are measured on its
    /// input's texel grid (1: every step).
    pub scale: usize,
    /// Wrap-around seam ratio of the candidate's base colour and normal, the larger (1 is
    /// seamless), and of the reference's, at the grid's phase ([`wrap_seam_ratio`]).
    pub seam_ratio: f64,
    pub reference_seam_ratio: f64,
    /// Each map's wrap-around seam ratio ([`seam_ratios`]), the candidate's and the reference's.
    pub map_seams: BTreeMap<String, f64>,
    pub reference_map_seams: BTreeMap<String, f64>,
    /// The two parts of each map's seam ratio ([`map_seam_steps`]): where the candidate's ratio
    /// exceeds the reference's, whether its wrap-around step is larger or its interior smoother.
    pub map_seam_steps: BTreeMap<String, SeamSteps>,
    pub reference_map_seam_steps: BTreeMap<String, SeamSteps>,
    /// Each map's block-edge ratio ([`block_edge_ratio`]), the candidate's and the
    /// reference's: about 1 without a grid of the input's texels in the output.
    pub map_block_edges: BTreeMap<String, f64>,
    pub reference_map_block_edges: BTreeMap<String, f64>,
    /// Sharpness of the candidate's and the reference's renders: the mean gradient magnitude
    /// ([`sharpness`]), averaged over the lights. A blurry result reads below the reference,
    /// an oversharpened one above.
    pub render_sharpness: f64,
    pub reference_render_sharpness: f64,
    /// Base-colour texels with a hue neither the input nor the reference has ([`false_colour`]),
    /// when the caller knows the input.
    #[serde(flatten)]
    pub false_colour: Option<FalseColour>,
    /// Each map's structure the input has nowhere near ([`new_structure`]), when the caller
    /// knows the input.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub new_structure: BTreeMap<String, NewStructure>,
    /// Of those maps, the largest share of texels of new structure ([`worst_new_structure`]).
    pub new_structure_worst: Option<f64>,
    /// Of those maps, the largest share of texels of invented structure
    /// ([`worst_invented_structure`]).
    pub invented_structure_worst: Option<f64>,
}

/// How many texels of an upscaled base colour have a hue that neither the input nor the truth
/// has ([`false_colour`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct FalseColour {
    pub false_colour_texels: f64,
    /// The share of all texels.
    pub false_colour_rate: f64,
}

/// Levels of 255 the input's chroma range is widened by before a texel counts as false colour.
pub const FALSE_COLOUR_MARGIN: i32 = 12;

/// The texels of `candidate` (a linear base colour `scale` times the size of `lr`, the linear
/// base colour it was upscaled from) whose chroma lies outside the chroma range of the input
/// texels around it, where `truth`'s (the true high-resolution base colour) does not. Chroma is
/// (R − G, B − G) of the stored 8-bit sRGB values; the range is that of the texel's own input
/// texel and its 8 neighbours, widened by [`FALSE_COLOUR_MARGIN`] levels. Detail finer than a
/// texel in luminance (a dark groove) is no false colour; a hue the input has nowhere near is.
/// Without a truth every texel outside the range counts. Neighbours past the edge wrap around
/// for a tileable input (`Border::Wrap`, as its output was made) and are clamped otherwise.
pub fn false_colour(
    lr: &Map,
    candidate: &Map,
    truth: Option<&Map>,
    border: Border,
) -> Result<FalseColour> {
    let scale = candidate.width() / lr.width().max(1);
    if scale == 0
        || candidate.width() != lr.width() * scale
        || candidate.height() != lr.height() * scale
        || truth.is_some_and(|t| (t.width(), t.height()) != (candidate.width(), candidate.height()))
    {
        return Err(Error::Invalid(format!(
            "false colour: the upscaled base colour ({}×{}) is no whole multiple of the input's \
             ({}×{}), or the truth's size differs",
            candidate.width(),
            candidate.height(),
            lr.width(),
            lr.height()
        )));
    }
    // Chroma in levels of the stored 8-bit sRGB values.
    let chroma = |m: &Map| -> Vec<[f32; 2]> {
        let level = |c: usize, i: usize| to_u8(linear_to_srgb(m.plane(c)[i])) as f32;
        (0..m.texels())
            .map(|i| [level(0, i) - level(1, i), level(2, i) - level(1, i)])
            .collect()
    };
    let (up, true_chroma) = (chroma(candidate), truth.map(chroma));
    let ranges = neighbourhood_ranges(&chroma(lr), lr.width(), border);
    let margin = FALSE_COLOUR_MARGIN as f32;
    let inside = |c: [f32; 2], r: &[[f32; 2]; 2]| {
        (0..2).all(|k| (r[k][0] - margin..=r[k][1] + margin).contains(&c[k]))
    };
    let w = candidate.width();
    let texels = (0..up.len())
        .filter(|&i| {
            let r = &ranges[lr_texel(i, w, scale, lr.width())];
            !inside(up[i], r) && true_chroma.as_ref().is_none_or(|t| inside(t[i], r))
        })
        .count();
    Ok(FalseColour {
        false_colour_texels: texels as f64,
        false_colour_rate: texels as f64 / up.len().max(1) as f64,
    })
}

/// How far a texel may lie outside the range of the input texels around it, in 8-bit levels,
/// before it counts as new structure ([`new_structure`]): well past a JPEG's noise, and past
/// what sharpening an edge the input has draws (bicubic: 0.003% of DamagedHelmet's colour).
pub const NEW_STRUCTURE_LEVELS: f32 = 16.0;

/// How far a normal may turn from every input normal around it before it counts as new
/// structure, in degrees.
pub const NEW_STRUCTURE_DEGREES: f32 = 10.0;

/// Structure an upscaled map has that its input has nowhere near, and how well it box-filters
/// back to its input ([`new_structure`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct NewStructure {
    /// The share of texels whose luminance (a grey map: value) lies more than
    /// [`NEW_STRUCTURE_LEVELS`] outside the range of its input texel's 3×3 neighbourhood.
    pub luminance: f64,
    /// The share of texels with any channel so far outside its neighbourhood's range.
    pub channel: f64,
    /// Normal maps: the share of texels turned more than [`NEW_STRUCTURE_DEGREES`] from every
    /// input normal around them.
    pub normal_angle: Option<f64>,
    /// The mean and the worst of the output's blocks box-filtered back against their input
    /// texel, in 8-bit levels of the stored values (colour averaged as light, in linear).
    pub box_back_mean: f64,
    pub box_back_worst: f64,
    /// Structure drawn where the input is flat within its noise, which neither a smooth
    /// upsampling of the input nor (where given) the truth has ([`invented_structure`]).
    pub invented: Invented,
}

/// [`NewStructure`] of each map `candidate` (upscaled `scale`×) and `lr` both have: base colour,
/// normal, roughness, metallic and height; invented structure against `truth` where given.
/// Neighbours past the edge as `border` says.
pub fn new_structure(
    lr: &Material,
    candidate: &Material,
    truth: Option<&Material>,
    border: Border,
) -> Result<BTreeMap<String, NewStructure>> {
    let scale = candidate.width() / lr.width().max(1);
    if scale == 0
        || candidate.width() != lr.width() * scale
        || candidate.height_px() != lr.height_px() * scale
    {
        return Err(Error::Invalid(format!(
            "new structure: the upscaled material ({}×{}) is no whole multiple of its input \
             ({}×{})",
            candidate.width(),
            candidate.height_px(),
            lr.width(),
            lr.height_px()
        )));
    }
    let kinds = [
        MapKind::BaseColor,
        MapKind::Normal,
        MapKind::Roughness,
        MapKind::Metallic,
        MapKind::Height,
    ];
    let mut out = BTreeMap::new();
    for kind in kinds {
        if let (Some(lr_map), Some(up)) = (lr.map(kind), candidate.map(kind)) {
            let truth = truth.and_then(|t| t.map(kind));
            out.insert(
                kind.file_stem().to_string(),
                map_new_structure(kind, lr_map, up, truth, scale, border),
            );
        }
    }
    Ok(out)
}

/// The largest share of texels of new structure over `maps`: any channel's, or a normal's angle.
pub fn worst_new_structure(maps: &BTreeMap<String, NewStructure>) -> f64 {
    (maps.values())
        .map(|m| m.channel.max(m.normal_angle.unwrap_or(0.0)))
        .fold(0.0, f64::max)
}

/// The largest share of texels of invented structure over `maps` ([`invented_structure`]).
pub fn worst_invented_structure(maps: &BTreeMap<String, NewStructure>) -> f64 {
    (maps.values())
        .map(|m| m.invented.share)
        .fold(0.0, f64::max)
}

/// [`new_structure`] of one map of `kind`.
fn map_new_structure(
    kind: MapKind,
    lr: &Map,
    up: &Map,
    truth: Option<&Map>,
    scale: usize,
    border: Border,
) -> NewStructure {
    // The values as stored, in 8-bit levels.
    let stored = |c: usize, v: f32| 255.0 * kind.stored(c, v);
    let channels = lr.channels().min(up.channels()).min(3);
    let levels = |m: &Map| -> Vec<[f32; 4]> {
        (0..m.texels())
            .map(|i| {
                let mut v = [0.0; 4];
                for (c, value) in v.iter_mut().enumerate().take(channels) {
                    *value = stored(c, m.plane(c)[i]);
                }
                // The luminance (Rec. 709 weights) of colours, else the first channel.
                v[3] = match channels {
                    3 => 0.2126 * v[0] + 0.7152 * v[1] + 0.0722 * v[2],
                    _ => v[0],
                };
                v
            })
            .collect()
    };
    let (lr_levels, up_levels) = (levels(lr), levels(up));
    let ranges = neighbourhood_ranges(&lr_levels, lr.width(), border);
    let (w, n) = (up.width(), up.texels().max(1) as f64);
    let outside =
        |v: f32, [lo, hi]: [f32; 2]| v < lo - NEW_STRUCTURE_LEVELS || v > hi + NEW_STRUCTURE_LEVELS;
    let (mut luminance, mut channel) = (0usize, 0usize);
    for (i, v) in up_levels.iter().enumerate() {
        let r = &ranges[lr_texel(i, w, scale, lr.width())];
        luminance += outside(v[3], r[3]) as usize;
        channel += (0..channels).any(|c| outside(v[c], r[c])) as usize;
    }
    let normal_angle = (kind == MapKind::Normal).then(|| {
        let cos_limit = NEW_STRUCTURE_DEGREES.to_radians().cos();
        let normal = |m: &Map, i: usize| glam::Vec3::from_array([0, 1, 2].map(|c| m.plane(c)[i]));
        let far = (0..up.texels())
            .filter(|&i| {
                let (y, x) = ((i / w / scale) as isize, ((i % w) / scale) as isize);
                let n = normal(up, i).normalize_or_zero();
                !(0..9).any(|k| {
                    let j = border.index(y + k / 3 - 1, lr.height()) * lr.width()
                        + border.index(x + k % 3 - 1, lr.width());
                    normal(lr, j).normalize_or_zero().dot(n) >= cos_limit
                })
            })
            .count();
        far as f64 / n
    });
    // Box-filtered back as the file's values average: colour as light, normals as directions.
    let back = box_downsample(up, scale);
    let (mut sum, mut worst) = (0.0f64, 0.0f32);
    for i in 0..lr.texels() {
        let mut mean = [0.0f32; 3];
        for (c, value) in mean.iter_mut().enumerate().take(channels) {
            *value = back.plane(c)[i];
        }
        if kind == MapKind::Normal {
            let unit = glam::Vec3::from_array(mean).normalize_or_zero();
            mean = unit.to_array();
        }
        let miss = (0..channels)
            .map(|c| (stored(c, mean[c]) - stored(c, lr.plane(c)[i])).abs())
            .fold(0.0f32, f32::max);
        sum += miss as f64;
        worst = worst.max(miss);
    }
    NewStructure {
        luminance: luminance as f64 / n,
        channel: channel as f64 / n,
        normal_angle,
        box_back_mean: sum / lr.texels().max(1) as f64,
        box_back_worst: worst as f64,
        invented: invented_structure(kind, lr, up, truth, border),
    }
}

/// Renders `reference` and `candidate` under `lights` with `model` and compares them.
/// The materials must have the same size.
pub fn evaluate(
    reference: &Material,
    candidate: &Material,
    scale: usize,
    model: &dyn ShadingModel,
    lights: &LightSetSpec,
) -> Result<Evaluation> {
    let size = |m: &Material| (m.width(), m.height_px());
    if size(reference) != size(candidate) {
        let name = |m: &Material| {
            m.origin.as_ref().map_or("(in memory)".to_string(), |o| {
                o.folder.display().to_string()
            })
        };
        return Err(Error::Invalid(format!(
            "the reference {} is {}×{} but the candidate {} is {}×{}: compare materials of one size",
            name(reference),
            reference.width(),
            reference.height_px(),
            name(candidate),
            candidate.width(),
            candidate.height_px()
        )));
    }
    let (reference_tiles, _) = detect_tileable(reference);
    let options = RenderOptions {
        supersample: true,
        border: Border::for_tiling(reference_tiles),
    };
    let lights: Vec<Light> = lights.build();
    // A few lights at a time, so memory stays bounded for large materials.
    let per_light: Vec<[f64; 5]> = lights
        .chunks(LIGHTS_AT_ONCE)
        .flat_map(|chunk| {
            let a = render(reference, model, chunk, options);
            let b = render(candidate, model, chunk, options);
            a.par_iter()
                .zip(&b)
                .map(|(x, y)| {
                    // In the order of the means below.
                    [
                        squared_error(x, y),
                        ssim(x, y),
                        flip(x, y),
                        sharpness(y),
                        sharpness(x),
                    ]
                })
                .collect::<Vec<_>>()
        })
        .collect();
    let n = per_light.len().max(1) as f64;
    let mean = |k: usize| per_light.iter().map(|p| p[k]).sum::<f64>() / n;
    let texels = (reference.width() * reference.height_px()) as f64;
    let seam_steps = map_seam_steps(candidate, scale);
    let reference_seam_steps = map_seam_steps(reference, scale);
    Ok(Evaluation {
        lights: lights.len(),
        render_psnr: psnr(mean(0) / (3.0 * texels)),
        render_ssim: mean(1),
        render_flip: mean(2),
        base_color_rmse: rmse(&reference.base_color, &candidate.base_color),
        normal_error_degrees: mean_angle_degrees(&reference.normal, &candidate.normal),
        roughness_rmse: rmse(&reference.roughness, &candidate.roughness),
        metallic_rmse: rmse(&reference.metallic, &candidate.metallic),
        scale,
        seam_ratio: wrap_seam_ratio(candidate, scale) as f64,
        reference_seam_ratio: wrap_seam_ratio(reference, scale) as f64,
        map_seams: seam_ratios(&seam_steps),
        reference_map_seams: seam_ratios(&reference_seam_steps),
        map_seam_steps: seam_steps,
        reference_map_seam_steps: reference_seam_steps,
        map_block_edges: map_block_edges(candidate, scale),
        reference_map_block_edges: map_block_edges(reference, scale),
        render_sharpness: mean(3),
        reference_render_sharpness: mean(4),
        false_colour: None,
        new_structure: BTreeMap::new(),
        new_structure_worst: None,
        invented_structure_worst: None,
    })
}

/// Each map's wrap-around seam ratio, by file name (`baseColor`, `normal`, …), from its
/// [`map_seam_steps`]: the mean |difference| across the wrap-around edges over that across
/// interior edges at the same phase of the input's texel grid ([`seam_steps`]), the larger of
/// rows and columns. About 1 where copies laid side by side join without a seam; a tileable
/// input's maps show what its output's should be. Needs no reference.
pub fn seam_ratios(steps: &BTreeMap<String, SeamSteps>) -> BTreeMap<String, f64> {
    (steps.iter())
        .map(|(map, s)| (map.clone(), s.ratio()))
        .collect()
}

/// Each map's [`SeamSteps`] (the wrap-around step and the interior steps at the grid's phase
/// that [`seam_ratios`] divides), by file name.
pub fn map_seam_steps(material: &Material, scale: usize) -> BTreeMap<String, SeamSteps> {
    each_map(material, |map| seam_steps(map, scale))
}

/// Each map's [`block_edge_ratio`], by file name; empty at scale 1.
pub fn map_block_edges(material: &Material, scale: usize) -> BTreeMap<String, f64> {
    if scale < 2 {
        return BTreeMap::new();
    }
    each_map(material, |map| block_edge_ratio(map, scale))
}

fn each_map<T>(material: &Material, f: impl Fn(&Map) -> T) -> BTreeMap<String, T> {
    MapKind::ALL
        .into_iter()
        .filter_map(|kind| Some((kind.file_stem().to_string(), f(material.map(kind)?))))
        .collect()
}

/// How strongly an output ×`scale` shows its input's texel grid: the mean |difference| across
/// the edges of the `scale`-texel blocks over the mean |difference| between neighbours inside
/// a block, over both axes and every channel (the wrap-around edge left out). A smooth
/// upscale of smooth content reads about 1; on real base colours at ×4 bilinear reads
/// 1.0–1.15, Lanczos-3 up to 1.3 and bicubic up to 1.45, because the input's own texel steps
/// land on the block edges (docs/experiments/2026-11-26-seamless-by-default.md).
pub fn block_edge_ratio(map: &Map, scale: usize) -> f64 {
    let (w, h) = (map.width(), map.height());
    // [across block edges, inside blocks]: (sum, count).
    let mut sums = [(0.0f64, 0u64); 2];
    for c in 0..map.channels() {
        let plane = map.plane(c);
        for y in 0..h {
            for x in 0..w {
                let v = plane[y * w + x] as f64;
                if x + 1 < w {
                    let s = &mut sums[((x + 1) % scale != 0) as usize];
                    s.0 += (plane[y * w + x + 1] as f64 - v).abs();
                    s.1 += 1;
                }
                if y + 1 < h {
                    let s = &mut sums[((y + 1) % scale != 0) as usize];
                    s.0 += (plane[(y + 1) * w + x] as f64 - v).abs();
                    s.1 += 1;
                }
            }
        }
    }
    let mean = |(sum, n): (f64, u64)| sum / n.max(1) as f64;
    let (edges, inside) = (mean(sums[0]), mean(sums[1]));
    if inside <= 1e-12 {
        return if edges <= 1e-12 { 1.0 } else { f64::INFINITY };
    }
    edges / inside
}

/// Sharpness of an image: the gradient magnitude `√(dx² + dy²)` from forward differences
/// between neighbouring texels, averaged over the texels (the last row and column have no
/// forward neighbour) and the channels.
pub fn sharpness(image: &Map) -> f64 {
    let (w, h) = (image.width(), image.height());
    if w < 2 || h < 2 {
        return 0.0;
    }
    let total: f64 = (0..image.channels())
        .map(|c| {
            let p = image.plane(c);
            (0..h - 1)
                .into_par_iter()
                .map(|y| {
                    (0..w - 1)
                        .map(|x| {
                            let v = p[y * w + x];
                            let (dx, dy) = (p[y * w + x + 1] - v, p[(y + 1) * w + x] - v);
                            ((dx * dx + dy * dy) as f64).sqrt()
                        })
                        .sum::<f64>()
                })
                .sum::<f64>()
        })
        .sum();
    total / (image.channels() * (w - 1) * (h - 1)) as f64
}

/// PSNR in dB of a mean squared error over values with peak 1.
pub fn psnr(mse: f64) -> f64 {
    (-10.0 * mse.max(1e-10).log10()).min(MAX_PSNR)
}

fn squared_error(a: &Map, b: &Map) -> f64 {
    a.data()
        .iter()
        .zip(b.data())
        .map(|(x, y)| ((x - y) as f64).powi(2))
        .sum()
}

/// Root mean squared difference over every value of two maps of one shape.
pub fn rmse(a: &Map, b: &Map) -> f64 {
    (squared_error(a, b) / a.data().len().max(1) as f64).sqrt()
}

/// Mean angle in degrees between two unit normal maps.
pub fn mean_angle_degrees(a: &Map, b: &Map) -> f64 {
    let n = a.texels();
    let total: f64 = (0..n)
        .map(|i| {
            let u = glam::DVec3::from_array(std::array::from_fn(|c| a.plane(c)[i] as f64));
            let v = glam::DVec3::from_array(std::array::from_fn(|c| b.plane(c)[i] as f64));
            // atan2(|u × v|, u · v) stays exact near 0°, where acos (glam's angle_between)
            // loses precision.
            u.cross(v).length().atan2(u.dot(v)).to_degrees()
        })
        .sum();
    total / n.max(1) as f64
}

/// Mean SSIM of two images with values in [0, 1] (Wang et al. 2004: Gaussian window σ = 1.5
/// truncated at 11 texels (3σ each side), K1 = 0.01, K2 = 0.03), averaged over texels and channels; borders
/// repeat the edge texel.
pub fn ssim(a: &Map, b: &Map) -> f64 {
    const C1: f32 = 0.01 * 0.01;
    const C2: f32 = 0.03 * 0.03;
    let (w, h) = (a.width(), a.height());
    let mut total = 0.0f64;
    for c in 0..a.channels() {
        let x = a.plane(c);
        let y = b.plane(c);
        let blur = |v: Vec<f32>| gaussian_blur(&v, w, h, 1.5, Border::Clamp);
        let mx = blur(x.to_vec());
        let my = blur(y.to_vec());
        let xx = blur(x.iter().map(|v| v * v).collect());
        let yy = blur(y.iter().map(|v| v * v).collect());
        let xy = blur(x.iter().zip(y).map(|(p, q)| p * q).collect());
        total += (0..w * h)
            .map(|i| {
                let (mx, my) = (mx[i], my[i]);
                let vx = xx[i] - mx * mx;
                let vy = yy[i] - my * my;
                let cov = xy[i] - mx * my;
                (((2.0 * mx * my + C1) * (2.0 * cov + C2))
                    / ((mx * mx + my * my + C1) * (vx + vy + C2))) as f64
            })
            .sum::<f64>();
    }
    total / (a.channels() * w * h).max(1) as f64
}

/// Mean FLIP error of two display-space RGB images, through NVIDIA's reference
/// implementation (the `nv-flip` crate) on their 8-bit sRGB form.
pub fn flip(reference: &Map, test: &Map) -> f64 {
    let to_rgb8 = |m: &Map| -> Vec<u8> {
        (0..m.texels())
            .flat_map(|i| (0..3).map(move |c| to_u8(m.plane(c)[i])))
            .collect()
    };
    let (w, h) = (reference.width() as u32, reference.height() as u32);
    let error = nv_flip::flip(
        nv_flip::FlipImageRgb8::with_data(w, h, &to_rgb8(reference)),
        nv_flip::FlipImageRgb8::with_data(w, h, &to_rgb8(test)),
        nv_flip::DEFAULT_PIXELS_PER_DEGREE,
    );
    nv_flip::FlipPool::from_image(&error).mean() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Grey with dark grooves every 8th row, `size`² (linear).
    fn grooved_grey(size: usize) -> Map {
        Map::from_fn(size, size, 3, |_, y, _| if y % 8 == 3 { 0.01 } else { 0.3 })
    }

    #[test]
    fn new_structure_counts_blobs_the_input_has_nowhere_near_and_box_back_errors() {
        // A light speckled ground, 16² input texels upscaled ×4 by repetition (nothing new),
        // then with one black blob of 2×2 output texels in a light neighbourhood.
        let lr_colour = Map::from_fn(16, 16, 3, |_, y, x| {
            if (x * 7 + y * 3) % 11 == 0 {
                0.45
            } else {
                0.8
            }
        });
        let mut lr = Material::uniform(16, [0.8; 3], 0.5, 0.0);
        lr.base_color = lr_colour.clone();
        let mut up = Material::uniform(64, [0.8; 3], 0.5, 0.0);
        up.base_color = Map::from_fn(64, 64, 3, |c, y, x| lr_colour.get(c, y / 4, x / 4));
        let clean = new_structure(&lr, &up, None, Border::Wrap).unwrap();
        for (map, n) in &clean {
            assert_eq!((n.luminance, n.channel), (0.0, 0.0), "{map}");
            assert!(n.box_back_worst < 0.01, "{map}: {}", n.box_back_worst);
        }
        assert_eq!(clean["normal"].normal_angle, Some(0.0));
        assert_eq!(worst_new_structure(&clean), 0.0);
        // Input texel (1, 2) and its 8 neighbours are all 0.8: a black blob of 4 texels in its
        // block is 4 new texels,
        // and its block box-filters back far off (colour averaged as light).
        let (y0, x0) = (4 + 1, 8 + 1);
        assert!((0..9).all(|k| lr_colour.get(0, k / 3, 1 + k % 3) == 0.8));
        let mut blob = up.clone();
        for (y, x) in [(y0, x0), (y0, x0 + 1), (y0 + 1, x0), (y0 + 1, x0 + 1)] {
            for c in 0..3 {
                blob.base_color.plane_mut(c)[y * 64 + x] = 0.0;
            }
        }
        let found = new_structure(&lr, &blob, None, Border::Wrap).unwrap();
        let colour = found["baseColor"];
        assert_eq!(colour.luminance, 4.0 / 4096.0);
        assert_eq!(colour.channel, 4.0 / 4096.0);
        // The block's mean in linear light is 0.8·12/16 = 0.6: sRGB 203 against 231.
        let want = 255.0 * (linear_to_srgb(0.8) - linear_to_srgb(0.6));
        assert!(
            (colour.box_back_worst - want as f64).abs() < 0.01,
            "{colour:?}"
        );
        assert_eq!(worst_new_structure(&found), 4.0 / 4096.0);
        // A normal turned 30° in a flat neighbourhood is new; one turned 5° is not.
        let mut turned = up.clone();
        for (i, degrees) in [(0usize, 30.0f32), (64 * 40 + 40, 5.0)] {
            let a = degrees.to_radians();
            for (c, v) in [a.sin(), 0.0, a.cos()].into_iter().enumerate() {
                turned.normal.plane_mut(c)[i] = v;
            }
        }
        let normal = new_structure(&lr, &turned, None, Border::Wrap).unwrap()["normal"];
        assert_eq!(normal.normal_angle, Some(1.0 / 4096.0));
        // Sizes that are no whole multiple are refused.
        let odd = Material::uniform(30, [0.8; 3], 0.5, 0.0);
        assert!(new_structure(&lr, &odd, None, Border::Wrap).is_err());
    }

    #[test]
    fn false_colour_counts_hues_neither_input_nor_truth_has() {
        let truth = grooved_grey(64);
        let lr = matup_core::resample::box_downsample(&truth, 4);
        // The truth itself: grooves finer than an input texel, but grey.
        let exact = false_colour(&lr, &truth, Some(&truth), Border::Mirror).unwrap();
        assert_eq!(exact.false_colour_texels, 0.0);
        // Grooves tinted magenta (red and blue over green), as the issue shows.
        let tinted = Map::from_fn(64, 64, 3, |c, y, x| {
            let v = truth.get(c, y, x);
            if y % 8 == 3 && c != 1 {
                0.06
            } else {
                v
            }
        });
        let grooves = (64 * 64 / 8) as f64;
        let counted = false_colour(&lr, &tinted, Some(&truth), Border::Mirror).unwrap();
        assert_eq!(counted.false_colour_texels, grooves);
        assert!((counted.false_colour_rate - 1.0 / 8.0).abs() < 1e-12);
        // Against the input alone, the same; where the truth has the hue too, none.
        assert_eq!(
            false_colour(&lr, &tinted, None, Border::Wrap)
                .unwrap()
                .false_colour_texels,
            grooves
        );
        assert_eq!(
            false_colour(&lr, &tinted, Some(&tinted), Border::Mirror)
                .unwrap()
                .false_colour_texels,
            0.0
        );
        // A slight tint, within the margin of 12 levels, is no false colour.
        let slight = Map::from_fn(64, 64, 3, |c, y, x| {
            truth.get(c, y, x) * if c == 0 { 1.04 } else { 1.0 }
        });
        assert_eq!(
            false_colour(&lr, &slight, Some(&truth), Border::Mirror)
                .unwrap()
                .false_colour_texels,
            0.0
        );
    }

    fn noise(w: usize, h: usize, seed: usize) -> Map {
        Map::from_fn(w, h, 3, |c, y, x| {
            (((x * 131 + y * 71 + c * 29 + seed * 17) % 97) as f32) / 96.0
        })
    }

    #[test]
    fn identical_images_score_perfectly() {
        let a = noise(32, 24, 1);
        assert_eq!(
            psnr(squared_error(&a, &a) / a.data().len() as f64),
            MAX_PSNR
        );
        assert!((ssim(&a, &a) - 1.0).abs() < 1e-6);
        assert_eq!(flip(&a, &a), 0.0);
    }

    #[test]
    fn sharpness_is_the_mean_gradient_magnitude() {
        // A ramp rising 0.1 per column: every gradient is (0.1, 0).
        let ramp = Map::from_fn(5, 4, 3, |_, _, x| 0.1 * x as f32);
        assert!((sharpness(&ramp) - 0.1).abs() < 1e-6);
        // A checkerboard of 0 and 1: every gradient is (±1, ±1), magnitude √2.
        let checker = Map::from_fn(6, 6, 1, |_, y, x| ((x + y) % 2) as f32);
        assert!((sharpness(&checker) - 2f64.sqrt()).abs() < 1e-6);
        assert_eq!(sharpness(&Map::filled(8, 8, 3, 0.4)), 0.0);
    }

    #[test]
    fn psnr_of_a_known_error() {
        // A uniform error of 0.1 has MSE 0.01: 20 dB.
        assert!((psnr(0.01) - 20.0).abs() < 1e-9);
    }

    #[test]
    fn more_distortion_scores_worse() {
        let a = noise(48, 48, 2);
        let slightly = a.clone().map_values(|v| (v + 0.02).min(1.0));
        let very = noise(48, 48, 3);
        assert!(ssim(&a, &slightly) > ssim(&a, &very));
        assert!(flip(&a, &slightly) < flip(&a, &very));
        assert!(ssim(&a, &very) < 0.5);
    }

    #[test]
    fn normal_angles_in_degrees() {
        let up = Map::from_fn(2, 1, 3, |c, _, _| if c == 2 { 1.0 } else { 0.0 });
        let side = Map::from_fn(2, 1, 3, |c, _, x| match (c, x) {
            (0, 0) => 1.0,
            (2, 1) => 1.0,
            _ => 0.0,
        });
        // One texel at 90°, one at 0°.
        assert!((mean_angle_degrees(&up, &side) - 45.0).abs() < 1e-4);
    }
}
