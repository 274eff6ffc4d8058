//! Validation: each exported network run by `matup upscale` itself on the validation
//! materials, scored against their truth, and logged.

use std::path::Path;

use candle_core::Device;
use matup_core::degrade::{degraded_input, MaterialDegradation};
use matup_core::map::Map;
use matup_core::render::render;
use matup_core::resample::Border;
use matup_core::shading::shading_model;
use matup_core::tileable::decide_tileable;
use matup_core::upsample::upsampler as rgb_upsampler;
use matup_core::{Error, LightSetSpec, Material, PluginSpec, Result};
use matup_eval::metrics::{evaluate, flip, psnr, rmse, sharpness, Evaluation};
use matup_method::{upscale, Config, RunOptions};
use rand::rngs::StdRng;
use rand::SeedableRng;

use super::checkpoint::{append, RunFiles};
use super::loss::{shipped_normals, CROP_RENDERS};
use crate::config::{LearnConfig, Target};
use crate::data::{Corpus, Pair};
use crate::net::TrainableNet;
use crate::post_process::BackProjection;

/// A validation material: the true crop and its LR version.
pub struct ValMaterial {
    pub name: String,
    pub truth: Material,
    pub lr: Material,
}

/// The validation crops of `config.val` (top-left `val_crop²` of each), and for each of
/// `config.val_degrade` a copy of them whose LR input is degraded so (named `NAME+DEGRADATION`).
pub fn validation_set(config: &LearnConfig) -> Result<Vec<ValMaterial>> {
    // Any size will do: a validation crop is at most the material.
    let corpus = Corpus::load(&config.corpus, &config.val, 0)?;
    let clean: Vec<ValMaterial> = corpus
        .names
        .into_iter()
        .zip(corpus.materials)
        .map(|(name, m)| {
            let size = config.val_crop.min(m.width()).min(m.height_px());
            let size = size - size % config.scale;
            let pair = Pair::new(m.crop(0, 0, size, size), config.scale);
            ValMaterial {
                name,
                truth: pair.truth,
                lr: pair.lr,
            }
        })
        .collect();
    let mut set = Vec::with_capacity(clean.len() * (1 + config.val_degrade.len()));
    for name in &config.val_degrade {
        let degradation: MaterialDegradation = name.parse()?;
        for (i, v) in clean.iter().enumerate() {
            // The same noise at every validation.
            let mut rng = StdRng::seed_from_u64(i as u64);
            set.push(ValMaterial {
                name: format!("{}+{name}", v.name),
                truth: v.truth.clone(),
                lr: degraded_input(&v.truth, config.scale, Some(&degradation), &mut rng)?,
            });
        }
    }
    set.splice(0..0, clean);
    Ok(set)
}

/// A validation's numbers for one material.
#[derive(Clone, Debug)]
pub struct Score {
    pub render_psnr: f64,
    pub render_flip: f64,
    /// Normal error (°), base colour, roughness and metallic RMSE, where the network makes maps.
    pub maps: Option<[f64; 4]>,
    pub render_sharpness: f64,
    pub reference_render_sharpness: f64,
}

impl From<Evaluation> for Score {
    fn from(e: Evaluation) -> Score {
        Score {
            render_psnr: e.render_psnr,
            render_flip: e.render_flip,
            maps: Some([
                e.normal_error_degrees,
                e.base_color_rmse,
                e.roughness_rmse,
                e.metallic_rmse,
            ]),
            render_sharpness: e.render_sharpness,
            reference_render_sharpness: e.reference_render_sharpness,
        }
    }
}

/// Validates the network `upsampler` as `target` says it is used, on every validation
/// material under `lights` held-out lights.
pub fn validate(
    target: Target,
    upsampler: &str,
    set: &[ValMaterial],
    lights: usize,
) -> Result<Vec<(String, Score)>> {
    match target {
        Target::Maps => validate_maps(upsampler, set, lights),
        Target::Renders => validate_renders(upsampler, set, lights),
        Target::Normals => {
            let spec = upsampler.parse::<PluginSpec>()?;
            let Some(path) = spec.argument.as_deref() else {
                return Err(Error::Invalid(format!(
                    "'{upsampler}': a network of normals is validated from its file (onnx:PATH)"
                )));
            };
            let net = TrainableNet::load(Path::new(path), &Device::Cpu)?;
            validate_normals(&net, set, lights)
        }
    }
}

/// The true validation material with `net`'s normals in place of its own, as `matup
/// upscale`'s defaults would ship them (decoded, back-projected onto the LR normals), against
/// the truth: how much of the render error the network's normal maps leave.
pub fn validate_normals(
    net: &TrainableNet,
    set: &[ValMaterial],
    lights: usize,
) -> Result<Vec<(String, Score)>> {
    let device = Device::Cpu;
    score_each(set, lights, |v| {
        let (w, h) = (v.truth.width(), v.truth.height_px());
        let scale = w / v.lr.width();
        // Borders as `matup upscale` takes them: wrapped where the LR map tiles.
        let border = Border::for_tiling(decide_tileable(&v.lr).0);
        let back_projection = BackProjection::new(v.lr.width(), scale, border, &device)?;
        let context = net.info.overlap;
        let normals = shipped_normals(net, &[&v.lr], &back_projection, context, border, &device)?;
        let planar = normals.t()?.flatten_all()?.to_vec1::<f32>()?;
        let mut candidate = v.truth.clone();
        candidate.normal = Map::from_planar(w, h, 3, planar);
        Ok(candidate)
    })
}

