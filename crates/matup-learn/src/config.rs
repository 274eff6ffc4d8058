//! A training run's settings, read from TOML (`configs/learn/*.toml`).

use std::path::{Path, PathBuf};

use matup_core::degrade::MaterialDegradation;
use matup_core::{Error, LossNorm, Result};
use serde::{Deserialize, Serialize};

use crate::data::Shares;
use crate::degradations::Degradations;

/// Which of the network's tensors a run trains; the others keep the base model's values.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum Trained {
    /// Every convolution's weights and biases.
    #[default]
    All,
    /// The biases alone: the smallest change that still moves every layer (a fine-tune that
    /// stays near its start, as per-material adaptation wants).
    Biases,
    /// The last convolution's weights and bias (the one that draws the output's texels).
    LastLayer,
}

/// What the network learns to upsample.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Target {
    /// The material's maps, judged by the renders of what `matup upscale`'s defaults make of
    /// them (decoded, back-projected): a network for the per-map residual base.
    #[default]
    Maps,
    /// Renders: the LR material's renders to the true material's, under the same light (the
    /// method's targets; METHOD.md). Judged by the upsampled renders of the validation
    /// materials against the renders of their truth.
    Renders,
    /// The normal map alone (a network per map kind), judged through the renders of the true
    /// material with its normals replaced by the network's, back-projected as the defaults
    /// back-project them: the map that carries the maps network's render gain.
    Normals,
}

/// What `matup learn` trains and how. Paths are relative to the directory matup runs in.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LearnConfig {
    /// The network to start from (`NAME.onnx` with its sidecar `NAME.toml`).
    pub base_model: PathBuf,
    /// The folder holding the training and validation materials.
    pub corpus: PathBuf,
    /// Materials trained on (folder names in `corpus`).
    pub train: Vec<String>,
    /// Materials validated on, never trained on.
    pub val: Vec<String>,
    /// What the network upsamples: `maps` (the default), `renders` or `normals`.
    #[serde(default)]
    pub target: Target,
    /// Upsampling factor: the network's, or a smaller one that matup reaches through it (×4,
    /// then area-shrunk: `matup_core::upsample::route`), which training then goes through too.
    #[serde(default = "default_scale")]
    pub scale: usize,
    /// Optimiser steps in all (a resumed run continues to this count).
    pub iterations: usize,
    /// Material crops per step; each sends its four maps through the network (its render under
    /// each light with `target = "renders"`, its normal map with `target = "normals"`).
    #[serde(default = "default_batch")]
    pub batch: usize,
    /// Side of a true crop in texels (its LR version is `patch / scale`).
    #[serde(default = "default_patch")]
    pub patch: usize,
    /// Random lights over the hemisphere per step (shared by the step's crops).
    #[serde(default = "default_lights")]
    pub lights: usize,
    /// Adam's step size.
    pub learning_rate: f64,
    /// The render loss's norm over colour and lights (as the method's `train.loss`).
    #[serde(default = "default_loss")]
    pub loss: String,
    /// Weight of the normal term (mean chordal distance between the normals) beside the renders;
    /// maps only.
    #[serde(default)]
    pub normal_weight: f64,
    /// With `target = "normals"`: the LR height map as a fourth input channel beside the
    /// normals (a joint network: normals and height are two views of one surface). Its
    /// weights in the first convolution start at zero, so the run starts as the base model.
    #[serde(default)]
    pub height_guide: bool,
    /// Share of the training crops cut into tiles with grout between them, made of the
    /// corpus's own maps (`floor_tiles.rs`: tiled floors and walls, which the corpus lacks); 0: none.
    #[serde(default)]
    pub tiled_share: f64,
    /// Share of the training crops taken at half the material's resolution (cut twice as
    /// large, box-filtered): the corpus's materials each come at one scale, the materials
    /// users bring at any; 0: none.
    #[serde(default)]
    pub zoom_out_share: f64,
    /// LR texels of the material around each training crop that the network reads and the
    /// loss does not score (maps only): inside an image, where matup's executor reads each
    /// tile with its neighbours, the network never meets the zero padding at a crop's edge,
    /// and with a 32² LR crop most of the loss lies within its reach; 0: the crop alone.
    #[serde(default)]
    pub context: usize,
    /// Weight of the grid term beside the renders (maps only): how far the steps across the
    /// output's `scale`-texel block edges lie from the truth's block-edge ratio to the steps
    /// inside its blocks, either way, over the batch ([`crate::grid_term::grid_term`]); 0: none.
    #[serde(default)]
    pub grid_weight: f64,
    /// Pull toward the base model's weights: after each step every weight `w` moves by
    /// `learning_rate · anchor_weight · (w₀ − w)` toward its start `w₀` (decoupled, as AdamW
    /// decays toward zero; the idea of L2-SP, Li et al. 2018). A blend with the base model
    /// learned while training rather than chosen after; 0: none.
    #[serde(default)]
    pub anchor_weight: f64,
    /// Which tensors learn: `all`, `biases` or `last-layer`.
    #[serde(default)]
    pub trained: Trained,
    /// Steps between checkpoints.
    #[serde(default = "default_checkpoint_every")]
    pub checkpoint_every: usize,
    /// Steps between validations (each exports the network and runs `matup upscale`'s
    /// defaults with it on every validation material).
    #[serde(default = "default_validate_every")]
    pub validate_every: usize,
    /// Side of the validation crops (top-left) of the true materials.
    #[serde(default = "default_val_crop")]
    pub val_crop: usize,
    /// Held-out lights of the validation renders.
    #[serde(default = "default_val_lights")]
    pub val_lights: usize,
    /// What the network's LR inputs go through (block compression, JPEG, dithering, noise,
    /// blur, halos), drawn per crop and per map; the truth stays clean. None: clean inputs.
    #[serde(default)]
    pub degradations: Option<Degradations>,
    /// Named degradations (`matup_core::degrade::MaterialDegradation`: `jpeg75`, `bc1`, …),
    /// each adding a degraded copy of every validation material to the validation set.
    #[serde(default)]
    pub val_degrade: Vec<String>,
    pub seed: u64,
}

