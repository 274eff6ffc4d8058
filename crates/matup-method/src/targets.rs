//! The renders the filter is trained to reproduce, made one of three ways: the LR renders
//! upsampled by the RGB upsampler (direct, the paper's), the same with the interpolation bias
//! removed (detail), or exact renders of the true material (the oracle, for benchmarks); and
//! how they are stored.

use rayon::prelude::*;

use crate::config::TargetKind;
use crate::filter::decode::decode;
use crate::filter::FEATURES;
use matup_core::color::to_u8;
use matup_core::lights::Light;
use matup_core::map::Map;
use matup_core::material::{texel_position, Material};
use matup_core::progress::Progress;
use matup_core::render::{render, render_texels, RenderOptions};
use matup_core::resample::{upsample, Border, Kernel};
use matup_core::shading::{ShadingModel, Texel};
use matup_core::upsample::RgbUpsampler;
use matup_core::{Error, Result};

/// Renders are made and upsampled this many lights at a time (bounds the memory of f32
/// renders in flight).
const LIGHT_CHUNK: usize = 8;

/// Display-space targets of every texel under every light, 8 bits per channel, texel-major
/// (`[texel][light][rgb]`): 100 lights × 4K² × RGB is 5 GB instead of 20 GB in f32.
#[derive(Clone, Debug, Default)]
pub struct Targets {
    pub lights: usize,
    pub data: Vec<u8>,
}

impl Targets {
    /// Room for `texels × lights` targets, all 0.
    pub fn new(texels: usize, lights: usize) -> Targets {
        Targets {
            lights,
            data: vec![0; texels * lights * 3],
        }
    }

    /// Quantises display-space renders (one map per light) by rounding.
    pub fn from_renders(renders: &[Map]) -> Targets {
        let mut targets = Targets::new(renders[0].texels(), renders.len());
        targets.fill(0, renders);
        targets
    }

    /// Stores the renders of lights `first..first + renders.len()`, quantised by rounding.
    pub fn fill(&mut self, first: usize, renders: &[Map]) {
        let lights = self.lights;
        assert!(first + renders.len() <= lights, "more renders than lights");
        self.data
            .par_chunks_mut(lights * 3)
            .enumerate()
            .for_each(|(t, row)| {
                for (l, r) in renders.iter().enumerate() {
                    for c in 0..3 {
                        row[(first + l) * 3 + c] = to_u8(r.plane(c)[t]);
                    }
                }
            });
    }

    /// The targets of one texel as f32, written into `out`.
    #[inline]
    pub fn texel(&self, index: usize, out: &mut Vec<[f32; 3]>) {
        let row = &self.data[index * self.lights * 3..][..self.lights * 3];
        out.clear();
        out.extend(row.chunks_exact(3).map(|c| {
            [
                c[0] as f32 / 255.0,
                c[1] as f32 / 255.0,
                c[2] as f32 / 255.0,
            ]
        }));
    }
}

/// What the upsampled targets are made from: the LR renders and how they were made.
pub struct LrRenders<'a> {
    /// The LR material's anti-aliased renders, one per light of `lights`.
    pub renders: &'a [Map],
    pub lights: &'a [Light],
    pub model: &'a dyn ShadingModel,
    pub scale: usize,
    pub border: Border,
}

/// The residual base as detail targets render it: output-size features, decoded as the
/// filter decodes (constant features held), at the training loss's positions.
pub struct DetailBase<'a> {
    pub features: &'a Map,
    pub fixed: &'a [Option<f32>; FEATURES],
    /// Output-size height, if any (the training loss's displacement).
    pub heights: Option<&'a Map>,
    /// The kernel that made the base from the LR maps, or `None` for a base made by the
    /// RGB upsampler itself (each map on its own), whose detail targets are its own renders.
    pub kernel: Option<Kernel>,
}

