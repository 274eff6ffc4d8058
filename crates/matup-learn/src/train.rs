//! The training loop: random pairs from the training materials, the network's maps through
//! what `matup upscale` does with them ([`crate::shipped`]), rendered under random lights
//! against the truth's renders; Adam; checkpoints that resume exactly; validation of the
//! exported network by `matup upscale` itself.

use std::collections::HashMap;
use std::f64::consts::TAU;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use candle_core::{backprop::GradStore, Device, Tensor, Var};
use matup_core::io::write_atomic;
use matup_core::lights::Light;
use matup_core::map::Map;
use matup_core::progress::Progress;
use matup_core::render::{render, RenderOptions};
use matup_core::resample::Border;
use matup_core::shading::tensor_form;
use matup_core::shading::{shading_model, ShadingModel};
use matup_core::tensor::{loss_norm, params_tensor, LightTensors};
use matup_core::tileable::decide_tileable;
use matup_core::upsample::upsampler as rgb_upsampler;
use matup_core::{Error, LightSetSpec, LossNorm, Material, PluginSpec, Result};
use matup_eval::metrics::{evaluate, flip, psnr, rmse, sharpness, Evaluation};
use matup_method::filter::FEATURES;
use matup_method::{upscale, Config, RunOptions};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

use crate::config::{LearnConfig, Target};
use crate::data::{
    lr_features, material_extent, network_inputs, normal_inputs, random_pair, Corpus, Pair,
};
use crate::export::export;
use crate::grid::grid_term;
use crate::net::TrainableNet;
use crate::shipped::{
    decode_normal_image, decode_outputs, normal_chord, normal_params, shown, BackProjection, Route,
};
use matup_method::filter::decode::shading_params;

/// Adam (Kingma & Ba 2015) over the network's tensors, its moments checkpointed with them;
/// with an anchor, each step also pulls the weights toward where they started
/// ([`LearnConfig::anchor_weight`]).
struct Adam {
    m: Vec<Tensor>,
    v: Vec<Tensor>,
    step: usize,
    learning_rate: f64,
    /// The starting weights and the pull's weight.
    anchor: Option<(Vec<Tensor>, f64)>,
}

const BETA1: f64 = 0.9;
const BETA2: f64 = 0.999;
const EPSILON: f64 = 1e-8;

impl Adam {
    /// For `vars` as they are now (the base model's weights, the anchor's start).
    fn new(vars: &[Var], learning_rate: f64, anchor_weight: f64) -> candle_core::Result<Adam> {
        let zeros = |v: &Var| v.as_tensor().zeros_like();
        // A copy: a `Var`'s tensor is updated in place.
        let start = |v: &Var| v.as_tensor().copy();
        Ok(Adam {
            m: vars.iter().map(zeros).collect::<candle_core::Result<_>>()?,
            v: vars.iter().map(zeros).collect::<candle_core::Result<_>>()?,
            step: 0,
            learning_rate,
            anchor: if anchor_weight > 0.0 {
                let start = vars.iter().map(start).collect::<candle_core::Result<_>>()?;
                Some((start, anchor_weight))
            } else {
                None
            },
        })
    }

    fn update(&mut self, vars: &[Var], grads: &GradStore) -> candle_core::Result<()> {
        self.step += 1;
        let c1 = 1.0 - BETA1.powi(self.step as i32);
        let c2 = 1.0 - BETA2.powi(self.step as i32);
        for (i, ((var, m), v)) in vars.iter().zip(&mut self.m).zip(&mut self.v).enumerate() {
            let Some(g) = grads.get(var.as_tensor()) else {
                continue;
            };
            *m = ((&*m * BETA1)? + (g * (1.0 - BETA1))?)?;
            *v = ((&*v * BETA2)? + (g.sqr()? * (1.0 - BETA2))?)?;
            let mut step = ((&*m / c1)? / ((&*v / c2)?.sqrt()? + EPSILON)?)?;
            if let Some((start, weight)) = &self.anchor {
                step = (step + ((var.as_tensor() - &start[i])? * *weight)?)?;
            }
            var.set(&(var.as_tensor() - (step * self.learning_rate)?)?)?;
        }
        Ok(())
    }
}