fn default_scale() -> usize {
    4
}
fn default_batch() -> usize {
    3
}
fn default_patch() -> usize {
    128
}
fn default_lights() -> usize {
    8
}
fn default_loss() -> String {
    "l11".into()
}
fn default_checkpoint_every() -> usize {
    25
}
fn default_validate_every() -> usize {
    200
}
fn default_val_crop() -> usize {
    512
}
fn default_val_lights() -> usize {
    16
}

impl LearnConfig {
    /// Reads and checks a configuration file.
    pub fn load(path: &Path) -> Result<LearnConfig> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let config: LearnConfig =
            toml::from_str(&text).map_err(|e| Error::file(path, e.to_string()))?;
        config
            .validate()
            .map_err(|e| Error::file(path, e.to_string()))?;
        Ok(config)
    }

    /// The side of the crops a step draws: the scored patch and its context.
    pub fn crop_size(&self) -> usize {
        self.patch + 2 * self.context * self.scale
    }

    /// The shares of the training crops zoomed out and cut into tiles.
    pub fn shares(&self) -> Shares {
        Shares {
            zoom_out: self.zoom_out_share,
            tiled: self.tiled_share,
        }
    }

    /// The loss norm `loss` names.
    pub fn loss_norm(&self) -> Result<LossNorm> {
        self.loss.parse()
    }

    fn validate(&self) -> std::result::Result<(), String> {
        if self.train.is_empty() {
            return Err("train lists no material".into());
        }
        if let Some(m) = self.train.iter().find(|m| self.val.contains(m)) {
            return Err(format!("'{m}' is in both train and val"));
        }
        if self.scale < 2 || !self.patch.is_multiple_of(self.scale) || self.patch < 4 * self.scale {
            return Err(format!(
                "patch {} must be a multiple of scale {} and at least 4 LR texels",
                self.patch, self.scale
            ));
        }
        if !self.val_crop.is_multiple_of(self.scale) {
            return Err(format!(
                "val_crop {} is not a multiple of scale {}",
                self.val_crop, self.scale
            ));
        }
        if self.batch == 0 || self.lights == 0 || self.checkpoint_every == 0 {
            return Err("batch, lights and checkpoint_every must be positive".into());
        }
        if !self.learning_rate.is_finite() || self.learning_rate <= 0.0 {
            return Err("learning_rate must be positive".into());
        }
        let pull = self.learning_rate * self.anchor_weight;
        if !(0.0..=1.0).contains(&pull) {
            return Err(format!(
                "anchor_weight {} must be at least 0 and at most 1 / learning_rate ({})",
                self.anchor_weight,
                1.0 / self.learning_rate
            ));
        }
        if self.target != Target::Maps && self.context != 0 {
            return Err("context needs target = \"maps\"".into());
        }
        if self.target == Target::Renders && self.normal_weight != 0.0 {
            return Err(
                "normal_weight needs target = \"maps\": a network of renders makes no normals"
                    .into(),
            );
        }
        for (key, share) in [
            ("tiled_share", self.tiled_share),
            ("zoom_out_share", self.zoom_out_share),
        ] {
            if !(0.0..=1.0).contains(&share) {
                return Err(format!("{key} {share} must be between 0 and 1"));
            }
        }
        if self.grid_weight != 0.0 && (self.target != Target::Maps || self.grid_weight < 0.0) {
            return Err("grid_weight needs target = \"maps\" and is at least 0".into());
        }
        if self.height_guide && self.target != Target::Normals {
            return Err("height_guide needs target = \"normals\"".into());
        }
        if let Some(d) = &self.degradations {
            if self.target != Target::Maps {
                return Err("degradations need target = \"maps\"".into());
            }
            d.validate()?;
        }
        for name in &self.val_degrade {
            name.parse::<MaterialDegradation>()
                .map_err(|e| format!("val_degrade: {e}"))?;
        }
        self.loss_norm().map_err(|e| e.to_string())?;
        Ok(())
    }
}
