//! The tensor backend: the filter as candle-nn layers, decoding, the shading model's tensor
//! form and the loss as candle operations on any candle device, differentiated by candle's
//! autograd and stepped by the tensor form of Adam ([`super::adam::Adam`]). It needs no hand-derived gradient, so a
//! shading model with only a tensor form trains here; it computes what the fused backend
//! computes (tested to 1e-3 of its loss after a short run).

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use candle_core::{Device, Tensor, Var};
use candle_nn::{Linear, Module};

use super::adam::Adam;

use super::examples::Examples;
use super::stepper::{CrossBatch, LossTerms, Stepper};
use crate::config::{Activation, FUSED_ONLY_TERMS};
use crate::filter::decode::decode_tensors;
use crate::filter::{tensor_name, Filter, FEATURES};
use matup_core::material::texel_position;
use matup_core::shading::tensor_form;
use matup_core::tensor_shading::{texel_losses, LightTensors, SvbrdfTensors, TensorShading};
use matup_core::{Error, Result};

/// Steps with candle tensor operations on `device`. The filter's weights are copied into
/// variables there (the first layer transposed to candle-nn's `[out, in]`) and copied back
/// by [`Stepper::finish`], so inference runs as after fused training.
pub(super) struct TensorStepper<'a> {
    filter: &'a Filter,
    main: &'a Arc<Examples>,
    terms: &'a LossTerms<'a>,
    model: &'a dyn TensorShading,
    device: Device,
    layers: Vec<Linear>,
    /// The layers' variables in the filter's order (`tensor_name`), which the optimiser's
    /// moments follow.
    vars: Vec<Var>,
    optimizer: Adam,
    /// Texels per step (the objective is evaluated in chunks of as many).
    batch: usize,
    steps: u64,
}

/// The weights of layer `index` of `filter` in candle-nn's layout: `[out, in]` and `[out]`.
fn layer_weights(filter: &Filter, index: usize) -> Result<(Tensor, Tensor)> {
    let w = filter.vars[2 * index].as_tensor();
    // The first layer is stored input-major, `[in, out]`.
    let w = if index == 0 { w.t()? } else { w.clone() };
    Ok((
        w.contiguous()?.copy()?,
        filter.vars[2 * index + 1].as_tensor().copy()?,
    ))
}

impl<'a> TensorStepper<'a> {
    pub(super) fn new(
        filter: &'a Filter,
        main: &'a Arc<Examples>,
        terms: &'a LossTerms<'a>,
        batch: usize,
        device: &Device,
    ) -> Result<TensorStepper<'a>> {
        let model = tensor_form(terms.shading.model.as_ref())?;
        let mut layers = Vec::new();
        let mut vars = Vec::new();
        for index in 0..filter.vars.len() / 2 {
            let (w, b) = layer_weights(filter, index)?;
            let (w, b) = (
                Var::from_tensor(&w.to_device(device)?)?,
                Var::from_tensor(&b.to_device(device)?)?,
            );
            // The layer reads the variables' storage, which the optimiser updates in place.
            layers.push(Linear::new(
                w.as_tensor().clone(),
                Some(b.as_tensor().clone()),
            ));
            vars.extend([w, b]);
        }
        // Each step sets its scheduled learning rate.
        let optimizer = Adam::new(&vars, 0.0, 0.0)?;
        Ok(TensorStepper {
            filter,
            main,
            terms,
            model,
            device: device.clone(),
            layers,
            vars,
            optimizer,
            batch,
            steps: 0,
        })
    }

    /// The filter's raw residuals `[B, 7]` at output texels `indices`.
    fn forward(&self, indices: &[usize]) -> Result<Tensor> {
        let windows = self.main.windows(indices);
        let inputs = windows.len() / indices.len().max(1);
        let mut x = Tensor::from_vec(windows, (indices.len(), inputs), &self.device)?;
        let last = self.layers.len() - 1;
        for (index, layer) in self.layers.iter().enumerate() {
            x = layer.forward(&x)?;
            if index < last {
                x = match self.filter.activation {
                    Activation::LeakyRelu(slope) => candle_nn::ops::leaky_relu(&x, slope as f64)?,
                    Activation::Relu => x.relu()?,
                    Activation::Gelu => x.gelu()?,
                    Activation::Silu => x.silu()?,
                };
            }
        }
        Ok(x)
    }

    /// METHOD.md's objective at `indices`, their mean: per texel the render loss over the
    /// lights divided by their number, plus the prior toward the residual base.
    fn loss(&self, indices: &[usize]) -> Result<Tensor> {
        let ex = self.main;
        let n = indices.len();
        let upload =
            |data: Vec<f32>, shape: (usize, usize)| Tensor::from_vec(data, shape, &self.device);
        let base: Vec<f32> = indices
            .iter()
            .flat_map(|&t| ex.residual_base.texel::<FEATURES>(t))
            .collect();
        let base = upload(base, (n, FEATURES))?;
        let (params, features) = decode_tensors(&self.forward(indices)?, &base, &self.terms.fixed)?;

        let shading = self.terms.shading;
        let positions: Vec<[f32; 3]> = indices
            .iter()
            .map(|&t| texel_position(t, ex.width, ex.height, ex.heights.as_ref()))
            .collect();
        let lights = LightTensors::new(&shading.lights, &positions, &self.device)?;
        let mut targets: Vec<f32> = Vec::with_capacity(n * shading.lights.len() * 3);
        let mut texel_targets = Vec::new();
        for &t in indices {
            ex.targets.texel(t, &mut texel_targets);
            targets.extend(texel_targets.iter().flatten());
        }
        let targets = Tensor::from_vec(targets, (n, shading.lights.len(), 3), &self.device)?;
        let fit = texel_losses(
            self.model,
            &SvbrdfTensors::from_params(&params)?,
            &lights,
            &targets,
            &shading.norm,
        )?;
        let fit = (fit / shading.lights.len() as f64)?;

        // The prior weighs learned features only (a held feature is not pulled).
        let weights: Vec<f32> = (0..FEATURES)
            .map(|k| {
                if self.terms.fixed[k].is_none() {
                    self.terms.prior[k]
                } else {
                    0.0
                }
            })
            .collect();
        let weights = upload(weights, (1, FEATURES))?;
        let prior = (features - base)?.sqr()?.broadcast_mul(&weights)?.sum(1)?;
        Ok(((fit + prior)?.sum_all()? / n as f64)?)
    }
}

