//! The one renderer: a material under a set of lights with a shading model, in display space.
//! It serves LR renders, previews and evaluation alike.

use rayon::prelude::*;

use crate::lights::Light;
use crate::map::Map;
use crate::material::Material;
use crate::resample::{box_downsample, Border, Kernel};
use crate::shading::{ShadingModel, Texel};
use crate::text::{draw_text, text_width};

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

/// Lays images out on a grid, `columns` wide, with a `gap`-texel dark border between them.
pub fn contact_sheet(images: &[Map], columns: usize, gap: usize) -> Map {
    assert!(!images.is_empty() && columns > 0);
    let (w, h) = (images[0].width(), images[0].height());
    let rows = images.len().div_ceil(columns);
    let (sw, sh) = (columns * (w + gap) + gap, rows * (h + gap) + gap);
    let mut sheet = Map::filled(sw, sh, 3, 0.1);
    for (k, image) in images.iter().enumerate() {
        let (x0, y0) = (
            gap + (k % columns) * (w + gap),
            gap + (k / columns) * (h + gap),
        );
        for c in 0..3 {
            for y in 0..h {
                for x in 0..w {
                    sheet.set(
                        c,
                        y0 + y,
                        x0 + x,
                        image.get(c.min(image.channels() - 1), y, x),
                    );
                }
            }
        }
    }
    sheet
}

/// A contact sheet with a label over each column and a caption over each row, in light grey
/// on the sheet's dark background (`gap` texels between images, as [`contact_sheet`]).
pub fn labelled_sheet(
    images: &[Map],
    columns: usize,
    gap: usize,
    column_labels: &[String],
    row_captions: &[String],
) -> Map {
    const TEXT: f32 = 14.0;
    const STRIP: usize = 20;
    const INK: [f32; 3] = [0.85, 0.85, 0.85];
    let (w, h) = (images[0].width(), images[0].height());
    let rows = images.len().div_ceil(columns);
    let sheet = contact_sheet(images, columns, gap);
    let mut out = Map::filled(sheet.width(), sheet.height() + STRIP * (rows + 1), 3, 0.1);
    for (column, label) in column_labels.iter().enumerate().take(columns) {
        let centre = (gap + column * (w + gap)) as f32 + w as f32 / 2.0;
        let x = (centre - text_width(TEXT, label) / 2.0).max(gap as f32);
        draw_text(&mut out, x, 2.0, TEXT, label, INK);
    }
    for row in 0..rows {
        let top = gap + row * (h + gap); // the row's first line in `sheet`
        let shift = STRIP * (row + 2); // its header strip and caption strips above it
        if let Some(caption) = row_captions.get(row) {
            draw_text(
                &mut out,
                gap as f32,
                (top + shift - STRIP + 2) as f32,
                TEXT,
                caption,
                INK,
            );
        }
        for y in top..(top + h + gap).min(sheet.height()) {
            for c in 0..3 {
                for x in 0..sheet.width() {
                    out.set(c, y + shift, x, sheet.get(c, y, x));
                }
            }
        }
    }
    out
}
