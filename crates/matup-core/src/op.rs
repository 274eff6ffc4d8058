//! The fused render + loss as a candle op, so training code gets analytic gradients from a
//! [`ShadingModel`] without building texels × lights tensors.

use std::sync::{Arc, Mutex};

use candle_core::{CpuStorage, CustomOp1, Layout, Shape, Tensor};
use rayon::prelude::*;

use crate::lights::Light;
use crate::loss::LossNorm;
use crate::shading::{ShadingModel, Svbrdf, Texel};

/// Maps texel parameters `[B, Svbrdf::LEN]` (in [`Svbrdf::to_array`] order) to each texel's
/// loss `[B]`: `Σ_ω norm(display(render_ω) − target_ω)`. The forward pass computes the
/// gradient too (one fused loop) and keeps it for the backward pass.
pub struct RenderLoss {
    model: Arc<dyn ShadingModel>,
    lights: Arc<[Light]>,
    /// Position of each texel of the batch.
    positions: Vec<[f32; 3]>,
    /// Display-space target of each texel under each light, texel-major (`B × lights`).
    targets: Vec<[f32; 3]>,
    norm: LossNorm,
    gradient: Mutex<Option<Vec<f32>>>,
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
            gradient: Mutex::new(None),
        }
    }

    /// Losses and gradients of a batch of parameters (row-major `B × Svbrdf::LEN`).
    fn evaluate(&self, params: &[f32]) -> (Vec<f32>, Vec<f32>) {
        let lights = self.lights.len();
        let mut losses = vec![0f32; self.positions.len()];
        let mut grads = vec![0f32; params.len()];
        losses
            .par_iter_mut()
            .zip(grads.par_chunks_mut(Svbrdf::LEN))
            .enumerate()
            .for_each(|(i, (loss, grad_out))| {
                let row = &params[i * Svbrdf::LEN..(i + 1) * Svbrdf::LEN];
                let texel = Texel {
                    params: Svbrdf::from_array(row.try_into().unwrap()),
                    position: self.positions[i],
                };
                let mut grad = Svbrdf::default();
                *loss = self.model.texel_loss(
                    &texel,
                    &self.lights,
                    &self.targets[i * lights..(i + 1) * lights],
                    &self.norm,
                    Some(&mut grad),
                );
                grad_out.copy_from_slice(&grad.to_array());
            });
        (losses, grads)
    }
}

impl CustomOp1 for RenderLoss {
    fn name(&self) -> &'static str {
        "matup-render-loss"
    }

    fn cpu_fwd(
        &self,
        storage: &CpuStorage,
        layout: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let dims = layout.shape().dims();
        if dims.len() != 2 || dims[1] != Svbrdf::LEN || dims[0] != self.positions.len() {
            candle_core::bail!(
                "render loss expects [{}, {}] parameters, got {:?}",
                self.positions.len(),
                Svbrdf::LEN,
                dims
            );
        }
        let Some((start, end)) = layout.contiguous_offsets() else {
            candle_core::bail!("render loss needs contiguous parameters");
        };
        let params = &storage.as_slice::<f32>()?[start..end];
        let (losses, grads) = self.evaluate(params);
        *self.gradient.lock().unwrap() = Some(grads);
        Ok((CpuStorage::F32(losses), Shape::from(dims[0])))
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
            None => {
                let params = arg.flatten_all()?.to_vec1::<f32>()?;
                self.evaluate(&params).1
            }
        };
        let grads = Tensor::from_vec(grads, (self.positions.len(), Svbrdf::LEN), arg.device())?;
        Ok(Some(grads.broadcast_mul(&grad_res.unsqueeze(1)?)?))
    }
}
