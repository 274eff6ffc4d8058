//! The method end to end: one function over a [`Config`] that runs the stages in order and
//! reports progress through a callback. It does not know which plugins exist.

use std::borrow::Cow;
use std::collections::hash_map::DefaultHasher;
use std::hash::{Hash, Hasher};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use rayon::prelude::*;
use serde::Serialize;

use crate::bands::{plan_bands, Assembler, BYTES_PER_BAND_TEXEL, ENSEMBLE_BYTES_PER_BAND_TEXEL};
use crate::config::{Chain, Config, ResidualBase, Selection, AUTO_UPSAMPLERS, MATERIAL_NETWORK};
use crate::filter::decode::decode;
use crate::filter::{Filter, FEATURES, FEATURE_NAMES};
use crate::height::{band_margin, detail_scale, rebuild_height};
use crate::residual::{self, residual_base};
use crate::select::{self, SelectionReport};
use crate::targets::{oracle_targets, upsampled_targets, DetailBase, LrRenders, Targets};
use crate::train::{train, Checkpoint, Examples, Shading, TrainStats};
use matup_core::lights::Light;
use matup_core::map::Map;
use matup_core::material::Material;
use matup_core::progress::{Progress, Silent};
use matup_core::render::{labelled_sheet, render, RenderOptions};
use matup_core::resample::{upsample, Border, Kernel};
use matup_core::shading::{shading_model, ShadingModel};
use matup_core::upsample::{check_scale, upsampler, RgbUpsampler};

pub use crate::features::{constant_features, features};
pub use matup_core::tileable::{detect_tileable, wrap_seam_ratio, TILEABLE_SEAM_RATIO};
use matup_core::{Error, PluginSpec, Result};

/// What a run did, for `run.json` and the CLI summary.
#[derive(Clone, Debug, Serialize)]
pub struct RunReport {
    pub matup_version: &'static str,
    /// The folder the input was loaded from, when it came from one.
    pub input_folder: Option<PathBuf>,
    pub input_size: [usize; 2],
    pub output_size: [usize; 2],
    pub config: Config,
    /// The RGB upsampler that ran (what `auto` chose).
    pub upsampler_used: String,
    pub tileable: bool,
    /// The seam ratio the tileability was detected from (absent when it was given).
    pub seam_ratio: Option<f32>,
    /// How the settings were chosen, with `select = "auto"` (`config` is the chosen one).
    pub selection: Option<SelectionReport>,
    pub levels: Vec<LevelReport>,
    /// Seconds per stage, in order.
    pub timings: Vec<(String, f64)>,
    pub total_seconds: f64,
    /// Mean training loss of the last epoch of the last level.
    pub final_loss: Option<f64>,
    /// Work skipped because the material could not use it.
    pub skipped: Vec<String>,
    /// The heap the output's bands were planned within (`--memory-limit`), in MiB; none: one
    /// band per level.
    pub memory_limit_mib: Option<f64>,
    /// Peak resident memory of the process (Linux), in MiB.
    pub peak_memory_mib: Option<f64>,
    pub threads: usize,
    /// A digest of the settings and input files, written by `matup batch` to tell a finished
    /// material from one to redo.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub settings_fingerprint: Option<String>,
}

/// One level (one ×s step) of a run.
#[derive(Clone, Debug, Serialize)]
pub struct LevelReport {
    pub scale: usize,
    pub input_size: [usize; 2],
    pub output_size: [usize; 2],
    pub lights_used: usize,
    /// Features held constant instead of learned.
    pub constant_features: Vec<&'static str>,
    pub training: TrainStats,
    /// The bands of rows the output was made in (1: whole).
    pub bands: usize,
}

/// Where a run may keep checkpoints, and whether to continue from them.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    pub checkpoint_folder: Option<PathBuf>,
    pub resume: bool,
    /// The true material at the output size, for benchmarks: its exact renders replace the
    /// upsampled ones as targets, which measures the method's ceiling (what the RGB upsampler
    /// costs).
    pub oracle: Option<Material>,
    /// Bytes of heap the output's bands are planned within (none: whole levels). Levels that
    /// train hold their residual base whole whatever the limit.
    pub memory_limit: Option<u64>,
}

