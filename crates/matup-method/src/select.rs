//! Self-validation one scale down (`select = "auto"`): each candidate setting upsamples the LR
//! material box-downsampled by the scale factor, where the LR material itself is the truth,
//! at 1/scale² of the cost; the candidate whose result renders closest to it runs at full
//! scale. Per-map super-resolution is one candidate, so the choice never does worse than it
//! at the validation scale.

use std::time::Instant;

use serde::Serialize;

use crate::config::{Config, ResidualBase, Selection, TargetKind};
use matup_core::lights::LightSetSpec;
use matup_core::material::Material;
use matup_core::progress::Progress;
use matup_core::resample::Kernel;
use matup_core::shading::ShadingModel;
use matup_core::Result;
use matup_eval::metrics::evaluate;

/// Held-out lights the candidates are scored under (as `matup eval`'s default).
const VALIDATION_LIGHTS: usize = 16;

/// The smallest side of the validation material: below it a few texels decide the choice.
pub const MIN_VALIDATION_SIDE: usize = 16;

/// A setting to validate.
#[derive(Clone, Debug)]
pub struct Candidate {
    pub name: String,
    pub config: Config,
}

/// How one candidate did at the validation scale.
#[derive(Clone, Debug, Serialize)]
pub struct CandidateScore {
    pub name: String,
    pub render_psnr: f64,
    pub render_flip: f64,
    /// What the choice maximises: [`score`].
    pub score: f64,
    pub seconds: f64,
}

/// What self-validation did, for `run.json` and the summary.
#[derive(Clone, Debug, Serialize)]
pub struct SelectionReport {
    /// The validation material's size (the input box-downsampled by the scale factor).
    pub validation_size: [usize; 2],
    pub candidates: Vec<CandidateScore>,
    pub chosen: String,
    pub seconds: f64,
}

/// The quantity self-validation maximises: render PSNR in dB minus FLIP in dB
/// (`10·log10 FLIP`), so that halving the FLIP error counts as much as 3 dB of PSNR.
pub fn score(render_psnr: f64, render_flip: f64) -> f64 {
    render_psnr - 10.0 * render_flip.max(1e-6).log10()
}

/// The candidates for `config`. `auto`: per-map super-resolution by the run's upsampler and
/// the LR maps interpolated by Lanczos-3 (each back-projected onto the LR maps, nothing
/// learned), the filter trained on the upsampled renders on top of the per-map base, and the
/// configuration as given. Both: the configuration as given with each of `select_upsamplers`
/// in place of its upsampler (`upsampler`: these and the configuration as given only).
pub fn candidates(config: &Config) -> Vec<Candidate> {
    let given = Config {
        select: Selection::Off,
        select_upsamplers: Vec::new(),
        ..config.clone()
    };
    let per_map = |base: ResidualBase| {
        let mut c = given.clone();
        c.filter.residual_base = base;
        c.filter.back_project = true;
        c.train.epochs = 0;
        c
    };
    let trained = {
        let mut c = per_map(ResidualBase::Upsampler);
        // The given epochs, or the paper's where the given settings train nothing.
        c.train.epochs = match given.train.epochs {
            0 => Config::paper().train.epochs,
            epochs => epochs,
        };
        c.train.targets = TargetKind::Direct;
        c
    };
    let mut settings: Vec<(String, Config)> = match config.select {
        Selection::Upsampler => vec![(format!("upsampler {}", given.upsampler), given.clone())],
        _ => vec![
            ("as configured".into(), given.clone()),
            ("per-map upsampler".into(), per_map(ResidualBase::Upsampler)),
            (
                "lanczos3-interpolated maps".into(),
                per_map(ResidualBase::Kernel(Kernel::Lanczos3)),
            ),
            ("filter on upsampled renders".into(), trained),
        ],
    };
    for name in &config.select_upsamplers {
        let c = Config {
            upsampler: name.clone(),
            ..given.clone()
        };
        settings.push((format!("upsampler {name}"), c));
    }
    // Each setting once, under the first name it came with.
    let mut out: Vec<Candidate> = Vec::new();
    for (name, config) in settings {
        if !out.iter().any(|o| o.config == config) {
            out.push(Candidate { name, config });
        }
    }
    out
}