/// What a checkpoint records beside its tensors.
#[derive(Debug, Serialize, Deserialize, PartialEq)]
struct CheckpointInfo {
    iteration: usize,
    /// The configuration it was trained with (a resume must use the same).
    config: LearnConfig,
    /// Mean validation render PSNR of the best export so far, and its iteration.
    best: Option<(f64, usize)>,
}

/// A run folder's files.
pub struct RunFiles {
    pub dir: PathBuf,
}

impl RunFiles {
    fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }
    pub fn checkpoint(&self) -> PathBuf {
        self.path("checkpoint.safetensors")
    }
    pub fn checkpoint_info(&self) -> PathBuf {
        self.path("checkpoint.json")
    }
    /// Per step: iteration, loss, render loss, normal term, seconds.
    pub fn train_log(&self) -> PathBuf {
        self.path("train.csv")
    }
    /// Per validation: iteration, material and its numbers (`mean` for the mean).
    pub fn val_log(&self) -> PathBuf {
        self.path("val.csv")
    }
    /// The exported network with the best mean validation PSNR (`best.onnx`, `best.toml`).
    pub fn best(&self) -> PathBuf {
        self.path("best.onnx")
    }
    /// The last exported network (what validation ran).
    pub fn last(&self) -> PathBuf {
        self.path("last.onnx")
    }
}

/// One step's numbers.
#[derive(Clone, Copy, Debug)]
pub struct StepLoss {
    pub loss: f64,
    pub render: f64,
    pub normal: f64,
}

/// Everything a training step needs that does not change between steps.
pub struct Trainer {
    pub config: LearnConfig,
    pub net: TrainableNet,
    model: Box<dyn ShadingModel>,
    norm: LossNorm,
    corpus: Corpus,
    back_projection: BackProjection,
    /// Where `config.scale` is below the network's: the filter down to it.
    route: Option<Route>,
    lights: LightSetSpec,
    device: Device,
}

impl Trainer {
    pub fn new(config: &LearnConfig, device: &Device) -> Result<Trainer> {
        let mut net = TrainableNet::load(&config.base_model, device)?;
        if config.height_guide {
            net.add_height_guide()
                .map_err(|e| Error::file(&config.base_model, e.to_string()))?;
        }
        let native = net.info.scale;
        if native < config.scale {
            return Err(Error::Invalid(format!(
                "{}: a ×{native} network, but the configuration asks for ×{}",
                config.base_model.display(),
                config.scale
            )));
        }
        if native > config.scale && config.target != Target::Maps {
            return Err(Error::Invalid(format!(
                "{}: a ×{native} network trained for ×{} goes through matup's route, which \
                 training models for target = \"maps\" only",
                config.base_model.display(),
                config.scale
            )));
        }
        let lr_size = config.patch / config.scale + 2 * config.context;
        let model = shading_model(&"ggx".parse::<PluginSpec>()?)?;
        tensor_form(model.as_ref())?;
        Ok(Trainer {
            net,
            model,
            norm: config.loss_norm()?,
            corpus: Corpus::load(
                &config.corpus,
                &config.train,
                material_extent(config.crop_size(), config.zoom_out_share),
            )?,
            // Crops do not tile: the bilinear spread mirrors at their borders, as `matup
            // upscale` does for materials that do not tile.
            back_projection: BackProjection::new(lr_size, config.scale, Border::Mirror, device)?,
            route: (native > config.scale)
                .then(|| Route::new(lr_size, native, config.scale, Border::Mirror, device))
                .transpose()?,
            lights: LightSetSpec::default(),
            config: config.clone(),
            device: device.clone(),
        })
    }

    /// Puts the weights of the run in `dir` (its last checkpoint, of this configuration) in
    /// place of the base model's; returns the checkpoint's step.
    pub fn load_run(&self, dir: &Path) -> Result<usize> {
        let vars = self.net.vars();
        let mut adam = Adam::new(&vars, self.config.learning_rate, 0.0)?;
        let files = RunFiles {
            dir: dir.to_path_buf(),
        };
        load_checkpoint(&files, &vars, &mut adam, &self.config, &self.device)?
            .map(|info| info.iteration)
            .ok_or_else(|| Error::file(&files.checkpoint_info(), "no checkpoint"))
    }

