//! Fused per-texel losses as candle ops: render + loss + analytic gradient in one pass over a
//! batch, with nothing of size texels × lights ever stored. One op serves every objective
//! that is a sum of independent per-texel terms.

use std::sync::{Arc, Mutex};

use candle_core::{CpuStorage, CustomOp1, Layout, Shape, Storage, Tensor};
use rayon::prelude::*;

use matup_core::lights::Light;
use matup_core::loss::LossNorm;
use matup_core::shading::{ShadingModel, Svbrdf, Texel};

/// The f32 values of a contiguous CPU tensor, as custom ops receive it (storage and layout).
pub fn contiguous_f32<'a>(
    storage: &'a CpuStorage,
    layout: &Layout,
) -> candle_core::Result<&'a [f32]> {
    match layout.contiguous_offsets() {
        Some((start, end)) => Ok(&storage.as_slice::<f32>()?[start..end]),
        None => candle_core::bail!("matup's ops need contiguous f32 tensors"),
    }
}

/// The f32 values of a contiguous tensor whose storage is on the CPU, read in place (from
/// `Tensor::storage_and_layout`).
pub fn storage_f32<'a>(storage: &'a Storage, layout: &Layout) -> candle_core::Result<&'a [f32]> {
    match storage {
        Storage::Cpu(cpu) => contiguous_f32(cpu, layout),
        _ => candle_core::bail!("matup's ops run on CPU tensors"),
    }
}

/// A loss that is a sum of independent terms, one per texel of a batch, each a function of
/// that texel's row of parameters.
pub trait TexelObjective: Send + Sync {
    /// Parameters per texel (the row width).
    fn width(&self) -> usize;
    /// Texels in the batch.
    fn texels(&self) -> usize;
    /// The loss of texel `i` at parameters `row`; its gradient is written into `grad` (zeroed
    /// on entry, `width()` long).
    fn eval(&self, i: usize, row: &[f32], grad: &mut [f32]) -> f32;
}

/// A [`TexelObjective`] as a candle op: parameters `[B, width]` → per-texel losses `[B]`.
/// The forward pass computes the gradient too and keeps it for the backward pass.
pub struct TexelLossOp<T> {
    objective: T,
    gradient: Mutex<Option<Vec<f32>>>,
}

impl<T: TexelObjective> TexelLossOp<T> {
    pub fn new(objective: T) -> Self {
        TexelLossOp {
            objective,
            gradient: Mutex::new(None),
        }
    }

    fn evaluate(&self, params: &[f32]) -> (Vec<f32>, Vec<f32>) {
        let width = self.objective.width();
        let mut losses = vec![0f32; self.objective.texels()];
        let mut grads = vec![0f32; params.len()];
        losses
            .par_iter_mut()
            .zip(grads.par_chunks_mut(width))
            .zip(params.par_chunks(width))
            .enumerate()
            .for_each(|(i, ((loss, grad), row))| *loss = self.objective.eval(i, row, grad));
        (losses, grads)
    }
}

impl<T: TexelObjective> CustomOp1 for TexelLossOp<T> {
    fn name(&self) -> &'static str {
        "matup-texel-loss"
    }

    fn cpu_fwd(
        &self,
        storage: &CpuStorage,
        layout: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let dims = layout.shape().dims();
        let (b, w) = (self.objective.texels(), self.objective.width());
        if dims != [b, w] {
            candle_core::bail!("texel loss expects [{b}, {w}] parameters, got {dims:?}");
        }
        let (losses, grads) = self.evaluate(contiguous_f32(storage, layout)?);
        *self.gradient.lock().unwrap() = Some(grads);
        Ok((CpuStorage::F32(losses), Shape::from(b)))
    }

    fn bwd(
        &self,
        arg: &Tensor,
        _res: &Tensor,
        grad_res: &Tensor,
    ) -> candle_core::Result<Option<Tensor>> {
        let cached = self.gradient.lock().unwrap().take();
        let grads = match cached {
            Some(g) => g,
            None => self.evaluate(&arg.flatten_all()?.to_vec1::<f32>()?).1,
        };
        let grads = Tensor::from_vec(grads, arg.shape(), arg.device())?;
        Ok(Some(grads.broadcast_mul(&grad_res.unsqueeze(1)?)?))
    }
}

/// Render + loss of texel parameters (rows in [`Svbrdf::to_array`] order):
/// `Σ_ω norm(display(render_ω) − target_ω)` over the lights.
pub struct RenderLoss {
    model: Arc<dyn ShadingModel>,
    lights: Arc<[Light]>,
    /// Position of each texel of the batch.
    positions: Vec<[f32; 3]>,
    /// Display-space target of each texel under each light, texel-major (`B × lights`).
    targets: Vec<[f32; 3]>,
    norm: LossNorm,
}

impl RenderLoss {
    pub fn new(
        model: Arc<dyn ShadingModel>,
        lights: Arc<[Light]>,
        positions: Vec<[f32; 3]>,
        targets: Vec<[f32; 3]>,
        norm: LossNorm,
    ) -> Self {
        assert_eq!(targets.len(), positions.len() * lights.len());
        RenderLoss {
            model,
            lights,
            positions,
            targets,
            norm,
        }
    }
}

impl TexelObjective for RenderLoss {
    fn width(&self) -> usize {
        Svbrdf::LEN
    }
    fn texels(&self) -> usize {
        self.positions.len()
    }
    fn eval(&self, i: usize, row: &[f32], grad: &mut [f32]) -> f32 {
        let lights = self.lights.len();
        let texel = Texel {
            params: Svbrdf::from_array(row.try_into().unwrap()),
            position: self.positions[i],
        };
        let mut g = Svbrdf::default();
        let loss = self.model.texel_loss(
            &texel,
            &self.lights,
            &self.targets[i * lights..(i + 1) * lights],
            &self.norm,
            Some(&mut g),
        );
        grad.copy_from_slice(&g.to_array());
        loss
    }
}
