//! The per-material filter: an MLP reading a window of upsampled LR maps around each output
//! texel and answering a residual on its 7 features (METHOD.md).

pub mod activation;
pub mod decode;
pub mod dense;
pub mod folded;
pub mod geometry;

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use candle_core::{DType, Device, Tensor, Var};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use crate::config::{Activation, FilterConfig};
use crate::{Error, Result};
use dense::Dense;
use folded::{FoldedLayer, FoldedLinear};
use geometry::WindowGeometry;

/// The features the filter reads and answers, per texel: linear base colour (3), metallic,
/// normal x and y, alpha.
pub const FEATURES: usize = 7;
pub const FEATURE_NAMES: [&str; FEATURES] = [
    "base_r", "base_g", "base_b", "metallic", "normal_x", "normal_y", "alpha",
];

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
            let w = if i == 0 {
                Tensor::from_vec(w, layer1.weight_len(), &Device::Cpu)?
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

    /// Everything after the first layer's matrix product: its bias, then the other layers.
    fn tail(&self, first: Tensor) -> Result<Tensor> {
        let mut x = self.activate(&first.broadcast_add(self.vars[1].as_tensor())?)?;
        let layers = self.vars.len() / 2;
        for layer in 1..layers {
            let (w, b) = (
                self.vars[2 * layer].as_tensor(),
                self.vars[2 * layer + 1].as_tensor(),
            );
            x = if layer + 1 == layers {
                x.apply_op3(w, b, Dense { slope: None })?
            } else {
                match self.activation {
                    Activation::LeakyRelu(slope) => {
                        x.apply_op3(w, b, Dense { slope: Some(slope) })?
                    }
                    Activation::Relu => x.apply_op3(w, b, Dense { slope: Some(0.0) })?,
                    Activation::Gelu | Activation::Silu => {
                        self.activate(&x.apply_op3(w, b, Dense { slope: None })?)?
                    }
                }
            };
        }
        Ok(x)
    }

    /// Raw residuals `[B, 7]` for a batch of gathered windows, differentiable in every weight.
    pub fn forward(&self, windows: Arc<Vec<f32>>, phases: Arc<Vec<usize>>) -> Result<Tensor> {
        let first = self.vars[0].as_tensor().apply_op1(FoldedLinear {
            layer: self.layer1.clone(),
            windows,
            phases,
        })?;
        self.tail(first)
    }

    /// Raw residuals `[B][7]` for many windows with fixed weights (inference): the first layer
    /// is folded once for all of them.
    pub fn infer(
        &self,
        folded: &[Vec<f32>],
        windows: &[f32],
        phases: &[usize],
    ) -> Result<Vec<f32>> {
        let first = self.layer1.apply(folded, windows, phases);
        let first = Tensor::from_vec(first, (phases.len(), self.layer1.hidden), &Device::Cpu)?;
        Ok(self.tail(first)?.flatten_all()?.to_vec1::<f32>()?)
    }

    /// The first layer folded per phase with the current weights.
    pub fn folded_weights(&self) -> Result<Vec<Vec<f32>>> {
        Ok(self
            .layer1
            .fold(&self.vars[0].as_tensor().to_vec1::<f32>()?))
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
    format!("{}{}", if index % 2 == 0 { "w" } else { "b" }, index / 2)
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