/// Why a material cannot be validated one scale down at `scale`, if it cannot.
pub fn too_small(material: &Material, scale: usize) -> Option<String> {
    let (w, h) = (material.width(), material.height_px());
    if w % scale != 0 || h % scale != 0 {
        Some(format!("{w}×{h} is not divisible by {scale}"))
    } else if w / scale < MIN_VALIDATION_SIDE || h / scale < MIN_VALIDATION_SIDE {
        Some(format!(
            "{w}×{h} ÷ {scale} is smaller than {MIN_VALIDATION_SIDE}×{MIN_VALIDATION_SIDE}"
        ))
    } else {
        None
    }
}

/// How a candidate is run: the pipeline without selection (passed in by the pipeline, which
/// stands above this module).
pub type Upscale<'a> = &'a dyn Fn(&Material, &Config, &dyn Progress) -> Result<Material>;

/// Validates `candidates` on `material` one level (`scale`) down with `upscale`, tiling as
/// `tileable` says and rendering by `model`, and returns the index of the best with the report.
pub fn select(
    material: &Material,
    candidates: &[Candidate],
    scale: usize,
    tileable: bool,
    model: &dyn ShadingModel,
    upscale: Upscale,
    progress: &dyn Progress,
) -> Result<(usize, SelectionReport)> {
    let start = Instant::now();
    let lower = material.box_downsample(scale);
    let lights = LightSetSpec::held_out(VALIDATION_LIGHTS);
    progress.stage("select: validate one scale down", candidates.len() as u64);
    let mut scores = Vec::with_capacity(candidates.len());
    for candidate in candidates {
        let began = Instant::now();
        let mut config = candidate.config.clone();
        config.scale = scale;
        config.tileable = Some(tileable);
        config.select = Selection::Off;
        let quiet = Cancellable(progress);
        let result = upscale(&lower, &config, &quiet)?;
        let e = evaluate(material, &result, scale, model, &lights)?;
        scores.push(CandidateScore {
            name: candidate.name.clone(),
            render_psnr: e.render_psnr,
            render_flip: e.render_flip,
            score: score(e.render_psnr, e.render_flip),
            seconds: began.elapsed().as_secs_f64(),
        });
        progress.advance(1, None);
    }
    // The first of equals wins: candidates come in order of preference.
    let best = (1..scores.len()).fold(0, |best, k| {
        if scores[k].score > scores[best].score {
            k
        } else {
            best
        }
    });
    let report = SelectionReport {
        validation_size: [lower.width(), lower.height_px()],
        chosen: scores[best].name.clone(),
        candidates: scores,
        seconds: start.elapsed().as_secs_f64(),
    };
    Ok((best, report))
}

/// Passes only cancellation through: a candidate's own stages would clutter the bars.
struct Cancellable<'a>(&'a dyn Progress);

impl Progress for Cancellable<'_> {
    fn cancelled(&self) -> bool {
        self.0.cancelled()
    }
}

/// With `select` on, the index of the best of `candidates` (the plan's) validated one level
/// (`scale`) down, each upsampled by `upscale` (the pipeline) and rendered by `model`, with the
/// report; none where the material is too small to validate.
pub fn choose_candidate(
    material: &Material,
    candidates: &[Candidate],
    scale: usize,
    tileable: bool,
    model: &dyn ShadingModel,
    upscale: Upscale,
    progress: &dyn Progress,
) -> Result<Option<(usize, SelectionReport)>> {
    if let Some(why) = too_small(material, scale) {
        progress.note(&format!(
            "select: settings as configured; no validation one scale down ({why})"
        ));
        return Ok(None);
    }
    let (best, report) = select(
        material, candidates, scale, tileable, model, upscale, progress,
    )?;
    progress.note(&format!(
        "select: {} (validated at {}×{})",
        report.chosen, report.validation_size[0], report.validation_size[1]
    ));
    Ok(Some((best, report)))
}
