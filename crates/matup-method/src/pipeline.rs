//! The method end to end, carrying out a run's [`Plan`] as one straight line of stages: the
//! selection among the plan's candidates, then per ×s level the per-material fit where one is
//! asked for, and band by band the residual base, the filter's inference and the height.
//! Progress goes through a callback. It does not know which plugins exist.

use std::borrow::Cow;
use std::sync::Arc;
use std::time::Instant;

use crate::bands::{
    plan_bands, Assembler, BYTES_PER_BAND_TEXEL, DEVICE_BYTES_PER_BAND_TEXEL,
    ENSEMBLE_BYTES_PER_BAND_TEXEL, ROUTE_BYTES_PER_NATIVE_TEXEL,
};
use crate::carried::{describe_carried, upscale_carried, CarriedPlan, CarriedUpsampling};
use crate::config::{Chain, Config, FilterConfig, ResidualBase, Selection};
use crate::context::{Context, RunOptions, StopsOnRequest};
use crate::fit::{
    decoded_maps_on_device, infer_material, learn_level, upsample_anisotropy, TrainedFilter,
};
use crate::height::{band_margin, detail_scale, rebuild_height};
use crate::normal_blend::{self, blend_clean_normals};
use crate::per_map::LEFT_OUT;
use crate::plan::{Plan, Setup, Tiling, TilingGrounds};
use crate::report::{peak_memory_mib, timed, LevelReport, RunReport};
use crate::residual::{self, project_onto_input, upsampled_base};
use crate::select::{choose_candidate, Candidate, SelectionReport};
use crate::train::TrainStats;
use matup_core::candle_core::Tensor;
use matup_core::device_maps;
use matup_core::map::Map;
use matup_core::material::{MapKind, Material};
use matup_core::output_band::OutputBand;
use matup_core::progress::{Progress, Silent};
use matup_core::resample::Border;
use matup_core::upsample::{route, RgbUpsampler};
use matup_core::{Error, Result};

pub use crate::features::{constant_features, features};
pub use matup_core::tileable::{
    decide_tileable, detect_tileable, wrap_seam_ratio, SEAM_OVER_LARGEST_STEP,
};

/// Upsamples `material` as `config` says: plans the run ([`Plan::new`]) and carries it out
/// whole. Returns the HR material (height included when the input has one) and what the run
/// did. [`upscale_streamed`] carries out a plan in bands instead.
pub fn upscale(
    material: &Material,
    config: &Config,
    options: &RunOptions,
    progress: &dyn Progress,
) -> Result<(Material, RunReport)> {
    let plan = Plan::new(material, config)?;
    let height = plan.output_size([material.width(), material.height_px()])[1];
    let (mut result, report) = assembled(height, |sink| {
        upscale_streamed(material, &plan, options, progress, sink)
    })?;
    result.origin = material.origin.clone();
    Ok((result, report))
}

/// A band sink: `sink(first_row, band)`.
type Sink<'a> = dyn FnMut(usize, &OutputBand) -> Result<()> + 'a;

/// What `stream` hands its sink in bands, assembled into one material `height` rows tall,
/// with what `stream` returns.
fn assembled<R>(
    height: usize,
    stream: impl FnOnce(&mut Sink) -> Result<R>,
) -> Result<(Material, R)> {
    let mut assembler = Assembler::new(height);
    let returned = stream(&mut |first, band| {
        assembler.add(first, &*band.to_material()?);
        Ok(())
    })?;
    let whole = assembler.finish().expect("a run makes at least one band");
    Ok((whole, returned))
}

