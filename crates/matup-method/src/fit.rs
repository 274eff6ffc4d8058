//! The per-material fit of the paper's method (`--epochs N`): a level's LR renders, the
//! targets made from them and the filter trained on them; then the filter run over every
//! output texel, its answers added to the residual base (with no filter, the residual base
//! decoded into maps).

use std::collections::hash_map::DefaultHasher;
use std::hash::{Hash, Hasher};
use std::sync::Arc;

use rayon::prelude::*;

use crate::config::{Config, ResidualBase};
use crate::context::Context;
use crate::features::{constant_features, features};
use crate::filter::decode::{decode, shading_params};
use crate::filter::{Filter, FEATURES, FEATURE_NAMES};
use crate::report::{timed, LevelReport};
use crate::residual::residual_base;
use crate::targets::{oracle_targets, upsampled_targets, DetailBase, LrRenders, Targets};
use crate::train::{train, Checkpoint, Examples, Shading, TrainStats};
use matup_core::candle_core::Tensor;
use matup_core::lights::Light;
use matup_core::map::Map;
use matup_core::material::{MapKind, Material};
use matup_core::progress::Progress;
use matup_core::render::{render, RenderOptions};
use matup_core::resample::{upsample, Border, Kernel};
use matup_core::{Error, Result};

/// A trained filter (none where nothing was learned) and the features it holds constant.
pub(crate) struct TrainedFilter {
    pub(crate) filter: Option<Filter>,
    pub(crate) fixed: [Option<f32>; FEATURES],
}

/// A level's learning: the features it holds constant, and unless every feature is constant
/// or training is off, the residual base (returned for reuse), LR renders, targets and the
/// trained filter. Fills in `report`'s training fields.
pub(crate) fn learn_level(
    lr: &Material,
    scale: usize,
    level: usize,
    ctx: &Context,
    report: &mut LevelReport,
    timings: &mut Vec<(String, f64)>,
    skipped: &mut Vec<String>,
) -> Result<(TrainedFilter, Option<Arc<Map>>)> {
    let config = ctx.config;
    let tag = |stage: &str| format!("level {}: {stage}", level + 1);
    let lr_features = features(lr);

    // Constant features are kept, not learned; they are no input either.
    let fixed = constant_features(&lr_features, config.skip);
    report.constant_features = (0..FEATURES)
        .filter(|&k| fixed[k].is_some())
        .map(|k| FEATURE_NAMES[k])
        .collect();
    if !report.constant_features.is_empty() {
        skipped.push(format!(
            "level {}: constant features kept, not learned: {}",
            level + 1,
            report.constant_features.join(", ")
        ));
    }
    let untrained = if fixed.iter().all(Option::is_some) {
        Some("every feature is constant")
    } else if config.train.epochs == 0 {
        Some("0 epochs, the residual base is the result")
    } else {
        None
    };
    if let Some(why) = untrained {
        skipped.push(format!("level {}: training: {why}", level + 1));
        return Ok((
            TrainedFilter {
                filter: None,
                fixed,
            },
            None,
        ));
    }

    // What the filter's answers are added to; training reads all of it (so a trained level
    // holds it whole, whatever the memory limit).
    ctx.progress.stage(&tag("residual base"), 1);
    let base = Arc::new(timed(timings, tag("residual base"), || {
        residual_base(lr, &config.filter, &ctx.map_upsamplers(), scale, ctx.border)
    })?);
    ctx.progress.advance(1, None);
    let (filter, lights, stats) = fit_filter(
        lr,
        &lr_features,
        &base,
        fixed,
        scale,
        level,
        ctx,
        timings,
        skipped,
    )?;
    report.lights_used = lights;
    report.training = stats;
    Ok((
        TrainedFilter {
            filter: Some(filter),
            fixed,
        },
        Some(base),
    ))
}

