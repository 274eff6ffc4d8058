//! The fused CPU backend: the render loss and its hand-derived gradient per texel
//! ([`TexelLossOp`]), the LR-consistency term as its own op, and a hand-written Adam, with
//! each thread taking its part of every batch forward and backward.

use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex};

use candle_core::{CpuStorage, Layout, Tensor};
use rayon::prelude::*;

use super::adam::FusedAdam;
use super::examples::Examples;
use super::stepper::{CrossBatch, LossTerms, Shading, Stepper};
use crate::filter::decode::decode;
use crate::filter::{Filter, FEATURES};
use crate::texel_loss_op::{contiguous_f32, TexelLossOp, TexelObjective};
use matup_core::material::texel_position;
use matup_core::shading::{Svbrdf, Texel};
use matup_core::Result;

/// Steps on the CPU with the fused ops, training the filter's own weights.
pub(super) struct FusedStepper<'a> {
    filter: &'a Filter,
    main: &'a Arc<Examples>,
    terms: &'a LossTerms<'a>,
    /// Texels per group of the consistency term (1 without it), and its weight β.
    group: usize,
    consistency_weight: Option<f32>,
    /// Texels per step (the objective is evaluated in chunks of as many).
    batch: usize,
    adam: FusedAdam,
}

impl<'a> FusedStepper<'a> {
    pub(super) fn new(
        filter: &'a Filter,
        main: &'a Arc<Examples>,
        terms: &'a LossTerms<'a>,
        group: usize,
        consistency_weight: Option<f32>,
        batch: usize,
    ) -> FusedStepper<'a> {
        FusedStepper {
            filter,
            main,
            terms,
            group,
            consistency_weight,
            batch,
            adam: FusedAdam::new(&filter.vars),
        }
    }
}