    /// The random generator of step `iteration`: a function of the seed and the step alone,
    /// so that a resumed run draws what an uninterrupted one would.
    fn rng(&self, iteration: usize) -> StdRng {
        StdRng::seed_from_u64(
            self.config
                .seed
                .wrapping_mul(0x9E37_79B9_7F4A_7C15)
                .wrapping_add(iteration as u64),
        )
    }

    /// `count` lights in directions uniform over the upper hemisphere.
    fn random_lights(&self, count: usize, rng: &mut impl Rng) -> Vec<Light> {
        (0..count)
            .map(|_| {
                let z: f64 = rng.random_range(0.0..1.0);
                let phi: f64 = rng.random_range(0.0..TAU);
                let r = (1.0 - z * z).sqrt();
                let d = [r * phi.cos(), r * phi.sin(), z].map(|v| v as f32);
                self.lights.light_towards(d)
            })
            .collect()
    }

    /// The loss of step `iteration` (its pairs and lights), as a tensor to differentiate.
    pub fn loss(&self, iteration: usize) -> Result<(Tensor, StepLoss)> {
        let mut rng = self.rng(iteration);
        let c = &self.config;
        let pairs: Vec<_> = (0..c.batch)
            .map(|_| random_pair(&self.corpus, c.crop_size(), c.scale, c.shares(), &mut rng))
            .collect();
        let lights = self.random_lights(c.lights, &mut rng);
        match c.target {
            Target::Maps => self.maps_loss(&pairs, &lights),
            Target::Renders => self.renders_loss(&pairs, &lights),
            Target::Normals => self.normals_loss(&pairs, &lights),
        }
    }

    /// The network's maps, decoded and back-projected as `matup upscale` ships them, rendered
    /// against the truth's renders (plus the normal term); only the crops' centres are scored,
    /// without the `context` around them.
    fn maps_loss(&self, pairs: &[Pair], lights: &[Light]) -> Result<(Tensor, StepLoss)> {
        let lrs: Vec<&Material> = pairs.iter().map(|p| &p.lr).collect();
        let (hr, fixed) = shipped_maps(
            &self.net,
            &lrs,
            self.route.as_ref(),
            &self.back_projection,
            &self.device,
        )?;
        let margin = self.config.context * self.config.scale;
        let hr = centre(&hr, margin)?;
        let params = (0..pairs.len())
            .map(|b| shading_params(&hr.get(b)?, &fixed[b]))
            .collect::<candle_core::Result<Vec<_>>>()?;
        let params = Tensor::cat(&params, 0)?;
        let truths: Vec<Material> = pairs
            .iter()
            .map(|p| {
                let size = p.truth.width() - 2 * margin;
                p.truth.crop(margin, margin, size, size)
            })
            .collect();
        let truth_refs: Vec<&Material> = truths.iter().collect();
        let truth = TrueTexels::new(&truth_refs, &self.device)?;
        let (loss, numbers) = self.against_truth(&truth, &params, lights)?;
        if self.config.grid_weight == 0.0 {
            return Ok((loss, numbers));
        }
        // The truth's features, made as the LR crops' are.
        let (true_features, _) = lr_features(&truth_refs, &self.device)?;
        let grid = grid_term(&hr, &true_features, self.config.scale)?;
        let loss = (loss + (grid * self.config.grid_weight)?)?;
        Ok((
            loss.clone(),
            StepLoss {
                loss: loss.to_scalar::<f32>()? as f64,
                ..numbers
            },
        ))
    }

    /// The network's normal maps, decoded and back-projected as `matup upscale` ships them,
    /// in the true material in place of its own normals, rendered against the truth's renders
    /// (plus the normal term).
    fn normals_loss(&self, pairs: &[Pair], lights: &[Light]) -> Result<(Tensor, StepLoss)> {
        let lrs: Vec<&Material> = pairs.iter().map(|p| &p.lr).collect();
        let normals = shipped_normals(
            &self.net,
            &lrs,
            &self.back_projection,
            0,
            Border::Mirror,
            &self.device,
        )?;
        let truths: Vec<&Material> = pairs.iter().map(|p| &p.truth).collect();
        let truth = TrueTexels::new(&truths, &self.device)?;
        let t = &truth.params;
        let params = Tensor::cat(&[&t.narrow(1, 0, 4)?, &normals, &t.narrow(1, 7, 3)?], 1)?;
        self.against_truth(&truth, &params, lights)
    }

