//! Training examples at one scale: the filter's input windows, the output texels they
//! stand for, and what the filter's answers are judged by.

use std::sync::Arc;

use crate::filter::input::UpsampledInput;
use crate::filter::Filter;
use crate::targets::Targets;
use matup_core::map::Map;
use matup_core::resample::Border;

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
    pub(super) fn scale(&self) -> usize {
        self.width / self.features.width()
    }

    /// The `scale²` output texels covering each of the input texels `parents`, a group per
    /// parent, row by row.
    pub(super) fn children(&self, parents: &[usize]) -> Vec<usize> {
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
    pub(super) fn children_of(&self, units: &[usize], group: usize) -> Vec<usize> {
        if group > 1 {
            self.children(units)
        } else {
            units.to_vec()
        }
    }

    /// The input texel an output texel lies in.
    pub(super) fn parent(&self, texel: usize) -> usize {
        let s = self.scale();
        (texel / self.width / s) * self.features.width() + (texel % self.width) / s
    }
}
