//! Adam (Kingma & Ba 2015, default betas), the optimiser of every training matup does, in
//! two forms of the same mathematics: [`Adam`], candle operations on any device (matup
//! learn's networks, the tensor backend's filter), and [`FusedAdam`], one pass per weight
//! over the CPU's storage (the fused backend, whose gradient comes in one part per thread:
//! it sums them as it updates, where the candle form would first add them up as tensors).

use std::collections::HashMap;
use std::path::Path;
use std::sync::Mutex;

use candle_core::backprop::GradStore;
use candle_core::{CpuStorage, Device, InplaceOp1, Layout, Tensor, Var};
use rayon::prelude::*;

use crate::texel_loss_op::storage_f32;
use matup_core::{Error, Result};
use matup_simd::with_avx2;

const BETA1: f64 = 0.9;
const BETA2: f64 = 0.999;
const EPSILON: f64 = 1e-8;
// The same, in the fused form's f32.
const BETA1_F32: f32 = 0.9;
const BETA2_F32: f32 = 0.999;
const EPSILON_F32: f32 = 1e-8;

/// Adam as candle operations over a network's tensors, on any device; its moments are
/// public, for checkpoints. With an anchor, each step also pulls the weights toward where
/// they started (matup learn's `anchor_weight`).
pub struct Adam {
    pub m: Vec<Tensor>,
    pub v: Vec<Tensor>,
    pub step: usize,
    pub learning_rate: f64,
    /// The starting weights and the pull's weight.
    anchor: Option<(Vec<Tensor>, f64)>,
}

impl Adam {
    /// For `vars` as they are now (the base model's weights, the anchor's start).
    pub fn new(vars: &[Var], learning_rate: f64, anchor_weight: f64) -> candle_core::Result<Adam> {
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

    /// One step of every variable of `vars` (those [`Adam::new`] was given, in its order)
    /// that has a gradient in `grads`; one without (a frozen one) is left as it is.
    pub fn update(&mut self, vars: &[Var], grads: &GradStore) -> candle_core::Result<()> {
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

/// Adam fused into one pass per weight tensor over the CPU's f32 storage, summing the
/// gradient's parts (one per thread's share of the batch) as it goes: the fused backend's.
/// Its moments are checkpointed, so a resumed run equals an uninterrupted one.
pub struct FusedAdam {
    pub step: u64,
    moments: Vec<Mutex<(Vec<f32>, Vec<f32>)>>,
}

/// Elements per parallel task of the update.
const ADAM_CHUNK: usize = 4096;

struct AdamUpdate<'a> {
    /// The gradient in parts (one per part of the batch), summed here.
    grads: &'a [&'a [f32]],
    moments: &'a Mutex<(Vec<f32>, Vec<f32>)>,
    learning_rate: f32,
    step: u64,
}

impl InplaceOp1 for AdamUpdate<'_> {
    fn name(&self) -> &'static str {
        "matup-adam"
    }
    fn cpu_fwd(&self, storage: &mut CpuStorage, layout: &Layout) -> candle_core::Result<()> {
        let Some((start, end)) = layout.contiguous_offsets() else {
            candle_core::bail!("adam needs contiguous weights");
        };
        let CpuStorage::F32(weights) = storage else {
            candle_core::bail!("adam needs f32 weights");
        };
        let weights = &mut weights[start..end];
        let mut guard = self.moments.lock().unwrap();
        let (m, v) = &mut *guard;
        let c1 = 1.0 - BETA1_F32.powi(self.step as i32);
        let c2 = 1.0 - BETA2_F32.powi(self.step as i32);
        // w -= lr·(m/c1) / (√(v/c2) + ε), with the bias corrections as factors.
        let (step_size, v_scale) = (self.learning_rate / c1, 1.0 / c2);
        weights
            .par_chunks_mut(ADAM_CHUNK)
            .zip(
                m.par_chunks_mut(ADAM_CHUNK)
                    .zip(v.par_chunks_mut(ADAM_CHUNK)),
            )
            .enumerate()
            .for_each(|(k, (w, (m, v)))| {
                let range = k * ADAM_CHUNK..k * ADAM_CHUNK + w.len();
                let mut sum = [0f32; ADAM_CHUNK];
                let g = &mut sum[..w.len()];
                g.copy_from_slice(&self.grads[0][range.clone()]);
                for p in &self.grads[1..] {
                    g.iter_mut()
                        .zip(&p[range.clone()])
                        .for_each(|(g, p)| *g += p);
                }
                with_avx2!(adam_chunk(w, g, m, v, step_size, v_scale));
            });
        Ok(())
    }
}