fn timed<T>(
    timings: &mut Vec<(String, f64)>,
    name: String,
    f: impl FnOnce() -> Result<T>,
) -> Result<T> {
    let start = Instant::now();
    let out = f()?;
    let seconds = start.elapsed().as_secs_f64();
    // A stage run once per band adds up under one name.
    match timings.iter_mut().find(|(n, _)| *n == name) {
        Some((_, total)) => *total += seconds,
        None => timings.push((name, seconds)),
    }
    Ok(out)
}

/// Peak resident memory from `/proc/self/status` (VmHWM), where there is one.
pub fn peak_memory_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

/// Everything a level needs that stays the same across levels.
struct Context<'a> {
    config: &'a Config,
    model: Arc<dyn ShadingModel>,
    upsampler: Box<dyn RgbUpsampler>,
    lights: Vec<Light>,
    border: Border,
    options: &'a RunOptions,
    progress: &'a dyn Progress,
}

/// Upsamples `material` as `config` says. Returns the HR material (height included when the
/// input has one) and what the run did. Holds the whole output; [`upscale_streamed`] hands it
/// over in bands instead.
pub fn upscale(
    material: &Material,
    config: &Config,
    options: &RunOptions,
    progress: &dyn Progress,
) -> Result<(Material, RunReport)> {
    let mut assembler = Assembler::new(output_size(material, config)[1]);
    let report = upscale_streamed(material, config, options, progress, &mut |first, band| {
        assembler.add(first, band);
        Ok(())
    })?;
    let mut result = assembler.finish().expect("a run makes at least one band");
    result.origin = material.origin.clone();
    Ok((result, report))
}

/// The size `config` upsamples `material` to: [width, height].
pub fn output_size(material: &Material, config: &Config) -> [usize; 2] {
    let scale: usize = config.levels().iter().product();
    [material.width() * scale, material.height_px() * scale]
}