    /// The render loss of shading parameters `[T, 10]` (the pairs' texels in order) against
    /// the truth's, plus the normal term.
    fn against_truth(
        &self,
        truth: &TrueTexels,
        params: &Tensor,
        lights: &[Light],
    ) -> Result<(Tensor, StepLoss)> {
        // Both rendered at the truth's positions (height displaced): the network makes no
        // height, and the loss should see only what it makes.
        let light_tensors = LightTensors::new(lights, &truth.positions, &self.device)?;
        let shading = tensor_form(self.model.as_ref())?;
        let target = shown(shading, &truth.params, &light_tensors)?.detach();
        let rendered = shown(shading, params, &light_tensors)?;
        let render = loss_norm(&self.norm, &(rendered - target)?)?.mean_all()?;
        let normal = normal_chord(params, &truth.params)?;
        let loss = (&render + (&normal * self.config.normal_weight)?)?;
        step_loss(loss, render, normal)
    }

    /// The network's upsampling of the LR crops' renders against the true crops' renders,
    /// both made by matup's renderer as the method makes its LR renders (anti-aliased; crops
    /// do not tile, so their borders mirror).
    fn renders_loss(&self, pairs: &[Pair], lights: &[Light]) -> Result<(Tensor, StepLoss)> {
        let renders = |pick: fn(&Pair) -> &Material| -> candle_core::Result<Tensor> {
            let maps: Vec<Map> = pairs
                .iter()
                .flat_map(|p| render(pick(p), self.model.as_ref(), lights, CROP_RENDERS))
                .collect();
            stack(&maps, &self.device)
        };
        let inputs = renders(|p| &p.lr)?;
        let target = renders(|p| &p.truth)?;
        let outputs = self.net.forward(&inputs)?;
        // The norm over colour, as the method's loss takes it: channels last.
        let error = (outputs - target)?.permute((0, 2, 3, 1))?;
        let render = loss_norm(&self.norm, &error)?.mean_all()?;
        let normal = render.zeros_like()?;
        step_loss(render.clone(), render, normal)
    }
}

/// The true crops' texels, in order: shading parameters `[T, 10]` and positions.
struct TrueTexels {
    params: Tensor,
    positions: Vec<[f32; 3]>,
}

impl TrueTexels {
    fn new(truths: &[&Material], device: &Device) -> Result<TrueTexels> {
        let texels: Vec<_> = truths
            .iter()
            .flat_map(|t| (0..t.base_color.texels()).map(|i| t.texel(i)))
            .collect();
        Ok(TrueTexels {
            params: params_tensor(&texels.iter().map(|t| t.params).collect::<Vec<_>>(), device)?,
            positions: texels.iter().map(|t| t.position).collect(),
        })
    }
}

/// What `matup upscale`'s defaults make of `net`'s upsampling of LR materials: the 7
/// features `[B, 7, H, W]`, decoded and back-projected, and per material the features held
/// constant. The network reads each LR crop whole, zero padded at its edges, which inference
/// inside an image never meets: [`centre`] keeps what lies out of the padding's reach. A
/// `route` shrinks the network's outputs to the scale trained for.
pub fn shipped_maps(
    net: &TrainableNet,
    lrs: &[&Material],
    route: Option<&Route>,
    back_projection: &BackProjection,
    device: &Device,
) -> Result<(Tensor, Vec<[Option<f32>; FEATURES]>)> {
    let inputs = network_inputs(lrs, device)?;
    let (lr, fixed) = lr_features(lrs, device)?;
    let mut outputs = net.forward(&inputs)?;
    if let Some(route) = route {
        outputs = route.apply(&outputs)?;
    }
    let hr = back_projection.apply(&decode_outputs(&outputs)?, &lr)?;
    Ok((hr, fixed))
}