/// Adam's update of one chunk of weights (zipped, not indexed: without bounds checks the
/// loop vectorises).
#[inline(always)]
fn adam_chunk(
    w: &mut [f32],
    g: &[f32],
    m: &mut [f32],
    v: &mut [f32],
    step_size: f32,
    v_scale: f32,
) {
    for (((w, g), m), v) in w.iter_mut().zip(g).zip(m).zip(v) {
        *m = BETA1_F32 * *m + (1.0 - BETA1_F32) * g;
        *v = BETA2_F32 * *v + (1.0 - BETA2_F32) * g * g;
        *w -= step_size * *m / ((*v * v_scale).sqrt() + EPSILON_F32);
    }
}

impl FusedAdam {
    pub fn new(vars: &[Var]) -> FusedAdam {
        FusedAdam {
            step: 0,
            moments: vars
                .iter()
                .map(|v| Mutex::new((vec![0.0; v.elem_count()], vec![0.0; v.elem_count()])))
                .collect(),
        }
    }

    /// One update of every weight from its gradient, the sum of its parts in `parts`.
    pub fn update(
        &mut self,
        vars: &[Var],
        parts: &[candle_core::backprop::GradStore],
        learning_rate: f64,
    ) -> Result<()> {
        self.step += 1;
        for (var, moments) in vars.iter().zip(&self.moments) {
            let grads = (parts.iter())
                .filter_map(|p| p.get(var.as_tensor()))
                .map(|g| g.contiguous())
                .collect::<candle_core::Result<Vec<_>>>()?;
            if grads.is_empty() {
                continue;
            }
            let storages: Vec<_> = grads.iter().map(|g| g.storage_and_layout()).collect();
            let slices = (storages.iter())
                .map(|(storage, layout)| storage_f32(storage, layout))
                .collect::<candle_core::Result<Vec<_>>>()?;
            let update = AdamUpdate {
                grads: &slices,
                moments,
                learning_rate: learning_rate as f32,
                step: self.step,
            };
            var.as_tensor().inplace_op1(&update)?;
        }
        Ok(())
    }

    pub(super) fn tensors(&self) -> Result<HashMap<String, Tensor>> {
        let mut out = HashMap::new();
        for (i, m) in self.moments.iter().enumerate() {
            let (m, v) = &*m.lock().unwrap();
            out.insert(
                format!("adam_m{i}"),
                Tensor::from_slice(m, m.len(), &Device::Cpu)?,
            );
            out.insert(
                format!("adam_v{i}"),
                Tensor::from_slice(v, v.len(), &Device::Cpu)?,
            );
        }
        Ok(out)
    }

    pub(super) fn restore(
        &mut self,
        tensors: &HashMap<String, Tensor>,
        step: u64,
        origin: &Path,
    ) -> Result<()> {
        for (i, slot) in self.moments.iter().enumerate() {
            let get = |k: String| -> Result<Vec<f32>> {
                let t = tensors
                    .get(&k)
                    .ok_or_else(|| Error::file(origin, format!("checkpoint lacks {k}")))?;
                Ok(t.to_vec1::<f32>()?)
            };
            let (m, v) = (get(format!("adam_m{i}"))?, get(format!("adam_v{i}"))?);
            let mut guard = slot.lock().unwrap();
            if m.len() != guard.0.len() || v.len() != guard.1.len() {
                return Err(Error::file(
                    origin,
                    "checkpoint optimiser state does not fit this filter",
                ));
            }
            *guard = (m, v);
        }
        self.step = step;
        Ok(())
    }
}
