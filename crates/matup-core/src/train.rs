//! Training the filter: examples, the fused objective, Adam, the epoch loop, checkpoints.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use candle_core::{CpuStorage, Device, InplaceOp1, Layout, Tensor, Var};
use rand::rngs::StdRng;
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::config::{EarlyStopConfig, Schedule, TrainConfig};
use crate::filter::decode::decode;
use crate::filter::input::UpsampledInput;
use crate::filter::{Filter, FEATURES};
use crate::lights::Light;
use crate::loss::LossNorm;
use crate::map::Map;
use crate::material::texel_position;
use crate::op::{contiguous_f32, storage_f32, TexelLossOp, TexelObjective};
use crate::progress::Progress;
use crate::resample::Border;
use crate::shading::{ShadingModel, Svbrdf, Texel};
use crate::targets::Targets;
use crate::{with_avx2, Error, Result};

/// Training examples at one scale: the filter's inputs and what its answers are judged by.
pub struct Examples {
    /// The 7 features of the input material (the LR-consistency term's reference).
    pub features: Map,
    /// The filter's input features upsampled to the output size (its windows are read here).
    pub input: UpsampledInput,
    /// Output size.
    pub width: usize,
    pub height: usize,
    /// The 7 features at the output size that residuals are added to, and that the prior
    /// pulls toward.
    pub residual_base: Arc<Map>,
    /// Output-size height, if the material has one (displaces the shading points).
    pub heights: Option<Map>,
    pub targets: Targets,
}

impl Examples {
    /// The examples of `filter` on input `features`: its windows read from `features`
    /// upsampled as the filter says, its answers added to `residual_base`, the shading points
    /// displaced by `heights` (output size), judged against `targets`.
    pub fn new(
        features: &Map,
        residual_base: Arc<Map>,
        heights: Option<Map>,
        targets: Targets,
        filter: &Filter,
        border: Border,
    ) -> Examples {
        let scale = filter.geometry().scale;
        Examples {
            input: UpsampledInput::new(features, &filter.input_channels, border, filter.geometry()),
            width: features.width() * scale,
            height: features.height() * scale,
            features: features.clone(),
            residual_base,
            heights,
            targets,
        }
    }

    pub fn texels(&self) -> usize {
        self.width * self.height
    }

    /// The filter's input windows (`[B][N·N·C]`) of output texels `batch`.
    pub fn windows(&self, batch: &[usize]) -> Vec<f32> {
        let mut windows = Vec::with_capacity(batch.len() * self.input.window_len());
        for &t in batch {
            self.input
                .push_window(t / self.width, t % self.width, &mut windows);
        }
        windows
    }

    /// The scale from the input features to the output.
    fn scale(&self) -> usize {
        self.width / self.features.width()
    }

    /// The `scale²` output texels covering each of the input texels `parents`, a group per
    /// parent, row by row.
    fn children(&self, parents: &[usize]) -> Vec<usize> {
        let s = self.scale();
        let lw = self.features.width();
        let mut out = Vec::with_capacity(parents.len() * s * s);
        for &p in parents {
            let (py, px) = (p / lw, p % lw);
            for dy in 0..s {
                for dx in 0..s {
                    out.push((py * s + dy) * self.width + px * s + dx);
                }
            }
        }
        out
    }

    /// `units` as output texels: themselves for groups of 1, else the children of each
    /// input texel.
    fn children_of(&self, units: &[usize], group: usize) -> Vec<usize> {
        if group > 1 {
            self.children(units)
        } else {
            units.to_vec()
        }
    }

    /// The input texel an output texel lies in.
    fn parent(&self, texel: usize) -> usize {
        let s = self.scale();
        (texel / self.width / s) * self.features.width() + (texel % self.width) / s
    }
}

