//! The per-material filter: an MLP reading a window of upsampled LR maps around each output
//! texel and answering a residual on its 7 features (METHOD.md).

pub mod activation;
pub mod decode;
pub mod dense;
pub mod folded;
pub mod geometry;
pub mod input;

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use candle_core::{DType, Device, Tensor, Var};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

use crate::config::{Activation, FilterConfig};
use dense::{Dense, WeightLayout};
use folded::FoldedLayer;
use geometry::WindowGeometry;
use matup_core::map::Map;
use matup_core::resample::Border;
use matup_core::{Error, Result};

pub use crate::features::{FEATURES, FEATURE_NAMES};

/// The MLP: a folded first layer, hidden layers, a 7-wide output.
pub struct Filter {
    pub layer1: FoldedLayer,
    pub activation: Activation,
    /// Which features are inputs (constant ones are left out).
    pub input_channels: Vec<usize>,
    /// `[w1, b1, w2, b2, …, w_out, b_out]`; `w1` is `[dy][dx][c][h]`, the others `[out][in]`.
    pub vars: Vec<Var>,
}

impl Filter {
    /// A freshly initialised filter (PyTorch's `Linear` default, U(±1/√fan_in); the output
    /// layer scaled by 0.1 so training starts near the residual base).
    pub fn new(
        config: &FilterConfig,
        scale: usize,
        input_channels: Vec<usize>,
        seed: u64,
    ) -> Result<Filter> {
        let geometry = Arc::new(WindowGeometry::new(scale, config.window, config.input.0));
        let layer1 = FoldedLayer {
            geometry,
            channels: input_channels.len(),
            hidden: config.hidden_width,
        };
        let mut rng = StdRng::seed_from_u64(seed);
        let mut uniform = |n: usize, bound: f32| -> Vec<f32> {
            (0..n).map(|_| rng.random_range(-bound..bound)).collect()
        };
        let h = config.hidden_width;
        let mut shapes: Vec<(usize, usize, f32)> = Vec::new(); // (out, fan_in, scale)
        shapes.push((h, config.window * config.window * input_channels.len(), 1.0));
        for _ in 1..config.hidden_layers.max(1) {
            shapes.push((h, h, 1.0));
        }
        shapes.push((FEATURES, h, 0.1));
        let mut vars = Vec::new();
        for (i, &(out, fan_in, scale)) in shapes.iter().enumerate() {
            let bound = scale / (fan_in as f32).sqrt();
            let w = uniform(out * fan_in, bound);
            // The first layer's weights are `[dy][dx][c][h]`: input-major.
            let w = if i == 0 {
                Tensor::from_vec(w, (fan_in, out), &Device::Cpu)?
            } else {
                Tensor::from_vec(w, (out, fan_in), &Device::Cpu)?
            };
            vars.push(Var::from_tensor(&w)?);
            vars.push(Var::from_tensor(&Tensor::from_vec(
                uniform(out, bound),
                out,
                &Device::Cpu,
            )?)?);
        }
        Ok(Filter {
            layer1,
            activation: config.activation,
            input_channels,
            vars,
        })
    }

    pub fn geometry(&self) -> &WindowGeometry {
        &self.layer1.geometry
    }

    fn activate(&self, x: &Tensor) -> Result<Tensor> {
        Ok(match self.activation {
            Activation::LeakyRelu(slope) => x.apply_op1(activation::LeakyRelu(slope))?,
            Activation::Relu => x.apply_op1(activation::LeakyRelu(0.0))?,
            Activation::Gelu => x.gelu()?,
            Activation::Silu => x.silu()?,
        })
    }

    /// Dense layer `index` on `x`, with the filter's activation after every layer but the
    /// output layer.
    fn dense(&self, index: usize, x: &Tensor, layout: WeightLayout) -> Result<Tensor> {
        let (w, b) = (
            self.vars[2 * index].as_tensor(),
            self.vars[2 * index + 1].as_tensor(),
        );
        let output_layer = index + 1 == self.vars.len() / 2;
        let fused = |slope| x.apply_op3(w, b, Dense { slope, layout });
        Ok(match self.activation {
            _ if output_layer => fused(None)?,
            Activation::LeakyRelu(slope) => fused(Some(slope))?,
            Activation::Relu => fused(Some(0.0))?,
            Activation::Gelu | Activation::Silu => self.activate(&fused(None)?)?,
        })
    }

    /// The layers after the first, on the first layer's activations.
    fn after_first(&self, mut x: Tensor) -> Result<Tensor> {
        for index in 1..self.vars.len() / 2 {
            x = self.dense(index, &x, WeightLayout::OutputMajor)?;
        }
        Ok(x)
    }