/// Targets of `kind` from the LR renders and the RGB upsampler `s`.
pub fn upsampled_targets(
    kind: TargetKind,
    lr: &LrRenders,
    s: &dyn RgbUpsampler,
    base: &DetailBase,
    progress: &dyn Progress,
) -> Result<Targets> {
    let mut targets = Targets::new(base.features.texels(), lr.renders.len());
    let (w, h) = (base.features.width(), base.features.height());
    let texels = (kind == TargetKind::Detail).then(|| base_texels(base));
    let chunks = lr
        .renders
        .chunks(LIGHT_CHUNK)
        .zip(lr.lights.chunks(LIGHT_CHUNK));
    for (k, (chunk, lights)) in chunks.enumerate() {
        let up = match (&texels, base.kernel) {
            (None, _) => s.upsample(chunk, lr.scale, lr.border)?,
            // S − B is 0: the base's own renders.
            (Some(texels), None) => render_texels(texels, w, h, lr.model, lights),
            (Some(texels), Some(kernel)) => {
                let mut up = s.upsample(chunk, lr.scale, lr.border)?;
                let renders = render_texels(texels, w, h, lr.model, lights);
                for ((t, r), b) in up.iter_mut().zip(chunk).zip(&renders) {
                    let interpolated = upsample(r, lr.scale, kernel, lr.border);
                    // T = R(M_base) + (S(r) − K(r)), in display space: the detail first, so
                    // that where S adds nothing the targets are the base's renders exactly.
                    let values = t.data_mut().iter_mut();
                    for ((v, i), b) in values.zip(interpolated.data()).zip(b.data()) {
                        *v = (b + (*v - i)).clamp(0.0, 1.0);
                    }
                }
                up
            }
        };
        targets.fill(k * LIGHT_CHUNK, &up);
        progress.advance(chunk.len() as u64, None);
    }
    Ok(targets)
}

/// Exact renders of the true material (box-filtered to the `w × h` output first when it is
/// larger, as for the first of two levels): the method's ceiling, for benchmarks.
pub fn oracle_targets(
    truth: &Material,
    w: usize,
    h: usize,
    lights: &[Light],
    model: &dyn ShadingModel,
    border: Border,
    progress: &dyn Progress,
) -> Result<Targets> {
    let factor = truth.width() / w;
    if factor == 0 || truth.width() != factor * w || truth.height_px() != factor * h {
        return Err(Error::Invalid(format!(
            "the oracle material is {}×{}, not a multiple of the {w}×{h} output",
            truth.width(),
            truth.height_px()
        )));
    }
    let truth = if factor > 1 {
        truth.box_downsample(factor)
    } else {
        truth.clone()
    };
    let mut targets = Targets::new(w * h, lights.len());
    for (k, chunk) in lights.chunks(LIGHT_CHUNK).enumerate() {
        let options = RenderOptions {
            supersample: true,
            border,
        };
        targets.fill(k * LIGHT_CHUNK, &render(&truth, model, chunk, options));
        progress.advance(chunk.len() as u64, None);
    }
    Ok(targets)
}

/// The display-space renders of the base under `lights`, one texel per output texel, as the
/// training loss renders them.
pub fn base_renders(base: &DetailBase, model: &dyn ShadingModel, lights: &[Light]) -> Vec<Map> {
    let (w, h) = (base.features.width(), base.features.height());
    render_texels(&base_texels(base), w, h, model, lights)
}

/// The base's texels: its features decoded with no residual, at the training loss's positions.
fn base_texels(base: &DetailBase) -> Vec<Texel> {
    let (w, h) = (base.features.width(), base.features.height());
    (0..w * h)
        .into_par_iter()
        .map(|t| {
            let f: [f32; FEATURES] = base.features.texel(t);
            Texel {
                params: decode(&[0.0; FEATURES], &f, base.fixed).params,
                position: texel_position(t, w, h, base.heights),
            }
        })
        .collect()
}
