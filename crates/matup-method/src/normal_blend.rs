//! A noisy material's normals from two upsamplings (`FilterConfig::normal_blend_noise`): the
//! run's where the input's normals are flat within the noise, the clean route's, projected
//! exactly, where they vary far past it. The network for degraded maps takes noise away but
//! softens bevels and grout, which carry a tiled material's shading (Tiles036 with σ 3 of
//! noise: 1.1 dB below the clean route in render PSNR, its flat tiles cleaner); the clean
//! route keeps edges and puts noise back only where the structure outweighs it
//! (docs/experiments/2026-12-02-texel-traces.md). The pipeline blends them into the residual
//! base once it is projected as the route says.

use crate::config::FilterConfig;
use crate::features::feature_range;
use crate::per_map::{upscale_one_map, MapUpsamplers};
use matup_core::map::Map;
use matup_core::material::{MapKind, Material};
use matup_core::resample::{gaussian_blur, gaussian_radius, upsample, Border, Kernel};
use matup_core::Result;

use crate::residual::{back_project_within, BACK_PROJECTIONS};

/// How `FilterConfig::normal_blend_noise` weighs the clean route's normals in, from the
/// local variance of the input's normals (x and y as the file stores them, the larger, in a
/// Gaussian window of [`NormalBlend::WINDOW`] LR texels) over the noise's: none up to
/// [`NormalBlend::FROM`] times it, all from [`NormalBlend::TO`] times it, a ramp between.
/// Tuned on the shared materials with σ 3 of noise, checked on the val sets
/// (docs/experiments/2026-12-02-texel-traces.md).
pub struct NormalBlend;

impl NormalBlend {
    pub const WINDOW: f32 = 1.5;
    pub const FROM: f32 = 20.0;
    pub const TO: f32 = 80.0;

    /// The clean route's weight where the input's normals vary by `variance` (levels²) under
    /// noise of `sigma` levels.
    pub fn weight(variance: f32, sigma: f32) -> f32 {
        let ratio = variance / (sigma * sigma);
        ((ratio - Self::FROM) / (Self::TO - Self::FROM)).clamp(0.0, 1.0)
    }
}

/// LR texels of context the blend reads around a region: the variance's window, the
/// weights' bilinear spread, and the clean normals' back-projection (two per round).
pub fn context(config: &FilterConfig) -> usize {
    match config.normal_blend_noise > 0.0 {
        true => gaussian_radius(NormalBlend::WINDOW) + 1 + 2 * BACK_PROJECTIONS,
        false => 0,
    }
}

/// Blends the clean route's normals of `lr` into the features `base` (×`scale`), where
/// `config` asks for it.
pub fn blend_clean_normals(
    base: &mut Map,
    lr: &Material,
    config: &FilterConfig,
    upsamplers: &MapUpsamplers,
    scale: usize,
    border: Border,
) -> Result<()> {
    let sigma = config.normal_blend_noise;
    if sigma <= 0.0 {
        return Ok(());
    }
    let upsampler = (upsamplers.clean_normals).unwrap_or_else(|| upsamplers.of(MapKind::Normal));
    let passes = config.map_passes();
    let upsampled = upscale_one_map(
        MapKind::Normal,
        &lr.normal,
        upsampler,
        scale,
        border,
        passes,
    )?;
    // The clean route's normal features (x and y), projected exactly onto the input's.
    let mut clean = upsampled.select_channels(&[0, 1]);
    let input = lr.normal.select_channels(&[0, 1]);
    back_project_within(&mut clean, &input, scale, border, |_| (-1.0, 1.0));
    let weights = upsample(
        &weights(&lr.normal, sigma, border),
        scale,
        Kernel::Bilinear,
        border,
    );
    let features = feature_range(MapKind::Normal).expect("normals are features");
    for (c, feature) in features.enumerate() {
        let planes = base.plane_mut(feature).iter_mut().zip(clean.plane(c));
        for ((b, n), w) in planes.zip(weights.data()) {
            *b += w * (n - *b);
        }
    }
    Ok(())
}

/// The clean route's weight at each texel of the input `normal` under noise of `sigma`
/// levels ([`NormalBlend::weight`]): from the local variance of x and y, the larger, as the
/// file stores them (8-bit levels of [0, 1]).
fn weights(normal: &Map, sigma: f32, border: Border) -> Map {
    let (w, h) = (normal.width(), normal.height());
    let levels = 255.0 / 2.0;
    let variance = |c: usize| -> Vec<f32> {
        let values: Vec<f32> = normal.plane(c).iter().map(|v| v * levels).collect();
        let squares: Vec<f32> = values.iter().map(|v| v * v).collect();
        let mean = gaussian_blur(&values, w, h, NormalBlend::WINDOW, border);
        let mean_square = gaussian_blur(&squares, w, h, NormalBlend::WINDOW, border);
        (mean.iter().zip(mean_square))
            .map(|(m, s)| (s - m * m).max(0.0))
            .collect()
    };
    let (x, y) = (variance(0), variance(1));
    let weights = (x.iter().zip(&y))
        .map(|(a, b)| NormalBlend::weight(a.max(*b), sigma))
        .collect();
    Map::from_planar(w, h, 1, weights)
}