/// Maps `[B, C, H, W]` without `margin` texels at each edge.
pub fn centre(maps: &Tensor, margin: usize) -> candle_core::Result<Tensor> {
    let (_, _, h, w) = maps.dims4()?;
    maps.narrow(2, margin, h - 2 * margin)?
        .narrow(3, margin, w - 2 * margin)
}

/// What `matup upscale`'s defaults make of `net`'s upsampling of the LR normal maps (decoded,
/// renormalised, back-projected onto the LR normals by `back_projection`), as the shading
/// parameters' normals `[T, 3]`, texel by texel. The network reads each LR map whole, zero padded (training crops), or with `context`
/// texels beyond its edges taken as `border` says, as matup's executor reads a whole image
/// (validation).
fn shipped_normals(
    net: &TrainableNet,
    lrs: &[&Material],
    back_projection: &BackProjection,
    context: usize,
    border: Border,
    device: &Device,
) -> Result<Tensor> {
    let (images, height) = normal_inputs(lrs, net.has_height_guide(), device)?;
    let upsampled = if context == 0 {
        net.forward_guided(&images, height.as_ref())?
    } else {
        net.forward_bordered(&images, height.as_ref(), context, border)?
    };
    let unit = decode_normal_image(&upsampled)?;
    let (lr, _) = lr_features(lrs, device)?;
    // Normal x and y are features 4 and 5.
    let xy = back_projection.apply_features(&unit.narrow(1, 0, 2)?, &lr.narrow(1, 4, 2)?, 4)?;
    Ok(normal_params(&xy)?)
}

/// Renders of training and validation crops: anti-aliased as the method's LR renders, borders
/// mirrored (a crop does not tile).
const CROP_RENDERS: RenderOptions = RenderOptions {
    supersample: true,
    border: Border::Mirror,
};

/// RGB maps of one size as a `[N, 3, h, w]` tensor (maps are stored plane by plane).
fn stack(maps: &[Map], device: &Device) -> candle_core::Result<Tensor> {
    let (w, h) = (maps[0].width(), maps[0].height());
    let data: Vec<f32> = maps.iter().flat_map(|m| m.data().iter().copied()).collect();
    Tensor::from_vec(data, (maps.len(), 3, h, w), device)
}

fn step_loss(loss: Tensor, render: Tensor, normal: Tensor) -> Result<(Tensor, StepLoss)> {
    let numbers = StepLoss {
        loss: loss.to_scalar::<f32>()? as f64,
        render: render.to_scalar::<f32>()? as f64,
        normal: normal.to_scalar::<f32>()? as f64,
    };
    Ok((loss, numbers))
}

/// Saves the network's tensors and the optimiser's moments, then the info (the info last: a
/// checkpoint is whole once its info names its iteration).
fn save_checkpoint(
    files: &RunFiles,
    vars: &[Var],
    adam: &Adam,
    config: &LearnConfig,
    iteration: usize,
    best: Option<(f64, usize)>,
) -> Result<()> {
    let mut tensors = HashMap::new();
    for (i, var) in vars.iter().enumerate() {
        tensors.insert(format!("w{i}"), var.as_tensor().clone());
        tensors.insert(format!("m{i}"), adam.m[i].clone());
        tensors.insert(format!("v{i}"), adam.v[i].clone());
    }
    let tmp = files.dir.join(".checkpoint.safetensors.tmp");
    candle_core::safetensors::save(&tensors, &tmp)?;
    std::fs::rename(&tmp, files.checkpoint()).map_err(|e| Error::io(&files.checkpoint(), e))?;
    write_atomic(
        &files.checkpoint_info(),
        serde_json::to_string_pretty(&CheckpointInfo {
            iteration,
            config: config.clone(),
            best,
        })
        .expect("serialisable")
        .as_bytes(),
    )
}