/// [`upscale`], handing the output to `sink` in bands of whole rows, top to bottom, as they
/// are finished: `sink(first_row, band)`, the band holding every map of the output's rows
/// from `first_row` on. Within [`RunOptions::memory_limit`] the last level works a band at a
/// time (levels before it are held whole: they are the next level's input).
pub fn upscale_streamed(
    material: &Material,
    config: &Config,
    options: &RunOptions,
    progress: &dyn Progress,
    sink: &mut dyn FnMut(usize, &Material) -> Result<()>,
) -> Result<RunReport> {
    config.validate()?;
    let start = Instant::now();
    let mut timings = Vec::new();
    let mut skipped = Vec::new();

    let model: Arc<dyn ShadingModel> =
        Arc::from(shading_model(&config.shading.parse::<PluginSpec>()?)?);
    let (tileable, seam) = match config.tileable {
        Some(t) => (t, None),
        None => {
            let (tileable, ratio) = detect_tileable(material);
            (tileable, Some(ratio))
        }
    };
    progress.note(&match seam {
        Some(r) => format!(
            "tileable: {} (wrap-around seam ratio {r:.2})",
            if tileable { "yes" } else { "no" }
        ),
        None => format!(
            "tileable: {} (as given)",
            if tileable { "yes" } else { "no" }
        ),
    });
    let (chosen, selection) = choose_settings(material, config, options, tileable, progress)?;
    let config = &chosen;
    // The upsampler of the chosen settings: the selection may have changed it.
    let (mut upsampler_used, upsampler) = choose_upsampler(config)?;
    if options.oracle.is_some() {
        upsampler_used = "oracle (exact renders of the true material)".into();
    }
    if let Some(s) = &selection {
        timings.push(("select".to_string(), s.seconds));
    }
    if material.height.is_none() {
        skipped.push("height stage: the input has no height map (flat geometry)".to_string());
    }
    if material.anisotropy.is_some() || material.anisotropy_angle.is_some() {
        skipped.push("anisotropy maps: upsampled bilinearly, not learned".to_string());
    }
    let lights = config.lights.build();
    let ctx = Context {
        config,
        model,
        upsampler,
        lights,
        border: Border::for_tiling(tileable),
        options,
        progress,
    };

    let scales = config.levels();
    let mut levels = Vec::new();
    // The input itself for level 1 (no copy: at 4K² it is 600 MB), then each level's output.
    let mut current = Cow::Borrowed(material);
    let mut single_filter: Option<TrainedFilter> = None;
    for (level, &scale) in scales.iter().enumerate() {
        let last = level + 1 == scales.len();
        // Levels before the last are the next one's input: assembled whole.
        let mut assembler = (!last).then(|| Assembler::new(current.height_px() * scale));
        let mut emit = |first: usize, band: &Material| match assembler.as_mut() {
            Some(a) => {
                a.add(first, band);
                Ok(())
            }
            None => sink(first, band),
        };
        let report = run_level(
            &current,
            scale,
            level,
            &ctx,
            &mut single_filter,
            &mut timings,
            &mut skipped,
            &mut emit,
        )?;
        levels.push(report);
        if let Some(a) = assembler {
            current = Cow::Owned(a.finish().expect("a level makes at least one band"));
        }
    }

    let final_loss = levels
        .iter()
        .rev()
        .find_map(|l| l.training.epoch_losses.last().copied());
    let [w, h] = output_size(material, config);
    Ok(RunReport {
        matup_version: env!("CARGO_PKG_VERSION"),
        input_folder: material.origin.as_ref().map(|o| o.folder.clone()),
        input_size: [material.width(), material.height_px()],
        output_size: [w, h],
        config: config.clone(),
        upsampler_used,
        tileable,
        seam_ratio: seam,
        selection,
        levels,
        timings,
        total_seconds: start.elapsed().as_secs_f64(),
        final_loss,
        skipped,
        memory_limit_mib: options.memory_limit.map(|b| b as f64 / (1024.0 * 1024.0)),
        peak_memory_mib: peak_memory_mib(),
        threads: rayon::current_num_threads(),
        settings_fingerprint: None,
    })
}

/// The settings to run: `config` itself, or with `select = "auto"` the best of its candidates
/// validated one scale down (not for the oracle, whose targets are the truth's).
fn choose_settings(
    material: &Material,
    config: &Config,
    options: &RunOptions,
    tileable: bool,
    progress: &dyn Progress,
) -> Result<(Config, Option<SelectionReport>)> {
    if config.select == Selection::Off || options.oracle.is_some() {
        return Ok((config.clone(), None));
    }
    let scale = config.levels()[0];
    if let Some(why) = select::too_small(material, scale) {
        progress.note(&format!(
            "select: settings as configured; no validation one scale down ({why})"
        ));
        return Ok((config.clone(), None));
    }
    let candidates = select::candidates(config);
    let run = |m: &Material, c: &Config, p: &dyn Progress| {
        upscale(m, c, &RunOptions::default(), p).map(|(result, _)| result)
    };
    let (best, report) = select::select(material, &candidates, scale, tileable, &run, progress)?;
    progress.note(&format!(
        "select: {} (validated at {}×{})",
        report.chosen, report.validation_size[0], report.validation_size[1]
    ));
    Ok((candidates[best].config.clone(), Some(report)))
}

