//! What the two backends' training steps share: the [`Stepper`] interface the epoch loop
//! drives, and a step's inputs besides its texels (shading, loss terms, the cross-scale part).

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use candle_core::Tensor;

use super::examples::Examples;
use crate::filter::FEATURES;
use matup_core::lights::Light;
use matup_core::loss::LossNorm;
use matup_core::shading::ShadingModel;
use matup_core::Result;

/// What the renders are compared with, and how.
#[derive(Clone)]
pub struct Shading {
    pub model: Arc<dyn ShadingModel>,
    pub lights: Arc<[Light]>,
    pub norm: LossNorm,
}

/// How training steps are computed: the fused CPU code (`fused_backend`) or candle tensor
/// operations on any device (`tensor_backend`). The epoch loop, early stopping and checkpoints
/// are the same for both.
pub(super) trait Stepper {
    /// One optimiser step at learning rate `lr` on the main texels `indices` (whole groups of
    /// `group` texels) and, with its weight, the cross-scale texels `cross`; the batch's loss.
    fn step(&mut self, indices: &[usize], cross: Option<CrossBatch>, lr: f64) -> Result<f64>;
    /// The objective's mean over `texels` (whole groups), no gradient kept.
    fn objective(&self, texels: &[usize]) -> Result<f64>;
    /// Optimiser steps taken.
    fn steps(&self) -> u64;
    /// The weights (named as [`Filter::named_tensors`]) and the optimiser's state.
    fn state(&self) -> Result<HashMap<String, Tensor>>;
    /// Restores [`state`](Self::state) saved after `steps` steps.
    fn restore(&mut self, state: &HashMap<String, Tensor>, steps: u64, origin: &Path)
        -> Result<()>;
    /// Leaves the trained weights in the filter.
    fn finish(&self) -> Result<()>;
}

/// A step's cross-scale part: its examples, weight and texels.
pub(super) struct CrossBatch<'a> {
    pub(super) examples: &'a Arc<Examples>,
    pub(super) weight: f32,
    pub(super) texels: Vec<usize>,
}

/// What a batch's loss is made of besides its examples and texels.
pub(super) struct LossTerms<'a> {
    pub(super) shading: &'a Shading,
    pub(super) fixed: [Option<f32>; FEATURES],
    /// The prior's weight per feature.
    pub(super) prior: [f32; FEATURES],
}