/// Restores a checkpoint into the network and optimiser; its iteration and best export.
fn load_checkpoint(
    files: &RunFiles,
    vars: &[Var],
    adam: &mut Adam,
    config: &LearnConfig,
    device: &Device,
) -> Result<Option<CheckpointInfo>> {
    let Ok(text) = std::fs::read_to_string(files.checkpoint_info()) else {
        return Ok(None);
    };
    let info: CheckpointInfo = serde_json::from_str(&text)
        .map_err(|e| Error::file(&files.checkpoint_info(), e.to_string()))?;
    // The step count may change between calls (a run is extended by asking for more).
    let settings = |c: &LearnConfig| LearnConfig {
        iterations: 0,
        ..c.clone()
    };
    if settings(&info.config) != settings(config) {
        return Err(Error::Invalid(format!(
            "{} was trained with other settings; use a new run folder, or the configuration in {}",
            files.dir.display(),
            files.checkpoint_info().display()
        )));
    }
    let tensors = candle_core::safetensors::load(files.checkpoint(), device)?;
    let get = |name: String| {
        tensors.get(&name).cloned().ok_or_else(|| {
            Error::Invalid(format!(
                "{}: no tensor {name}",
                files.checkpoint().display()
            ))
        })
    };
    for (i, var) in vars.iter().enumerate() {
        var.set(&get(format!("w{i}"))?)?;
        adam.m[i] = get(format!("m{i}"))?;
        adam.v[i] = get(format!("v{i}"))?;
    }
    adam.step = info.iteration;
    Ok(Some(info))
}

/// Keeps the header of a CSV log and the rows `keep` picks (what a checkpoint had seen), so
/// that a resumed run's log reads as an uninterrupted one's.
fn truncate_log(path: &Path, keep: impl Fn(&str) -> bool) -> Result<()> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Ok(());
    };
    let kept: String = text
        .lines()
        .enumerate()
        .filter(|(i, line)| *i == 0 || keep(line))
        .map(|(_, line)| format!("{line}\n"))
        .collect();
    write_atomic(path, kept.as_bytes())
}

fn append(path: &Path, header: &str, line: &str) -> Result<()> {
    let new = !path.exists();
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .map_err(|e| Error::io(path, e))?;
    let text = if new {
        format!("{header}\n{line}\n")
    } else {
        format!("{line}\n")
    };
    f.write_all(text.as_bytes()).map_err(|e| Error::io(path, e))
}

fn iteration_of(line: &str) -> usize {
    line.split(',')
        .next()
        .and_then(|v| v.parse().ok())
        .unwrap_or(usize::MAX)
}

/// A validation material: the true crop and its LR version.
pub struct ValMaterial {
    pub name: String,
    pub truth: Material,
    pub lr: Material,
}