/// What the renders are compared with, and how.
#[derive(Clone)]
pub struct Shading {
    pub model: Arc<dyn ShadingModel>,
    pub lights: Arc<[Light]>,
    pub norm: LossNorm,
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

/// Adam (Kingma & Ba, default betas), fused into one pass per weight tensor. Hand-written
/// so its state can be checkpointed (a resumed run equals an uninterrupted one).
pub struct Adam {
    pub step: u64,
    moments: Vec<Mutex<(Vec<f32>, Vec<f32>)>>,
}

const BETA1: f32 = 0.9;
const BETA2: f32 = 0.999;
const EPSILON: f32 = 1e-8;

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
        let c1 = 1.0 - BETA1.powi(self.step as i32);
        let c2 = 1.0 - BETA2.powi(self.step as i32);
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
        *m = BETA1 * *m + (1.0 - BETA1) * g;
        *v = BETA2 * *v + (1.0 - BETA2) * g * g;
        *w -= step_size * *m / ((*v * v_scale).sqrt() + EPSILON);
    }
}

impl Adam {
    pub fn new(vars: &[Var]) -> Adam {
        Adam {
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

    fn tensors(&self) -> Result<HashMap<String, Tensor>> {
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

    fn restore(
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

/// Where a run keeps its per-epoch checkpoint, and whether to continue from it.
#[derive(Clone, Debug)]
pub struct Checkpoint {
    pub folder: PathBuf,
    pub resume: bool,
    /// What must match for a checkpoint to be resumed (the configuration and input).
    pub fingerprint: String,
}

#[derive(Serialize, Deserialize)]
struct CheckpointMeta {
    fingerprint: String,
    epochs_done: usize,
    adam_step: u64,
    epoch_losses: Vec<f64>,
    #[serde(default)]
    validation: Validation,
}

impl Checkpoint {
    fn weights_path(&self) -> PathBuf {
        self.folder.join("state.safetensors")
    }
    fn meta_path(&self) -> PathBuf {
        self.folder.join("state.json")
    }

    /// Writes the state atomically (weights first, then the metadata that points at them).
    fn save(&self, filter: &Filter, adam: &Adam, meta: &CheckpointMeta) -> Result<()> {
        std::fs::create_dir_all(&self.folder).map_err(|e| Error::io(&self.folder, e))?;
        let mut tensors = filter.named_tensors();
        tensors.extend(adam.tensors()?);
        let tmp = self.folder.join("state.safetensors.partial");
        candle_core::safetensors::save(&tensors, &tmp)?;
        std::fs::rename(&tmp, self.weights_path())
            .map_err(|e| Error::io(&self.weights_path(), e))?;
        let json = serde_json::to_vec_pretty(meta).expect("checkpoint metadata serialises");
        crate::io::write_atomic(&self.meta_path(), &json)
    }

    /// The saved state, if there is one for this fingerprint.
    fn load(&self, filter: &Filter, adam: &mut Adam) -> Result<Option<CheckpointMeta>> {
        let Ok(bytes) = std::fs::read(self.meta_path()) else {
            return Ok(None);
        };
        let meta: CheckpointMeta = serde_json::from_slice(&bytes)
            .map_err(|e| Error::file(&self.meta_path(), format!("unreadable checkpoint: {e}")))?;
        if meta.fingerprint != self.fingerprint {
            return Ok(None);
        }
        let tensors = candle_core::safetensors::load(self.weights_path(), &Device::Cpu)?;
        filter.load_tensors(&tensors, &self.weights_path())?;
        adam.restore(&tensors, meta.adam_step, &self.weights_path())?;
        Ok(Some(meta))
    }

    /// Removes the checkpoint (after a finished run).
    pub fn clear(&self) {
        let _ = std::fs::remove_dir_all(&self.folder);
    }
}

/// The outcome of training.
#[derive(Clone, Debug, Default, Serialize)]
pub struct TrainStats {
    /// Mean loss of each epoch (the last over the part trained, if it stopped early).
    pub epoch_losses: Vec<f64>,
    pub steps: u64,
    /// Epochs trained, in fractions where training stopped within an epoch.
    pub epochs_trained: f64,
    /// Why training ended.
    pub stopped: Stop,
    /// The objective on the held-out texels at each check (empty without early stopping).
    pub validation_losses: Vec<f64>,
    /// Epochs taken from a checkpoint instead of trained.
    pub resumed_epochs: usize,
}

/// Why training ended.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Stop {
    /// Nothing was trained.
    #[default]
    NotTrained,
    /// Every epoch of `train.epochs` ran.
    MaxEpochs,
    /// The validation loss stopped improving.
    Converged,
}

impl std::fmt::Display for Stop {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Stop::NotTrained => "not trained",
            Stop::MaxEpochs => "ran every epoch",
            Stop::Converged => "converged (the validation loss stopped improving)",
        })
    }
}

/// Early stopping's state: the checks so far, the best value and the checks since it.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
struct Validation {
    losses: Vec<f64>,
    best: Option<f64>,
    stale: usize,
}

impl Validation {
    /// Records a check; true when training should stop.
    fn record(&mut self, loss: f64, config: &EarlyStopConfig) -> bool {
        self.losses.push(loss);
        match self.best {
            Some(best) if loss > best * (1.0 - config.min_gain) => self.stale += 1,
            _ => {
                self.best = Some(loss);
                self.stale = 0;
            }
        }
        self.converged(config)
    }

