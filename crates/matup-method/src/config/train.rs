//! The `[train]` settings: the filter's training, its prior and early stop.

use serde::{Deserialize, Serialize};

use super::values::{as_string, Backend, Schedule, TargetKind};
use matup_core::loss::LossNorm;
use matup_core::{Error, Result};

/// Weights of the map-space prior `Σ_k w_k (f_k − base_k)²`, averaged over texels: each
/// pulls a feature of the output toward the residual base.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PriorConfig {
    /// On each channel of the linear base colour.
    pub base_color: f32,
    /// α of METHOD.md's metallic regulariser.
    pub metallic: f32,
    /// On the normal's x and y.
    pub normal: f32,
    /// On alpha (roughness²).
    pub roughness: f32,
}

impl Default for PriorConfig {
    fn default() -> Self {
        PriorConfig {
            base_color: 0.0,
            metallic: 0.1,
            normal: 0.0,
            roughness: 0.0,
        }
    }
}

impl PriorConfig {
    /// The weight of each of the filter's 7 features.
    pub fn feature_weights(&self) -> [f32; 7] {
        let (b, n) = (self.base_color, self.normal);
        [b, b, b, self.metallic, n, n, self.roughness]
    }

    /// Sets weights from `KEY=W,KEY=W` (keys base_color, metallic, normal, roughness).
    pub fn set(&mut self, assignments: &str) -> Result<()> {
        for part in assignments.split(',').filter(|p| !p.trim().is_empty()) {
            let bad = || {
                Error::Invalid(format!(
                    "prior '{part}': use KEY=WEIGHT with KEY base_color, metallic, normal or roughness and WEIGHT ≥ 0"
                ))
            };
            let (key, value) = part.split_once('=').ok_or_else(bad)?;
            let value: f32 = value.trim().parse().map_err(|_| bad())?;
            let slot = match key.trim() {
                "base_color" => &mut self.base_color,
                "metallic" => &mut self.metallic,
                "normal" => &mut self.normal,
                "roughness" => &mut self.roughness,
                _ => return Err(bad()),
            };
            *slot = value;
        }
        Ok(())
    }
}

/// Why a tensor-backend run refuses β and γ (their ops run on the CPU only).
pub(crate) const FUSED_ONLY_TERMS: &str = "train.lr_consistency (β) and train.cross_scale (γ) are trained by the fused backend only (train.backend = fused, on the CPU)";

/// Training.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainConfig {
    /// Passes over every output texel; 0 (the default) trains no filter, and the residual
    /// base is the result. Measured on the shared materials, a filter trained on renders
    /// upsampled by the shipped SPAN network does not improve on a back-projected per-map
    /// base (docs/experiments/2026-11-21-quality-against-per-map.md).
    pub epochs: usize,
    /// Texels per step.
    pub batch_size: usize,
    pub learning_rate: f64,
    /// Multiply the learning rate by `batch_size / 128` (linear scaling).
    pub scale_learning_rate: bool,
    pub schedule: Schedule,
    #[serde(with = "as_string")]
    pub loss: LossNorm,
    pub targets: TargetKind,
    /// Map-space prior: weights pulling each feature toward the residual base (METHOD.md's
    /// metallic regulariser is `metallic = 0.1` with a bilinear base).
    pub prior: PriorConfig,
    /// β: weight of the LR-consistency term `mean ‖box_downsample(M_SR) − M_LR‖²` (0: off).
    pub lr_consistency: f32,
    /// γ: weight of cross-scale self-supervision on exact pairs one scale down (0: off).
    pub cross_scale: f32,
    /// Train on this many randomly chosen texels per epoch instead of all of them.
    pub texels_per_epoch: Option<usize>,
    /// Stop before `epochs` when a held-out validation loss stops improving.
    pub early_stop: EarlyStopConfig,
    /// How the steps are computed.
    pub backend: Backend,
}

/// Convergence-based stopping: `train.epochs` is a maximum. A fixed set of texels is held out
/// of training; every `1 / checks_per_epoch` of an epoch the objective is evaluated on them,
/// and training stops after `patience` checks in a row that did not lower the best value so
/// far by at least `min_gain` of it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EarlyStopConfig {
    /// false: train every epoch (the paper's fixed schedule).
    pub enabled: bool,
    /// Output texels held out to validate on (at most a tenth of the level's texels).
    pub validation_texels: usize,
    pub checks_per_epoch: usize,
    pub patience: usize,
    /// The relative gain a check must make to count as progress.
    pub min_gain: f64,
}

impl Default for EarlyStopConfig {
    fn default() -> Self {
        EarlyStopConfig {
            enabled: true,
            validation_texels: 8192,
            checks_per_epoch: 4,
            // Chosen on 256² and 512² crops of the four shared materials with the paper's
            // settings (docs/experiments/2026-11-23-early-stopping.md): 2 checks or a 0.2–0.5% gain
            // stopped too soon (−0.04 to −0.08 dB on average).
            patience: 4,
            min_gain: 1e-3,
        }
    }
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig {
            epochs: 0,
            batch_size: 128,
            learning_rate: 1e-4,
            scale_learning_rate: false,
            schedule: Schedule::Constant,
            loss: LossNorm::L21,
            targets: TargetKind::Detail,
            prior: PriorConfig::default(),
            lr_consistency: 0.0,
            cross_scale: 0.0,
            texels_per_epoch: None,
            early_stop: EarlyStopConfig::default(),
            backend: Backend::Auto,
        }
    }
}