/// The validation crops of `config.val` (top-left `val_crop²` of each).
pub fn validation_set(config: &LearnConfig) -> Result<Vec<ValMaterial>> {
    // Any size will do: a validation crop is at most the material.
    let corpus = Corpus::load(&config.corpus, &config.val, 0)?;
    Ok(corpus
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
        .collect())
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
fn validate_maps(
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
fn score_each(
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
fn validate_renders(
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

const VAL_HEADER: &str = "iteration,material,render_psnr,render_flip,normal_degrees,base_color_rmse,roughness_rmse,metallic_rmse,render_sharpness,reference_render_sharpness";

fn log_validation(files: &RunFiles, iteration: usize, scores: &[(String, Score)]) -> Result<()> {
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

/// How a call to [`train`] ended.
#[derive(Debug)]
pub struct Summary {
    pub iterations: usize,
    pub resumed_from: Option<usize>,
    /// The best mean validation render PSNR and its iteration.
    pub best: Option<(f64, usize)>,
    pub seconds: f64,
}

/// Trains (or resumes) the run in `dir` up to `config.iterations` steps, checkpointing every
/// `checkpoint_every` steps and validating every `validate_every` (and at the start and the
/// end), keeping the best export as `best.onnx`. Stops cleanly, checkpoint written, when
/// `progress` says cancelled.
pub fn train(
    config: &LearnConfig,
    dir: &Path,
    device: &Device,
    progress: &dyn Progress,
) -> Result<Summary> {
    let start = Instant::now();
    // The data and network first: a run that cannot start leaves no folder behind.
    let trainer = Trainer::new(config, device)?;
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let files = RunFiles {
        dir: dir.to_path_buf(),
    };
    let vars = trainer.net.vars();
    let frozen = trainer.net.frozen_vars(config.trained);
    let mut adam = Adam::new(&vars, config.learning_rate, config.anchor_weight)?;
    let info = load_checkpoint(&files, &vars, &mut adam, config, device)?;
    let resumed_from = info.as_ref().map(|i| i.iteration);
    let mut iteration = resumed_from.unwrap_or(0);
    let mut best = info.and_then(|i| i.best);
    if let Some(i) = resumed_from {
        progress.note(&format!("resuming {} at step {i}", dir.display()));
    }
    // A resumed run keeps the rows its checkpoint had seen; a new one (into a folder holding
    // an earlier run's logs, as when a run is recreated) keeps none.
    let seen = |line: &str| resumed_from.is_some_and(|i| iteration_of(line) <= i);
    truncate_log(&files.train_log(), seen)?;
    truncate_log(&files.val_log(), seen)?;

    let set = if config.validate_every > 0 {
        validation_set(config)?
    } else {
        Vec::new()
    };
    let validate_now = |iteration: usize, best: &mut Option<(f64, usize)>| -> Result<()> {
        if set.is_empty() {
            return Ok(());
        }
        progress.stage(&format!("validate step {iteration}"), set.len() as u64);
        let evaluations = if config.target == Target::Normals {
            // In candle: a height-guided network has no ONNX form.
            validate_normals(&trainer.net, &set, config.val_lights)?
        } else {
            export(&trainer.net, &files.last(), config, iteration)?;
            validate(
                config.target,
                &format!("onnx:{}", files.last().display()),
                &set,
                config.val_lights,
            )?
        };
        progress.advance(set.len() as u64, None);
        log_validation(&files, iteration, &evaluations)?;
        let (psnr, flip) = means(&evaluations);
        progress.note(&format!(
            "step {iteration}: validation render PSNR {psnr:.3} dB, FLIP {flip:.4}"
        ));
        if best.is_none_or(|(b, _)| psnr > b) {
            *best = Some((psnr, iteration));
            if !trainer.net.has_height_guide() {
                export(&trainer.net, &files.best(), config, iteration)?;
            }
        }
        Ok(())
    };
    if resumed_from.is_none() {
        validate_now(0, &mut best)?;
    }

    progress.stage("train", config.iterations as u64);
    progress.advance(iteration as u64, None);
    while iteration < config.iterations {
        if progress.cancelled() {
            save_checkpoint(&files, &vars, &adam, config, iteration, best)?;
            return Err(Error::Cancelled {
                epochs_done: iteration,
            });
        }
        let step_start = Instant::now();
        let (loss, numbers) = trainer.loss(iteration)?;
        if !numbers.loss.is_finite() {
            return Err(Error::Invalid(format!(
                "step {}: the loss is {}; training diverged (lower learning_rate), the last checkpoint in {} is intact",
                iteration + 1,
                numbers.loss,
                dir.display()
            )));
        }
        let mut grads = loss.backward()?;
        // A frozen tensor has no gradient, so Adam leaves it (and its moments) as they are.
        for var in &frozen {
            grads.remove(var.as_tensor());
        }
        adam.update(&vars, &grads)?;
        iteration += 1;
        append(
            &files.train_log(),
            "iteration,loss,render_loss,normal_term,seconds",
            &format!(
                "{iteration},{:.6},{:.6},{:.6},{:.3}",
                numbers.loss,
                numbers.render,
                numbers.normal,
                step_start.elapsed().as_secs_f64()
            ),
        )?;
        progress.advance(1, Some(numbers.loss));
        let validating = config.validate_every > 0
            && (iteration % config.validate_every == 0 || iteration == config.iterations);
        if validating {
            validate_now(iteration, &mut best)?;
            progress.stage("train", config.iterations as u64);
            progress.advance(iteration as u64, None);
        }
        if validating || iteration % config.checkpoint_every == 0 || iteration == config.iterations
        {
            save_checkpoint(&files, &vars, &adam, config, iteration, best)?;
        }
    }
    Ok(Summary {
        iterations: iteration,
        resumed_from,
        best,
        seconds: start.elapsed().as_secs_f64(),
    })
}
