//! One training step's loss: random pairs from the training materials, the network's maps
//! through what `matup upscale` does with them ([`crate::post_process`]), rendered under random
//! lights against the truth's renders (or compared as maps, or as normals).

use std::f64::consts::TAU;
use std::path::Path;

use candle_core::{Device, Tensor};
use matup_core::lights::Light;
use matup_core::map::Map;
use matup_core::render::{render, RenderOptions};
use matup_core::resample::Border;
use matup_core::shading::tensor_form;
use matup_core::shading::{shading_model, ShadingModel};
use matup_core::tensor_shading::{loss_norm, params_tensor, LightTensors};
use matup_core::{Error, LightSetSpec, LossNorm, Material, PluginSpec, Result};
use matup_method::filter::FEATURES;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use super::checkpoint::{load_checkpoint, RunFiles};
use crate::config::{LearnConfig, Target};
use crate::data::{
    lr_features, material_extent, network_inputs, normal_inputs, random_pair, Corpus, Pair,
};
use crate::grid_term::grid_term;
use crate::net::TrainableNet;
use crate::post_process::{
    decode_normal_image, decode_outputs, normal_chord, normal_params, shown, BackProjection, Route,
};
use matup_method::filter::decode::shading_params;
use matup_method::train::adam::Adam;

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
        let mut pairs: Vec<_> = (0..c.batch)
            .map(|_| random_pair(&self.corpus, c.crop_size(), c.scale, c.shares(), &mut rng))
            .collect();
        let lights = self.random_lights(c.lights, &mut rng);
        // Drawn after the lights, so that runs without degradations draw what they always drew.
        let mut projected = vec![true; pairs.len()];
        if let Some(degradations) = &c.degradations {
            for (pair, projected) in pairs.iter_mut().zip(&mut projected) {
                let (lr, degraded) = degradations.apply(&pair.lr, &mut rng)?;
                pair.lr = lr;
                *projected = !degraded || degradations.project_degraded;
            }
        }
        match c.target {
            Target::Maps => self.maps_loss(&pairs, &projected, &lights),
            Target::Renders => self.renders_loss(&pairs, &lights),
            Target::Normals => self.normals_loss(&pairs, &lights),
        }
    }

    /// The network's maps, decoded and back-projected as `matup upscale` ships them, rendered
    /// against the truth's renders (plus the normal term); only the crops' centres are scored,
    /// without the `context` around them.
    fn maps_loss(
        &self,
        pairs: &[Pair],
        projected: &[bool],
        lights: &[Light],
    ) -> Result<(Tensor, StepLoss)> {
        let lrs: Vec<&Material> = pairs.iter().map(|p| &p.lr).collect();
        let (hr, fixed) = shipped_maps(
            &self.net,
            &lrs,
            projected,
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
pub(super) struct TrueTexels {
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
/// `route` shrinks the network's outputs to the scale trained for. The materials `projected`
/// marks false keep the network's decoded maps unprojected (`filter.back_project = false`: a
/// degraded input is not what the output should box-filter back to).
pub fn shipped_maps(
    net: &TrainableNet,
    lrs: &[&Material],
    projected: &[bool],
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
    let decoded = decode_outputs(&outputs)?;
    let hr = back_projection.apply(&decoded, &lr)?;
    if projected.iter().all(|&p| p) {
        return Ok((hr, fixed));
    }
    let each = (0..lrs.len())
        .map(|b| {
            if projected[b] {
                hr.narrow(0, b, 1)
            } else {
                decoded.narrow(0, b, 1)
            }
        })
        .collect::<candle_core::Result<Vec<_>>>()?;
    Ok((Tensor::cat(&each, 0)?, fixed))
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
pub(super) fn shipped_normals(
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
pub(super) const CROP_RENDERS: RenderOptions = RenderOptions {
    supersample: true,
    border: Border::Mirror,
};

/// RGB maps of one size as a `[N, 3, h, w]` tensor (maps are stored plane by plane).
pub(super) fn stack(maps: &[Map], device: &Device) -> candle_core::Result<Tensor> {
    let (w, h) = (maps[0].width(), maps[0].height());
    let data: Vec<f32> = maps.iter().flat_map(|m| m.data().iter().copied()).collect();
    Tensor::from_vec(data, (maps.len(), 3, h, w), device)
}

pub(super) fn step_loss(
    loss: Tensor,
    render: Tensor,
    normal: Tensor,
) -> Result<(Tensor, StepLoss)> {
    let numbers = StepLoss {
        loss: loss.to_scalar::<f32>()? as f64,
        render: render.to_scalar::<f32>()? as f64,
        normal: normal.to_scalar::<f32>()? as f64,
    };
    Ok((loss, numbers))
}