/// Carries out `plan` on `material`, handing the output to `sink` in bands of whole rows, top
/// to bottom, as they are finished: `sink(first_row, band)`, the band holding every map of
/// the output's rows from `first_row` on. Within [`RunOptions::memory_limit`] the last level
/// works a band at a time (levels before it are held whole: they are the next level's input).
/// Where the run works on a GPU, the band's maps are still there: the sink brings back what
/// it needs.
pub fn upscale_streamed(
    material: &Material,
    plan: &Plan,
    options: &RunOptions,
    progress: &dyn Progress,
    sink: &mut dyn FnMut(usize, &OutputBand) -> Result<()>,
) -> Result<RunReport> {
    let input = [material.width(), material.height_px()];
    let Some(size) = plan.reach.shrink_to else {
        if let Some(size) = plan.asked_size {
            progress.note(&format!("output {size}: {}", plan.reach.describe()));
        }
        return run_levels(material, plan, options, progress, sink);
    };
    // No whole scale reaches the size asked for: the output is made whole at the scale past
    // it, then shrunk by area, and handed over as one band.
    progress.note(&format!(
        "output {}×{}: {}",
        size[0],
        size[1],
        plan.reach.describe()
    ));
    let (whole, report) = assembled(input[1] * plan.reach.scale, |sink| {
        run_levels(material, plan, options, progress, sink)
    })?;
    sink(0, &whole.area_resize(size[0], size[1]).into())?;
    Ok(report)
}