    fn converged(&self, config: &EarlyStopConfig) -> bool {
        self.stale >= config.patience
    }
}

/// Trains `filter` on `main` (and, with weight `cross_weight`, on `cross`): METHOD.md's loop,
/// every texel once per epoch in an order drawn from `seed`, for `config.epochs` or, with
/// early stopping, until the objective on held-out texels (never trained on) stops improving.
#[allow(clippy::too_many_arguments)]
pub fn train(
    filter: &Filter,
    main: &Arc<Examples>,
    cross: Option<(&Arc<Examples>, f32)>,
    shading: &Shading,
    fixed: [Option<f32>; FEATURES],
    config: &TrainConfig,
    seed: u64,
    checkpoint: Option<&Checkpoint>,
    progress: &dyn Progress,
) -> Result<TrainStats> {
    let mut adam = Adam::new(&filter.vars);
    let mut stats = TrainStats::default();
    let mut validation = Validation::default();
    let mut start_epoch = 0;
    if let Some(cp) = checkpoint.filter(|c| c.resume) {
        if let Some(meta) = cp.load(filter, &mut adam)? {
            progress.note(&format!(
                "resumed from the checkpoint after epoch {}",
                meta.epochs_done
            ));
            start_epoch = meta.epochs_done;
            stats.epoch_losses = meta.epoch_losses;
            stats.resumed_epochs = start_epoch;
            validation = meta.validation;
        }
    }

    // With the LR-consistency term, batches are made of whole LR texels (groups of scale²
    // output texels), so the term reads the render loss's own forward pass.
    let group = if config.lr_consistency > 0.0 {
        main.scale().pow(2)
    } else {
        1
    };
    let consistency_weight = (group > 1).then_some(config.lr_consistency);
    let units = main.texels() / group;
    // Early stopping's held-out units: drawn once from the seed, never trained on.
    let early_stop = config.early_stop.enabled.then_some(&config.early_stop);
    let (held_out, trained_units) = match early_stop {
        Some(e) => split_validation(units, e.validation_texels.div_ceil(group), seed),
        None => (Vec::new(), (0..units).collect()),
    };
    let held_out = main.children_of(&held_out, group);
    let per_epoch = config
        .texels_per_epoch
        .map_or(trained_units.len(), |t| t.div_ceil(group))
        .min(trained_units.len());
    let batch_units = config.batch_size.div_ceil(group);
    let batch = batch_units * group;
    let steps_per_epoch = per_epoch.div_ceil(batch_units);
    let total_steps = (steps_per_epoch * config.epochs) as u64;
    let base_lr = if config.scale_learning_rate {
        config.learning_rate * batch as f64 / 128.0
    } else {
        config.learning_rate
    };
    let terms = LossTerms {
        shading,
        fixed,
        prior: config.prior.feature_weights(),
    };
    progress.stage("train", total_steps);
    progress.advance(adam.step, stats.epoch_losses.last().copied());

    let mut stopped = early_stop.is_some_and(|e| validation.converged(e));
    let mut epochs_trained = start_epoch as f64;
    for epoch in start_epoch..config.epochs {
        if stopped {
            break;
        }
        let mut rng =
            StdRng::seed_from_u64(seed ^ (epoch as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let mut order = trained_units.clone();
        order.shuffle(&mut rng);
        order.truncate(per_epoch);
        let order = main.children_of(&order, group);
        let mut cross_order: Vec<usize> = cross
            .map(|(c, _)| (0..c.texels()).collect())
            .unwrap_or_default();
        cross_order.shuffle(&mut rng);

        let mut epoch_loss = 0.0f64;
        let mut epoch_texels = 0;
        for (step_in_epoch, indices) in order.chunks(batch).enumerate() {
            let lr = match config.schedule {
                Schedule::Constant => base_lr,
                Schedule::Cosine => {
                    let t = adam.step as f64 / total_steps.max(1) as f64;
                    base_lr * 0.5 * (1.0 + (std::f64::consts::PI * t).cos())
                }
            };
            let cross_picked = cross.map(|(examples, weight)| {
                let n = examples.texels();
                let start = (step_in_epoch * batch) % n;
                let picked: Vec<usize> = (0..indices.len())
                    .map(|k| cross_order[(start + k) % n])
                    .collect();
                (examples, weight, picked)
            });
            if progress.cancelled() {
                return Err(Error::Cancelled { epochs_done: epoch });
            }
            // The batch in one part per thread, each run forward and backward on its own:
            // the loss is a sum over texels, so the parts' gradients add up to the batch's,
            // and the threads meet once a step instead of in every op. Parts hold whole groups.
            let groups = indices.len() / group;
            let parts = rayon::current_num_threads().min(groups).max(1);
            let share = |items: usize, part: usize, unit: usize| {
                unit * (items * part / parts)..unit * (items * (part + 1) / parts)
            };
            let consistency = consistency_weight.map(|w| (w, groups));
            let results = (0..parts)
                .into_par_iter()
                .map(|part| -> Result<(f64, candle_core::backprop::GradStore)> {
                    let mut loss = batch_loss(
                        filter,
                        main,
                        &terms,
                        &indices[share(groups, part, group)],
                        indices.len(),
                        consistency,
                    )?;
                    if let Some((examples, weight, picked)) = &cross_picked {
                        let extra = batch_loss(
                            filter,
                            examples,
                            &terms,
                            &picked[share(picked.len(), part, 1)],
                            picked.len(),
                            None,
                        )?;
                        loss = (loss + extra.affine(*weight as f64, 0.0)?)?;
                    }
                    Ok((loss.to_scalar::<f32>()? as f64, loss.backward()?))
                })
                .collect::<Result<Vec<_>>>()?;
            let (values, grads): (Vec<f64>, Vec<_>) = results.into_iter().unzip();
            let value: f64 = values.iter().sum();
            if !value.is_finite() {
                return Err(Error::Invalid(format!(
                    "training diverged: loss {value} at epoch {}",
                    epoch + 1
                )));
            }
            adam.update(&filter.vars, &grads, lr)?;
            epoch_loss += value * indices.len() as f64;
            epoch_texels += indices.len();
            progress.advance(1, Some(value));

            // `checks_per_epoch` evenly spaced checks, the last at the epoch's end.
            let step = step_in_epoch + 1;
            if let Some(e) = early_stop {
                let checks = |steps: usize| steps * e.checks_per_epoch / steps_per_epoch;
                if checks(step) > checks(step - 1) {
                    let loss = objective_on(
                        filter,
                        main,
                        &terms,
                        &held_out,
                        batch,
                        group,
                        consistency_weight,
                    )?;
                    if validation.record(loss, e) {
                        stopped = true;
                        epochs_trained = epoch as f64 + step as f64 / steps_per_epoch as f64;
                        break;
                    }
                }
            }
        }
        stats
            .epoch_losses
            .push(epoch_loss / epoch_texels.max(1) as f64);
        if !stopped {
            epochs_trained = (epoch + 1) as f64;
        }
        if let Some(cp) = checkpoint {
            cp.save(
                filter,
                &adam,
                &CheckpointMeta {
                    fingerprint: cp.fingerprint.clone(),
                    epochs_done: epoch + 1,
                    adam_step: adam.step,
                    epoch_losses: stats.epoch_losses.clone(),
                    validation: validation.clone(),
                },
            )?;
        }
    }
    if stopped {
        progress.note(&format!(
            "training stopped after {epochs_trained:.2} of {} epochs: the held-out loss gained less than {}% over {} checks",
            config.epochs,
            config.early_stop.min_gain * 100.0,
            config.early_stop.patience
        ));
    }
    stats.steps = adam.step;
    stats.epochs_trained = epochs_trained;
    stats.stopped = if stopped {
        Stop::Converged
    } else {
        Stop::MaxEpochs
    };
    stats.validation_losses = validation.losses;
    Ok(stats)
}

/// Splits `units` into `held` (up to `wanted`, at most a tenth of them, at least one) drawn
/// from `seed`, and the rest, in order.
fn split_validation(units: usize, wanted: usize, seed: u64) -> (Vec<usize>, Vec<usize>) {
    let held = wanted.min(units / 10).max(1).min(units.saturating_sub(1));
    let mut rng = StdRng::seed_from_u64(seed ^ 0x005E_ED0F_4E1D_0075);
    let mut picked = rand::seq::index::sample(&mut rng, units, held).into_vec();
    picked.sort_unstable();
    let mut is_held = vec![false; units];
    for &u in &picked {
        is_held[u] = true;
    }
    let rest = (0..units).filter(|&u| !is_held[u]).collect();
    (picked, rest)
}

/// The objective's mean over `texels` (whole groups of `group`), in batches of `batch`, no
/// gradient kept: what early stopping watches.
fn objective_on(
    filter: &Filter,
    examples: &Arc<Examples>,
    terms: &LossTerms,
    texels: &[usize],
    batch: usize,
    group: usize,
    consistency_weight: Option<f32>,
) -> Result<f64> {
    let sums = texels
        .par_chunks(batch)
        .map(|chunk| -> Result<f64> {
            let consistency = consistency_weight.map(|w| (w, chunk.len() / group));
            let loss = batch_loss(filter, examples, terms, chunk, chunk.len(), consistency)?;
            Ok(loss.to_scalar::<f32>()? as f64 * chunk.len() as f64)
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(sums.iter().sum::<f64>() / texels.len().max(1) as f64)
}

/// What a batch's loss is made of besides its examples and texels.
struct LossTerms<'a> {
    shading: &'a Shading,
    fixed: [Option<f32>; FEATURES],
    /// The prior's weight per feature.
    prior: [f32; FEATURES],
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
    fn early_stopping_waits_for_patience_checks_without_the_minimum_gain() {
        let config = EarlyStopConfig {
            patience: 2,
            min_gain: 0.01,
            ..Default::default()
        };
        let mut v = Validation::default();
        // 0.995 and 0.992 gain under 1% on the best (1.0): stale twice, stop.
        assert!(!v.record(1.0, &config));
        assert!(!v.record(0.995, &config));
        assert_eq!((v.best, v.stale), (Some(1.0), 1));
        // 0.98 is a 2% gain: the count starts again.
        assert!(!v.record(0.98, &config));
        assert_eq!((v.best, v.stale), (Some(0.98), 0));
        // 0.975 and 0.99 do not gain 1% on 0.98: stop after the second.
        assert!(!v.record(0.975, &config));
        assert!(v.record(0.99, &config));
        assert!(v.converged(&config));
        assert_eq!(v.losses, [1.0, 0.995, 0.98, 0.975, 0.99]);
    }

    #[test]
    fn validation_texels_are_a_fixed_part_never_trained_on() {
        let (held, rest) = split_validation(1000, 64, 7);
        assert_eq!((held.len(), rest.len()), (64, 936));
        let mut all: Vec<usize> = held.iter().chain(&rest).copied().collect();
        all.sort_unstable();
        assert_eq!(all, (0..1000).collect::<Vec<_>>(), "disjoint and complete");
        assert_eq!(
            split_validation(1000, 64, 7).0,
            held,
            "the same seed, the same part"
        );
        assert_ne!(split_validation(1000, 64, 8).0, held);
        // At most a tenth of the texels.
        assert_eq!(split_validation(1000, 5000, 7).0.len(), 100);
    }

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