/// Trains a level's filter on the residual base `base`: LR renders, targets, training.
/// Returns the filter, the number of lights it was trained under and the training's stats.
#[allow(clippy::too_many_arguments)]
fn fit_filter(
    lr: &Material,
    lr_features: &Map,
    base: &Arc<Map>,
    fixed: [Option<f32>; FEATURES],
    scale: usize,
    level: usize,
    ctx: &Context,
    timings: &mut Vec<(String, f64)>,
    skipped: &mut Vec<String>,
) -> Result<(Filter, usize, TrainStats)> {
    let config = ctx.config;
    let tag = |stage: &str| format!("level {}: {stage}", level + 1);
    let input_channels: Vec<usize> = (0..FEATURES).filter(|&k| fixed[k].is_none()).collect();

    // LR renders (anti-aliased), dropping lights that light nothing.
    ctx.progress
        .stage(&tag("render LR"), ctx.lights.len() as u64);
    let (lights, renders) = timed(timings, tag("render LR"), || render_lr(lr, ctx))?;
    ctx.progress.advance(ctx.lights.len() as u64, None);
    if lights.len() < ctx.lights.len() {
        skipped.push(format!(
            "level {}: {} of {} lights light nothing; their renders were not upsampled",
            level + 1,
            ctx.lights.len() - lights.len(),
            ctx.lights.len()
        ));
    }

    // The targets, stored compactly.
    ctx.progress.stage(&tag("targets"), renders.len() as u64);
    let (w, h) = (lr.width() * scale, lr.height_px() * scale);
    let heights = (lr.height.as_ref()).map(|m| upsample(m, scale, Kernel::Bilinear, ctx.border));
    let targets = timed(timings, tag("targets"), || match &ctx.options.oracle {
        Some(truth) => oracle_targets(
            truth,
            w,
            h,
            &lights,
            ctx.model.as_ref(),
            ctx.border,
            ctx.progress,
        ),
        None => upsampled_targets(
            config.train.targets,
            &LrRenders {
                renders: &renders,
                lights: &lights,
                model: ctx.model.as_ref(),
                scale,
                border: ctx.border,
            },
            ctx.upsampler,
            &DetailBase {
                features: base,
                fixed: &fixed,
                heights: heights.as_ref(),
                kernel: match config.filter.residual_base {
                    ResidualBase::Kernel(k) => Some(k),
                    ResidualBase::Upsampler => None,
                },
            },
            ctx.progress,
        ),
    })?;

    let filter = Filter::new(
        &config.filter,
        scale,
        input_channels,
        config.seed.wrapping_add(level as u64),
    )?;
    let main = Arc::new(Examples::new(
        lr_features,
        Arc::clone(base),
        heights,
        targets,
        &filter,
        ctx.border,
    ));

    // Cross-scale self-supervision: the LR material one scale down is the input, the LR
    // material the answer, its exact renders the targets.
    let cross = if config.train.cross_scale > 0.0 {
        if lr.width().is_multiple_of(scale) && lr.height_px().is_multiple_of(scale) {
            let lower = lr.box_downsample(scale);
            let lower_base = residual_base(
                &lower,
                &config.filter,
                &ctx.map_upsamplers(),
                scale,
                ctx.border,
            )?;
            Some(Arc::new(Examples::new(
                &features(&lower),
                Arc::new(lower_base),
                lr.height.clone(),
                Targets::from_renders(&renders),
                &filter,
                ctx.border,
            )))
        } else {
            skipped.push(format!(
                "level {}: cross-scale term: {}×{} is not divisible by {scale}",
                level + 1,
                lr.width(),
                lr.height_px()
            ));
            None
        }
    } else {
        None
    };
    drop(renders);

    let shading = Shading {
        model: ctx.model.clone(),
        lights: lights.clone().into(),
        norm: config.train.loss,
    };
    let checkpoint = ctx
        .options
        .checkpoint_folder
        .as_ref()
        .map(|folder| Checkpoint {
            folder: folder.join(format!("level{}", level + 1)),
            resume: ctx.options.resume,
            fingerprint: fingerprint(lr_features, config, level),
        });
    let stats = timed(timings, tag("train"), || {
        train(
            &filter,
            &main,
            cross.as_ref().map(|c| (c, config.train.cross_scale)),
            &shading,
            fixed,
            &config.train,
            &config.device,
            config.seed.wrapping_add(level as u64),
            checkpoint.as_ref(),
            ctx.progress,
        )
    })?;
    Ok((filter, lights.len(), stats))
}

/// The anti-aliased LR renders under the lights that light something (all of them with
/// skipping off).
fn render_lr(lr: &Material, ctx: &Context) -> Result<(Vec<Light>, Vec<Map>)> {
    let renders = render(
        lr,
        ctx.model.as_ref(),
        &ctx.lights,
        RenderOptions {
            supersample: true,
            border: ctx.border,
        },
    );
    let (lights, renders): (Vec<Light>, Vec<Map>) = ctx
        .lights
        .iter()
        .zip(renders)
        .filter(|(_, r)| !ctx.config.skip || r.data().iter().any(|&v| v >= 0.5 / 255.0))
        .map(|(l, r)| (*l, r))
        .unzip();
    if lights.is_empty() {
        return Err(Error::Invalid(
            "no light lights the material: every render is black".into(),
        ));
    }
    Ok((lights, renders))
}

/// A digest of what a level's training depends on, so a checkpoint is resumed only for the
/// same input and settings.
fn fingerprint(material_features: &Map, config: &Config, level: usize) -> String {
    let mut h = DefaultHasher::new();
    config.to_toml().hash(&mut h);
    level.hash(&mut h);
    (material_features.width(), material_features.height()).hash(&mut h);
    for v in material_features.data() {
        v.to_bits().hash(&mut h);
    }
    format!("{:016x}", h.finish())
}

