//! Training the filter: the epoch loop with early stopping, and checkpoints. Its examples are
//! in `examples`; the steps themselves in `fused_backend` (hand-written CPU code) or
//! `tensor_backend` (candle operations, any device), behind `stepper`'s interface, both
//! stepped by [`adam`].

pub mod adam;
mod examples;
mod fused_backend;
mod stepper;
mod tensor_backend;

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;

use candle_core::{Device, Tensor};
use rand::rngs::StdRng;
use rand::seq::SliceRandom;
use rand::SeedableRng;
use serde::{Deserialize, Serialize};

use crate::config::{Backend, EarlyStopConfig, Schedule, TrainConfig, FUSED_ONLY_TERMS};
use crate::filter::{Filter, FEATURES};
use matup_core::device::parse_device;
use matup_core::progress::Progress;
use matup_core::shading::ShadingModel;
use matup_core::{Error, Result};

pub use examples::Examples;
pub use stepper::Shading;
use stepper::{CrossBatch, LossTerms, Stepper};

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
    fn save(&self, state: &HashMap<String, Tensor>, meta: &CheckpointMeta) -> Result<()> {
        std::fs::create_dir_all(&self.folder).map_err(|e| Error::io(&self.folder, e))?;
        let tmp = self.folder.join("state.safetensors.partial");
        candle_core::safetensors::save(state, &tmp)?;
        std::fs::rename(&tmp, self.weights_path())
            .map_err(|e| Error::io(&self.weights_path(), e))?;
        let json = serde_json::to_vec_pretty(meta).expect("checkpoint metadata serialises");
        matup_core::io::write_atomic(&self.meta_path(), &json)
    }

    /// The saved state, if there is one for this fingerprint.
    fn load(&self) -> Result<Option<(CheckpointMeta, HashMap<String, Tensor>)>> {
        let Ok(bytes) = std::fs::read(self.meta_path()) else {
            return Ok(None);
        };
        let meta: CheckpointMeta = serde_json::from_slice(&bytes)
            .map_err(|e| Error::file(&self.meta_path(), format!("unreadable checkpoint: {e}")))?;
        if meta.fingerprint != self.fingerprint {
            return Ok(None);
        }
        let state = candle_core::safetensors::load(self.weights_path(), &Device::Cpu)?;
        Ok(Some((meta, state)))
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
    /// The backend that computed the steps (`fused` or `tensor`) and the device.
    pub backend: String,
    pub device: String,
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

/// The backend that trains `model` on `device` as `config` asks: `auto` is the fused backend
/// on the CPU when the model has a Jacobian of its own, the tensor backend otherwise.
fn training_backend(
    config: &TrainConfig,
    device: &Device,
    model: &dyn ShadingModel,
    cross_scale: bool,
) -> Result<Backend> {
    let backend = match config.backend.resolve(device.is_cpu()) {
        Backend::Fused if !model.has_jacobian() => {
            if config.backend != Backend::Auto {
                return Err(Error::Invalid(
                    "the shading model has no Jacobian of its own, so the fused backend cannot train it; use --backend tensor (or auto)".into(),
                ));
            }
            Backend::Tensor
        }
        other => other,
    };
    if backend == Backend::Tensor && (config.lr_consistency > 0.0 || cross_scale) {
        return Err(Error::Invalid(FUSED_ONLY_TERMS.into()));
    }
    Ok(backend)
}

/// Trains `filter` on `main` (and, with weight `cross_weight`, on `cross`): METHOD.md's loop,
/// every texel once per epoch in an order drawn from `seed`, for `config.epochs` or, with
/// early stopping, until the objective on held-out texels (never trained on) stops improving.
/// `config.backend` and `config.device` say how and where the steps run.
#[allow(clippy::too_many_arguments)]
pub fn train(
    filter: &Filter,
    main: &Arc<Examples>,
    cross: Option<(&Arc<Examples>, f32)>,
    shading: &Shading,
    fixed: [Option<f32>; FEATURES],
    config: &TrainConfig,
    device: &str,
    seed: u64,
    checkpoint: Option<&Checkpoint>,
    progress: &dyn Progress,
) -> Result<TrainStats> {
    // With the LR-consistency term, batches are made of whole LR texels (groups of scale²
    // output texels), so the term reads the render loss's own forward pass.
    let group = if config.lr_consistency > 0.0 {
        main.scale().pow(2)
    } else {
        1
    };
    let terms = LossTerms {
        shading,
        fixed,
        prior: config.prior.feature_weights(),
    };
    let batch = config.batch_size.div_ceil(group) * group;
    let device_name = device;
    let device = parse_device(device_name)?;
    let backend = training_backend(config, &device, shading.model.as_ref(), cross.is_some())?;
    let mut stepper: Box<dyn Stepper + '_> = match backend {
        Backend::Tensor => Box::new(tensor_backend::TensorStepper::new(
            filter, main, &terms, batch, &device,
        )?),
        Backend::Fused | Backend::Auto => Box::new(fused_backend::FusedStepper::new(
            filter,
            main,
            &terms,
            group,
            (group > 1).then_some(config.lr_consistency),
            batch,
        )),
    };
    let mut stats = TrainStats {
        backend: backend.to_string(),
        device: device_name.to_string(),
        ..TrainStats::default()
    };
    let mut validation = Validation::default();
    let mut start_epoch = 0;
    if let Some(cp) = checkpoint.filter(|c| c.resume) {
        if let Some((meta, state)) = cp.load()? {
            stepper.restore(&state, meta.adam_step, &cp.weights_path())?;
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
    let batch_units = batch / group;
    let steps_per_epoch = per_epoch.div_ceil(batch_units);
    let total_steps = (steps_per_epoch * config.epochs) as u64;
    let base_lr = if config.scale_learning_rate {
        config.learning_rate * batch as f64 / 128.0
    } else {
        config.learning_rate
    };
    progress.stage("train", total_steps);
    progress.advance(stepper.steps(), stats.epoch_losses.last().copied());

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
                    let t = stepper.steps() as f64 / total_steps.max(1) as f64;
                    base_lr * 0.5 * (1.0 + (std::f64::consts::PI * t).cos())
                }
            };
            let cross_batch = cross.map(|(examples, weight)| {
                let n = examples.texels();
                let start = (step_in_epoch * batch) % n;
                CrossBatch {
                    examples,
                    weight,
                    texels: (0..indices.len())
                        .map(|k| cross_order[(start + k) % n])
                        .collect(),
                }
            });
            if progress.cancelled() {
                return Err(Error::Cancelled { epochs_done: epoch });
            }
            let value = stepper.step(indices, cross_batch, lr)?;
            if !value.is_finite() {
                return Err(Error::Invalid(format!(
                    "training diverged: loss {value} at epoch {}",
                    epoch + 1
                )));
            }
            epoch_loss += value * indices.len() as f64;
            epoch_texels += indices.len();
            progress.advance(1, Some(value));

            // `checks_per_epoch` evenly spaced checks, the last at the epoch's end.
            let step = step_in_epoch + 1;
            if let Some(e) = early_stop {
                let checks = |steps: usize| steps * e.checks_per_epoch / steps_per_epoch;
                if checks(step) > checks(step - 1)
                    && validation.record(stepper.objective(&held_out)?, e)
                {
                    stopped = true;
                    epochs_trained = epoch as f64 + step as f64 / steps_per_epoch as f64;
                    break;
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
                &stepper.state()?,
                &CheckpointMeta {
                    fingerprint: cp.fingerprint.clone(),
                    epochs_done: epoch + 1,
                    adam_step: stepper.steps(),
                    epoch_losses: stats.epoch_losses.clone(),
                    validation: validation.clone(),
                },
            )?;
        }
    }
    stepper.finish()?;
    if stopped {
        progress.note(&format!(
            "training stopped after {epochs_trained:.2} of {} epochs: the held-out loss gained less than {}% over {} checks",
            config.epochs,
            config.early_stop.min_gain * 100.0,
            config.early_stop.patience
        ));
    }
    stats.steps = stepper.steps();
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
}