impl Stepper for TensorStepper<'_> {
    fn step(&mut self, indices: &[usize], cross: Option<CrossBatch>, lr: f64) -> Result<f64> {
        if cross.is_some() {
            return Err(Error::Invalid(FUSED_ONLY_TERMS.into()));
        }
        let loss = self.loss(indices)?;
        let value = loss.to_scalar::<f32>()? as f64;
        if value.is_finite() {
            self.optimizer.learning_rate = lr;
            self.optimizer.update(&self.vars, &loss.backward()?)?;
            self.steps += 1;
        }
        Ok(value)
    }

    fn objective(&self, texels: &[usize]) -> Result<f64> {
        let mut sum = 0.0;
        for chunk in texels.chunks(self.batch) {
            sum += self.loss(chunk)?.to_scalar::<f32>()? as f64 * chunk.len() as f64;
        }
        Ok(sum / texels.len().max(1) as f64)
    }

    fn steps(&self) -> u64 {
        self.steps
    }

    /// The weights in the filter's layout, and the optimiser's moments in the layers' own
    /// (`tensor_adam_m{i}`, `tensor_adam_v{i}`), so that a resumed run equals an
    /// uninterrupted one.
    fn state(&self) -> Result<HashMap<String, Tensor>> {
        let mut state = HashMap::new();
        for (i, var) in self.vars.iter().enumerate() {
            let t = var.as_tensor().to_device(&Device::Cpu)?;
            // Back to the filter's input-major first layer.
            let t = if i == 0 { t.t()?.contiguous()? } else { t };
            state.insert(tensor_name(i), t);
        }
        for (i, (m, v)) in self.optimizer.m.iter().zip(&self.optimizer.v).enumerate() {
            state.insert(format!("tensor_adam_m{i}"), m.to_device(&Device::Cpu)?);
            state.insert(format!("tensor_adam_v{i}"), v.to_device(&Device::Cpu)?);
        }
        Ok(state)
    }

    fn restore(
        &mut self,
        state: &HashMap<String, Tensor>,
        steps: u64,
        origin: &Path,
    ) -> Result<()> {
        self.filter.load_tensors(state, origin)?;
        for index in 0..self.filter.vars.len() / 2 {
            let (w, b) = layer_weights(self.filter, index)?;
            self.vars[2 * index].set(&w.to_device(&self.device)?)?;
            self.vars[2 * index + 1].set(&b.to_device(&self.device)?)?;
        }
        // A checkpoint that holds no moments (a fused run's) starts Adam's afresh.
        let moment = |kind: &str, i: usize| state.get(&format!("tensor_adam_{kind}{i}"));
        if moment("m", 0).is_none() {
            self.steps = steps;
            return Ok(());
        }
        for (i, var) in self.vars.iter().enumerate() {
            let (Some(m), Some(v)) = (moment("m", i), moment("v", i)) else {
                return Err(Error::file(
                    origin,
                    format!("checkpoint lacks tensor_adam_m{i}/v{i}"),
                ));
            };
            if m.dims() != var.dims() || v.dims() != var.dims() {
                return Err(Error::file(
                    origin,
                    "checkpoint optimiser state does not fit this filter",
                ));
            }
            self.optimizer.m[i] = m.to_device(&self.device)?;
            self.optimizer.v[i] = v.to_device(&self.device)?;
        }
        self.optimizer.step = steps as usize;
        self.steps = steps;
        Ok(())
    }

    fn finish(&self) -> Result<()> {
        let state = self.state()?;
        for (i, var) in self.filter.vars.iter().enumerate() {
            var.set(&state[&tensor_name(i)])?;
        }
        Ok(())
    }
}