/// Runs the trained filter (none: no residual) over every output texel of `lr` upsampled by
/// `scale`, adding its answers to `residual_base` (the output-size features).
pub(crate) fn infer_material(
    lr: &Material,
    filter: Option<&Filter>,
    fixed: [Option<f32>; FEATURES],
    residual_base: &Map,
    scale: usize,
    border: Border,
    progress: &dyn Progress,
) -> Result<Material> {
    let lr_features = features(lr);
    let (w, h) = (lr.width() * scale, lr.height_px() * scale);
    let n = w * h;
    progress.stage("infer", n as u64);
    let folded = filter.map(Filter::folded_weights).transpose()?;
    let mut hr = Material::uniform(1, [0.0; 3], 0.5, 0.0);
    hr.base_color = Map::filled(w, h, 3, 0.0);
    hr.normal = Map::filled(w, h, 3, 0.0);
    hr.roughness = Map::filled(w, h, 1, 0.0);
    hr.metallic = Map::filled(w, h, 1, 0.0);
    let [red, green, blue] = hr.base_color.planes_mut();
    let [nx, ny, nz] = hr.normal.planes_mut();
    let (metallic, roughness) = (hr.metallic.data_mut(), hr.roughness.data_mut());
    for start in (0..n).step_by(16384) {
        let end = n.min(start + 16384);
        let raw = match (filter, &folded) {
            (Some(filter), Some(folded)) => {
                let chunk: Vec<usize> = (start..end).collect();
                let (windows, phases) = filter.lr_windows(&lr_features, border, &chunk);
                filter.infer(folded, &windows, &phases)?
            }
            _ => vec![0.0; (end - start) * FEATURES],
        };
        // Decoded and written into the maps texel by texel on rayon's threads.
        (
            (start..end).into_par_iter(),
            raw.par_chunks(FEATURES),
            red[start..end].par_iter_mut(),
            green[start..end].par_iter_mut(),
            blue[start..end].par_iter_mut(),
            nx[start..end].par_iter_mut(),
            ny[start..end].par_iter_mut(),
            nz[start..end].par_iter_mut(),
            metallic[start..end].par_iter_mut(),
            roughness[start..end].par_iter_mut(),
        )
            .into_par_iter()
            .for_each(
                |(t, r, red, green, blue, nx, ny, nz, metallic, roughness)| {
                    let base: [f32; FEATURES] = residual_base.texel(t);
                    let p = decode(r, &base, &fixed).params;
                    [*red, *green, *blue] = p.base_color;
                    [*nx, *ny, *nz] = p.normal;
                    *metallic = p.metallic;
                    *roughness = p.alpha.sqrt();
                },
            );
        progress.advance((end - start) as u64, None);
    }
    upsample_anisotropy(lr, &mut hr, scale, border);
    hr.restore_invariants();
    Ok(hr)
}

/// [`infer_material`] without a filter, on the device of the residual base `features`
/// (`[7, h, w]`): the four maps the features decode to, `[channels, h, w]` each, left there.
/// The anisotropy maps are the caller's ([`upsample_anisotropy`]).
pub(crate) fn decoded_maps_on_device(
    features: &Tensor,
    fixed: [Option<f32>; FEATURES],
) -> Result<Vec<(MapKind, Tensor)>> {
    let (_, h, w) = features.dims3()?;
    // [10, h·w]: colour, metallic, normal, alpha, anisotropy's two.
    let params = shading_params(features, &fixed)?.t()?.contiguous()?;
    let map = |first: usize, channels: usize| {
        params.narrow(0, first, channels)?.reshape((channels, h, w))
    };
    // The invariants the host restores (`Material::restore_invariants`): the decoded values
    // are in range; the normals are made unit (never zero: z is at least √10⁻³).
    let normal = map(4, 3)?;
    let normal = normal.broadcast_div(&normal.sqr()?.sum_keepdim(0)?.sqrt()?)?;
    Ok(vec![
        (MapKind::BaseColor, map(0, 3)?),
        (MapKind::Normal, normal),
        (MapKind::Roughness, map(7, 1)?.sqrt()?),
        (MapKind::Metallic, map(3, 1)?),
    ])
}

/// `hr`'s anisotropy maps: `lr`'s upsampled bilinearly (not learned).
pub(crate) fn upsample_anisotropy(lr: &Material, hr: &mut Material, scale: usize, border: Border) {
    let up = |m: &Option<Map>| {
        m.as_ref()
            .map(|m| upsample(m, scale, Kernel::Bilinear, border))
    };
    hr.anisotropy = up(&lr.anisotropy);
    hr.anisotropy_angle = up(&lr.anisotropy_angle);
}