/// `matup upscale`'s defaults with `upsampler` run once over each map (no self-ensemble: the
/// network's own measure, as every run before the ensemble became a default scored it),
/// against the truth.
pub(super) fn validate_maps(
    upsampler: &str,
    set: &[ValMaterial],
    lights: usize,
) -> Result<Vec<(String, Score)>> {
    let config = Config {
        upsampler: upsampler.to_string(),
        ..one_pass_defaults()
    };
    score_each(set, lights, |v| {
        let config = Config {
            scale: v.truth.width() / v.lr.width(),
            ..config.clone()
        };
        let (out, _) = upscale(
            &v.lr,
            &config,
            &RunOptions::default(),
            &matup_core::progress::Silent,
        )?;
        Ok(out)
    })
}

/// matup's defaults with each map upsampled once (no self-ensemble).
pub fn one_pass_defaults() -> Config {
    let mut config = Config::default();
    config.filter.self_ensemble = 1;
    config
}

/// Each validation material's `candidate` against its truth, rendered with `ggx` under
/// `lights` held-out lights.
pub(super) fn score_each(
    set: &[ValMaterial],
    lights: usize,
    candidate: impl Fn(&ValMaterial) -> Result<Material>,
) -> Result<Vec<(String, Score)>> {
    let model = shading_model(&"ggx".parse::<PluginSpec>()?)?;
    let lights = LightSetSpec::held_out(lights);
    set.iter()
        .map(|v| {
            let scale = v.truth.width() / v.lr.width();
            let e = evaluate(&v.truth, &candidate(v)?, scale, model.as_ref(), &lights)?;
            Ok((v.name.clone(), e.into()))
        })
        .collect()
}

/// The LR material's renders upsampled by `upsampler` (matup's own executor) against the
/// truth's renders, light by light: how close the method's direct targets come to exact ones.
pub(super) fn validate_renders(
    upsampler: &str,
    set: &[ValMaterial],
    lights: usize,
) -> Result<Vec<(String, Score)>> {
    let s = rgb_upsampler(&upsampler.parse::<PluginSpec>()?)?;
    let model = shading_model(&"ggx".parse::<PluginSpec>()?)?;
    let lights = LightSetSpec::held_out(lights).build();
    set.iter()
        .map(|v| {
            let scale = v.truth.width() / v.lr.width();
            // Per light: squared error, FLIP, sharpness of the upsampled and the true render.
            let mut per_light: Vec<[f64; 4]> = Vec::with_capacity(lights.len());
            for light in &lights {
                let light = std::slice::from_ref(light);
                let lr = render(&v.lr, model.as_ref(), light, CROP_RENDERS);
                let up = s.upsample(&lr, scale, Border::Mirror)?.remove(0);
                let truth = render(&v.truth, model.as_ref(), light, CROP_RENDERS).remove(0);
                per_light.push([
                    rmse(&truth, &up).powi(2),
                    flip(&truth, &up),
                    sharpness(&up),
                    sharpness(&truth),
                ]);
            }
            let mean = |k: usize| per_light.iter().map(|p| p[k]).sum::<f64>() / lights.len() as f64;
            Ok((
                v.name.clone(),
                Score {
                    render_psnr: psnr(mean(0)),
                    render_flip: mean(1),
                    maps: None,
                    render_sharpness: mean(2),
                    reference_render_sharpness: mean(3),
                },
            ))
        })
        .collect()
}

/// The mean render PSNR and FLIP of a validation.
pub fn means(scores: &[(String, Score)]) -> (f64, f64) {
    let n = scores.len().max(1) as f64;
    (
        scores.iter().map(|e| e.1.render_psnr).sum::<f64>() / n,
        scores.iter().map(|e| e.1.render_flip).sum::<f64>() / n,
    )
}

pub(super) const VAL_HEADER: &str = "iteration,material,render_psnr,render_flip,normal_degrees,base_color_rmse,roughness_rmse,metallic_rmse,render_sharpness,reference_render_sharpness";

pub(super) fn log_validation(
    files: &RunFiles,
    iteration: usize,
    scores: &[(String, Score)],
) -> Result<()> {
    let row = |name: &str, e: &Score| {
        let maps = match e.maps {
            Some([normal, base, rough, metal]) => {
                format!("{normal:.4},{base:.5},{rough:.5},{metal:.5}")
            }
            None => ",,,".into(),
        };
        format!(
            "{iteration},{name},{:.4},{:.5},{maps},{:.5},{:.5}",
            e.render_psnr, e.render_flip, e.render_sharpness, e.reference_render_sharpness
        )
    };
    for (name, e) in scores {
        append(&files.val_log(), VAL_HEADER, &row(name, e))?;
    }
    let (psnr, flip) = means(scores);
    append(
        &files.val_log(),
        VAL_HEADER,
        &format!("{iteration},mean,{psnr:.4},{flip:.5},,,,,,"),
    )
}
