//! The one renderer: a material under a set of lights with a shading model, in display space.
//! It serves LR renders, previews and evaluation alike.

use rayon::prelude::*;

use crate::lights::Light;
use crate::map::Map;
use crate::material::Material;
use crate::resample::{box_downsample, Border, Kernel};
use crate::shading::{ShadingModel, Texel};

/// How to render.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderOptions {
    /// Anti-alias: upsample the maps 2× bilinearly, render, average 2×2 blocks (METHOD.md's
    /// LR renders).
    pub supersample: bool,
    /// Border used by the supersampling upsample.
    pub border: Border,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            supersample: true,
            border: Border::Wrap,
        }
    }
}

/// Every texel of a material, ready to shade.
pub fn texels(material: &Material) -> Vec<Texel> {
    (0..material.base_color.texels())
        .into_par_iter()
        .map(|i| material.texel(i))
        .collect()
}

/// Renders `material` under each light: one display-space RGB map per light, the size of the
/// material.
pub fn render(
    material: &Material,
    model: &dyn ShadingModel,
    lights: &[Light],
    options: RenderOptions,
) -> Vec<Map> {
    if options.supersample {
        let fine = material.upsample(2, Kernel::Bilinear, options.border);
        render_texels(
            &texels(&fine),
            fine.width(),
            fine.height_px(),
            model,
            lights,
        )
        .iter()
        .map(|m| box_downsample(m, 2))
        .collect()
    } else {
        render_texels(
            &texels(material),
            material.width(),
            material.height_px(),
            model,
            lights,
        )
    }
}

/// Display-space renders of `texels` (a `width × height` grid, one per output texel) under
/// each light.
pub fn render_texels(
    texels: &[Texel],
    width: usize,
    height: usize,
    model: &dyn ShadingModel,
    lights: &[Light],
) -> Vec<Map> {
    let n = width * height;
    lights
        .iter()
        .map(|light| {
            let mut data = vec![0f32; 3 * n];
            let (r, rest) = data.split_at_mut(n);
            let (g, b) = rest.split_at_mut(n);
            r.par_chunks_mut(width)
                .zip(g.par_chunks_mut(width))
                .zip(b.par_chunks_mut(width))
                .zip(texels.par_chunks(width))
                .for_each(|(((r, g), b), row)| {
                    for (x, t) in row.iter().enumerate() {
                        let mut out = [[0f32; 3]; 1];
                        model.render_texel(t, std::slice::from_ref(light), &mut out);
                        [r[x], g[x], b[x]] = out[0];
                    }
                });
            Map::from_planar(width, height, 3, data)
        })
        .collect()
}