    /// Raw residuals `[B, 7]` for a batch of upsampled windows `[B][N·N·C]` (training's
    /// input, [`input::UpsampledInput`]), differentiable in every weight.
    pub fn forward(&self, windows: Vec<f32>) -> Result<Tensor> {
        let inputs = self.vars[0].dims()[0];
        let rows = windows.len() / inputs;
        let x = Tensor::from_vec(windows, (rows, inputs), &Device::Cpu)?;
        let first = self.dense(0, &x, WeightLayout::InputMajor)?;
        self.after_first(first)
    }

    /// Raw residuals `[B][7]` for many LR windows with fixed weights (inference): the first
    /// layer is folded once for all of them.
    pub fn infer(
        &self,
        folded: &[Vec<f32>],
        windows: &[f32],
        phases: &[usize],
    ) -> Result<Vec<f32>> {
        let first = self.layer1.apply(folded, windows, phases);
        let first = Tensor::from_vec(first, (phases.len(), self.layer1.hidden), &Device::Cpu)?;
        let first = self.activate(&first.broadcast_add(self.vars[1].as_tensor())?)?;
        Ok(self.after_first(first)?.flatten_all()?.to_vec1::<f32>()?)
    }

    /// The LR windows (`[B][K·K·C]`, [`WindowGeometry::gather`]) and phases of output texels
    /// `batch` of `features` upsampled by the filter's scale, for [`infer`](Self::infer).
    pub fn lr_windows(
        &self,
        features: &Map,
        border: Border,
        batch: &[usize],
    ) -> (Vec<f32>, Vec<usize>) {
        let g = self.geometry();
        let width = features.width() * g.scale;
        let len = g.window_len(self.input_channels.len());
        let mut windows = vec![0f32; batch.len() * len];
        windows
            .par_chunks_mut(len.max(1))
            .zip(batch)
            .for_each(|(out, &t)| {
                let (row, col) = (t / width, t % width);
                g.gather(features, &self.input_channels, border, row, col, out);
            });
        let phases = batch
            .iter()
            .map(|&t| g.phase(t / width, t % width))
            .collect();
        (windows, phases)
    }

    /// The first layer folded per phase with the current weights.
    pub fn folded_weights(&self) -> Result<Vec<Vec<f32>>> {
        Ok(self
            .layer1
            .fold(&self.vars[0].as_tensor().flatten_all()?.to_vec1::<f32>()?))
    }

    /// The weights by name (`w0`, `b0`, `w1`, …), for checkpoints.
    pub fn named_tensors(&self) -> HashMap<String, Tensor> {
        self.vars
            .iter()
            .enumerate()
            .map(|(i, v)| (tensor_name(i), v.as_tensor().clone()))
            .collect()
    }

    /// Restores weights saved by [`named_tensors`](Self::named_tensors).
    pub fn load_tensors(&self, tensors: &HashMap<String, Tensor>, origin: &Path) -> Result<()> {
        for (i, var) in self.vars.iter().enumerate() {
            let key = tensor_name(i);
            let t = tensors
                .get(&key)
                .ok_or_else(|| Error::file(origin, format!("checkpoint lacks tensor {key}")))?;
            if t.shape() != var.shape() || t.dtype() != DType::F32 {
                return Err(Error::file(
                    origin,
                    format!("checkpoint tensor {key} does not fit this filter"),
                ));
            }
            var.set(t)?;
        }
        Ok(())
    }
}

/// `w0`, `b0`, `w1`, `b1`, … for weight and bias of each layer.
pub fn tensor_name(index: usize) -> String {
    format!(
        "{}{}",
        if index.is_multiple_of(2) { "w" } else { "b" },
        index / 2
    )
}

/// A small LR map with variation in every channel, for the window tests.
#[cfg(test)]
pub(crate) fn test_map(width: usize, height: usize, channels: usize) -> Map {
    Map::from_fn(width, height, channels, |c, y, x| {
        ((x * 3 + y * 5 + c * 7) % 11) as f32 / 10.0
    })
}

/// Deterministic values in [−1, 1) for the filter's tests.
#[cfg(test)]
pub(crate) fn pseudo_random(n: usize, seed: u32) -> Vec<f32> {
    (0..n)
        .map(|i| {
            (((i as u32).wrapping_mul(2654435761).wrapping_add(seed) >> 8) % 1000) as f32 / 500.0
                - 1.0
        })
        .collect()
}