/// The run's levels, each one's output the next one's input, the last one's handed to `sink`:
/// the notes on the input, the selection among the plan's candidates, then level by level.
fn run_levels(
    material: &Material,
    plan: &Plan,
    options: &RunOptions,
    progress: &dyn Progress,
    sink: &mut dyn FnMut(usize, &OutputBand) -> Result<()>,
) -> Result<RunReport> {
    let start = Instant::now();
    let mut timings = Vec::new();
    let mut skipped = Vec::new();
    progress.note(&tiling_note(&plan.tiling));
    progress.note(&plan.input.describe());
    let sources: Vec<String> = (material.origin.iter())
        .flat_map(|o| o.sources().into_iter().chain(o.notes.iter().cloned()))
        .collect();
    let stand_ins = stand_in_notes(material, &plan.setup.settings);
    for note in sources.iter().chain(&stand_ins) {
        progress.note(note);
    }
    let (setup, selection) = select_candidate(material, plan, options, progress)?;
    let upsampler_used = match options.oracle {
        Some(_) => "oracle (exact renders of the true material)".to_string(),
        None => setup.upsamplers_used(),
    };
    let network_devices = setup.placements();
    for placement in &network_devices {
        progress.note(&format!("network: {placement}"));
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
    let carried = carried_by_level(material, setup, plan.tiling.border(), &upsampler_used);
    let stopping = StopsOnRequest {
        inner: setup.upsampler.as_ref(),
        progress,
    };
    let stopping_apart: Vec<(MapKind, StopsOnRequest)> = (setup.apart.iter())
        .map(|apart| {
            let inner = apart.upsampler.as_ref();
            (apart.kind, StopsOnRequest { inner, progress })
        })
        .collect();
    let stopping_clean_normals = (setup.clean_normals.as_ref()).map(|c| StopsOnRequest {
        inner: c.upsampler.as_ref(),
        progress,
    });
    let ctx = Context {
        config: &setup.settings,
        model: plan.shading.clone(),
        upsampler: &stopping,
        apart: (stopping_apart.iter())
            .map(|(kind, u)| (*kind, u as &dyn RgbUpsampler))
            .collect(),
        clean_normals: (stopping_clean_normals.as_ref()).map(|u| u as &dyn RgbUpsampler),
        upsampler_name: &upsampler_used,
        lights: plan.lights.clone(),
        border: plan.tiling.border(),
        options,
        progress,
    };

    let mut levels = Vec::new();
    // The input itself for level 1 (no copy: at 4K² it is 600 MB), then each level's output.
    let mut current = Cow::Borrowed(material);
    let mut single_filter: Option<TrainedFilter> = None;
    for (index, level) in setup.levels.iter().enumerate() {
        let last = index + 1 == setup.levels.len();
        // Levels before the last are the next one's input: assembled whole.
        let mut assembler = (!last).then(|| Assembler::new(current.height_px() * level.scale));
        let mut emit = |first: usize, band: &OutputBand| match assembler.as_mut() {
            Some(a) => {
                a.add(first, &*band.to_material()?);
                Ok(())
            }
            None => sink(first, band),
        };
        let ctx = Context {
            config: &level.settings,
            ..ctx.clone()
        };
        let report = run_level(
            &current,
            level.scale,
            index,
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
    let input = [material.width(), material.height_px()];
    drop(ctx); // it borrows the upsampler's name, which the report takes
    Ok(RunReport {
        matup_version: env!("CARGO_PKG_VERSION"),
        input_folder: material.origin.as_ref().map(|o| o.folder.clone()),
        input_size: input,
        output_size: plan.output_size(input),
        config: Config {
            size: plan.asked_size,
            ..setup.settings.clone()
        },
        upsampler_used,
        network_devices,
        route: plan.reach.describe(),
        tileable: plan.tiling.tileable,
        tiling_evidence: match plan.tiling.grounds {
            TilingGrounds::Edges(e) => Some(e),
            _ => None,
        },
        tiling_source: match &plan.tiling.grounds {
            TilingGrounds::Source(why) => Some(why.clone()),
            _ => None,
        },
        input_route: plan.input.describe(),
        selection,
        levels,
        timings,
        total_seconds: start.elapsed().as_secs_f64(),
        final_loss,
        skipped,
        carried,
        sources,
        stand_ins,
        other_sizes: Vec::new(),
        memory_limit_mib: options.memory_limit.map(|b| b as f64 / (1024.0 * 1024.0)),
        peak_memory_mib: peak_memory_mib(),
        threads: rayon::current_num_threads(),
        settings_fingerprint: None,
    })
}

/// The tiling decided, and how to decide otherwise, in words.
fn tiling_note(tiling: &Tiling) -> String {
    let tileable = tiling.tileable;
    match &tiling.grounds {
        TilingGrounds::Source(why) => format!(
            "tileable: {} ({why}; --{}tileable decides otherwise)",
            if tileable {
                "yes, wrapped"
            } else {
                "no, mirrored"
            },
            if tileable { "no-" } else { "" }
        ),
        // Decided by what each wrong call costs: mirroring a tileable input seams its output,
        // wrapping a crop costs little (docs/experiments/2026-11-26-seamless-by-default.md).
        TilingGrounds::Edges(e) if tileable => format!(
            "tileable: yes, wrapped (its wrap-around step is {e:.2}× its largest interior step; \
             only past {SEAM_OVER_LARGEST_STEP} on both axes is it taken for a crop; \
             --no-tileable mirrors)"
        ),
        TilingGrounds::Edges(e) => format!(
            "tileable: no, mirrored (its wrap-around step is {e:.2}× its largest interior step \
             on both axes: a crop; --tileable wraps)"
        ),
        TilingGrounds::Given => format!(
            "tileable: {} (as given)",
            if tileable { "yes" } else { "no" }
        ),
    }
}

/// The setup the run carries out: the plan's own, or with `select` on the best of its
/// candidates validated one level down (not for the oracle, whose targets are the truth's).
fn select_candidate<'a>(
    material: &Material,
    plan: &'a Plan,
    options: &RunOptions,
    progress: &dyn Progress,
) -> Result<(&'a Setup, Option<SelectionReport>)> {
    if plan.candidates.is_empty() || options.oracle.is_some() {
        return Ok((&plan.setup, None));
    }
    let candidates: Vec<Candidate> = (plan.candidates.iter())
        .map(|(name, c)| Candidate {
            name: name.clone(),
            config: c.settings.clone(),
        })
        .collect();
    let run = |m: &Material, c: &Config, p: &dyn Progress| {
        upscale(m, c, &RunOptions::default(), p).map(|(result, _)| result)
    };
    let chosen = choose_candidate(
        material,
        &candidates,
        plan.setup.levels[0].scale,
        plan.tiling.tileable,
        plan.shading.as_ref(),
        &run,
        progress,
    )?;
    Ok(match chosen {
        Some((best, report)) => (&plan.candidates[best].1, Some(report)),
        None => (&plan.setup, None),
    })
}

/// What upsamples the maps the material carries, in words: once, or level by level where the
/// levels differ (×8: the network at ×4, Lanczos-3 at ×2).
fn carried_by_level(
    material: &Material,
    setup: &Setup,
    border: Border,
    upsampler_name: &str,
) -> Vec<String> {
    let carried_plan = CarriedPlan::of(&material.carried);
    let by_level: Vec<Vec<String>> = (setup.levels.iter())
        .map(|level| {
            let how = carried_upsampling(
                &level.settings,
                setup.upsampler.as_ref(),
                level.scale,
                border,
            );
            describe_carried(material, &carried_plan, upsampler_name, how)
        })
        .collect();
    if by_level.iter().all(|d| *d == by_level[0]) {
        by_level[0].clone()
    } else {
        (by_level.iter().enumerate())
            .flat_map(|(i, lines)| lines.iter().map(move |l| format!("level {}: {l}", i + 1)))
            .collect()
    }
}

/// One ×`scale` level, `ctx` holding its settings: unless there is nothing to learn (or `chain = "single"` reuses level
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
    emit: &mut dyn FnMut(usize, &OutputBand) -> Result<()>,
) -> Result<LevelReport> {
    let config = ctx.config;
    let tag = |stage: &str| format!("level {}: {stage}", level + 1);
    let reuse = config.chain == Chain::Single && level > 0 && single_filter.is_some();
    let route = level_route(ctx, scale);
    ctx.progress.note(&format!("level {}: {route}", level + 1));
    let mut report = LevelReport {
        scale,
        route,
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

    let context = residual::context(&config.filter, &ctx.map_upsamplers())
        + normal_blend::context(&config.filter)
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
    let plan_within = |limit: Option<u64>, per_texel: u64| {
        plan_bands(
            lr.width(),
            lr.height_px(),
            scale,
            context,
            tile,
            ctx.border,
            limit,
            per_texel,
        )
    };
    let passes = if config.filter.residual_base == ResidualBase::Upsampler {
        config.filter.self_ensemble.max(1) as u64
    } else {
        1
    };
    let plan = plan_within(
        ctx.options.memory_limit,
        BYTES_PER_BAND_TEXEL
            + route_bytes_per_texel(ctx, scale)
            + if passes > 1 {
                // The sum of the passes; where they run in one call, each pass's output too
                // (the one pass made at a time is in the band's own bytes).
                let held = if ctx.upsampler.batches_images() {
                    passes
                } else {
                    1
                };
                ENSEMBLE_BYTES_PER_BAND_TEXEL * held
            } else {
                0
            },
    )?;
    // Where the residual base is made on a GPU, a band must also fit a quarter of its free
    // memory: the network's batches take up to half (`onnx`'s `tiles_per_call`).
    let on_device = residual::device_for(&config.filter, &ctx.map_upsamplers());
    let free = match &on_device {
        Some(device) => matup_core::device_maps::free_memory(device)?,
        None => None,
    };
    let plan = match free {
        Some(free) => {
            let per_texel =
                DEVICE_BYTES_PER_BAND_TEXEL + route_bytes_per_texel(ctx, scale) * passes;
            let fitting = plan_within(Some(free / 4), per_texel).map_err(|e| {
                Error::Invalid(format!(
                    "the GPU has {} MiB free, and a band may take a quarter of it: {e}",
                    free >> 20
                ))
            })?;
            if fitting.count() > plan.count() {
                fitting
            } else {
                plan
            }
        }
        None => plan,
    };
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
    // Decided from the whole level input: every band treats each carried map alike.
    let carried_plan = CarriedPlan::of(&lr.carried);
    // Ctrl-C stops the run between its stages; what was not finished is not written.
    let go_on = || match ctx.progress.cancelled() {
        true => Err(Error::Interrupted),
        false => Ok(()),
    };
    for band in plan.bands() {
        go_on()?;
        let read = (!whole).then(|| band.read_material(lr));
        let lr_band = read.as_ref().unwrap_or(lr);
        let base = match trained_base.take() {
            Some(base) if whole => Base::Host(base),
            _ => {
                inner.stage(&tag("residual base"), 1);
                // On a device its stages run there, one after another: timed as one.
                let base = match &on_device {
                    Some(device) => Base::Device(timed(timings, tag("residual base"), || {
                        residual::residual_base_on_device(
                            lr_band,
                            &config.filter,
                            &ctx.map_upsamplers(),
                            device,
                            scale,
                            ctx.border,
                        )
                    })?),
                    None => Base::Host(Arc::new(host_residual_base(
                        lr_band, scale, ctx, timings, &tag,
                    )?)),
                };
                inner.advance(1, None);
                go_on()?;
                base
            }
        };
        // Without a learned filter, a base on a device is decoded into maps there, which stay
        // there until the sink takes them; a filter runs on the host.
        let (mut hr, mut held) = match base {
            Base::Device(features) if filter.filter.is_none() => {
                let maps = timed(timings, tag("infer"), || {
                    decoded_maps_on_device(&features, filter.fixed)
                })?;
                // The band's maps on the host: none of the four held, which `OutputBand`
                // stands in for; the anisotropy, height and carried maps join them here.
                let mut rest = Material::uniform(0, [0.0; 3], 0.0, 0.0);
                upsample_anisotropy(lr_band, &mut rest, scale, ctx.border);
                (rest, maps)
            }
            base => {
                let base = match base {
                    Base::Host(base) => base,
                    Base::Device(features) => Arc::new(device_maps::download(&features)?),
                };
                let hr = timed(timings, tag("infer"), || {
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
                (hr, Vec::new())
            }
        };
        if let (Some(lr_height), Some(k)) = (&lr_band.height, detail_scale) {
            inner.stage(&tag("height"), 1);
            hr.height = Some(timed(timings, tag("height"), || {
                // The height's solve runs on the host: it reads the normals from there.
                if let Some(i) = held.iter().position(|(k, _)| *k == MapKind::Normal) {
                    hr.normal = device_maps::download(&held.remove(i).1)?;
                }
                let band = (!whole).then_some(report.output_size);
                let mut height = rebuild_height(lr_height, &hr.normal, k, scale, tileable, band);
                if config.filter.back_project {
                    // Unbounded: EXR heights may leave [0, 1].
                    let any = |_| (f32::NEG_INFINITY, f32::INFINITY);
                    residual::back_project_within(&mut height, lr_height, scale, ctx.border, any);
                }
                Ok(height)
            })?);
            inner.advance(1, None);
        }
        if !lr_band.carried.is_empty() {
            let how = carried_upsampling(config, ctx.upsampler, scale, ctx.border);
            hr.carried = timed(timings, tag("carried maps"), || {
                upscale_carried(&lr_band.carried, &carried_plan, how)
            })?;
        }
        let mut out = OutputBand::with_maps_on_device(hr, held)?;
        if !whole {
            band.keep(&mut out, scale)?;
        }
        emit(band.first * scale, &out)?;
        if !whole {
            ctx.progress.advance(1, None);
        }
    }
    if let Some(t) = trained {
        *single_filter = Some(t);
    }
    Ok(report)
}

/// A band's residual base: on the host, or on the device where it was made.
enum Base {
    Host(Arc<Map>),
    Device(Tensor),
}

/// The residual base on the host, in its two stages timed apart: the upsampler's and the
/// projection onto the input's.
fn host_residual_base(
    lr_band: &Material,
    scale: usize,
    ctx: &Context,
    timings: &mut Vec<(String, f64)>,
    tag: &dyn Fn(&str) -> String,
) -> Result<Map> {
    let config = ctx.config;
    let mut base = timed(timings, tag("residual base"), || {
        upsampled_base(
            lr_band,
            &config.filter,
            &ctx.map_upsamplers(),
            scale,
            ctx.border,
        )
    })?;
    timed(timings, tag("back-projection"), || {
        project_onto_input(&mut base, lr_band, &config.filter, scale, ctx.border);
        Ok(())
    })?;
    if config.filter.normal_blend_noise > 0.0 {
        timed(timings, tag("normal blend"), || {
            let upsamplers = ctx.map_upsamplers();
            blend_clean_normals(
                &mut base,
                lr_band,
                &config.filter,
                &upsamplers,
                scale,
                ctx.border,
            )
        })?;
    }
    Ok(base)
}

/// Heap bytes per output texel an upsampler adds to a band where it serves `scale` through
/// its larger native scale (the per-map base is the only stage that upsamples in bands).
fn route_bytes_per_texel(ctx: &Context, scale: usize) -> u64 {
    match ctx.upsampler.native_scale() {
        Some(native)
            if native > scale && ctx.config.filter.residual_base == ResidualBase::Upsampler =>
        {
            (ROUTE_BYTES_PER_NATIVE_TEXEL * (native * native) as u64)
                .div_ceil((scale * scale) as u64)
        }
        _ => 0,
    }
}

/// What makes a ×`scale` level's maps, in words: the upsampler, its route to the scale
/// (through its native one), the self-ensemble's passes and the back-projection, where they
/// make the per-map base; the kernel and the filter otherwise.
fn level_route(ctx: &Context, scale: usize) -> String {
    let filter = &ctx.config.filter;
    let upsampler = match route(ctx.upsampler.native_scale(), scale) {
        Some(route) => format!("{} at {route}", ctx.upsampler_name),
        None => ctx.upsampler_name.to_string(),
    };
    let trains = ctx.config.train.epochs > 0;
    let passes = filter.map_passes();
    match filter.residual_base {
        ResidualBase::Upsampler => format!(
            "×{scale} by {}{}{}{}",
            passes.by(MapKind::Normal, &upsampler),
            if passes.upsampled.includes(MapKind::BaseColor) {
                String::new()
            } else {
                format!(" on the normal map, {LEFT_OUT} on the others")
            },
            projection_words(filter),
            if trains { ", then the filter" } else { "" }
        ),
        ResidualBase::Kernel(kernel) => format!(
            "×{scale}: {} maps{}",
            kernel,
            if trains {
                format!(" and a filter fitted to renders upsampled by {upsampler}")
            } else {
                String::new()
            }
        ),
    }
}

/// Whether the per-map base is back-projected, in words: all of it, all but some maps (those
/// routed as lossy), or none.
fn projection_words(filter: &FilterConfig) -> String {
    let unprojected: Vec<String> = (filter.unprojected_maps.iter())
        .map(|kind| kind.to_string())
        .collect();
    match (filter.back_project, unprojected.is_empty()) {
        (false, _) => String::new(),
        (true, true) => ", back-projected".into(),
        (true, false) => format!(", back-projected but the {}", unprojected.join(", ")),
    }
}

/// How a run upsamples the maps a material carries: with its upsampler and passes,
/// back-projected when its residual base is.
fn carried_upsampling<'a>(
    config: &Config,
    upsampler: &'a dyn RgbUpsampler,
    scale: usize,
    border: Border,
) -> CarriedUpsampling<'a> {
    CarriedUpsampling {
        upsampler,
        passes: config.filter.map_passes(),
        back_project: config.filter.back_project,
        scale,
        border,
    }
}

/// A note for each map the input lacks: what stands in for it, where renders use it, and that
/// it is not written.
fn stand_in_notes(material: &Material, config: &Config) -> Vec<String> {
    let stand_ins = material.stand_ins();
    // Images alone (a model's emission texture, a folder of textures) stand in for no maps.
    if stand_ins.len()
        == MapKind::ALL
            .iter()
            .filter(|k| k.stand_in().is_some())
            .count()
    {
        return vec!["no material maps: each image is upscaled on its own".into()];
    }
    let renders = config.train.epochs > 0 || config.select != Selection::Off;
    stand_ins
        .into_iter()
        .map(|kind| {
            format!(
                "the input has no {kind} map: {} stands in for it{}; none is written",
                kind.stand_in_words(),
                if renders {
                    " in the renders this run fits to"
                } else {
                    ""
                }
            )
        })
        .collect()
}