impl Stepper for FusedStepper<'_> {
    fn step(&mut self, indices: &[usize], cross: Option<CrossBatch>, lr: f64) -> Result<f64> {
        let (filter, main, terms, group) = (self.filter, self.main, self.terms, self.group);
        // The batch in one part per thread, each run forward and backward on its own: the
        // loss is a sum over texels, so the parts' gradients add up to the batch's, and the
        // threads meet once a step instead of in every op. Parts hold whole groups.
        let groups = indices.len() / group;
        let parts = rayon::current_num_threads().min(groups).max(1);
        let share = |items: usize, part: usize, unit: usize| {
            unit * (items * part / parts)..unit * (items * (part + 1) / parts)
        };
        let consistency = self.consistency_weight.map(|w| (w, groups));
        let results = (0..parts)
            .into_par_iter()
            .map(|part| -> Result<(f64, candle_core::backprop::GradStore)> {
                let mut loss = batch_loss(
                    filter,
                    main,
                    terms,
                    &indices[share(groups, part, group)],
                    indices.len(),
                    consistency,
                )?;
                if let Some(c) = &cross {
                    let extra = batch_loss(
                        filter,
                        c.examples,
                        terms,
                        &c.texels[share(c.texels.len(), part, 1)],
                        c.texels.len(),
                        None,
                    )?;
                    loss = (loss + extra.affine(c.weight as f64, 0.0)?)?;
                }
                Ok((loss.to_scalar::<f32>()? as f64, loss.backward()?))
            })
            .collect::<Result<Vec<_>>>()?;
        let (values, grads): (Vec<f64>, Vec<_>) = results.into_iter().unzip();
        let value: f64 = values.iter().sum();
        if value.is_finite() {
            self.adam.update(&filter.vars, &grads, lr)?;
        }
        Ok(value)
    }

    fn objective(&self, texels: &[usize]) -> Result<f64> {
        let sums = texels
            .par_chunks(self.batch)
            .map(|chunk| -> Result<f64> {
                let consistency = self
                    .consistency_weight
                    .map(|w| (w, chunk.len() / self.group));
                let loss = batch_loss(
                    self.filter,
                    self.main,
                    self.terms,
                    chunk,
                    chunk.len(),
                    consistency,
                )?;
                Ok(loss.to_scalar::<f32>()? as f64 * chunk.len() as f64)
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(sums.iter().sum::<f64>() / texels.len().max(1) as f64)
    }

    fn steps(&self) -> u64 {
        self.adam.step
    }

    fn state(&self) -> Result<HashMap<String, Tensor>> {
        let mut state = self.filter.named_tensors();
        state.extend(self.adam.tensors()?);
        Ok(state)
    }

    fn restore(
        &mut self,
        state: &HashMap<String, Tensor>,
        steps: u64,
        origin: &Path,
    ) -> Result<()> {
        self.filter.load_tensors(state, origin)?;
        self.adam.restore(state, steps, origin)
    }

    fn finish(&self) -> Result<()> {
        Ok(())
    }
}

thread_local! {
    static TARGETS: std::cell::RefCell<Vec<[f32; 3]>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// METHOD.md's objective for one batch: per texel, the render loss over the lights divided by
/// their number, plus the prior `Σ_k w_k (f_k − base_k)²` (the paper's metallic regulariser
/// when only metallic is weighted and the base is bilinear).
struct FilterObjective {
    examples: Arc<Examples>,
    shading: Shading,
    batch: Vec<usize>,
    fixed: [Option<f32>; FEATURES],
    prior: [f32; FEATURES],
}

impl TexelObjective for FilterObjective {
    fn width(&self) -> usize {
        FEATURES
    }
    fn texels(&self) -> usize {
        self.batch.len()
    }
    fn eval(&self, i: usize, row: &[f32], grad: &mut [f32]) -> f32 {
        let ex = &self.examples;
        let t = self.batch[i];
        let base: [f32; FEATURES] = ex.residual_base.texel(t);
        let decoded = decode(row, &base, &self.fixed);
        let texel = Texel {
            params: decoded.params,
            position: texel_position(t, ex.width, ex.height, ex.heights.as_ref()),
        };
        let mut g = Svbrdf::default();
        let scale = 1.0 / self.shading.lights.len() as f32;
        // The targets of one texel as f32, in a buffer each thread reuses.
        let fit = TARGETS.with(|buffer| {
            let mut targets = buffer.borrow_mut();
            ex.targets.texel(t, &mut targets);
            self.shading.model.texel_loss(
                &texel,
                &self.shading.lights,
                &targets,
                &self.shading.norm,
                Some(&mut g),
            )
        });
        let mut g_scaled = Svbrdf::default();
        g_scaled.add_scaled(&g, scale);
        let (prior, prior_grad) = prior_term(&decoded.features(), &base, &self.prior, &self.fixed);
        g_scaled.add_scaled(&feature_gradient(&prior_grad), 1.0);
        grad.copy_from_slice(&decoded.backward(&g_scaled));
        fit * scale + prior
    }
}

/// `Σ_k w_k (f_k − base_k)²` over the learned features, and its gradient in `f`.
#[inline]
fn prior_term(
    features: &[f32; FEATURES],
    base: &[f32; FEATURES],
    weights: &[f32; FEATURES],
    fixed: &[Option<f32>; FEATURES],
) -> (f32, [f32; FEATURES]) {
    let mut value = 0.0;
    let mut grad = [0f32; FEATURES];
    for k in (0..FEATURES).filter(|&k| weights[k] != 0.0 && fixed[k].is_none()) {
        let d = features[k] - base[k];
        value += weights[k] * d * d;
        grad[k] = 2.0 * weights[k] * d;
    }
    (value, grad)
}

/// A gradient over the 7 features as one over the shading parameters they decode to.
#[inline]
fn feature_gradient(g: &[f32; FEATURES]) -> Svbrdf {
    Svbrdf {
        base_color: [g[0], g[1], g[2]],
        metallic: g[3],
        normal: [g[4], g[5], 0.0],
        alpha: g[6],
        ..Default::default()
    }
}

/// The LR-consistency term for groups of `scale²` output texels that make up whole LR
/// texels: `mean_groups ‖box(decoded features) − LR features‖²` over the 7 features. Not a
/// sum of per-texel terms (a group's mean couples its texels), so it has its own op. It reads
/// the same filter outputs as the render loss: batches are drawn as whole groups, so the term
/// costs no forward pass of its own.
struct Consistency {
    examples: Arc<Examples>,
    /// Output texels, `group_size` consecutive ones per LR texel.
    batch: Vec<usize>,
    group_size: usize,
    /// Groups in the whole step (this op may see a part of them): the loss is their mean.
    step_groups: usize,
    fixed: [Option<f32>; FEATURES],
    gradient: Mutex<Option<Vec<f32>>>,
}

impl candle_core::CustomOp1 for Consistency {
    fn name(&self) -> &'static str {
        "matup-lr-consistency"
    }

    fn cpu_fwd(
        &self,
        storage: &CpuStorage,
        layout: &Layout,
    ) -> candle_core::Result<(CpuStorage, candle_core::Shape)> {
        let raw = contiguous_f32(storage, layout)?;
        let ex = &self.examples;
        let n = self.group_size;
        let mut grads = vec![0f32; raw.len()];
        let mut total = 0.0f32;
        for (g, members) in self.batch.chunks_exact(n).enumerate() {
            let decoded: Vec<_> = members
                .iter()
                .enumerate()
                .map(|(j, &t)| {
                    let base: [f32; FEATURES] = ex.residual_base.texel(t);
                    decode(
                        &raw[(g * n + j) * FEATURES..][..FEATURES],
                        &base,
                        &self.fixed,
                    )
                })
                .collect();
            let want: [f32; FEATURES] = ex.features.texel(ex.parent(members[0]));
            let mut diff = [0f32; FEATURES];
            for d in &decoded {
                let f = d.features();
                for k in 0..FEATURES {
                    diff[k] += f[k] / n as f32;
                }
            }
            for k in 0..FEATURES {
                diff[k] -= want[k];
                total += diff[k] * diff[k];
            }
            // d/d(feature of member j) = 2·diff / n, then through the decode.
            let up = feature_gradient(&diff.map(|d| 2.0 * d / n as f32));
            for (j, d) in decoded.iter().enumerate() {
                grads[(g * n + j) * FEATURES..][..FEATURES].copy_from_slice(&d.backward(&up));
            }
        }
        let groups = self.step_groups.max(1) as f32;
        grads.iter_mut().for_each(|v| *v /= groups);
        *self.gradient.lock().unwrap() = Some(grads);
        Ok((
            CpuStorage::F32(vec![total / groups]),
            candle_core::Shape::from(()),
        ))
    }

    fn bwd(
        &self,
        arg: &Tensor,
        _res: &Tensor,
        grad_res: &Tensor,
    ) -> candle_core::Result<Option<Tensor>> {
        let grads = self
            .gradient
            .lock()
            .unwrap()
            .take()
            .expect("forward ran before backward");
        let grads = Tensor::from_vec(grads, arg.shape(), arg.device())?;
        Ok(Some(grads.broadcast_mul(grad_res)?))
    }
}

/// The objective over texels `indices`, a part of a batch of `batch` texels, as their share
/// of the batch's mean: a differentiable scalar. With `consistency = (β, groups)`, `indices`
/// are whole groups of the step's `groups` and the LR-consistency term is added, weighted β.
fn batch_loss(
    filter: &Filter,
    examples: &Arc<Examples>,
    terms: &LossTerms,
    indices: &[usize],
    batch: usize,
    consistency: Option<(f32, usize)>,
) -> Result<Tensor> {
    let raw = filter.forward(examples.windows(indices))?;
    let objective = FilterObjective {
        examples: examples.clone(),
        shading: terms.shading.clone(),
        batch: indices.to_vec(),
        fixed: terms.fixed,
        prior: terms.prior,
    };
    let losses = raw.apply_op1(TexelLossOp::new(objective))?;
    let loss = losses.sum_all()?.affine(1.0 / batch as f64, 0.0)?;
    Ok(match consistency {
        Some((weight, step_groups)) if !indices.is_empty() => {
            let term = raw.apply_op1(Consistency {
                examples: examples.clone(),
                batch: indices.to_vec(),
                group_size: examples.scale().pow(2),
                step_groups,
                fixed: terms.fixed,
                gradient: Mutex::new(None),
            })?;
            (loss + term.affine(weight as f64, 0.0)?)?
        }
        _ => loss,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_prior_weighs_each_learned_feature_toward_the_base() {
        let f = [0.5, 0.5, 0.5, 0.9, 0.2, -0.1, 0.3];
        let base = [0.4, 0.5, 0.7, 0.5, 0.2, 0.1, 0.3];
        let weights = crate::config::PriorConfig {
            base_color: 1.0,
            metallic: 0.1,
            normal: 2.0,
            roughness: 5.0,
        }
        .feature_weights();
        let (value, grad) = prior_term(&f, &base, &weights, &[None; FEATURES]);
        // 1·(0.1² + 0.2²) + 0.1·0.4² + 2·0.2² = 0.05 + 0.016 + 0.08.
        assert!((value - 0.146).abs() < 1e-6, "{value}");
        let want = [0.2, 0.0, -0.4, 0.08, 0.0, -0.8, 0.0];
        for (g, w) in grad.iter().zip(want) {
            assert!((g - w).abs() < 1e-6, "{grad:?}");
        }
        // A constant feature is held, not pulled.
        let mut fixed = [None; FEATURES];
        fixed[3] = Some(0.9);
        let (held, grad) = prior_term(&f, &base, &weights, &fixed);
        assert!((held - 0.13).abs() < 1e-6 && grad[3] == 0.0, "{held}");
    }
}