/// The configured upsampler, or for `auto` the first that loads and supports every level's
/// scale: [`MATERIAL_NETWORK`] where the configuration only upsamples maps, then
/// [`AUTO_UPSAMPLERS`].
pub fn choose_upsampler(config: &Config) -> Result<(String, Box<dyn RgbUpsampler>)> {
    let fits = |spec: &str| -> Result<Box<dyn RgbUpsampler>> {
        let spec: PluginSpec = spec.parse()?;
        let up = upsampler(&spec)?;
        for &s in &config.levels() {
            check_scale(&spec.name, up.as_ref(), s)?;
        }
        Ok(up)
    };
    if config.upsampler != "auto" {
        return Ok((config.upsampler.clone(), fits(&config.upsampler)?));
    }
    let material = config.upsamples_maps_only().then_some(MATERIAL_NETWORK);
    let mut last = None;
    for spec in material.into_iter().chain(AUTO_UPSAMPLERS) {
        match fits(spec) {
            Ok(up) => return Ok((spec.to_string(), up)),
            Err(e) => last = Some(e),
        }
    }
    Err(last.expect("AUTO_UPSAMPLERS is not empty"))
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

/// A trained filter (none where nothing was learned) and the features it holds constant.
struct TrainedFilter {
    filter: Option<Filter>,
    fixed: [Option<f32>; FEATURES],
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

/// One ×`scale` level: unless there is nothing to learn (or `chain = "single"` reuses level
/// 1's filter), the residual base, LR renders, targets and training; then the output, band by
/// band within the memory limit: residual base, inference, height. Hands each band's kept rows
/// to `emit` and keeps the filter it trained in `single_filter`.
#[allow(clippy::too_many_arguments)]
fn run_level(
    lr: &Material,
    scale: usize,
    level: usize,
    ctx: &Context,
    single_filter: &mut Option<TrainedFilter>,
    timings: &mut Vec<(String, f64)>,
    skipped: &mut Vec<String>,
    emit: &mut dyn FnMut(usize, &Material) -> Result<()>,
) -> Result<LevelReport> {
    let config = ctx.config;
    let tag = |stage: &str| format!("level {}: {stage}", level + 1);
    let reuse = config.chain == Chain::Single && level > 0 && single_filter.is_some();
    let mut report = LevelReport {
        scale,
        input_size: [lr.width(), lr.height_px()],
        output_size: [lr.width() * scale, lr.height_px() * scale],
        lights_used: 0,
        constant_features: Vec::new(),
        training: TrainStats::default(),
        bands: 1,
    };
    let (trained, trained_base) = if reuse {
        (None, None)
    } else {
        let (trained, base) = learn_level(lr, scale, level, ctx, &mut report, timings, skipped)?;
        (Some(trained), base)
    };
    let filter = match &trained {
        Some(t) => t,
        None => single_filter.as_ref().expect("level 1 trained a filter"),
    };

    let context = residual::context(&config.filter, ctx.upsampler.as_ref())
        + band_margin(scale).div_ceil(scale)
        + if filter.filter.is_some() {
            config.filter.window.div_ceil(2 * scale) + 2
        } else {
            0
        };
    let tile = match config.filter.residual_base {
        ResidualBase::Upsampler => ctx.upsampler.tile(),
        ResidualBase::Kernel(_) => None,
    };
    let plan = plan_bands(
        lr.width(),
        lr.height_px(),
        scale,
        context,
        tile,
        ctx.border,
        ctx.options.memory_limit,
        BYTES_PER_BAND_TEXEL
            + if config.filter.residual_base == ResidualBase::Upsampler
                && config.filter.self_ensemble > 1
            {
                ENSEMBLE_BYTES_PER_BAND_TEXEL
            } else {
                0
            },
    )?;
    report.bands = plan.count();
    let whole = plan.is_whole();
    let tileable = ctx.border == Border::Wrap;
    let detail_scale = (lr.height.as_ref()).map(|h| detail_scale(h, &lr.normal, tileable));
    // In bands the stages repeat: one bar counts the bands, the stages report nothing.
    let inner: &dyn Progress = if whole { ctx.progress } else { &Silent };
    if !whole {
        ctx.progress.note(&format!(
            "level {}: {} bands of up to {} rows (memory limit {} MiB)",
            level + 1,
            plan.count(),
            plan.rows() * scale,
            ctx.options.memory_limit.unwrap_or(0) >> 20
        ));
        ctx.progress.stage(&tag("bands"), plan.count() as u64);
    }
    let mut trained_base = trained_base;
    for band in plan.bands() {
        let read = (!whole).then(|| band.read_material(lr));
        let lr_band = read.as_ref().unwrap_or(lr);
        let base = match trained_base.take() {
            Some(base) if whole => base,
            _ => {
                inner.stage(&tag("residual base"), 1);
                let base = timed(timings, tag("residual base"), || {
                    residual_base(
                        lr_band,
                        &config.filter,
                        ctx.upsampler.as_ref(),
                        scale,
                        ctx.border,
                    )
                })?;
                inner.advance(1, None);
                Arc::new(base)
            }
        };
        let mut hr = timed(timings, tag("infer"), || {
            infer_material(
                lr_band,
                filter.filter.as_ref(),
                filter.fixed,
                &base,
                scale,
                ctx.border,
                inner,
            )
        })?;
        drop(base);
        if let (Some(lr_height), Some(k)) = (&lr_band.height, detail_scale) {
            inner.stage(&tag("height"), 1);
            hr.height = Some(timed(timings, tag("height"), || {
                let band = (!whole).then_some(report.output_size);
                Ok(rebuild_height(
                    lr_height, &hr.normal, k, scale, tileable, band,
                ))
            })?);
            inner.advance(1, None);
        }
        if !whole {
            band.keep(&mut hr, scale);
        }
        emit(band.first * scale, &hr)?;
        if !whole {
            ctx.progress.advance(1, None);
        }
    }
    if let Some(t) = trained {
        *single_filter = Some(t);
    }
    Ok(report)
}

/// A level's learning: the features it holds constant, and unless every feature is constant
/// or training is off, the residual base (returned for reuse), LR renders, targets and the
/// trained filter. Fills in `report`'s training fields.
fn learn_level(
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
    if fixed.iter().all(Option::is_some) {
        skipped.push(format!(
            "level {}: training: every feature is constant",
            level + 1
        ));
        return Ok((
            TrainedFilter {
                filter: None,
                fixed,
            },
            None,
        ));
    }
    if config.train.epochs == 0 {
        skipped.push(format!(
            "level {}: training: 0 epochs, the residual base is the result",
            level + 1
        ));
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
        residual_base(
            lr,
            &config.filter,
            ctx.upsampler.as_ref(),
            scale,
            ctx.border,
        )
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
            ctx.upsampler.as_ref(),
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
        if lr.width() % scale == 0 && lr.height_px() % scale == 0 {
            let lower = lr.box_downsample(scale);
            let lower_base = residual_base(
                &lower,
                &config.filter,
                ctx.upsampler.as_ref(),
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
            config.seed.wrapping_add(level as u64),
            checkpoint.as_ref(),
            ctx.progress,
        )
    })?;
    Ok((filter, lights.len(), stats))
}

/// Runs the trained filter (none: no residual) over every output texel of `lr` upsampled by
/// `scale`, adding its answers to `residual_base` (the output-size features).
fn infer_material(
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
    for start in (0..n).step_by(16384) {
        let chunk: &[usize] = &(start..n.min(start + 16384)).collect::<Vec<_>>();
        let raw = match (filter, &folded) {
            (Some(filter), Some(folded)) => {
                let (windows, phases) = filter.lr_windows(&lr_features, border, chunk);
                filter.infer(folded, &windows, &phases)?
            }
            _ => vec![0.0; chunk.len() * FEATURES],
        };
        let decoded: Vec<_> = chunk
            .par_iter()
            .zip(raw.par_chunks(FEATURES))
            .map(|(&t, r)| {
                let base: [f32; FEATURES] = residual_base.texel(t);
                decode(r, &base, &fixed).params
            })
            .collect();
        for (&t, p) in chunk.iter().zip(&decoded) {
            for c in 0..3 {
                hr.base_color.plane_mut(c)[t] = p.base_color[c];
                hr.normal.plane_mut(c)[t] = p.normal[c];
            }
            hr.metallic.data_mut()[t] = p.metallic;
            hr.roughness.data_mut()[t] = p.alpha.sqrt();
        }
        progress.advance(chunk.len() as u64, None);
    }
    hr.anisotropy = lr
        .anisotropy
        .as_ref()
        .map(|m| upsample(m, scale, Kernel::Bilinear, border));
    hr.anisotropy_angle = lr
        .anisotropy_angle
        .as_ref()
        .map(|m| upsample(m, scale, Kernel::Bilinear, border));
    hr.restore_invariants();
    Ok(hr)
}

/// `input` upsampled bilinearly to `output`'s size: what the preview and the viewer compare
/// matup's result with.
pub fn bilinear_baseline(input: &Material, output: &Material, tileable: bool) -> Material {
    input.upsample(
        scale_between(input, output.width()),
        Kernel::Bilinear,
        Border::for_tiling(tileable),
    )
}

/// How many times wider an output `output_width` wide is than `input` (at least 1).
fn scale_between(input: &Material, output_width: usize) -> usize {
    (output_width / input.width().max(1)).max(1)
}

/// The side of the square the preview shows (the whole of a smaller output).
const PREVIEW_SIDE: usize = 512;

/// The side of the preview's square for an output of `size`.
fn preview_side(size: [usize; 2]) -> usize {
    PREVIEW_SIDE.min(size[0]).min(size[1])
}

/// The top-left texel of the central `side` × `side` square of an output of `size`.
fn centre_origin(size: [usize; 2], side: usize) -> (usize, usize) {
    ((size[0] - side) / 2, (size[1] - side) / 2)
}

/// The central square of an output that the preview shows, collected from the output's
/// bands as they pass (a streamed output is never whole).
pub struct PreviewWindow {
    side: usize,
    origin: (usize, usize),
    rows: Assembler,
}

impl PreviewWindow {
    /// For an output of `size` ([width, height]).
    pub fn new(size: [usize; 2]) -> PreviewWindow {
        let side = preview_side(size);
        PreviewWindow {
            side,
            origin: centre_origin(size, side),
            rows: Assembler::new(side),
        }
    }

    /// Keeps what of `band`, the output's rows from `first` on, lies in the square.
    pub fn add(&mut self, first: usize, band: &Material) {
        let (x0, y0) = self.origin;
        let top = first.max(y0);
        let bottom = (first + band.height_px()).min(y0 + self.side);
        if top < bottom {
            let piece = band.map_maps(|m| m.crop(x0, top - first, self.side, bottom - top));
            self.rows.add(top - y0, &piece);
        }
    }

    /// The square (`None` before any band).
    pub fn finish(self) -> Option<Material> {
        self.rows.finish()
    }
}

/// The central `side` × `side` texels of `m`.
fn centre(m: &Material, side: usize) -> Material {
    if side == m.width() && side == m.height_px() {
        return m.clone();
    }
    let (x0, y0) = centre_origin([m.width(), m.height_px()], side);
    // The maps as they are, as [`PreviewWindow`] keeps them from bands.
    m.map_maps(|map| map.crop(x0, y0, side, side))
}

/// `centre` of `input` upsampled bilinearly to `output_size`, from a window of the input
/// with two texels of context (bilinear taps reach one) instead of the whole input: a 2K²
/// input's preview would otherwise upsample all of it to 8K² (2 GB) for 512² texels.
/// Windows that reach the input's edges take the whole, whose borders wrap or mirror.
fn bilinear_centre(
    input: &Material,
    output_size: [usize; 2],
    side: usize,
    tileable: bool,
) -> Material {
    let scale = scale_between(input, output_size[0]);
    let border = Border::for_tiling(tileable);
    let (x0, y0) = centre_origin(output_size, side);
    let window = |start: usize, len: usize| {
        let first = (start / scale).saturating_sub(2);
        let end = (start + side).div_ceil(scale) + 2;
        (first > 0 && end < len).then_some((first, end - first))
    };
    match (window(x0, input.width()), window(y0, input.height_px())) {
        (Some((wx, ww)), Some((wy, wh))) => {
            // The maps as they are: `Material::crop` would renormalise the input's normals,
            // which the whole upsample reads unrenormalised.
            let window = input.map_maps(|m| m.crop(wx, wy, ww, wh));
            let up = window.upsample(scale, Kernel::Bilinear, border);
            up.map_maps(|m| m.crop(x0 - wx * scale, y0 - wy * scale, side, side))
        }
        _ => centre(&input.upsample(scale, Kernel::Bilinear, border), side),
    }
}

/// `preview.png`: the bilinearly upsampled input (left) and the result (right), rendered
/// under two training lights (rows), labelled. Large outputs show their central 512² texels.
pub fn preview(
    input: &Material,
    output: &Material,
    config: &Config,
    tileable: bool,
) -> Result<Map> {
    let size = [output.width(), output.height_px()];
    preview_of_centre(
        input,
        &centre(output, preview_side(size)),
        size,
        config,
        tileable,
    )
}

/// [`preview`] from the output's central square alone (what [`PreviewWindow`] kept of an
/// output of `output_size`).
pub fn preview_of_centre(
    input: &Material,
    result: &Material,
    output_size: [usize; 2],
    config: &Config,
    tileable: bool,
) -> Result<Map> {
    let border = Border::for_tiling(tileable);
    let side = preview_side(output_size);
    let baseline = bilinear_centre(input, output_size, side, tileable);
    let model = shading_model(&config.shading.parse::<PluginSpec>()?)?;
    let lights = config.lights.build();
    // A high light and a low one: shading detail shows at grazing angles.
    let by_height = |a: &&Light, b: &&Light| a.position[2].total_cmp(&b.position[2]);
    let high = *lights.iter().max_by(by_height).unwrap();
    let low = *lights
        .iter()
        .filter(|l| l.position[2] > 0.3 * config.lights.distance)
        .min_by(by_height)
        .unwrap_or(&high);
    let options = RenderOptions {
        supersample: false,
        border,
    };
    let mut tiles = Vec::new();
    let mut captions = Vec::new();
    for light in [high, low] {
        for m in [&baseline, result] {
            tiles.extend(render(m, model.as_ref(), &[light], options));
        }
        let [x, y, z] = light.position;
        captions.push(format!(
            "light at {:.0}° elevation, {:.0}° azimuth",
            z.atan2(x.hypot(y)).to_degrees(),
            y.atan2(x).to_degrees().rem_euclid(360.0)
        ));
    }
    let scale = scale_between(input, output_size[0]);
    let columns = [format!("bilinear ×{scale}"), "matup".to_string()];
    Ok(labelled_sheet(&tiles, 2, 4, &columns, &captions))
}

#[cfg(test)]
mod tests {
    use super::*;
    use matup_core::io::{load_material, LoadOptions};
    use matup_core::material::MapKind;

    #[test]
    fn the_preview_window_keeps_the_centre_of_the_bands() {
        let output = Material::uniform(1, [0.0; 3], 0.5, 0.0)
            .map_maps(|_| Map::from_fn(1100, 900, 1, |_, y, x| (y * 1100 + x) as f32));
        let mut window = PreviewWindow::new([1100, 900]);
        for first in (0..900).step_by(130) {
            let rows = 130.min(900 - first);
            window.add(first, &output.map_maps(|m| m.rows(first, rows)));
        }
        let kept = window.finish().unwrap();
        assert!(kept == centre(&output, 512));
        assert_eq!(kept.roughness.get(0, 0, 0), (194 * 1100 + 294) as f32);
    }

    #[test]
    fn the_preview_upsamples_a_window_equal_to_the_whole() {
        let sample =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../samples/victorian_wood");
        let input = load_material(Some(&sample), &LoadOptions::default()).unwrap();
        let output = input.upsample(4, Kernel::Bilinear, Border::Wrap); // its size is what counts
        for tileable in [true, false] {
            let whole = centre(&bilinear_baseline(&input, &output, tileable), 64);
            let size = [output.width(), output.height_px()];
            let window = bilinear_centre(&input, size, 64, tileable);
            for kind in MapKind::ALL {
                // Not assert_eq: a failure would print every value.
                let same = whole.map(kind).map(Map::data) == window.map(kind).map(Map::data);
                assert!(same, "{kind:?}, tileable {tileable}");
            }
        }
    }
}
